"""The attitude error predicted from centroid noise, star count and geometry — what a Monte
Carlo campaign's measured errors are compared with.

**Fisher (Cramér–Rao) prediction** (:func:`predicted_covariance_rad2`). Each star ``i`` is seen
at pixel ``p_i = π(R(δθ) A r_i)`` with isotropic Gaussian centroid noise ``σ`` px per axis;
``π`` is the camera model (its distortion included). With ``H_i = ∂p_i/∂δθ`` (2 × 3, taken by
central differences of :meth:`skyfix.camera.Camera.ray_to_pixel`), the information is
``F = Σ H_iᵀ H_i / σ²`` and the smallest attitude covariance any unbiased estimator reaches is
``P = F⁻¹`` — about the camera axes (x, y cross-boresight, z roll), the axes of
:func:`skyfix.attitude.attitude_covariance`. For a narrow pinhole field it is that function's
QUEST measurement model with ``σ_rad = σ·plate scale``; off axis the pixel Jacobian shrinks
radial errors by ``cos² θ`` and tangential ones by ``cos θ``, which the QUEST model ignores.

**Liebe's rules of thumb** (thesis 000 §2.9, after Liebe 2002): boresight
``σ_b = FOV · σ / (N_px · √N)`` and roll ``σ_r = atan(σ / (0.3825 · N_px)) / √N`` for ``N`` stars
and ``N_px`` pixels across the field (:func:`liebe_sigma_rad`) — per cross-boresight axis and in
roll; they assume stars spread evenly over a circular field.
"""

from __future__ import annotations

import math

import numpy as np

from skyfix.camera import Camera

__all__ = ["liebe_sigma_rad", "predicted_covariance_rad2"]

_STEP_RAD = 1e-6  # the central differences' rotation: ~0.2″, far inside the model's linear range


def predicted_covariance_rad2(camera: Camera, b_cam: np.ndarray, sigma_px: float) -> np.ndarray:
    """Cramér–Rao attitude covariance (3, 3), rad², of stars at camera-frame directions ``b_cam``
    (N, 3) centroided with noise ``sigma_px`` per axis (see the module text). NaN when fewer than
    two stars (the roll is then not observable)."""
    b = np.asarray(b_cam, dtype=np.float64)
    if len(b) < 2 or not sigma_px > 0:
        return np.full((3, 3), np.nan)
    x, y, z = b.T
    # e_k × b for the three axes (R(δθ) b ≈ b + δθ × b): one projection of 6N rays
    turned = np.zeros((3, len(b), 3))
    turned[0, :, 1], turned[0, :, 2] = -z, y
    turned[1, :, 0], turned[1, :, 2] = z, -x
    turned[2, :, 0], turned[2, :, 1] = -y, x
    turned *= _STEP_RAD
    pix, _ = camera.ray_to_pixel(np.concatenate([b + turned, b - turned]).reshape(-1, 3))
    pix = pix.reshape(2, 3, len(b), 2)
    H = (pix[0] - pix[1]) / (2.0 * _STEP_RAD)  # (axis, star, pixel axis)
    F = np.einsum("kni,lni->kl", H, H) / sigma_px**2
    if not np.all(np.isfinite(F)):
        return np.full((3, 3), np.nan)
    w = np.linalg.eigvalsh(F)  # F is symmetric: its condition number is its eigenvalues' ratio
    if not (w[0] > 0 and w[2] < 1e12 * w[0]):
        return np.full((3, 3), np.nan)
    P = np.linalg.inv(F)
    return 0.5 * (P + P.T)


def liebe_sigma_rad(fov_deg: float, pixels_across: int, sigma_px: float, n_stars: float
                    ) -> tuple[float, float]:
    """Liebe's (cross-boresight per axis, roll) 1σ errors, radians (see the module text)."""
    if not n_stars > 0:
        return math.nan, math.nan
    root = math.sqrt(n_stars)
    return (math.radians(fov_deg) * sigma_px / (pixels_across * root),
            math.atan(sigma_px / (0.3825 * pixels_across)) / root)
