"""The 3×3 binomial smoothing ([1 2 1]ᵀ[1 2 1]/16, edges replicated), one formula for all.

Private to :mod:`skyfix.detect`. Three kernels smooth: :func:`~skyfix.detect.background.smooth3`
(the whole frame), the background's lattice samples (a tenth of the pixels) and the extractor's
fused smooth-and-threshold pass. They share these ``inline="always"`` helpers, which numba
compiles into each caller with the caller's own flags (the two full-frame passes allow
reassociation so that their loops vectorise).

The arithmetic is float32: twice the SIMD width of float64, and exact on 8- to 16-bit data,
whose 3×3 weighted sums stay below 2²⁴.
"""

from __future__ import annotations

import numpy as np

from skyfix._jit import njit

__all__ = ["F2", "F3", "F16", "column_sum", "smooth_at", "smooth_row"]

# the weights as float32, so that the arithmetic stays float32
F2, F3, F16 = np.float32(2.0), np.float32(3.0), np.float32(0.0625)


@njit(cache=True, inline="always")
def column_sum(img, ya, y, yb, x):
    """The vertical [1 2 1] sum at (y, x), rows ``ya = max(y − 1, 0)`` and ``yb = min(y + 1, H − 1)``."""
    return img[ya, x] + F2 * img[y, x] + img[yb, x]


@njit(cache=True, inline="always")
def smooth_at(t, xa, x, xb):
    """The horizontal [1 2 1]/16 of a row of vertical sums ``t`` at x (neighbours ``xa``, ``xb``)."""
    return (t[xa] + F2 * t[x] + t[xb]) * F16


@njit(cache=True, inline="always")
def smooth_row(t, out, w):
    """One smoothed row into ``out[:w]`` from its vertical sums ``t[:w]`` (edges replicated)."""
    if w == 1:
        out[0] = t[0] * np.float32(0.25)
        return
    out[0] = (F3 * t[0] + t[1]) * F16
    for x in range(1, w - 1):
        out[x] = smooth_at(t, x - 1, x, x + 1)
    out[w - 1] = (t[w - 2] + F3 * t[w - 1]) * F16
