"""Streaks: stars smeared by the camera's turn during the exposure, and the time each is seen.

At a body rate ``ω`` a star crosses ``|ω|·τ·f`` pixels in an exposure ``τ`` (2 °/s, 50 ms and
85 px/° make a streak 8.5 px long): its light is a line of PSFs, not a spot. Tracking predicts
where each star is and how it moves, so the window can be made to hold the whole streak:

- :func:`streak_motion` — a star's predicted displacement over the exposure (start to end),
  pixels, from the body rate: its positions at ``∓τ/2`` under ``b(t) = R(−ω t) b``.
- :func:`centroid_streaks` — one centroid per predicted streak, in a window stretched to hold
  it. ``method="streak"`` (the default) fits the streak's own shape: in a rectangle around the
  predicted segment (grown along x and along y by half the displacement, on top of the margin
  ``half_size``), the model is a Gaussian PSF of σ ``s`` swept along the predicted motion,
  ``A·[erf((a + L/2)/√2s) − erf((a − L/2)/√2s)]·exp(−b²/2s²)`` at ``a`` along and ``b``
  across the motion from the centre, with the sky from the window's border. A few steps of the
  centre of gravity weighted by that shape, twice as wide (the prediction may be a pixel or two
  off), start a Gauss–Newton fit of the amplitude and the centre — or the prediction itself when
  it is known to within ``START_SIGMA_PX`` (a tracker's) — weighted by each pixel's
  variance, that stops when the step, or the distance left (the last step times ρ/(1 − ρ), ρ
  the signed ratio of the last two steps), is under a tenth of σ (0.01 in χ²), or the step
  under 1e-3 px; the centre's covariance is ``(JᵀWJ)⁻¹`` with the gain, the sandwich estimate
  without. The flat middle of a streak says nothing about where it is along the motion, its
  two ends do: the fit weighs the pixels by what they say, where a centre of mass weighs the
  middle's noise as much as the ends' light, and a threshold cuts a faint streak's wings.
  ``"com"``, ``"iwcog"`` and ``"gaussian"`` run the centroiders of
  :mod:`skyfix.detect.centroid` in the square window of
  :func:`~skyfix.detect.centroid_windows` grown to hold the streak. For a constant rate the
  star sweeps its segment at constant speed, so the streak is symmetric about its middle and its
  intensity centroid is the star's position at mid-exposure (every method here is symmetric,
  so none is biased). The projection bends the path only to second order: the centroid is off
  mid-exposure by ``ẍ·τ²/24`` (10⁻⁴ px at 2 °/s, 50 ms, 15°); an acceleration ``α`` during the
  exposure makes the streak brighter at its slow end, and moves the centre of mass (the mean
  position over the exposure) by ``α·τ²/24`` in angle, the fit by less.
- :func:`star_times` — the time of each star's mid-exposure. A rolling-shutter sensor exposes
  row ``r`` at ``t_r = t_frame + (r − (H − 1)/2)·line_time`` (the frame's time is the centre
  row's mid-exposure, as the simulator defines it: :func:`skyfix.simulate.motion.star_tracks`
  calls this function), so a star centroided at row ``y`` was seen at ``t_frame + (y − (H −
  1)/2)·line_time``; a global shutter (``line_time = 0``) sees every star at ``t_frame``.

A star moving along y while the rows are read sweeps rows whose times differ, but only by
``line_time`` per row crossed (microseconds), against an exposure of milliseconds.
"""

from __future__ import annotations

import math

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.rotation import rodrigues
from skyfix.detect.centroid import CENTROIDERS, centroid_windows
from skyfix.detect.centroids import Centroids, background_snr
from skyfix.detect.streak_fit import START_SIGMA_PX, StreakFit, fit_streaks
from skyfix.errors import InputError, unknown_name

__all__ = ["START_SIGMA_PX", "STREAK_CENTROIDERS", "StreakFit", "centroid_streaks", "fit_streaks",
           "row_time_offset", "star_times", "streak_model_sigma", "streak_motion", "streak_half_sizes"]

#: Centroiders of :func:`centroid_streaks`: the matched streak weight, then those of
#: :data:`skyfix.detect.CENTROIDERS` in a grown square window.
STREAK_CENTROIDERS = ("streak", *CENTROIDERS)

_ARRAYS = ("x", "y", "flux", "area", "snr", "elongation", "peak", "sigma_x", "sigma_y", "cov_xy")
@njit(cache=True, inline="always")
def row_time_offset(y, line_time_s, height):
    """A star's mid-exposure time at row ``y`` less the frame's time on a rolling-shutter sensor
    of ``height`` rows, ``(y − (height − 1)/2)·line_time_s`` (s; module docstring): the one
    formula of :func:`star_times` (which calls it as Python) and the tracker's kernel."""
    return (y - (height - 1) / 2.0) * line_time_s


def streak_model_sigma(psf_sigma: float | None) -> float:
    """The σ of ``"streak"``'s model across the motion for a PSF of σ ``psf_sigma`` pixels
    (default 1): a Gaussian PSF integrated over a pixel is nearly one of σ² + 1/12 px²."""
    s = 1.0 if psf_sigma is None else float(psf_sigma)
    if not (math.isfinite(s) and s > 0):
        raise InputError(f"psf_sigma must be a positive number of pixels, got {psf_sigma!r}")
    return math.sqrt(s * s + 1.0 / 12.0)


def star_times(xy: np.ndarray, t_frame_s: float, line_time_s: float, height: int) -> np.ndarray:
    """Mid-exposure time of stars at pixel positions ``xy`` (N, 2) on a rolling-shutter sensor:
    ``t_frame_s + (y − (height − 1)/2)·line_time_s`` (s), (N,).

    ``t_frame_s`` is the frame's time (the centre row's mid-exposure), ``line_time_s`` the delay
    from one row to the next (0: a global shutter), ``height`` the frame's rows.
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    line = float(line_time_s)
    if not (math.isfinite(line) and line >= 0):
        raise InputError(f"line_time_s must be a non-negative number of seconds, got {line_time_s!r}")
    if not (float(height) == int(height) and int(height) >= 1):
        raise InputError(f"height must be a whole number of rows >= 1, got {height!r}")
    return t_frame_s + row_time_offset.py_func(xy[:, 1], line, int(height))


def streak_motion(camera, xy: np.ndarray, rate_rad_s: np.ndarray, exposure_s: float) -> np.ndarray:
    """Predicted displacement (N, 2), pixels, of stars at ``xy`` (N, 2, their mid-exposure
    positions) over an exposure ``exposure_s`` under the body rate ``rate_rad_s`` (camera
    frame): the end position minus the start position, ``b(±τ/2) = R(∓ω τ/2)·b``."""
    rate = np.asarray(rate_rad_s, dtype=np.float64).reshape(3)
    half = 0.5 * float(exposure_s)
    if not (np.all(np.isfinite(rate)) and math.isfinite(half) and half >= 0):
        raise InputError("streak_motion needs a finite rate and a non-negative exposure")
    b = camera.pixel_to_ray(np.asarray(xy, dtype=np.float64).reshape(-1, 2))
    end = camera.ray_to_pixel(b @ rodrigues(-rate * half).T)[0]
    start = camera.ray_to_pixel(b @ rodrigues(rate * half).T)[0]
    return end - start


def streak_half_sizes(motion_px: np.ndarray, half_size: int) -> np.ndarray:
    """Half sizes (N,) of the square windows that hold streaks of displacement ``motion_px``
    (N, 2): the margin ``half_size`` plus half the longer of the displacement's x and y."""
    m = np.abs(np.asarray(motion_px, dtype=np.float64).reshape(-1, 2))
    return int(half_size) + np.ceil(np.max(m, axis=1, initial=0.0) / 2).astype(np.int64)


def centroid_streaks(
    image: np.ndarray,
    xy_pred: np.ndarray,
    motion_px: np.ndarray,
    half_size: int = 6,
    *,
    method: str = "streak",
    sigma: float = 3.0,
    psf_sigma: float | None = None,
    gain: float | None = None,
    prediction_sigma: float | np.ndarray | None = None,
) -> Centroids:
    """Centroid the streak of each star predicted at ``xy_pred`` moving by ``motion_px``.

    Parameters
    ----------
    image : (H, W) array
        The frame, ADU.
    xy_pred : (N, 2) array
        Predicted mid-exposure positions ``(x, y)``, pixels (docs/design.md#pixel-coordinates).
    motion_px : (N, 2) or (2,) array
        Each star's predicted displacement over the exposure, end minus start, pixels
        (:func:`streak_motion`); one (2,) row for all.
    half_size : int
        The margin around the streak for the PSF and the prediction's error, pixels.
        ``"streak"``: the window is the rectangle ``x ± (half_size + ⌈|Δx|/2⌉)``,
        ``y ± (half_size + ⌈|Δy|/2⌉)`` about the rounded prediction; the others: the square
        window of :func:`~skyfix.detect.centroid_windows` with half size
        ``half_size + ⌈max(|Δx|, |Δy|)/2⌉`` (stars of one size centroided together).
    method : {"streak", "com", "iwcog", "gaussian"}
        The fit of the streak's shape (module docstring), or a centroider of
        :func:`~skyfix.detect.centroid_windows`.
    sigma : float
        ``"com"``'s threshold, in noise σ.
    psf_sigma : float, optional
        PSF σ, pixels: the width of ``"streak"``'s model across the motion (default 1 px,
        widened by the pixel's 1/12 px²; a wrong width costs a little precision, not a bias),
        and as for ``centroid_windows``.
    gain : float, optional
        Electrons per ADU: the star's shot noise then enters the weights and the centroid's σ
        (without it, ``"streak"``'s σ is the sandwich estimate from the residuals).
    prediction_sigma : float or (N,) array, optional
        The predictions' σ per axis, pixels (default: unknown, a pixel or so): ``"streak"``
        starts its fit at those within :data:`START_SIGMA_PX`, the others at the weighted centre
        (module docstring).

    Returns
    -------
    Centroids
        One entry per prediction, in the order given: ``x, y`` the streak's centroid (its
        mid-exposure position), ``sigma_x, sigma_y, cov_xy`` its error, ``elongation`` the
        streak's long over short axis, ``angle`` the direction of the predicted motion; NaN
        where no centroid was found (a window off the frame, no light, or a fit that left it).
    """
    from skyfix import warmup

    warmup.ensure("streaks")  # the streak fit's kernels, compiled up front
    xy = np.asarray(xy_pred, dtype=np.float64).reshape(-1, 2)
    motion = np.asarray(motion_px, dtype=np.float64)
    try:
        motion = motion.reshape(-1, 2)
        if motion.shape != xy.shape:
            motion = np.broadcast_to(motion, xy.shape)
    except ValueError:
        raise InputError(f"motion_px must be (2,) or one (dx, dy) per star ({len(xy)}), got shape "
                         f"{np.shape(motion_px)}") from None
    if not np.isfinite(motion).all():
        raise InputError("motion_px must be finite")
    if not (float(half_size) == int(half_size) and int(half_size) >= 2):
        raise InputError(f"half_size must be a whole number of pixels >= 2, got {half_size!r}")
    if method not in STREAK_CENTROIDERS:
        raise unknown_name("streak centroider", method, STREAK_CENTROIDERS)
    img = np.asarray(image)
    if img.ndim != 2:
        raise InputError(f"image must be 2-D, got shape {img.shape}")
    img = np.ascontiguousarray(img, dtype=np.float32)
    angle = _directions(np.ascontiguousarray(motion))
    if method == "streak":
        try:
            sigma_pred = np.broadcast_to(np.asarray(np.nan if prediction_sigma is None else prediction_sigma,
                                                    dtype=np.float64), (len(xy),))
        except ValueError:
            raise InputError(f"prediction_sigma must be one number or one per star ({len(xy)}), got shape "
                             f"{np.shape(prediction_sigma)}") from None
        return _fit_streaks(img, xy, motion, int(half_size), psf_sigma, gain, angle,
                            np.ascontiguousarray(sigma_pred))
    n = len(xy)
    half = streak_half_sizes(motion, int(half_size))
    cols = {name: np.full(n, np.nan) for name in _ARRAYS}
    saturated = np.zeros(n, bool)
    sky, noise = np.zeros(n), np.zeros(n)
    for h in np.unique(half):  # one call per window size (a frame's streaks share a few)
        sel = np.flatnonzero(half == h)
        c = centroid_windows(img, xy[sel], int(h), method=method, sigma=sigma, psf_sigma=psf_sigma, gain=gain)
        for name in _ARRAYS:
            cols[name][sel] = getattr(c, name)
        saturated[sel] = c.saturated
        sky[sel], noise[sel] = c.background_level, c.noise
    return Centroids(**cols, saturated=saturated, image_shape=img.shape,
                     background_level=float(np.median(sky)) if n else 0.0,
                     noise=float(np.median(noise)) if n else 0.0,
                     angle=angle, meta={"ordered": True, "half_size": half})


def _fit_streaks(img, xy, motion, half_size, psf_sigma, gain, angle, sigma_pred) -> Centroids:
    """``centroid_streaks(method="streak")``: the kernel, then its columns as Centroids."""
    s_model = streak_model_sigma(psf_sigma)
    if gain is not None and not (math.isfinite(float(gain)) and float(gain) > 0):
        raise InputError(f"gain must be a positive number of electrons per ADU, got {gain!r}")
    f = fit_streaks(img, np.ascontiguousarray(xy), np.ascontiguousarray(motion), np.int64(half_size), s_model,
                    0.0 if gain is None else 1.0 / float(gain), sigma_pred)
    return Centroids(x=f.x, y=f.y, flux=f.flux, area=f.area, elongation=f.elongation, peak=f.peak,
                     snr=background_snr(f.flux, f.noise, f.area),  # 0 where no centroid (no flux)
                     sigma_x=f.sigma_x, sigma_y=f.sigma_y, cov_xy=f.cov_xy,
                     saturated=np.zeros(len(xy), bool), image_shape=img.shape,
                     background_level=f.background_level, noise=f.noise_level, angle=angle,
                     meta={"ordered": True, "half_size": f.half})


# --- the kernel of centroid_streaks --------------------------------------------------------------


@njit(cache=True)
def _directions(motion):
    """The direction of each motion (N, 2) from +x toward +y, radians in (−π/2, π/2]."""
    angle = np.empty(len(motion))
    for i in range(len(motion)):
        a = math.atan2(motion[i, 1], motion[i, 0])
        angle[i] = a - math.pi if a > math.pi / 2 else (a + math.pi if a <= -math.pi / 2 else a)
    return angle
