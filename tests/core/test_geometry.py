"""The conventions of docs/design.md: frames, quaternions and roll, pinned with numbers."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skyfix.camera import Camera
from skyfix.geometry import (
    angle_between,
    attitude_from_quaternion,
    attitude_from_radec_roll,
    quaternion_from_attitude,
    radec_roll_from_attitude,
    radec_to_vector,
    vector_to_radec,
)

ARCSEC = np.radians(1 / 3600)


def _project(A, cam, ra, dec):
    xy, front = cam.ray_to_pixel(A @ radec_to_vector(ra, dec))
    assert front
    return xy


def test_north_is_up_and_east_is_left_at_roll_zero():
    cam = Camera.from_fov(1000, 800, 10.0)
    ra0, dec0 = np.radians(80.0), np.radians(20.0)
    A = attitude_from_radec_roll(ra0, dec0, 0.0)
    centre = _project(A, cam, ra0, dec0)
    np.testing.assert_allclose(centre, [cam.cx, cam.cy], atol=1e-9)
    north = _project(A, cam, ra0, dec0 + np.radians(1.0))
    east = _project(A, cam, ra0 + np.radians(1.0), dec0)
    assert north[1] < cam.cy - 50 and abs(north[0] - cam.cx) < 1e-6  # toward row 0
    assert east[0] < cam.cx - 50  # east is left (smaller column)


def test_roll_90_puts_north_to_the_right():
    # Roll is the PA of image-up from north through east: at 90° image-up points east,
    # so north lies toward +x (the image's right).
    cam = Camera.from_fov(1000, 800, 10.0)
    ra0, dec0 = np.radians(200.0), np.radians(-35.0)
    A = attitude_from_radec_roll(ra0, dec0, np.radians(90.0))
    north = _project(A, cam, ra0, dec0 + np.radians(1.0))
    east = _project(A, cam, ra0 + np.radians(1.0) / np.cos(dec0), dec0)
    assert north[0] > cam.cx + 50 and abs(north[1] - cam.cy) < 1.0
    assert east[1] < cam.cy - 50  # east is up


def test_attitude_rows_are_camera_axes_and_right_handed():
    rng = np.random.default_rng(1)
    for _ in range(100):
        ra, dec, roll = rng.uniform(0, 2 * np.pi), rng.uniform(-1.5, 1.5), rng.uniform(0, 2 * np.pi)
        A = attitude_from_radec_roll(ra, dec, roll)
        np.testing.assert_allclose(A @ A.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(A) == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_allclose(A[2], radec_to_vector(ra, dec), atol=1e-12)


def test_radec_roll_round_trip():
    rng = np.random.default_rng(2)
    for _ in range(300):
        ra, dec, roll = rng.uniform(0, 2 * np.pi), rng.uniform(-1.55, 1.55), rng.uniform(0, 2 * np.pi)
        ra2, dec2, roll2 = radec_roll_from_attitude(attitude_from_radec_roll(ra, dec, roll))
        assert angle_between(radec_to_vector(ra, dec), radec_to_vector(ra2, dec2)) < 1e-4 * ARCSEC
        assert abs(np.angle(np.exp(1j * (roll2 - roll)))) < 1e-4 * ARCSEC


def test_quaternion_is_scipy_scalar_last_of_A():
    rng = np.random.default_rng(3)
    for _ in range(100):
        A = attitude_from_radec_roll(*rng.uniform(-1.5, 1.5, 3))
        q = quaternion_from_attitude(A)
        assert q[3] >= 0
        np.testing.assert_allclose(abs(q @ Rotation.from_matrix(A).as_quat()), 1.0, atol=1e-12)
        np.testing.assert_allclose(attitude_from_quaternion(q), A, atol=1e-12)


def test_quaternion_of_known_rotation():
    # Boresight at RA 0, Dec 0, roll 0: camera z = ICRS x, camera y = -ICRS z (north up),
    # camera x = -ICRS y (east left).
    A = attitude_from_radec_roll(0.0, 0.0, 0.0)
    np.testing.assert_allclose(A, [[0, -1, 0], [0, 0, -1], [1, 0, 0]], atol=1e-15)
    np.testing.assert_allclose(quaternion_from_attitude(A), [0.5, -0.5, 0.5, 0.5], atol=1e-15)


def test_vector_radec_round_trip():
    ra = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    dec = np.linspace(-1.5, 1.5, 50)
    ra2, dec2 = vector_to_radec(radec_to_vector(ra, dec))
    np.testing.assert_allclose(ra2, ra, atol=1e-14)
    np.testing.assert_allclose(dec2, dec, atol=1e-14)


def test_pole_roll_is_defined():
    A = attitude_from_radec_roll(0.3, np.pi / 2 - 1e-9, 0.7)
    _, dec, roll = radec_roll_from_attitude(A)
    assert dec == pytest.approx(np.pi / 2, abs=1e-8)
    assert np.isfinite(roll)
