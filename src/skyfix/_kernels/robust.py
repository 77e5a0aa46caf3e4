"""Robust selection of stars by their residuals, once: the final fit's outlier cut (accept rule
16, :func:`skyfix.final_fit.inliers`) and the triangle method's check that a sparse frame's
triangle holds among the stars that verify it (:mod:`skyfix.identify.methods.triangle`)."""

from __future__ import annotations

import numpy as np

from skyfix._jit import njit

__all__ = ["rayleigh_inliers", "sorted_copy"]


@njit(cache=True)
def sorted_copy(a):
    """A sorted copy of a short 1-D array (Shell sort: compiles in a fraction of np.sort's time)."""
    out = a.copy()
    n = out.shape[0]
    for gap in (701, 301, 132, 57, 23, 10, 4, 1):  # Ciura's gaps
        for i in range(gap, n):
            v = out[i]
            j = i
            while j >= gap and out[j - gap] > v:
                out[j] = out[j - gap]
                j -= gap
            out[j] = v
    return out


@njit(cache=True)
def rayleigh_inliers(resid, floor):
    """Stars to keep: residual lengths of 2-D Gaussian errors are Rayleigh distributed (median
    1.177 σ); those beyond 4 σ (P = 3e-4 by chance; σ floored at ``floor``) are blends or
    mismatched stars. At least half of the stars, and three, are always kept."""
    n = resid.shape[0]
    if n == 0:
        return np.zeros(0, dtype=np.bool_)
    ordered = sorted_copy(resid)
    median = ordered[n // 2] if n % 2 else (ordered[n // 2 - 1] + ordered[n // 2]) / 2.0
    sigma = max(median / 1.177, floor)
    keep = resid <= 4.0 * sigma
    n_min = min(n, max(3, n // 2))
    if keep.sum() < n_min:
        keep = resid <= ordered[n_min - 1]
    return keep
