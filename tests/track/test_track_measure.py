"""The tracker's compiled calls against the same steps run one at a time.

1. :func:`skyfix.track.measure.measure_frame` (the window plan to the attitude fit) against
   :func:`measure_steps`, each kernel called on its own from Python: the Tracker runs as in
   flight on simulated frames — at rest (the centre of mass in the windows), at 1 °/s (the
   streak fit) and at 1 °/s on a rolling shutter (windows moved along ``J ω Δt``, rays turned
   back to the frame time) — and every ``measure_frame`` inside the tracker's one compiled step
   (:func:`skyfix.track.step.track_step`) is repeated on the same arguments: the same windows,
   centroids, stars and attitude must come out (to 1e-12; the kernels are the same compiled
   code, inlined or not).
2. The Tracker with the MEKF in one compiled step (:meth:`Tracker._step`: the window plan to the
   filter's correction and the Solution's numbers) against the same Tracker step by step
   (:meth:`Tracker._steps`: the predictor's ``predict``, ``measure_frame``, its
   ``update_gated``, the Solution's numbers), on the same frames, with and without gyro rates:
   every Solution is the same, bit for bit (docs/tracking.md#one-tracking-update).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import skyfix.track.frame_steps as frame_steps_module
from skyfix.camera import Camera
from skyfix.detect.centroid import Centroider, refine_kernel, refined_columns
from skyfix.detect.centroids import background_snr
from skyfix.detect.streak import row_time_offset
from skyfix.detect.streak_fit import fit_streaks
from skyfix.geometry import attitude_from_radec_roll
from skyfix.simulate import Sensor, render_sequence
from skyfix.track import Tracker
from skyfix.track.measure import CentroidSettings, measure_frame
from skyfix.track.step import track_step
from skyfix.track.windows import (
    Local,
    MatchSettings,
    Selection,
    View,
    WindowSettings,
    cut_tiles,
    fit_windows,
    plan_windows,
    tile_layout,
)

CAMERA = Camera.from_fov(1280, 960, 15.0)
EPOCH = 2025.5
A0 = attitude_from_radec_roll(math.radians(84.0), math.radians(-2.0), math.radians(20.0))
AXIS = np.array([0.6, -0.75, 0.28]) / np.linalg.norm([0.6, -0.75, 0.28])
LINE_TIME_S = 2e-5
CASES = {  # rate (°/s), Tracker keywords, render keywords, the windows' centroider
    "rest": (0.0, {}, {}, "round"),
    "1 deg/s": (1.0, {}, {}, "streak"),  # 8.5 px streaks in the 0.1 s exposure
    "1 deg/s, rolling shutter": (1.0, {"exposure_s": 0.02, "line_time_s": LINE_TIME_S},  # 1.7 px: round
                                 {"exposure_s": 0.02,
                                  "sensor": Sensor.from_preset("generic").replace(line_time_s=LINE_TIME_S)},
                                 "round"),
}


def measure_steps(img, A, P, rate, P_rate, exposure_s, line_time_s, local_t, select_mag, cam, settings_t,
                  view_t, tiles, max_tile, vectors, zero_point, match_t, centroid_t, min_stars, outlier_k):
    """``measure_frame``'s steps one by one (its arguments; buffers of its own). Returns the
    :class:`~skyfix.track.windows.Plan`, the :class:`~skyfix.track.windows.WindowFit` (None
    when too few windows), the windows' centroids ``(n, 2)`` in the mosaic, and which
    centroider ran (``"streak"`` or ``"round"``)."""
    height, width = img.shape
    settings = WindowSettings(*settings_t)
    sel = Selection.empty(settings.n_max)
    plan = plan_windows(A, P, rate, P_rate, exposure_s, Local(*local_t), select_mag, cam, width, height,
                        settings, View.empty(len(view_t[0])), sel)
    n = plan.n
    if n < min_stars:
        return plan, None, None, None
    dt = np.zeros(n)
    if line_time_s != 0.0:  # each star at its row's time: J ω Δt
        dt = np.array([row_time_offset(y, line_time_s, height) for y in sel.y[:n]])
        motion = sel.jac[:n] @ rate
        sel.x[:n] += motion[:, 0] * dt
        sel.y[:n] += motion[:, 1] * dt
    c = CentroidSettings(*centroid_t)
    how = Centroider(*c.round)
    _, recentred, streak = tile_layout(sel, n, max_tile)
    streaks = c.streak and not recentred and streak >= c.streak_px
    origin, at, sky, noise = np.empty((n, 2), np.int64), np.empty((n, 2)), np.empty(n), np.empty(n)
    own = np.zeros_like(tiles)
    tile_half, _, _ = cut_tiles(img, sel, n, max_tile, own, origin, at, sky, noise, not streaks)
    size = 2 * tile_half
    mosaic = own[:n * size * size].reshape(n * size, size)
    if streaks:
        margin = min(tile_half - math.ceil(streak / 2) - 1, c.margin_px)
        sigma = np.sqrt(np.maximum(np.maximum(sel.cov[:n, 0], sel.cov[:n, 2]), 0.0))
        f = fit_streaks(mosaic, at, sel.smear[:n], np.int64(max(2, margin)), c.model_sigma_px, how.inv_gain,
                        sigma)
        x, y, sx, sy, flux = f.x, f.y, f.sigma_x, f.sigma_y, f.flux
        snr = background_snr(f.flux, f.noise, f.area)
    else:
        r = refined_columns(refine_kernel(mosaic, at[:, 0].copy(), at[:, 1].copy(), sky, noise,
                                          np.full(n, tile_half, np.int64), how))
        found = r.ok > 0
        x, y, sx, sy, flux = np.where(found, r.x, np.nan), r.y, r.sigma_x, r.sigma_y, r.flux
        snr = np.where(found, background_snr(r.flux, r.noise, r.npix), 0.0)
    fit = fit_windows(n, x, y, sx, sy, flux, snr, origin, size, sel, vectors, zero_point,
                      MatchSettings(*match_t), cam, rate, dt, plan.n_view, float(width * height), min_stars,
                      outlier_k)
    return plan, fit, np.column_stack([x, y]), "streak" if streaks else "round"


@pytest.mark.parametrize("case", list(CASES))
def test_compiled_measurement_is_the_steps_one_by_one(case, monkeypatch):
    rate_dps, options, render, expected = CASES[case]
    rate = np.radians(AXIS * rate_dps) if rate_dps else None
    frames = list(render_sequence(A0, CAMERA, n_frames=8, fps=10.0, rate_rad_s=rate, epoch=EPOCH, seed=5,
                                  **render))
    compared = []

    def both(*args):
        out = track_step(*args)
        img, A, P, rate = args[:4]
        measured = (img, A, P[:3, :3].copy(), rate, P[3:, 3:].copy(), *args[7:-3])  # measure_frame's
        compared.append((out[0], measure_steps(*measured)))
        alone = measure_frame(*measured)
        assert all(np.array_equal(x, y, equal_nan=True) for x, y in zip(out[0], alone, strict=True))
        return out

    monkeypatch.setattr(frame_steps_module, "track_step", both)
    tracker = Tracker(CAMERA, epoch=EPOCH, **options)
    sols = [tracker.update(f.image, f.truth["t_s"]) for f in frames]
    assert [s.mode for s in sols[2:]] == ["tracking"] * 6
    fitted = 0
    worst = {"xy": 0.0, "A": 0.0, "P": 0.0}
    for out, (plan, fit, centroids, centroider) in compared:
        n, too_wide, faintest, ok, n_found, n_gated, n_fit, A, P, zero_point, log_chance, index, xy, b = out
        assert (n, too_wide, faintest) == (plan.n, plan.too_wide, plan.faintest_mag)
        if fit is None:
            assert not ok
            continue
        assert (ok, n_found, n_gated, n_fit) == (fit.success, fit.n_found, fit.n_gated, fit.n_fit)
        assert np.array_equal(index[:n_fit], fit.index[:n_fit])
        assert np.isclose(zero_point, fit.zero_point, rtol=0, atol=1e-12)
        assert np.isclose(log_chance, fit.log_chance)
        assert centroider == expected
        worst["xy"] = max(worst["xy"], np.abs(xy[:n_fit] - fit.xy[:n_fit]).max())
        worst["A"] = max(worst["A"], np.abs(A - fit.A_icrs_to_cam).max())
        worst["P"] = max(worst["P"], np.abs(P - fit.covariance_rad2).max() / np.abs(P).max())
        assert np.isfinite(centroids).sum() >= 2 * n_fit
        fitted += ok
    print(f"\n{case}: {fitted} fits compared; largest differences: centroids {worst['xy']:.1e} px, "
          f"attitude {worst['A']:.1e}, covariance {worst['P']:.1e} relative")
    assert fitted >= 6
    assert worst["xy"] <= 1e-12 and worst["A"] <= 1e-12 and worst["P"] <= 1e-12


def _numbers(sol):
    """A Solution's numbers: all that a tracked frame reports but its times."""
    matches = [tuple(m) for m in sol.matches]
    A = None if sol.A_icrs_to_cam is None else sol.A_icrs_to_cam.tolist()
    return (sol.mode, sol.status, sol.reason, A, sol.covariance_arcsec2, sol.rate_dps,
            sol.rate_covariance_dps2, sol.n_matched, sol.n_detected, sol.prob_false, sol.rmse_arcsec,
            sol.ra_deg, sol.dec_deg, sol.roll_deg, sol.quaternion_xyzw, matches)


@pytest.mark.parametrize("case", ["rest", "1 deg/s", "1 deg/s, rolling shutter", "1 deg/s, gyro"])
def test_one_compiled_step_is_the_steps_one_by_one(case, monkeypatch):
    rate_dps, options, render, _ = CASES[case.removesuffix(", gyro")]
    rate = np.radians(AXIS * rate_dps) if rate_dps else None
    gyro = rate if case.endswith("gyro") else None
    frames = list(render_sequence(A0, CAMERA, n_frames=8, fps=10.0, rate_rad_s=rate, epoch=EPOCH, seed=5,
                                  **render))
    runs = {}
    for how in ("step", "steps"):
        if how == "steps":
            monkeypatch.setattr(Tracker, "_step", Tracker._steps)
        tracker = Tracker(CAMERA, epoch=EPOCH, **options)
        sols = [tracker.update(f.image, f.truth["t_s"], gyro_rate_rad_s=gyro) for f in frames]
        runs[how] = sols
    step, steps = runs["step"], runs["steps"]
    assert [s.mode for s in step[2:]] == ["tracking"] * 6
    assert set(step[-1].time_ms) == {"predict", "step", "total"}
    assert set(steps[-1].time_ms) == {"predict", "measure", "filter", "total"}
    for a, b in zip(step, steps, strict=True):
        assert _numbers(a) == _numbers(b)
