"""Sky background and noise: a tiled robust estimate on a coarse grid, interpolated bilinearly.

The frame is cut into tiles (about 1/16 of the short side, 16–64 px). In each tile a regular
lattice of ~144 pixels of the 3×3-smoothed frame gives the median (the sky level) and a clipped
RMS about it (the noise σ; a plain MAD collapses to zero on 8-bit frames whose noise is below
one level). The raw-pixel noise is one pooled robust estimate over all tiles, scaled tile by
tile like the smoothed noise. A 3×3
median filter over the tile grid removes tiles dominated by a bright star or the Moon, and the
grid is interpolated bilinearly between tile centres (held constant beyond the outer centres).
Vignetting, sky glow and gradients that vary over more than a couple of tiles are followed.

The statistics are those of the smoothed frame because that is the image the extractor
thresholds: measuring its noise directly keeps the threshold right for spatially correlated
noise (JPEG, Bayer interpolation), where σ_raw·√(Σw²) would be wrong.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import ndimage

__all__ = ["Background", "estimate_background", "smooth3", "default_tile_size"]

# A clipped RMS at ±3σ of a Gaussian underestimates σ by this factor.
_CLIP = 3.0
# The sampling lattice in a tile has about this many points per side.
_SAMPLES_PER_SIDE = 12
_CLIP_CORRECTION = 1.0 / math.sqrt(1.0 - 2.0 * _CLIP * math.exp(-0.5 * _CLIP**2) / math.sqrt(2 * math.pi)
                                   / math.erf(_CLIP / math.sqrt(2.0)))


@dataclass(frozen=True)
class Background:
    """Sky level and noise on a tile grid (float64 arrays of shape (ny, nx)).

    Attributes
    ----------
    level, noise : sky level and per-pixel σ of the raw frame, ADU.
    level_smooth, noise_smooth : the same for the 3×3-binomial-smoothed frame (the sky level
        of both is the smoothed frame's median).
    centers_y, centers_x : (ny,), (nx,) tile-centre rows and columns, pixels.
    tile : tile size, pixels.
    """

    level: np.ndarray
    noise: np.ndarray
    level_smooth: np.ndarray
    noise_smooth: np.ndarray
    centers_y: np.ndarray
    centers_x: np.ndarray
    tile: int

    @property
    def global_level(self) -> float:
        """Median sky level over the tiles, ADU."""
        return float(np.median(self.level))

    @property
    def global_noise(self) -> float:
        """Median per-pixel noise σ over the tiles, ADU."""
        return float(np.median(self.noise))

    def level_map(self, shape: tuple[int, int], smooth: bool = False) -> np.ndarray:
        """The sky level interpolated to every pixel, float32 (H, W)."""
        grid = self.level_smooth if smooth else self.level
        return interpolate_grid(grid, self.centers_y, self.centers_x, shape)

    def noise_map(self, shape: tuple[int, int], smooth: bool = False) -> np.ndarray:
        """The noise σ interpolated to every pixel, float32 (H, W)."""
        grid = self.noise_smooth if smooth else self.noise
        return interpolate_grid(grid, self.centers_y, self.centers_x, shape)


def default_tile_size(shape: tuple[int, int]) -> int:
    """About 1/16 of the short side, clipped to 16–64 px (and to the frame)."""
    short = min(shape)
    return int(max(1, min(short, max(16, min(64, short // 16)))))


def estimate_background(image: np.ndarray, tile: int | None = None, grid_filter: int = 3,
                        smoothed: np.ndarray | None = None) -> Background:
    """Tiled median background and clipped-RMS noise of a frame.

    Parameters
    ----------
    image : (H, W) float32 array
        The frame, ADU.
    tile : int, optional
        Tile size in pixels (default :func:`default_tile_size`).
    grid_filter : int
        Size of the median filter applied over the tile grid (1 = none).
    smoothed : (H, W) float32 array, optional
        ``smooth3(image)`` if the caller already has it.

    Returns
    -------
    Background
    """
    img = np.ascontiguousarray(image, dtype=np.float32)
    h, w = img.shape
    t = default_tile_size(img.shape) if tile is None else int(max(1, min(tile, h, w)))
    ny, nx = max(1, round(h / t)), max(1, round(w / t))
    edges_y = np.linspace(0, h, ny + 1).round().astype(np.int64)
    edges_x = np.linspace(0, w, nx + 1).round().astype(np.int64)
    stride = max(1, round(t / _SAMPLES_PER_SIDE))
    sm = smooth3(img) if smoothed is None else np.ascontiguousarray(smoothed, dtype=np.float32)
    stats, raw_dev = _tile_stats(img, sm, edges_y, edges_x, stride)
    if grid_filter > 1 and min(ny, nx) > 1:
        stats = ndimage.median_filter(stats, size=(grid_filter, grid_filter, 1), mode="nearest")
    level, noise_s = stats[..., 0], stats[..., 1]
    # raw-pixel noise: one pooled robust estimate, spread over the tiles like the smoothed noise
    _, raw_sigma = _robust_level_noise(raw_dev[:: max(1, raw_dev.size // 8192)].copy())
    ref_s = float(np.median(noise_s))
    kappa = raw_sigma / ref_s if ref_s > 0 else 1.0
    cy = 0.5 * (edges_y[:-1] + edges_y[1:]) - 0.5
    cx = 0.5 * (edges_x[:-1] + edges_x[1:]) - 0.5
    return Background(level=level, noise=kappa * noise_s, level_smooth=level, noise_smooth=noise_s,
                      centers_y=cy, centers_x=cx, tile=t)


def smooth3(image: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """3×3 binomial smoothing ([1 2 1]ᵀ[1 2 1]/16), edges replicated; float32 (H, W).

    ``out``, if given, is a float32 array of the same shape that receives the result.
    """
    img = np.ascontiguousarray(image, dtype=np.float32)
    if out is None:
        out = np.empty(img.shape, np.float32)
    _smooth3(img, out)
    return out


def interpolate_grid(grid: np.ndarray, centers_y: np.ndarray, centers_x: np.ndarray,
                     shape: tuple[int, int]) -> np.ndarray:
    """Bilinear interpolation of a tile grid to every pixel (constant beyond the outer centres)."""
    iy, fy = interp_weights(centers_y, shape[0])
    ix, fx = interp_weights(centers_x, shape[1])
    return _interp_full(np.ascontiguousarray(grid, dtype=np.float64), iy, fy, ix, fx)


def interp_weights(centers: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """For pixels 0..n-1: index of the lower tile centre and the weight of the upper one."""
    pos = np.arange(n, dtype=np.float64)
    if centers.size == 1:
        return np.zeros(n, np.int64), np.zeros(n, np.float32)
    i = np.clip(np.searchsorted(centers, pos, side="right") - 1, 0, centers.size - 2)
    f = np.clip((pos - centers[i]) / (centers[i + 1] - centers[i]), 0.0, 1.0)
    return i.astype(np.int64), f.astype(np.float32)


# --- numba kernels ------------------------------------------------------------------------


@njit(cache=True)
def _smooth3(img, out):
    h, w = img.shape
    tmp = np.empty(w, np.float32)
    for y in range(h):
        ya, yb = max(y - 1, 0), min(y + 1, h - 1)
        for x in range(w):
            tmp[x] = img[ya, x] + 2.0 * img[y, x] + img[yb, x]
        if w == 1:
            out[y, 0] = tmp[0] * 0.25
            continue
        out[y, 0] = (3.0 * tmp[0] + tmp[1]) * 0.0625
        for x in range(1, w - 1):
            out[y, x] = (tmp[x - 1] + 2.0 * tmp[x] + tmp[x + 1]) * 0.0625
        out[y, w - 1] = (tmp[w - 2] + 3.0 * tmp[w - 1]) * 0.0625


@njit(cache=True)
def _robust_level_noise(v):
    """Median and clipped RMS (about the median, ±3σ, corrected) of a 1-D sample."""
    n = v.size
    med = np.median(v)
    dev = np.abs(v - med)
    s0 = 1.4826 * np.median(dev)
    if s0 <= 0.0:
        # more than half the sample equals the median (quantised, quiet sky): one quantum
        step = np.inf
        for i in range(n):
            if 0.0 < dev[i] < step:
                step = dev[i]
        s0 = step if step < np.inf else 0.0
    if s0 <= 0.0:
        return med, 0.0
    cut = _CLIP * s0
    for _ in range(3):
        acc = 0.0
        m = 0
        for i in range(n):
            if dev[i] <= cut:
                acc += dev[i] * dev[i]
                m += 1
        s = math.sqrt(acc / max(m, 1)) * _CLIP_CORRECTION
        new_cut = _CLIP * max(s, 0.5 * s0)
        if abs(new_cut - cut) < 1e-3 * cut:
            break
        cut = new_cut
    return med, s


@njit(cache=True)
def _tile_stats(img, sm_img, edges_y, edges_x, stride):
    """Per tile: median and clipped RMS of the smoothed frame on a sampling lattice.

    Also returns the raw samples minus their tile's smoothed median, pooled over all tiles.
    """
    ny, nx = edges_y.size - 1, edges_x.size - 1
    out = np.empty((ny, nx, 2))
    cap_y = (edges_y[1:] - edges_y[:-1]).max() // stride + 1
    cap = cap_y * ((edges_x[1:] - edges_x[:-1]).max() // stride + 1)
    raw = np.empty(cap, np.float64)
    sm = np.empty(cap, np.float64)
    pooled = np.empty(ny * nx * cap, np.float64)
    npool = 0
    for ty in range(ny):
        for tx in range(nx):
            # centre the sampling lattice in the tile
            y0 = edges_y[ty] + ((edges_y[ty + 1] - edges_y[ty] - 1) % stride) // 2
            x0 = edges_x[tx] + ((edges_x[tx + 1] - edges_x[tx] - 1) % stride) // 2
            k = 0
            for y in range(y0, edges_y[ty + 1], stride):
                for x in range(x0, edges_x[tx + 1], stride):
                    raw[k] = img[y, x]
                    sm[k] = sm_img[y, x]
                    k += 1
            med, sig = _robust_level_noise(sm[:k])
            out[ty, tx, 0] = med
            out[ty, tx, 1] = sig
            for i in range(k):
                pooled[npool] = raw[i] - med
                npool += 1
    return out, pooled[:npool]


@njit(cache=True)
def _interp_full(grid, iy, fy, ix, fx):
    h, w = iy.size, ix.size
    ny, nx = grid.shape
    out = np.empty((h, w), np.float32)
    row = np.empty(nx, np.float32)
    for y in range(h):
        i = iy[y]
        f = fy[y]
        j = min(i + 1, ny - 1)
        for c in range(nx):
            row[c] = (1.0 - f) * grid[i, c] + f * grid[j, c]
        for x in range(w):
            a = ix[x]
            b = min(a + 1, nx - 1)
            g = fx[x]
            out[y, x] = (1.0 - g) * row[a] + g * row[b]
    return out
