"""Wahba solvers, their covariance, residuals and the focal-length refinement."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skyfix import attitude as att
from skyfix.attitude import (
    METHODS,
    attitude_covariance,
    attitude_error,
    covariance_to_arcsec2,
    residuals_arcsec,
    rmse_arcsec,
    solve_attitude,
    svd_attitude,
)
from skyfix.errors import UnknownNameError
from skyfix.geometry import angle_between, attitude_from_radec_roll, normalize, rotation_angle_between

OPTIMAL = ["svd", "quest", "esoq2", "q-method"]  # all minimise the same Wahba loss


def _field(rng: np.random.Generator, A: np.ndarray, n: int, fov_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """n camera-frame unit vectors spread over a square field, and their ICRS vectors."""
    t = np.tan(np.radians(fov_deg) / 2)
    b = normalize(np.column_stack([rng.uniform(-t, t, (n, 2)), np.ones(n)]))
    return b, b @ A  # r = Aᵀ b


def _tangent_noise(rng: np.random.Generator, b: np.ndarray, sigma: float | np.ndarray) -> np.ndarray:
    """Perturb unit vectors by isotropic tangential errors of σ rad per axis (scalar or per star)."""
    helper = np.where(np.abs(b[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = normalize(np.cross(b, helper))
    e2 = np.cross(b, e1)
    d = rng.normal(0.0, 1.0, (len(b), 2)) * np.reshape(sigma, (-1, 1))
    return normalize(b + d[:, :1] * e1 + d[:, 1:] * e2)


@pytest.mark.parametrize("method", list(METHODS))
@pytest.mark.parametrize("fov_deg", [1.0, 15.0, 60.0])
def test_noiseless_matches_truth(method: str, fov_deg: float) -> None:
    rng = np.random.default_rng(7)
    worst = 0.0
    for A in Rotation.random(50, random_state=11).as_matrix():
        b, r = _field(rng, A, 8, fov_deg)
        worst = max(worst, rotation_angle_between(A, solve_attitude(b, r, method=method)))
    assert worst < 1e-9


@pytest.mark.parametrize("method", list(METHODS))
def test_solution_is_proper_rotation_in_design_convention(method: str) -> None:
    A = attitude_from_radec_roll(1.0, -0.3, 2.0)
    b, r = _field(np.random.default_rng(1), A, 5, 20.0)
    Ah = solve_attitude(b, r, method=method)
    assert np.allclose(Ah @ Ah.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(Ah) == pytest.approx(1.0, abs=1e-12)
    assert np.allclose(r @ Ah.T, b, atol=1e-10)  # b = A r


@pytest.mark.parametrize("method", ["quest", "esoq2", "q-method", "svd"])
@pytest.mark.parametrize("angle", [np.pi, np.pi - 1e-7, np.pi - 1e-3, 1e-9, 0.0])
def test_near_180_and_near_zero_rotations(method: str, angle: float) -> None:
    rng = np.random.default_rng(3)
    axes = [np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0])]
    axes += list(normalize(rng.normal(size=(5, 3))))
    for axis in axes:
        A = Rotation.from_rotvec(axis * angle).as_matrix()
        b, r = _field(rng, A, 6, 10.0)
        assert rotation_angle_between(A, solve_attitude(b, r, method=method)) < 1e-9


def test_quest_without_sequential_rotation_fails_at_180() -> None:
    # Pins why the frame flips exist: plain QUEST loses the attitude at a 180° rotation.
    rng = np.random.default_rng(0)
    A = Rotation.from_rotvec(normalize(rng.normal(size=3)) * np.pi).as_matrix()
    b, r = _field(rng, A, 6, 10.0)
    B = att._profile(b, r, np.full(6, 1 / 6))
    plain = att._matrix_from_shuster(att._quest_quaternion(B, att._lambda_max(B)))
    assert rotation_angle_between(A, plain) > 1e-3
    assert rotation_angle_between(A, solve_attitude(b, r, method="quest")) < 1e-9


def test_quest_newton_lambda_is_largest_eigenvalue() -> None:
    rng = np.random.default_rng(5)
    A = Rotation.random(random_state=5).as_matrix()
    b, r = _field(rng, A, 10, 20.0)
    b = _tangent_noise(rng, b, 1e-3)
    w = rng.uniform(0.5, 2.0, 10)
    B = att._profile(b, r, w / w.sum())
    assert att._lambda_max(B) == pytest.approx(np.linalg.eigvalsh(att._davenport_k(B))[-1], abs=1e-13)


def test_noisy_methods_agree_within_noise() -> None:
    rng = np.random.default_rng(42)
    sigma = np.radians(5.0 / 3600)  # 5″ per axis
    for A in Rotation.random(20, random_state=42).as_matrix():
        b, r = _field(rng, A, 12, 15.0)
        b = _tangent_noise(rng, b, sigma)
        w = rng.uniform(0.5, 2.0, len(b))
        sols = {m: solve_attitude(b, r, w, method=m) for m in METHODS}
        # The four optimal solvers minimise the same loss: identical to rounding.
        for m in OPTIMAL[1:]:
            assert rotation_angle_between(sols["svd"], sols[m]) < 1e-9
        # Each is within a few σ_roll of the truth; TRIAD (2 stars) within its own noise.
        P = attitude_covariance(sols["svd"], b, sigma, w / w.mean())
        assert rotation_angle_between(A, sols["svd"]) < 5 * np.sqrt(np.trace(P))
        sep = angle_between(b[np.argsort(-w)[0]], b[np.argsort(-w)[1]])
        assert rotation_angle_between(A, sols["triad"]) < 6 * sigma * (1 + 1 / sep)


def test_weights_matter_and_zero_weight_drops_a_star() -> None:
    rng = np.random.default_rng(9)
    A = Rotation.random(random_state=9).as_matrix()
    b, r = _field(rng, A, 6, 15.0)
    b_bad = b.copy()
    b_bad[0] = normalize(b[0] + [0.01, 0, 0])  # an outlier of ~34′
    w = np.array([0.0, 1, 1, 1, 1, 1])
    for m in OPTIMAL:
        assert rotation_angle_between(A, solve_attitude(b_bad, r, w, method=m)) < 1e-9
        assert rotation_angle_between(A, solve_attitude(b_bad, r, method=m)) > 1e-4


def test_triad_exactly_two_vectors_anchored_on_first() -> None:
    rng = np.random.default_rng(2)
    A = Rotation.random(random_state=2).as_matrix()
    b, r = _field(rng, A, 2, 15.0)
    assert rotation_angle_between(A, solve_attitude(b, r, method="triad")) < 1e-12
    b2 = b.copy()
    b2[1] = _tangent_noise(rng, b[1:2], 1e-3)[0]
    Ah = solve_attitude(b2, r, method="triad")
    assert np.allclose(Ah @ r[0], b2[0], atol=1e-14)  # the anchor is kept exactly
    # With weights, the heavier vector becomes the anchor.
    Aw = solve_attitude(b2, r, np.array([1.0, 3.0]), method="triad")
    assert np.allclose(Aw @ r[1], b2[1], atol=1e-14)


@pytest.mark.parametrize("method", list(METHODS))
def test_degenerate_input_raises_one_line(method: str) -> None:
    b1 = np.array([[0.0, 0.0, 1.0]])
    with pytest.raises(ValueError) as e:
        solve_attitude(b1, b1, method=method)
    assert "\n" not in str(e.value)
    col = normalize(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [0.0, 0.0, -1.0]]))
    with pytest.raises(ValueError, match="collinear") as e:
        solve_attitude(col, col, method=method)
    assert "\n" not in str(e.value)


def test_bad_arguments_raise() -> None:
    b, r = _field(np.random.default_rng(0), np.eye(3), 4, 10.0)
    with pytest.raises(UnknownNameError, match="unknown attitude method 'foam'; choose one of "):
        solve_attitude(b, r, method="foam")
    with pytest.raises(ValueError):
        solve_attitude(b, r[:3])
    with pytest.raises(ValueError):
        solve_attitude(b, r, weights=-np.ones(4))
    bad = b.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError):
        solve_attitude(bad, r)


def test_svd_attitude_keeps_its_signature() -> None:
    A = attitude_from_radec_roll(0.3, 0.2, 0.1)
    b, r = _field(np.random.default_rng(4), A, 5, 10.0)
    assert rotation_angle_between(A, svd_attitude(b, r, np.ones(5))) < 1e-12
    assert rotation_angle_between(A, svd_attitude(b, r)) < 1e-12


def test_covariance_matches_monte_carlo() -> None:
    rng = np.random.default_rng(2024)
    A = attitude_from_radec_roll(2.0, 0.5, 1.0)
    b, r = _field(rng, A, 10, 15.0)
    sigma = np.array([2.0, 2, 2, 2, 2, 4, 4, 4, 8, 8]) * 1e-5  # rad per axis, per star
    w = 1.0 / sigma**2
    errs = np.empty((2000, 3))
    for k in range(len(errs)):
        Ah = solve_attitude(_tangent_noise(rng, b, sigma), r, w, method="quest")
        errs[k] = attitude_error(A, Ah)  # A_est = R(δθ) A_true, camera frame
    P = attitude_covariance(A, b, sigma)
    C = np.cov(errs.T)
    assert np.allclose(np.diag(C) / np.diag(P), 1.0, atol=0.10)
    # Roll (z) is the weak axis for a narrow field, as the model says.
    assert P[2, 2] > 10 * max(P[0, 0], P[1, 1])
    # Correlations agree too (each off-diagonal within 0.1 of the predicted correlation).
    sd_p, sd_c = np.sqrt(np.diag(P)), np.sqrt(np.diag(C))
    assert np.allclose(C / np.outer(sd_c, sd_c), P / np.outer(sd_p, sd_p), atol=0.1)
    assert np.abs(errs.mean(axis=0) / sd_p).max() < 0.1  # unbiased


def test_covariance_units_frames_and_degenerate() -> None:
    b, _ = _field(np.random.default_rng(1), np.eye(3), 20, 10.0)
    P = attitude_covariance(np.eye(3), b, 1e-5)
    # Cross-boresight σ ≈ σ_star / sqrt(N) for stars near the boresight.
    assert np.sqrt(P[0, 0]) == pytest.approx(1e-5 / np.sqrt(20), rel=0.02)
    assert covariance_to_arcsec2(P)[0, 0] == pytest.approx(P[0, 0] * 206264.80624709636**2)
    A = attitude_from_radec_roll(1.0, 0.2, 0.3)
    assert np.allclose(attitude_covariance(A, b, 1e-5, frame="icrs"), A.T @ P @ A)
    # Weight w means σ² / w.
    assert np.allclose(attitude_covariance(A, b, 1e-5, np.full(20, 4.0)), P / 4)
    with pytest.raises(ValueError, match="unbounded"):
        attitude_covariance(A, np.array([[0.0, 0, 1], [0, 0, 1]]), 1e-5)


def test_residuals_and_rmse() -> None:
    A = attitude_from_radec_roll(0.5, 0.1, 0.0)
    b, r = _field(np.random.default_rng(3), A, 4, 10.0)
    assert np.all(residuals_arcsec(A, b, r) < 1e-6)
    b_off = b.copy()
    b_off[0] = Rotation.from_rotvec(normalize(np.cross(b[0], [1, 0, 0])) * np.radians(10 / 3600)).apply(b[0])
    res = residuals_arcsec(A, b_off, r)
    assert res[0] == pytest.approx(10.0, abs=1e-6)
    assert rmse_arcsec(A, b_off, r) == pytest.approx(10.0 / 2, abs=1e-6)  # sqrt(100 / 4)


def test_attitude_error_axes_and_quaternion_inverse() -> None:
    A = attitude_from_radec_roll(1.2, 0.4, 0.7)
    roll = np.radians(30 / 3600)
    A_est = Rotation.from_rotvec([0.0, 0.0, roll]).as_matrix() @ A  # pure roll about the boresight
    d = attitude_error(A, A_est)
    assert d == pytest.approx([0.0, 0.0, roll], abs=1e-15)
    assert np.allclose(A_est[2], A[2])  # boresight unchanged
    # Thesis 003 Eq. 7.15 corrected: the error quaternion needs the inverse of the truth.
    q_t = Rotation.from_matrix(A)
    q_e = Rotation.from_matrix(A_est)
    assert np.allclose((q_e * q_t.inv()).as_rotvec(), d, atol=1e-15)
    assert not np.allclose((q_e * q_t).as_rotvec(), d, atol=1e-3)  # the printed form
