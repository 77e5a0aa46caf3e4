"""The binomial tail behind every chance-match probability (verification in the kernels, the
acceptance rule in :mod:`skyfix.identify.accept`), once."""

from __future__ import annotations

import math

import numpy as np

from skyfix._jit import njit

__all__ = ["log_binom_sf"]


# log n! for the binomial tails (the same ``math.lgamma`` values, looked up instead of recomputed).
_N_LOG_FACT = 4096
_LOG_FACT = np.array([math.lgamma(j + 1.0) for j in range(_N_LOG_FACT)])


@njit(cache=True, inline="always")
def _log_fact(j: int) -> float:
    return _LOG_FACT[j] if j < _N_LOG_FACT else math.lgamma(j + 1.0)


@njit(cache=True)
def log_binom_sf(k: int, n: int, p: float) -> float:
    """log P(X >= k) for X ~ Binomial(n, p)."""
    if k <= 0:
        return 0.0
    if k > n:
        return -np.inf
    p = min(max(p, 1e-300), 1.0 - 1e-16)
    lp, lq = np.log(p), np.log1p(-p)
    base = _log_fact(n)
    # Two passes over the terms (largest first, then the scaled sum): no scratch array.
    best = -np.inf
    for j in range(k, n + 1):
        t = base - _log_fact(j) - _log_fact(n - j) + j * lp + (n - j) * lq
        best = max(best, t)
    acc = 0.0
    for j in range(k, n + 1):
        t = base - _log_fact(j) - _log_fact(n - j) + j * lp + (n - j) * lq
        acc += np.exp(t - best)
    return best + np.log(acc)
