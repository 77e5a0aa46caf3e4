"""The tracking filter (skyfix.track.filter) and the predictors (skyfix.track.predictors) against
simulated attitude sequences with known truth (skyfix.simulate.motion.attitude_at) and
measurements noised with a known covariance.

- The exact discretisation (Φ, Q) equals Van Loan's matrix exponential of the continuous model,
  on both sides of the series switch.
- Constant rate: the rate converges to the truth within 3σ; the attitude NEES over 600 frames has
  a mean inside the χ² band (honest error bars); the NIS too.
- Accelerating slew: with the default acceleration density the filter stays consistent.
- Gyro mode recovers a constant gyro bias.
- Three-point predictors: under a constant angular acceleration the thesis weights miss by
  ½ α T² about the rotation axis, the exact weights by nothing.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.stats import chi2

from skyfix._kernels.rotation import rodrigues, rotation_vector
from skyfix.attitude import attitude_error
from skyfix.camera import Camera
from skyfix.errors import InputError, UnknownNameError
from skyfix.geometry import attitude_from_radec_roll
from skyfix.simulate.motion import attitude_at
from skyfix.track.filter import NIS_GATE, AttitudeFilter, interval_model
from skyfix.track.predictors import PREDICTORS, Prediction, make_predictor

ARCSEC = math.pi / 180 / 3600
DEG = math.pi / 180
A0 = attitude_from_radec_roll(1.1, 0.4, 2.0)
# A realistic star-fit covariance: 2" across the boresight, 30" in roll, a little correlation.
R_MEAS = np.array([[4.0, 0.5, 3.0], [0.5, 4.4, -2.0], [3.0, -2.0, 900.0]]) * ARCSEC**2
L_MEAS = np.linalg.cholesky(R_MEAS)


def skew(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def van_loan(omega, dt, gyro, q_rate, q_att=0.0):
    """Φ and Q of the continuous error model by Van Loan's method (scipy's expm)."""
    F = np.zeros((6, 6))
    F[:3, :3] = -skew(omega)
    F[:3, 3:] = np.eye(3) if gyro else -np.eye(3)
    GQG = np.zeros((6, 6))
    GQG[:3, :3] = q_att * np.eye(3)
    GQG[3:, 3:] = q_rate * np.eye(3)
    C = np.zeros((12, 12))
    C[:6, :6] = -F
    C[:6, 6:] = GQG
    C[6:, 6:] = F.T
    E = expm(C * dt)
    Phi = E[6:, 6:].T
    return Phi, Phi @ E[:6, 6:]


@pytest.mark.parametrize("gyro", [False, True])
@pytest.mark.parametrize("omega", [(0.0, 0.0, 0.0), (1e-7, -2e-7, 3e-7), (0.3, -0.2, 0.5),
                                   (2.9, 0.0, 0.4), (3.1, 0.0, 0.4), (20.0, -10.0, 5.0)])
def test_propagation_is_van_loans_exact_discretisation(omega, gyro):
    """P ← Φ P Φᵀ + Q equals the matrix exponential of the continuous model, at |ω| T from 0 to
    2.3 rad, on both sides of the series switch at 0.3 (|ω| T = 0.293 and 0.313)."""
    omega = np.array(omega)
    dt = 0.1
    rng = np.random.default_rng(3)
    X = rng.normal(size=(6, 6))
    P0 = X @ X.T * 1e-6 + np.eye(6) * 1e-8
    q_rate, q_att = (1e-9, 1e-8) if gyro else (1e-5, 0.0)
    f = AttitudeFilter(A0, 0.0, P0[:3, :3], gyro=gyro, rate_rad_s=omega, accel_psd=q_rate,
                       bias_walk=math.sqrt(q_rate), gyro_noise=math.sqrt(q_att))
    f._P = P0.copy()  # a full covariance with cross terms, to exercise every block of Φ
    # In gyro mode ω̂ = g − β̂ with β̂ = 0.
    state = f.predict(dt, omega if gyro else None)
    Phi, Q = van_loan(omega, dt, gyro, q_rate, q_att)
    expected = Phi @ P0 @ Phi.T + Q
    np.testing.assert_allclose(state.covariance, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())
    np.testing.assert_allclose(state.A_icrs_to_cam, rodrigues(-omega * dt) @ A0, atol=1e-14)


def test_interval_model_continuous_across_the_series_switch():
    axis = np.array([0.6, -0.64, 0.48])
    below = interval_model(axis * (0.3 - 1e-9) / 0.1, 0.1)
    above = interval_model(axis * (0.3 + 1e-9) / 0.1, 0.1)
    np.testing.assert_allclose(below, above, rtol=1e-7, atol=1e-14)


def noisy(A_true, rng):
    return rodrigues(L_MEAS @ rng.normal(size=3)) @ A_true


def nees(A_true, state):
    e = attitude_error(A_true, state.A_icrs_to_cam)
    return float(e @ np.linalg.solve(state.covariance[:3, :3], e))


def chi2_band(dof, n, p=0.999):
    """Two-sided band of the mean of n independent χ²(dof) values."""
    lo, hi = chi2.ppf([(1 - p) / 2, (1 + p) / 2], dof * n)
    return lo / n, hi / n


def run_filter(truth, rate_truth, times, rng, **options):
    f = AttitudeFilter(noisy(truth[0], rng), times[0], R_MEAS, **options)
    nees_att, nis, rate_err = [], [], []
    for A, w, t in zip(truth[1:], rate_truth[1:], times[1:], strict=True):
        meas = noisy(A, rng)
        nis.append(f.innovation_nis(t, meas, R_MEAS))
        s = f.update(t, meas, R_MEAS)
        nees_att.append(nees(A, s))
        rate_err.append((s.rate_rad_s - w) / np.sqrt(np.diag(s.covariance)[3:]))
    return f, np.array(nees_att), np.array(nis), np.array(rate_err)


def test_constant_rate_converges():
    """600 frames at 10 Hz, ω = (0.3, −0.5, 1.0) °/s, a filter tuned for it (accel_psd ≈ 0): the
    rate is within 3σ of the truth at the end, σ 0.015"/s across the boresight and 0.05"/s in
    roll; the NIS (white for a consistent filter, so 600 independent values) has its mean in the
    χ² band."""
    rng = np.random.default_rng(11)
    omega = np.array([0.3, -0.5, 1.0]) * DEG
    times = np.arange(601) * 0.1
    truth = attitude_at(A0, omega, times)
    f, ne, nis, rerr = run_filter(truth, np.tile(omega, (len(times), 1)), times, rng, accel_psd=1e-16)
    s = f.state
    sigma_rate = np.sqrt(np.diag(s.covariance)[3:])
    assert np.all(np.abs(s.rate_rad_s - omega) <= 3 * sigma_rate)
    assert sigma_rate[:2].max() < 0.03 * ARCSEC and sigma_rate[2] < 0.1 * ARCSEC
    lo, hi = chi2_band(3, len(nis))
    assert lo < nis.mean() < hi, nis.mean()


def test_nees_monte_carlo():
    """The attitude NEES over 500 independent runs (20 frames at 10 Hz, constant rate): its mean
    at frames 1, 5 and 20 is in the two-sided 0.999 band of χ²(3·500)/500.

    Why runs and not one long run: a smoothing filter's errors are correlated from frame to frame,
    so the time average of one run scatters far more than independent values would (one 600-frame
    run at accel_psd ≈ 0 gives 1.3 to 5.5 depending on the seed); values from independent runs
    at one frame are independent (Bar-Shalom's Monte Carlo NEES test)."""
    rng = np.random.default_rng(12)
    omega = np.array([0.3, -0.5, 1.0]) * DEG
    times = np.arange(21) * 0.1
    truth = attitude_at(A0, omega, times)
    rates = np.tile(omega, (len(times), 1))
    ne = np.array([run_filter(truth, rates, times, rng, accel_psd=1e-16)[1] for _ in range(500)])
    lo, hi = chi2_band(3, 500)
    for frame in (1, 5, 20):
        assert lo < ne[:, frame - 1].mean() < hi, (frame, ne[:, frame - 1].mean())


def slew_angle(t, alpha, t_ramp, t_coast):
    """Angle (rad) and rate (rad/s) of a slew from rest: accelerate at alpha for t_ramp, coast
    for t_coast, decelerate at alpha to rest."""
    t = np.asarray(t, dtype=np.float64)
    w_max = alpha * t_ramp
    a1 = 0.5 * alpha * t_ramp**2
    t2 = t_ramp + t_coast
    t_end = t2 + t_ramp
    tc = np.clip(t, 0.0, t_end)
    angle = np.where(tc < t_ramp, 0.5 * alpha * tc**2,
                     np.where(tc < t2, a1 + w_max * (tc - t_ramp),
                              a1 + w_max * t_coast + w_max * (tc - t2) - 0.5 * alpha * (tc - t2) ** 2))
    rate = np.where(tc < t_ramp, alpha * tc, np.where(tc < t2, w_max, w_max - alpha * (tc - t2)))
    return angle, np.where(t > t_end, 0.0, rate)


def test_accelerating_slew_stays_consistent():
    """A slew about a fixed axis (1 °/s² for 10 s, 10 s at 10 °/s, 1 °/s² down to rest; 600
    frames at 20 Hz) with the default acceleration density: the attitude NEES mean is in the χ²
    band (the fits dominate, so successive errors are nearly independent), the NIS is not above it
    (the default is conservative for 1 °/s²: ~1.0 instead of 3) and the rate stays within 4.5σ."""
    rng = np.random.default_rng(5)
    axis = np.array([0.48, -0.6, 0.64])
    times = np.arange(601) * 0.05
    angle, rate = slew_angle(times, 1.0 * DEG, 10.0, 10.0)
    # attitude_at with a unit rate about the axis and "time" = the angle turned.
    truth = attitude_at(A0, axis, angle)
    rate_truth = rate[:, None] * axis
    f, ne, nis, rerr = run_filter(truth, rate_truth, times, rng)
    lo, hi = chi2_band(3, len(ne))
    assert lo < ne.mean() < hi, ne.mean()
    assert 0.5 < nis.mean() < hi, nis.mean()
    assert np.abs(rerr[5:]).max() < 4.5  # 600 × 3 normal values: 4.5σ is ~1 % to be exceeded


def test_gyro_mode_recovers_a_constant_bias():
    """Gyro at 10 Hz with angle random walk 1e-4 rad/√s and a bias of (0.1, −0.05, 0.15) °/s;
    the bias is found within 3σ, to better than 0.005 °/s, in 60 s."""
    rng = np.random.default_rng(2)
    omega = np.array([0.4, 0.1, -0.7]) * DEG
    bias = np.array([0.1, -0.05, 0.15]) * DEG
    T, arw = 0.1, 1e-4
    times = np.arange(601) * T
    truth = attitude_at(A0, omega, times)
    f = AttitudeFilter(noisy(truth[0], rng), 0.0, R_MEAS, gyro=True, gyro_noise=arw, bias_walk=1e-7)
    ne = []
    for A, t in zip(truth[1:], times[1:], strict=True):
        g = omega + bias + rng.normal(size=3) * arw / math.sqrt(T)  # the mean rate over the interval
        s = f.update(t, noisy(A, rng), R_MEAS, gyro_rate_rad_s=g)
        ne.append(nees(A, s))
    sigma = np.sqrt(np.diag(s.covariance)[3:])
    assert np.all(np.abs(s.gyro_bias_rad_s - bias) <= 3 * sigma)
    assert np.abs(s.gyro_bias_rad_s - bias).max() < 0.005 * DEG
    # The rate is the last gyro sample less the bias: off by that sample's noise.
    assert np.abs(s.rate_rad_s - omega).max() < 4 * arw / math.sqrt(T)
    lo, hi = chi2_band(3, len(ne))
    assert lo < np.mean(ne) < hi


def test_nis_flags_a_jump():
    rng = np.random.default_rng(4)
    omega = np.array([0.0, 0.5, 0.0]) * DEG
    f = AttitudeFilter(noisy(A0, rng), 0.0, R_MEAS)
    for k in range(1, 6):
        f.update(0.1 * k, noisy(attitude_at(A0, omega, 0.1 * k), rng), R_MEAS)
    good = noisy(attitude_at(A0, omega, 0.6), rng)
    jumped = rodrigues(np.array([0.0, 0.0, 90 * DEG])) @ good
    assert f.innovation_nis(0.6, good, R_MEAS) < NIS_GATE
    assert f.innovation_nis(0.6, jumped, R_MEAS) > 1e6


def test_update_gated_is_the_innovation_then_the_update():
    """``update_gated`` (the tracker's one call) commits exactly what ``innovation`` then
    ``update`` would, and a fit beyond the gate leaves the filter as it was; bad input raises as
    ``update`` does. Every predictor's ``update_gated`` gates the same way."""
    rng = np.random.default_rng(5)
    omega = np.array([0.3, -0.4, 0.1]) * DEG
    fits = [noisy(attitude_at(A0, omega, 0.1 * k), rng) for k in range(7)]
    a, b = AttitudeFilter(fits[0], 0.0, R_MEAS), AttitudeFilter(fits[0], 0.0, R_MEAS)
    for k in range(1, 6):
        nis = a.innovation(0.1 * k, fits[k], R_MEAS).nis
        sa = a.update(0.1 * k, fits[k], R_MEAS)
        done, inn = b.update_gated(0.1 * k, fits[k], R_MEAS, NIS_GATE)
        sb = b.state
        assert done and inn.nis == nis and sb.t_s == sa.t_s
        for x, y in zip(sa[1:], sb[1:], strict=True):
            assert (x is None and y is None) or np.array_equal(x, y)
        A, P_att, rate, P_rate = b.prediction(0.1 * k)
        assert np.array_equal(A, sb.A_icrs_to_cam) and np.array_equal(P_att, sb.covariance[:3, :3])
        assert np.array_equal(rate, sb.rate_rad_s) and np.array_equal(P_rate, sb.covariance[3:, 3:])
    before = b.state
    jumped = rodrigues(np.array([0.0, 300 * ARCSEC, 0.0])) @ fits[6]
    done, inn = b.update_gated(0.6, jumped, R_MEAS, NIS_GATE)
    assert not done and inn.nis > NIS_GATE
    assert inn.nis == pytest.approx(b.innovation(0.6, jumped, R_MEAS).nis, rel=1e-12)
    assert np.array_equal(b.state.covariance, before.covariance) and b.state.t_s == before.t_s
    with pytest.raises(InputError, match="rotation"):
        b.update_gated(0.6, 2 * fits[6], R_MEAS, NIS_GATE)
    with pytest.raises(InputError, match="positive definite"):
        b.update_gated(0.6, fits[6], -R_MEAS, NIS_GATE)
    with pytest.raises(InputError, match="3x3"):
        b.update_gated(0.6, fits[6], np.eye(2), NIS_GATE)
    with pytest.raises(InputError, match="increase"):
        b.update_gated(0.5, fits[6], R_MEAS, NIS_GATE)
    for name in sorted(PREDICTORS):
        p = make_predictor(name, fits[0], 0.0, R_MEAS)
        for k in range(1, 4):
            post, _ = p.update_gated(0.1 * k, fits[k], R_MEAS, NIS_GATE)
            assert isinstance(post, Prediction), name
        post, inn = p.update_gated(0.4, rodrigues(np.array([0.0, 0.0, 0.2])) @ fits[4], R_MEAS, NIS_GATE)
        assert post is None and inn.nis > NIS_GATE, name


def test_filter_rejects_bad_input():
    f = AttitudeFilter(A0, 1.0, R_MEAS)
    for t in (1.0, 0.5, float("nan"), float("inf")):
        with pytest.raises(InputError):
            f.update(t, A0, R_MEAS)
    bad_A = A0.copy()
    bad_A[0, 0] = np.nan
    with pytest.raises(InputError, match="finite"):
        f.update(1.1, bad_A, R_MEAS)
    with pytest.raises(InputError, match="rotation"):
        f.update(1.1, 2 * A0, R_MEAS)
    with pytest.raises(InputError, match="rotation"):
        f.update(1.1, -A0, R_MEAS)  # improper
    with pytest.raises(InputError, match="positive definite"):
        f.update(1.1, A0, -R_MEAS)
    with pytest.raises(InputError, match="finite"):
        f.update(1.1, A0, R_MEAS * np.nan)
    with pytest.raises(InputError, match="gyro"):
        f.update(1.1, A0, R_MEAS, gyro_rate_rad_s=np.zeros(3))
    with pytest.raises(InputError):
        f.predict(0.9)
    g = AttitudeFilter(A0, 0.0, R_MEAS, gyro=True)
    with pytest.raises(InputError, match="finite"):
        g.update(0.1, A0, R_MEAS, gyro_rate_rad_s=[0.0, np.nan, 0.0])
    with pytest.raises(InputError):
        AttitudeFilter(A0, float("nan"), R_MEAS)
    with pytest.raises(InputError):
        AttitudeFilter(A0, 0.0, R_MEAS, accel_psd=-1.0)
    assert f.state.t_s == 1.0  # nothing was committed


def test_rotation_vector_inverts_rodrigues():
    rng = np.random.default_rng(0)
    for v in [np.zeros(3), np.array([1e-9, 0, 0]), np.array([0.0, 0.0, math.pi - 1e-6]),
              *rng.normal(size=(20, 3))]:
        v = v * min(1.0, (math.pi - 1e-6) / max(np.linalg.norm(v), 1e-300))
        np.testing.assert_allclose(rotation_vector(rodrigues(v)), v, atol=1e-12)


# --- predictors -------------------------------------------------------------------------------

def test_registry_and_bad_names():
    assert set(PREDICTORS) == {"mekf", "small-angle", "three-point", "three-point-thesis"}
    with pytest.raises(UnknownNameError, match="unknown predictor"):
        make_predictor("kalman", A0, 0.0, R_MEAS)
    with pytest.raises(InputError, match="bad option"):
        make_predictor("three-point", A0, 0.0, R_MEAS, accel_psd=1.0)


@pytest.mark.parametrize("kind, bias_factor", [("three-point", 0.0), ("three-point-thesis", 0.5)])
def test_three_point_bias_under_constant_acceleration(kind, bias_factor):
    """Noiseless attitudes turning at α = 2 °/s² about a fixed axis, T = 0.1 s: the exact
    weights predict the next attitude to rounding; the thesis's miss by ½ α T² = 36" along the
    axis (the sign: they lag)."""
    axis = np.array([0.0, 0.6, 0.8])
    alpha, w0, T = 2.0 * DEG, 0.3 * DEG, 0.1
    angle = lambda t: w0 * t + 0.5 * alpha * t**2  # noqa: E731
    p = make_predictor(kind, attitude_at(A0, axis, angle(0.0)), 0.0, R_MEAS)
    for k in (1, 2):
        p.update(k * T, attitude_at(A0, axis, angle(k * T)), R_MEAS)
    pred = p.predict(3 * T)
    err = attitude_error(attitude_at(A0, axis, angle(3 * T)), pred.A_icrs_to_cam)
    np.testing.assert_allclose(err, bias_factor * alpha * T**2 * axis, atol=1e-12)
    assert isinstance(pred, Prediction)
    # The covariance carried through the weights: Σ w² C (19 C exact, 10.5 C thesis).
    np.testing.assert_allclose(pred.attitude_cov_rad2, (19.0 if bias_factor == 0 else 10.5) * R_MEAS,
                               rtol=1e-12)


@pytest.mark.parametrize("name", sorted(PREDICTORS))
def test_predictors_follow_a_constant_rate(name):
    """Each predictor, fed noisy fits at 10 Hz and 1 °/s, predicts the next frame within 4σ of
    its own covariance, and its rate within 4σ."""
    rng = np.random.default_rng(7)
    omega = np.array([0.2, -0.6, 0.8]) * DEG
    camera = Camera.from_fov(1280, 960, 15.0)
    r_icrs = star_field(camera, rng)
    times = np.arange(31) * 0.1
    truth = attitude_at(A0, omega, times)
    ids = np.arange(len(r_icrs))

    def frame(A):
        xy = camera.ray_to_pixel(r_icrs @ A.T)[0]
        return xy + rng.normal(scale=0.1, size=xy.shape)

    options = dict(sigma_px=0.1, xy=frame(truth[0]), ids=ids) if name == "small-angle" else {}
    p = make_predictor(name, noisy(truth[0], rng), 0.0, R_MEAS, rate_sigma_rad_s=0.05, **options)
    for A, t in zip(truth[1:-1], times[1:-1], strict=True):
        p.update(t, noisy(A, rng), R_MEAS, xy=frame(A), ids=ids, camera=camera)
    pred = p.predict(times[-1])
    e = attitude_error(truth[-1], pred.A_icrs_to_cam)
    assert e @ np.linalg.solve(pred.attitude_cov_rad2, e) < 4.0**2 * 3
    de = pred.rate_rad_s - omega
    assert de @ np.linalg.solve(pred.rate_cov_rad2_s2, de) < 4.0**2 * 3
    assert p.innovation_nis(times[-1], noisy(truth[-1], rng), R_MEAS) < NIS_GATE
    with pytest.raises(InputError):
        p.update(times[-3], truth[-1], R_MEAS)


def star_field(camera, rng, n=12):
    """Catalogue-like ICRS unit vectors of n stars inside the field at attitude A0."""
    xy = rng.uniform([50, 50], [camera.width - 50, camera.height - 50], size=(n, 2))
    return camera.pixel_to_ray(xy) @ A0


def test_mekf_predictor_with_gyro_tracks():
    """Started with gyro=True, the MEKF predictor propagates with the gyro rates: one frame ahead
    the error is within its σ (~7" across the boresight, set by the default angle random walk)."""
    rng = np.random.default_rng(8)
    omega = np.array([0.0, 1.0, 0.3]) * DEG
    p = make_predictor("mekf", noisy(A0, rng), 0.0, R_MEAS, gyro=True)
    for k in range(1, 20):
        A = attitude_at(A0, omega, 0.1 * k)
        p.update(0.1 * k, noisy(A, rng), R_MEAS, gyro_rate_rad_s=omega)
    pred = p.predict(2.0, omega)
    e = attitude_error(attitude_at(A0, omega, 2.0), pred.A_icrs_to_cam)
    assert e @ np.linalg.solve(pred.attitude_cov_rad2, e) < 4.0**2 * 3
    assert np.linalg.norm(e[:2]) < 10 * ARCSEC
    np.testing.assert_allclose(pred.rate_rad_s, omega, atol=0.01 * DEG)
