"""The MEKF's consider states (skyfix.track.filter): a self-calibrated camera's numbers carried
with their covariance, never estimated (Schmidt–Kalman), so that an error every frame shares is
not averaged away."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyfix._kernels.rotation import rodrigues, rotation_vector
from skyfix.errors import InputError
from skyfix.track.filter import AttitudeFilter, consider_correct, interval_model, propagate_cross

ARCSEC = math.pi / (180 * 3600)


def _spd(rng, n, scale):
    L = rng.normal(size=(n, n))
    return scale * (L @ L.T + n * np.eye(n))


def test_consider_update_is_the_augmented_joseph_form():
    """One update against the textbook: the state [x (6), c (n)] with the gain's camera rows held
    at zero, Joseph's form on the augmented covariance (S, the gain, P, X, and C unchanged)."""
    rng = np.random.default_rng(3)
    n = 5
    aug = _spd(rng, 6 + n, 1e-10)
    P, X, C = aug[:6, :6].copy(), aug[:6, 6:].copy(), aug[6:, 6:].copy()
    G = rng.normal(size=(3, n)) * 0.3
    R = _spd(rng, 3, 1e-11)
    A_pred = rodrigues(np.array([0.3, -0.2, 0.9]))
    A_meas = rodrigues(np.array([2e-6, -1e-6, 3e-6])) @ A_pred
    out = consider_correct(A_pred, P, X, C, A_meas, R.copy(), G, math.inf)
    H = np.hstack([np.eye(3), np.zeros((3, 3)), G])
    S = H @ aug @ H.T + R
    K = np.zeros((6 + n, 3))
    K[:6] = (aug @ H.T)[:6] @ np.linalg.inv(S)
    IKH = np.eye(6 + n) - K @ H
    aug_new = IKH @ aug @ IKH.T + K @ R @ K.T
    z = rotation_vector(A_meas @ A_pred.T)
    assert out[6]  # corrected
    np.testing.assert_allclose(out[4], S, rtol=1e-12, atol=1e-30)
    np.testing.assert_allclose(out[5], z @ np.linalg.solve(S, z), rtol=1e-10)
    np.testing.assert_allclose(out[8], K[:6] @ z, rtol=1e-9, atol=1e-22)
    np.testing.assert_allclose(out[9], aug_new[:6, :6], rtol=1e-9, atol=1e-24)
    np.testing.assert_allclose(out[10], aug_new[:6, 6:], rtol=1e-9, atol=1e-24)
    np.testing.assert_allclose(aug_new[6:, 6:], C, rtol=1e-12)  # the camera is never updated
    np.testing.assert_allclose(out[7], rodrigues(K[:3] @ z) @ A_pred, atol=1e-15)
    # propagation: Φ X, Φ = [[R(−ω̂T), −M(T)], [0, I]] (the rate model)
    omega, dt = np.array([0.01, -0.02, 0.005]), 0.1
    m = interval_model(omega, dt)
    Phi = np.eye(6)
    Phi[:3, :3], Phi[:3, 3:] = m[0], -m[1]
    np.testing.assert_allclose(propagate_cross(omega, dt, X, -1.0), Phi @ X, rtol=1e-12, atol=1e-25)


def _run_filters(rng, trials: int, frames: int):
    """Many trials of one shared camera bias: each trial draws a camera error ``c`` once, every
    frame's star fit errs by ``G_k c + ν`` (``G_k`` turning slowly, as the stars move through the
    field), at rest. Returns the final normalised errors squared (NEES) of the consider filter and of
    a plain filter given ``G C Gᵀ`` as each frame's white noise."""
    n = 4
    C = np.diag([1.0, 0.5, 2.0, 0.3])
    G0 = rng.normal(size=(3, n)) * 0.5 * ARCSEC
    G1 = rng.normal(size=(3, n)) * 0.5 * ARCSEC
    R = np.diag([1.0, 1.0, 4.0]) * ARCSEC**2
    L = np.linalg.cholesky(R)
    nees = {"consider": [], "white": []}
    for _ in range(trials):
        c = rng.multivariate_normal(np.zeros(n), C)
        filters = {}
        for k in range(frames):
            G = G0 + (k / frames) * G1
            err = G @ c + L @ rng.normal(size=3)
            A_meas = rodrigues(err)  # the truth is the identity, at rest
            if k == 0:
                filters["consider"] = AttitudeFilter(A_meas, 0.0, R + G @ C @ G.T, rate_rad_s=np.zeros(3),
                                                     rate_sigma_rad_s=1e-6, accel_psd=1e-14,
                                                     camera_covariance=C, camera_cross_rad=G @ C)
                filters["white"] = AttitudeFilter(A_meas, 0.0, R + G @ C @ G.T, rate_rad_s=np.zeros(3),
                                                  rate_sigma_rad_s=1e-6, accel_psd=1e-14)
                continue
            t = 0.1 * k
            filters["consider"].update(t, A_meas, R, camera_sensitivity=G)
            filters["white"].update(t, A_meas, R + G @ C @ G.T)
        for name, f in filters.items():
            s = f.state
            e = rotation_vector(np.ascontiguousarray(s.A_icrs_to_cam))
            nees[name].append(e @ np.linalg.solve(s.covariance[:3, :3], e))
    return {k: float(np.mean(v)) for k, v in nees.items()}


def test_a_shared_camera_error_is_not_averaged_away():
    """400 trials of 20 frames: the consider filter's attitude error over its own covariance is
    χ²₃ (mean NEES within 3 ± 0.45, its 3σ over 400 trials); the filter that takes the camera's
    error as new noise each frame averages it down and is overconfident (measured: 2.70 and 15.5)."""
    nees = _run_filters(np.random.default_rng(11), 400, 20)
    print(f"\nmean NEES: consider {nees['consider']:.2f}, white {nees['white']:.2f}")
    assert abs(nees["consider"] - 3.0) < 0.45, nees
    assert nees["white"] > 6.0, nees


def test_consider_filter_needs_each_fits_sensitivity():
    C = np.eye(2)
    f = AttitudeFilter(np.eye(3), 0.0, np.eye(3) * 1e-10, camera_covariance=C)
    with pytest.raises(InputError, match=r"carries 2 camera numbers: a measurement needs its camera_sens"):
        f.update(0.1, np.eye(3), np.eye(3) * 1e-10)
    with pytest.raises(InputError, match=r"camera_sensitivity must be a finite \(3, 2\) array"):
        f.update(0.1, np.eye(3), np.eye(3) * 1e-10, camera_sensitivity=np.zeros((3, 3)))
    with pytest.raises(InputError, match="not by a compiled step"):
        f.step_inputs(0.1)
    with pytest.raises(InputError, match=r"camera_covariance must be a finite \(n, n\) covariance"):
        AttitudeFilter(np.eye(3), 0.0, np.eye(3) * 1e-10, camera_covariance=np.ones((2, 3)))
    assert f.state.covariance.shape == (6, 6) and f.camera_covariance.shape == (2, 2)
