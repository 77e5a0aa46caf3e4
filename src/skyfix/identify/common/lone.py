"""A sparse frame's lone triangle judged on its own chance: the triangle search through the pair
table (:func:`triangle_matches`) and the judgement (:func:`judge_lone`), shared by the ``triangle``
method (:mod:`skyfix.identify.methods.triangle`) and the pair-table methods' sparse frames
(:mod:`skyfix.identify.common.angle_match`).

*Sparse frames* (three or four stars, or up to :data:`LONE_MAX_STARS` that the 4-star
confirmation did not settle): a lone triangle has nothing else to verify it against, so its own
chance is computed, honestly (numbered as :mod:`skyfix.identify.accept`'s rules):

8. **How unusual a match this close is.** The catalogue triangles near the measured one — all
   three sides within ``W`` (:func:`window_rad`) — are counted, among stars no fainter than
   ``mag_margin`` beyond the faintest of the match (the image's three brightest stars are among
   the sky's brightest there), and of those only the ones rule 11 would not refute where they
   stand (:func:`judge_lone`: a triangle with a brighter star beside it is no rival; the share
   is measured on a sample of 4096 when there are more). Their density times the volume of the
   box the match actually falls in (its largest side error ``ε``, floored at
   ``min_error_px``) is the expected number
   of catalogue triangles that close to a *random* triangle: ``λ = M_W · (ε / W)^d``, ``d`` = 3
   with a calibrated camera, 2 with a FOV only (the scale is then free: only the shape counts).
   The match's own triangle is among the ``M_W``, which keeps ``λ`` from reaching 0. A false
   star turns the image triangle into a random one, so ``λ`` is the chance it matches as well.
9. **Every look counted.** ``λ`` is multiplied by the image triangles tried (each one a fresh
   chance to meet a catalogue triangle by accident; every combination of false stars is one of
   them).
10. **Every other star counted.** Stars beyond the triangle verify it as in the 4-star method: the
   catalogue stars in view (as bright as ``mag_margin`` beyond the triangle's faintest) that land
   on centroids by chance is a binomial tail (:func:`skyfix.identify.accept.chance_log_probability`),
   multiplied in.
11. **Nothing bright missing.** A catalogue star in the frame brighter than the triangle's
   faintest by ``missing_margin`` magnitudes that lands on no centroid would have been detected:
   the hypothesis is rejected.
13. **Unique.** When two hypotheses that put the camera in different places (different stars,
    or the same stars assigned another way: an equilateral triangle's three rolls) both pass
    8–11 within a factor of :data:`AMBIGUITY_RATIO` of the best chance, the frame fails
    "ambiguous" — it does not guess. (Rule 12, the triangle holds, and 14, not mirrored, are the
    ``triangle`` method's: :mod:`skyfix.identify.methods.triangle`.)
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.rotation import chord_angle
from skyfix.identify.accept import chance_log_probability as binomial_log_probability
from skyfix.identify.catalogue.pairs import PairTable, neighbours_in_range, pairs_in_range
from skyfix.identify.common.hypothesis import Frame, Hypothesis, rays_at
from skyfix.identify.common.verify import stars_in_view

__all__ = ["AMBIGUITY_RATIO", "LONE_MAX_STARS", "LoneJudgement", "NO_CONFIRM", "in_view", "judge_lone",
           "pair_angles3", "rank_limit", "triangle_matches", "window_rad"]

LONE_MAX_STARS = 8
"""Frames of more centroids than this are judged by the common rules only: the lone-triangle
test is for sparse frames (its cost grows with the stars; a rich frame that the common rules
cannot settle has a reason to fail)."""
AMBIGUITY_RATIO = 100.0  # a second triangle this close to the best one's chance makes the frame ambiguous
NO_CONFIRM = np.empty((0, 3))
_WINDOW_MAX = 4096  # catalogue triangles near a sparse frame's match tested by rule 11 (a sample beyond)



@njit(cache=True, inline="always")
def _angle(u, v):
    """The angle between unit vectors ``u`` and ``v`` from their chord (accurate when small)."""
    chord = math.sqrt((u[0] - v[0]) ** 2 + (u[1] - v[1]) ** 2 + (u[2] - v[2]) ** 2)
    return 2.0 * math.asin(min(chord / 2.0, 1.0))


@njit(cache=True)
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


@njit(cache=True)
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
    """How a sparse frame's hypothesis fared (accept rules 8–11).

    log_chance : float — log of λ × image triangles tried × the other stars' binomial tail.
    n_window : int — catalogue triangles within the window (M_W, the match's own included).
    error_rad : float — the match's largest side error ε (before the floor).
    stars, catalog : (K,) int64 — all matched centroid rows and catalogue rows (the triangle first).
    n_missing : int — bright catalogue stars in the frame on no centroid (rule 11).
    """

    log_chance: float
    n_window: int
    error_rad: float
    stars: np.ndarray
    catalog: np.ndarray
    n_missing: int


def pair_angles3(v: np.ndarray) -> np.ndarray:
    """(θ01, θ02, θ12) of three unit vectors."""
    return chord_angle(np.linalg.norm(v[[0, 0, 1]] - v[[1, 2, 2]], axis=1))


def rank_limit(star_mag: np.ndarray, mag: float) -> int:
    """One past the faintest-ranked star no fainter than ``mag`` (stars are brightest first; a
    catalogue whose order is not strictly by this magnitude gets the conservative bound)."""
    below = np.flatnonzero(star_mag <= mag)
    return int(below[-1]) + 1 if len(below) else 0


def in_view(frame: Frame, h: Hypothesis, limit: int) -> tuple[np.ndarray, np.ndarray]:
    """Catalogue rows (< ``limit``) in the frame at ``h`` and their offsets (pixels, at h's focal)."""
    n = stars_in_view(np.ascontiguousarray(h.A_icrs_to_cam), float(h.focal_px), 0.0, frame.image.frame_px,
                      np.int64(limit), frame.stars, frame.view)
    return frame.view.index[:n].copy(), np.column_stack([frame.view.x_px[:n], frame.view.y_px[:n]])


def judge_lone(frame: Frame, h: Hypothesis, table: PairTable, star_mag: np.ndarray, *, sides_img: np.ndarray,
               tolerance_rad: float, n_triangles: int, mag_margin: float, missing_margin: float,
               min_error_px: float) -> LoneJudgement:
    """Accept rules 8–11 for a triangle hypothesis ``h`` (its three centroid rows
    and catalogue rows in vertex order; ``sides_img`` the image triangle's sides at the
    nominal focal length, θ01 the longest)."""
    vectors = frame.stars.vectors
    f = float(h.focal_px)
    m_faint = float(star_mag[h.catalog[:3]].max())
    # The other stars: matched ones verify (rule 10), bright unmatched ones refute (rule 11).
    idx, xy = in_view(frame, h, rank_limit(star_mag, m_faint + mag_margin))
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
    cat_sides = pair_angles3(vectors[h.catalog[:3]])
    img_sides = pair_angles3(rays_at(frame, h.stars[:3], f))
    error = float(np.abs(cat_sides - img_sides).max())
    fov = 2.0 * math.atan(frame.camera.width / 2.0 / f)
    window = window_rad(fov, tolerance_rad)
    rank = rank_limit(star_mag, m_faint + mag_margin)
    calibrated = frame.calibrated
    s_tol = frame.scale_tolerance
    # The box in the sides' space: side 01 over the focal range, the others as the search's.
    other = window if calibrated else window * (1.0 + sides_img[1:].max() / sides_img[0])
    tol = np.array([sides_img[0] * (1 - s_tol) - window, sides_img[0] * (1 + s_tol) + window, other, other,
                    window, 0.0, 1.0])
    found = np.empty((_WINDOW_MAX, 5), np.int32)
    n_window = triangle_matches(table, vectors, sides_img, tol, calibrated, rank, NO_CONFIRM, found,
                                np.empty(_WINDOW_MAX))
    # The share of them rule 11 leaves standing, from the first _WINDOW_MAX found (in the order
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


@njit(cache=True)
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
    centroids — survive rule 11 (no catalogue star brighter than the triangle's faintest by
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
