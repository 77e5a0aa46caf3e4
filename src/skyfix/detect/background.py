"""Sky background and noise: a tiled robust estimate on a coarse grid, interpolated bilinearly.

The frame is cut into tiles (about 1/16 of the short side, 32–64 px). In each tile a regular
lattice of ~100 pixels of the 3×3-smoothed frame gives the median (the sky level). The grid is
interpolated bilinearly between tile centres (and extrapolated linearly over the half tile
beyond the outer centres); then, in a second pass, each tile's samples minus that model give a
correction to its level (a plain median of a sloped tile is as uncertain as the slope is steep)
and the noise σ: a clipped RMS of the values *below* the median (stars only add light, so the
lower half is noise alone even when a bright star fills much of a tile; a plain MAD collapses
to zero on 8-bit frames whose noise is below one level). The raw-pixel noise is one pooled
robust estimate over about 64 tiles, scaled tile by tile like the smoothed noise. On strongly
quantised frames (raw noise below one level) the level is the clipped mean and the smoothed
noise is floored at the white-noise value.

Vignetting, sky glow and gradients that vary over more than a couple of tiles are followed. An
optional median filter over the grid (``grid_filter``) removes tiles dominated by a bright
object but bends strong vignetting at the corners, so it is off by default. ``method="global"``
(one offset, thesis 000) and ``method="rows"`` (one level per row, thesis 004) are the seeds'
simpler models.

The statistics are those of the smoothed frame because that is the image the extractor
thresholds: measuring its noise directly keeps the threshold right for spatially correlated
noise (JPEG, Bayer interpolation), where σ_raw·√(Σw²) would be wrong.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix.detect._grid import GridWeights, bilinear, grid_weights
from skyfix.detect._smooth import column_sum, smooth_at, smooth_row
from skyfix.detect._stats import CLIP, median, median_inplace, robust_level_noise, tile_level_noise
from skyfix.detect._threads import run_chunks, split
from skyfix.errors import unknown_name

__all__ = ["METHODS", "Background", "estimate_background", "smooth3", "default_tile_size"]

# Raw noise below this (in levels) on integer data counts as quantised.
_QUANTISED_SIGMA = 1.0
# Noise of the 3×3 binomial mean of white noise, relative to the pixel noise: √(36/256).
_SMOOTH_WHITE = 0.375
# The sampling lattice in a tile has about this many points per side.
_SAMPLES_PER_SIDE = 10


class _Lattice(NamedTuple):
    """Where a frame is sampled: tile edges ((ny + 1,), (nx + 1,) int64) and the sampling steps,
    pixels; in each tile the samples form a lattice centred in it (:func:`_lattice_start`)."""

    edges_y: np.ndarray
    edges_x: np.ndarray
    step_y: int
    step_x: int


class _Samples(NamedTuple):
    """The frame on each tile's lattice (:func:`_lattice_samples`); tiles row-major."""

    smooth: np.ndarray  # (T, cap) float64 — the smoothed frame, in scan order
    raw: np.ndarray  # (T, cap) float64 — the raw frame
    count: np.ndarray  # (T,) int64 — samples in each tile
    median: np.ndarray  # (T,) float64 — each tile's median (of the smoothed or the raw samples)


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
        return float(median_of(self.level))

    @property
    def global_noise(self) -> float:
        """Median per-pixel noise σ over the tiles, ADU."""
        return float(median_of(self.noise))

    def level_map(self, shape: tuple[int, int], smooth: bool = False) -> np.ndarray:
        """The sky level interpolated to every pixel, float32 (H, W)."""
        grid = self.level_smooth if smooth else self.level
        return interpolate_grid(grid, self.centers_y, self.centers_x, shape)

    def noise_map(self, shape: tuple[int, int], smooth: bool = False) -> np.ndarray:
        """The noise σ interpolated to every pixel, float32 (H, W)."""
        grid = self.noise_smooth if smooth else self.noise
        return interpolate_grid(grid, self.centers_y, self.centers_x, shape)


def default_tile_size(shape: tuple[int, int]) -> int:
    """About 1/16 of the short side, clipped to 32–64 px (and to the frame)."""
    short = min(shape)
    return int(max(1, min(short, max(32, min(64, short // 16)))))


class _Tiling(NamedTuple):
    """How a background method cuts an H×W frame: tiles and the sampling steps in them, pixels."""

    tile: int  # the size reported in Background.tile
    ny: int  # tiles down and across
    nx: int
    step_y: int  # sampling lattice steps
    step_x: int
    # tiles are single rows: their levels are the raw rows' medians, which the smoothed frame
    # sees mixed [1 2 1]/4 with the neighbouring rows, and no gradient is fitted inside them
    per_row: bool = False


def _tiled(h: int, w: int, tile: int | None) -> _Tiling:
    t = default_tile_size((h, w)) if tile is None else int(max(1, min(tile, h, w)))
    step = max(1, round(t / _SAMPLES_PER_SIDE))
    return _Tiling(t, max(1, round(h / t)), max(1, round(w / t)), step, step)


def _global(h: int, w: int, tile: int | None) -> _Tiling:
    step = max(1, int(np.sqrt(h * w / 16384)))
    return _Tiling(max(h, w), 1, 1, step, step)


def _rows(h: int, w: int, tile: int | None) -> _Tiling:
    return _Tiling(1, h, 1, 1, max(1, w // 128), per_row=True)


#: Background models by name (``method=`` of :func:`estimate_background`), each a way to cut
#: the frame into tiles, ``(h, w, tile) -> _Tiling``.
METHODS = {"tiled": _tiled, "global": _global, "rows": _rows}


def estimate_background(image: np.ndarray, tile: int | None = None, grid_filter: int = 1,
                        smoothed: np.ndarray | None = None, method: str = "tiled") -> Background:
    """Sky level and noise of a frame: tiled (default), one global value, or one per row.

    Parameters
    ----------
    image : (H, W) float32 array
        The frame, ADU.
    tile : int, optional
        Tile size in pixels (default :func:`default_tile_size`), for ``method="tiled"``.
    method : {"tiled", "global", "rows"}
        ``"tiled"``: the interpolated tile grid (module docstring). ``"global"``: one offset for
        the whole frame (thesis 000, which found its background uniform). ``"rows"``: one level per
        row (thesis 004's per-row dark reference, which follows the slow offset droop of an
        AC-coupled readout; here from the row's own pixels, as frames have no shielded columns).
    grid_filter : int
        Size of the median filter applied over the tile grid (1 = none).
    smoothed : (H, W) float32 array, optional
        ``smooth3(image)`` if the caller already has it.

    Returns
    -------
    Background
    """
    if not isinstance(method, str) or method not in METHODS:
        raise unknown_name("background method", method, METHODS)
    img = frame_f32(image)
    h, w = img.shape
    t, ny, nx, sy, sx, per_row = METHODS[method](h, w, tile)
    edges_y, edges_x = _tile_edges(h, ny), _tile_edges(w, nx)
    # The statistics need the smoothed frame only on the sampling lattice: without a smoothed
    # frame from the caller, the 3×3 kernel is evaluated at those points alone (a tenth of the
    # pixels or fewer), so the extractor can smooth and threshold in one later pass.
    if smoothed is None:
        sm = np.empty((0, 0), np.float32)
    else:
        sm = np.ascontiguousarray(smoothed, dtype=np.float32)
    lattice = _Lattice(edges_y, edges_x, sy, sx)
    samples = _lattice_samples(img, sm, lattice, per_row)
    med = samples.median
    if per_row:
        # levels of the raw rows; the smoothed frame sees each row mixed [1 2 1]/4 with its neighbours
        level_raw = med.reshape(ny, nx)
        padded = np.concatenate([level_raw[:1], level_raw, level_raw[-1:]])
        level = 0.25 * padded[:-2] + 0.5 * padded[1:-1] + 0.25 * padded[2:]
    else:
        level = med.reshape(ny, nx)
    if grid_filter > 1 and min(ny, nx) > 1:
        from scipy import ndimage

        level = ndimage.median_filter(level, size=grid_filter, mode="nearest")
    cy = 0.5 * (edges_y[:-1] + edges_y[1:]) - 0.5
    cx = 0.5 * (edges_x[:-1] + edges_x[1:]) - 0.5
    weights = grid_weights(cy, cx, (h, w))
    if not per_row:
        level_raw = level
    # noise about the interpolated sky, not the tile median, so a gradient across a tile is
    # not taken for noise
    is_int = is_integer_valued(img)
    stats, raw_res = _tile_noise(samples, lattice, level, level_raw, weights, is_int, not per_row)
    if not per_row:  # rows are one pixel tall: no gradient inside them to correct for
        level = level + stats[..., 0]
        level_raw = level
    noise_s = stats[..., 1]
    if grid_filter > 1 and min(ny, nx) > 1:
        from scipy import ndimage

        noise_s = ndimage.median_filter(noise_s, size=grid_filter, mode="nearest")
    # raw-pixel noise: one pooled robust estimate, spread over the tiles like the smoothed noise
    # residuals about the sky model: their median is near 0, a good first pivot
    raw_med, raw_sigma = robust_level_noise(raw_res, 1.0 if is_int else 0.0, False, 0.0)
    if is_int and raw_sigma < _QUANTISED_SIGMA and raw_res.size:
        # Noise below one level: most pixels share a value, so medians sit on the integer grid
        # while the sky's mean does not (a few tenths of a level, times hundreds of pixels in a
        # footprint), and the lower half of the distribution hides the noise. Use the clipped
        # mean for the level and the white-noise smoothing factor as a floor for the noise.
        near = np.abs(raw_res - raw_med) <= CLIP * max(raw_sigma, 1.0)
        delta = float(np.mean(raw_res[near]) - raw_med) if near.any() else 0.0
        level = level + delta
        level_raw = level_raw + delta
        noise_s = np.maximum(noise_s, _SMOOTH_WHITE * raw_sigma)
    ref_s = median_of(noise_s)
    kappa = raw_sigma / ref_s if ref_s > 0 else 1.0
    return Background(level=level_raw, noise=kappa * noise_s, level_smooth=level, noise_smooth=noise_s,
                      centers_y=cy, centers_x=cx, tile=t)


def frame_f32(image: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """A frame as the extraction's kernels take it: C-contiguous float32, whatever it was.

    One pixel type keeps each kernel to one compiled signature (8- and 16-bit frames given as
    they are compiled every kernel twice more: ~25 s of first use each, against a 0.15 ms
    conversion of a 1280 × 960 frame). Both integer types are exact in float32, and
    :func:`is_integer_valued` still sees their whole numbers. ``out``, a C-contiguous float32
    array of the frame's shape, receives the conversion if one is needed (the values
    ``astype`` gives).
    """
    if out is None or (image.dtype == np.float32 and image.flags.c_contiguous):
        return np.ascontiguousarray(image, dtype=np.float32)
    np.copyto(out, image, casting="unsafe")
    return out


def is_integer_valued(image: np.ndarray) -> bool:
    """Whether a frame holds whole numbers (8/16-bit data), judged on a sparse subsample."""
    a = np.asarray(image)
    if a.dtype.kind in "biu":
        return True
    if a.ndim == 2 and a.dtype in (np.float32, np.float64):
        return bool(_whole_on_lattice(a, 7, 5))
    sub = a[::7, ::5]
    return bool(np.array_equal(sub, np.floor(sub)))


@functools.lru_cache(maxsize=64)
def _tile_edges_cached(n: int, m: int) -> np.ndarray:
    edges = np.linspace(0, n, m + 1).round().astype(np.int64)
    edges.setflags(write=False)
    return edges


def _tile_edges(n: int, m: int) -> np.ndarray:
    """Edges of ``m`` near-equal tiles over ``n`` pixels, (m + 1,) int64 (read-only, cached)."""
    return _tile_edges_cached(int(n), int(m))


def smooth3(image: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """3×3 binomial smoothing ([1 2 1]ᵀ[1 2 1]/16), edges replicated; float32 (H, W).

    ``out``, if given, is a float32 array of the same shape that receives the result.
    """
    return smooth3_stats(image, out)[0]


def smooth3_stats(image: np.ndarray, out: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """:func:`smooth3`, plus the sum of the frame (non-finite if any pixel is)."""
    img = np.ascontiguousarray(image, dtype=np.float32)
    if out is None:
        out = np.empty(img.shape, np.float32)
    total = _smooth3(img, out)
    return out, float(total)


def interpolate_grid(grid: np.ndarray, centers_y: np.ndarray, centers_x: np.ndarray,
                     shape: tuple[int, int]) -> np.ndarray:
    """Bilinear interpolation of a tile grid to every pixel (linear beyond the outer centres)."""
    weights = grid_weights(centers_y, centers_x, shape)
    return _interp_full(np.ascontiguousarray(grid, dtype=np.float64), weights)


def median_of(values: np.ndarray) -> float:
    """Median of an array (as ``np.median``, without its per-call overhead on small arrays)."""
    return median(np.ascontiguousarray(values, dtype=np.float64).reshape(-1))


# --- numba kernels ------------------------------------------------------------------------


@njit(cache=True)
def _whole_on_lattice(a, sy, sx):
    """Whether every ``a[::sy, ::sx]`` is a whole number (False on NaN and ±inf).

    A row at a time, with no exit inside a row, so the test runs without a branch a sample:
    0.12 → 0.025 ms on an integer-valued 1280 × 960 frame (which every sample is).
    """
    for y in range(0, a.shape[0], sy):
        row = a[y]
        whole = True
        for x in range(0, a.shape[1], sx):
            v = row[x]
            whole &= (np.floor(v) == v) & (np.abs(v) < np.inf)
        if not whole:
            return False
    return True


@njit(cache=True, fastmath={"reassoc", "contract"})
def _smooth3(img, out):
    """Smooth into ``out``; returns the sum of the raw frame (non-finite if any pixel is)."""
    h, w = img.shape
    tmp = np.empty(w, np.float32)
    total = 0.0
    for y in range(h):
        ya, yb = max(y - 1, 0), min(y + 1, h - 1)
        acc = np.float32(0.0)
        for x in range(w):
            tmp[x] = column_sum(img, ya, y, yb, x)
            acc += img[y, x]
        total += acc
        smooth_row(tmp, out[y], w)
    return total


@njit(cache=True)
def _lattice_start(e0, e1, stride):
    """First sample of a lattice with ``stride`` centred in [e0, e1)."""
    return e0 + ((e1 - e0 - 1) % stride) // 2


def _lattice_samples(img: np.ndarray, sm: np.ndarray, lattice: _Lattice, of_raw: bool = False) -> _Samples:
    """The smoothed and raw frame on each tile's sampling lattice, and each tile's median.

    ``sm`` is the smoothed frame, or a 0×0 array to smooth at the lattice points only.
    Returns the :class:`_Samples`, with the medians of the smoothed samples (of the raw ones if
    ``of_raw``). Bands of tile rows are shared with the helper thread (:mod:`skyfix.detect._threads`).
    """
    edges_y, edges_x, sy, sx = lattice
    n_tiles = (edges_y.size - 1) * (edges_x.size - 1)
    cap = int((np.diff(edges_y).max() // sy + 1) * (np.diff(edges_x).max() // sx + 1))
    samples = _Samples(np.empty((n_tiles, cap)), np.empty((n_tiles, cap)), np.zeros(n_tiles, np.int64),
                       np.empty(n_tiles))
    edges = _tile_bands(lattice)
    run_chunks(lambda i: _lattice_rows(img, sm, lattice, of_raw, samples, edges[i], edges[i + 1]),
               len(edges) - 1)
    return samples


def _tile_bands(lattice: _Lattice) -> list[int]:
    """Bands of tile rows for the helper thread, about 150 tiles or more each."""
    ny, nx = lattice.edges_y.size - 1, lattice.edges_x.size - 1
    return split(ny, -(-150 // nx))


@njit(cache=True, nogil=True)
def _lattice_rows(img, sm, lattice, of_raw, samples, ty0, ty1):
    """:func:`_lattice_samples` for the tile rows ``ty0..ty1 − 1``, into ``samples``."""
    edges_y, edges_x, sy, sx = lattice
    smp, rawp, cnt, med = samples
    nx = edges_x.size - 1
    have_sm = sm.shape[0] > 0
    h, w = img.shape
    vsum = np.empty(w, np.float32)  # a lattice row's vertical [1 2 1] sums, as smooth3 has them
    buf = np.empty(smp.shape[1])
    for ty in range(ty0, ty1):
        row = 0  # lattice row within this row of tiles
        for y in range(_lattice_start(edges_y[ty], edges_y[ty + 1], sy), edges_y[ty + 1], sy):
            if not have_sm:
                ya, yb = max(y - 1, 0), min(y + 1, h - 1)
                for x in range(w):  # contiguous: vectorises, unlike per-sample 3×3 gathers
                    vsum[x] = column_sum(img, ya, y, yb, x)
            for tx in range(nx):
                t = ty * nx + tx
                x_first = _lattice_start(edges_x[tx], edges_x[tx + 1], sx)
                k = row * ((edges_x[tx + 1] - 1 - x_first) // sx + 1)
                for x in range(x_first, edges_x[tx + 1], sx):
                    rawp[t, k] = img[y, x]
                    if have_sm:
                        smp[t, k] = sm[y, x]
                    elif w == 1:
                        smp[t, k] = vsum[0] * np.float32(0.25)
                    else:
                        xa, xb = max(x - 1, 0), min(x + 1, w - 1)
                        smp[t, k] = smooth_at(vsum, xa, x, xb)
                    k += 1
                cnt[t] = k
            row += 1
        for tx in range(nx):
            t = ty * nx + tx
            k = cnt[t]
            src = rawp if of_raw else smp
            for i in range(k):
                buf[i] = src[t, i]
            # the previous tile's median (the one above at a row start) as the first pivot (the
            # median is the same whatever the pivot)
            guess = med[t - 1] if tx > 0 else (med[t - nx] if ty > ty0 else np.nan)
            med[t] = median_inplace(buf, k, guess)


class _NoiseIndex(NamedTuple):
    """What the tiles of :func:`_tile_noise` share (:func:`_noise_index`)."""

    start: np.ndarray  # (T + 1,) int64 — where each tile's pooled samples go
    col_start: np.ndarray  # (nx + 1,) int64 — each tile column's first lattice column
    along_x: np.ndarray  # (ny, lattice columns) float64 — the level along x at the tile-centre rows


def _tile_noise(samples: _Samples, lattice: _Lattice, level: np.ndarray, level_raw: np.ndarray,
                weights: GridWeights, is_int: bool, same_level: bool) -> tuple[np.ndarray, np.ndarray]:
    """Per tile, the median and lower-side clipped RMS of the smoothed frame minus the sky model.

    The median is a correction to the tile's level: a plain tile median of a sky with a
    gradient is as uncertain as the gradient is steep, the median about the model is not.
    ``samples``: the :class:`_Samples` of :func:`_lattice_samples` on ``lattice``; ``weights``
    the frame's :class:`~skyfix.detect._grid.GridWeights`. Returns the statistics as
    (ny, nx, 2), then the raw samples minus the sky pooled over about 64 tiles (in tile order).
    ``is_int``: the frame holds integers (quantised data); ``same_level``: ``level_raw`` is
    ``level``. Bands of tile rows are shared with the helper thread, each band starting from
    the statistics of the tile before it, so the result is the same whatever the bands.
    """
    ny, nx = lattice.edges_y.size - 1, lattice.edges_x.size - 1
    pool_every = max(1, (ny * nx) // 64)  # the tiles whose raw samples are pooled: every this many
    stats = np.empty((ny, nx, 2))
    pooled = np.empty(int(samples.count[::pool_every].sum()))
    edges = _tile_bands(lattice)
    run_chunks(lambda i: _tile_noise_tiles(samples, lattice, level, level_raw, weights, is_int, same_level,
                                           pool_every, stats, pooled, edges[i] * nx, edges[i + 1] * nx),
               len(edges) - 1)
    return stats, pooled


@njit(cache=True, inline="always")
def _noise_index(count, lattice, level, weights, pool_every):
    """:class:`_NoiseIndex` for :func:`_tile_noise`: the pooled tiles' places and the level
    interpolated along x at every tile-centre row, on the lattice columns (each sample's model
    is then one interpolation along y: the arithmetic of bilinear, in two steps)."""
    edges_y, edges_x, sy, sx = lattice
    ix, fx = weights.ix, weights.fx
    ny, nx = edges_y.size - 1, edges_x.size - 1
    start = np.zeros(ny * nx + 1, np.int64)
    for t in range(ny * nx):
        start[t + 1] = start[t] + (count[t] if t % pool_every == 0 else 0)
    col_start = np.zeros(nx + 1, np.int64)
    for tx in range(nx):
        x_first = _lattice_start(edges_x[tx], edges_x[tx + 1], sx)
        col_start[tx + 1] = col_start[tx] + (edges_x[tx + 1] - 1 - x_first) // sx + 1
    along_x = np.empty((ny, col_start[nx]))
    for tx in range(nx):
        c = col_start[tx]
        for x in range(_lattice_start(edges_x[tx], edges_x[tx + 1], sx), edges_x[tx + 1], sx):
            j = ix[x]
            j1 = min(j + 1, nx - 1)
            g = fx[x]
            for i in range(ny):
                along_x[i, c] = (1.0 - g) * level[i, j] + g * level[i, j1]
            c += 1
    return _NoiseIndex(start, col_start, along_x)


@njit(cache=True, nogil=True)
def _tile_noise_tiles(samples, lattice, level, level_raw, weights, is_int, same_level, pool_every, stats,
                      pooled, t0, t1):
    """:func:`_tile_noise` for the tiles ``t0..t1 − 1`` (row-major), into ``stats`` and ``pooled``.

    Each tile's lower-half median starts from the previous tile's offset below its median (a
    pivot, which changes the order the selection leaves the values in, and so the rounding of
    their RMS): the first tile of the band takes it from the tile before, measured again here.
    """
    index = _noise_index(samples.count, lattice, level, weights, pool_every)
    res = np.empty(samples.smooth.shape[1], np.float64)
    nx = lattice.edges_x.size - 1
    lower_offset = np.nan
    if t0 > 0:  # the offset the tile before would hand on (its value does not depend on pivots)
        med, _, lower = _tile_stats(samples, lattice, level_raw, weights, is_int, same_level, index, pooled,
                                    t0 - 1, res, np.nan, False)
        lower_offset = lower - med
    for t in range(t0, t1):
        med, sig, lower = _tile_stats(samples, lattice, level_raw, weights, is_int, same_level, index, pooled,
                                      t, res, lower_offset, t % pool_every == 0)
        lower_offset = lower - med
        stats[t // nx, t % nx, 0] = med
        stats[t // nx, t % nx, 1] = sig


@njit(cache=True, inline="always")
def _tile_stats(samples, lattice, level_raw, weights, is_int, same_level, index, pooled, t, res, lower_offset,
                pool):
    """Tile ``t``'s median, lower-side clipped RMS and lower-half median of its smoothed samples
    less the sky model (in ``res``); with ``pool``, its raw samples less the sky go to ``pooled``."""
    smp, rawp = samples.smooth, samples.raw
    edges_y, edges_x, sy, sx = lattice
    iy, fy = weights.iy, weights.fy
    ny, nx = edges_y.size - 1, edges_x.size - 1
    along_x, col_start, start = index.along_x, index.col_start, index.start
    ty, tx = t // nx, t % nx
    k = np.int64(0)  # typed (skyfix.detect._stats)
    for y in range(_lattice_start(edges_y[ty], edges_y[ty + 1], sy), edges_y[ty + 1], sy):
        i = iy[y]
        i1 = min(i + 1, ny - 1)
        f = fy[y]
        c = col_start[tx]
        for x in range(_lattice_start(edges_x[tx], edges_x[tx + 1], sx), edges_x[tx + 1], sx):
            model = (1.0 - f) * along_x[i, c] + f * along_x[i1, c]
            c += 1
            res[k] = smp[t, k] - model
            if pool:  # the raw residuals of the pooled tiles only
                if not same_level:
                    model = bilinear(level_raw, weights, y, x)
                pooled[start[t] + k] = rawp[t, k] - model
            k += 1
    # a 3×3 binomial mean of integers moves in steps of 1/16
    # first pivots: residuals about the sky model centre on 0; the lower half's median
    # sits about as far below as in the previous tile
    return tile_level_noise(res, k, 0.0625 if is_int else 0.0, 0.0, lower_offset)


@njit(cache=True)
def _interp_full(grid, weights):
    """A tile grid interpolated to every pixel, float32 (H, W)."""
    iy, fy, ix, fx = weights
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
