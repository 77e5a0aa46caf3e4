"""The ``triangle`` method: three stars are enough when their triangle is unique.

Thesis 000's camera was designed around three stars per 30° frame (§1, §2.6.7); the 4-star
hash cannot see such a frame. This method matches triangles of the brightest centroids to
catalogue triangles through the pair table (:mod:`skyfix.identify.pairs`: the longest side by a
range search over pair angles, the third vertex among the first vertex's neighbours, the last
side checked), and judges what it finds in one of two ways:

*Rich frames* (the usual case with five or more stars): a catalogue triangle that fits counts
only when a fourth image star confirms it (a catalogue neighbour at the right three angles,
checked in the compiled search), and the four stars are a proposal judged by the common rules
(:func:`skyfix.identify.hypothesis.first_accepted`), exactly as any other method's.

*Sparse frames* (three or four stars, or up to :data:`LONE_MAX_STARS` that the first way did not
settle): a lone triangle has nothing else to verify it against, so its own chance is computed,
honestly:

1. **How unusual a match this close is.** The catalogue triangles near the measured one — all
   three sides within ``W`` (:func:`window_rad`) — are counted, among stars no fainter than
   ``mag_margin`` beyond the faintest of the match (the image's three brightest stars are among
   the sky's brightest there), and of those only the ones rule 4 would not refute where they
   stand (:func:`_unrefuted`: a triangle with a brighter star beside it is no rival; the share
   is measured on a sample of 4096 when there are more). Their density times the volume of the
   box the match actually falls in (its largest side error ``ε``, floored at
   ``min_error_px``) is the expected number
   of catalogue triangles that close to a *random* triangle: ``λ = M_W · (ε / W)^d``, ``d`` = 3
   with a calibrated camera, 2 with a FOV only (the scale is then free: only the shape counts).
   The match's own triangle is among the ``M_W``, which keeps ``λ`` from reaching 0. A false
   star turns the image triangle into a random one, so ``λ`` is the chance it matches as well.
2. **Every look counted.** ``λ`` is multiplied by the image triangles tried (each one a fresh
   chance to meet a catalogue triangle by accident; every combination of false stars is one of
   them).
3. **Every other star counted.** Stars beyond the triangle verify it as in the 4-star method: the
   catalogue stars in view (as bright as ``mag_margin`` beyond the triangle's faintest) that land
   on centroids by chance is a binomial tail (:func:`skyfix.identify.accept.chance_log_probability`),
   multiplied in.
4. **Nothing bright missing.** A catalogue star in the frame brighter than the triangle's
   faintest by ``missing_margin`` magnitudes that lands on no centroid would have been detected:
   the hypothesis is rejected.
5. **Unique.** When two hypotheses that put the camera in different places (different stars, or
   the same stars assigned another way: an equilateral triangle's three rolls) both pass 1–4
   within a factor of :data:`AMBIGUITY_RATIO` of the best chance, the frame fails "ambiguous" —
   it does not guess.

The sparse frame is accepted when the product is at most ``lone_prob_threshold`` (1e-4 by
default: a lone triangle cannot reach the 1e-9 of a rich frame; a solution reports the chance it
was given, ``prob_false``). A mirror image is rejected as everywhere, since no proper rotation
fits it — and where a near-symmetric group of stars fits one all the same, by
:func:`unless_mirrored`: the frame flipped left-right matching more surely refuses the match.
"""

from __future__ import annotations

import math
import time
from itertools import combinations
from typing import NamedTuple

import numba
import numpy as np

from skyfix._kernels.robust import rayleigh_inliers
from skyfix._kernels.rotation import chord_angle
from skyfix.camera import Camera
from skyfix.errors import InputError
from skyfix.identify.accept import chance_log_probability as binomial_log_probability
from skyfix.identify.database import PatternDatabase
from skyfix.identify.hypothesis import (
    Frame,
    Hypothesis,
    failure,
    first_accepted,
    fits,
    frame_for,
    hypothesis,
    rays_at,
)
from skyfix.identify.pairs import PairTable, neighbours_in_range, pair_table, pairs_in_range
from skyfix.identify.result import Identification
from skyfix.identify.verify import stars_in_view

__all__ = ["AMBIGUITY_RATIO", "LONE_MAX_STARS", "METHOD", "LoneJudgement", "identify", "judge_lone",
           "triangle_matches", "unless_mirrored", "window_rad"]

METHOD = "triangle"
LONE_MAX_STARS = 8
"""Frames of more centroids than this are judged by the common rules only: the lone-triangle
test is for sparse frames (its cost grows with the stars; a rich frame that the common rules
cannot settle has a reason to fail)."""
AMBIGUITY_RATIO = 100.0  # a second triangle this close to the best one's chance makes the frame ambiguous
_MAX_MATCHES = 4096  # catalogue triangles kept per image triangle (more are counted, not kept)
_NO_CONFIRM = np.empty((0, 3))
_FIRST_STARS = 5  # the image triangles among this many brightest stars are searched cheapest first
_WINDOW_MAX = 4096  # catalogue triangles near a sparse frame's match tested by rule 4 (a sample beyond)


@numba.njit(cache=True, inline="always")
def _angle(u, v):
    """The angle between unit vectors ``u`` and ``v`` from their chord (accurate when small)."""
    chord = math.sqrt((u[0] - v[0]) ** 2 + (u[1] - v[1]) ** 2 + (u[2] - v[2]) ** 2)
    return 2.0 * math.asin(min(chord / 2.0, 1.0))


@numba.njit(cache=True)
def _confirming_star(table, vectors, a, b, c, s, confirm, tol, theta01, spread, need):
    """The first extra image star (row of ``confirm``: its angles to vertices 0, 1, 2 at the
    nominal focal length) that a catalogue neighbour ``e`` of ``a`` matches at scale ``s``
    (angles to ``a``, ``b``, ``c`` within ``tol``, the scale's own error — ``tol / theta01``
    relative — and the projection's ``spread`` included), as ``(row, e)``, when at least
    ``need`` extra stars are matched so; ``(-1, -1)`` otherwise."""
    first_d, first_e, found = -1, -1, 0
    for d in range(confirm.shape[0]):
        if found + confirm.shape[0] - d < need:
            break  # too few rows left to reach ``need``
        t0 = tol * (1.0 + confirm[d, 0] / theta01) + spread * confirm[d, 0]
        q0, q1 = neighbours_in_range(table, a, confirm[d, 0] * s - t0, confirm[d, 0] * s + t0)
        t1 = tol * (1.0 + confirm[d, 1] / theta01) + spread * confirm[d, 1]
        t2 = tol * (1.0 + confirm[d, 2] / theta01) + spread * confirm[d, 2]
        for q in range(q0, q1):
            e = table.neighbour[q]
            if e == b or e == c:
                continue
            if (abs(_angle(vectors[e], vectors[b]) - confirm[d, 1] * s) <= t1
                    and abs(_angle(vectors[e], vectors[c]) - confirm[d, 2] * s) <= t2):
                if found == 0:
                    first_d, first_e = d, e
                found += 1
                break
        if found >= need:
            return first_d, first_e
    return -1, -1


@numba.njit(cache=True)
def triangle_matches(table, vectors, sides, tol, calibrated, rank_limit, confirm, out, err):
    """Catalogue triangles ``(a, b, c)`` whose sides match the image triangle's ``sides`` =
    (θ01, θ02, θ12) (radians), stars below ``rank_limit`` only.

    ``tol`` = (t01_lo, t01_hi, t02, t12, t, spread, need): with ``calibrated`` the catalogue sides
    must be within ``θ ± t02``; else side 01 within ``[t01_lo, t01_hi]`` (the focal range's) and
    the other two within ``± t02, t12`` of ``θ · s``, ``s`` the scale side 01 implies; ``t`` is
    one angle's tolerance, ``spread`` the projection's bending of ratios, ``need`` the confirming
    stars asked for (confirmation). With rows in ``confirm``
    (M, 3) — other image stars' angles to the three vertices — a triangle counts only when a
    fourth star confirms it (:func:`_confirming_star`, the seeds' fourth-star check, compiled).
    Writes up to ``len(out)`` rows of ``out`` (K, 5) = (a, b, c, confirm row or -1, its catalogue
    star or -1), their larger error of sides 02 and 12 in ``err`` (K,), and returns how many
    triangles match (which may be more)."""
    lo01, hi01 = (sides[0] - tol[2] if calibrated else tol[0]), (sides[0] + tol[2] if calibrated else tol[1])
    start, stop = pairs_in_range(table.angle_rad, lo01, hi01)
    n = 0
    for p in range(start, stop):
        for orient in range(2):
            a = table.first[p] if orient == 0 else table.second[p]
            b = table.second[p] if orient == 0 else table.first[p]
            if a >= rank_limit or b >= rank_limit:
                continue
            s = 1.0 if calibrated else table.angle_rad[p] / sides[0]
            q0, q1 = neighbours_in_range(table, a, sides[1] * s - tol[2], sides[1] * s + tol[2])
            vb = vectors[b]
            for q in range(q0, q1):
                c = table.neighbour[q]
                if c >= rank_limit or c == b:
                    continue
                e12 = abs(_angle(vb, vectors[c]) - sides[2] * s)
                if e12 > tol[3]:
                    continue
                d, e = -1, -1
                if confirm.shape[0]:
                    d, e = _confirming_star(table, vectors, a, b, c, s, confirm, tol[4],
                                            math.inf if calibrated else sides[0], tol[5], tol[6])
                    if d < 0:
                        continue
                if n < out.shape[0]:
                    out[n, 0] = a
                    out[n, 1] = b
                    out[n, 2] = c
                    out[n, 3] = d
                    out[n, 4] = e
                    err[n] = max(e12, abs(table.neighbour_angle[q] - sides[1] * s))
                n += 1
    return n


def window_rad(fov_rad: float, tolerance_rad: float) -> float:
    """The half-width of the box in which catalogue triangles are counted around a match (rule
    1): wide enough to hold several at any star density (2 % of the field), and at least ten
    match tolerances."""
    return max(0.02 * fov_rad, 10.0 * tolerance_rad)


class LoneJudgement(NamedTuple):
    """How a sparse frame's hypothesis fared (module text, rules 1–4).

    log_chance : float — log of λ × image triangles tried × the other stars' binomial tail.
    n_window : int — catalogue triangles within the window (M_W, the match's own included).
    error_rad : float — the match's largest side error ε (before the floor).
    stars, catalog : (K,) int64 — all matched centroid rows and catalogue rows (the triangle first).
    n_missing : int — bright catalogue stars in the frame on no centroid (rule 4).
    """

    log_chance: float
    n_window: int
    error_rad: float
    stars: np.ndarray
    catalog: np.ndarray
    n_missing: int


def _pair_angles3(v: np.ndarray) -> np.ndarray:
    """(θ01, θ02, θ12) of three unit vectors."""
    return chord_angle(np.linalg.norm(v[[0, 0, 1]] - v[[1, 2, 2]], axis=1))


def _rank_limit(star_mag: np.ndarray, mag: float) -> int:
    """One past the faintest-ranked star no fainter than ``mag`` (stars are brightest first; a
    catalogue whose order is not strictly by this magnitude gets the conservative bound)."""
    below = np.flatnonzero(star_mag <= mag)
    return int(below[-1]) + 1 if len(below) else 0


def _in_view(frame: Frame, h: Hypothesis, limit: int) -> tuple[np.ndarray, np.ndarray]:
    """Catalogue rows (< ``limit``) in the frame at ``h`` and their offsets (pixels, at h's focal)."""
    n = stars_in_view(np.ascontiguousarray(h.A_icrs_to_cam), float(h.focal_px), 0.0, frame.image.frame_px,
                      np.int64(limit), frame.stars, frame.view)
    return frame.view.index[:n].copy(), np.column_stack([frame.view.x_px[:n], frame.view.y_px[:n]])


def judge_lone(frame: Frame, h: Hypothesis, table: PairTable, star_mag: np.ndarray, *, sides_img: np.ndarray,
               tolerance_rad: float, n_triangles: int, mag_margin: float, missing_margin: float,
               min_error_px: float) -> LoneJudgement:
    """Rules 1–4 of the module text for a triangle hypothesis ``h`` (its three centroid rows
    and catalogue rows in vertex order; ``sides_img`` the image triangle's sides at the
    nominal focal length, θ01 the longest)."""
    vectors = frame.stars.vectors
    f = float(h.focal_px)
    m_faint = float(star_mag[h.catalog[:3]].max())
    # The other stars: matched ones verify (rule 3), bright unmatched ones refute (rule 4).
    idx, xy = _in_view(frame, h, _rank_limit(star_mag, m_faint + mag_margin))
    own = np.isin(idx, h.catalog)
    idx, xy = idx[~own], xy[~own]
    offsets = frame.image.offsets_px
    others = np.setdiff1d(np.arange(len(offsets)), h.stars)
    stars, catalog = list(h.stars[:3]), list(h.catalog[:3])
    n_missing = 0
    lo_x, hi_x, lo_y, hi_y = frame.image.frame_px
    r = frame.radius_px
    free = np.ones(len(offsets), bool)
    free[h.stars] = False
    for s, p in zip(idx, xy, strict=True):  # the few catalogue stars in view, brightest first
        d2 = ((offsets - p) ** 2).sum(axis=1)
        d2[~free] = np.inf
        i = int(np.argmin(d2)) if len(d2) else -1
        if i >= 0 and d2[i] <= r * r:
            free[i] = False
            stars.append(i)
            catalog.append(int(s))
        elif (star_mag[s] <= m_faint - missing_margin and lo_x + r <= p[0] <= hi_x - r
              and lo_y + r <= p[1] <= hi_y - r):
            n_missing += 1
    if n_missing:  # refuted: its chance is not worth counting
        return LoneJudgement(0.0, 0, math.inf, np.array(stars, np.int64), np.array(catalog, np.int64),
                             n_missing)
    cat_sides = _pair_angles3(vectors[h.catalog[:3]])
    img_sides = _pair_angles3(rays_at(frame, h.stars[:3], f))
    error = float(np.abs(cat_sides - img_sides).max())
    fov = 2.0 * math.atan(frame.camera.width / 2.0 / f)
    window = window_rad(fov, tolerance_rad)
    rank = _rank_limit(star_mag, m_faint + mag_margin)
    calibrated = frame.calibrated
    s_tol = frame.scale_tolerance
    # The box in the sides' space: side 01 over the focal range, the others as the search's.
    other = window if calibrated else window * (1.0 + sides_img[1:].max() / sides_img[0])
    tol = np.array([sides_img[0] * (1 - s_tol) - window, sides_img[0] * (1 + s_tol) + window, other, other,
                    window, 0.0, 1.0])
    found = np.empty((_WINDOW_MAX, 5), np.int32)
    n_window = triangle_matches(table, vectors, sides_img, tol, calibrated, rank, _NO_CONFIRM, found,
                                np.empty(_WINDOW_MAX))
    # The share of them rule 4 leaves standing, from the first _WINDOW_MAX found (in the order
    # of one side's length, which has nothing to do with where they are on the sky), one added
    # to what survived so that a small sample never rules rivals out.
    tested = min(n_window, _WINDOW_MAX)
    n_rivals = 0
    if n_window:
        alive = _unrefuted(frame, h, table, found[:tested, :3], star_mag, missing_margin)
        n_rivals = alive if tested == n_window else math.ceil(n_window * (alive + 1) / (tested + 1))
    eps = max(error, min_error_px / f)
    d = 3 if calibrated else 2
    log_lambda = math.log(max(n_rivals, 1)) + d * math.log(min(eps / window, 1.0))
    log_chance = min(log_lambda + math.log(max(n_triangles, 1)), 0.0)
    n_extra = len(stars) - 3
    if len(idx):
        area = (hi_x - lo_x) * (hi_y - lo_y)
        log_chance += binomial_log_probability(n_extra, len(idx), max(len(others), 1), r, area)
    return LoneJudgement(log_chance, int(n_window), error, np.array(stars, np.int64),
                         np.array(catalog, np.int64), n_missing)


@numba.njit(cache=True)
def _count_unrefuted(table, vectors, star_mag, tris, A, faint, f, frame_px, radius_px, offsets):
    """How many of the triangles ``tris`` (K, 3) at attitudes ``A`` (K, 3, 3) have no pair-table
    neighbour of their first vertex brighter than ``faint`` (K,) in the frame (``radius_px``
    inside its edges, offsets at focal ``f``) and on no centroid ``offsets``."""
    lo_x, hi_x, lo_y, hi_y = frame_px[0] + radius_px, frame_px[1] - radius_px, frame_px[2] + radius_px, \
        frame_px[3] - radius_px
    r2 = radius_px * radius_px
    alive = 0
    for k in range(tris.shape[0]):
        a = tris[k, 0]
        refuted = False
        for q in range(table.neighbour_start[a], table.neighbour_start[a + 1]):
            e = table.neighbour[q]
            if star_mag[e] > faint[k] or e == tris[k, 1] or e == tris[k, 2]:
                continue
            v = vectors[e]
            z = A[k, 2, 0] * v[0] + A[k, 2, 1] * v[1] + A[k, 2, 2] * v[2]
            if z <= 1e-6:
                continue
            x = f * (A[k, 0, 0] * v[0] + A[k, 0, 1] * v[1] + A[k, 0, 2] * v[2]) / z
            y = f * (A[k, 1, 0] * v[0] + A[k, 1, 1] * v[1] + A[k, 1, 2] * v[2]) / z
            if x < lo_x or x > hi_x or y < lo_y or y > hi_y:
                continue
            seen = False
            for i in range(offsets.shape[0]):
                if (offsets[i, 0] - x) ** 2 + (offsets[i, 1] - y) ** 2 <= r2:
                    seen = True
                    break
            if not seen:
                refuted = True
                break
        if not refuted:
            alive += 1
    return alive


def _unrefuted(frame: Frame, h: Hypothesis, table: PairTable, tris: np.ndarray, star_mag: np.ndarray,
               missing_margin: float) -> int:
    """How many catalogue triangles ``tris`` (K, 3) — each put on the hypothesis's three
    centroids — survive rule 4 (no catalogue star brighter than the triangle's faintest by
    ``missing_margin`` in the frame and on no centroid), the hypothesis's own among them.

    Only such triangles compete with the match: a triangle refuted by a bright star beside it
    could not have been accepted. Each attitude is the TRIAD of the first two vertices
    (vectorised over the K triangles); the stars tested are the pair table's neighbours of the
    first vertex (every star of the table in a frame around it; a bright star missing from the
    table leaves a triangle standing, the safe way)."""
    vectors = frame.stars.vectors
    b = rays_at(frame, h.stars[:3], float(h.focal_px))

    def triad(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        w = np.cross(u, v)
        w /= np.linalg.norm(w, axis=-1, keepdims=True)
        return np.stack([u, w, np.cross(u, w)], axis=-1)

    Mb = triad(b[0], b[1])
    Mr = triad(vectors[tris[:, 0]], vectors[tris[:, 1]])
    A = np.ascontiguousarray(np.einsum("ij,kmj->kim", Mb, Mr))  # (K, 3, 3): b = A r
    faint = star_mag[tris].max(axis=1).astype(np.float64) - missing_margin
    f = float(h.focal_px)
    return int(_count_unrefuted(table, vectors, star_mag, np.ascontiguousarray(tris), A, faint, f,
                                frame.image.frame_px, frame.radius_px, frame.image.offsets_px))


def _sides_order(frame: Frame, table: PairTable, tri: tuple[int, int, int],
                 tol: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The triangle's vertices ordered for the search, and its sides (θ01, θ02, θ12).

    Side 01 is searched in the pair table; its pairs are the work. With a calibrated camera its
    range is ± the tolerance whichever side it is, so the longest side (fewest pairs per radian
    is not the point: its relative error is the smallest). With a FOV only, its range is the
    focal range's (±10 %) and the other sides' tolerance grows as ``θ_other / θ01``: the side
    whose pairs in range times that growth is least is searched. Returns the vertices, the
    sides and that cost (the search's work, to order image triangles by)."""
    i, j, k = tri
    best, best_cost = None, math.inf
    s_tol = frame.scale_tolerance
    for a, b, c in ((i, j, k), (j, i, k), (i, k, j), (k, i, j), (j, k, i), (k, j, i)):
        s = _pair_angles3(frame.rays[[a, b, c]])
        if s[1] < s[2]:
            continue  # of the two orientations of a side, the one whose first vertex sees the longer side
        if frame.calibrated:
            cost = -s[0]
        else:
            lo, hi = pairs_in_range(table.angle_rad, s[0] * (1 - s_tol) - tol, s[0] * (1 + s_tol) + tol)
            cost = (hi - lo) * (1.0 + s[1] / max(s[0], 1e-12))
        if cost < best_cost:
            best, best_cost = (np.array([a, b, c], np.int64), s), cost
    return best[0], best[1], best_cost


def _angles_to(rays: np.ndarray, extra: np.ndarray, verts: np.ndarray) -> np.ndarray:
    """(M, 3) angles from centroid rows ``extra`` to the three ``verts``."""
    if not len(extra):
        return _NO_CONFIRM
    return chord_angle(np.linalg.norm(rays[extra][:, None, :] - rays[verts][None, :, :], axis=2))


def _ratio_spread(frame: Frame, verts: np.ndarray) -> float:
    """How much the ratios θ02/θ01, θ12/θ01 of an image triangle move across the focal range."""
    if frame.calibrated:
        return 0.0
    lo, hi = frame.focal_range_px
    r = [(lambda s: s[1:] / s[0])(_pair_angles3(rays_at(frame, verts, f))) for f in (lo, hi)]
    return float(np.abs(r[0] - r[1]).max())


def _image_triangles(n: int):
    """Image triangles of the ``n`` brightest centroids, those of the brightest stars first."""
    return sorted(combinations(range(n), 3), key=lambda t: (t[2], t[1], t[0]))


def _triangle_holds(frame: Frame, judgement: LoneJudgement) -> bool:
    """Whether each of the hypothesis's own three stars fits the attitude the other matched
    stars give without it (rule 8's Rayleigh cut over their residuals and its own,
    :func:`skyfix._kernels.robust.rayleigh_inliers`, floored at 0.1 px).

    A triangle of two true stars and a false one lands near the truth: the stars around it verify
    it, but the false star pulls its attitude off (a 15° frame with 10 false stars came back 240″
    and 1.7° off with P 2.5e-9 before this check; fitted with it, the false star's residual was
    only 3× the others', as it had pulled them too). Needs five or more matched stars."""
    n = len(judgement.stars)
    if n < 5:
        return True
    for i in range(3):
        rest = np.arange(n) != i
        fit = hypothesis(frame, judgement.stars[rest], judgement.catalog[rest])
        if not fit.focal_px == fit.focal_px:
            return False
        order = np.concatenate([np.flatnonzero(rest), [i]])
        stars, catalog = judgement.stars[order], judgement.catalog[order]
        b = rays_at(frame, stars, float(fit.focal_px))
        r = frame.stars.vectors[catalog] @ fit.A_icrs_to_cam.T
        resid = chord_angle(np.linalg.norm(b - r, axis=1))
        if not rayleigh_inliers(np.ascontiguousarray(resid), 0.1 / float(fit.focal_px))[-1]:
            return False
    return True


def _lone_identification(frame: Frame, h: Hypothesis, judgement: LoneJudgement, n_tried: int,
                         n_candidates: int) -> Identification:
    """The Identification of an accepted sparse frame: the attitude refitted (SVD) on every
    matched star, with the chance it was given."""
    full = hypothesis(frame, judgement.stars, judgement.catalog)
    if not fits(frame, full):
        full = h
    db = frame.database
    camera = frame.camera
    if not frame.calibrated:
        f = float(full.focal_px)
        camera = Camera(width=camera.width, height=camera.height, fx=f, fy=f, cx=camera.cx, cy=camera.cy)
    order = np.argsort(full.stars)
    star_index, cat_index = full.stars[order], full.catalog[order]
    if frame.kept is not None:
        star_index = frame.kept[star_index]
    star_ids, star_mag, _ = db.star_arrays()
    return Identification(True, "", star_index, star_ids[cat_index], db.vectors_at(cat_index, frame.epoch),
                          star_mag[cat_index], full.A_icrs_to_cam, camera, math.exp(judgement.log_chance),
                          n_tried, n_candidates, METHOD, time.perf_counter() - frame.t0, frame.radius_px,
                          database=db)


def identify(xy: np.ndarray, width: int, height: int, *, fov_deg: float | None = None,
             fov_tolerance_deg: float | None = None, camera: Camera | None = None,
             database: PatternDatabase | None = None, epoch: float | None = None, max_stars: int = 8,
             centroid_sigma_px: float = 0.5, n_sigma: float = 3.0, mag_margin: float = 1.0,
             missing_margin: float = 0.75, min_error_px: float = 0.05, lone_prob_threshold: float = 1e-4,
             prob_threshold: float = 1e-9, max_candidates: int = 2000, max_per_triangle: int = 64,
             per_field: int = 12) -> Identification:
    """Identify a frame's stars from triangles of its brightest centroids (the module text).

    Parameters (beyond the interface of :mod:`skyfix.identify.methods`)
    -------------------------------------------------------------------
    max_stars : int — the brightest centroids whose triangles are tried (3–12).
    centroid_sigma_px : float — the centroids' noise per axis; an angle's tolerance is
        ``n_sigma · √2 · centroid_sigma_px / f`` (plus the focal range's with a FOV only).
    mag_margin : float — catalogue stars this much fainter than a match's faintest still count
        as its competitors and verifiers (the image's brightness order is not the catalogue's).
    missing_margin : float — a catalogue star this much brighter than the match's faintest, in
        the frame and on no centroid, refutes the match.
    min_error_px : float — the floor of a match's side error in rule 1 (no centroid is exact).
    lone_prob_threshold : float — the largest chance accepted for a sparse frame.
    prob_threshold : float — the largest chance accepted for a rich frame (as the 4-star method's).
    max_candidates : int — catalogue triangles judged at most.
    max_per_triangle : int — on rich frames, an image triangle that more catalogue triangles
        match (with a fourth star confirming) than this is skipped: it cannot tell them apart.
    per_field : int — catalogue stars per field in the pair table (:func:`skyfix.identify.pairs.pair_table`).
    """
    options = {"fov_deg": fov_deg, "fov_tolerance_deg": fov_tolerance_deg, "camera": camera,
               "database": database, "epoch": epoch, "max_stars": max_stars,
               "centroid_sigma_px": centroid_sigma_px, "n_sigma": n_sigma, "mag_margin": mag_margin,
               "missing_margin": missing_margin, "min_error_px": min_error_px,
               "lone_prob_threshold": lone_prob_threshold, "prob_threshold": prob_threshold,
               "max_candidates": max_candidates, "max_per_triangle": max_per_triangle, "per_field": per_field}
    t0 = time.perf_counter()
    result, lone = _identify(xy, width, height, **options)
    return unless_mirrored(result, xy, width, height, options, t0) if lone else result


def unless_mirrored(result: Identification, xy: np.ndarray, width: int, height: int, options: dict,
                    t0: float) -> Identification:
    """Rule 7, the mirror image (docs/identification-methods.md#triangle): a sparse frame's
    lone triangle ``result`` is refused when the same centroids flipped left-right (about the
    principal point) are identified more surely (a smaller chance of a wrong match). A frame
    flipped by its reader (a FITS row order, a mirror in the optics) is a real input, and a
    near-symmetric constellation seen mirrored can put three or four of its stars on the sky's
    own within the tolerance: Orion's Rigel and belt, mirrored, were named with a chance of 8e-5
    (``tests/identify/test_identify_every_method.py``); flipped back they match with 3e-15. A flipped
    frame is the rarer input, so a mirror that fits only about as well (within
    :data:`AMBIGUITY_RATIO`, rule 5's margin between two hypotheses of the same frame) does not
    refuse: it would cost 2 of the 40 noise-free three-star fields of
    ``tests/identify/test_identify_triangle.py``, whose mirrored triangles match other catalogue ones."""
    flipped = np.array(xy, dtype=np.float64)
    flipped[:, 0] = 2.0 * float(result.camera.cx) - flipped[:, 0]
    mirror, _ = _identify(flipped, width, height, **options)
    if not mirror.success or mirror.prob_false >= result.prob_false:
        return result
    return failure(METHOD, "ambiguous: the stars fit the sky mirrored left-right better (chance "
                           f"{mirror.prob_false:.1e} against {result.prob_false:.1e}): a mirror image? "
                           "Flip it before solving", t0,
                   result.n_patterns_tried, result.n_candidates)


def _identify(xy: np.ndarray, width: int, height: int, *, fov_deg: float | None,
              fov_tolerance_deg: float | None, camera: Camera | None, database: PatternDatabase | None,
              epoch: float | None, max_stars: int, centroid_sigma_px: float, n_sigma: float,
              mag_margin: float, missing_margin: float, min_error_px: float, lone_prob_threshold: float,
              prob_threshold: float, max_candidates: int, max_per_triangle: int,
              per_field: int) -> tuple[Identification, bool]:
    """:func:`identify` without the mirror rule: the Identification, and whether it is a sparse
    frame's lone triangle (accepted by rules 1–5)."""
    if not 3 <= int(max_stars) <= 12:
        raise InputError(f"max_stars must be 3–12, not {max_stars}")
    frame = frame_for(METHOD, xy, width, height, fov_deg=fov_deg, fov_tolerance_deg=fov_tolerance_deg,
                      camera=camera, database=database, epoch=epoch, min_stars=3,
                      prob_threshold=prob_threshold, centroid_sigma_px=centroid_sigma_px)
    if isinstance(frame, Identification):
        return frame, False
    cam = frame.camera
    f0 = float(cam.fx)
    s_tol = frame.scale_tolerance
    fov = math.degrees(2.0 * math.atan(cam.width / 2.0 / f0))
    diag = math.degrees(2.0 * math.atan(math.hypot(cam.width, cam.height) / 2.0 / f0))
    table = pair_table(frame.database, fov, diag * (1.0 + s_tol) * 1.02 + 0.05, per_field=per_field)
    vectors = frame.stars.vectors
    _, star_mag, _ = frame.database.star_arrays()
    tol = n_sigma * math.sqrt(2.0) * centroid_sigma_px / f0
    n = min(len(frame.xy), int(max_stars))
    triangles = _image_triangles(n)
    # Of the first image triangles (those of the five brightest stars), the cheapest to search
    # first: with a FOV only a long side's range holds ten thousand pairs, a short one's hundreds.
    first = sum(1 for t in triangles if t[2] < _FIRST_STARS)
    plan = [(tri, *_sides_order(frame, table, tri, tol)) for tri in triangles[:first]]
    plan.sort(key=lambda e: e[3])
    plan += [(tri, None, None, 0.0) for tri in triangles[first:]]
    out = np.empty((_MAX_MATCHES, 5), np.int32)
    err = np.empty(_MAX_MATCHES)
    n_all = len(star_mag)
    sparse = len(frame.xy) <= 4
    n_cand = 0

    def candidates(confirm: bool):
        """(image triangle number, its vertices (and the confirming star's) and sides, catalogue
        stars) in search order; with ``confirm``, only triangles a fourth star confirms."""
        nonlocal n_cand
        for t, (tri, verts, sides, _) in enumerate(plan):
            if verts is None:
                verts, sides, _ = _sides_order(frame, table, tri, tol)
            # FOV only: the scale side 01 implies carries its error into the other sides, and a
            # focal length across its range bends the sides' ratios a little (projection).
            spread = _ratio_spread(frame, verts)
            t_other = tol * (1.0 + sides[1:].max() / sides[0]) + spread * sides[0]
            extra = np.setdiff1d(np.arange(n), verts) if confirm else np.zeros(0, np.int64)
            # With a FOV only one confirming star is often found by chance: ask for two when
            # three or more could confirm.
            need = 2.0 if not frame.calibrated and len(extra) >= 3 else 1.0
            bounds = np.array([sides[0] * (1 - s_tol) - tol, sides[0] * (1 + s_tol) + tol, t_other, t_other,
                               tol, spread, need])
            if frame.calibrated:
                bounds[2] = bounds[3] = tol
            angles = _angles_to(frame.rays, extra, verts)
            k = triangle_matches(table, vectors, sides, bounds, frame.calibrated, n_all, angles, out, err)
            if confirm and k > max_per_triangle:
                continue  # an image triangle that many catalogue ones confirm tells nothing (pyramid's rule)
            k = min(k, len(out))
            for a, b, c, d, e in out[:k][np.argsort(err[:k], kind="stable")]:  # the closest shapes first
                if n_cand >= max_candidates:
                    return
                n_cand += 1
                if d >= 0:
                    yield t, np.append(verts, extra[d]), sides, np.array([a, b, c, e], np.int64)
                else:
                    yield t, verts, sides, np.array([a, b, c], np.int64)

    if not sparse:
        result = first_accepted(frame, ((v, c) for _, v, _, c in candidates(True)), n_tried=len(triangles),
                                max_candidates=max_candidates)
        if result.success or len(frame.xy) > LONE_MAX_STARS:
            return result, False
        n_cand = 0
    lone: list[tuple[float, Hypothesis, LoneJudgement]] = []
    for _, verts, sides, cat in candidates(False):
        h = hypothesis(frame, verts, cat)
        if not fits(frame, h):
            continue
        # Every image triangle counts (rule 2): the best match is chosen among all of them.
        j = judge_lone(frame, h, table, star_mag, sides_img=sides, tolerance_rad=tol, n_triangles=len(plan),
                       mag_margin=mag_margin, missing_margin=missing_margin, min_error_px=min_error_px)
        if j.n_missing == 0 and _triangle_holds(frame, j):
            lone.append((j.log_chance, h, j))
    if not lone:
        return failure(METHOD, f"no catalogue triangle fits ({n_cand} candidates from {len(triangles)} "
                               "image triangles)", frame.t0, len(triangles), n_cand), False
    lone.sort(key=lambda e: e[0])
    best_log, best_h, best_j = lone[0]
    if best_log > math.log(lone_prob_threshold):
        return failure(METHOD, "no triangle unique enough: best chance of a wrong match "
                               f"{math.exp(best_log):.1e} > {lone_prob_threshold:g}", frame.t0,
                       len(triangles), n_cand), False
    apart = 3.0 * frame.radius_px / float(best_h.focal_px)
    rivals = {tuple(j.catalog[:3]) for lp, h, j in lone
              if lp <= best_log + math.log(AMBIGUITY_RATIO) and _rotation_angle(h, best_h) > apart}
    if rivals:
        return failure(METHOD, f"ambiguous: {len(rivals) + 1} catalogue triangles fit these stars about "
                               "equally well", frame.t0, len(triangles), n_cand), False
    return _lone_identification(frame, best_h, best_j, len(triangles), n_cand), True


def _rotation_angle(a: Hypothesis, b: Hypothesis) -> float:
    """The angle (radians) of the rotation between two hypotheses' attitudes. Two hypotheses
    that put the camera in different places are rivals whatever stars they name (an equilateral
    triangle's three vertex assignments name the same stars at three rolls)."""
    c = (np.trace(a.A_icrs_to_cam @ b.A_icrs_to_cam.T) - 1.0) / 2.0
    return math.acos(min(max(c, -1.0), 1.0))
