"""The tracking study (skyfix.analysis.tracking_study, docs/tracking-study.md) on a short run.

One 36-frame sequence (1280 × 960, 15°, 10 Hz, the generic sensor's noise): a slew accelerating
at 1 °/s² from rest to 1.5 °/s, a blank frame and a 90° jump. Its prediction errors must follow
the analytic response to a steady acceleration (a held rate is off by αT², thesis 004's
three-point weights by ½αT², the exact quadratic by nothing), the tracker's error bars must fit
its errors, and the thesis's binned-slope analysis must recover a known line. The Table 5-1 frame
is checked for what its timing rests on — every window and the full frame find every star —
never for a time.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from skyfix.analysis import tracking_report
from skyfix.analysis import tracking_study as ts
from skyfix.geometry import normalize

DEG = math.pi / 180
SLEW = ts.SequenceSpec(
    "test slew", "slew", {"rotation_rad": (10 * DEG * normalize(np.array([0.3, 1.0, 0.1]))).tolist(),
                          "max_rate_rad_s": 1.5 * DEG, "accel_rad_s2": 1.0 * DEG, "start_s": 0.0},
    n_frames=36, blank_frame=24, jump_frame=29, radec_roll_deg=(84.0, -2.0, 20.0), seed=11, time_error_s=0.02)


@pytest.fixture(scope="module")
def slew() -> ts.SequenceResult:
    return ts.run_sequence(SLEW)


@pytest.mark.parametrize("predictor", sorted(ts.ANALYTIC_ACCEL_RATIO))
def test_prediction_error_under_acceleration_is_the_analytic_one(slew, predictor):
    """δθ of the prediction along α, over αT² (36″ at 1 °/s², 10 Hz), on the ramp's frames."""
    a = ts.accel_slopes([slew], predictor)
    print(f"\n{predictor}: δθ/αT² {a['ratio']:.3f} (analytic {a['analytic']}), residual "
          f"{a['residual_arcsec']:.1f}″ over {a['n']} accelerating frames")
    assert a["n"] >= 10
    assert abs(a["ratio"] - a["analytic"]) < 0.15


def test_the_filter_lags_less_than_a_held_rate(slew):
    mekf, held = ts.accel_slopes([slew], "mekf"), ts.accel_slopes([slew], "small-angle")
    assert 0.0 < mekf["ratio"] < held["ratio"]


def test_prediction_error_in_pixels_is_near_the_centroid_noise_at_constant_rate(slew):
    """On the coast at 1.5 °/s every predictor puts the stars within a pixel of their centroids."""
    coast = (np.abs(slew.accel_dps2).max(axis=1) == 0) & slew.steady_accel
    for name in ts.PREDICTOR_NAMES:
        e = slew.predictions[name].meas_px[coast]
        e = e[np.isfinite(e)]
        assert len(e) >= 5
        assert np.mean(e) < 1.0, (name, e)


def test_error_bars_fit_the_errors(slew):
    """δθ/σ over the tracked frames: the RMS of all three axes together within the issue's
    0.7–1.5, each axis within a looser band — ~30 frames of a filter's errors, correlated from
    frame to frame, pin one axis's RMS only to about ±40 % (the ≥ 1000-frame figure is the full
    study's, docs/tracking-study.md)."""
    z = ts.normalised_errors([slew])
    pooled = float(np.sqrt(np.mean(np.square(z["rms"]))))
    print(f"\nδθ/σ RMS per axis {np.round(z['rms'], 2)}, all axes {pooled:.2f} over {z['n_frames']} "
          f"frames, NEES {z['nees_mean']:.2f}")
    assert z["n_frames"] >= 25
    assert 0.7 <= pooled <= 1.5
    assert all(0.35 <= r <= 2.0 for r in z["rms"]), z["rms"]


def test_tracked_frames_are_measured_against_the_truth(slew):
    acc = ts.accuracy_summary(slew)
    assert acc["frames"] == 36 and acc["compared"] >= 20
    assert acc["bore_track"] < 5.0 and acc["bore_lis"] < 10.0
    assert slew.event[24] == "blank" and slew.event[29] == "jump"
    assert not slew.tracked[24] and slew.n_visible[24] == 0  # the blank frame has no star
    assert slew.mode[29] == "lost"                            # the jump is solved lost in space
    assert 1 <= ts.recovery_frames(slew, "jump") <= 2 and 1 <= ts.recovery_frames(slew, "blank") <= 2
    assert ts.recovery_frames(slew, "nothing") is None


def test_binned_slopes_recover_a_known_line():
    """Thesis 002 Fig 5-9's analysis on errors drawn about 0.1 px + 0.0028 px per arcsec/s."""
    rng = np.random.default_rng(3)
    rate = rng.uniform(0, 300, 4000)
    err = 0.1 + 0.0028 * rate + rng.normal(0, 0.05, rate.size)
    fits, bins = ts.binned_fits(rate, err, 6)
    mean = fits[1]
    assert mean.statistic == "mean"
    assert mean.slope == pytest.approx(0.0028, rel=0.03)
    assert mean.intercept == pytest.approx(0.1, abs=0.01)
    assert fits[0].slope == pytest.approx(fits[2].slope, rel=0.05)  # a constant std: parallel lines
    assert len(bins) == 6 and bins[:, 3].sum() == 4000


def test_table_5_1_frame_windows_and_full_frame_find_every_star():
    rows = ts.run_timing(rois=(40, 200), star_counts=(5,), repeats=1, seed=2)
    for r in rows:
        assert r.found_windowed == 5 and r.found_full == 5
        assert r.rms_windowed_px < 0.1
    big = next(r for r in rows if r.roi_px == 200)
    assert big.rms_windowed_3sigma_px > 3 * big.rms_windowed_px  # a low threshold over a big window


def test_write_study(slew, tmp_path):
    timing = ts.run_timing(rois=(40,), star_counts=(5,), repeats=1, seed=2)
    study = ts.TrackingStudy(sequences=[slew], timing=timing,
                             settings=dict(ts.QUICK._asdict(), camera="1280×960, 15°", epoch=ts.EPOCH,
                                           cpu_count=2))
    paths = tracking_report.write_study(study, tmp_path, command="test")
    assert [p.name for p in paths[:2]] == ["tracking_study.json", "tracking_study.md"]
    assert len(paths) == 7 and all(p.stat().st_size > 0 for p in paths)
    data = json.loads(paths[0].read_text())  # strict JSON: NaN written as null
    assert len(data["sequences"][0]["t_s"]) == 36
    md = paths[1].read_text()
    for text in ("Table 5-1", "0.0019", "δθ / αT²", "test slew", "small-angle, times ±20 ms"):
        assert text in md
