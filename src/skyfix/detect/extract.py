"""The default star extractor: background, k·σ threshold, connected components, centroids.

Pipeline of :func:`extract_centroids` (``method="components"``):

1. Tiled robust background and noise (:mod:`skyfix.detect.background`) of the raw frame and of
   the frame smoothed by a 3×3 binomial kernel (a cheap matched filter for a PSF of σ ≈ 1 px).
2. Pixels whose smoothed value exceeds the smoothed sky by ``sigma``·σ (more on the frame
   border, where smoothing averages fewer pixels) are grouped into 8-connected components
   (runs along rows joined by union-find, numba), which also records each component's size,
   box and summed excess.
3. Components that are too small, too large or too extended (Moon, roof edges) are dropped, and
   lone hot pixels (nearly all the light in one pixel) before the cap on measured candidates.
4. Touching stars are split at the saddle between prominent maxima (``deblend``).
5. Each candidate is measured on the raw frame minus the interpolated sky, over the component
   grown by one pixel so faint wings count: intensity-weighted centroid (negative residuals
   weigh zero), flux (plain sum), peak, second moments → elongation and direction, SNR, the
   centroid's noise σ, and saturation. A peak sharper than optics allow is a hot pixel: it is
   left out and the star measured again.
6. Rejections: hot pixels; particle tracks (narrower than starlight); diffuse blobs (foliage,
   cloud, nebulae: far larger ``flux/peak`` than the frame's typical star); anything in or next
   to a cluttered tile (tile noise > ``max_noise_ratio`` × the median: lit trees, roofs, a comet).
7. Optional refinement by IWCoG or a 2-D Gaussian fit (``centroid=``); sort by flux, cut to
   ``max_stars``.

Bad frames (constant, black, saturated, 1×1, too many non-finite pixels) give an empty list.

Speed (about 2–3 ms per megapixel on one core): the background needs the smoothed frame only on
its sampling lattice, so it comes first; smoothing, threshold, the frame's sum (non-finite
pixels) and maximum (saturation) then share one pass over the frame, which also flags the
64-pixel blocks holding detections so that the labelling skips empty sky. Steps 3 and 6 run
in numba, not as dozens of small numpy calls, and 8/16-bit frames are not converted to float.
Everything is serial: on a shared 2-core machine a parallel kernel waits for a descheduled
thread (measured: 40× slower under load with OpenMP's default spinning).
"""

from __future__ import annotations

import math
import threading

import numpy as np
from numba import njit

from skyfix.detect.background import (
    _F2,
    _F3,
    _F16,
    Background,
    _median_of,
    estimate_background,
    interp_weights,
)
from skyfix.detect.centroid import CENTROIDERS, refine_centroids
from skyfix.detect.centroids import Centroids
from skyfix.errors import ImageReadError, InputError
from skyfix.io import as_image
from skyfix.validate import check_count, check_positive

__all__ = ["METHODS", "extract_centroids", "saturation_level"]

METHODS = ("components", "threshold_hillclimb", "region_grow", "regionprops")

# Full-scale values of common integer sensors and of normalised float images.
_FULL_SCALES = (1.0, 255.0, 1023.0, 4095.0, 16383.0, 65535.0)
_MAX_COMPONENTS = 1 << 16
# A diffuse object must have a faint peak, below this many σ, to be dropped at the lower ratio.
_DIFFUSE_MAX_PEAK_SNR = 15.0
_DIFFUSE_PERCENTILE = 30
# Fraction of a component's positive raw light in its brightest pixel beyond which it is a hot
# pixel (a star centred on a pixel with PSF σ = 0.35 px puts 80% there).
_HOT_CONCENTRATION = 0.9
# A particle track's variance across, relative to a typical star's, is below this.
_TRACK_WIDTH_RATIO = 0.4


def extract_centroids(
    image: np.ndarray,
    *,
    sigma: float = 5.0,
    max_stars: int = 100,
    min_area: int = 3,
    max_area: int | None = None,
    max_extent: int | None = None,
    min_sharpness: float = 0.03,
    max_noise_ratio: float | None = 2.5,
    max_diffuseness: float | None = 3.0,
    max_elongation: float | None = None,
    saturation: float | None = None,
    tile: int | None = None,
    background: Background | None = None,
    method: str = "components",
    centroid: str = "com",
    gain: float | None = None,
    deblend: float | None = 0.3,
    reject_tracks: bool = True,
) -> Centroids:
    """Find stars in a frame and measure their centroids, brightest first.

    Parameters
    ----------
    image : (H, W) array
        The frame (any real dtype; colour is converted to luminance), ADU.
    sigma : float
        Detection threshold in units of the smoothed frame's noise σ (k in k·σ).
    max_stars : int
        Keep at most this many stars (the brightest by flux).
    min_area : int
        Smallest footprint (pixels above threshold in the smoothed frame) kept.
    max_area : int, optional
        Largest footprint kept; larger blobs are foreground, the Moon or a planet's glare.
        Default ``max(400, 0.002·H·W)`` pixels.
    max_extent : int, optional
        Largest bounding-box side kept, pixels. Default ``max(32, 0.06·min(H, W))``.
    min_sharpness : float
        Smallest ratio to the peak of the mean of its neighbours less the brightest one (all
        above sky). A hot pixel, or two side by side, is near 0 (noise/peak); a pixel-integrated
        Gaussian star gives at its least favourable sub-pixel phase 0.02 at PSF σ = 0.3 px,
        0.038 at 0.35 px, 0.06 at 0.4 px and 0.12 at 0.5 px. Optics that put a star's light in
        one pixel need calibration (:func:`hot_pixel_map`) and ``0`` here.
    max_noise_ratio : float, optional
        Drop stars in or next to a background tile whose noise exceeds this multiple of the
        frame's median noise: such tiles hold lit foreground (trees, roofs), a comet or glare,
        whose texture makes false stars. ``None`` keeps them. On the 21 real frames (two
        cameras and several phones/DSLRs) clear sky never exceeds 1.6× the median; lit
        foreground reaches 3–18×. A sky glow 6× brighter than the frame's median (shot-noise
        limited) would also be masked.
    max_diffuseness : float, optional
        Drop diffuse blobs (foliage, cloud, nebulae, galaxies): a faint object (peak below
        15σ) whose effective area ``flux/peak`` exceeds this multiple of the frame's typical
        star, or any unsaturated object beyond ``10/3`` times this multiple. The typical star
        is the 30th percentile of ``flux/peak`` over unsaturated candidates with SNR > 10.
        ``None`` keeps them.
    max_elongation : float, optional
        Drop stars more elongated than this (axis ratio); default keeps all (streaks count).
    saturation : float, optional
        Pixel level at or above which a star is flagged saturated. Default: the frame maximum
        when it is a full-scale value (1, 255, 1023, 4095, 16383, 65535 within 0.5%).
    tile : int, optional
        Background tile size, pixels (default: about 1/16 of the short side, 32–64).
    background : Background, optional
        A precomputed background (e.g. shared with another extraction of the same frame).
    method : {"components", "threshold_hillclimb", "region_grow", "regionprops"}
        Detection method: this module's connected components (default); thesis 000's global
        k·σ threshold with a 3×3 hill climb (:mod:`skyfix.detect.hillclimb`); thesis 004's
        every-third-pixel scan with 4-connected region growing (:mod:`skyfix.detect.region_grow`);
        thesis 003's threshold, 8-connected spots, area and eccentricity limits
        (:mod:`skyfix.detect.regionprops`; its smoothing/diffusion options are keywords there).
        The rejection options above apply to ``"components"`` only.
    centroid : {"com", "iwcog", "gaussian"}
        Centroider. ``"com"`` keeps each method's own centre of mass (for ``"components"``: the
        intensity-weighted CoM over the grown component); ``"iwcog"`` and ``"gaussian"`` refine
        it in a window (:mod:`skyfix.detect.centroid`); the Gaussian fit also gives the flux and
        the per-star covariance.
    gain : float, optional
        Electrons per ADU, for the refined centroids' weights and errors (see
        :func:`skyfix.detect.centroid.centroid_windows`).
    deblend : float, optional
        Split touching stars (``"components"`` only): a second maximum of the smoothed frame in
        the same component becomes its own star when it rises above the saddle toward a
        brighter maximum by this fraction of its height above the sky (and by 3σ), at least
        2 px away. Pixels go to the maximum their steepest ascent reaches. A component with more
        than 3 such maxima is texture and stays whole. ``None`` turns it off (e.g. for
        defocused, ring-shaped PSFs).

    reject_tracks : bool
        Drop cosmic-ray and other particle tracks (``"components"`` only): candidates longer
        than 2:1 and narrower across than a third of the typical star's variance (starlight,
        even trailed, keeps the PSF's width).

    Returns
    -------
    Centroids
        Empty for blank, constant, saturated or unreadable frames.

    Raises
    ------
    skyfix.errors.InputError
        An unknown method or centroider, ``sigma`` not a positive number, ``max_stars`` not a
        whole number >= 1.
    """
    if method not in METHODS:
        raise InputError(f"unknown detection method {method!r}; choose one of {', '.join(METHODS)}")
    if centroid not in CENTROIDERS:
        raise InputError(f"unknown centroider {centroid!r}; choose one of {', '.join(CENTROIDERS)}")
    sigma = check_positive(sigma, "sigma")
    max_stars = check_count(max_stars, "max_stars")
    try:
        raw = np.asarray(image)
        if method == "components" and centroid == "com" and raw.ndim == 2 and raw.size and raw.dtype in (
                np.uint8, np.uint16):
            # 8/16-bit frames go to the kernels as they are (no float32 copy; same numbers)
            img = np.ascontiguousarray(raw)
        else:
            # the default method finds non-finite pixels itself while smoothing (one pass less)
            img = as_image(image, name="image", replace_nonfinite=method != "components")
    except ImageReadError:
        return Centroids.empty((0, 0) if np.ndim(image) != 2 else np.shape(image), reason="unusable")
    h, w = img.shape
    if h < 3 or w < 3:
        return Centroids.empty((h, w), reason="too small")
    if method == "components":
        c = _components(img, sigma, max_stars, min_area, max_area, max_extent, min_sharpness,
                        max_noise_ratio, max_diffuseness, max_elongation, saturation, tile, background,
                        deblend, reject_tracks)
    elif method == "threshold_hillclimb":
        from skyfix.detect.hillclimb import extract_hillclimb

        c = extract_hillclimb(img, sigma=sigma, max_stars=max_stars, saturation=saturation)
    elif method == "region_grow":
        from skyfix.detect.region_grow import extract_region_grow

        c = extract_region_grow(img, sigma=sigma, max_stars=max_stars, saturation=saturation)
    else:
        from skyfix.detect.regionprops import extract_regionprops

        c = extract_regionprops(img, sigma=sigma, max_stars=max_stars, saturation=saturation)
    if centroid != "com" and len(c):
        c = _refine(img, c, centroid, gain, background, tile)
    return c


def _components(img, sigma, max_stars, min_area, max_area, max_extent, min_sharpness, max_noise_ratio,
                max_diffuseness, max_elongation, saturation, tile, background, deblend,
                reject_tracks) -> Centroids:
    """The default detector (module docstring, steps 1–5)."""
    args = (sigma, max_stars, min_area, max_area, max_extent, min_sharpness, max_noise_ratio, max_diffuseness,
            max_elongation, saturation, tile, background, deblend, reject_tracks)
    c = _components_pass(img, *args, check_finite=True)
    if c is None:  # NaN/Inf pixels (or an overflowing sum): replace them, then once more
        try:
            img = as_image(img, name="image")
        except ImageReadError:
            return Centroids.empty(img.shape, reason="mostly non-finite")
        c = _components_pass(img, *args, check_finite=False)
    return c


def _components_pass(img, sigma, max_stars, min_area, max_area, max_extent, min_sharpness, max_noise_ratio,
                     max_diffuseness, max_elongation, saturation, tile, background, deblend,
                     reject_tracks, check_finite) -> Centroids | None:
    """:func:`_components` on one frame; ``None`` if ``check_finite`` and a pixel is not finite."""
    h, w = img.shape
    # the background needs the smoothed frame only on its sampling lattice, so it comes first
    # and the full-frame smoothing, threshold, sum and maximum share one pass
    bg = estimate_background(img, tile=tile) if background is None else background
    level, noise = bg.global_level, bg.global_noise
    if not np.any(bg.noise_smooth > 0):
        if check_finite and not math.isfinite(float(img.sum(dtype=np.float64))):
            return None
        return Centroids.empty((h, w), level, noise, reason="flat frame")
    if max_area is None:
        max_area = int(max(400, 0.002 * h * w))
    if max_extent is None:
        max_extent = int(max(32, 0.06 * min(h, w)))

    iy, fy = interp_weights(bg.centers_y, h)
    ix, fx = interp_weights(bg.centers_x, w)
    # The threshold never falls below a tiny fraction of the frame's range, so an exactly
    # flat (noise-free) sky is not detected everywhere.
    floor = 1e-6 * max(1.0, float(np.abs(bg.level_smooth).max()))
    thr_grid = bg.level_smooth + np.maximum(sigma * bg.noise_smooth, floor)
    ws = _workspace(h, w)
    sm = ws.smooth
    is_float = img.dtype == np.float32
    total, vmax = _smooth_threshold(img, img.view(np.int32) if is_float else img, is_float, sm, ws.mask,
                                    ws.blocks, thr_grid, bg.level_smooth, iy, fy, ix, fx)
    if check_finite and not math.isfinite(total):
        return None
    if saturation is None:
        saturation = _full_scale(float(vmax))
    labels = ws.labels
    if ws.dirty is None:
        labels.fill(0)
    else:  # clear only what the last call labelled
        _clear_boxes(labels, ws.dirty)
    ws.dirty = None
    comps = _label(sm, img, labels, ws.mask, ws.blocks, bg.level_smooth, bg.level, iy, fy, ix, fx,
                   _MAX_COMPONENTS)
    ws.dirty = comps[:, 1:5].astype(np.int64)
    n_comp = comps.shape[0]
    if n_comp == 0:
        return Centroids.empty((h, w), level, noise, n_components=0)
    # a lone hot pixel holds nearly all of its component's light: dropped before the cap on
    # measured candidates, so that a frame with thousands of hot pixels still measures its stars.
    # Measure only the brightest candidates, with room for the clusters of hot pixels, blobs and
    # noise that the tests below remove (measuring costs ~1 µs per small candidate).
    ids, boxes = _candidates(comps, float(min_area), float(max_area), float(max_extent), min_sharpness > 0,
                             max(4 * int(max_stars) + 50, 200))
    n_cand = ids.size
    n_split = 0
    is_part = np.zeros(ids.size, bool)
    if deblend is not None and ids.size:
        ids, boxes, is_part = _deblend(sm, labels, ids, boxes, bg.level_smooth, bg.noise_smooth,
                                       iy, fy, ix, fx, n_comp + 1, float(deblend), 2.0, 3,
                                       img, bg.level, float(min_sharpness))
        n_split = ids.size - n_cand
    m = _measure(img, labels, ids, boxes, bg.level, iy, fy, ix, fx, float(saturation), float(min_sharpness))
    # rejections (module docstring, step 6) in one kernel: dozens of small numpy calls cost more
    noise_px, elong, snr, good = _screen(
        m, is_part, bg.noise, bg.noise_smooth, bg.centers_y, bg.centers_x, iy, fy, ix, fx, float(sigma),
        float(min_sharpness), math.inf if max_elongation is None else float(max_elongation), reject_tracks,
        math.nan if max_diffuseness is None else float(max_diffuseness),
        math.nan if max_noise_ratio is None else float(max_noise_ratio))
    x, y, flux, area, snr, elong, peak, sigma_x, sigma_y, angle, sat = _star_table(
        m, noise_px, elong, snr, good, int(max_stars))
    return Centroids(
        x=x, y=y, flux=flux, area=area, snr=snr, elongation=elong, peak=peak, sigma_x=sigma_x,
        sigma_y=sigma_y, saturated=sat > 0, image_shape=(h, w), background_level=level, noise=noise,
        angle=angle,
        meta={"n_components": int(n_comp), "n_deblended": int(n_split), "saturation": float(saturation),
              "tile": bg.tile},
    )


class _Workspace(threading.local):
    """Per-thread full-frame buffers reused between calls of the same frame size.

    Fresh multi-megabyte arrays cost page faults on every call (about as much as the
    smoothing itself); reusing them keeps a video-rate loop at its compute cost.
    """

    shape: tuple[int, int] = (0, 0)
    smooth: np.ndarray
    labels: np.ndarray
    mask: np.ndarray
    blocks: np.ndarray
    dirty: np.ndarray | None = None  # bounding boxes of the labels left by the last call


_WS = _Workspace()


def _workspace(h: int, w: int) -> _Workspace:
    if _WS.shape != (h, w):
        _WS.smooth = np.empty((h, w), np.float32)
        _WS.labels = np.empty((h, w), np.int32)
        _WS.mask = np.zeros((h, (w + 63) // 64 * 64), np.uint8)  # padding columns stay 0
        _WS.blocks = np.zeros((h, (w + 63) // 64), np.uint8)
        _WS.dirty = None
        _WS.shape = (h, w)
    return _WS


def _refine(img: np.ndarray, c: Centroids, centroid: str, gain: float | None,
            background: Background | None, tile: int | None) -> Centroids:
    """Re-centroid each star in a window with ``centroid``; keep the CoM where it fails."""
    bg = background
    if bg is None or bg.level.shape == ():
        bg = estimate_background(img, tile=tile)
    h, w = img.shape
    iy, fy = interp_weights(bg.centers_y, h)
    ix, fx = interp_weights(bg.centers_x, w)
    sky = _noise_at(bg.level, iy, fy, ix, fx, c.x, c.y)
    nz = _noise_at(bg.noise, iy, fy, ix, fx, c.x, c.y)
    # window: the footprint's equivalent radius plus 2 px of wings, 3–10 px
    half = np.clip(np.ceil(np.sqrt(np.maximum(c.area, 1.0) / np.pi)) + 2, 3, 10).astype(np.int64)
    r = refine_centroids(img, c.xy, sky, nz, half, method=centroid, gain=gain)
    x, y, flux, _peak, sx, sy, cxy, _npix, psx, psy, ok = r[:, :11].T
    ok = (ok > 0) & np.isfinite(x) & (np.hypot(x - c.x, y - c.y) < 1.5)
    new_flux = np.where(ok, flux, c.flux) if centroid == "gaussian" else c.flux
    order = np.argsort(-new_flux, kind="stable")
    big, small = np.maximum(psx, psy), np.maximum(np.minimum(psx, psy), 1e-6)
    out = Centroids(
        x=np.where(ok, x, c.x), y=np.where(ok, y, c.y), flux=new_flux, area=c.area,
        snr=np.where(ok, new_flux, c.flux) / np.maximum(nz * np.sqrt(np.maximum(c.area, 1.0)), 1e-30),
        elongation=np.where(ok & (centroid == "gaussian"), big / small, c.elongation), peak=c.peak,
        sigma_x=np.where(ok, sx, c.sigma_x), sigma_y=np.where(ok, sy, c.sigma_y),
        saturated=c.saturated, image_shape=c.image_shape, background_level=c.background_level,
        noise=c.noise, meta={**c.meta, "centroid": centroid, "refined": int(ok.sum())},
        cov_xy=np.where(ok, cxy, 0.0), angle=c.angle)
    return out.subset(order)


def saturation_level(image: np.ndarray) -> float:
    """The frame's saturation level: its maximum if that is a full-scale value, else +inf.

    Full scale means 1, 255, 1023, 4095, 16383 or 65535 within 0.5% (8- to 16-bit sensors and
    normalised floats). A frame whose brightest pixel is below full scale has no saturated star.
    """
    return _full_scale(float(np.max(image)))


def _full_scale(vmax: float) -> float:
    near = any(abs(f - vmax) <= 0.005 * f for f in _FULL_SCALES)  # six floats: no numpy call
    return vmax if near else math.inf


@njit(cache=True)
def _particle_tracks(minor_var, elong, snr, candidate):
    """Cosmic-ray and other particle tracks: narrower across than any starlight.

    Starlight passes the optics, so even a trailed star keeps the PSF's width across its
    trail; a particle track or hit is about one pixel wide. A candidate whose variance across
    is below ``_TRACK_WIDTH_RATIO`` of the frame's typical (compact, SNR > 10) star's and that is
    longer than 1.5:1 is a track; below half that ratio it is one whatever its length. Only
    candidates with SNR ≥ 20 are judged: a faint star's footprint holds just its core, so its
    moments look narrow too.
    """
    compact = candidate & (elong < 1.5) & (snr > 10.0)
    if compact.sum() < 3:
        return np.zeros(elong.size, np.bool_)
    rel = minor_var / _median_of(minor_var[compact])
    narrow = ((elong > 1.5) & (rel < _TRACK_WIDTH_RATIO)) | (rel < 0.5 * _TRACK_WIDTH_RATIO)
    return narrow & (snr >= 20.0)


@njit(cache=True)
def _diffuse(flux, peak, snr, peak_snr, saturated, candidate, ratio):
    """Objects far more spread out than the frame's typical star (see ``max_diffuseness``)."""
    aeff = flux / np.maximum(peak, 1e-30)
    typical = candidate & ~saturated & (snr > 10.0)
    if not typical.any():
        return np.zeros(flux.size, np.bool_)
    rel = aeff / _percentile_linear(aeff[typical], _DIFFUSE_PERCENTILE / 100.0)
    return ((rel > ratio) & (peak_snr < _DIFFUSE_MAX_PEAK_SNR)) | ((rel > ratio * 10.0 / 3.0) & ~saturated)


@njit(cache=True)
def _percentile_linear(v, q):
    """``np.percentile(v, 100·q)`` (linear method), with numpy's arithmetic."""
    a = np.sort(v)
    n = a.size
    vi = (n - 1) * q
    if vi >= n - 1:
        return a[n - 1]
    lo = int(math.floor(vi))
    gamma = vi - lo
    diff = a[lo + 1] - a[lo]
    if gamma >= 0.5:
        return a[lo + 1] - diff * (1.0 - gamma)
    return a[lo] + diff * gamma


@njit(cache=True)
def _cluttered(noise_smooth, centers_y, centers_x, x, y, ratio):
    """Positions in or next to a tile whose noise exceeds ``ratio`` × the frame's median noise.

    The neighbouring tiles count too because lit foreground thins out at its edge (the last
    leaves of a tree) while its tile noise is already back to normal.
    """
    ny, nx = noise_smooth.shape
    noisy = noise_smooth > ratio * _median_of(noise_smooth.ravel())
    out = np.zeros(x.size, np.bool_)
    if not noisy.any():
        return out
    if ny > 1 and nx > 1:
        grown = np.zeros_like(noisy)
        for i in range(ny):
            for j in range(nx):
                if noisy[i, j]:
                    grown[max(i - 1, 0):i + 2, max(j - 1, 0):j + 2] = True
        noisy = grown
    for c in range(x.size):
        out[c] = noisy[_nearest_index(centers_y, y[c]), _nearest_index(centers_x, x[c])]
    return out


@njit(cache=True)
def _nearest_index(centers, v):
    """Index of the nearest tile centre (the first one on a tie)."""
    best, bd = 0, abs(v - centers[0])
    for k in range(1, centers.size):
        d = abs(v - centers[k])
        if d < bd:
            best, bd = k, d
    return best


def _noise_at(grid, iy, fy, ix, fx, x, y):
    """Bilinearly interpolated noise σ at (rounded) positions."""
    if x.size == 0:
        return np.zeros(0)
    xi = np.clip(np.rint(x).astype(np.int64), 0, ix.size - 1)
    yi = np.clip(np.rint(y).astype(np.int64), 0, iy.size - 1)
    ny, nx = grid.shape
    i, j = iy[yi], ix[xi]
    i1, j1 = np.minimum(i + 1, ny - 1), np.minimum(j + 1, nx - 1)
    f, g = fy[yi], fx[xi]
    top = (1 - g) * grid[i, j] + g * grid[i, j1]
    bot = (1 - g) * grid[i1, j] + g * grid[i1, j1]
    return np.maximum((1 - f) * top + f * bot, 1e-12)


# --- numba kernels ------------------------------------------------------------------------


@njit(cache=True)
def _candidates(comps, min_area, max_area, max_extent, drop_hot, cap):
    """Labels and boxes of the components worth measuring, by decreasing summed excess.

    Size and extent limits; with ``drop_hot``, lone hot pixels (nearly all of the component's
    light in one pixel); at most ``cap``, the brightest (ties keep label order).
    """
    n = comps.shape[0]
    keep = np.empty(n, np.int64)
    k = 0
    for c in range(n):
        area = comps[c, 0]
        extent = max(comps[c, 2] - comps[c, 1], comps[c, 4] - comps[c, 3]) + 1
        ok = area >= min_area and area <= max_area and extent <= max_extent
        if drop_hot and not comps[c, 6] < _HOT_CONCENTRATION * max(comps[c, 7], 1e-30):
            ok = False
        if ok:
            keep[k] = c
            k += 1
    idx = keep[:k]
    order = np.argsort(-comps[idx, 5], kind="mergesort")  # stable
    idx = idx[order[:cap]]
    ids = (idx + 1).astype(np.int32)
    boxes = np.empty((idx.size, 4), np.int64)
    for i in range(idx.size):
        for j in range(4):
            boxes[i, j] = np.int64(comps[idx[i], 1 + j])
    return ids, boxes


@njit(cache=True)
def _star_table(m, noise_px, elong, snr, good, max_stars):
    """The kept stars by decreasing flux (ties keep candidate order), at most ``max_stars``.

    Returns x, y, flux, area, snr, elongation, peak, sigma_x, sigma_y, angle, saturated pixels.
    """
    sel = np.flatnonzero(good)
    sel = sel[np.argsort(-m[sel, 0], kind="mergesort")][:max_stars]
    flux = m[sel, 0]
    nz = noise_px[sel]
    sigma_x = nz * np.sqrt(m[sel, 9]) / flux
    sigma_y = nz * np.sqrt(m[sel, 10]) / flux
    angle = 0.5 * np.arctan2(2.0 * m[sel, 8], m[sel, 6] - m[sel, 7])
    return (m[sel, 1], m[sel, 2], flux, m[sel, 3], snr[sel], elong[sel], m[sel, 4], sigma_x, sigma_y, angle,
            m[sel, 11])


@njit(cache=True)
def _screen(m, is_part, noise_grid, noise_smooth, centers_y, centers_x, iy, fy, ix, fx, sigma, min_sharpness,
            max_elongation, reject_tracks, max_diffuseness, max_noise_ratio):
    """Noise, elongation and SNR of the measured candidates, and which of them are stars.

    ``m`` is :func:`_measure`'s table. The tests run in this order, each on the survivors of the
    ones before: flux > 0, sharpness, hot pixels, ``max_elongation`` (``inf``: none), particle
    tracks (:func:`_particle_tracks`), diffuse blobs (:func:`_diffuse`, ``max_diffuseness``
    NaN: none), cluttered tiles (:func:`_cluttered`, ``max_noise_ratio`` NaN: none).
    Returns (noise_px, elongation, snr, good).
    """
    n = m.shape[0]
    noise_px = np.empty(n)
    elong = np.empty(n)
    snr = np.empty(n)
    minor = np.empty(n)
    good = np.zeros(n, np.bool_)
    ny, nx = noise_grid.shape
    for c in range(n):
        flux, x, y, npix = m[c, 0], m[c, 1], m[c, 2], m[c, 3]
        mxx, myy, mxy = m[c, 6], m[c, 7], m[c, 8]
        # noise at the rounded position, bilinear in the grid (as _noise_at)
        xi = min(max(int(np.rint(x)), 0), ix.size - 1)
        yi = min(max(int(np.rint(y)), 0), iy.size - 1)
        i, j = iy[yi], ix[xi]
        i1, j1 = min(i + 1, ny - 1), min(j + 1, nx - 1)
        f, g = fy[yi], fx[xi]
        top = (np.float32(1.0) - g) * noise_grid[i, j] + g * noise_grid[i, j1]
        bot = (np.float32(1.0) - g) * noise_grid[i1, j] + g * noise_grid[i1, j1]
        noise_px[c] = max((np.float32(1.0) - f) * top + f * bot, 1e-12)
        tr = mxx + myy
        det = math.sqrt(max((mxx - myy) * (mxx - myy) + 4.0 * (mxy * mxy), 0.0))
        # the 1/12 px² of a uniform pixel keeps a one-pixel object's minor axis above zero
        lam1, lam2 = 0.5 * (tr + det) + 1.0 / 12.0, max(0.5 * (tr - det), 0.0) + 1.0 / 12.0
        elong[c] = math.sqrt(lam1 / lam2)
        minor[c] = 0.5 * (tr - det)
        snr[c] = flux / (noise_px[c] * math.sqrt(max(npix, 1.0)))
        # hot pixels: too sharp even after leaving out up to 3 of them, or nothing left but
        # noise; a deblended part around a hot pixel is only a neighbouring star's wing
        good[c] = (flux > 0) and (m[c, 5] >= min_sharpness) and (
            m[c, 12] == 0 or (snr[c] >= sigma and not is_part[c]))
        if elong[c] > max_elongation:
            good[c] = False
    if reject_tracks:
        good &= ~_particle_tracks(minor, elong, snr, good)
    if not math.isnan(max_diffuseness):
        good &= ~_diffuse(m[:, 0], m[:, 4], snr, m[:, 4] / noise_px, m[:, 11] > 0, good, max_diffuseness)
    if not math.isnan(max_noise_ratio):
        good &= ~_cluttered(noise_smooth, centers_y, centers_x, m[:, 1], m[:, 2], max_noise_ratio)
    return noise_px, elong, snr, good


@njit(cache=True)
def _clear_boxes(labels, boxes):
    for k in range(boxes.shape[0]):
        for y in range(boxes[k, 0], boxes[k, 1] + 1):
            for x in range(boxes[k, 2], boxes[k, 3] + 1):
                labels[y, x] = 0


@njit(cache=True)
def _grid_at(grid, iy, fy, ix, fx, y, x):
    """Bilinear value of a tile grid at pixel (y, x)."""
    ny, nx = grid.shape
    i, j = iy[y], ix[x]
    i1, j1 = min(i + 1, ny - 1), min(j + 1, nx - 1)
    f, g = fy[y], fx[x]
    top = (1.0 - g) * grid[i, j] + g * grid[i, j1]
    bot = (1.0 - g) * grid[i1, j] + g * grid[i1, j1]
    return (1.0 - f) * top + f * bot


# Noise σ of the 3×3 binomial mean with replicated edges, relative to the interior:
# [3 1]/4 along a border axis has Σw² = 10/16 against 6/16.
_EDGE_NOISE = math.sqrt(10.0 / 6.0)


@njit(cache=True)
def _threshold_at(thr_grid, bg_grid, iy, fy, ix, fx, y, x, h, w):
    """Detection threshold at (y, x), raised on the frame border where smoothing averages less."""
    t = _grid_at(thr_grid, iy, fy, ix, fx, y, x)
    fac = 1.0
    if y == 0 or y == h - 1:
        fac *= _EDGE_NOISE
    if x == 0 or x == w - 1:
        fac *= _EDGE_NOISE
    if fac == 1.0:
        return t
    b = _grid_at(bg_grid, iy, fy, ix, fx, y, x)
    return b + (t - b) * fac


@njit(cache=True)
def _grid_rows(grid, ix, fx, w):
    """A tile grid interpolated along x at each tile-centre row, and the row-to-row step."""
    ny, nx = grid.shape
    r0 = np.empty((ny, w), np.float32)
    dr = np.empty((ny, w), np.float32)
    for i in range(ny):
        for x in range(w):
            a = ix[x]
            r0[i, x] = (1.0 - fx[x]) * grid[i, a] + fx[x] * grid[i, min(a + 1, nx - 1)]
    for i in range(ny):
        for x in range(w):
            dr[i, x] = r0[min(i + 1, ny - 1), x] - r0[i, x]
    return r0, dr


@njit(cache=True, fastmath={"reassoc", "contract"})
def _smooth_threshold(img, bits, float_bits, sm, mask, blocks, thr_grid, bg_grid, iy, fy, ix, fx):
    """One pass over the frame: :func:`smooth3` into ``sm``, ``sm > threshold`` into ``mask``.

    ``bits`` is a float32 ``img`` viewed as int32 (``float_bits``), or an unsigned integer
    ``img`` itself (its values are their own order); ``mask`` a (H, W rounded up to 64) uint8
    frame and ``blocks`` (H, W/64 rounded up) flags whether each 64-pixel block of a mask row has
    a pixel set (so the labelling skips empty sky without reading it). The threshold grid is
    interpolated bilinearly (raised on the border, :func:`_threshold_at`).
    Returns the sum of the raw frame (non-finite if any pixel is) and its maximum.
    Reassociation lets the row loops vectorise; NaN and Inf still propagate (no "nnan"/"ninf").
    The arithmetic is float32, as :func:`smooth3`'s (exact on 8- to 16-bit data).
    """
    h, w = img.shape
    # the threshold grid interpolated along x at the tile-centre rows: any pixel row is then
    # r0 + f·dr, one fused multiply-add per pixel
    t0, dt = _grid_rows(thr_grid, ix, fx, w)
    tmp = np.empty(w, np.float32)
    total = 0.0
    top = np.int32(-(2**31))
    for y in range(h):
        ya, yb = max(y - 1, 0), min(y + 1, h - 1)
        acc = np.float32(0.0)
        for x in range(w):
            v = img[y, x]
            tmp[x] = img[ya, x] + _F2 * v + img[yb, x]
            acc += v
            # the maximum on the float's bits made monotonic as int32: a float max reduction
            # does not vectorise without "nnan", an integer one does
            b = bits[y, x]
            top = max(top, b ^ ((b >> 31) & np.int32(0x7FFFFFFF)))
        total += acc
        out = sm[y]
        if w == 1:
            out[0] = tmp[0] * np.float32(0.25)
        else:
            out[0] = (_F3 * tmp[0] + tmp[1]) * _F16
            for x in range(1, w - 1):
                out[x] = (tmp[x - 1] + _F2 * tmp[x] + tmp[x + 1]) * _F16
            out[w - 1] = (tmp[w - 2] + _F3 * tmp[w - 1]) * _F16
        i = iy[y]
        f = np.float32(fy[y])
        m = mask[y]
        for x in range(w):
            m[x] = out[x] > t0[i, x] + f * dt[i, x]
        # border pixels: the replicated edge makes their smoothed noise larger
        if y == 0 or y == h - 1:
            for x in range(w):
                m[x] = out[x] > _threshold_at(thr_grid, bg_grid, iy, fy, ix, fx, y, x, h, w)
        else:
            m[0] = out[0] > _threshold_at(thr_grid, bg_grid, iy, fy, ix, fx, y, 0, h, w)
            m[w - 1] = out[w - 1] > _threshold_at(thr_grid, bg_grid, iy, fy, ix, fx, y, w - 1, h, w)
        words = m.view(np.uint64)
        for c in range(blocks.shape[1]):
            any_set = np.uint64(0)
            for wi in range(8 * c, 8 * c + 8):
                any_set |= words[wi]
            blocks[y, c] = any_set != 0
    if not float_bits:
        return total, float(top)
    top ^= (top >> 31) & np.int32(0x7FFFFFFF)
    return total, float(np.array([top], np.int32).view(np.float32)[0])


@njit(cache=True)
def _label(sm, img, labels, mask, blocks, bg_grid, raw_bg_grid, iy, fy, ix, fx, max_components):
    """8-connected components of the pixels set in ``mask``; labels are 1-based.

    ``mask`` and ``blocks`` are the frames of :func:`_smooth_threshold`. Components are numbered
    in the raster order of their first pixel (as a flood fill from a raster scan numbers them);
    those beyond ``max_components`` stay unlabelled. Works on runs of set pixels along rows,
    joined to the touching runs of the row above by union-find: the frame is read row by row
    (a flood fill's scattered reads wait on memory). Returns (K, 8) float64: area, ymin, ymax,
    xmin, xmax, summed excess of ``sm`` over the sky, and of the raw frame the highest pixel and
    the sum of positive pixels above the sky.
    """
    h, w = sm.shape
    b0, db = _grid_rows(bg_grid, ix, fx, w)
    q0, dq = _grid_rows(raw_bg_grid, ix, fx, w)
    n_blocks = 0
    for y in range(h):
        for c in range(blocks.shape[1]):
            n_blocks += blocks[y, c] != 0
    cap = 32 * n_blocks + 1  # a 64-pixel block holds at most 32 runs
    run_y = np.empty(cap, np.int64)
    run_x0 = np.empty(cap, np.int64)
    run_x1 = np.empty(cap, np.int64)
    parent = np.empty(cap, np.int64)
    run_excess = np.empty(cap)
    run_peak = np.empty(cap)
    run_sum = np.empty(cap)
    nr = 0
    prev_start = prev_end = 0
    for y in range(h):
        words = mask[y].view(np.uint64)
        cur_start = nr
        i = iy[y]
        f = fy[y]
        for c in range(blocks.shape[1]):
            if blocks[y, c] == 0:
                continue
            for wi in range(8 * c, 8 * c + 8):
                if words[wi] == 0:
                    continue
                for x in range(8 * wi, min(8 * wi + 8, w)):
                    if mask[y, x] == 0:
                        continue
                    if nr == cur_start or run_x1[nr - 1] != x - 1:
                        run_y[nr] = y
                        run_x0[nr] = x
                        parent[nr] = nr
                        run_excess[nr] = 0.0
                        run_peak[nr] = -np.inf
                        run_sum[nr] = 0.0
                        nr += 1
                    run_x1[nr - 1] = x
                    run_excess[nr - 1] += sm[y, x] - (b0[i, x] + f * db[i, x])
                    r = img[y, x] - (q0[i, x] + f * dq[i, x])
                    run_peak[nr - 1] = max(run_peak[nr - 1], r)
                    run_sum[nr - 1] += max(r, 0.0)
        # join each run to the runs of the row above that touch it (8-connected), both in x order
        k0 = prev_start
        for j in range(cur_start, nr):
            while k0 < prev_end and run_x1[k0] < run_x0[j] - 1:
                k0 += 1
            k = k0
            while k < prev_end and run_x0[k] <= run_x1[j] + 1:
                # union, the earlier run (in raster order) becoming the root
                a = k
                while parent[a] != a:
                    parent[a] = parent[parent[a]]
                    a = parent[a]
                bb = j
                while parent[bb] != bb:
                    parent[bb] = parent[parent[bb]]
                    bb = parent[bb]
                if a < bb:
                    parent[bb] = a
                elif bb < a:
                    parent[a] = bb
                k += 1
        prev_start, prev_end = cur_start, nr
    # component numbers: roots in raster order (each root is its component's first run)
    rank = np.empty(nr, np.int64)
    k = 0
    for r in range(nr):
        a = r
        while parent[a] != a:
            a = parent[a]
        parent[r] = a
        if a == r:
            rank[r] = k
            k += 1
    n_comp = min(k, max_components)
    comps = np.zeros((n_comp, 8))
    for c in range(n_comp):
        comps[c, 1] = h
        comps[c, 3] = w
        comps[c, 2] = comps[c, 4] = -1.0
        comps[c, 6] = -np.inf
    for r in range(nr):
        c = rank[parent[r]]
        if c >= n_comp:
            continue
        y, x0, x1 = run_y[r], run_x0[r], run_x1[r]
        comps[c, 0] += x1 - x0 + 1
        comps[c, 1] = min(comps[c, 1], y)
        comps[c, 2] = max(comps[c, 2], y)
        comps[c, 3] = min(comps[c, 3], x0)
        comps[c, 4] = max(comps[c, 4], x1)
        comps[c, 5] += run_excess[r]
        comps[c, 6] = max(comps[c, 6], run_peak[r])
        comps[c, 7] += run_sum[r]
        for x in range(x0, x1 + 1):
            labels[y, x] = c + 1
    return comps


@njit(cache=True)
def _ascent_step(sm, labels, lab, first_new, y, x):
    """One step of steepest ascent on ``sm`` inside one component (original or split labels).

    The highest neighbour (the first in scan order among equals), or (y, x) at a maximum.
    """
    h, w = sm.shape
    by, bx = y, x
    for qy in range(max(y - 1, 0), min(y + 2, h)):
        for qx in range(max(x - 1, 0), min(x + 2, w)):
            lv = labels[qy, qx]
            if (lv == lab or lv >= first_new) and sm[qy, qx] > sm[by, bx]:
                by, bx = qy, qx
    return by, bx


@njit(cache=True)
def _saddle(sm, y0, x0, y1, x1):
    """Lowest value of ``sm`` on the straight segment between two pixels."""
    n = max(abs(y1 - y0), abs(x1 - x0))
    lo = min(sm[y0, x0], sm[y1, x1])
    for k in range(1, n):
        t = k / n
        lo = min(lo, sm[int(round(y0 + t * (y1 - y0))), int(round(x0 + t * (x1 - x0)))])
    return lo


@njit(cache=True)
def _deblend(sm, labels, ids, boxes, bg_grid, noise_grid, iy, fy, ix, fx, next_label, contrast, min_sep,
             max_parts, img, raw_bg_grid, min_sharpness):
    """Split components with several prominent maxima; returns the new (ids, boxes, is_part).

    New labels are allocated from ``next_label`` upward; the component keeps its label for the
    part around its highest maximum. Scratch arrays are allocated once, not per component.
    """
    h, w = sm.shape
    n_in = ids.size
    cap = 1
    for c in range(n_in):
        cap = max(cap, (boxes[c, 1] - boxes[c, 0] + 1) * (boxes[c, 3] - boxes[c, 2] + 1))
    my = np.empty(cap, np.int64)
    mx = np.empty(cap, np.int64)
    mv = np.empty(cap, sm.dtype)
    ky = np.empty(cap, np.int64)
    kx = np.empty(cap, np.int64)
    kept = np.empty(cap, np.int64)
    step = np.empty(cap, np.int64)
    root = np.empty(cap, np.int64)
    n_max_out = n_in * max(max_parts, 1)
    ids_out = np.empty(n_max_out, np.int32)
    boxes_out = np.empty((n_max_out, 4), np.int64)
    split_out = np.zeros(n_max_out, np.bool_)
    n = 0
    nxt = next_label
    for c in range(n_in):
        lab = ids[c]
        y0, y1, x0, x1 = boxes[c, 0], boxes[c, 1], boxes[c, 2], boxes[c, 3]
        nm = 0
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                if labels[y, x] != lab:
                    continue
                v = sm[y, x]
                is_max = True
                for qy in range(max(y - 1, 0), min(y + 2, h)):
                    for qx in range(max(x - 1, 0), min(x + 2, w)):
                        if (qy != y or qx != x) and labels[qy, qx] == lab:
                            u = sm[qy, qx]
                            # ties: the first in scan order wins
                            if u > v or (u == v and (qy < y or (qy == y and qx < x))):
                                is_max = False
                                break
                    if not is_max:
                        break
                if is_max:
                    # a hot pixel is no star to split off: the measurement leaves it out later
                    r = _residual(img, raw_bg_grid, iy, fy, ix, fx, y, x)
                    if _sharpness(img, raw_bg_grid, iy, fy, ix, fx, y, x, r) < min_sharpness:
                        continue
                    my[nm] = y
                    mx[nm] = x
                    mv[nm] = v
                    nm += 1
        nk = 1
        kept[0] = 0
        if nm > 1:
            order = np.argsort(-mv[:nm])
            ky[0] = my[order[0]]
            kx[0] = mx[order[0]]
            kept[0] = order[0]
            for r in range(1, order.size):
                i = order[r]
                yy, xx = my[i], mx[i]
                near = False
                col = -np.inf
                for j in range(nk):
                    if (ky[j] - yy) ** 2 + (kx[j] - xx) ** 2 < min_sep**2:
                        near = True
                    col = max(col, _saddle(sm, yy, xx, ky[j], kx[j]))
                if near:
                    continue
                height = mv[i] - _grid_at(bg_grid, iy, fy, ix, fx, yy, xx)
                prom = mv[i] - col
                if prom >= contrast * height and prom >= 3.0 * _grid_at(noise_grid, iy, fy, ix, fx, yy, xx):
                    ky[nk] = yy
                    kx[nk] = xx
                    kept[nk] = i
                    nk += 1
        # no maximum, one, or more than a few prominent ones (texture: foliage, nebula, left for
        # the diffuseness test): the component stays whole
        if nm == 0 or nk < 2 or nk > max_parts:
            ids_out[n] = lab
            boxes_out[n, 0], boxes_out[n, 1], boxes_out[n, 2], boxes_out[n, 3] = y0, y1, x0, x1
            split_out[n] = False
            n += 1
            continue
        first_new = nxt
        part_label = np.empty(nk, np.int32)
        part_label[0] = lab
        for k in range(1, nk):
            part_label[k] = nxt
            nxt += 1
        # assign every pixel to the kept maximum its ascent reaches (else the nearest one); the
        # ascent graph is fixed while labels change (the eligible pixels stay eligible), so each
        # pixel's step is found once and the paths are shared
        bw = x1 - x0 + 1
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                li = (y - y0) * bw + (x - x0)
                lv = labels[y, x]
                root[li] = -2  # not in the component
                if lv != lab and lv < first_new:
                    continue
                root[li] = -1
                by, bx = _ascent_step(sm, labels, lab, first_new, y, x)
                step[li] = (by - y0) * bw + (bx - x0)
        for li in range(bw * (y1 - y0 + 1)):
            if root[li] != -1:
                continue
            j = li
            while root[j] == -1 and step[j] != j:
                j = step[j]
            end = root[j] if root[j] >= 0 else j
            j = li
            while root[j] == -1:
                root[j] = end
                j = step[j]
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                li = (y - y0) * bw + (x - x0)
                if root[li] < 0:
                    continue
                ty, tx = y0 + root[li] // bw, x0 + root[li] % bw
                best = -1
                bd = np.inf
                for k in range(nk):
                    d = (ky[k] - ty) ** 2 + (kx[k] - tx) ** 2
                    if d < bd:
                        bd, best = d, k
                labels[y, x] = part_label[best]
        for k in range(nk):
            by0, by1, bx0, bx1 = h, -1, w, -1
            for y in range(y0, y1 + 1):
                for x in range(x0, x1 + 1):
                    if labels[y, x] == part_label[k]:
                        by0, by1 = min(by0, y), max(by1, y)
                        bx0, bx1 = min(bx0, x), max(bx1, x)
            if by1 >= 0:
                ids_out[n] = part_label[k]
                boxes_out[n, 0], boxes_out[n, 1], boxes_out[n, 2], boxes_out[n, 3] = by0, by1, bx0, bx1
                split_out[n] = True
                n += 1
    return ids_out[:n].copy(), boxes_out[:n].copy(), split_out[:n].copy()


@njit(cache=True)
def _residual(img, bg_grid, iy, fy, ix, fx, y, x):
    return img[y, x] - _grid_at(bg_grid, iy, fy, ix, fx, y, x)


@njit(cache=True)
def _sharpness(img, bg_grid, iy, fy, ix, fx, py, px, peak):
    """Mean of the neighbours of (py, px) but the brightest, over the peak, above the sky.

    Leaving out the brightest neighbour makes two adjacent hot pixels as sharp as one, while a
    star centred between two pixels keeps its other neighbours.
    """
    h, w = img.shape
    nb = 0.0
    top = -np.inf
    cnt = 0
    for qy in range(max(py - 1, 0), min(py + 2, h)):
        for qx in range(max(px - 1, 0), min(px + 2, w)):
            if qy != py or qx != px:
                r = _residual(img, bg_grid, iy, fy, ix, fx, qy, qx)
                nb += r
                top = max(top, r)
                cnt += 1
    if cnt < 2 or peak <= 0:
        return 0.0
    return ((nb - top) / (cnt - 1)) / peak


@njit(cache=True)
def _measure(img, labels, ids, boxes, bg_grid, iy, fy, ix, fx, saturation, min_sharpness):
    """Centroid and moments of each component grown by one pixel, on the raw frame minus sky.

    A peak sharper than ``min_sharpness`` is a hot pixel: it is left out and the component
    measured again (up to 3 times), so a hot pixel on a star does not take the star with it.

    Returns (K, 13): flux, x, y, npix, peak, sharpness, mxx, myy, mxy, Σ(x-x̄)², Σ(y-ȳ)², nsat,
    number of hot pixels left out.
    """
    h, w = img.shape
    out = np.zeros((ids.size, 13))
    skip_y = np.empty(4, np.int64)
    skip_x = np.empty(4, np.int64)
    for c in range(ids.size):
        lab = ids[c]
        y0, y1 = max(boxes[c, 0] - 1, 0), min(boxes[c, 1] + 1, h - 1)
        x0, x1 = max(boxes[c, 2] - 1, 0), min(boxes[c, 3] + 1, w - 1)
        nskip = 0
        for _attempt in range(4):
            sw = swx = swy = swxx = swyy = swxy = 0.0
            total = 0.0  # plain sum: clipping negative pixels would bias faint fluxes up
            sx = sy = sxx = syy = 0.0
            npix = 0
            nsat = 0
            peak = -np.inf
            py = px = 0
            for y in range(y0, y1 + 1):
                for x in range(x0, x1 + 1):
                    lv = labels[y, x]
                    if lv != lab:
                        if lv != 0:
                            continue
                        near = False
                        for qy in range(max(y - 1, 0), min(y + 2, h)):
                            for qx in range(max(x - 1, 0), min(x + 2, w)):
                                if labels[qy, qx] == lab:
                                    near = True
                                    break
                            if near:
                                break
                        if not near:
                            continue
                    skipped = False
                    for i in range(nskip):
                        if skip_y[i] == y and skip_x[i] == x:
                            skipped = True
                    if skipped:
                        continue
                    r = _residual(img, bg_grid, iy, fy, ix, fx, y, x)
                    npix += 1
                    total += r
                    sx += x
                    sy += y
                    sxx += x * x
                    syy += y * y
                    if img[y, x] >= saturation:
                        nsat += 1
                    if r > peak:
                        peak, py, px = r, y, x
                    if r > 0.0:
                        sw += r
                        swx += r * x
                        swy += r * y
                        swxx += r * x * x
                        swyy += r * y * y
                        swxy += r * x * y
            if sw <= 0.0:
                break
            sharp = _sharpness(img, bg_grid, iy, fy, ix, fx, py, px, peak)
            if sharp >= min_sharpness or nskip == skip_y.size:
                break
            skip_y[nskip] = py
            skip_x[nskip] = px
            nskip += 1
        if sw <= 0.0:
            continue
        xc, yc = swx / sw, swy / sw
        out[c, 0] = total
        out[c, 1] = xc
        out[c, 2] = yc
        out[c, 3] = npix
        out[c, 4] = peak
        out[c, 5] = sharp
        out[c, 6] = max(swxx / sw - xc * xc, 0.0)
        out[c, 7] = max(swyy / sw - yc * yc, 0.0)
        out[c, 8] = swxy / sw - xc * yc
        out[c, 9] = max(sxx - 2.0 * xc * sx + npix * xc * xc, 0.0)
        out[c, 10] = max(syy - 2.0 * yc * sy + npix * yc * yc, 0.0)
        out[c, 11] = nsat
        out[c, 12] = nskip
    return out
