"""One tracked frame's measurement in one compiled call: windows planned, tiles cut and
centroided, stars matched, the attitude fitted (docs/tracking.md#one-tracking-update).

:func:`measure_frame` runs the steps of :mod:`skyfix.track.windows` in order with nothing in
Python between them:

1. :func:`~skyfix.track.windows.plan_windows` — the catalogue stars in the frame at the
   predicted attitude, and the windows chosen and sized among them;
2. on a rolling-shutter sensor, each window's star moved to the time its row was seen
   (:func:`skyfix.detect.streak.row_time_offset`), ``J ω Δt`` (the windows' docstring);
3. :func:`~skyfix.track.windows.cut_tiles` — the tiles in one mosaic, and each one's sky and
   noise from its border (not for the streak fit, which takes its own);
4. the centroids: the streak fit (:func:`skyfix.detect.streak_fit.fit_streaks`) when the tracker's
   centroider is ``"streak"``, the tiles are centred on the predictions and the streaks are at
   least ``streak_px`` long; else the round-star centroider of
   :func:`skyfix.detect.centroid.refine_kernel` (the centre of mass for ``"streak"``) with each
   tile's own sky and noise;
5. :func:`~skyfix.track.windows.fit_windows` — gate, magnitude, pair check, attitude fit.

One call because the calls cost more than the work: a kernel called from Python types each
argument (~0.2 µs an array, more a tuple) and the Python between the kernels allocated; at
16 windows at rest that was over half of the measurement's time.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix.detect.centroid import Centroider, refine_kernel, refined_columns
from skyfix.detect.centroids import background_snr
from skyfix.detect.streak import row_time_offset
from skyfix.detect.streak_fit import fit_streaks
from skyfix.track.windows import (
    Local,
    MatchSettings,
    View,
    WindowSettings,
    cut_tiles,
    fit_windows,
    new_selection,
    no_fit,
    plan_windows,
    tile_layout,
)

__all__ = ["CentroidSettings", "measure_frame"]


class CentroidSettings(NamedTuple):
    """How the tracker centroids its windows (:class:`skyfix.track.Tracker`'s ``centroid``,
    ``psf_sigma_px``, ``gain`` and ``star_radius_px``).

    streak : bool — the streak fit for streaks at least ``streak_px`` long (``"streak"``).
    streak_px : float — the shortest streak fitted as one, pixels.
    margin_px : int — the streak fit's margin around a streak at most (the star and a pixel).
    model_sigma_px : float — the streak model's σ (:func:`skyfix.detect.streak.streak_model_sigma`).
    round : Centroider — the round-star centroider (:func:`skyfix.detect.centroid.centroider`),
        with the gain's inverse (0: unknown), which the streak fit takes too.
    """

    streak: bool
    streak_px: float
    margin_px: int
    model_sigma_px: float
    round: Centroider


@njit(cache=True)
def measure_frame(img, A, P, rate, P_rate, exposure_s, line_time_s, local_t, select_mag, cam, settings_t,
                  view_t, tiles, max_tile, vectors, zero_point, match_t, centroid_t, min_stars, outlier_k):
    """The steps of the module docstring for the frame ``img`` (H, W; any real dtype, never
    copied) at the predicted attitude ``A`` (covariance ``P``, rad²), rate ``rate`` (rad/s,
    covariance ``P_rate``), exposure ``exposure_s`` and ``line_time_s`` (0: a global shutter).
    The :class:`~skyfix.track.windows.Local` catalogue, :class:`~skyfix.track.windows.WindowSettings`,
    :class:`~skyfix.track.windows.View`, :class:`~skyfix.track.windows.MatchSettings` and
    :class:`CentroidSettings` come as plain tuples (numba types a NamedTuple argument in Python,
    ~1.6 µs each, a plain tuple in its C dispatcher); ``tiles`` is a float32 buffer of at least
    ``n_max·(2·max_tile)²`` values; ``vectors`` the star index's unit vectors; ``zero_point``
    the magnitudes' running zero point (NaN: none yet).

    Returns a plain tuple (a NamedTuple costs twice as much to hand back to Python): of the
    :class:`~skyfix.track.windows.Plan`, ``n``, ``too_wide`` and ``faintest_mag``; of the
    :class:`~skyfix.track.windows.WindowFit` (not ``ok``, no stars, when the plan found fewer
    than ``min_stars`` windows), ``ok``, ``n_found``, ``n_gated``, ``n_fit``, ``A_icrs_to_cam``,
    ``covariance_rad2``, ``zero_point``, ``log_chance`` and the fitted stars' ``index``, ``xy``
    and ``b`` (the first ``n_fit`` rows)."""
    height, width = img.shape
    settings = WindowSettings(*settings_t)
    sel = new_selection(settings.n_max)
    plan = plan_windows(A, P, rate, P_rate, exposure_s, Local(*local_t), select_mag, cam, width, height,
                        settings, View(*view_t), sel)
    n = plan.n
    if n < min_stars:
        return _flat(plan, no_fit(np.int64(0), np.int64(0), np.nan))
    dt = np.zeros(n)
    if line_time_s != 0.0:
        for i in range(n):
            d = row_time_offset(sel.y[i], line_time_s, height)
            J = sel.jac[i]
            dt[i] = d
            sel.x[i] += (J[0, 0] * rate[0] + J[0, 1] * rate[1] + J[0, 2] * rate[2]) * d
            sel.y[i] += (J[1, 0] * rate[0] + J[1, 1] * rate[1] + J[1, 2] * rate[2]) * d
    origin = np.empty((n, 2), np.int64)
    at = np.empty((n, 2))  # the predictions in the mosaic
    sky = np.empty(n)
    noise = np.empty(n)
    c = CentroidSettings(*centroid_t)
    how = Centroider(*c.round)
    _, recentred, streak = tile_layout(sel, n, max_tile)
    streaks = c.streak and not recentred and streak >= c.streak_px  # the streak fit takes its own sky
    tile_half, _, _ = cut_tiles(img, sel, n, max_tile, tiles, origin, at, sky, noise, not streaks)
    size = 2 * tile_half
    mosaic = tiles[:n * size * size].reshape(n * size, size)
    x, y, sx, sy, flux, snr = np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    if streaks:
        margin = min(tile_half - int(math.ceil(streak / 2)) - 1, c.margin_px)
        sigma = np.empty(n)  # the predictions' σ, px: precise ones start the fit themselves
        for i in range(n):
            sigma[i] = math.sqrt(max(sel.cov[i, 0], sel.cov[i, 2], 0.0))
        f = fit_streaks(mosaic, at, sel.smear[:n], np.int64(max(2, margin)), c.model_sigma_px, how.inv_gain,
                        sigma)
        for i in range(n):
            x[i], y[i], sx[i], sy[i], flux[i] = f.x[i], f.y[i], f.sigma_x[i], f.sigma_y[i], f.flux[i]
            snr[i] = background_snr(f.flux[i], f.noise[i], f.area[i])  # 0 where no centroid (no flux)
    else:
        r = refined_columns(refine_kernel(mosaic, at[:, 0].copy(), at[:, 1].copy(), sky, noise,
                                          np.full(n, tile_half, np.int64), how))
        for i in range(n):
            found = r.ok[i] > 0
            x[i] = r.x[i] if found else np.nan
            y[i], sx[i], sy[i], flux[i] = r.y[i], r.sigma_x[i], r.sigma_y[i], r.flux[i]
            snr[i] = background_snr(r.flux[i], r.noise[i], r.npix[i]) if found else 0.0
    fit = fit_windows(n, x, y, sx, sy, flux, snr, origin, size, sel, vectors, zero_point,
                      MatchSettings(*match_t), cam, rate, dt, plan.n_view, float(width * height), min_stars,
                      outlier_k)
    return _flat(plan, fit)


@njit(cache=True, inline="always")
def _flat(plan, fit):
    """:func:`measure_frame`'s tuple."""
    return (plan.n, plan.too_wide, plan.faintest_mag, fit.success, fit.n_found, fit.n_gated, fit.n_fit,
            fit.A_icrs_to_cam, fit.covariance_rad2, fit.zero_point, fit.log_chance, fit.index, fit.xy, fit.b)
