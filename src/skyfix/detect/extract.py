"""Star extraction by name: one entry point, :func:`extract_centroids`, over four detectors.

The detection methods are registered in :data:`METHODS`, each with the options of
:func:`extract_centroids` it reads:

- ``"components"`` (default): background, k·σ threshold on the smoothed frame, connected
  components, deblending, measurement and rejections (:mod:`skyfix.detect.components`);
- ``"threshold_hillclimb"``: thesis 000's global threshold and 3×3 hill climb
  (:mod:`skyfix.detect.hillclimb`);
- ``"region_grow"``: thesis 004's every-third-pixel scan and region growing
  (:mod:`skyfix.detect.region_grow`);
- ``"regionprops"``: thesis 003's threshold, 8-connected spots and eccentricity limit
  (:mod:`skyfix.detect.regionprops`).

A centroider other than each method's own centre of mass (:data:`~skyfix.detect.CENTROIDERS`)
then refines every star in a window (:func:`~skyfix.detect.refine_centroids`).

Bad frames (constant, black, saturated, 1×1, too many non-finite pixels) give an empty list.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from skyfix.detect._grid import sky_grid, values_near
from skyfix.detect.background import Background, estimate_background
from skyfix.detect.centroid import CENTROIDERS, GAUSSIAN, Refined, refine_centroids
from skyfix.detect.centroids import Centroids, background_snr
from skyfix.detect.components import Options, float32_frame
from skyfix.detect.components import run as run_components
from skyfix.detect.saturation import saturation_level
from skyfix.errors import ImageReadError, unknown_name
from skyfix.io import as_image
from skyfix.validate import check_count, check_positive

__all__ = ["METHODS", "Method", "Options", "extract_centroids", "saturation_level"]


class Method(NamedTuple):
    """A detection method as :func:`extract_centroids` runs it."""

    #: ``extract(frame, options) -> Centroids``, ``options`` the :class:`Options`
    extract: Callable[[np.ndarray, Options], Centroids]
    #: takes frames with non-finite pixels (it finds them itself); the others get them replaced
    raw_frames: bool = False


def _seed(module: str, function: str) -> Method:
    """A seed thesis's detector, ``function`` of ``module``: it reads the threshold, the cap on the
    count and the saturation level (the other options apply to ``"components"`` only). Its module
    is imported on its first use: a solve runs ``"components"`` alone."""
    def extract(img: np.ndarray, o: Options) -> Centroids:
        run = getattr(importlib.import_module(module), function)
        return run(img, sigma=o.sigma, max_stars=o.max_stars, saturation=o.saturation)
    return Method(extract)


#: Detection methods by name (``method=`` of :func:`extract_centroids`, ``skyfix detect --method``).
METHODS: dict[str, Method] = {
    "components": Method(run_components, raw_frames=True),
    "threshold_hillclimb": _seed("skyfix.detect.hillclimb", "extract_hillclimb"),
    "region_grow": _seed("skyfix.detect.region_grow", "extract_region_grow"),
    "regionprops": _seed("skyfix.detect.regionprops", "extract_regionprops"),
}


# One keyword per option, each documented below: a flat signature is the public API (and the CLI's).
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
    if not isinstance(method, str) or method not in METHODS:
        raise unknown_name("detection method", method, METHODS)
    if not isinstance(centroid, str) or centroid not in CENTROIDERS:
        raise unknown_name("centroider", centroid, CENTROIDERS)
    sigma = check_positive(sigma, "sigma")
    max_stars = check_count(max_stars, "max_stars")
    detector = METHODS[method]
    if method != "components" or centroid != "com":  # their kernels, compiled up front (skyfix.warmup)
        from skyfix import warmup

        if method != "components":
            warmup.ensure(f"detector-{method}", missing_ok=True)
        if centroid != "com":
            warmup.ensure("centroiders")
    frame, check = image, not detector.raw_frames
    if isinstance(image, np.ndarray) and image.ndim == 2 and image.size and image.dtype.kind in "biuf":
        # float32 for every kernel, converted into a reused buffer (components.float32_frame);
        # only float data can hold non-finite pixels
        frame, check = float32_frame(image), check and image.dtype.kind == "f"
    try:
        # a method that finds non-finite pixels itself (while smoothing) saves a pass
        img = as_image(frame, name="image", replace_nonfinite=check)
    except ImageReadError:
        return Centroids.empty((0, 0) if np.ndim(image) != 2 else np.shape(image), reason="unusable")
    h, w = img.shape
    if h < 3 or w < 3:
        return Centroids.empty((h, w), reason="too small")
    options = Options(sigma, max_stars, min_area, max_area, max_extent, min_sharpness, max_noise_ratio,
                      max_diffuseness, max_elongation, saturation, tile, background, deblend, reject_tracks)
    c = detector.extract(img, options)
    if centroid != "com" and len(c):
        c = _refine(img, c, centroid, gain, background, tile)
    return c


def _refine(img: np.ndarray, c: Centroids, centroid: str, gain: float | None,
            background: Background | None, tile: int | None) -> Centroids:
    """Re-centroid each star in a window with ``centroid``; keep the CoM where it fails."""
    bg = background
    if bg is None or bg.level.shape == ():
        bg = estimate_background(img, tile=tile)
    grid = sky_grid(bg, img.shape)
    # (the sky level too is floored at 1e-12, as it always was)
    sky = values_near(grid.level, grid.weights, c.x, c.y)
    nz = values_near(grid.noise, grid.weights, c.x, c.y)
    # window: the footprint's equivalent radius plus 2 px of wings, 3–10 px
    half = np.clip(np.ceil(np.sqrt(np.maximum(c.area, 1.0) / np.pi)) + 2, 3, 10).astype(np.int64)
    r = Refined.of(refine_centroids(img, c.xy, sky, nz, half, method=centroid, gain=gain))
    ok = (r.ok > 0) & np.isfinite(r.x) & (np.hypot(r.x - c.x, r.y - c.y) < 1.5)
    fitted = CENTROIDERS[centroid] == GAUSSIAN  # the fit also measures the flux and the shape
    new_flux = np.where(ok, r.flux, c.flux) if fitted else c.flux
    order = np.argsort(-new_flux, kind="stable")
    out = Centroids(
        x=np.where(ok, r.x, c.x), y=np.where(ok, r.y, c.y), flux=new_flux, area=c.area,
        snr=background_snr(np.where(ok, new_flux, c.flux), nz, c.area),
        elongation=np.where(ok & fitted, r.elongation, c.elongation), peak=c.peak,
        sigma_x=np.where(ok, r.sigma_x, c.sigma_x), sigma_y=np.where(ok, r.sigma_y, c.sigma_y),
        saturated=c.saturated, image_shape=c.image_shape, background_level=c.background_level,
        noise=c.noise, meta={**c.meta, "centroid": centroid, "refined": int(ok.sum())},
        cov_xy=np.where(ok, r.cov_xy, 0.0), angle=c.angle)
    return out.subset(order)
