"""The final fit: camera model chosen by BIC, re-matching, honest attitude error bars.

A camera with non-square pixels (thesis 004's Sunsat CCD, 6.5 × 6.25 µm) solved with no camera
model used to report roll errors of 0.3–0.8° with error bars of ~0.1°; the aspect ratio is now
fitted when the stars support it and the covariance includes the camera's uncertainty.
"""

import numpy as np
import pytest

from skyfix.attitude import attitude_error
from skyfix.calibrate import fit_camera, score_camera_models, select_camera_model
from skyfix.camera import Camera
from skyfix.catalog import load_hipparcos
from skyfix.geometry import attitude_from_radec_roll
from skyfix.pipeline import solve_centroids

ARCSEC = np.radians(1 / 3600)


def _field(camera, A, catalog, sigma_px, rng):
    uv, front = camera.ray_to_pixel(catalog.vectors @ A.T)
    ok = front & camera.in_frame(uv)
    xy = uv[ok] + rng.normal(0, sigma_px, (ok.sum(), 2))
    return xy, catalog.vectors[ok]


@pytest.fixture(scope="module")
def stars():
    return load_hipparcos(epoch=2025.0, mag_limit=7.5)


def test_bic_keeps_a_pinhole_a_pinhole(stars):
    cam = Camera.from_fov(1280, 960, 15.0)
    rng = np.random.default_rng(1)
    picks = []
    for _ in range(20):
        A = attitude_from_radec_roll(*rng.uniform([0, -1.2, 0], [6.28, 1.2, 6.28]))
        xy, r = _field(cam, A, stars, 0.3, rng)
        best = min(score_camera_models(xy, r, cam, A), key=lambda s: s.bic)
        picks.append(best.params)
    assert sum(p == ("f",) for p in picks) >= 17  # BIC's false-alarm rate is small


def test_aspect_and_distortion_recovered(stars):
    truth = Camera(width=752, height=582, fx=3846.0, fy=4000.0, cx=375.5, cy=290.5, k1=-0.3, k2=0.1)
    start = Camera.from_fov(752, 582, truth.fov_deg)
    rng = np.random.default_rng(2)
    A = attitude_from_radec_roll(1.0, 0.3, 0.4)
    xy, r = _field(truth, A, load_hipparcos(epoch=2025.0, mag_limit=9.0), 0.1, rng)
    fit = select_camera_model(xy, r, start, A)
    assert set(fit.params) >= {"f", "aspect", "k1"}
    assert fit.camera.fy / fit.camera.fx == pytest.approx(4000 / 3846, rel=2e-4)
    assert fit.camera.fx == pytest.approx(3846.0, rel=2e-4)
    assert fit.sigma_px == pytest.approx(0.1, rel=0.25)
    err = attitude_error(A, fit.A_icrs_to_cam)
    sig = np.sqrt(np.diag(fit.attitude_covariance_rad2))
    assert np.all(np.abs(err) < 4 * sig)


def test_fit_camera_rejects_unknown_parameters(stars):
    cam = Camera.from_fov(640, 480, 10.0)
    with pytest.raises(ValueError, match="unknown camera parameters"):
        fit_camera(np.zeros((10, 2)), np.tile([0, 0, 1.0], (10, 1)), cam, np.eye(3), ("f", "bogus"))


def test_non_square_pixels_solve_with_honest_error_bars(stars, database):
    # Sunsat-like CCD: 752×582, pixels 6.5 × 6.25 µm behind 25 mm, solved with no camera.
    truth = Camera.from_optics(752, 582, 25.0, 6.5).replace(fy=25000 / 6.25)
    rng = np.random.default_rng(3)
    z = []
    for _ in range(12):
        A = attitude_from_radec_roll(*rng.uniform([0, -1.2, 0], [6.28, 1.2, 6.28]))
        xy, _ = _field(truth, A, stars, 0.3, rng)
        sol = solve_centroids(xy, 752, 582, database=database, epoch=2025.0)
        if not sol.solved:
            continue
        err = attitude_error(A, sol.A_icrs_to_cam) / ARCSEC
        sig = np.sqrt(np.diag(sol.covariance_arcsec2))
        z.append(err / sig)
        assert abs(err[2]) < 0.5 * 3600 and np.hypot(err[0], err[1]) < 60  # never a wrong attitude
    assert len(z) >= 9
    z = np.array(z)
    assert np.sqrt(np.mean(z**2)) < 2.0  # error bars honest to within a factor of 2
