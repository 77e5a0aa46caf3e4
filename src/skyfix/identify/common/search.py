"""The compiled inner loop of the 4-star search: image patterns -> candidate catalogue patterns.

For each image 4-star combination (in the breadth-first order the caller gives), the kernel
computes the edge ratios from camera rays at an assumed focal length, probes every key bin
within the tolerance, walks the hash table, keeps catalogue patterns whose ratios agree, then
estimates the focal length from the ratio of largest edges, recomputes the image ratios at that
focal length and keeps the pattern only if they agree tightly and the focal length is allowed.
The data it reads and returns are the named tuples of :mod:`skyfix.identify.catalogue.kernel_data`; the
rules that accept or reject a candidate are the helpers of :mod:`skyfix.identify.accept` it calls
(rules 1–5 there).
"""

from __future__ import annotations

import math
from itertools import chain, combinations, permutations

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.lens import offset_ray
from skyfix._kernels.rotation import chord_angle, proper_rotation
from skyfix.identify.accept import (
    QUICK_CATALOG_STARS,
    QUICK_CENTROIDS,
    focal_allowed,
    is_verified,
    log_prob_false,
    no_rotation_fits,
    pattern_fits,
    quick_check_fails,
    ratio_tolerance,
)
from skyfix.identify.catalogue.hashing import lookup_run
from skyfix.identify.catalogue.kernel_data import (
    FocalRange,
    ImageStars,
    PatternTable,
    SearchResult,
    StarIndex,
    Tolerances,
    VerifySettings,
    ViewBuffers,
)
from skyfix.identify.common.verify import verify_attitude

__all__ = ["breadth_first_combinations", "centre_first_combinations", "search", "search_entry"]

_COMBOS: dict[int, np.ndarray] = {}
_COMBO_ROWS: dict[int, tuple[np.ndarray, np.ndarray]] = {}
_PERMS = np.array(list(permutations(range(4))), dtype=np.int64)  # (24, 4): every vertex correspondence


def breadth_first_combinations(n: int) -> np.ndarray:
    """All 4-subsets of ``range(n)`` ordered so that those of the brightest stars come first.

    Subsets are sorted by their largest member, then lexicographically: every subset of the
    first ``m`` stars precedes any subset that uses star ``m``.
    """
    if n not in _COMBOS:
        # the 3-subsets of range(n) in lexicographic order; those below m, still in that
        # order, then m (an n⁴ grid sorted took 60 ms at n = 30, this 2 ms)
        triples = np.fromiter(chain.from_iterable(combinations(range(n), 3)), dtype=np.int64,
                              count=3 * math.comb(n, 3)).reshape(-1, 3)
        out = np.empty((math.comb(n, 4), 4), dtype=np.int64)
        row = 0
        for m in range(3, n):
            below = triples[triples[:, 2] < m]
            out[row:row + len(below), :3] = below
            out[row:row + len(below), 3] = m
            row += len(below)
        _COMBOS[n] = out
    return _COMBOS[n]


def centre_first_combinations(central: np.ndarray, count: int | None = None) -> np.ndarray:
    """The 4-subsets of the ``n = len(central)`` brightest stars in two breadth-first orders
    interleaved: over the stars by brightness (:func:`breadth_first_combinations`) and over them
    with the ``central`` ones (bool, (n,)) first, each group by brightness; every subset at the
    earlier of its two places (ties: the brightness order's). All of them, or the first
    ``count`` (a search that finds its frame early needs no more). A wide, distorted frame's
    central stars keep their shapes under any distortion hypothesis, and a database field about
    the boresight holds their brightest; the brightness order's patterns still come no more
    than twice as late."""
    n = len(central)
    base = breadth_first_combinations(n)
    if n not in _COMBO_ROWS:
        binom = np.array([[math.comb(i, k) for k in range(5)] for i in range(n)], dtype=np.int64)
        rows = np.empty(math.comb(n, 4), dtype=np.int64)
        rows[_colex_rank(base, binom)] = np.arange(len(base))
        _COMBO_ROWS[n] = (binom, rows)
    binom, rows = _COMBO_ROWS[n]
    order = np.argsort(~np.asarray(central, dtype=bool), kind="stable")  # central first, by brightness
    return _interleaved(base, order, binom, rows, len(base) if count is None else min(count, len(base)))


@njit(cache=True)
def _interleaved(base, order, binom, rows, count):
    """The first ``count`` of ``base``'s rows in the order ``base[0], other[0], base[1], other[1],
    ...`` without repeats, ``other[j]`` the row of ``base`` holding the stars ``order[base[j]]``
    (``rows``: colex rank -> row of ``base``; ``binom``: C(i, k))."""
    n = len(base)
    out = np.empty((count, 4), dtype=base.dtype)
    seen = np.zeros(n, dtype=np.bool_)
    k = 0
    for j in range(n):
        if k >= count:
            break
        if not seen[j]:
            seen[j] = True
            out[k] = base[j]
            k += 1
        a, b, c, d = order[base[j, 0]], order[base[j, 1]], order[base[j, 2]], order[base[j, 3]]
        a, b = min(a, b), max(a, b)  # a sorting network: a <= b <= c <= d
        c, d = min(c, d), max(c, d)
        a, c = min(a, c), max(a, c)
        b, d = min(b, d), max(b, d)
        b, c = min(b, c), max(b, c)
        row = rows[binom[a, 1] + binom[b, 2] + binom[c, 3] + binom[d, 4]]
        if not seen[row] and k < count:
            seen[row] = True
            out[k] = base[row]
            k += 1
    return out


def _colex_rank(combos: np.ndarray, binom: np.ndarray) -> np.ndarray:
    """The colexicographic rank of each ascending 4-subset row of ``combos`` (C(c0,1) + C(c1,2) +
    C(c2,3) + C(c3,4)), from the binomial table ``binom[i, k] = C(i, k)``."""
    return (binom[combos[:, 0], 1] + binom[combos[:, 1], 2] + binom[combos[:, 2], 3]
            + binom[combos[:, 3], 4])


@njit(cache=True)
def _pattern_edges(p: np.ndarray, combo: np.ndarray, f: float, out: np.ndarray) -> None:
    """Sorted six edge angles (radians) of image stars ``combo`` at focal length ``f`` (pixels)."""
    rays = np.empty((4, 3))
    for a in range(4):
        rays[a, 0], rays[a, 1], rays[a, 2] = offset_ray(p[combo[a], 0], p[combo[a], 1], f)
    e = 0
    for a in range(4):
        for b in range(a + 1, 4):
            dx = rays[a, 0] - rays[b, 0]
            dy = rays[a, 1] - rays[b, 1]
            dz = rays[a, 2] - rays[b, 2]
            out[e] = chord_angle(np.sqrt(dx * dx + dy * dy + dz * dz))
            e += 1
    out.sort()


@njit(cache=True)
def _kabsch(b: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Proper rotation A minimising Σ|b − A r|² (det A = +1, so mirror images fit badly).

    The small products are written out: BLAS calls cost more than the arithmetic here.
    """
    B = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for a in range(len(b)):
                acc += b[a, i] * r[a, j]
            B[i, j] = acc
    return proper_rotation(B)


@njit(cache=True)
def _angle_matrix(v: np.ndarray, out: np.ndarray) -> None:
    for a in range(4):
        out[a, a] = 0.0
        for b in range(a + 1, 4):
            dx = v[a, 0] - v[b, 0]
            dy = v[a, 1] - v[b, 1]
            dz = v[a, 2] - v[b, 2]
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            out[a, b] = out[b, a] = chord_angle(d)


@njit(cache=True)
def search_entry(image, combos, start, stop, focal, tolerances, patterns, stars, verification, cand_before):
    """:func:`search` with its NamedTuple arguments as plain tuples (``tuple(nt)``): the entry
    for Python callers (:mod:`skyfix.identify.catalogue.kernel_data` says why)."""
    return search(ImageStars(*image), combos, start, stop, FocalRange(*focal), Tolerances(*tolerances),
                  PatternTable(*patterns), StarIndex(*stars), VerifySettings(*verification), cand_before)


@njit(cache=True)
def search(image, combos, start, stop, focal, tolerances, patterns, stars, verification, cand_before):
    """Search image combinations ``start:stop`` for a verified catalogue pattern.

    Parameters
    ----------
    image : ImageStars — the centroids as undistorted offsets from the principal point
        (``x_n · f0``), brightest first, and the frame's extent.
    combos : (C, 4) int64 — image-star index quadruples, in search order.
    start, stop : int — the combinations to search.
    focal : FocalRange — the assumed focal length and the allowed range.
    tolerances : Tolerances — the ratio tolerances of the key probe and of the tight check
        (:func:`skyfix.identify.accept.ratio_tolerance`).
    patterns : PatternTable — the database's patterns and hash table.
    stars : StarIndex — the database's sky-cell index of all stars (verification).
    verification : VerifySettings — stars matched, match radius, acceptance threshold.
    cand_before : int — candidates verified by earlier calls (the look-elsewhere count).

    Returns
    -------
    SearchResult
    """
    p = image.offsets_px
    f0, f_lo, f_hi, fix_focal = focal
    eps_key, sigma_px, model_err = tolerances
    n_bins = patterns.n_bins
    table, key_codes, key_start = patterns.table, patterns.key_codes, patterns.key_start
    pattern_ratios, pattern_largest, pattern_stars = patterns.ratios, patterns.largest_rad, patterns.stars
    star_vectors = stars.vectors
    n_verify, radius_px, log_threshold = verification
    perms = _PERMS
    edges = np.empty(6)
    edges1 = np.empty(6)
    ratios = np.empty(5)
    runs = np.empty((1024, 2), dtype=np.int64)
    lo = np.empty(5, dtype=np.int64)
    hi = np.empty(5, dtype=np.int64)
    cur = np.empty(5, dtype=np.int64)
    weights = np.empty(5, dtype=np.int64)
    w = 1
    for i in range(5):
        weights[i] = w
        w *= n_bins
    b = np.empty((4, 3))
    r = np.empty((4, 3))
    rp = np.empty((4, 3))
    ai = np.empty((4, 4))
    ac = np.empty((4, 4))
    n_img = min(n_verify, len(p))
    view = ViewBuffers(np.empty(8192, dtype=np.int64), np.empty(8192), np.empty(8192),
                       np.zeros(n_img, dtype=np.bool_), np.empty(8192, dtype=np.int64))
    n_cand = 0
    n_compared = 0
    for c in range(start, stop):
        combo = combos[c]
        _pattern_edges(p, combo, f0, edges)
        largest = edges[5]
        if largest <= 0.0:
            continue
        for i in range(5):
            rr = edges[i] / largest
            ratios[i] = rr
            lo[i] = max(0, min(n_bins - 1, np.int64((rr - eps_key) * n_bins)))
            hi[i] = max(0, min(n_bins - 1, np.int64((rr + eps_key) * n_bins)))
            cur[i] = lo[i]
        # Every key code in the box lo..hi (an odometer over the five bins); each code's
        # patterns are one contiguous run.
        n_runs = 0
        while True:
            code = np.int64(0)
            ok = True
            for i in range(5):
                if i > 0 and cur[i] < cur[i - 1]:
                    ok = False  # sorted ratios have non-decreasing bins
                code += cur[i] * weights[i]
            if ok:
                r0, r1 = lookup_run(code, table, key_codes, key_start)
                if r1 > r0 and n_runs < len(runs):
                    runs[n_runs, 0] = r0
                    runs[n_runs, 1] = r1
                    n_runs += 1
            i = 0
            while i < 5:
                cur[i] += 1
                if cur[i] <= hi[i]:
                    break
                cur[i] = lo[i]
                i += 1
            if i == 5:
                break
        x0, x1, x2, x3, x4 = ratios[0], ratios[1], ratios[2], ratios[3], ratios[4]
        for k in range(n_runs):
            n_compared += runs[k, 1] - runs[k, 0]
            for q in range(runs[k, 0], runs[k, 1]):
                # Branch-free: about 40 % of patterns pass each ratio, so an early exit per ratio
                # mispredicts; the five differences and their maximum cost less.
                dev = max(max(max(abs(x0 - pattern_ratios[q, 0]), abs(x1 - pattern_ratios[q, 1])),
                              max(abs(x2 - pattern_ratios[q, 2]), abs(x3 - pattern_ratios[q, 3]))),
                          abs(x4 - pattern_ratios[q, 4]))
                if dev > eps_key:
                    continue
                # Focal length from the largest edges (angles scale ~ 1/f), refined once.
                if fix_focal:
                    f1 = f0
                else:
                    f1 = f0 * largest / pattern_largest[q]
                    _pattern_edges(p, combo, f1, edges1)
                    f1 = f1 * edges1[5] / pattern_largest[q]
                if not focal_allowed(f1, f_lo, f_hi):  # accept rule 2
                    continue
                _pattern_edges(p, combo, f1, edges1)
                tol = ratio_tolerance(sigma_px, edges1[5], f1, model_err)  # accept rule 1
                bad = False
                for i in range(5):
                    if abs(edges1[i] / edges1[5] - pattern_ratios[q, i]) > tol:
                        bad = True
                        break
                if bad:
                    continue
                n_cand += 1
                theta_max = 2.0 * np.arcsin(min(1.0, radius_px / f1 / 2.0))  # allowed star error, rad
                # Vertex correspondence: the permutation whose six edges agree best.
                for a in range(4):
                    x = p[combo[a], 0] / f1
                    y = p[combo[a], 1] / f1
                    nn = np.sqrt(x * x + y * y + 1.0)
                    b[a, 0], b[a, 1], b[a, 2] = x / nn, y / nn, 1.0 / nn
                    r[a] = star_vectors[pattern_stars[q, a]]
                _angle_matrix(b, ai)
                _angle_matrix(r, ac)
                best_err = np.inf
                best = 0
                for m in range(len(perms)):
                    err = 0.0
                    for a in range(4):
                        for a2 in range(a + 1, 4):
                            err = max(err, abs(ai[a, a2] - ac[perms[m, a], perms[m, a2]]))
                    if err < best_err:
                        best_err = err
                        best = m
                # Each edge is off by at most the sum of its two stars' errors after any rotation,
                # so an edge mismatch above twice the allowed star error (accept rule 3, below)
                # rejects the candidate without the SVD.
                if best_err > 2.0 * theta_max + 1e-9:
                    continue
                for a in range(4):
                    rp[a] = r[perms[best, a]]
                if no_rotation_fits(b, rp, radius_px / f1):
                    continue  # a mirror image: accept rule 3 below would reject it
                A = _kabsch(b, rp)
                resid = 0.0
                for a in range(4):
                    d2 = 0.0
                    for i in range(3):
                        e = b[a, i] - (A[i, 0] * rp[a, 0] + A[i, 1] * rp[a, 1] + A[i, 2] * rp[a, 2])
                        d2 += e * e
                    resid = max(resid, np.sqrt(d2))
                if not pattern_fits(resid, f1, radius_px):  # accept rule 3
                    continue  # a mirror image or an inconsistent correspondence
                # Verification: the brightest catalogue stars in the frame, matched to centroids.
                # A quick first stage (the 15 brightest against 30 centroids) rejects most false
                # candidates at a third of the cost; the pattern's own stars are not counted.
                n_img1 = min(n_img, QUICK_CENTROIDS)
                # np.int64(): a typed int, not a literal: both calls share one compiled verify_attitude
                n_cat1 = np.int64(QUICK_CATALOG_STARS)
                logp1, _, n1_ = verify_attitude(A, f1, image, n_cat1, n_img1, radius_px,
                                                pattern_stars[q], combo, stars, view)
                if quick_check_fails(n1_, logp1):  # accept rule 4
                    continue
                logp, n_match, n_cat = verify_attitude(A, f1, image, n_img, n_img, radius_px,
                                                       pattern_stars[q], combo, stars, view)
                logp = log_prob_false(logp, cand_before + n_cand)  # every candidate examined so far
                if is_verified(logp, log_threshold):  # accept rule 5
                    return SearchResult(True, c - start + 1, n_cand, A, f1, logp, c, q, n_match, n_cat,
                                        n_compared)
    return SearchResult(False, stop - start, n_cand, np.zeros((3, 3)), 0.0, 0.0, -1, -1, 0, 0, n_compared)
