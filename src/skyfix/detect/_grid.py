"""The background's tile grids laid over a frame: bilinear interpolation, one formula for all.

Private to :mod:`skyfix.detect`. The sky level and noise live on a coarse grid of tile centres
(:class:`~skyfix.detect.background.Background`); every pixel row ``y`` has a lower tile-centre
row ``iy[y]`` and the weight ``fy[y]`` of the next one (likewise ``ix``, ``fx`` for columns),
linear beyond the outer centres. The kernels of the extractor read the grids through:

- :class:`GridWeights` — those four arrays; :class:`SkyGrid` — a Background and its weights
  on one frame, the single argument the kernels take for "the sky";
- :func:`grid_at` — the value at a pixel (float64 weights; :func:`bilinear` the same formula
  with the caller's floating-point flags);
- :func:`value_near` — the value at a sub-pixel position rounded to its pixel (float32
  one-minus-weights, floored at 1e-12, as the star noise σ has always been computed);
- :func:`grid_rows` — the grid interpolated along x at each tile-centre row, so that any pixel
  row is one multiply-add per pixel.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from skyfix._jit import njit

__all__ = ["GridWeights", "SkyGrid", "interp_weights", "grid_weights", "sky_grid", "grid_at", "bilinear",
           "value_near", "values_near", "grid_rows"]


class GridWeights(NamedTuple):
    """Bilinear interpolation weights of a tile grid on a frame of H×W pixels."""

    iy: np.ndarray  #: (H,) int64 — the tile-centre row at or above each pixel row (clipped)
    fy: np.ndarray  #: (H,) float32 — the weight of the next tile-centre row
    ix: np.ndarray  #: (W,) int64 — likewise for columns
    fx: np.ndarray  #: (W,) float32


class SkyGrid(NamedTuple):
    """A :class:`~skyfix.detect.background.Background` on one frame, for the kernels.

    The four (ny, nx) float64 grids (raw and 3×3-smoothed frame, level and noise σ, ADU), the
    tile centres (pixels) and the frame's :class:`GridWeights`.
    """

    level: np.ndarray
    noise: np.ndarray
    level_smooth: np.ndarray
    noise_smooth: np.ndarray
    centers_y: np.ndarray
    centers_x: np.ndarray
    weights: GridWeights


def interp_weights(centers: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """For pixels 0..n-1: index of the lower tile centre and the weight of the upper one."""
    return _interp_weights(np.ascontiguousarray(centers, dtype=np.float64), int(n))


def grid_weights(centers_y: np.ndarray, centers_x: np.ndarray, shape: tuple[int, int]) -> GridWeights:
    """The :class:`GridWeights` of tile centres on a frame of ``shape`` (H, W).

    Kept for the last few tilings asked for (an extraction asks twice, and every frame of one
    size has the same tiling): the arrays are shared, read them only. Four kernel calls fewer
    an extraction: 0.7–0.9 % of its CPU time on 0.26–1.2 MP frames.
    """
    cy = np.ascontiguousarray(centers_y, dtype=np.float64)
    cx = np.ascontiguousarray(centers_x, dtype=np.float64)
    key = (cy.tobytes(), cx.tobytes(), int(shape[0]), int(shape[1]))
    got = _WEIGHTS.get(key)
    if got is None:
        if len(_WEIGHTS) >= 16:
            _WEIGHTS.clear()
        got = _WEIGHTS[key] = GridWeights(*interp_weights(cy, shape[0]), *interp_weights(cx, shape[1]))
    return got


_WEIGHTS: dict[tuple, GridWeights] = {}  # grid_weights' last tilings: (centres, centres, H, W) → weights


def sky_grid(bg, shape: tuple[int, int]) -> SkyGrid:
    """The :class:`SkyGrid` of a Background ``bg`` on a frame of ``shape`` (H, W): every array
    C-contiguous float64, whatever the background held (a background's grids may be views: one
    layout keeps the kernels to one compiled signature)."""
    def c64(a: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(a, dtype=np.float64)

    return SkyGrid(c64(bg.level), c64(bg.noise), c64(bg.level_smooth), c64(bg.noise_smooth),
                   c64(bg.centers_y), c64(bg.centers_x), grid_weights(bg.centers_y, bg.centers_x, shape))


@njit(cache=True)
def _interp_weights(centers, n):
    i = np.zeros(n, np.int64)
    f = np.zeros(n, np.float32)
    m = centers.size
    if m == 1:
        return i, f
    j = 0  # centres ≤ pos (searchsorted "right"), advanced as pos grows
    for p in range(n):
        pos = float(p)
        while j < m and centers[j] <= pos:
            j += 1
        k = min(max(j - 1, 0), m - 2)
        i[p] = k
        # linear beyond the outer centres too (half a tile): a gradient continues to the edge
        f[p] = (pos - centers[k]) / (centers[k + 1] - centers[k])
    return i, f


# The extractor's kernels read the sky with multiply-adds allowed to fuse (FMA). They always
# did: numba compiles a helper first called from a fastmath kernel (the threshold pass) with
# that kernel's flags and reuses that build for every later caller, so the flags are now
# stated here rather than left to the order of compilation. The background's own kernels use
# :func:`bilinear` under their exact arithmetic.
_FUSED = {"reassoc", "contract"}


@njit(cache=True, fastmath=_FUSED)
def grid_at(grid, w, y, x):
    """Bilinear value of a tile grid at pixel (y, x); ``w`` its :class:`GridWeights` (:data:`_FUSED`)."""
    return bilinear(grid, w, y, x)


@njit(cache=True, inline="always")
def bilinear(grid, w, y, x):
    """Bilinear value of a tile grid at pixel (y, x), with the caller's floating-point flags."""
    ny, nx = grid.shape
    i, j = w.iy[y], w.ix[x]
    i1, j1 = min(i + 1, ny - 1), min(j + 1, nx - 1)
    f, g = w.fy[y], w.fx[x]
    top = (1.0 - g) * grid[i, j] + g * grid[i, j1]
    bot = (1.0 - g) * grid[i1, j] + g * grid[i1, j1]
    return (1.0 - f) * top + f * bot


@njit(cache=True, inline="always")
def value_near(grid, w, x, y):
    """Bilinear value of a tile grid at the pixel nearest to (x, y), at least 1e-12.

    The one-minus-weights stay float32 (the arithmetic the extractor's star noise has always
    had; :func:`grid_at` computes them in float64).
    """
    ny, nx = grid.shape
    xi = min(max(int(np.rint(x)), 0), w.ix.size - 1)
    yi = min(max(int(np.rint(y)), 0), w.iy.size - 1)
    i, j = w.iy[yi], w.ix[xi]
    i1, j1 = min(i + 1, ny - 1), min(j + 1, nx - 1)
    f, g = w.fy[yi], w.fx[xi]
    top = (np.float32(1.0) - g) * grid[i, j] + g * grid[i, j1]
    bot = (np.float32(1.0) - g) * grid[i1, j] + g * grid[i1, j1]
    return max((np.float32(1.0) - f) * top + f * bot, 1e-12)


@njit(cache=True)
def values_near(grid, w, x, y):
    """:func:`value_near` at each of the positions ``(x[k], y[k])``, (N,) float64."""
    out = np.empty(x.size)
    for k in range(x.size):
        out[k] = value_near(grid, w, x[k], y[k])
    return out


@njit(cache=True, fastmath=_FUSED)
def grid_rows(grid, w):
    """A tile grid interpolated along x at each tile-centre row, and the row-to-row step.

    Both (ny, W) float32: pixel row y is then ``r0[iy[y]] + fy[y]·dr[iy[y]]``.
    """
    ny, nx = grid.shape
    width = w.ix.size
    r0 = np.empty((ny, width), np.float32)
    dr = np.empty((ny, width), np.float32)
    for i in range(ny):
        for x in range(width):
            a = w.ix[x]
            r0[i, x] = (1.0 - w.fx[x]) * grid[i, a] + w.fx[x] * grid[i, min(a + 1, nx - 1)]
    for i in range(ny):
        for x in range(width):
            dr[i, x] = r0[min(i + 1, ny - 1), x] - r0[i, x]
    return r0, dr
