"""Markley's quaternion average with its covariance (skyfix.frames.average_quaternions) and the
mounting of a fixed ground camera from a night of images (skyfix.analysis.mounting, thesis 003
§2.9–2.10)."""

from __future__ import annotations

import math

import erfa
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skyfix.analysis import mounting as mt
from skyfix.corrections import refraction as rf
from skyfix.errors import InputError
from skyfix.frames import average_quaternions, matrix_from_euler123
from skyfix.geometry import quaternion_from_attitude

ARCSEC = math.radians(1.0 / 3600.0)


def _about_z(angle_rad: float) -> np.ndarray:
    return np.array([0.0, 0.0, math.sin(angle_rad / 2), math.cos(angle_rad / 2)])


def test_identical_quaternions_average_to_themselves():
    # thesis 003 §5.10: the average of identical quaternions is that quaternion (up to sign)
    q = Rotation.from_euler("XYZ", [20, -35, 110], degrees=True).as_quat(canonical=True)
    avg = average_quaternions(np.array([q, -q, q, q]))
    assert avg.quaternion_xyzw == pytest.approx(q, abs=1e-15)
    assert np.max(np.abs(avg.deviations_rad)) < 1e-15
    assert np.max(np.abs(avg.covariance_rad2)) < 1e-28 and avg.n == 4 and avg.n_effective == 4.0
    one = average_quaternions(q[None])
    assert one.quaternion_xyzw == pytest.approx(q) and np.all(np.isnan(one.covariance_rad2))


def test_average_about_one_axis_is_the_weighted_circular_mean():
    # rotations about one axis by a and b: Markley's average maximises Σ wᵢ cos²(φ − aᵢ/2), so its
    # angle is atan2(Σ wᵢ sin aᵢ, Σ wᵢ cos aᵢ) — exactly
    a, b = math.radians(10.0), math.radians(-20.0)
    for w in ((1.0, 1.0), (3.0, 1.0), (0.2, 5.0)):
        avg = average_quaternions(np.array([_about_z(a), -_about_z(b)]), weights=w)
        angle = math.atan2(w[0] * math.sin(a) + w[1] * math.sin(b), w[0] * math.cos(a) + w[1] * math.cos(b))
        assert avg.quaternion_xyzw == pytest.approx(_about_z(angle), abs=1e-15)
    # the deviations are about z, and the equal-weight scatter of ±15° is (15°)² · 2/(2−1)
    avg = average_quaternions(np.array([_about_z(math.radians(15)), _about_z(math.radians(-15))]))
    assert avg.deviations_rad[:, 2] == pytest.approx([math.radians(15), -math.radians(15)], abs=1e-15)
    assert avg.scatter_rad2[2, 2] == pytest.approx(2 * math.radians(15) ** 2, rel=1e-12)
    assert avg.covariance_rad2[2, 2] == pytest.approx(math.radians(15) ** 2, rel=1e-12)


def test_average_of_noisy_attitudes_and_its_covariance():
    # 400 attitudes scattered by 10″, 20″, 40″ about the target frame's axes: the average lands
    # within its own error bars and the scatter comes back
    rng = np.random.default_rng(7)
    truth = Rotation.from_euler("XYZ", [70, 10, -140], degrees=True)
    sigma = np.array([10.0, 20.0, 40.0]) * ARCSEC
    noise = Rotation.from_rotvec(rng.normal(size=(400, 3)) * sigma)
    qs = (noise * truth).as_quat()  # A_i = R(δθ_i) A_true
    qs[::3] *= -1  # signs do not matter
    avg = average_quaternions(qs)
    err = Rotation.from_quat(avg.quaternion_xyzw) * truth.inv()
    z = err.as_rotvec() / np.sqrt(np.diag(avg.covariance_rad2))
    assert np.all(np.abs(z) < 4.0)
    assert np.sqrt(np.diag(avg.scatter_rad2)) / sigma == pytest.approx([1, 1, 1], abs=0.12)
    assert avg.covariance_rad2 == pytest.approx(avg.scatter_rad2 / 400, rel=1e-12)
    # weights that favour half the attitudes: the effective count drops
    w = np.where(np.arange(400) < 200, 1.0, 0.25)
    weighted = average_quaternions(qs, w)
    assert weighted.n_effective == pytest.approx(250.0**2 / (200 + 200 / 16), rel=1e-12)  # 294.1


@pytest.mark.parametrize("args, match", [
    ((np.zeros((0, 4)),), "shape"), ((np.ones((3, 3)),), "shape"), ((np.zeros((2, 4)),), "non-zero"),
    ((np.ones((2, 4)), [1.0]), "one finite number"), ((np.ones((2, 4)), [-1.0, 1.0]), "one finite number"),
    ((np.ones((2, 4)), [0.0, 0.0]), "not all 0"),
])
def test_bad_quaternions(args, match):
    with pytest.raises(InputError, match=match):
        average_quaternions(*args)


# --- the mounting of a fixed ground camera (thesis 003 §2.10) ---------------------------------------------
@pytest.fixture(scope="module")
def night():
    """A camera fixed at azimuth 120°, altitude 45° (its x axis level), imaged every 10 minutes
    through an 8-hour night: each image's A_icrs_to_enu, the true mounting, the true attitudes."""
    site = rf.Site(40.7, -111.8, 1400.0)
    start = sum(erfa.dtf2d("UTC", 2024, 3, 20, 3, 0, 0.0))
    A_icrs_to_enu = np.array([rf.ground_frame(site, start + k / 144.0).A_icrs_to_enu for k in range(48)])
    # camera axes in ENU: boresight at az 120°, alt 45°; x level (along −azimuth); y = z × x
    alt, az = math.radians(45.0), math.radians(120.0)
    z = np.array([math.cos(alt) * math.sin(az), math.cos(alt) * math.cos(az), math.sin(alt)])
    x = np.array([-math.cos(az), math.sin(az), 0.0])
    A_cam_to_enu = np.column_stack([x, np.cross(z, x), z])
    A_true = A_cam_to_enu.T @ A_icrs_to_enu  # each image's A_icrs_to_cam
    return A_icrs_to_enu, A_cam_to_enu, A_true


def test_mounting_of_a_perfect_night_is_exact(night):
    A_icrs_to_enu, A_cam_to_enu, A_true = night
    est = mt.estimate_mounting(mt.camera_to_enu(A_true, A_icrs_to_enu))
    assert np.max(np.abs(est.A_cam_to_enu - A_cam_to_enu)) < 1e-12
    assert est.quaternion_xyzw == pytest.approx(quaternion_from_attitude(A_cam_to_enu), abs=1e-12)
    assert est.standard_error_arcsec < 1e-6 and est.n_images == 48
    assert np.max(np.abs(mt.truth_attitudes(est, A_icrs_to_enu) - A_true)) < 1e-12
    # the sky turned 120° while the mounting stood still
    assert math.degrees(math.acos((np.trace(A_true[-1] @ A_true[0].T) - 1) / 2)) > 100


def test_mounting_standard_error_of_a_noisy_night(night):
    A_icrs_to_enu, A_cam_to_enu, A_true = night
    rng = np.random.default_rng(11)
    sigma = 30.0  # arcsec per camera axis, each image's attitude error
    noise = Rotation.from_rotvec(rng.normal(size=(48, 3)) * sigma * ARCSEC).as_matrix()
    A_est = noise @ A_true  # A_est = R(δθ) A_true, δθ about the camera axes
    est = mt.estimate_mounting(mt.camera_to_enu(A_est, A_icrs_to_enu))
    # the average within its error bars of the truth, and those bars σ/√n
    miss = Rotation.from_matrix(est.A_cam_to_enu @ A_cam_to_enu.T).as_rotvec() / ARCSEC
    sd = np.sqrt(np.diag(est.covariance_arcsec2))
    assert np.all(np.abs(miss) < 4 * sd)
    assert np.sqrt(np.trace(est.covariance_arcsec2) / 3) == pytest.approx(sigma / math.sqrt(48), rel=0.25)
    # thesis 003's truth error: Euler-angle deviations' σ/√n, RMS of three; the Euler angles of
    # this mounting (x level: θ = 0) take the noise about one for one
    assert est.euler123_deg == pytest.approx(np.degrees(
        [math.atan2(-A_cam_to_enu[2, 1], A_cam_to_enu[2, 2]), 0.0,
         math.atan2(-A_cam_to_enu[1, 0], A_cam_to_enu[0, 0])]), abs=0.05)
    se = np.std(est.euler_deviations_arcsec, axis=0, ddof=1) / math.sqrt(48)
    assert est.euler_standard_error_arcsec == pytest.approx(se, rel=1e-12)
    assert est.standard_error_arcsec == pytest.approx(math.sqrt(np.mean(se**2)), rel=1e-12)
    assert 0.6 * sigma / math.sqrt(48) < est.standard_error_arcsec < 1.6 * sigma / math.sqrt(48)
    js = est.to_json()
    assert (js["from"], js["to"], js["n_images"]) == ("camera", "enu", 48)


def test_mounting_needs_two_images():
    with pytest.raises(InputError, match="two or more"):
        mt.estimate_mounting(matrix_from_euler123(0.1, 0.2, 0.3)[None])
