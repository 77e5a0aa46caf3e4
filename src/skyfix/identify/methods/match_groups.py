"""van Bezooijen's match groups (thesis 004 ch. 3, docs/identification-methods.md#van-bezooijen).

The Sunsat star sensor identified up to eight observed stars by the *largest group of mutually
consistent matches* — the one method of its time robust to false stars (meteors, planets,
satellites). skyfix follows its five steps on the shared pair table
(:func:`skyfix.identify.catalogue.pairs.pair_table`, the thesis's sorted distance table):

1. **Star-pair matching** (§3.3.1). Every pair of the ``pair_stars`` brightest centroids (at most
   28 for eight) finds the catalogue pairs whose angle is its own ± the distance tolerance
   (:func:`~skyfix.identify.catalogue.pairs.pairs_in_range`), each in both orientations that pass the
   magnitude test: ``|m_obs − m_cat| ≤ magnitude_tolerance`` for each star when ``magnitudes``
   are given (the thesis's (3.1)), else the brightness order standing in for them (the brighter
   centroid's star may be at most ``magnitude_tolerance`` fainter than the other's).
2. **Match groups and elimination** (§3.3.1–3.3.2). Every distinct match (centroid ``k`` is
   catalogue star ``g``) is the *kernel* of a group; its *associated matches* are the other
   ends of the pair matches that contain it; its *confidence* is the number of other centroids
   among them. A true constellation of ``n`` stars gives ``n`` kernels of confidence ``n − 1``:
   ``n`` is estimated as the largest with that many groups, and groups of confidence ≤
   ``ICLim = n − 2`` are removed, with their kernels from every other group's associated
   matches (repeated until nothing changes: a true match is never removed this way). skyfix
   checks the estimate after elimination (:func:`estimated_level`: ``n`` groups must survive),
   since its tolerances and table make high confidences common by chance before it.
3. **Geometry test with splitting, and the mirror test** (§3.3.3). Two associated matches of a
   group must be consistent: different centroids, different stars, and the triangle they make
   with the kernel measured as in the catalogue (one scale for its three angles, within the
   focal range, each within the tolerance) and not mirrored (the triple products of rays and of
   catalogue vectors agree in sign where the noise cannot flip it). A group whose members are
   not all consistent is split into its consistent subgroups — the thesis splits on each
   failing pair ``(x, y)`` into a group without ``x`` and one without ``y``; skyfix enumerates
   the same maximal subgroups directly (Bron–Kerbosch with pivoting on bit masks), without the
   duplicates the splitting makes.
4. **Redundancy removal** (§3.3.4). Subgroups holding the same set of matches are one.
5. **The largest group** (§3.3.5). Subgroups of at least ``min_group`` stars, largest first,
   equal sizes by the smallest sum of |angle measured − angle catalogued| (the thesis's
   tie-break), are proposed in that order to :func:`skyfix.identify.common.hypothesis.first_accepted`
   — the thesis takes the largest group as correct; skyfix accepts it only when it passes the
   rules every method passes (a proper rotation fits, the chance of a wrong match with every
   proposal counted, the refit). When none does, ``ICLim`` is decremented and the groups it
   lets through are proposed, down to ``ICLim = 1`` (thesis: failure when ICLim reaches 1).

The pieces are public for the study to report on: :func:`match_setup`, :func:`match_groups`
(steps 1–2: :func:`pair_matches`, :func:`match_groups`), :func:`geometry_test` (steps 3–5).

Differences from the thesis (and why): the distance tolerance is derived from the centroid
noise (``n_sigma · centroid_sigma_px · √2 / f``), not set in µrad; angles come from unit vectors
(no RA/Dec differences, so no trouble at the poles or at RA 0h — the correction 004's reading
asks for); the Cartesian block expansion of App. D.2 is replaced by the subgroup enumeration of
step 3 (same groups, no exponential copy); a group is accepted only after verification. The
thesis's sensor knew its focal length; with only a field of view, skyfix searches the focal
range in pieces ``scale_step`` wide (:func:`scale_ranges`, the nominal focal length's first):
one search over the whole range would find ~1.5 M pair matches at 15° ± 10 % and groups mostly
of chance. Groups of ``prompt_group`` stars are proposed as soon as their piece is searched;
smaller ones once every piece has been, largest first.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.rotation import chord_angle, det3
from skyfix.camera import Camera
from skyfix.errors import InputError
from skyfix.identify.accept import CENTROID_SIGMA_PX, PROB_THRESHOLD
from skyfix.identify.catalogue.database import PatternDatabase
from skyfix.identify.catalogue.pairs import PairTable, pairs_in_range
from skyfix.identify.common.angle_match import LONE_PROB_THRESHOLD, TableRows, frame_table, judged
from skyfix.identify.common.hypothesis import Frame, failure, frame_for
from skyfix.identify.common.result import Identification

__all__ = ["METHOD", "MatchGroups", "MatchSetup", "PairMatches", "Subgroups", "estimated_level",
           "geometry_test", "identify", "match_groups", "match_setup", "pair_matches",
           "scale_ranges"]

METHOD = "van-bezooijen"
MAX_STARS = 62  # centroids a match mask holds (bits of an int64)
_MAX_MEMBERS = 62  # associated matches a group's geometry test holds (bits of an int64)


class MatchSetup(NamedTuple):
    """The observed stars and tolerances of one frame as the match kernels read them.

    rays : (n, 3) — unit rays of the ``n`` brightest centroids (rows of :attr:`Frame.xy`).
    angle_rad : (n, n) — their angles at the frame's nominal focal length.
    tolerance_rad : float — a measured angle's allowed error (the centroid noise's share).
    scale_lo, scale_hi : float — the range of catalogue angle / measured angle the focal range
        allows (1, 1 for a calibrated camera).
    magnitude : (n,) float64 — the centroids' magnitudes (NaN: not known).
    magnitude_tolerance : float — allowed |m_obs − m_cat| (or, by brightness order, how much
        fainter the brighter centroid's star may be).
    by_order : bool — no magnitudes: the brightness order stands in for them.
    """

    rays: np.ndarray
    angle_rad: np.ndarray
    tolerance_rad: float
    scale_lo: float
    scale_hi: float
    magnitude: np.ndarray
    magnitude_tolerance: float
    by_order: bool


class MatchGroups(NamedTuple):
    """Match groups after elimination (steps 1–2); star numbers are rows of the pair table's
    :attr:`~skyfix.identify.catalogue.pairs.PairTable.stars` (``catalogue_rows`` maps them to the star index).

    kernel_star, kernel_local : (K,) int64 — each group's kernel: centroid row and its star.
    start : (K + 1,) int64 — group ``i``'s associated matches are rows ``start[i]:start[i + 1]``
        of ``member_star``, ``member_local``.
    member_star, member_local : (R,) int64 — associated matches.
    confidence : (K,) int64 — the other centroids among each group's associated matches.
    ic_lim : int — the elimination limit applied (groups of confidence ≤ it removed).
    n_estimated : int — the estimated size of the largest true constellation (before elimination).
    n_pair_matches : int — step 1's pair matches (both orientations counted).
    """

    kernel_star: np.ndarray
    kernel_local: np.ndarray
    start: np.ndarray
    member_star: np.ndarray
    member_local: np.ndarray
    confidence: np.ndarray
    ic_lim: int
    n_estimated: int
    n_pair_matches: int


class Subgroups(NamedTuple):
    """Consistent subgroups (steps 3–5), largest first, then by ``residual_rad``.

    catalog : (G, n) int64 — each subgroup's star (row of the star index) for each observed
        centroid, -1 where it has none.
    size : (G,) int64 — matches in each subgroup.
    residual_rad : (G,) float64 — sum over its pairs of |scale · measured − catalogued| angle.
    n_nodes : int — subgroup-enumeration steps spent (work).
    complete : bool — every group was tested within ``max_splits``.
    """

    catalog: np.ndarray
    size: np.ndarray
    residual_rad: np.ndarray
    n_nodes: int
    complete: bool


def match_setup(frame: Frame, *, pair_stars: int = 8, centroid_sigma_px: float = CENTROID_SIGMA_PX,
                n_sigma: float = 3.0, magnitudes: np.ndarray | None = None,
                magnitude_tolerance: float = 0.5) -> MatchSetup:
    """The :class:`MatchSetup` of the ``pair_stars`` brightest centroids of ``frame``.
    ``magnitudes`` are those of :attr:`Frame.xy`'s rows (NaN where unknown)."""
    n = min(len(frame.xy), pair_stars)
    rays = np.ascontiguousarray(frame.rays[:n])
    angle = chord_angle(np.linalg.norm(rays[:, None, :] - rays[None, :, :], axis=2))
    f = float(frame.camera.fx)
    lo, hi = frame.focal_range_px
    # Angles scale ~ 1/f; 2 % of the range's width covers the tangent's departure from it.
    slack = 0.02 * frame.scale_tolerance
    scale_lo, scale_hi = f / hi * (1.0 - slack), f / lo * (1.0 + slack)
    by_order = magnitudes is None
    mag = np.full(n, np.nan) if by_order else np.asarray(magnitudes, np.float64)[:n].copy()
    return MatchSetup(rays, angle, n_sigma * centroid_sigma_px * math.sqrt(2.0) / f, scale_lo, scale_hi, mag,
                      float(magnitude_tolerance), by_order)


def scale_ranges(scale_lo: float, scale_hi: float, step: float) -> list[tuple[float, float]]:
    """The range of scales [``scale_lo``, ``scale_hi``] (catalogue angle / measured angle) cut
    into pieces at most ``step`` wide (relative), overlapping by a tenth, the one holding 1 (the
    nominal focal length) first, then alternately outward."""
    n = max(1, math.ceil(math.log(scale_hi / scale_lo) / math.log1p(step) - 1e-9))
    edges = scale_lo * (scale_hi / scale_lo) ** (np.arange(n + 1) / n)
    pad = 0.05 * (edges[1:] - edges[:-1])
    pieces = [(float(lo - p), float(hi + p)) for lo, hi, p in zip(edges[:-1], edges[1:], pad, strict=True)]
    first = int(np.clip(np.searchsorted(edges, 1.0) - 1, 0, n - 1))
    order = sorted(range(n), key=lambda i: (abs(i - first), i < first))
    return [pieces[i] for i in order]


@njit(cache=True, inline="always")
def _popcount(x):
    n = 0
    while x:
        x &= x - 1
        n += 1
    return n


@njit(cache=True, inline="always")
def _magnitude_ok(setup, cat_mag, a, b, ga, gb):
    """Magnitude test (thesis 004 (3.1)) of centroids ``a`` < ``b`` as stars ``ga``, ``gb`` (of
    magnitudes ``cat_mag``)."""
    tol = setup.magnitude_tolerance
    if setup.by_order:  # a is the brighter centroid
        return cat_mag[ga] <= cat_mag[gb] + tol
    ma, mb = setup.magnitude[a], setup.magnitude[b]
    if ma == ma and abs(ma - cat_mag[ga]) > tol:
        return False
    return not (mb == mb and abs(mb - cat_mag[gb]) > tol)


@njit(cache=True)
def _pair_matches(setup, angle_rad, rows, records):
    """Step 1: every pair match (centroid a < b, table rows la, lb) written to ``records`` while
    it has room. Returns the number of pair matches (each orientation counted)."""
    n = setup.angle_rad.shape[0]
    count = 0
    cap = records.shape[0]
    for a in range(n):
        for b in range(a + 1, n):
            d = setup.angle_rad[a, b]
            s, e = pairs_in_range(angle_rad, d * setup.scale_lo - setup.tolerance_rad,
                                  d * setup.scale_hi + setup.tolerance_rad)
            for p in range(s, e):
                for o in range(2):
                    la = rows.first[p] if o == 0 else rows.second[p]
                    lb = rows.second[p] if o == 0 else rows.first[p]
                    if not _magnitude_ok(setup, rows.magnitude, a, b, la, lb):
                        continue
                    if count < cap:
                        records[count, 0], records[count, 1] = a, la
                        records[count, 2], records[count, 3] = b, lb
                    count += 1
    return count


@njit(cache=True)
def _run_lengths(setup, angle_rad):
    """The catalogue pairs step 1 examines (an upper bound on half its pair matches)."""
    n = setup.angle_rad.shape[0]
    total = 0
    for a in range(n):
        for b in range(a + 1, n):
            d = setup.angle_rad[a, b]
            s, e = pairs_in_range(angle_rad, d * setup.scale_lo - setup.tolerance_rad,
                                  d * setup.scale_hi + setup.tolerance_rad)
            total += e - s
    return total


@njit(cache=True)
def _confidence(records, n_stars, n_local, alive):
    """Each match's confidence: the other centroids it is paired with among ``records`` whose
    both matches are ``alive`` (all when ``alive`` is empty); and those records."""
    masks = np.zeros((n_stars, n_local), np.int64)
    keep = np.empty(records.shape[0], np.bool_)
    check = alive.shape[0] > 0
    for i in range(records.shape[0]):
        a, la, b, lb = records[i, 0], records[i, 1], records[i, 2], records[i, 3]
        keep[i] = not check or (alive[a, la] and alive[b, lb])
        if keep[i]:
            masks[a, la] |= np.int64(1) << b
            masks[b, lb] |= np.int64(1) << a
    conf = np.zeros((n_stars, n_local), np.int64)
    for a in range(n_stars):
        for la in range(n_local):
            if masks[a, la]:
                conf[a, la] = _popcount(masks[a, la])
    return conf, keep


@njit(cache=True)
def _eliminate(records, conf, limit):
    """Step 2's elimination: drop matches of confidence ≤ ``limit`` and the pair matches that
    hold them, recount, until nothing changes. Returns the records kept and the confidences."""
    n, n_local = conf.shape
    alive = conf > limit
    while True:
        conf, keep = _confidence(records, n, n_local, alive)
        kept = np.empty((keep.sum(), 4), records.dtype)
        j = 0
        for i in range(records.shape[0]):
            if keep[i]:
                kept[j] = records[i]
                j += 1
        records = kept
        changed = False
        for a in range(n):
            for la in range(n_local):
                if alive[a, la] and conf[a, la] <= limit:
                    alive[a, la] = False
                    changed = True
        if not changed:
            return records, conf


class PairMatches(NamedTuple):
    """Step 1's pair matches of one frame.

    records : (P, 4) int32 — (centroid a, table row of its star, centroid b > a, table row).
    confidence : (n, T) int64 — each match's confidence (centroids it is paired with).
    n_estimated : int — the largest ``n`` with at least ``n`` matches of confidence ≥ ``n − 1``:
        the thesis's estimate of the largest true constellation.
    n_pair_matches : int — pair matches found (more than ``records`` holds when the bound was hit).
    """

    records: np.ndarray
    confidence: np.ndarray
    n_estimated: int
    n_pair_matches: int


def pair_matches(setup: MatchSetup, table: PairTable, rows: TableRows, *,
                 max_pair_matches: int = 1_000_000) -> PairMatches:
    """Step 1: the catalogue pairs of every pair of observed stars, in both orientations that
    pass the magnitude test. ``max_pair_matches`` bounds the work: beyond it no record is kept
    (``n_pair_matches`` says how many catalogue pairs, both orientations, step 1 would examine)."""
    n, n_local = len(setup.rays), len(table.stars)
    bound = 2 * int(_run_lengths(setup, table.angle_rad))
    if bound > max_pair_matches:
        return PairMatches(np.zeros((0, 4), np.int32), np.zeros((n, n_local), np.int64), 0, bound)
    records = np.empty((bound, 4), np.int32)
    count = _pair_matches(setup, table.angle_rad, rows, records)
    records = records[:count]
    conf, _ = _confidence(records, n, n_local, np.zeros((0, 0), np.bool_))
    at_least = np.cumsum(np.bincount(conf.ravel(), minlength=n + 1)[::-1])[::-1]  # [c]: confidence >= c
    n_est = next((k for k in range(n, 1, -1) if at_least[k - 1] >= k), 2)
    return PairMatches(records, conf, n_est, int(count))


def estimated_level(matches: PairMatches, *, min_size: int = 3) -> int | None:
    """The thesis's ICLim = ``n − 2`` for the estimated size ``n`` of the largest constellation,
    checked after elimination: the largest ``n`` from :attr:`PairMatches.n_estimated` down to
    ``min_size`` for which ``n`` groups survive elimination at ``n − 2`` (a true constellation
    of ``n`` stars always leaves its ``n`` kernels; with skyfix's wider tolerances and denser
    table, chance alone gives many groups a high confidence before elimination, not after).
    None when no ``n`` does."""
    for n in range(matches.n_estimated, max(min_size, 3) - 1, -1):
        _, conf = _eliminate(matches.records, matches.confidence, n - 2)
        if (conf > n - 2).sum() >= n:
            return n - 2
    return None


def match_groups(matches: PairMatches, *, ic_lim: int | None = None) -> MatchGroups:
    """Step 2: the match groups of ``matches`` after elimination at ``ic_lim`` (default
    :func:`estimated_level`, else 1): groups of confidence ≤ ``ic_lim`` are removed with their
    kernels from the others' associated matches until none is left to remove."""
    limit = int(ic_lim) if ic_lim is not None else (estimated_level(matches) or 1)
    records, conf = _eliminate(matches.records, matches.confidence, limit)
    n_local = matches.confidence.shape[1]
    directed = np.concatenate([records, records[:, [2, 3, 0, 1]]]).astype(np.int64)
    key = directed[:, 0] * n_local + directed[:, 1]
    order = np.argsort(key, kind="stable")
    directed, key = directed[order], key[order]
    first = np.flatnonzero(np.r_[True, key[1:] != key[:-1]]) if len(key) else np.zeros(0, np.int64)
    start = np.r_[first, len(key)].astype(np.int64)
    kernel_star, kernel_local = directed[first, 0], directed[first, 1]
    return MatchGroups(kernel_star, kernel_local, start, directed[:, 2].copy(), directed[:, 3].copy(),
                       conf[kernel_star, kernel_local], limit, matches.n_estimated, matches.n_pair_matches)


@njit(cache=True, inline="always")
def _cat_angle(vectors, g1, g2):
    d = 0.0
    for i in range(3):
        x = vectors[g1, i] - vectors[g2, i]
        d += x * x
    return chord_angle(math.sqrt(d))


@njit(cache=True, inline="always")
def _scale_interval(measured, catalogued, tol, lo, hi):
    """Narrow [lo, hi] to the scales at which ``measured`` becomes ``catalogued`` within ``tol``."""
    if measured <= 0.0:
        return lo, hi
    return max(lo, (catalogued - tol) / measured), min(hi, (catalogued + tol) / measured)


@njit(cache=True)
def _mirrored(setup, vectors, k, gk, x, gx, y, gy, c_kx, c_ky, c_xy):
    """The mirror test (thesis 004 (3.3)) on unit vectors: the triangle (k, x, y) is mirrored when
    the triple products of rays and of catalogue vectors differ in sign by more than the
    tolerance can make them (each vertex moved by ``tol`` changes it by at most ``tol`` times the
    opposite side)."""
    m = np.empty((3, 3))
    for i in range(3):
        m[0, i], m[1, i], m[2, i] = setup.rays[k, i], setup.rays[x, i], setup.rays[y, i]
    t_obs = det3(m)
    for i in range(3):
        m[0, i], m[1, i], m[2, i] = vectors[gk, i], vectors[gx, i], vectors[gy, i]
    t_cat = det3(m)
    thr = setup.tolerance_rad * (c_kx + c_ky + c_xy) * setup.scale_hi
    return t_obs * t_cat < 0.0 and abs(t_obs) > thr and abs(t_cat) > thr


@njit(cache=True)
def _consistent(setup, vectors, k, gk, x, gx, y, gy, check_mirror):
    """Step 3's test of two associated matches (x, gx), (y, gy) of the kernel (k, gk)."""
    if x == y or gx == gy:
        return False
    tol = setup.tolerance_rad
    c_kx, c_ky, c_xy = _cat_angle(vectors, gk, gx), _cat_angle(vectors, gk, gy), _cat_angle(vectors, gx, gy)
    lo, hi = _scale_interval(setup.angle_rad[k, x], c_kx, tol, setup.scale_lo, setup.scale_hi)
    lo, hi = _scale_interval(setup.angle_rad[k, y], c_ky, tol, lo, hi)
    lo, hi = _scale_interval(setup.angle_rad[x, y], c_xy, tol, lo, hi)
    if lo > hi:
        return False
    return not (check_mirror and _mirrored(setup, vectors, k, gk, x, gx, y, gy, c_kx, c_ky, c_xy))


@njit(cache=True)
def _residual(setup, vectors, row):
    """Sum over the matched pairs of |scale · measured − catalogued| at the best single scale."""
    n = row.shape[0]
    sm, sc = 0.0, 0.0
    for i in range(n):
        for j in range(i + 1, n):
            if row[i] >= 0 and row[j] >= 0:
                sm += setup.angle_rad[i, j]
                sc += _cat_angle(vectors, row[i], row[j])
    s = min(max(sc / sm, setup.scale_lo), setup.scale_hi) if sm > 0.0 else 1.0
    r = 0.0
    for i in range(n):
        for j in range(i + 1, n):
            if row[i] >= 0 and row[j] >= 0:
                r += abs(s * setup.angle_rad[i, j] - _cat_angle(vectors, row[i], row[j]))
    return r


@njit(cache=True)
def _subgroups(setup, vectors, stars, kernel_star, kernel_local, start, member_star, member_local,
               check_mirror, min_size, max_nodes, out, out_size, out_residual):
    """Steps 3: each group's maximal consistent subgroups (Bron–Kerbosch with pivoting on bit
    masks of its associated matches) of at least ``min_size`` matches, written to ``out`` (rows:
    star per centroid). Returns (subgroups written, nodes spent, complete)."""
    n = setup.angle_rad.shape[0]
    n_out = 0
    nodes = 0
    adj = np.zeros(_MAX_MEMBERS, np.int64)
    stack = np.zeros((64 * _MAX_MEMBERS, 3), np.int64)
    for gi in range(kernel_star.shape[0]):
        k, gk = kernel_star[gi], stars[kernel_local[gi]]
        s = start[gi]
        m = min(start[gi + 1] - s, _MAX_MEMBERS)
        if m + 1 < min_size:
            continue
        for i in range(m):
            adj[i] = 0
        for i in range(m):
            xi, gxi = member_star[s + i], stars[member_local[s + i]]
            for j in range(i + 1, m):
                if _consistent(setup, vectors, k, gk, xi, gxi, member_star[s + j], stars[member_local[s + j]],
                               check_mirror):
                    adj[i] |= np.int64(1) << j
                    adj[j] |= np.int64(1) << i
        full = (np.int64(1) << m) - 1
        top = 0
        stack[0, 0], stack[0, 1], stack[0, 2] = 0, full, 0
        top = 1
        while top > 0:
            top -= 1
            r, p, x = stack[top, 0], stack[top, 1], stack[top, 2]
            nodes += 1
            if nodes > max_nodes:
                return n_out, nodes, False
            if _popcount(r) + _popcount(p) + 1 < min_size:
                continue
            if p == 0:
                if x == 0 and n_out < out.shape[0]:
                    for i in range(n):
                        out[n_out, i] = -1
                    out[n_out, k] = gk
                    size = 1
                    for i in range(m):
                        if (r >> i) & 1:
                            out[n_out, member_star[s + i]] = stars[member_local[s + i]]
                            size += 1
                    out_size[n_out] = size
                    out_residual[n_out] = _residual(setup, vectors, out[n_out])
                    n_out += 1
                continue
            # pivot: the vertex of P ∪ X with the most neighbours in P
            px = p | x
            best, pivot = -1, 0
            for u in range(m):
                if (px >> u) & 1:
                    c = _popcount(p & adj[u])
                    if c > best:
                        best, pivot = c, u
            cand = p & ~adj[pivot]
            for v in range(m):
                if (cand >> v) & 1 and top < stack.shape[0]:
                    bit = np.int64(1) << v
                    stack[top, 0], stack[top, 1], stack[top, 2] = r | bit, p & adj[v], x & adj[v]
                    top += 1
                    p &= ~bit
                    x |= bit
    return n_out, nodes, True


def geometry_test(frame: Frame, setup: MatchSetup, table: PairTable, groups: MatchGroups, *,
                  check_mirror: bool = True, min_size: int = 3, max_splits: int = 200_000,
                  max_subgroups: int = 20_000) -> Subgroups:
    """Steps 3–5: each group split into its consistent, unmirrored subgroups of at least
    ``min_size`` matches; duplicates removed; largest first, then by the smallest angle
    residual. ``max_splits`` bounds the enumeration's steps, ``max_subgroups`` its output."""
    n = len(setup.rays)
    out = np.empty((max_subgroups, n), np.int64)
    size = np.empty(max_subgroups, np.int64)
    resid = np.empty(max_subgroups)
    vectors = frame.stars.vectors
    k, nodes, complete = _subgroups(setup, vectors, table.stars.astype(np.int64), groups.kernel_star,
                                    groups.kernel_local, groups.start, groups.member_star,
                                    groups.member_local, check_mirror, min_size, max_splits, out, size, resid)
    out, size, resid = out[:k], size[:k], resid[:k]
    order = np.lexsort(out.T[::-1])  # identical subgroups side by side
    fresh = np.r_[True, (out[order[1:]] != out[order[:-1]]).any(axis=1)] if k else np.zeros(0, np.bool_)
    first = order[fresh]
    first = first[np.lexsort((resid[first], -size[first]))]
    return Subgroups(out[first], size[first], resid[first], int(nodes), bool(complete and k < max_subgroups))


def identify(xy: np.ndarray, width: int, height: int, *, fov_deg: float | None = None,
             fov_tolerance_deg: float | None = None, camera: Camera | None = None,
             database: PatternDatabase | None = None, epoch: float | None = None, pair_stars: int = 8,
             centroid_sigma_px: float = CENTROID_SIGMA_PX, n_sigma: float = 3.0,
             magnitudes: np.ndarray | None = None, magnitude_tolerance: float = 0.5,
             check_mirror: bool = True, min_group: int = 3,
             max_candidates: int = 200, max_pair_matches: int = 1_000_000,
             max_splits: int = 50_000, scale_step: float = 0.01, prompt_group: int = 5,
             time_limit_s: float = 2.0, lone_prob_threshold: float = LONE_PROB_THRESHOLD,
             prob_threshold: float = PROB_THRESHOLD) -> Identification:
    """Identify the stars of one frame by van Bezooijen's match groups (the module text).

    Parameters
    ----------
    xy, width, height, fov_deg, fov_tolerance_deg, camera, database, epoch
        The interface's (:mod:`skyfix.identify.methods`); a camera or a FOV is needed.
    pair_stars : int
        The brightest centroids matched (thesis: 8, its optimum; at most 62).
    centroid_sigma_px : float
        Centroid noise per axis, pixels; with ``n_sigma`` it sets the distance tolerance
        ``n_sigma · centroid_sigma_px · √2 / f`` (thesis: d_uncert, 50–200 µrad).
    n_sigma : float
        Tolerance in standard deviations.
    magnitudes : (N,) float, optional
        The centroids' magnitudes on the catalogue's scale (rows of ``xy``; NaN: unknown).
        Without them the brightness order of ``xy`` stands in.
    magnitude_tolerance : float
        Mv_uncert (thesis: 0.3–0.6): allowed |m_obs − m_cat|, or by brightness order how much
        fainter the brighter centroid's star may be.
    check_mirror : bool
        Apply the mirror test in the geometry test (the verification rejects mirrors anyway).
    min_group : int
        Smallest group proposed (thesis: 3, failure when ICLim reaches 1).
    prompt_group : int
        Groups this large are proposed as soon as their piece of the focal range is searched
        (chance rarely makes one); smaller ones wait until every piece has been.
    max_candidates : int
        Work bound: groups proposed to the verification.
    max_pair_matches : int
        Work bound: step 1's pair matches (a frame beyond it fails with the reason).
    max_splits : int
        Work bound: subgroup-enumeration steps per elimination level.
    time_limit_s : float
        Work bound: no further piece or level is searched after this long (s, counted from the
        end of the first geometry test: the kernels' first load is not counted).
    scale_step : float
        With a FOV only, the focal range is searched in pieces this wide (relative), the nominal
        focal length's first: step 1 over the whole range at once would find ~1.5 M pair
        matches at 15° ± 10 %, and its groups would be mostly chance.
    prob_threshold : float
        The largest chance of a false match accepted (accept rule 5; every method's, default 1e-9).
    lone_prob_threshold : float
        A sparse frame (at most 8 centroids) whose groups the common rules refused (too few
        stars beyond a group to verify it at 1e-9): the largest chance of a wrong match accepted
        when each group's triangle is judged by the ``triangle`` method's sparse-frame rules
        (:func:`skyfix.identify.common.angle_match.sparse_identification`).

    Returns
    -------
    Identification
        Success with the matched stars and attitude, or the reason it failed.

    Raises
    ------
    skyfix.errors.InputError
        ``magnitudes`` not one per centroid, or ``pair_stars`` outside 2–62.
    skyfix.errors.CameraError
        An impossible ``fov_deg``.
    """
    t0 = time.perf_counter()
    if not 2 <= int(pair_stars) <= MAX_STARS:
        raise InputError(f"pair_stars must be 2–{MAX_STARS}, not {pair_stars}")
    frame = frame_for(METHOD, xy, width, height, fov_deg=fov_deg, fov_tolerance_deg=fov_tolerance_deg,
                      camera=camera, database=database, epoch=epoch, min_stars=3,
                      prob_threshold=prob_threshold, centroid_sigma_px=centroid_sigma_px)
    if isinstance(frame, Identification):
        return frame
    if magnitudes is not None:
        magnitudes = np.asarray(magnitudes, np.float64).ravel()
        n_rows = len(frame.xy) if frame.kept is None else len(np.asarray(xy, np.float64).reshape(-1, 2))
        if len(magnitudes) != n_rows:
            raise InputError(f"magnitudes must be one per centroid ({len(magnitudes)} given for {n_rows} "
                             "centroids)")
        if frame.kept is not None:
            magnitudes = magnitudes[frame.kept]
    setup = match_setup(frame, pair_stars=pair_stars, centroid_sigma_px=centroid_sigma_px, n_sigma=n_sigma,
                        magnitudes=magnitudes, magnitude_tolerance=magnitude_tolerance)
    table, rows = frame_table(frame)
    work = {"pairs": 0, "over": 0, "ranges": 0, "late": 0, "start": 0.0}

    def late() -> bool:
        # the clock starts once a geometry test has run (every kernel then loaded or compiled)
        work["late"] = bool(work["start"]) and time.perf_counter() - work["start"] > time_limit_s
        return bool(work["late"])

    def tested(part: MatchSetup, groups: MatchGroups, min_size: int) -> Subgroups:
        sub = geometry_test(frame, part, table, groups, check_mirror=check_mirror, min_size=min_size,
                            max_splits=max_splits)
        work["start"] = work["start"] or time.perf_counter()
        return sub

    def proposals() -> Iterator[tuple[np.ndarray, np.ndarray]]:
        # Largest groups first across the pieces of the focal range (one piece when calibrated):
        # a piece's groups of prompt_group stars or more (a constellation chance does not make)
        # as soon as the piece is searched; once every piece is, the rest at each piece's first
        # ICLim, all pieces' together by size, then residual; then every piece at each lower
        # ICLim in turn.
        seen: set[bytes] = set()

        def fresh(sub: Subgroups, keep: np.ndarray) -> Iterator[tuple[np.ndarray, np.ndarray]]:
            for row in sub.catalog[keep]:
                key = row.tobytes()
                if key not in seen:
                    seen.add(key)
                    stars = np.flatnonzero(row >= 0)
                    yield stars, row[stars]

        pieces = []
        for scale_lo, scale_hi in scale_ranges(setup.scale_lo, setup.scale_hi, scale_step):
            if late():
                return
            part = setup._replace(scale_lo=scale_lo, scale_hi=scale_hi)
            matches = pair_matches(part, table, rows, max_pair_matches=max_pair_matches)
            work["ranges"] += 1
            work["pairs"] += matches.n_pair_matches
            if matches.n_pair_matches > max_pair_matches:
                work["over"] += 1
                continue
            pieces.append((part, matches))
            level = estimated_level(matches, min_size=prompt_group)
            if level is not None:
                sub = tested(part, match_groups(matches, ic_lim=level), level + 2)
                yield from fresh(sub, sub.size >= level + 2)
        tops, subs = [], []
        for part, matches in pieces:
            if late():
                return
            tops.append(estimated_level(matches) or 1)
            subs.append(tested(part, match_groups(matches, ic_lim=tops[-1]), min_group))
        if subs:  # every piece's groups together: largest first, then the smallest residual
            merged = Subgroups(np.concatenate([sub.catalog for sub in subs]),
                               np.concatenate([sub.size for sub in subs]),
                               np.concatenate([sub.residual_rad for sub in subs]), 0, True)
            order = np.lexsort((merged.residual_rad, -merged.size))
            yield from fresh(merged._replace(catalog=merged.catalog[order], size=merged.size[order]),
                             np.ones(len(order), np.bool_))
        for drop in range(1, len(setup.rays)):
            for (part, matches), top in zip(pieces, tops, strict=True):
                if late():
                    return
                if top - drop >= 1:
                    sub = tested(part, match_groups(matches, ic_lim=top - drop), min_group)
                    yield from fresh(sub, sub.size > 0)

    result, sparse = judged(frame, table, proposals(), max_candidates=max_candidates, n_stars=len(setup.rays),
                            tolerance_rad=setup.tolerance_rad, centroid_sigma_px=centroid_sigma_px,
                            work=lambda: work["ranges"], threshold=lone_prob_threshold)
    if not result.success:
        if work["late"]:
            reason = (f"time limit ({time_limit_s} s) reached after {result.n_candidates} groups proposed "
                      f"over {work['ranges']} focal-length ranges")
        elif work["over"] and work["over"] == work["ranges"]:
            reason = (f"step 1 would examine {work['pairs']} pair matches, beyond max_pair_matches "
                      f"({max_pair_matches}): tolerances too wide")
        else:
            reason = (f"no match group verified ({result.n_candidates} proposed, {work['pairs']} pair "
                      f"matches over {work['ranges']} focal-length ranges){sparse}")
        return failure(METHOD, reason, t0, work["ranges"], result.n_candidates)
    return result
