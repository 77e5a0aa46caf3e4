"""The small-angle rate from centroid motion and the three-point extrapolators
(skyfix.track.rate), against synthetic stars projected with skyfix.camera.Camera at known
attitudes (skyfix.simulate.motion.attitude_at)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyfix.camera import Camera
from skyfix.errors import InputError, UnknownNameError
from skyfix.geometry import attitude_from_radec_roll
from skyfix.simulate.motion import attitude_at
from skyfix.track.rate import (
    extrapolation_weights,
    predict_positions,
    small_angle_rate,
    three_point,
    three_point_error,
)

DEG = math.pi / 180
ARCSEC = DEG / 3600
A0 = attitude_from_radec_roll(4.0, -0.7, 0.3)
CAMERA = Camera.from_fov(1280, 960, 15.0)
# A camera with distortion, an off-centre principal point and fx ≠ fy.
CAMERA_DISTORTED = Camera(width=1280, height=960, fx=4900.0, fy=4880.0, cx=655.0, cy=470.0,
                          k1=-0.08, k2=0.05, p1=1e-4)


def catalogue_like(camera, rng, n):
    """n random ICRS unit vectors of stars in the field at attitude A0."""
    xy = rng.uniform([20, 20], [camera.width - 20, camera.height - 20], size=(n, 2))
    return camera.pixel_to_ray(xy) @ A0


def frames(camera, omega, period, r_icrs):
    """Pixel positions of the stars at t = 0 and t = period."""
    A = attitude_at(A0, omega, np.array([0.0, period]))
    return [camera.ray_to_pixel(r_icrs @ Ak.T)[0] for Ak in A]


@pytest.mark.parametrize("camera", [CAMERA, CAMERA_DISTORTED], ids=["pinhole", "distorted"])
@pytest.mark.parametrize("period", [0.1, 0.01])
def test_small_angle_rate_recovers_a_known_rate(camera, period):
    """8 stars, 0.1 px centroid noise, (0.3, −0.4, 0.5) °/s: the rate is within 3σ per axis,
    and the rate scales with 1/period (the thesis's 'divide by the frame rate' would be off by
    period² = 10⁻² or 10⁻⁴)."""
    rng = np.random.default_rng(1)
    omega = np.array([0.3, -0.4, 0.5]) * DEG
    r = catalogue_like(camera, rng, 8)
    prev, cur = frames(camera, omega, period, r)
    noise = 0.1
    est = small_angle_rate(prev + rng.normal(scale=noise, size=prev.shape),
                           cur + rng.normal(scale=noise, size=cur.shape), camera, period, sigma_px=noise)
    sigma = np.sqrt(np.diag(est.covariance))
    assert np.all(np.abs(est.rate_rad_s - omega) <= 3 * sigma), (est.rate_rad_s - omega) / sigma
    assert est.n_stars == 8
    np.testing.assert_allclose(est.angles_rad, est.rate_rad_s * period)
    # Cross-boresight σ: ~0.1 px / f / √8 · √2 / period.
    expected = noise / camera.fx * math.sqrt(2 / 8) / period
    assert 0.5 * expected < sigma[:2].max() < 3 * expected


def test_small_angle_rate_noiseless_and_covariance_is_honest():
    """Without noise the first-order Jacobian (taken at the previous positions) leaves a relative
    error of the order of the angle turned, φ = 0.11° = 2e-3 rad here: 4e-4 of the rate;
    over 400 noisy trials the normalised errors have unit RMS per axis, with σ given or from
    the residuals."""
    rng = np.random.default_rng(2)
    omega = np.array([0.5, 0.2, -1.0]) * DEG
    period = 0.1
    r = catalogue_like(CAMERA, rng, 10)
    prev, cur = frames(CAMERA, omega, period, r)
    est = small_angle_rate(prev, cur, CAMERA, period, sigma_px=0.1)
    assert np.linalg.norm(est.rate_rad_s - omega) < 1e-3 * np.linalg.norm(omega)
    assert est.residual_rms_px < 0.01
    z_given, z_resid = [], []
    for _ in range(400):
        a = prev + rng.normal(scale=0.1, size=prev.shape)
        b = cur + rng.normal(scale=0.1, size=cur.shape)
        for sigma_px, out in ((0.1, z_given), (None, z_resid)):
            e = small_angle_rate(a, b, CAMERA, period, sigma_px=sigma_px)
            out.append((e.rate_rad_s - omega) / np.sqrt(np.diag(e.covariance)))
    rms_given = np.sqrt(np.mean(np.square(z_given), axis=0))
    rms_resid = np.sqrt(np.mean(np.square(z_resid), axis=0))
    assert np.all((0.85 < rms_given) & (rms_given < 1.15)), rms_given
    assert np.all((0.85 < rms_resid) & (rms_resid < 1.25)), rms_resid


def test_position_prediction():
    """J(k)·φ predicts the next frame's positions: to < 0.01 px at 1 °/s and 10 Hz."""
    rng = np.random.default_rng(3)
    omega = np.array([0.6, -0.5, 0.6]) * DEG
    r = catalogue_like(CAMERA_DISTORTED, rng, 10)
    A = attitude_at(A0, omega, np.array([0.0, 0.1]))
    xy0, xy1 = (CAMERA_DISTORTED.ray_to_pixel(r @ Ak.T)[0] for Ak in A)
    pred = predict_positions(xy0, CAMERA_DISTORTED, omega, 0.1)
    moved = np.hypot(*(xy1 - xy0).T)
    assert moved.min() > 3  # the stars move several pixels
    assert np.hypot(*(pred - xy1).T).max() < 0.05


def test_small_angle_rate_rejects_bad_input():
    xy = np.array([[100.0, 200.0], [300.0, 400.0], [500.0, 100.0]])
    with pytest.raises(InputError, match="at least 2"):
        small_angle_rate(xy[:1], xy[:1], CAMERA, 0.1)
    with pytest.raises(InputError, match="period"):
        small_angle_rate(xy, xy, CAMERA, 0.0)
    with pytest.raises(InputError, match="match"):
        small_angle_rate(xy, xy[:2], CAMERA, 0.1)
    bad = xy.copy()
    bad[1, 0] = np.nan
    with pytest.raises(InputError, match="finite"):
        small_angle_rate(xy, bad, CAMERA, 0.1)
    with pytest.raises(InputError, match="undetermined"):
        small_angle_rate(np.tile(xy[:1], (3, 1)), np.tile(xy[:1], (3, 1)), CAMERA, 0.1)


# --- three-point --------------------------------------------------------------------------------

def test_three_point_weights():
    assert three_point(9.0, 4.0, 1.0, "thesis") == -1.0  # x = t² at t = −3, −2, −1: truth 0
    assert three_point(9.0, 4.0, 1.0, "exact") == 0.0
    w, _ = extrapolation_weights([-3.0, -2.0, -1.0], 0.0, "thesis")
    np.testing.assert_array_equal(w, [0.5, -2.0, 2.5])
    w, _ = extrapolation_weights([-3.0, -2.0, -1.0], 0.0, "exact")
    np.testing.assert_array_equal(w, [1.0, -3.0, 3.0])
    with pytest.raises(UnknownNameError, match="unknown three-point weights"):
        three_point(1, 2, 3, "quadratic")


@pytest.mark.parametrize("weights", ["exact", "thesis"])
def test_three_point_error_analytic_equals_sampled(weights):
    """x(t) = x0 + v t + ½ a t² sampled every T: the prediction error of three_point equals
    three_point_error — 0 for the exact weights, −½ a T² for the thesis's."""
    x0, v, a, T = 0.7, -3.0, 5.0, 0.1
    t = np.array([-3.0, -2.0, -1.0, 0.0]) * T
    x = x0 + v * t + 0.5 * a * t**2
    err = three_point(x[0], x[1], x[2], weights) - x[3]
    assert err == pytest.approx(three_point_error(a, T, weights), abs=1e-14)
    assert three_point_error(a, T, weights) == (0.0 if weights == "exact" else -0.5 * a * T**2)


def test_extrapolation_weights_uneven_times_and_derivative():
    """At uneven sample times the exact weights reproduce a quadratic and its derivative at any
    target time; two samples extrapolate a line, one holds."""
    t = np.array([0.0, 0.13, 0.21])
    f = lambda s: 1.0 - 2.0 * s + 4.0 * s**2  # noqa: E731
    df = lambda s: -2.0 + 8.0 * s  # noqa: E731
    for target in (0.21, 0.3, 0.55):
        w, dw = extrapolation_weights(t, target, "exact")
        assert w @ f(t) == pytest.approx(f(target), abs=1e-12)
        assert dw @ f(t) == pytest.approx(df(target), abs=1e-11)
    w, dw = extrapolation_weights(t[1:], 0.3, "thesis")
    line = lambda s: 2.0 + 3.0 * s  # noqa: E731
    assert w @ line(t[1:]) == pytest.approx(line(0.3))
    assert dw @ line(t[1:]) == pytest.approx(3.0)
    w, dw = extrapolation_weights(t[2:], 0.3, "exact")
    assert list(w) == [1.0] and list(dw) == [0.0]
    with pytest.raises(InputError, match="increase"):
        extrapolation_weights([0.0, 0.0, 0.1], 0.2)
