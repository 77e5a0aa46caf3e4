"""Robust statistics shared by the detectors: medians by selection, a clipped-RMS noise, a percentile.

Private to :mod:`skyfix.detect`: the background, the centroiders, the seeds' detectors and the
frame calibration all estimate a sky level and its noise the same way, so they share these
kernels rather than each keeping a copy.

- :func:`median_inplace` — the median by quickselect (branch-free partitions, an optional
  guessed first pivot), no allocation; :func:`median` the same on a copy.
- :func:`robust_level_noise` — median and clipped RMS of a sample (the frame-wide and window
  estimates); :func:`tile_level_noise` the lower-side variant the tiled background runs
  thousands of times per frame, in place. Both clip with :func:`clipped_rms`.
- :func:`percentile_linear` — ``np.percentile`` (linear) inside a kernel, by selection;
  :func:`argsort_descending` — a stable argsort, largest first. Neither calls numpy's sorts,
  which numba compiles afresh for each kind and dtype (2–2.5 s each on a fresh cache); a
  solve's identification still compiles the float64 sort, numba's merge sort no more.
- :func:`sum_sq_dev` — ``Σ(v − c)²`` from the running sums ``Σv²``, ``Σv`` and ``n``.

Typed zeros: numba compiles a kernel once per argument types, and a literal ``0`` has a type
of its own (``Literal[int](0)``) — so has a counter that starts at ``0``, as numba's type
inference first sees it, before the increments make it ``int64``. ``f(a, 0)`` or ``f(a, k)``
after ``k = 0`` would compile ``f`` twice (and everything it calls), so a zero that reaches a
kernel call is ``np.int64(0)`` in the detect kernels.
"""

from __future__ import annotations

import math

import numpy as np

from skyfix._jit import njit

__all__ = ["CLIP", "median", "median_inplace", "robust_level_noise", "tile_level_noise", "clipped_rms",
           "percentile_linear", "argsort_descending", "sum_sq_dev", "window_border"]

#: Half-width of the clip of :func:`clipped_rms`, in σ.
CLIP = 3.0
# A clipped RMS at ±3σ of a Gaussian underestimates σ by this factor.
_CLIP_CORRECTION = 1.0 / math.sqrt(1.0 - 2.0 * CLIP * math.exp(-0.5 * CLIP**2) / math.sqrt(2 * math.pi)
                                   / math.erf(CLIP / math.sqrt(2.0)))


@njit(cache=True)
def median(v):
    """Median of a 1-D float64 array (NaN if empty), leaving it untouched."""
    if v.size == 0:
        return np.nan
    return median_inplace(v.copy(), v.size, np.nan)


@njit(cache=True)
def robust_level_noise(v, quantum=0.0, lower=False, guess=np.nan):
    """Median and clipped RMS (about the median, ±3σ, corrected) of a 1-D sample.

    ``quantum`` is the data's quantisation step (0 for continuous data): the clip starts no
    narrower than ±3 steps, since a MAD below one step only says the noise is unresolved.
    With ``lower`` only values below the median count: stars add light, so the lower half of
    a tile's distribution is noise alone even when a bright star covers much of the tile.
    ``guess``: a likely value of the median, the selection's first pivot (NaN: none).
    """
    n = v.size
    if n == 0:
        return 0.0, 0.0
    scratch = v.astype(np.float64)  # a copy: the selection reorders it
    med = median_inplace(scratch, n, guess)
    if lower:
        m = 0
        dev = np.empty(n)
        for i in range(n):
            if v[i] <= med:
                dev[m] = med - v[i]
                m += 1
        dev = dev[:m]
    else:
        dev = np.abs(v - med)
    scratch = dev.copy()
    s0 = max(1.4826 * median_inplace(scratch, dev.size, np.nan), quantum)
    return med, clipped_rms(dev, dev.size, s0)


@njit(cache=True, inline="always")
def window_border(img, y0, y1, x0, x1, buf):
    """The pixels of the border of the window rows ``y0..y1``, columns ``x0..x1`` (inclusive) of
    ``img`` into ``buf`` (at least ``2·(x1 − x0 + 1) + 2·(y1 − y0 − 1)`` long), top and bottom
    rows in pairs, then the left and right columns; returns how many: a window's sky sample."""
    m = 0
    for x in range(x0, x1 + 1):
        buf[m] = img[y0, x]
        buf[m + 1] = img[y1, x]
        m += 2
    for y in range(y0 + 1, y1):
        buf[m] = img[y, x0]
        buf[m + 1] = img[y, x1]
        m += 2
    return m


@njit(cache=True)
def tile_level_noise(a, n, quantum, guess=np.nan, guess_lower=np.nan):
    """Median and lower-side clipped RMS of ``a[:n]``, in place and without allocating.

    The same estimate as ``robust_level_noise(a[:n], quantum, lower=True)``. ``guess`` and
    ``guess_lower``: likely values of the median and of the lower half's median less the
    median (NaN: none). ``a[:n]`` is left reordered, its values below the median replaced by
    their distance to it.
    Returns the median, the RMS and the lower half's median.
    """
    if n == 0:
        return 0.0, 0.0, np.nan
    med = median_inplace(a, n, guess)
    # the values ≤ median: the first n//2 after the select, plus any ties above (branch-free)
    m = np.int64(0)  # typed (module docstring)
    for i in range(n):
        e = a[i]
        a[i] = a[m]
        a[m] = e
        m += e <= med
    # median of the deviations med − a[i] is med − (median of the lower values)
    lower_med = median_inplace(a, m, med + guess_lower)
    s0 = max(1.4826 * (med - lower_med), quantum)
    for i in range(m):
        a[i] = med - a[i]
    return med, clipped_rms(a, m, s0), lower_med


@njit(cache=True)
def clipped_rms(dev, n, s0):
    """RMS of the deviations ``dev[:n]`` (≥ 0) within ±3σ, iterated from ``s0`` and corrected.

    The clip is ``3·max(s, s0/2)``, updated until it moves by less than 0.1% (at most 4
    passes); the RMS of a Gaussian clipped at ±3σ is scaled back up by ``_CLIP_CORRECTION``.
    ``s0 ≤ 0`` (more than half the sample equals the median) starts from the smallest nonzero
    deviation instead; 0 if there is none.
    """
    if s0 <= 0.0:
        step = np.inf
        for i in range(n):
            if 0.0 < dev[i] < step:
                step = dev[i]
        s0 = step if step < np.inf else 0.0
    if s0 <= 0.0:
        return 0.0
    cut = CLIP * s0
    s = s0
    for _ in range(4):
        acc = 0.0
        m = 0
        for i in range(n):  # branch-free: noise makes the test unpredictable
            d = dev[i]
            keep = d <= cut
            acc += d * d if keep else 0.0
            m += keep
        s = math.sqrt(acc / max(m, 1)) * _CLIP_CORRECTION
        new_cut = CLIP * max(s, 0.5 * s0)
        if abs(new_cut - cut) < 1e-3 * cut:
            break
        cut = new_cut
    return s


@njit(cache=True)
def percentile_linear(v, q):
    """``np.percentile(v, 100·q)`` (linear method), with numpy's arithmetic.

    The two order statistics it needs are found by selection (:func:`_select`), not by
    ``np.sort``, whose float64 sort (~2 s to compile on a fresh cache) an extraction needed
    for this alone (a solve compiles it all the same, for the pattern search's edge angles).
    """
    a = v.astype(np.float64)  # a copy: the selection reorders it
    n = a.size
    vi = (n - 1) * q
    lo = min(int(math.floor(vi)), n - 1)
    below = _select(a, np.int64(0), n, lo)
    if vi >= n - 1:
        return below
    above = a[lo + 1:].min()  # the selection left a[lo + 1:] ≥ a[lo]: their least is the next one
    gamma = vi - lo
    diff = above - below
    if gamma >= 0.5:
        return above - diff * (1.0 - gamma)
    return below + diff * gamma


@njit(cache=True)
def argsort_descending(v):
    """Indices that order ``v`` from largest to smallest, equal values in index order (NaN last).

    ``np.argsort(-v, kind="mergesort")`` written out (a bottom-up merge sort): numba's merge
    sort takes ~2.5 s to compile on a fresh cache, and the extractor needs only this one.
    """
    n = v.size
    idx = np.arange(n)
    tmp = np.empty(n, np.int64)
    width = 1
    while width < n:
        for lo in range(0, n, 2 * width):
            mid, hi = min(lo + width, n), min(lo + 2 * width, n)
            i, j = lo, mid
            for k in range(lo, hi):
                # the right run's value goes first only if it is strictly larger (stable)
                if j < hi and (i == mid or _larger(v[idx[j]], v[idx[i]])):
                    tmp[k] = idx[j]
                    j += 1
                else:
                    tmp[k] = idx[i]
                    i += 1
        idx, tmp = tmp, idx
        width *= 2
    return idx


@njit(cache=True, inline="always")
def _larger(a, b):
    """Whether ``a`` goes before ``b`` in decreasing order with NaN last."""
    return a > b or (math.isnan(b) and not math.isnan(a))


@njit(cache=True, inline="always")
def sum_sq_dev(s2, s1, n, c):
    """``Σ(v − c)²`` from ``Σv²``, ``Σv`` and ``n`` (0 where rounding makes it negative)."""
    return np.maximum(s2 - 2.0 * c * s1 + n * c * c, 0.0)


@njit(cache=True)
def median_inplace(a, n, guess=np.nan):
    """Median of ``a[:n]`` (reordered in place); below index n//2 lie values ≤ it.

    ``guess``, if not NaN, is a likely value of the median (see :func:`_select_around`).
    """
    k = n // 2
    if math.isnan(guess):
        upper = _select(a, np.int64(0), n, k)  # typed (module docstring)
    else:
        upper = _select_around(a, n, k, guess)
    if n % 2 == 1:
        return upper
    lower = a[0]
    for i in range(1, k):
        lower = max(lower, a[i])
    return 0.5 * (lower + upper)


@njit(cache=True)
def _select(a, lo, hi, k):
    """Partially sort ``a[lo:hi]`` in place so that ``a[k]`` is its k-th smallest; returns it.

    Quickselect with a median-of-three pivot and branch-free Lomuto partitions (about 3× faster
    than Hoare's on noise, whose comparisons a branch predictor cannot guess); no allocation
    (the tiles call it thousands of times per frame). Values equal to the pivot are gathered
    in a second pass, so quantised data with many ties stays linear. Terminates on NaN.
    """
    hi -= 1
    while hi > lo:
        mid = (lo + hi) >> 1
        u, v, t = a[lo], a[mid], a[hi]
        if u > v:
            u, v = v, u
        if v > t:
            v = t
        pivot = max(u, v)
        # a[lo:store] < pivot ≤ a[store:hi+1]; every element is swapped, the index moves or not
        store = lo
        for i in range(lo, hi + 1):
            e = a[i]
            a[i] = a[store]
            a[store] = e
            store += e < pivot
        if k < store:
            hi = store - 1
            continue
        # then the ties: a[store:eq] == pivot
        eq = store
        for i in range(store, hi + 1):
            e = a[i]
            a[i] = a[eq]
            a[eq] = e
            eq += e == pivot
        if k < eq or eq == lo:  # found, or a NaN pivot that nothing equals
            return a[k] if eq == lo else pivot
        lo = eq
    return a[k]


@njit(cache=True)
def _select_around(a, n, k, guess):
    """:func:`_select` on ``a[:n]`` whose first partition is around ``guess``, a likely value.

    Neighbouring tiles have nearly the same sky, so one tile's median is a good first pivot
    for the next: the selection then works on the few values beside it (on quantised data the
    guess is often the median itself and two passes find it).
    """
    store = np.int64(0)  # typed (module docstring)
    for i in range(n):
        e = a[i]
        a[i] = a[store]
        a[store] = e
        store += e < guess
    if k < store:
        return _select(a, np.int64(0), store, k)
    eq = store
    for i in range(store, n):
        e = a[i]
        a[i] = a[eq]
        a[eq] = e
        eq += e == guess
    if k < eq:
        return a[k]
    return _select(a, eq, n, k)
