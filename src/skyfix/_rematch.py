"""Re-matching the catalogue through a fitted camera, for the final fit (:mod:`skyfix.final_fit`):
the matches as arrays (:class:`Matches`), the catalogue stars about the boresight, found once
per final fit (:class:`CatalogueCone`), the match itself (:func:`match_catalogue`), and
the equidistant consensus a fisheye's fit starts from when identification's stars hold many
wrong neighbours (:func:`equidistant_consensus`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix._kernels import lens, rotation
from skyfix.identify.common.verify import cell_band

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

__all__ = ["CONE_MARGIN", "CatalogueCone", "Matches", "Rematched", "chord", "cone_stars",
           "equidistant_consensus", "match_catalogue", "rotated", "star_tree", "within"]


class Matches(NamedTuple):
    """Centroid index, catalogue id, unit vector and magnitude of each matched star."""

    idx: np.ndarray
    ids: np.ndarray
    r: np.ndarray
    mag: np.ndarray

    def take(self, keep: np.ndarray) -> Matches:
        return Matches(self.idx[keep], self.ids[keep], self.r[keep], self.mag[keep])

    def same_as(self, other: Matches) -> bool:
        a, b = np.argsort(self.idx), np.argsort(other.idx)
        return (len(self.idx) == len(other.idx) and np.array_equal(self.idx[a], other.idx[b])
                and np.array_equal(self.ids[a], other.ids[b]))


class Rematched(NamedTuple):
    """What :func:`match_catalogue` found: the matches, how many catalogue stars were predicted
    in the frame, the RMS search radius (px), and whether every one of those stars was looked
    for (none beyond ``max_radius_px``: then the match is the one without that limit)."""

    matches: Matches
    n_catalog: int
    rms_radius_px: float
    complete: bool


def star_tree(database) -> cKDTree:
    """The database's stars as a k-d tree of their unit vectors (built once, kept on it)."""
    from scipy.spatial import cKDTree

    tree = database.__dict__.get("_star_tree")
    if tree is None:
        tree = cKDTree(np.asarray(database.star_vectors, dtype=np.float64))
        database.__dict__["_star_tree"] = tree
    return tree


# The cone of catalogue stars a final fit keeps is this much (rad) wider than the frame's: the
# fits move the boresight by well under it.
CONE_MARGIN = math.radians(3.0)


# A cone holding more than this share of the sky is found by :func:`within` over every catalogue
# star (in catalogue order, no sort), a smaller one from the sky cells that reach it
# (:func:`cone_stars`, then sorted). Against a star tree query then a sort (what both replace): a
# 40° cone of the wide band's 118 000 stars 2.6 → 0.7 ms by the scan, a 4° one of the narrow
# band's 482 000 0.6 ms by the scan, 0.24 by the tree — whose build, once per process and band,
# took 250 ms for the narrow band's stars, landing in the first sparse frame's solve.
_SCAN_SHARE = 0.02


class CatalogueCone:
    """The catalogue stars about the boresight, for every re-match of one final fit: the stars
    within a cone :data:`CONE_MARGIN` wider than the frame's are found once (from the sky cells
    that reach it, :func:`cone_stars`, or for a cone wider than :data:`_SCAN_SHARE` of the sky by
    :func:`within` over the whole catalogue: both the star tree's test, squared chord within the
    squared radius, so the same stars as :func:`star_tree` finds)
    and each re-match takes its cone from those stars by the same test, and each star's vector
    at the epoch is computed once. (A tree query of a 60–90° cone returns 10–20 thousand stars
    and took 8 ms a re-match; the rest of one takes 1–2.)

    ``seen``, when given, turns those vectors into the directions the camera sees the stars in:
    a callable ``seen(vectors (K, 3), catalogue ids (K,)) -> (K, 3)``
    (:meth:`skyfix.corrections.observation.Observation.seen`: aberration, refraction, …); the
    re-matches then predict and fit those."""

    def __init__(self, database, epoch: float | None, seen=None) -> None:
        self.database, self.epoch, self.seen = database, epoch, seen
        self._axis: np.ndarray | None = None

    def cone(self, axis: np.ndarray, half_angle: float, limit: int | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
        """The stars within ``half_angle`` (rad) of ``axis``: their database indices, brightest
        first (database order), and their rows in the cache (for :meth:`vectors`); only the
        first ``limit`` of them when given (the scan stops there)."""
        if self._axis is None or _angle(axis, self._axis) + half_angle > self._half_angle:
            self._half_angle = min(half_angle + CONE_MARGIN, math.pi)
            self._axis = np.array(axis, dtype=np.float64)
            all_points = self.database.star_arrays()[2]
            chord2 = chord(self._half_angle) ** 2
            if (1.0 - math.cos(self._half_angle)) / 2.0 > _SCAN_SHARE:
                self._index = within(all_points, self._axis, chord2, len(all_points))
            else:
                self._index = cone_stars(*self.database.star_index(), self._axis, self._half_angle, chord2)
            self._points = all_points[self._index]
            self._vectors = np.full((len(self._index), 3), np.nan)
        rows = within(self._points, np.ascontiguousarray(axis, dtype=np.float64), chord(half_angle) ** 2,
                      len(self._points) if limit is None else limit)
        return self._index[rows], rows

    def vectors(self, rows: np.ndarray) -> np.ndarray:
        """The vectors (K, 3) at the epoch of the cached stars ``rows``
        (:meth:`~skyfix.identify.PatternDatabase.vectors_at`, once a star), as ``seen`` when given."""
        todo = rows[np.isnan(self._vectors[rows, 0])]
        if len(todo):
            index = self._index[todo]
            v = self.database.vectors_at(index, self.epoch)
            if self.seen is not None:
                v = self.seen(v, self.database.star_arrays()[0][index])
            self._vectors[todo] = v
        return self._vectors[rows]


@njit(inline="always")
def _chord2(points, i, axis) -> float:
    """The squared distance from ``points[i]`` to ``axis``."""
    dx = points[i, 0] - axis[0]
    dy = points[i, 1] - axis[1]
    dz = points[i, 2] - axis[2]
    return dx * dx + dy * dy + dz * dz


@njit(cache=True)
def within(points, axis, chord2, limit):
    """The first ``limit`` rows of ``points`` (N, 3) whose squared distance to ``axis`` is at most
    ``chord2`` (the scan stops there)."""
    rows = np.empty(min(points.shape[0], limit), dtype=np.int64)
    n = 0
    for i in range(points.shape[0]):
        if n == limit:
            break
        if _chord2(points, i, axis) <= chord2:
            rows[n] = i
            n += 1
    return rows[:n]


@njit(cache=True)
def cone_stars(vectors, cell_centres, cell_start, cell_stars, cell_radius, axis, half_angle, chord2):
    """Indices (ascending: brightest first) of the stars ``vectors`` (S, 3) whose squared distance
    to ``axis`` is at most ``chord2`` (the squared chord of ``half_angle``, rad), read from the sky
    cells whose cap of ``cell_radius`` about their centre reaches the cone: those of
    :func:`skyfix.identify.common.verify.cell_band`'s z band within ``half_angle + cell_radius`` of the
    axis. The first five arguments are a :class:`~skyfix.identify.catalogue.kernel_data.StarIndex`'s."""
    reach = min(half_angle + cell_radius, np.pi)
    cos_reach = np.cos(reach) - 1e-9
    lo, hi = cell_band(cell_centres, axis, reach)
    cells = np.empty(hi - lo, dtype=np.int64)
    n_cells = total = 0
    for c in range(lo, hi):
        cx, cy, cz = cell_centres[c, 0], cell_centres[c, 1], cell_centres[c, 2]
        if cx * axis[0] + cy * axis[1] + cz * axis[2] >= cos_reach:
            cells[n_cells] = c
            n_cells += 1
            total += cell_start[c + 1] - cell_start[c]
    out = np.empty(total, dtype=np.int64)
    n = 0
    for c in cells[:n_cells]:
        for k in range(cell_start[c], cell_start[c + 1]):
            s = cell_stars[k]
            if _chord2(vectors, s, axis) <= chord2:
                out[n] = s
                n += 1
    return np.sort(out[:n])


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    """The angle (rad) between unit vectors ``a`` and ``b``."""
    return float(rotation.chord_angle(np.linalg.norm(a - b)))


def chord(angle: float) -> float:
    """The chord of an arc of ``angle`` rad on the unit sphere (what the star tree measures; the
    inverse of :func:`skyfix._kernels.rotation.chord_angle`)."""
    return 2.0 * math.sin(angle / 2.0)


def match_catalogue(xy: np.ndarray, fit, stars: CatalogueCone, max_radius_px: float = math.inf
                    ) -> Rematched:
    """Match the catalogue stars in view (the brightest, twice as many as centroids) to the
    centroids ``xy`` through the fitted camera and attitude of ``fit`` (a
    :class:`~skyfix.calibrate.PriorFit`). Each star is searched within 3.5 σ of its predicted
    position, σ combining the centroid noise with the model's own uncertainty there (large
    where the stars fitted so far leave the camera unknown: far from them, or with the pixel
    aspect unconstrained), at least 1 px. Unambiguous pairs only (a centroid with two catalogue
    stars within the radius, a blend, or a star claimed by two centroids says nothing reliable).
    A star whose radius would exceed ``max_radius_px`` is not looked for (nor counted).
    Returns the matches, how many catalogue stars were predicted in the frame, the RMS search
    radius (px) for the chance test, and whether no star was left out for its radius
    (:class:`Rematched`)."""
    camera, A = fit.camera, fit.A_icrs_to_cam
    half_diag = math.radians(camera.fov_diagonal_deg) / 2.0 * 1.05
    if math.isnan(half_diag):  # a fisheye's θ polynomial that folds back before the corners
        half_diag = math.pi / 2.0
    # The brightest first (database order); the cone is at most ~2.5× the frame's area, so
    # 6× as many as will be kept is enough to fill the frame's quota.
    near, rows = stars.cone(A[2], half_diag, 12 * len(xy))
    empty = Rematched(Matches(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0)),
                      0, 1.0, True)
    if len(near) == 0:
        return empty
    v = stars.vectors(rows)
    uv, front = camera.ray_to_pixel(v @ A.T)
    seen = np.flatnonzero(front & camera.in_frame(uv))[:2 * len(xy)]  # brightest first (database order)
    near, v, uv = near[seen], v[seen], uv[seen]
    if len(near) == 0:
        return empty
    radius = np.maximum(3.5 * np.hypot(fit.sigma_px, fit.prediction_sigma_px(v)), 1.0)
    complete = True
    if max_radius_px < math.inf:
        look = radius <= max_radius_px
        complete = bool(look.all())
        near, v, uv, radius = near[look], v[look], uv[look], radius[look]
        if len(near) == 0:
            return empty._replace(complete=False)
    from scipy.spatial import cKDTree

    dist, j = cKDTree(xy).query(uv, distance_upper_bound=float(radius.max()))
    hit = dist <= radius
    star, cen = np.flatnonzero(hit), j[hit]
    # Ambiguity: another predicted star within the larger of the two radii of this centroid.
    n_stars_near = cKDTree(uv).query_ball_point(xy[cen], radius[star], return_length=True)
    n_claims = np.bincount(cen, minlength=len(xy))[cen]
    ok = (n_stars_near == 1) & (n_claims == 1)
    star, cen = star[ok], cen[ok]
    star_ids, star_mag, _ = stars.database.star_arrays()
    ids = star_ids[near[star]].astype(np.int64)
    mag = star_mag[near[star]].astype(np.float64)
    rms_radius = float(np.sqrt(np.mean(radius**2)))
    return Rematched(Matches(cen.astype(np.int64), ids, v[star], mag), len(near), rms_radius, complete)


@njit(cache=True)
def equidistant_consensus(xy, r, cam, n_stars, tol_px):
    """The equidistant camera (the Kannala–Brandt camera numbers ``cam``, every k 0, at another
    focal length) and attitude that most of the matched stars ``xy`` (N, 2) ↔ ``r`` (N, 3) agree with (a miss
    within ``tol_px``), from each pair of the first ``n_stars``: the focal length at which the
    pair's rays are as far apart as its catalogue stars (bisection over 0.5–2× ``cam``'s; the
    rays' angle shrinks as it grows), the attitude by TRIAD. Returns (focal length, attitude,
    which stars agree (N,) bool); ties go to the smaller summed squared miss. (RANSAC over every
    pair instead of random ones: a few hundred hypotheses, each checked on every star.)"""
    n = xy.shape[0]
    k = min(n, n_stars)
    c = cam.copy()
    pair = np.empty((2, 2))
    best_f, best_A = cam[lens.FX], np.eye(3)
    best_count, best_cost = -1, math.inf
    tol2 = tol_px * tol_px
    for i in range(k):
        for j in range(i + 1, k):
            cos_stars = r[i, 0] * r[j, 0] + r[i, 1] * r[j, 1] + r[i, 2] * r[j, 2]
            pair[0], pair[1] = xy[i], xy[j]
            lo, hi = 0.5 * cam[lens.FX], 2.0 * cam[lens.FX]
            for _ in range(30):
                c[lens.FX] = c[lens.FY] = 0.5 * (lo + hi)
                b = lens.pixel_rays(pair, c)
                if b[0, 0] * b[1, 0] + b[0, 1] * b[1, 1] + b[0, 2] * b[1, 2] < cos_stars:
                    lo = c[lens.FX]  # the rays are farther apart than the stars: a longer focal length
                else:
                    hi = c[lens.FX]
            c[lens.FX] = c[lens.FY] = 0.5 * (lo + hi)
            b = lens.pixel_rays(pair, c)
            A, ok = rotation.triad(b[0], b[1], r[i], r[j], 1e-6)
            if not ok:
                continue
            uv, front = lens.project_rays(rotated(r, A), c)
            count, cost = 0, 0.0
            for m in range(n):
                d2 = (uv[m, 0] - xy[m, 0]) ** 2 + (uv[m, 1] - xy[m, 1]) ** 2
                if front[m] and d2 <= tol2:
                    count += 1
                    cost += d2
            if count > best_count or (count == best_count and cost < best_cost):
                best_f, best_A, best_count, best_cost = c[lens.FX], A, count, cost
    c[lens.FX] = c[lens.FY] = best_f
    uv, front = lens.project_rays(rotated(r, best_A), c)
    agree = np.empty(n, dtype=np.bool_)
    for m in range(n):
        agree[m] = front[m] and (uv[m, 0] - xy[m, 0]) ** 2 + (uv[m, 1] - xy[m, 1]) ** 2 <= tol2
    return best_f, best_A, agree


@njit(cache=True)
def rotated(r, A):
    """The vectors ``r`` (N, 3) rotated by ``A``: ``(A r_i)`` (N, 3)."""
    out = np.empty_like(r)
    for i in range(r.shape[0]):
        for k in range(3):
            out[i, k] = A[k, 0] * r[i, 0] + A[k, 1] * r[i, 1] + A[k, 2] * r[i, 2]
    return out
