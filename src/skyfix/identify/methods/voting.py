"""Lost-in-space identification by geometric voting: the ``"voting"`` method (thesis 000
§2.6.6; Kolomenkin, Pollak, Shimshoni & Lindenbaum, "Geometric voting algorithm for star
trackers", IEEE Trans. Aerospace and Electronic Systems 44(2), 2008).

1. **Votes.** Every pair of the ``vote_stars`` brightest centroids votes for every catalogue
   pair of the pair table (:mod:`skyfix.identify.catalogue.pairs`) whose angle is within the pair's
   tolerance (:func:`~skyfix.identify.catalogue.pairs.pairs_in_range`): each of the two centroids gets a
   vote for each of the two catalogue stars (both assignments). One compiled kernel
   (:func:`cast_votes`) adds them into a (centroid, catalogue star) table.
2. **Candidates.** Each of the ``n`` centroids keeps its ``candidate_nodes // n`` most-voted
   catalogue stars (the paper keeps the first only: in a sparse field the true star, with one
   vote per other centroid, is often outvoted by chance ones among thousands; the fewer the
   centroids, the more candidates each keeps, at the same cost of validation).
3. **Validation.** Every pair of candidates whose angle agrees with its centroids' angle votes
   again, for both; each centroid keeps the candidate that agrees with the most other
   centroids (most votes first on ties). The consistent set grows from the best-validated
   centroid, adding the next best-validated ones whose candidates agree with every member's
   (:func:`consistent_set`).
4. **Proposal.** The set, best-validated first, goes to
   :func:`skyfix.identify.common.hypothesis.first_accepted` (one proper rotation — a mirror image has
   none — the chance of a wrong match with every proposal counted, the refit on all stars);
   while it fails, the sets grown from the next best-validated centroids not yet used follow
   (``sets_per_scale`` at most). On a rich frame whose sets all fail, a second pass with twice
   the candidates per centroid follows (a field of faint stars, few of them in the pair table,
   has its true stars outvoted at the first pass's budget).

The paper assumes a calibrated camera. With only a FOV known, skyfix votes at one focal-length
interval at a time — the nominal one first, then outward, each narrow enough that the scale
adds no more than the noise to a typical angle's tolerance — since votes over the whole focal
range would bury every true vote under chance ones. Options and measured numbers:
docs/identification-methods.md#voting.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import time

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.rotation import chord_angle
from skyfix.camera import Camera
from skyfix.identify.accept import CENTROID_SIGMA_PX, PROB_THRESHOLD
from skyfix.identify.catalogue.database import PatternDatabase
from skyfix.identify.catalogue.pairs import PairTable, pairs_in_range
from skyfix.identify.common.angle_match import (
    LONE_PROB_THRESHOLD,
    AngleSettings,
    angle_range,
    angle_settings,
    consistent_set,
    frame_pair_table,
    judged,
    star_chord2,
)
from skyfix.identify.common.hypothesis import Frame, failure, frame_for
from skyfix.identify.common.lone import LONE_MAX_STARS
from skyfix.identify.common.result import Identification

__all__ = ["METHOD", "cast_votes", "focal_steps", "identify", "top_voted", "validate"]

METHOD = "voting"


@njit(cache=True)
def cast_votes(s, table, local, n, f_a, f_b, votes):
    """Add the votes of the ``n`` brightest centroids' pairs at a focal length in
    ``[f_a, f_b]`` into ``votes`` (n, T) int32: centroid row × table star (``local`` maps a
    star-index row to its column). Returns the votes cast."""
    p = s.offsets_px
    cast = 0
    for a in range(n):
        for b in range(a + 1, n):
            lo, hi = angle_range(p, a, b, f_a, f_b, s.noise_px)
            q0, q1 = pairs_in_range(table.angle_rad, lo, hi)
            for q in range(q0, q1):
                u = local[table.first[q]]
                w = local[table.second[q]]
                votes[a, u] += 1
                votes[a, w] += 1
                votes[b, u] += 1
                votes[b, w] += 1
            cast += 4 * (q1 - q0)
    return cast


def focal_steps(s: AngleSettings, n: int) -> np.ndarray:
    """The focal-length intervals ``(f_a, f_b)`` (K, 2) voted one at a time, the nominal one first
    then outward: one ``(f0, f0)`` for a calibrated camera; else intervals of equal width in
    log f over ``[f_lo, f_hi]``, each shifting the median angle of the ``n`` brightest
    centroids by no more than its noise tolerance."""
    if s.calibrated or s.f_hi <= s.f_lo:
        return np.array([[s.f0, s.f0]])
    i, j = np.triu_indices(n, 1)
    p = s.offsets_px
    r = np.column_stack([p[:n], np.full(n, s.f0)])
    r /= np.linalg.norm(r, axis=1)[:, None]
    theta = float(np.median(chord_angle(np.linalg.norm(r[i] - r[j], axis=1))))
    width = max(s.noise_px / s.f0 / max(theta, 1e-9), 1e-4)
    below, above = math.log(s.f0 / s.f_lo), math.log(s.f_hi / s.f0)
    k = np.arange(-math.ceil(below / width - 0.5), math.ceil(above / width - 0.5) + 1)
    k = k[np.argsort(np.abs(k) - 0.1 * np.sign(k), kind="stable")]  # 0, 1, -1, 2, -2, …
    lo = np.clip(s.f0 * np.exp((k - 0.5) * width), s.f_lo, s.f_hi)
    hi = np.clip(s.f0 * np.exp((k + 0.5) * width), s.f_lo, s.f_hi)
    return np.column_stack([lo, hi])


@njit(cache=True)
def top_voted(votes, table_stars, out):
    """Each row's ``K = out.shape[1]`` most-voted columns of ``votes`` (n, T), most votes first
    (the lower column on ties), as the table's stars ``table_stars[column]``, into ``out`` (n, K);
    -1 past a row's voted columns."""
    n, k = out.shape
    best = np.empty(k, np.int64)
    for a in range(n):
        size = 0
        for c in range(votes.shape[1]):
            v = votes[a, c]
            if v == 0 or (size == k and v <= votes[a, best[k - 1]]):
                continue
            e = min(size, k - 1)  # insertion: shift the lower-voted down
            while e > 0 and votes[a, best[e - 1]] < v:
                best[e] = best[e - 1]
                e -= 1
            best[e] = c
            size = min(size + 1, k)
        for e in range(k):
            out[a, e] = table_stars[best[e]] if e < size else -1


@njit(cache=True)
def validate(s, vectors, nodes, f_a, f_b, candidate, agree):
    """The validation (module text, step 3) of centroids' candidates ``nodes`` (n, K) at a focal
    length in ``[f_a, f_b]``: each centroid's ``candidate`` (n,) is the one whose angles agree
    with the most other centroids' candidates (each pair's angle within its centroids' range,
    :func:`~skyfix.identify.common.angle_match.angle_range`); ``agree`` (n, n) whether two centroids'
    candidates agree."""
    p = s.offsets_px
    n, k = nodes.shape
    lo = np.empty((n, n))  # each pair's range as squared chords (no angle per candidate pair)
    hi = np.empty((n, n))
    for a in range(n):
        for b in range(n):
            if a != b:
                low, high = angle_range(p, a, b, f_a, f_b, s.noise_px)
                lo[a, b] = (2.0 * math.sin(max(low, 0.0) / 2.0)) ** 2
                hi[a, b] = (2.0 * math.sin(min(high, math.pi) / 2.0)) ** 2
    for a in range(n):
        top = -1
        candidate[a] = -1
        for u in range(k):
            cu = nodes[a, u]
            if cu < 0:
                break
            count = 0
            for b in range(n):
                if b == a:
                    continue
                for w in range(k):
                    cw = nodes[b, w]
                    if cw < 0:
                        break
                    if cw != cu:
                        chord2 = star_chord2(vectors, cu, cw)
                        if lo[a, b] <= chord2 <= hi[a, b]:
                            count += 1
                            break
            if count > top:
                top = count
                candidate[a] = cu
    for a in range(n):
        for b in range(n):
            ca, cb = candidate[a], candidate[b]
            agree[a, b] = False
            if a != b and ca != cb and ca >= 0 and cb >= 0:
                chord2 = star_chord2(vectors, ca, cb)
                agree[a, b] = lo[a, b] <= chord2 <= hi[a, b]


class _Progress:
    """What the proposal generator reports back: focal intervals voted and why it stopped."""

    def __init__(self) -> None:
        self.steps = 0
        self.stopped = ""
        self.deadline = math.inf  # the search's end, set by the first pass: a second one shares it


def _proposals(frame: Frame, s: AngleSettings, table: PairTable, n: int, n_candidates: int, min_set: int,
               sets_per_scale: int, time_limit_s: float, progress: _Progress):
    """The consistent sets of every focal interval, in order (a generator for ``first_accepted``)."""
    local = np.full(len(frame.stars.vectors), -1, np.int64)
    local[table.stars] = np.arange(len(table.stars))
    votes = np.zeros((n, len(table.stars)), np.int32)
    members = np.empty(n, np.int64)
    steps = focal_steps(s, n)
    nodes = np.empty((n, max(min(n_candidates, len(table.stars)), 1)), np.int64)
    candidate = np.full(n, -1, np.int64)
    agree = np.zeros((n, n), np.bool_)
    # The kernels run once on no votes: the first call in a process loads (or compiles) them
    # before the time limit's clock starts.
    cast_votes(s, table, local, 0, s.f0, s.f0, votes)
    top_voted(votes, table.stars, nodes)
    validate(s, frame.stars.vectors, nodes, s.f0, s.f0, candidate, agree)
    consistent_set(agree, np.arange(n), 0, members)
    if math.isinf(progress.deadline):
        progress.deadline = time.perf_counter() + time_limit_s
    deadline = progress.deadline
    for f_a, f_b in steps:
        if time.perf_counter() > deadline:
            progress.stopped = "time limit reached"
            return
        progress.steps += 1
        votes[:] = 0
        cast_votes(s, table, local, n, f_a, f_b, votes)
        top_voted(votes, table.stars, nodes)
        validate(s, frame.stars.vectors, nodes, f_a, f_b, candidate, agree)
        support = agree.sum(axis=1)
        order = np.argsort(-support, kind="stable")
        used = np.zeros(n, np.bool_)
        tried = 0
        for seed in order:
            if tried >= sets_per_scale or support[seed] < min_set - 1:
                break
            if used[seed]:
                continue
            m = consistent_set(agree, order, seed, members)
            used[members[:m]] = True
            if m < min_set:
                continue
            tried += 1
            yield members[:m].copy(), candidate[members[:m]]
    progress.stopped = f"all {len(steps)} focal intervals voted"


# Over ten parameters: the interface of every method (:mod:`skyfix.identify.methods`) and this
# method's options, all keywords with a documented default.
def identify(xy: np.ndarray, width: int, height: int, *, fov_deg: float | None = None,
             fov_tolerance_deg: float | None = None, camera: Camera | None = None,
             database: PatternDatabase | None = None, epoch: float | None = None, vote_stars: int = 24,
             centroid_sigma_px: float = CENTROID_SIGMA_PX, n_sigma: float = 3.0, candidate_nodes: int = 240,
             min_set: int = 4, sets_per_scale: int = 3,
             max_candidates: int = 200, time_limit_s: float = 2.0, per_field: int = 12,
             prob_threshold: float = PROB_THRESHOLD,
             lone_prob_threshold: float = LONE_PROB_THRESHOLD) -> Identification:
    """Identify the stars of one frame, lost in space, by geometric voting (module text).

    Parameters
    ----------
    xy, width, height, fov_deg, fov_tolerance_deg, camera, database, epoch
        The interface of every method (:mod:`skyfix.identify.methods`). A camera or a FOV is
        required (the method measures angles).
    vote_stars : int
        Brightest centroids whose pairs vote.
    centroid_sigma_px : float
        Expected centroid noise per axis, pixels: an angle's noise is ``σ·√2 / f``.
    n_sigma : float
        Angles match within ``n_sigma`` times their noise (plus the focal interval's share).
    candidate_nodes : int
        Candidates kept over all ``n`` centroids voting: each keeps its ``candidate_nodes // n``
        most-voted catalogue stars (at least 2) for the validation (the paper: 1 each).
    min_set : int
        Fewest centroids of a frame (and of a consistent set proposed; at least 3). In a sparse
        frame (at most 8 centroids) sets of 3 are proposed too.
    sets_per_scale : int
        Work bound: consistent sets proposed per focal interval.
    max_candidates : int
        Work bound: sets proposed to the verification in all.
    time_limit_s : float
        Work bound: wall time of the search, seconds (checked between focal intervals; the
        kernels' first load or compilation in a process not counted).
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
        The first consistent set that passes every acceptance rule, refitted on all matched
        stars; or a failure with the reason (no scale, too few stars, the bound that stopped it).

    Raises
    ------
    skyfix.errors.CameraError
        An impossible ``fov_deg``.
    """
    min_set = max(int(min_set), 3)
    frame = frame_for(METHOD, xy, width, height, fov_deg=fov_deg, fov_tolerance_deg=fov_tolerance_deg,
                      camera=camera, database=database, epoch=epoch, min_stars=min_set,
                      prob_threshold=prob_threshold, centroid_sigma_px=centroid_sigma_px)
    if isinstance(frame, Identification):
        return frame
    table = frame_pair_table(frame, per_field)
    s = angle_settings(frame, centroid_sigma_px, n_sigma)
    n = min(len(frame.xy), vote_stars)
    progress = _Progress()
    per_star = max(candidate_nodes // max(n, 1), 2)
    if len(frame.xy) <= LONE_MAX_STARS:  # a sparse frame's true star has few votes: sets of three too
        min_set = 3
    sets = _proposals(frame, s, table, n, per_star, min_set, sets_per_scale, time_limit_s, progress)
    if len(frame.xy) > LONE_MAX_STARS:
        # A rich frame of faint stars, few of them in the pair table, has its true stars
        # outvoted by chance ones: 240 candidates lost 5 of 700 noise-free 15° fields with a FOV
        # only. While the first pass's sets fail, a second with twice the candidates per
        # centroid follows (its sets counted with the first's by the chance of a wrong match).
        # Not on a sparse frame: more candidates there make more chance sets of three.
        sets = itertools.chain(sets, _proposals(frame, s, table, n, 2 * per_star, min_set, sets_per_scale,
                                                time_limit_s, progress))
    result, sparse = judged(frame, table, sets, max_candidates=max_candidates, n_stars=n,
                            tolerance_rad=s.noise_px / s.f0, centroid_sigma_px=centroid_sigma_px,
                            work=lambda: progress.steps, threshold=lone_prob_threshold)
    if result.success:
        return dataclasses.replace(result, n_patterns_tried=progress.steps)
    stopped = progress.stopped or f"max_candidates {max_candidates} sets proposed"
    return failure(METHOD, f"no voted set verified: {result.n_candidates} proposed, {stopped}{sparse}",
                   frame.t0,
                   progress.steps, result.n_candidates)
