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
from typing import NamedTuple

import numpy as np
from numba import njit

from skyfix._kernels.rotation import rodrigues
from skyfix.detect._stats import robust_level_noise
from skyfix.detect.centroid import CENTROIDERS, centroid_windows
from skyfix.detect.centroids import Centroids, background_snr
from skyfix.errors import InputError, unknown_name

__all__ = ["START_SIGMA_PX", "STREAK_CENTROIDERS", "StreakFit", "centroid_streaks", "fit_streaks",
           "row_time_offset", "star_times", "streak_model_sigma", "streak_motion", "streak_half_sizes"]

#: Centroiders of :func:`centroid_streaks`: the matched streak weight, then those of
#: :data:`skyfix.detect.CENTROIDERS` in a grown square window.
STREAK_CENTROIDERS = ("streak", *CENTROIDERS)

_ARRAYS = ("x", "y", "flux", "area", "snr", "elongation", "peak", "sigma_x", "sigma_y", "cov_xy")
# The rows of the streak kernel's (11, N) table, in the order of StreakFit's first fields.
(_X, _Y, _FLUX, _AREA, _PEAK, _SIGMA_X, _SIGMA_Y, _COV_XY, _ELONGATION, _NOISE, _SKY) = range(11)
_NCOL = 11
# The streak model is taken as zero beyond this many σ of its segment (3e-4 of its peak).
_REACH = 4.0
# The column walk seeds a Gaussian afresh below this (its products keep every digit above it).
_TINY = 1e-280
# Gauss–Newton stops when the step or the distance left (extrapolated) is under 0.1 σ (χ² 0.01).
_TOL_CHI2 = 0.01
# The passes over the pixels may fuse a multiply and an add (one rounding, not two), and take a
# pass's sums in any order (split four ways: its loop vectorises); the centres move by 1e-14 px.
_CONTRACT = {"contract"}
_VECTOR = {"contract", "reassoc"}
#: A prediction whose σ per axis is at most this (pixels) starts the Gauss–Newton fit itself,
#: without the weighted centre's passes: from predictions 0.1–0.5 px σ off (up to ~2 px) the fit
#: converges on every one of 600 synthetic streaks (``tests/detect/test_detect_streak.py``'s) to the
#: centre it reaches from the weighted one, within its tolerance (≤ 0.006 px); from 0.7 px σ a
#: few are lost.
START_SIGMA_PX = 0.3


class StreakFit(NamedTuple):
    """What :func:`fit_streaks` measured of N streaks: (N,) columns, NaN centre, σ and elongation
    and zero flux, area and covariance where no centroid was found."""

    x: np.ndarray  #: the streak's centre (its mid-exposure position), pixels
    y: np.ndarray
    flux: np.ndarray  #: the model's integral, ADU
    area: np.ndarray  #: pixels of the footprint (above the sky, at least 1 % of the profile's peak)
    peak: np.ndarray  #: highest pixel above the sky in the window, ADU
    sigma_x: np.ndarray  #: the centre's 1-σ error and x–y covariance, pixels, px²
    sigma_y: np.ndarray
    cov_xy: np.ndarray
    elongation: np.ndarray  #: long over short axis of the footprint's second moments
    noise: np.ndarray  #: each window's noise σ and sky level (its border), ADU
    sky: np.ndarray
    half: np.ndarray  #: (N, 2) int64: each window's half sizes along x and y, pixels
    noise_level: float  #: the median noise and sky level
    background_level: float


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


# --- the streak kernels -----------------------------------------------------------------------------


@njit(cache=True)
def _directions(motion):
    """The direction of each motion (N, 2) from +x toward +y, radians in (−π/2, π/2]."""
    angle = np.empty(len(motion))
    for i in range(len(motion)):
        a = math.atan2(motion[i, 1], motion[i, 0])
        angle[i] = a - math.pi if a > math.pi / 2 else (a + math.pi if a <= -math.pi / 2 else a)
    return angle


class _Shape(NamedTuple):
    """A predicted streak: the motion's unit vector, half its length, 1/length, the PSF σ; for
    the row walk (:func:`_row_start`) ``q = 1/(√2 s)`` and the ratios ``exp(−2(ux·q)²)``,
    ``exp(−2(uy·q)²)`` by which its Gaussians' pixel-to-pixel factors change along a row (and,
    the other way round, from row to row), and ``exp(−2·ux·uy·q²)``, by which the along
    Gaussians' pixel-to-pixel factors change from row to row (the across one's: its inverse)."""

    ux: float
    uy: float
    half_len: float
    inv_len: float
    s: float
    q: float
    ca: float
    cb: float
    cab: float
    inv_cab: float


class _Box(NamedTuple):
    """A streak's window, rows y0..y1 and columns x0..x1 inclusive, with its sky and noise σ."""

    y0: int
    y1: int
    x0: int
    x1: int
    sky: float
    noise: float


@njit(cache=True, inline="always")
def _shape(ux, uy, half_len, s):
    """The :class:`_Shape` of a streak along ``(ux, uy)``, ``2·half_len`` long, of PSF σ ``s``."""
    q = 1.0 / (math.sqrt(2.0) * s)
    return _Shape(ux, uy, half_len, 0.5 / half_len, s, q, math.exp(-2.0 * (ux * q) ** 2),
                  math.exp(-2.0 * (uy * q) ** 2), math.exp(-2.0 * ux * uy * q * q),
                  math.exp(2.0 * ux * uy * q * q))


# --- the profile, pixel by pixel along a row --------------------------------------------------------
# Along a row ``a`` and ``b`` are linear in x, so each Gaussian ``exp(−z²)`` of the profile (z =
# (a ± L/2)·q, b·q, with steps dz = ux·q, −uy·q) follows from the last pixel's by the recurrence
# ``g ← g·r, r ← r·exp(−2dz²)`` (``r = exp(−2z·dz − dz²)``): two exps a row, not three a pixel.
# Down a column ``a`` and ``b`` are linear in y too: each row's walk starts in the window's first
# column from the row above's start by the same recurrence (steps dz = uy·q, ux·q), with its
# pixel-to-pixel factors r carried along (``r ← r·exp(−2·dzx·dzy)``), and walks on to the first
# pixel within the streak's reach: nine exps a window, not six a row (an exp is most of a short
# row's walk). A start that underflows (below _TINY) is seeded afresh. Over a 40 px row the
# recurrence drifts under 1e-12 (relative, where the Gaussian is above 1e-30; 3e-13 absolute),
# as much again over 40 rows. The two erfs take the along Gaussians: erfc(|z|) =
# exp(−z²)·P(1/(1 + p|z|)) (Abramowitz & Stegun 7.1.26, within 1.5e-7 of erf; the centres move
# 2e-6 px), a fifth of ``math.erf``'s cost.


@njit(cache=True, inline="always")
def _seed(z, dz):
    """``exp(−z²)`` and its ratio to the next pixel's, ``exp(−(z + dz)²)``; ``(0, 1)`` where it
    underflows (``z² > 700``)."""
    if z * z > 700.0:
        return 0.0, 1.0
    return math.exp(-z * z), math.exp(-dz * (2.0 * z + dz))


@njit(cache=True, inline="always")
def _next(g, r, c, z, dz):
    """The Gaussian ``exp(−z²)`` at the next pixel (``z`` its offset there) and its ratio, from
    this pixel's ``g`` and ``r``; a zero (underflowed, or beyond the seed's reach) seeds afresh."""
    if g == 0.0:
        return _seed(z, dz)
    return g * r, r * c


@njit(cache=True, inline="always")
def _row_start(dx, dy, shape):
    """The row walk at the offset ``(dx, dy)`` from the streak's centre: ``a`` along and ``b``
    across the motion, and each Gaussian with its ratio (``(a + L/2)q``, ``(a − L/2)q``, ``bq``)."""
    ux, uy, h, q = shape.ux, shape.uy, shape.half_len, shape.q
    a, b = dx * ux + dy * uy, dy * ux - dx * uy
    return (a, b) + _seed((a + h) * q, ux * q) + _seed((a - h) * q, ux * q) + _seed(b * q, -uy * q)


@njit(cache=True, inline="always")
def _row_next(walk, shape):
    """The row walk one pixel on (``x + 1``)."""
    a, b, gp, rp, gm, rm, gb, rb = walk
    ux, uy, h, q = shape.ux, shape.uy, shape.half_len, shape.q
    a, b = a + ux, b - uy
    return ((a, b) + _next(gp, rp, shape.ca, (a + h) * q, ux * q)
            + _next(gm, rm, shape.ca, (a - h) * q, ux * q) + _next(gb, rb, shape.cb, b * q, -uy * q))


@njit(cache=True, inline="always")
def _row_step(walk, shape):
    """:func:`_row_next` without its re-seeding, for where no Gaussian can underflow
    (:func:`_no_underflow`): the recurrence alone, no exp in the loop that walks it."""
    a, b, gp, rp, gm, rm, gb, rb = walk
    return (a + shape.ux, b - shape.uy, gp * rp, rp * shape.ca, gm * rm, rm * shape.ca, gb * rb,
            rb * shape.cb)


@njit(cache=True, inline="always")
def _no_underflow(shape):
    """Whether every Gaussian of the profile stays above ``exp(−700)`` within the streak's reach
    (``|a ± L/2| ≤ L + 4s``, ``|b| ≤ 4s``): streaks shorter than ~33 σ."""
    z = (2.0 * shape.half_len + _REACH * shape.s) * shape.q
    return z * z <= 700.0


@njit(cache=True, inline="always")
def _put(buf, m, walk, v):
    """A pixel of the walk into ``buf``'s column ``m``: ``a``, ``b``, the three Gaussians and
    its value ``v`` above the sky."""
    a, b, gp, _, gm, _, gb, _ = walk
    buf[0, m] = a
    buf[1, m] = b
    buf[2, m] = gp
    buf[3, m] = gm
    buf[4, m] = gb
    buf[5, m] = v


@njit(cache=True, inline="always")
def _seed3(z, dzx, dzy):
    """``exp(−z²)`` and its ratios to the next pixel's along a row (``exp(−(z + dzx)²)``) and
    down a column (``exp(−(z + dzy)²)``); ``(0, 1, 1)`` where it underflows (``z² > 700``)."""
    if z * z > 700.0:
        return 0.0, 1.0, 1.0
    return math.exp(-z * z), math.exp(-dzx * (2.0 * z + dzx)), math.exp(-dzy * (2.0 * z + dzy))


@njit(cache=True, inline="always")
def _down(g, rx, ry, cx, cy, z, dzx, dzy):
    """A Gaussian of the column walk one row down (``z`` its offset there), with its ratios
    along the row and down the column, from this row's ``g``, ``rx``, ``ry`` and the ratios'
    factors ``cx``, ``cy``; seeded afresh below :data:`_TINY` (where the products lose digits)."""
    if g < _TINY:
        return _seed3(z, dzx, dzy)
    return g * ry, rx * cx, ry * cy


@njit(cache=True, inline="always")
def _column_start(dx, dy, shape):
    """The column walk at the offset ``(dx, dy)`` from the streak's centre (a window's first
    column and row): ``a``, ``b`` and each Gaussian with its ratios along and down (the
    ``(a + L/2)q``, ``(a − L/2)q`` and ``bq`` of :func:`_row_start`)."""
    ux, uy, h, q = shape.ux, shape.uy, shape.half_len, shape.q
    a, b = dx * ux + dy * uy, dy * ux - dx * uy
    return ((a, b) + _seed3((a + h) * q, ux * q, uy * q) + _seed3((a - h) * q, ux * q, uy * q)
            + _seed3(b * q, -uy * q, ux * q))


@njit(cache=True, inline="always")
def _column_next(col, shape):
    """The column walk one row down (``y + 1``)."""
    a, b, gp, xp, yp, gm, xm, ym, gb, xb, yb = col
    ux, uy, h, q = shape.ux, shape.uy, shape.half_len, shape.q
    a, b = a + uy, b + ux
    return ((a, b) + _down(gp, xp, yp, shape.cab, shape.cb, (a + h) * q, ux * q, uy * q)
            + _down(gm, xm, ym, shape.cab, shape.cb, (a - h) * q, ux * q, uy * q)
            + _down(gb, xb, yb, shape.inv_cab, shape.ca, b * q, -uy * q, ux * q))


@njit(cache=True, inline="always")
def _row_from(col, steps, shape):
    """The row walk ``steps`` pixels on from the column walk's pixel."""
    a, b, gp, xp, _, gm, xm, _, gb, xb, _ = col
    walk = (a, b, gp, xp, gm, xm, gb, xb)
    for _ in range(steps):
        walk = _row_next(walk, shape)
    return walk


@njit(cache=True, inline="always")
def _erf(z, g):
    """``erf(z)`` from ``g = exp(−z²)``: Abramowitz & Stegun 7.1.26, within 1.5e-7."""
    t = 1.0 / (1.0 + 0.3275911 * abs(z))
    poly = 0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429)))
    y = 1.0 - t * poly * g
    return y if z >= 0.0 else -y


@njit(cache=True, inline="always")
def _weight(a, b, gp, gm, gb, shape):
    """The streak profile (a Gaussian of σ ``s`` swept over ``±half_len`` along ``u``, divided by
    the length; it integrates to ``2√(2π)·s``) at the pixel ``a`` along and ``b`` across the
    motion (its Gaussians ``gp``, ``gm``, ``gb`` from the row walk: the erf difference along, the
    Gaussian across), and its gradient by the offset ``(dx, dy)``; zero beyond the streak's light
    — by a product with 0 or 1, not a branch, so that the loop of :func:`_sums` vectorises."""
    h, s, q = shape.half_len, shape.s, shape.q
    g = gb if (abs(b) <= _REACH * s) & (abs(a) <= h + _REACH * s) else 0.0
    e = (_erf((a + h) * q, gp) - _erf((a - h) * q, gm)) * shape.inv_len
    de = (2.0 / math.sqrt(math.pi)) * q * (gp - gm) * shape.inv_len
    da, db = de * g, -e * g * b * (2.0 * q * q)  # 1/s² = 2q²
    return e * g, da * shape.ux - db * shape.uy, da * shape.uy + db * shape.ux


@njit(cache=True, inline="always")
def _profile(walk, shape):
    """The streak profile of :func:`_weight` at the row walk's pixel."""
    a, b, gp, _, gm, _, gb, _ = walk
    return _weight(a, b, gp, gm, gb, shape)[0]


@njit(cache=True, inline="always")
def _limits(c1, c0, width, lo, hi):
    """``[lo, hi]`` cut to the offsets ``t`` with ``|c1·t + c0| <= width`` (empty: ``lo > hi``)."""
    if abs(c1) < 1e-12:
        return (lo, hi) if abs(c0) <= width else (1.0, 0.0)
    t0, t1 = (-width - c0) / c1, (width - c0) / c1
    return max(lo, min(t0, t1)), min(hi, max(t0, t1))


@njit(cache=True, inline="always")
def _span(y, box, shape, xc, yc):
    """The columns ``x0..x1`` of row ``y`` within the reach of the streak centred at ``(xc, yc)``
    (where :func:`_weight` is not zero): the others add nothing to a sum weighted by it, so the
    loops skip them (about half of a 2 °/s window's pixels)."""
    ux, uy, half_len, s = shape.ux, shape.uy, shape.half_len, shape.s
    dy = y - yc
    lo, hi = _limits(ux, dy * uy, half_len + _REACH * s, -1e300, 1e300)  # along
    lo, hi = _limits(-uy, dy * ux, _REACH * s, lo, hi)  # across
    if lo > hi:
        return box.x0, box.x0 - 1
    return max(box.x0, int(math.ceil(xc + lo))), min(box.x1, int(math.floor(xc + hi)))


@njit(cache=True, fastmath=_CONTRACT)
def _weighted_centre(img, box, shape, xc, yc, reach_x, reach_y):
    """A few steps of the streak-weighted centre of gravity from ``(xc, yc)``, with a weight twice
    as wide as the streak (the prediction may be a pixel or two off): the fit's start. ``ok``
    False if it has no light or leaves ``±reach`` of the start."""
    x_start, y_start = xc, yc
    wide = _shape(shape.ux, shape.uy, shape.half_len, 2.0 * shape.s)
    for _ in range(2):
        sw = swx = swy = 0.0
        col = _column_start(box.x0 - xc, box.y0 - yc, wide)
        for y in range(box.y0, box.y1 + 1):
            lo, hi = _span(y, box, wide, xc, yc)
            walk = _row_from(col, lo - box.x0, wide)
            col = _column_next(col, wide)
            for x in range(lo, hi + 1):
                v = (img[y, x] - box.sky) * _profile(walk, wide)
                walk = _row_next(walk, wide)
                sw += v
                swx += v * x
                swy += v * y
        if not sw > 0.0:
            return xc, yc, False
        nx_, ny_ = swx / sw, swy / sw
        if abs(nx_ - x_start) > reach_x or abs(ny_ - y_start) > reach_y:
            return xc, yc, False
        done = abs(nx_ - xc) < 0.25 and abs(ny_ - yc) < 0.25
        xc, yc = nx_, ny_
        if done:
            break
    return xc, yc, True


@njit(cache=True, fastmath=_CONTRACT)
def _gather(img, box, shape, xc, yc, buf):
    """The pixels within the reach of the streak centred at ``(xc, yc)`` (:func:`_span`) into
    the columns of ``buf`` (9 rows, ≥ their count): ``a`` and ``b`` (along and across the motion),
    the row walk's three Gaussians and the value above the sky. Returns their count."""
    m = 0
    safe = _no_underflow(shape)
    col = _column_start(box.x0 - xc, box.y0 - yc, shape)
    for y in range(box.y0, box.y1 + 1):
        lo, hi = _span(y, box, shape, xc, yc)
        walk = _row_from(col, lo - box.x0, shape)
        col = _column_next(col, shape)
        if safe:  # two loops: one with no exp (nor its spills) in it
            for x in range(lo, hi + 1):
                _put(buf, m, walk, img[y, x] - box.sky)
                m += 1
                walk = _row_step(walk, shape)
        else:
            for x in range(lo, hi + 1):
                _put(buf, m, walk, img[y, x] - box.sky)
                m += 1
                walk = _row_next(walk, shape)
    return m


@njit(cache=True, fastmath=_VECTOR, error_model="numpy")
def _sums(img, box, shape, xc, yc, amp, ig, buf):
    """One pass over the streak's reach at the centre ``(xc, yc)``: the sums of the weighted
    normal equations with the amplitude left out (the model is linear in it, :func:`_scaled`):
    ``Σ wᵢ·jᵢ·jₖ`` (6: ``j = (profile, ∂x, ∂y)``, the gradient of the profile without the
    amplitude's −A) and ``Σ wᵢ·jᵢ·vᵢ`` (3), and the count of the pixels, whose ``j`` it leaves in
    ``buf``'s rows 6–8 for :func:`_meat_footprint`. The weights ``wᵢ`` are the pixels' inverse
    variances: the sky's, ``1/noise²``, and with the gain's inverse ``ig`` their shot noise at
    ``amp`` (taken as a factor ``1/(1 + μᵢ·ig/noise²)`` of the sky's, which multiplies the sums
    after the loop).

    The row walk is a recurrence from pixel to pixel: :func:`_gather` runs it into ``buf``; the
    sums are one loop without a branch, which the compiler vectorises (four pixels at a time):
    numba's check of each division for a zero (``error_model="numpy"`` leaves it out; nothing
    here divides by zero) or the sums' fixed order (``_VECTOR``) would each keep it scalar. Without
    the gain (a tracker's fit) the weights are all the sky's: the loop divides by nothing but
    its erfs' own."""
    v0 = box.noise * box.noise if box.noise > 0 else 1.0
    m = _gather(img, box, shape, xc, yc, buf)
    shot = max(amp, 0.0) * ig / v0  # the shot noise at the peak, in sky variances
    s00 = s01 = s02 = s11 = s12 = s22 = t0 = t1 = t2 = 0.0
    for k in range(m):
        w, gx, gy = _weight(buf[0, k], buf[1, k], buf[2, k], buf[3, k], buf[4, k], shape)
        buf[6, k] = w
        buf[7, k] = gx
        buf[8, k] = gy
        v = buf[5, k]
        iv = 1.0 if shot == 0.0 else 1.0 / (1.0 + max(w, 0.0) * shot)
        iw, igx, igy = iv * w, iv * gx, iv * gy
        s00 += iw * w
        s01 += iw * gx
        s02 += iw * gy
        s11 += igx * gx
        s12 += igx * gy
        s22 += igy * gy
        t0 += iw * v
        t1 += igx * v
        t2 += igy * v
    i0 = 1.0 / v0
    return ((i0 * s00, i0 * s01, i0 * s02, i0 * s11, i0 * s12, i0 * s22), (i0 * t0, i0 * t1, i0 * t2), m)


@njit(cache=True, fastmath=_VECTOR, error_model="numpy")
def _meat_footprint(box, shape, amp, ig, wmin, buf, m):
    """At the last pass of :func:`_sums` (its ``m`` pixels and their ``j`` in ``buf``, the
    amplitude ``amp``): the sandwich's meat ``Σ (wᵢ·dᵢ)²·jᵢ·jₖ`` (6) with the residual ``d`` at
    ``amp``, only without the gain (zeros otherwise), and the streak's footprint (the pixels
    above the sky where the profile is at least ``wmin``): its count and ``Σ v``, ``Σ v·dx``,
    ``Σ v·dy``, ``Σ v·dx²``, ``Σ v·dy²``, ``Σ v·dx·dy`` about the pass's centre."""
    v0 = box.noise * box.noise if box.noise > 0 else 1.0
    meat = 1.0 if ig == 0.0 else 0.0
    ux, uy = shape.ux, shape.uy
    m00 = m01 = m02 = m11 = m12 = m22 = 0.0
    n = sv = svx = svy = svxx = svyy = svxy = 0.0
    for k in range(m):
        a, b, v = buf[0, k], buf[1, k], buf[5, k]
        w, gx, gy = buf[6, k], buf[7, k], buf[8, k]
        r = v - amp * w
        r = r * r * meat
        m00 += r * w * w
        m01 += r * w * gx
        m02 += r * w * gy
        m11 += r * gx * gx
        m12 += r * gx * gy
        m22 += r * gy * gy
        f = 1.0 if (v > 0.0) & (w >= wmin) else 0.0
        fv = f * v
        dx, dy = a * ux - b * uy, a * uy + b * ux
        n += f
        sv += fv
        svx += fv * dx
        svy += fv * dy
        svxx += fv * dx * dx
        svyy += fv * dy * dy
        svxy += fv * dx * dy
    i2 = 1.0 / (v0 * v0)
    return ((i2 * m00, i2 * m01, i2 * m02, i2 * m11, i2 * m12, i2 * m22),
            (n, sv, svx, svy, svxx, svyy, svxy))


@njit(cache=True, inline="always")
def _scaled(six, amp, m):
    """The symmetric 3×3 ``Σ w·Jᵢ·Jₖ`` of the Jacobian ``J = (j₀, −A·j₁, −A·j₂)`` from the six
    amplitude-free sums of :func:`_sums`, into ``m`` (returned)."""
    c = (1.0, -amp, -amp)
    k = 0
    for i in range(3):
        for j in range(i, 3):
            m[i, j] = m[j, i] = c[i] * c[j] * six[k]
            k += 1
    return m


@njit(cache=True, inline="always")
def _inverse3(m, adj):
    """The inverse of a 3×3 matrix by its adjugate (a tenth of ``pinv``'s 3 µs), into ``adj``
    (returned); pinv if near singular."""
    for i in range(3):
        for j in range(3):
            r0, r1 = (j + 1) % 3, (j + 2) % 3
            c0, c1 = (i + 1) % 3, (i + 2) % 3
            adj[i, j] = m[r0, c0] * m[r1, c1] - m[r0, c1] * m[r1, c0]
    det = m[0, 0] * adj[0, 0] + m[0, 1] * adj[1, 0] + m[0, 2] * adj[2, 0]
    scale = abs(m[0, 0] * m[1, 1] * m[2, 2])
    if not abs(det) > 1e-12 * scale:
        adj[:, :] = np.linalg.pinv(m)
    else:
        adj /= det
    return adj


@njit(cache=True, inline="always")
def _sandwich3(a, b):
    """``a·b·a`` of two 3×3 matrices (the fit's sandwich covariance from its meat), by loops:
    BLAS's calls cost more than the 54 multiplications."""
    ab = np.zeros((3, 3))
    out = np.zeros((3, 3))
    for i in range(3):
        for k in range(3):
            for j in range(3):
                ab[i, j] += a[i, k] * b[k, j]
    for i in range(3):
        for k in range(3):
            for j in range(3):
                out[i, j] += ab[i, k] * a[k, j]
    return out


@njit(cache=True)
def _fit(img, box, shape, xc, yc, ig, buf):
    """Gauss–Newton fit of the streak model from the weighted centre: (amplitude, x, y), its
    covariance ((JᵀWJ)⁻¹ with a gain, else the sandwich), whether it converged near the start,
    and the footprint of :func:`_meat_footprint` at the last pass, its moments moved to the fit's
    centre (the count, ``Σ v``, ``Σ v·dx²``, ``Σ v·dy²``, ``Σ v·dx·dy``).
    The first pass has no amplitude yet: it takes the linear least-squares one at the start (the
    model is linear in it) and weighs the pixels by the sky's noise alone; the covariance is
    from a later pass, at the amplitude and centre of the last step's start."""
    p = np.array([0.0, xc, yc])
    cov = np.zeros((3, 3))
    jtj, inv, jtr, step = np.empty((3, 3)), np.empty((3, 3)), np.empty(3), np.empty(3)
    prev_x = prev_y = 0.0  # the last step
    wmin = 0.01 * _profile(_row_start(0.0, 0.0, shape), shape)  # the footprint: 1 % of the peak
    nothing = (0.0, 0.0, 0.0, 0.0, 0.0)
    for it in range(15):
        at_x, at_y = p[1], p[2]
        six, tv, m = _sums(img, box, shape, at_x, at_y, p[0], ig, buf)
        if it == 0:
            p[0] = tv[0] / six[0] if six[0] > 0 else 0.0
            if not p[0] > 0:
                return p, cov, False, nothing
        amp = p[0]
        _scaled(six, amp, jtj)
        jtr[0] = tv[0] - amp * six[0]
        jtr[1] = -amp * (tv[1] - amp * six[1])
        jtr[2] = -amp * (tv[2] - amp * six[2])
        _inverse3(jtj, inv)
        for i in range(3):
            step[i] = inv[i, 0] * jtr[0] + inv[i, 1] * jtr[1] + inv[i, 2] * jtr[2]
        # the χ² the step gains (its length², in σ of the fit's metric), and the distance left,
        # extrapolated from the signed ratio ρ of the last two steps (Gauss–Newton converges
        # linearly; the steps alternate, ρ < 0, when the model is wider than the stars):
        # ρ/(1 − ρ) steps
        gain = step[0] * jtr[0] + step[1] * jtr[1] + step[2] * jtr[2]
        d = prev_x * prev_x + prev_y * prev_y
        rho = (step[1] * prev_x + step[2] * prev_y) / d if d > 0.0 else 1.0
        small = gain < _TOL_CHI2 or (abs(rho) < 1.0 and gain * (rho / (1.0 - rho)) ** 2 < _TOL_CHI2)
        prev_x, prev_y = step[1], step[2]
        big = max(abs(step[1]), abs(step[2]))
        if big > 0.5:  # at most half a pixel a step
            step *= 0.5 / big
        p += step
        if not p[0] > 0 or abs(p[1] - xc) > 2.0 or abs(p[2] - yc) > 2.0:
            return p, cov, False, nothing  # lost the star
        if (small or big < 1e-3) and it > 0:
            break
    meat6, foot = _meat_footprint(box, shape, amp, ig, wmin, buf, m)  # the last pass's
    if ig > 0:  # at the last step's start, under 0.1 σ away
        cov = inv
    else:
        cov = _sandwich3(inv, _scaled(meat6, amp, jtj))
    n, sv, svx, svy, svxx, svyy, svxy = foot
    ex, ey = p[1] - at_x, p[2] - at_y  # Σ v·(dx − ex)² …
    return p, cov, True, (n, sv, svxx - 2.0 * ex * svx + ex * ex * sv, svyy - 2.0 * ey * svy + ey * ey * sv,
                          svxy - ex * svy - ey * svx + ex * ey * sv)


@njit(cache=True)
def fit_streaks(img, xy, motion, half_size, s, ig, sigma_pred):
    """:func:`centroid_streaks` ``method="streak"`` without its argument handling, for other
    kernels (the tracker's windows): the streaks predicted at ``xy`` (N, 2) to within
    ``sigma_pred`` (N,) pixels (NaN: unknown) moving by ``motion`` (N, 2) in the float32 image
    ``img``, a margin of ``half_size`` (int64) pixels, the model's σ ``s``
    (:func:`streak_model_sigma`) and the gain's inverse ``ig`` (0: unknown). Returns a
    :class:`StreakFit`."""
    h, w = img.shape
    n = len(xy)
    out = np.zeros((_NCOL, n))
    for row in (_X, _Y, _SIGMA_X, _SIGMA_Y, _ELONGATION):
        out[row, :] = np.nan
    half = np.empty((n, 2), np.int64)
    pixels = np.empty((9, 0))  # _sums' pixels, grown to the largest window
    for i in range(n):
        dx, dy = motion[i, 0], motion[i, 1]
        length = math.hypot(dx, dy)
        hx, hy = half_size + int(math.ceil(abs(dx) / 2)), half_size + int(math.ceil(abs(dy) / 2))
        half[i, 0], half[i, 1] = hx, hy
        xs, ys = xy[i, 0], xy[i, 1]
        if not (np.isfinite(xs) and np.isfinite(ys)):
            continue
        cx, cy = int(round(xs)), int(round(ys))
        y0, y1 = max(cy - hy, 0), min(cy + hy, h - 1)
        x0, x1 = max(cx - hx, 0), min(cx + hx, w - 1)
        if y1 - y0 < 2 or x1 - x0 < 2:
            continue
        buf = np.empty(2 * (x1 - x0 + 1) + 2 * (y1 - y0 - 1))  # the sky from the window's border
        m = 0
        for x in range(x0, x1 + 1):
            buf[m] = img[y0, x]
            buf[m + 1] = img[y1, x]
            m += 2
        for y in range(y0 + 1, y1):
            buf[m] = img[y, x0]
            buf[m + 1] = img[y, x1]
            m += 2
        sky, noise = robust_level_noise(buf, 0.0, False)
        out[_SKY, i] = sky
        out[_NOISE, i] = noise
        box = _Box(y0, y1, x0, x1, sky, noise)
        half_len = max(0.5 * length, 5e-4)  # a still star: the limit, a Gaussian along too
        ux, uy = (dx / length, dy / length) if length > 0 else (1.0, 0.0)
        shape = _shape(ux, uy, half_len, s)
        if sigma_pred[i] <= START_SIGMA_PX:
            xc, yc = xs, ys
        else:
            xc, yc, ok = _weighted_centre(img, box, shape, xs, ys, hx, hy)
            if not ok:
                continue
        area = (y1 - y0 + 1) * (x1 - x0 + 1)
        pixels = pixels if pixels.shape[1] >= area else np.empty((9, area))
        p, cov, ok, (npix, sv, sxx, syy, sxy) = _fit(img, box, shape, xc, yc, ig, pixels)
        if not ok:
            continue
        peak = -np.inf
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                peak = max(peak, img[y, x] - sky)
        out[_X, i] = p[1]
        out[_Y, i] = p[2]
        out[_FLUX, i] = p[0] * 2.0 * math.sqrt(2.0 * math.pi) * s  # the model's integral
        out[_PEAK, i] = peak
        out[_SIGMA_X, i] = math.sqrt(max(cov[1, 1], 0.0))
        out[_SIGMA_Y, i] = math.sqrt(max(cov[2, 2], 0.0))
        out[_COV_XY, i] = cov[1, 2]
        out[_AREA, i] = npix
        out[_ELONGATION, i] = 0.0
        if sv > 0.0:  # long over short axis of the second moments
            mxx, myy, mxy = sxx / sv, syy / sv, sxy / sv
            root = math.sqrt(max(0.25 * (mxx - myy) ** 2 + mxy * mxy, 0.0))
            big, small = 0.5 * (mxx + myy) + root, 0.5 * (mxx + myy) - root
            out[_ELONGATION, i] = math.sqrt(big / max(small, 1e-12))
    noise_level = np.median(out[_NOISE]) if n else 0.0
    sky_level = np.median(out[_SKY]) if n else 0.0
    return StreakFit(out[_X], out[_Y], out[_FLUX], out[_AREA], out[_PEAK], out[_SIGMA_X], out[_SIGMA_Y],
                     out[_COV_XY], out[_ELONGATION], out[_NOISE], out[_SKY], half, noise_level, sky_level)
