"""The small-matrix kernels a solve runs without BLAS or LAPACK (skyfix._kernels.rotation, issue 22):
the Wahba rotation by one-sided Jacobi against the truth and against LAPACK's SVD, the symmetric
3 × 3 eigen-decomposition against ``np.linalg.eigh``, the 3 × 3 product against ``@``."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skyfix._kernels.rotation import det3, matmul3, proper_rotation, symmetric_eigen3

ARCSEC = np.pi / (180 * 3600)


def _svd_rotation(B: np.ndarray) -> np.ndarray:
    """Markley's SVD solution, as LAPACK (numpy) gives it."""
    U, _, Vt = np.linalg.svd(B)
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U) * np.linalg.det(Vt))]) @ Vt


def _angle(A: np.ndarray, C: np.ndarray) -> float:
    """The rotation angle between two attitudes, radians (accurate at small angles)."""
    D = A @ C.T
    return float(np.linalg.norm([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]]) / 2)


def _profile(rng, fov_deg: float, n: int, A: np.ndarray, noise_rad: float = 0.0):
    """``B = Σ w b rᵀ`` of ``n`` stars in a field ``fov_deg`` across, seen through ``A``."""
    th = np.radians(fov_deg / 2) * np.sqrt(rng.random(n))
    ph = 2 * np.pi * rng.random(n)
    b = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=1)
    r = b @ A  # the same stars in ICRS
    b = b + noise_rad * rng.normal(size=b.shape)
    b /= np.linalg.norm(b, axis=1)[:, None]
    w = 0.1 + rng.random(n)
    return (b * w[:, None]).T @ r


@pytest.mark.parametrize("fov_deg", [0.5, 1.0, 8.0, 15.0, 60.0])
def test_the_wahba_rotation_is_the_truth_on_exact_stars(fov_deg):
    # Noise-free stars: the answer is the attitude itself. One-sided Jacobi gets within 1e-7″
    # (LAPACK's SVD within ~1e-4″ at 0.5°: its singular vectors of a narrow field's near-equal
    # small singular values are less accurate).
    rng = np.random.default_rng(int(fov_deg * 10))
    worst = 0.0
    for _ in range(100):
        A = Rotation.random(random_state=rng.integers(1 << 30)).as_matrix()
        B = _profile(rng, fov_deg, int(rng.integers(3, 40)), A)
        R = proper_rotation(B)
        assert abs(det3(R) - 1.0) < 1e-12
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-14)
        worst = max(worst, _angle(R, A))
    assert worst < 1e-7 * ARCSEC


@pytest.mark.parametrize("fov_deg", [1.0, 15.0, 90.0])
def test_the_wahba_rotation_is_lapacks_on_noisy_stars(fov_deg):
    rng = np.random.default_rng(7)
    for _ in range(100):
        A = Rotation.random(random_state=rng.integers(1 << 30)).as_matrix()
        B = _profile(rng, fov_deg, int(rng.integers(2, 40)), A, noise_rad=1e-5 * np.radians(fov_deg))
        assert _angle(proper_rotation(B), _svd_rotation(B)) < 1e-4 * ARCSEC


def test_the_wahba_rotation_of_a_general_matrix_and_of_a_mirror():
    rng = np.random.default_rng(3)
    for B in rng.normal(size=(500, 3, 3)):  # any matrix: the nearest proper rotation
        assert np.abs(proper_rotation(B) - _svd_rotation(B)).max() < 1e-12
    # a mirror image (det B < 0) still gives a proper rotation, as good a fit as LAPACK's
    B = np.diag([1.0, 0.5, -0.2]) @ Rotation.random(random_state=1).as_matrix()
    R = proper_rotation(B)
    assert abs(det3(R) - 1.0) < 1e-12
    assert np.trace(R.T @ B) == pytest.approx(np.trace(_svd_rotation(B).T @ B), abs=1e-14)


def test_a_degenerate_profile_goes_to_lapack():
    # rank one (one star): no unique answer; LAPACK's, as before the Jacobi rotations
    B = np.outer([0.0, 0.6, 0.8], [1.0, 0.0, 0.0])
    assert np.array_equal(proper_rotation(B), _svd_rotation(B))
    with pytest.raises(np.linalg.LinAlgError):
        proper_rotation(np.full((3, 3), np.nan))


def test_the_symmetric_eigen_decomposition_is_eighs():
    rng = np.random.default_rng(11)
    for k in range(500):
        Q = Rotation.random(random_state=k).as_matrix()
        ev = rng.normal(size=3) * 10.0 ** rng.uniform(-12, 0, 3)
        if k % 5 == 0:
            ev[1] = ev[0]  # a repeated eigenvalue
        S = Q @ np.diag(ev) @ Q.T
        S = 0.5 * (S + S.T)
        vals, vecs = symmetric_eigen3(S)
        ref = np.linalg.eigh(S)[0]
        scale = np.abs(ref).max()
        assert np.all(np.diff(vals) >= 0)
        assert np.abs(vals - ref).max() <= 1e-14 * scale
        assert np.abs(S @ vecs - vecs * vals).max() <= 1e-14 * scale
        assert np.abs(vecs.T @ vecs - np.eye(3)).max() <= 1e-14


def test_the_3x3_product_is_matmuls():
    X, Y = np.random.default_rng(5).normal(size=(2, 3, 3))
    assert np.abs(matmul3(X, Y) - X @ Y).max() <= 1e-15
