"""A lens with decentring (tangential) distortion solved with no camera file: the uncalibrated
pinhole prior fits p1, p2 under σ 1e-3 (``CameraPrior.uncalibrated``), so the attitude's error
bar includes them (``docs/solving-without-a-camera.md``). Without them thesis 003's MT9P031 lens
(p1 2.3e-4) put its p1 into the principal point and the boresight, 5.6″ about x against error
bars 5.5× too small."""

import numpy as np
import pytest

from skyfix.analysis.preset_campaign import CampaignRow, run_campaign, summarize_row
from skyfix.calibrate import CameraPrior, fit_camera_with_prior, prior_parameters
from skyfix.camera import Camera, camera_from_preset
from skyfix.geometry import attitude_from_radec_roll


def test_the_uncalibrated_pinhole_prior_fits_p1_p2():
    prior = CameraPrior.uncalibrated(2592, 1944)
    assert prior.sigma_tangential == 1e-3
    assert prior.parameters == ("f", "aspect", "principal_point", "k1", "k2", "tangential")
    assert prior_parameters("pinhole") == ("f", "aspect", "principal_point", "k1", "k2")
    fisheye = CameraPrior.uncalibrated(640, 480, "kannala-brandt")
    assert fisheye.parameters == prior_parameters("kannala-brandt")


def _stars(camera: Camera, A: np.ndarray, n: int, noise_px: float, seed: int):
    rng = np.random.default_rng(seed)
    xy = rng.uniform([0, 0], [camera.width - 1, camera.height - 1], (n, 2))
    r = camera.pixel_to_ray(xy) @ A
    return xy + rng.normal(0.0, noise_px, xy.shape), r


def test_prior_fit_recovers_p1_and_holds_it_when_asked():
    """400 stars at 0.3 px through the MT9P031 camera: p1 within 4σ of its posterior (its σ
    well inside the prior's), p2 within 4σ of 0; a prior with no tangential σ holds them at 0
    (9 step parameters, as before)."""
    cam = camera_from_preset("mt9p031")
    A = attitude_from_radec_roll(1.0, 0.3, 0.4)
    xy, r = _stars(cam, A, 400, 0.3, 3)
    start = Camera.from_fov(cam.width, cam.height, cam.fov_deg)
    A0 = attitude_from_radec_roll(1.0 + 1e-4, 0.3, 0.4)
    prior = CameraPrior.uncalibrated(cam.width, cam.height)
    fit = fit_camera_with_prior(xy, r, start, A0, prior, principal_point="fit")
    assert fit.parameters == prior.parameters
    assert fit.parameter_covariance.shape == (11, 11)
    rmax = np.hypot(cam.width, cam.height) / 2.0 / fit.camera.fx
    s1, s2 = np.sqrt(np.diag(fit.parameter_covariance)[9:11]) / rmax  # steps are p·rmax
    assert s1 < 0.5 * prior.sigma_tangential
    assert abs(fit.camera.p1 - cam.p1) < 4 * s1
    assert abs(fit.camera.p2) < 4 * s2
    no_p = prior._replace(sigma_tangential=0.0)
    held = fit_camera_with_prior(xy, r, start, A0, no_p, principal_point="fit")
    assert held.parameter_covariance.shape == (9, 9)
    assert (held.camera.p1, held.camera.p2) == (0.0, 0.0)
    assert fit.prediction_sigma_px(r).shape == (400,)


@pytest.mark.slow  # a campaign: 8 rendered 5-megapixel frames solved blind (50 s in a loaded default run)
def test_mt9p031_frames_with_no_camera_have_honest_error_bars():
    """Rendered MT9P031 frames (50° field) solved with no hint: error about x over σ has RMS
    within 0.5–2 (5.5 when p1 was held at 0), none wrong."""
    campaign = run_campaign(8, seed=0, rows=(CampaignRow("mt9p031"),))
    (_, _, frames), = campaign.rows
    s = summarize_row(frames, "bands/blind")
    assert s["solved"] == 8 and s["wrong"] == 0
    rms_x, rms_y, _ = s["normalised_rms"]
    assert 0.5 < rms_x < 2.0
    assert 0.5 < rms_y < 2.0
    assert s["boresight_median_arcsec"] < 6.0
