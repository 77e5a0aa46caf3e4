"""Campaign parameters for what real frames carry (issue 27 part 5): the camera told the solver
off by its calibration's own 1σ or by a residual distortion, a ground frame's time stamp off, and
the image-level sources (seeing, scintillation, PSF growth, JPEG) reaching ``render``."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from skyfix.errors import InputError
from skyfix.geometry import attitude_from_radec_roll, rotation_angle_between
from skyfix.montecarlo.campaign import calibration_sigma, campaign_from_dict
from skyfix.montecarlo.trials import EARTH_RATE_RAD_S, run_trial, stamped_attitude, told_camera
from skyfix.simulate import resolve_setup

ARCSEC = math.pi / 180 / 3600


def _campaign(level="centroid", camera="mt9p031", **parameters):
    return campaign_from_dict({"campaign": {"name": "t", "level": level, "trials": 4, "seed": 3},
                               "camera": {"preset": camera}, "parameters": parameters})


def test_a_time_stamp_one_second_off_turns_the_truth_by_15_arcsec():
    A = attitude_from_radec_roll(1.0, 0.0, 0.2)
    assert rotation_angle_between(A, stamped_attitude(A, 1.0)) / ARCSEC == pytest.approx(15.0411, abs=1e-3)
    assert EARTH_RATE_RAD_S / ARCSEC == pytest.approx(15.0411, abs=1e-3)
    # at Dec 60° the boresight moves half as far (the rest is roll)
    B = attitude_from_radec_roll(1.0, math.radians(60.0), 0.2)
    moved = math.acos(np.clip(B[2] @ stamped_attitude(B, 1.0)[2], -1, 1)) / ARCSEC
    assert moved == pytest.approx(15.0411 * 0.5, rel=1e-4)


def test_a_trial_is_judged_against_the_stamped_truth():
    campaign = _campaign(sigma_px=0.0, timestamp_error_s=10.0)
    row = run_trial(campaign, 0)
    rng = np.random.default_rng(np.random.SeedSequence(row["seed"]).spawn(4)[3])  # the trial's "told" stream
    dt = 10.0 * rng.standard_normal()
    A = attitude_from_radec_roll(*np.radians([row["ra_true_deg"], row["dec_true_deg"], row["roll_true_deg"]]))
    expected = math.acos(np.clip(A[2] @ stamped_attitude(A, dt)[2], -1, 1)) / ARCSEC
    assert row["status"] == "solved" and expected > 10
    assert row["boresight_error_arcsec"] == pytest.approx(expected, abs=0.05)


def test_calibration_error_draws_each_coefficient_at_its_one_sigma():
    sigma = calibration_sigma("mt9p031")
    assert sigma["fx"] == pytest.approx(1.212 / 3)
    assert set(sigma) == {"fx", "fy", "cx", "cy", "k1", "k2", "p1"}
    camera = resolve_setup("mt9p031", None, None, None)[0]
    values = {"focal_error": 0.0, "calibration_error": 2.0, "distortion_error": 0.0}
    rng = np.random.default_rng(7)
    told = [told_camera(camera, values, sigma, rng) for _ in range(4000)]
    for key in sigma:
        z = np.array([getattr(t, key) - getattr(camera, key) for t in told]) / (2.0 * sigma[key])
        assert np.std(z) == pytest.approx(1.0, abs=0.05) and abs(np.mean(z)) < 0.05
    same = told_camera(camera, {**values, "calibration_error": 0.0}, sigma, rng)
    assert same == camera
    bent = told_camera(camera, {**values, "calibration_error": 0.0, "distortion_error": 0.1}, sigma, rng)
    assert bent == dataclasses.replace(camera, k1=camera.k1 * 1.1, k2=camera.k2 * 1.1)


def test_calibration_error_needs_a_camera_with_calibration_sigma():
    with pytest.raises(InputError, match=r"calibration\.sigma"):
        _campaign(camera="generic", calibration_error=1.0)
    assert _campaign(camera="generic", calibration_error=0.0).fixed["calibration_error"] == 0.0
    with pytest.raises(InputError, match="jpeg_quality"):
        _campaign(level="image", camera="generic", jpeg_quality=99)
    with pytest.raises(InputError, match="acts at the image level"):
        _campaign(seeing_arcsec=2.0)


def test_image_level_sources_reach_the_render():
    campaign = _campaign(level="image", camera="generic", jpeg_quality=80, seeing_arcsec=30.0,
                         scintillation=True, airmass=1.5, psf_growth=0.2, exposure_s=0.05)
    row = run_trial(campaign, 1)
    assert row["status"] in ("solved", "failed")
    assert (row["jpeg_quality"], row["seeing_arcsec"], row["scintillation"]) == (80, 30.0, True)
