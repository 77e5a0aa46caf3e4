"""Body rate from star motion between frames, and the three-point extrapolators.

**Small-angle rate (thesis 002 §2.4, after Kolomenkin et al.).** Between frames ``k−1`` and
``k`` the camera turns by the small angles ``φ = (Φ, θ, Ψ)`` about its x, y and z (boresight)
axes; a star at normalised image coordinates ``(u, v)`` (offsets from the principal point over
the focal length, both in pixels — the equations are homogeneous in ``(u, v, f)``) then moves by

    [Δu, Δv]ᵀ = J(u, v) φ,   J = [[u v,  −(1 + u²),  v],
                                  [1 + v², −u v,     −u]]          (thesis Eq. 2-22, f = 1)

with ``J`` taken at the previous positions. Stacking the stars matched by ID gives the
over-determined ``A φ = b`` (2n equations, 3 unknowns, n ≥ 2), solved by least squares. The
rate is the angle over the frame **period**, ``ω = φ / Δt`` (the thesis writes "divided by the
frame rate", which is dimensionally wrong; ``docs/tracking.md``). In skyfix's motion convention
(``skyfix.simulate.motion``: ``A(t) = R(−ω t) A(0)``, so a star moves as ``ḃ = −ω × b``) the
thesis's small-angle DCM ``I − [φ×]`` is exactly that motion, so ``φ = ω Δt`` with ``ω`` in the
camera frame — no sign change. The next positions follow as ``J(k) φ`` (:func:`predict_positions`,
thesis §2.4 step 5: the same angles over the next period, i.e. a constant rate).

Coordinates go through :meth:`skyfix.camera.Camera.pixel_to_normalized`, so lens distortion,
``fx ≠ fy`` and the principal point are the camera model's (the thesis's pixel offsets from the
detector centre are the distortion-free, square-pixel case).

**Three-point extrapolation (thesis 004 §4.9).** From the last three samples ``x(k−3), x(k−2),
x(k−1)`` the thesis predicts ``x(k) = 2.5 x(k−1) − 2 x(k−2) + 0.5 x(k−3)``: ``x + v T + ½ a T²``
with the backward differences ``v = x(k−1) − x(k−2)`` (the velocity half a period back) and
``a = x(k−1) − 2 x(k−2) + x(k−3)``. Under a constant acceleration ``ẍ`` it is biased by
``−½ ẍ T²`` (for ``x = t²``: −1 instead of 0); the quadratic through the three points,
``3 x(k−1) − 3 x(k−2) + x(k−3)``, is exact (:func:`three_point_error`). The exact weights amplify
the samples' noise more (``√19 ≈ 4.4`` vs ``√10.5 ≈ 3.2`` times one sample's σ) — the price of
having no bias.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._kernels.rotation import spd_inverse
from skyfix.errors import InputError, unknown_name

__all__ = [
    "RateEstimate",
    "THREE_POINT_KINDS",
    "extrapolation_weights",
    "predict_positions",
    "rate_jacobian",
    "small_angle_rate",
    "three_point",
    "three_point_error",
]


class RateEstimate(NamedTuple):
    """A body rate measured from star motion between two frames."""

    rate_rad_s: np.ndarray      # (3,) about camera x, y, z (docs/design.md#conventions)
    covariance: np.ndarray      # (3, 3) rad²/s²
    angles_rad: np.ndarray      # (3,) the rotation φ = (Φ, θ, Ψ) between the frames
    residual_rms_px: float      # RMS of the fit's residuals (pixels, both axes)
    n_stars: int


def rate_jacobian(uv: np.ndarray) -> np.ndarray:
    """Image-motion Jacobian ``J`` (N, 2, 3) of thesis 002 Eq. 2-22 at normalised coordinates
    ``uv`` (N, 2) (``f = 1``): ``[Δu, Δv] = J φ`` for a small rotation ``φ`` about camera x, y, z."""
    u, v = uv[:, 0], uv[:, 1]
    J = np.empty((len(uv), 2, 3))
    J[:, 0, 0] = u * v
    J[:, 0, 1] = -(1.0 + u * u)
    J[:, 0, 2] = v
    J[:, 1, 0] = 1.0 + v * v
    J[:, 1, 1] = -u * v
    J[:, 1, 2] = -u
    return J


def _points(xy: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(xy, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 2:
        raise InputError(f"{name} must be an (N, 2) array of pixel positions, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name} must be finite")
    return a


def small_angle_rate(xy_prev: np.ndarray, xy_cur: np.ndarray, camera, period_s: float, *,
                     sigma_px: float | None = None) -> RateEstimate:
    """Body rate from the motion of the same stars between two frames (thesis 002 Eq. 2-22…2-26).

    Parameters
    ----------
    xy_prev, xy_cur : (N, 2) pixel positions ``(x, y)`` of the same N ≥ 2 stars (row i of both
        is one star, e.g. matched by :func:`skyfix.track.relative.match_relative`'s IDs).
    camera : :class:`skyfix.camera.Camera` (principal point, focal lengths, distortion).
    period_s : time between the two frames, s (> 0).
    sigma_px : centroid σ per axis in each frame, px. Given, the covariance is
        ``2 σ² (AᵀA)⁻¹`` (a displacement is the difference of two centroids); otherwise it is
        scaled by the residuals, ``s² (AᵀA)⁻¹`` with ``s² = |r|² / (2N − 3)`` (N = 2 leaves one
        degree of freedom: a poor σ).

    Returns
    -------
    RateEstimate
        ``rate_rad_s = φ / period_s`` and its covariance (rad²/s²), the angles ``φ``, the
        residual RMS in pixels and the star count.

    Raises
    ------
    InputError
        Fewer than 2 stars, mismatched or non-finite positions, a period ≤ 0 or a geometry that
        does not determine the rate (all stars at one point).
    """
    prev = _points(xy_prev, "xy_prev")
    cur = _points(xy_cur, "xy_cur")
    if prev.shape != cur.shape:
        raise InputError(f"xy_prev and xy_cur must match, got {prev.shape} and {cur.shape}")
    if len(prev) < 2:
        raise InputError(f"the small-angle rate needs at least 2 stars, got {len(prev)}")
    if not (np.isfinite(period_s) and period_s > 0):
        raise InputError(f"frame period must be a positive time, got {period_s!r} s")
    n_prev, n_cur = np.split(camera.pixel_to_normalized(np.concatenate([prev, cur])), 2)
    # Rows in pixel units (x rows × fx, y rows × fy) so that residuals and σ are pixels.
    scale = np.array([camera.fx, camera.fy])
    A = (rate_jacobian(n_prev) * scale[None, :, None]).reshape(-1, 3)
    b = ((n_cur - n_prev) * scale).reshape(-1)
    N = A.T @ A
    N_inv, ok = spd_inverse(N)
    # ‖N‖_F ‖N⁻¹‖_F bounds the condition number from above: near-singular geometries go too.
    if not ok or np.linalg.norm(N) * np.linalg.norm(N_inv) > 1e12:
        raise InputError("the small-angle rate is undetermined by these star positions")
    phi = N_inv @ (A.T @ b)
    resid = b - A @ phi
    dof = len(b) - 3
    s2 = 2.0 * float(sigma_px) ** 2 if sigma_px is not None else float(resid @ resid) / dof
    cov = s2 * N_inv / period_s**2
    return RateEstimate(phi / period_s, 0.5 * (cov + cov.T), phi,
                        float(np.sqrt(np.mean(resid**2))), len(prev))


def predict_positions(xy: np.ndarray, camera, rate_rad_s: np.ndarray, dt_s: float) -> np.ndarray:
    """Pixel positions (N, 2) of stars now at ``xy`` (N, 2) after ``dt_s`` at a constant body
    rate: ``uv + J(uv)·ω Δt`` in normalised coordinates (thesis 002 §2.4 step 5–6, first order;
    the attitude predictors rotate exactly instead)."""
    cur = _points(xy, "xy")
    uv = camera.pixel_to_normalized(cur)
    uv_next = uv + rate_jacobian(uv) @ (np.asarray(rate_rad_s, dtype=np.float64) * float(dt_s))
    rays = np.column_stack([uv_next, np.ones(len(uv_next))])
    return camera.ray_to_pixel(rays)[0]


# --- three-point extrapolation -------------------------------------------------------------
THREE_POINT_KINDS = ("exact", "thesis")
"""``"exact"``: the quadratic through the three samples (weights 1, −3, 3 on ``x(k−3), x(k−2),
x(k−1)``); ``"thesis"``: thesis 004's ``x + v T + ½ a T²`` with backward differences
(0.5, −2, 2.5)."""


def extrapolation_weights(times_s: np.ndarray, t_s: float, kind: str = "exact"
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Weights ``w`` and ``ẇ`` so that ``Σ wᵢ xᵢ`` extrapolates samples ``xᵢ`` taken at
    ``times_s`` (1 to 3 times, newest last) to ``t_s`` and ``Σ ẇᵢ xᵢ`` is its time derivative.

    In Newton's form with the newest sample ``x₁`` at ``t₁``, ``Δ = t_s − t₁``, the backward
    difference ``v = (x₁ − x₂)/(t₁ − t₂)`` and the second divided difference ``f₁₂₃``:
    one sample holds (``x₁``), two extrapolate linearly (``x₁ + v Δ``, thesis 004's iteration 2),
    three give ``x₁ + v Δ + f₁₂₃ Δ (Δ + t₁ − t₂)`` (``"exact"``, the interpolating quadratic) or
    ``x₁ + v Δ + f₁₂₃ Δ²`` (``"thesis"``, ``½ a Δ²`` with ``a = 2 f₁₂₃``). Equal spacing ``T``
    and ``Δ = T`` give the weights (1, −3, 3) and (0.5, −2, 2.5), oldest first.
    """
    if kind not in THREE_POINT_KINDS:
        raise unknown_name("three-point weights", kind, THREE_POINT_KINDS)
    t = [float(x) for x in np.asarray(times_s, dtype=np.float64).reshape(-1)]
    k = len(t)
    target = float(t_s)
    if not 1 <= k <= 3 or not all(map(math.isfinite, t)) or not math.isfinite(target):
        raise InputError("extrapolation needs 1 to 3 finite sample times and a finite target time")
    if any(b <= a for a, b in zip(t, t[1:], strict=False)):
        raise InputError("extrapolation sample times must increase")
    # Plain floats: a few dozen operations, cheaper than as many numpy calls on 3-vectors.
    if k == 1:
        return np.ones(1), np.zeros(1)
    delta = target - t[-1]
    h12 = t[-1] - t[-2]
    v = [0.0] * (k - 2) + [-1.0 / h12, 1.0 / h12]
    w = [delta * x for x in v]
    w[-1] += 1.0
    dw = list(v)
    if k == 3:
        h23, h13 = t[-2] - t[-3], t[-1] - t[-3]
        f123 = (1.0 / (h23 * h13), -1.0 / (h12 * h13) - 1.0 / (h23 * h13), 1.0 / (h12 * h13))
        g, dg = ((delta * (delta + h12), 2.0 * delta + h12) if kind == "exact"
                 else (delta * delta, 2.0 * delta))
        w = [a + g * b for a, b in zip(w, f123, strict=True)]
        dw = [a + dg * b for a, b in zip(dw, f123, strict=True)]
    return np.array(w), np.array(dw)


def three_point(x_km3, x_km2, x_km1, weights: str = "exact"):
    """Extrapolate equally spaced samples ``x(k−3), x(k−2), x(k−1)`` (scalars or arrays) to
    ``x(k)``: ``"exact"`` ``3 x(k−1) − 3 x(k−2) + x(k−3)``, ``"thesis"``
    ``2.5 x(k−1) − 2 x(k−2) + 0.5 x(k−3)`` (thesis 004 Eq. 4.22; biased, :func:`three_point_error`)."""
    w, _ = extrapolation_weights(np.array([-3.0, -2.0, -1.0]), 0.0, weights)
    return (w[0] * np.asarray(x_km3, dtype=np.float64) + w[1] * np.asarray(x_km2, dtype=np.float64)
            + w[2] * np.asarray(x_km1, dtype=np.float64))


def three_point_error(accel: float, period_s: float, weights: str = "exact") -> float:
    """Prediction error (predicted − true) of :func:`three_point` for a constant acceleration
    ``accel`` (``ẍ``) sampled every ``period_s``: ``½ ẍ T² Σ wᵢ iᵢ²`` with ``iᵢ`` the samples'
    steps back (3, 2, 1) — the constant and linear parts cancel for both weight sets. It is
    ``0`` for ``"exact"`` and ``−½ ẍ T²`` for ``"thesis"`` (``−c T²`` for ``x = c t²``)."""
    w, _ = extrapolation_weights(np.array([-3.0, -2.0, -1.0]), 0.0, weights)
    return float(0.5 * accel * period_s**2 * (w @ np.array([9.0, 4.0, 1.0])))
