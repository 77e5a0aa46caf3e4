"""The reported covariance of a sparse field is honest: errors divided by it have RMS 1.

Each trial: M unit vectors in a 40° field, observed with isotropic tangential noise σ, the
attitude solved (SVD), σ estimated from the residuals (ν = 2M − 3), the covariance scaled to
it, then :func:`skyfix.identify.accept.error_covariance`. Unscaled, four stars' normalised
errors have RMS √(5/3) = 1.29 — Student's t with ν = 5 — which is what the campaigns saw.
"""

import math

import numpy as np
import pytest

from skyfix.attitude import attitude_covariance, attitude_error, solve_attitude
from skyfix.geometry import attitude_from_radec_roll
from skyfix.identify.accept import MIN_VARIANCE_DOF, error_covariance


def _normalised_errors(n_stars: int, trials: int, seed: int, scaled: bool) -> np.ndarray:
    rng = np.random.default_rng(seed)
    sigma = 1e-4
    out = []
    for _ in range(trials):
        A = attitude_from_radec_roll(*rng.uniform(0.0, 2 * math.pi, 3))
        theta = np.radians(20.0) * np.sqrt(rng.uniform(0, 1, n_stars))
        phi = rng.uniform(0, 2 * math.pi, n_stars)
        b_true = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
        r = b_true @ A  # catalogue directions: b_true = A r
        # isotropic tangential noise on each observed ray
        e1 = np.cross(b_true, [0.0, 0.0, 1.0])
        e1 /= np.linalg.norm(e1, axis=1)[:, None]
        e2 = np.cross(b_true, e1)
        noise = sigma * (rng.standard_normal((n_stars, 1)) * e1 + rng.standard_normal((n_stars, 1)) * e2)
        b = b_true + noise
        b /= np.linalg.norm(b, axis=1)[:, None]
        A_est = solve_attitude(b, r)
        resid = np.arccos(np.clip(np.sum(b * (r @ A_est.T), axis=1), -1, 1))
        dof = 2 * n_stars - 3
        s = math.sqrt(float(resid @ resid) / dof)
        cov = attitude_covariance(A_est, b, s)
        if scaled:
            cov = error_covariance(cov, dof)
        err = attitude_error(A, A_est)
        out.append(err / np.sqrt(np.diag(cov)))
    return np.asarray(out)


@pytest.mark.parametrize("n_stars", [4, 6])
def test_sparse_field_normalised_rms_is_one(n_stars):
    z = _normalised_errors(n_stars, 3000, seed=n_stars, scaled=True)
    rms = np.sqrt(np.mean(z**2, axis=0))
    assert np.all(np.abs(rms - 1.0) < 0.08), rms


def test_unscaled_covariance_is_too_small_by_students_variance():
    z = _normalised_errors(4, 3000, seed=4, scaled=False)
    rms = np.sqrt(np.mean(z**2, axis=0))
    assert np.all(np.abs(rms - math.sqrt(5 / 3)) < 0.1), rms


def test_error_covariance_factors():
    c = np.eye(3)
    assert error_covariance(c, 5.0)[0, 0] == pytest.approx(5 / 3)
    assert error_covariance(c, 1.0)[0, 0] == pytest.approx(MIN_VARIANCE_DOF / (MIN_VARIANCE_DOF - 2))
    assert error_covariance(c, math.inf)[0, 0] == 1.0
    assert error_covariance(c, math.nan)[0, 0] == 1.0
