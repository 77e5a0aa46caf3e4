"""The default star extractor: background, k·σ threshold, connected components, centroids.

:func:`extract_components` (``method="components"`` of :func:`skyfix.detect.extract_centroids`)
runs, each step in its own module:

1. Tiled robust background and noise (:mod:`skyfix.detect.background`) of the raw frame and of
   the frame smoothed by a 3×3 binomial kernel (a cheap matched filter for a PSF of σ ≈ 1 px).
2. Pixels whose smoothed value exceeds the smoothed sky by ``sigma``·σ (more on the frame
   border, where smoothing averages fewer pixels) are grouped into 8-connected components
   (runs along rows joined by union-find, numba), which also records each component's size,
   box and summed excess (:mod:`skyfix.detect.labelling`).
3. Components that are too small, too large or too extended (Moon, roof edges) are dropped, and
   lone hot pixels (nearly all the light in one pixel) before the cap on measured candidates.
4. Touching stars are split at the saddle between prominent maxima
   (:mod:`skyfix.detect.deblend`).
5. Each candidate is measured on the raw frame minus the interpolated sky, over the component
   grown by one pixel so faint wings count: intensity-weighted centroid (negative residuals
   weigh zero), flux (plain sum), peak, second moments → elongation and direction, SNR, the
   centroid's noise σ, and saturation. A peak sharper than optics allow is a hot pixel: it is
   left out and the star measured again (:mod:`skyfix.detect.measure`).
6. Rejections: hot pixels; particle tracks (narrower than starlight); diffuse blobs (foliage,
   cloud, nebulae: far larger ``flux/peak`` than the frame's typical star); anything in or next
   to a cluttered tile (tile noise > ``max_noise_ratio`` × the median: lit trees, roofs, a comet)
   (:mod:`skyfix.detect.screen`).
7. Sort by flux, cut to ``max_stars`` (refinement by another centroider is
   :func:`~skyfix.detect.extract_centroids`'s).

Speed (about 2–3 ms per megapixel on one core): the background needs the smoothed frame only on
its sampling lattice, so it comes first; smoothing, threshold, the frame's sum (non-finite
pixels) and maximum (saturation) then share one pass over the frame, which also flags the
64-pixel blocks holding detections so that the labelling skips empty sky and finds the runs of
detected pixels along the rows. Steps 3 and 6 run in numba, not as dozens of small numpy calls.
The background's tile rows and the frame's rows are cut into two bands on frames large enough
(about 300 tiles, 600 kilopixels), shared with a helper thread that takes a band when the
machine schedules it and is never waited for otherwise (:mod:`skyfix.detect._threads`; no
OpenMP-style spinning, which measured 40× slower under load); the results are the same bit for
bit whatever the bands and threads. Deblending and measurement stay in the calling thread.
"""

from __future__ import annotations

import math
import threading
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix.detect._grid import sky_grid
from skyfix.detect._stats import argsort_descending
from skyfix.detect.background import Background, estimate_background, frame_f32
from skyfix.detect.centroids import Centroids
from skyfix.detect.deblend import DeblendRule, deblend
from skyfix.detect.labelling import (
    MAX_COMPONENTS,
    Frames,
    clear_boxes,
    label_components,
    select_candidates,
    smooth_threshold,
)
from skyfix.detect.measure import measure
from skyfix.detect.saturation import full_scale
from skyfix.detect.screen import Rejections, screen
from skyfix.errors import ImageReadError
from skyfix.io import as_image

__all__ = ["Options", "extract_components", "float32_frame", "run"]

# Deblending: a second maximum is a star of its own at least this far (px) from a brighter one,
# and a component with more than this many prominent maxima is texture.
_DEBLEND_MIN_SEP = 2.0
_DEBLEND_MAX_PARTS = 3


class Options(NamedTuple):
    """The detection options of :func:`~skyfix.detect.extract_centroids` (documented there), as
    every detection method of :data:`~skyfix.detect.METHODS` receives them: this extractor reads
    them all, the seeds' detectors ``sigma``, ``max_stars`` and ``saturation``."""

    sigma: float
    max_stars: int
    min_area: int
    max_area: int | None
    max_extent: int | None
    min_sharpness: float
    max_noise_ratio: float | None
    max_diffuseness: float | None
    max_elongation: float | None
    saturation: float | None
    tile: int | None
    background: Background | None
    deblend: float | None
    reject_tracks: bool


# One keyword per option, documented in extract_centroids (so more than ~10 parameters).
def extract_components(
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
    deblend: float | None = 0.3,
    reject_tracks: bool = True,
) -> Centroids:
    """Find stars by connected components (module docstring), brightest first.

    ``image`` is one (H, W) frame: 8/16-bit frames are used as they are, anything else as
    float32; non-finite pixels are found while smoothing and then replaced. The keywords are
    :func:`~skyfix.detect.extract_centroids`'s (documented there), which runs this method
    (:func:`run`) for ``method="components"`` after checking them.
    """
    return run(image, Options(sigma, max_stars, min_area, max_area, max_extent, min_sharpness,
                              max_noise_ratio, max_diffuseness, max_elongation, saturation, tile,
                              background, deblend, reject_tracks))


def run(image: np.ndarray, s: Options) -> Centroids:
    """:func:`extract_components` with its keywords as :class:`Options` (the registry's form)."""
    img = float32_frame(image)
    c = _one_pass(img, s, check_finite=True)
    if c is None:  # NaN/Inf pixels (or an overflowing sum): replace them, then once more
        try:
            img = as_image(img, name="image")
        except ImageReadError:
            return Centroids.empty(img.shape, reason="mostly non-finite")
        c = _one_pass(img, s, check_finite=False)
    return c


def _one_pass(img: np.ndarray, s: Options, check_finite: bool) -> Centroids | None:
    """:func:`extract_components` on one frame; ``None`` if ``check_finite`` and a pixel is not finite."""
    h, w = img.shape
    # the background needs the smoothed frame only on its sampling lattice, so it comes first
    # and the full-frame smoothing, threshold, sum and maximum share one pass
    bg = estimate_background(img, tile=s.tile) if s.background is None else s.background
    level, noise = bg.global_level, bg.global_noise
    if not np.any(bg.noise_smooth > 0):
        if check_finite and not math.isfinite(float(img.sum(dtype=np.float64))):
            return None
        return Centroids.empty((h, w), level, noise, reason="flat frame")
    max_area = int(max(400, 0.002 * h * w)) if s.max_area is None else s.max_area
    max_extent = int(max(32, 0.06 * min(h, w))) if s.max_extent is None else s.max_extent

    sky = sky_grid(bg, (h, w))
    # The threshold never falls below a tiny fraction of the frame's range, so an exactly
    # flat (noise-free) sky is not detected everywhere.
    floor = 1e-6 * max(1.0, float(np.abs(bg.level_smooth).max()))
    thr_grid = bg.level_smooth + np.maximum(s.sigma * bg.noise_smooth, floor)
    ws = _workspace(h, w)
    frames = ws.frames
    found = smooth_threshold(img, thr_grid, sky, frames)
    if check_finite and not math.isfinite(found.total):
        return None
    saturation = full_scale(found.maximum) if s.saturation is None else s.saturation
    if ws.dirty is None:
        frames.labels.fill(0)
    else:  # clear only what the last call labelled
        clear_boxes(frames.labels, ws.dirty)
    ws.dirty = None
    comps = label_components(img, frames, sky, MAX_COMPONENTS, found)
    ws.dirty = comps
    n_comp = comps.size
    if n_comp == 0:
        return Centroids.empty((h, w), level, noise, n_components=0)
    # a lone hot pixel holds nearly all of its component's light: dropped before the cap on
    # measured candidates, so that a frame with thousands of hot pixels still measures its stars.
    # Measure only the brightest candidates, with room for the clusters of hot pixels, blobs and
    # noise that the tests below remove (measuring costs ~1 µs per small candidate).
    cap = max(4 * int(s.max_stars) + 50, 200)
    drop_hot = s.min_sharpness > 0
    cand = select_candidates(comps, float(s.min_area), float(max_area), float(max_extent), drop_hot, cap)
    n_cand = cand.size
    n_split = 0
    if s.deblend is not None and n_cand:
        rule = DeblendRule(float(s.deblend), _DEBLEND_MIN_SEP, _DEBLEND_MAX_PARTS, float(s.min_sharpness))
        cand = deblend(img, frames, cand, sky, n_comp + 1, rule)
        n_split = cand.size - n_cand
    rules = Rejections(
        float(s.sigma), float(s.min_sharpness),
        math.inf if s.max_elongation is None else float(s.max_elongation), s.reject_tracks,
        math.nan if s.max_diffuseness is None else float(s.max_diffuseness),
        math.nan if s.max_noise_ratio is None else float(s.max_noise_ratio))
    stars = _measure_and_screen(img, frames.labels, cand, sky, float(saturation), rules, int(s.max_stars))
    return Centroids(
        **stars._asdict(), image_shape=(h, w), background_level=level, noise=noise,
        meta={"n_components": int(n_comp), "n_deblended": int(n_split), "saturation": float(saturation),
              "tile": bg.tile},
    )


class _Stars(NamedTuple):
    """The kept stars, as :class:`~skyfix.detect.Centroids` names its columns."""

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
    area: np.ndarray
    snr: np.ndarray
    elongation: np.ndarray
    peak: np.ndarray
    sigma_x: np.ndarray
    sigma_y: np.ndarray
    angle: np.ndarray
    saturated: np.ndarray


@njit(cache=True)
def _measure_and_screen(img, labels, cand, sky, saturation, rules, max_stars):
    """Steps 5–7 in one kernel: measure the candidates, screen them, keep the brightest stars.

    One call rather than three: the measurements and the screen's verdicts are not needed in
    Python, and each call and each array crossing between numba and Python costs microseconds
    (together ~10% of a small frame's time). :func:`~skyfix.detect.screen.screen` and
    :func:`_star_table` are written into this kernel (``inline="always"``; it is their only
    caller), :func:`~skyfix.detect.measure.measure` is called. On a fresh cache this kernel
    compiled in 9.1–10.5 s CPU (with what it calls; three runs) against 10.2–14.7 s with all
    three called (each compiled on its own, then optimised again inside this kernel) and
    9.3–12.8 s with ``measure`` written in too.
    """
    m = measure(img, labels, cand, sky, saturation, rules.min_sharpness)
    return _star_table(m, screen(m, cand.is_part, sky, rules), max_stars)


@njit(cache=True, inline="always")
def _star_table(m, screened, max_stars):
    """The stars among the measured candidates ``m`` (a ``MEASUREMENT`` array), by decreasing
    flux (ties keep candidate order), at most ``max_stars``; their centroid σ is the noise
    times the unweighted spread over the flux."""
    sel = np.flatnonzero(screened.good)
    sel = sel[argsort_descending(m.flux[sel])][:max_stars]
    flux = m.flux[sel]
    nz = screened.noise[sel]
    sigma_x = nz * np.sqrt(m.spread_x[sel]) / flux
    sigma_y = nz * np.sqrt(m.spread_y[sel]) / flux
    angle = 0.5 * np.arctan2(2.0 * m.mxy[sel], m.mxx[sel] - m.myy[sel])
    return _Stars(m.x[sel], m.y[sel], flux, m.npix[sel], screened.snr[sel], screened.elongation[sel],
                  m.peak[sel], sigma_x, sigma_y, angle, m.nsat[sel] > 0)


class _Workspace(threading.local):
    """Per-thread full-frame buffers reused between calls of the same frame size.

    Fresh multi-megabyte arrays cost page faults on every call (about as much as the
    smoothing itself); reusing them keeps a video-rate loop at its compute cost.
    """

    shape: tuple[int, int] = (0, 0)
    frames: Frames
    dirty: np.ndarray | None = None  # the components labelled by the last call (their boxes)
    pixels: np.ndarray | None = None  # a frame converted to float32 (float32_frame), on first need


_WS = _Workspace()


def _workspace(h: int, w: int) -> _Workspace:
    if _WS.shape != (h, w):
        _WS.frames = Frames(
            smooth=np.empty((h, w), np.float32),
            mask=np.zeros((h, (w + 63) // 64 * 64), np.uint8),  # padding columns stay 0
            blocks=np.zeros((h, (w + 63) // 64), np.uint8),
            labels=np.empty((h, w), np.int32),
        )
        _WS.dirty = None
        _WS.pixels = None
        _WS.shape = (h, w)
    return _WS


def float32_frame(image: np.ndarray) -> np.ndarray:
    """A 2-D frame as C-contiguous float32 (:func:`~skyfix.detect.background.frame_f32`): as it is
    if it already is, else converted into this thread's reused buffer, which the thread's next
    conversion overwrites (an extraction's working copy; never hand it out).

    A fresh array of a 1280 × 960 frame took 858 page faults and 2.3 ms of system time a
    call, more than converting and smoothing it (a uint16 frame on a loaded 2-core machine,
    ``getrusage``).
    """
    if image.dtype == np.float32 and image.flags.c_contiguous:
        return image
    ws = _workspace(*image.shape)
    if ws.pixels is None:
        ws.pixels = np.empty(image.shape, np.float32)
    return frame_f32(image, ws.pixels)
