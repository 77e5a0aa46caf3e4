"""Lost-in-space identification by the Pyramid of Mortari et al.: the ``"pyramid"`` method
(thesis 000 §2.6.4; Mortari, Samaan, Bruccoleri & Junkins, "The Pyramid Star Identification
Technique", Navigation 51(3), 2004).

1. Image triangles ``(i, j, k)`` of the ``pattern_stars`` brightest centroids in the paper's
   order (:func:`triangle_order`): ``dj`` outermost, then ``dk``, then ``i``, with ``j = i + dj``
   and ``k = j + dk`` — consecutive triangles share few stars, so a false star is not tried
   over and over.
2. The triangle's three angles are matched through the pair table
   (:mod:`skyfix.identify.catalogue.pairs`): the shortest side, labelled ``(i, j)``, by
   :func:`~skyfix.identify.catalogue.pairs.pairs_in_range`
   (both orientations of each catalogue pair); with only a FOV known that pair fixes the focal
   length (:func:`~skyfix.identify.common.angle_match.focal_for_angle`); ``(i, k)`` by
   :func:`~skyfix.identify.catalogue.pairs.neighbours_in_range` of ``i``'s candidate; ``(j, k)`` and the
   handedness — the sign of the triple product, which a rotation keeps and a mirror flips —
   checked directly. A triangle with more than one catalogue match is skipped, as in the paper;
   so is one too thin for its handedness to be measured.
3. A unique triangle gets its apex: the next centroid ``r`` (brightest first) whose three
   angles to the triangle match exactly one catalogue star. The pyramid (4 stars) is the
   proposal, judged by :func:`skyfix.identify.common.hypothesis.first_accepted` (one proper rotation,
   the chance of a wrong match with every proposal counted, the refit on all stars — which
   identifies the remaining stars, the paper's last step).

Steps 1–3 are one compiled kernel (:func:`pyramid_search`) that stops at each proposal and
resumes at the next triangle. Where this differs from the paper, its options and measured
numbers: docs/identification-methods.md#pyramid.
"""

from __future__ import annotations

import dataclasses
import functools
import time

import numpy as np

from skyfix._jit import njit
from skyfix.camera import Camera
from skyfix.identify.accept import CENTROID_SIGMA_PX, PROB_THRESHOLD
from skyfix.identify.catalogue.database import PatternDatabase
from skyfix.identify.catalogue.pairs import neighbours_in_range, pairs_in_range
from skyfix.identify.common.angle_match import (
    LONE_PROB_THRESHOLD,
    angle_range,
    angle_settings,
    angle_tolerance,
    focal_for_angle,
    frame_pair_table,
    judged,
    ray_angle,
    star_angle,
    triple_product,
)
from skyfix.identify.common.hypothesis import failure, frame_for
from skyfix.identify.common.result import Identification

__all__ = ["METHOD", "identify", "pyramid_search", "triangle_order"]

METHOD = "pyramid"

_CHUNK = 64  # triangles per kernel call between checks of the time limit
_NO_BOUND = 2**62


@functools.cache
def triangle_order(n: int) -> np.ndarray:
    """The ``n·(n−1)·(n−2)/6`` image triangles ``(i, j, k)``, ``i < j < k``, of ``n`` stars in
    the Pyramid paper's order: ``for dj: for dk: for i: (i, i + dj, i + dj + dk)``.

    Examples
    --------
    >>> triangle_order(4).tolist()
    [[0, 1, 2], [1, 2, 3], [0, 1, 3], [0, 2, 3]]
    """
    rows = [(i, i + dj, i + dj + dk) for dj in range(1, n - 1) for dk in range(1, n - dj)
            for i in range(n - dj - dk)]
    out = np.array(rows, np.int64).reshape(-1, 3)
    out.flags.writeable = False
    return out


@njit(cache=True, inline="always")
def _labelled(p, f, a, b, c):
    """The triangle ``a, b, c`` labelled ``(i, j, k)``: ``(i, j)`` its shortest side (searched in
    the pair table: the fewest pairs), ``(i, k)`` its longest (with only a FOV known, it fixes
    the focal length)."""
    ab, ac, bc = ray_angle(p, a, b, f), ray_angle(p, a, c, f), ray_angle(p, b, c, f)
    if ab <= ac and ab <= bc:
        x, y, k = a, b, c
    elif ac <= bc:
        x, y, k = a, c, b
    else:
        x, y, k = b, c, a
    if ray_angle(p, x, k, f) >= ray_angle(p, y, k, f):
        return x, y, k
    return y, x, k


@njit(cache=True)
def _apex(s, table, vectors, i, j, k, cat, focal, ref, n_match, n, out_stars, out_cat):
    """The first centroid ``r`` below ``n`` (not i, j, k) that makes exactly one pyramid: over the
    ``n_match`` catalogue triangles ``cat[m]`` of image triangle ``(i, j, k)`` (each at focal
    length ``focal[m]``, fixed by a side ``ref[m]`` rad long), exactly one catalogue star whose
    three angles match ``r``'s. Written to ``out_*`` (True) or none (False)."""
    p = s.offsets_px
    for r in range(n):
        if r == i or r == j or r == k:
            continue
        count = 0
        for m in range(n_match):
            ci, cj, ck, f = cat[m, 0], cat[m, 1], cat[m, 2], focal[m]
            a_ir = ray_angle(p, i, r, f)
            a_jr = ray_angle(p, j, r, f)
            a_kr = ray_angle(p, k, r, f)
            t_ir = angle_tolerance(a_ir, ref[m], f, s.noise_px, s.calibrated)
            t_jr = angle_tolerance(a_jr, ref[m], f, s.noise_px, s.calibrated)
            t_kr = angle_tolerance(a_kr, ref[m], f, s.noise_px, s.calibrated)
            m0, m1 = neighbours_in_range(table, ci, a_ir - t_ir, a_ir + t_ir)
            for e in range(m0, m1):
                c = table.neighbour[e]
                if c == cj or c == ck:
                    continue
                if abs(star_angle(vectors, cj, c) - a_jr) > t_jr:
                    continue
                if abs(star_angle(vectors, ck, c) - a_kr) > t_kr:
                    continue
                count += 1
                if count > 1:
                    break
                out_cat[0], out_cat[1], out_cat[2], out_cat[3] = ci, cj, ck, c
            if count > 1:
                break
        if count == 1:
            out_stars[0], out_stars[1], out_stars[2], out_stars[3] = i, j, k, r
            return True
    return False


@njit(cache=True)
def pyramid_search(s, table, vectors, triangles, start, stop, n, min_pairs, max_pairs, max_matches, out_stars,
                   out_cat):
    """Search triangles ``start:stop`` of ``triangles`` (image rows of the ``n`` stars used) for
    a pyramid (module text, steps 2–3).

    Parameters
    ----------
    s : AngleSettings
        The frame's angles (:func:`skyfix.identify.common.angle_match.angle_settings`).
    table : PairTable
        The pair table (:func:`skyfix.identify.common.angle_match.frame_pair_table`).
    vectors : (S, 3) float64
        The catalogue unit vectors the table's rows index.
    min_pairs, max_pairs : int
        Only triangles whose searched side has this many candidate pairs are examined.
    max_matches : int
        Without a camera, the most catalogue triangles one image triangle may match.
    out_stars, out_cat : (4,) int64
        Receive the pyramid's centroid rows and catalogue rows.

    Returns
    -------
    next_triangle : int — where to resume (``stop`` when none was found).
    found : bool
    """
    p = s.offsets_px
    limit = 1 if s.calibrated else max_matches
    cat = np.empty((max(limit, 1), 3), np.int64)
    focal = np.empty(max(limit, 1))
    ref = np.empty(max(limit, 1))
    for t in range(start, stop):
        i, j, k = _labelled(p, s.f0, triangles[t, 0], triangles[t, 1], triangles[t, 2])
        a0_ik = ray_angle(p, i, k, s.f0)
        handed = triple_product(s.rays, i, j, k)
        if abs(handed) <= a0_ik * s.noise_px / s.f0:  # too thin: its height is within the noise
            continue
        lo, hi = angle_range(p, i, j, s.f_lo, s.f_hi, s.noise_px)
        q0, q1 = pairs_in_range(table.angle_rad, lo, hi)
        if not min_pairs <= q1 - q0 <= max_pairs:  # a side this ambiguous is left to a later pass
            continue
        n_found = 0
        for q in range(q0, q1):
            if n_found > limit:
                break
            f = s.f0
            if not s.calibrated:
                f = focal_for_angle(p, i, j, table.angle_rad[q], s.f0, s.f_lo, s.f_hi)
            a_ik = ray_angle(p, i, k, f)
            t_ik = angle_tolerance(a_ik, ray_angle(p, i, j, f), f, s.noise_px, s.calibrated)
            for o in range(2):
                ci = table.first[q] if o == 0 else table.second[q]
                cj = table.second[q] if o == 0 else table.first[q]
                m0, m1 = neighbours_in_range(table, ci, a_ik - t_ik, a_ik + t_ik)
                for m in range(m0, m1):
                    ck = table.neighbour[m]
                    if ck == cj or triple_product(vectors, ci, cj, ck) * handed <= 0.0:
                        continue
                    f_k = f
                    if not s.calibrated:  # the longest side (i, k) fixes the focal length better
                        f_k = focal_for_angle(p, i, k, table.neighbour_angle[m], f, s.f_lo, s.f_hi)
                        a_ref = ray_angle(p, i, k, f_k)
                        a_ij = ray_angle(p, i, j, f_k)
                        t_ij = angle_tolerance(a_ij, a_ref, f_k, s.noise_px, False)
                        if abs(table.angle_rad[q] - a_ij) > t_ij:
                            continue
                    else:
                        a_ref = a_ik
                    a_jk = ray_angle(p, j, k, f_k)
                    if abs(star_angle(vectors, cj, ck) - a_jk) > angle_tolerance(a_jk, a_ref, f_k, s.noise_px,
                                                                                  s.calibrated):
                        continue
                    if n_found < limit:
                        cat[n_found, 0], cat[n_found, 1], cat[n_found, 2] = ci, cj, ck
                        focal[n_found], ref[n_found] = f_k, a_ref
                    n_found += 1
                    if n_found > limit:
                        break
                if n_found > limit:
                    break
        if n_found == 0 or n_found > limit:
            continue
        if _apex(s, table, vectors, i, j, k, cat, focal, ref, n_found, n, out_stars, out_cat):
            return t + 1, True
    return stop, False


class _Progress:
    """What the proposal generator reports back: triangles examined and why it stopped."""

    def __init__(self) -> None:
        self.triangles = 0
        self.stopped = ""


def _pyramids(frame, s, table, n, max_triangles, max_pairs, max_matches, time_limit_s, progress):
    """The pyramids of the frame, in the search's order (a generator for ``first_accepted``)."""
    triangles = triangle_order(n)
    end = min(len(triangles), max_triangles)
    vectors = frame.stars.vectors
    out_stars = np.empty(4, np.int64)
    out_cat = np.empty(4, np.int64)
    # No triangles: the first call in a process loads (or compiles) the kernel before the clock starts.
    pyramid_search(s, table, vectors, triangles, 0, 0, n, 0, max_pairs, max_matches, out_stars, out_cat)
    deadline = time.perf_counter() + time_limit_s
    # Two passes: triangles whose searched side has at most max_pairs candidate pairs, then the rest.
    for min_pairs, max_pairs_pass in ((0, max_pairs), (max_pairs + 1, _NO_BOUND)):
        t = 0
        while t < end:
            if time.perf_counter() > deadline:
                progress.stopped = "time limit reached"
                return
            t, found = pyramid_search(s, table, vectors, triangles, t, min(t + _CHUNK, end), n, min_pairs,
                                      max_pairs_pass, max_matches, out_stars, out_cat)
            progress.triangles = max(progress.triangles, t)
            if found:
                yield out_stars.copy(), out_cat.copy()
    progress.stopped = f"{'all' if end == len(triangles) else 'max_triangles'} {end} triangles tried"


# Over ten parameters: the interface of every method (:mod:`skyfix.identify.methods`) and this
# method's options, all keywords with a documented default.
def identify(xy: np.ndarray, width: int, height: int, *, fov_deg: float | None = None,
             fov_tolerance_deg: float | None = None, camera: Camera | None = None,
             database: PatternDatabase | None = None, epoch: float | None = None, pattern_stars: int = 20,
             centroid_sigma_px: float = CENTROID_SIGMA_PX, n_sigma: float = 3.0, max_triangles: int = 2000,
             max_side_share: float = 0.004, max_triangle_matches: int = 64, max_candidates: int = 200,
             time_limit_s: float = 2.0, per_field: int = 12, prob_threshold: float = PROB_THRESHOLD,
             lone_prob_threshold: float = LONE_PROB_THRESHOLD) -> Identification:
    """Identify the stars of one frame, lost in space, by the Pyramid method (module text).

    Parameters
    ----------
    xy, width, height, fov_deg, fov_tolerance_deg, camera, database, epoch
        The interface of every method (:mod:`skyfix.identify.methods`). A camera or a FOV is
        required (the method measures angles).
    pattern_stars : int
        Brightest centroids that form triangles and apexes.
    centroid_sigma_px : float
        Expected centroid noise per axis, pixels: an angle's noise is ``σ·√2 / f``.
    n_sigma : float
        Angles match within ``n_sigma`` times their noise (plus the focal range's share).
    max_triangles : int
        Work bound: image triangles examined.
    max_side_share : float
        Work order: a triangle whose searched side matches more than this share of the pair
        table's pairs waits for a second pass over the triangles (without a camera a side's
        pairs over the focal range number thousands; with one, at 15° and σ 0.5 px, below
        0.4 %: 1000 of ~250,000).
    max_triangle_matches : int
        With only a FOV known: an image triangle that matches more catalogue triangles than this
        is skipped (a calibrated camera's must match exactly one).
    max_candidates : int
        Work bound: pyramids proposed to the verification.
    time_limit_s : float
        Work bound: wall time of the search, seconds (checked every 64 triangles; the kernel's
        first load or compilation in a process not counted).
    per_field : int
        Catalogue stars per field of the pair table (:func:`skyfix.identify.catalogue.pairs.pair_table`).
    prob_threshold : float
        Largest accepted probability that the match is chance.
    lone_prob_threshold : float
        The same for a sparse frame (at most 8 centroids) whose proposals ``prob_threshold``
        refused: each proposal's triangle judged by the ``triangle`` method's sparse-frame rules
        (:func:`skyfix.identify.common.angle_match.sparse_identification`).

    Returns
    -------
    Identification
        The first pyramid that passes every acceptance rule, refitted on all matched stars; or
        a failure with the reason (no scale, too few stars, the work bound that stopped it).

    Raises
    ------
    skyfix.errors.CameraError
        An impossible ``fov_deg``.
    """
    frame = frame_for(METHOD, xy, width, height, fov_deg=fov_deg, fov_tolerance_deg=fov_tolerance_deg,
                      camera=camera, database=database, epoch=epoch, min_stars=4,
                      prob_threshold=prob_threshold, centroid_sigma_px=centroid_sigma_px)
    if isinstance(frame, Identification):
        return frame
    table = frame_pair_table(frame, per_field)
    s = angle_settings(frame, centroid_sigma_px, n_sigma)
    n = min(len(frame.xy), pattern_stars)
    progress = _Progress()
    max_pairs = max(int(max_side_share * len(table.angle_rad)), 1)
    pyramids = _pyramids(frame, s, table, n, max_triangles, max_pairs, max_triangle_matches,
                         time_limit_s, progress)
    result, sparse = judged(frame, table, pyramids, max_candidates=max_candidates, n_stars=n,
                            tolerance_rad=s.noise_px / s.f0, centroid_sigma_px=centroid_sigma_px,
                            work=lambda: progress.triangles, threshold=lone_prob_threshold)
    if result.success:
        return dataclasses.replace(result, n_patterns_tried=progress.triangles)
    stopped = progress.stopped or f"max_candidates {max_candidates} pyramids proposed"
    return failure(METHOD, f"no pyramid verified: {result.n_candidates} proposed, {stopped}{sparse}",
                   frame.t0, progress.triangles, result.n_candidates)
