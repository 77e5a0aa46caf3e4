"""Slow suite: blind solves, no camera file, no FOV hint — never a wrong attitude, honest error
bars (issue 7). ``pytest -m slow tests/analysis/test_blind_campaign.py``; the same numbers as a table:
``benchmarks/run --suites e``.

Wrong = boresight beyond max(60″, 1 px) or roll beyond 0.5° at the solution's boresight pixel;
the normalised error (error / reported σ per axis) must have an RMS within 0.7–1.5.
"""

import pytest

from skyfix.analysis.blind_campaign import preset_image_trials, summarize, uncalibrated_centroid_trials

pytestmark = pytest.mark.slow

PRESETS = ("sunsat", "generic", "has2", "mt9v022", "mt9p031", "droid_x2", "ov5642")


def test_ten_thousand_uncalibrated_sparse_fields_never_wrong():
    """Measured 2026-11-23: 7989 of 10 000 solved, 0 wrong, normalised RMS 1.03/1.05/1.03 (the
    rest fail as too few stars or "attitude too uncertain": a chance of a wrong attitude above
    1e-3)."""
    s = summarize(uncalibrated_centroid_trials(10_000, seed=1))
    assert s["wrong"] == 0, s
    assert s["solved"] >= 0.78 * s["n"], s
    assert all(0.7 <= v <= 1.5 for v in s["normalised_rms"]), s


@pytest.mark.parametrize("preset", PRESETS)
@pytest.mark.parametrize(("n_false", "n_hot"), [(0, 0), (3, 20)])
def test_preset_frames_never_wrong(preset, n_false, n_hot):
    s = summarize(preset_image_trials(preset, 500, seed=1, false_stars=n_false, hot_pixels=n_hot))
    assert s["wrong"] == 0, s
    if s["solved"] >= 50:  # enough solves to judge the error bars
        assert all(0.7 <= v <= 1.5 for v in s["normalised_rms"]), s
