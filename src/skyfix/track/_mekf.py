"""The MEKF's compiled kernels (:mod:`skyfix.track.filter` is their readable API and exports the
public ones): the propagation over an interval, the innovation and the gated correction, the
gyro rate's correction, and the camera's consider states (Schmidt–Kalman: the cross-covariance's
propagation and the consider update). The fused tracking step (:mod:`skyfix.track.step`) calls
the same kernels.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.rotation import rodrigues, rotation_vector, spd_inverse

_SERIES_BELOW = 0.3  # θ below which c₃, c₄, c₅ come from their series

# Error codes of the checking kernels (skyfix.track.filter turns them into one-line messages).
_OK, _NOT_FINITE, _NOT_ROTATION, _NOT_SPD = 0, 1, 2, 3


class FilterState(NamedTuple):
    """The filter's estimate at one time."""

    t_s: float
    A_icrs_to_cam: np.ndarray           # (3, 3)
    rate_rad_s: np.ndarray              # (3,) body rate, camera frame (gyro mode: gyro − bias)
    gyro_bias_rad_s: np.ndarray | None  # (3,) in gyro mode, else None
    covariance: np.ndarray              # (6, 6): [δθ (rad, camera frame), δω or δβ (rad/s)]


class Innovation(NamedTuple):
    """A measurement against a prediction: ``A_meas = R(residual) A_pred``."""

    residual_rad: np.ndarray     # (3,) rotation vector, camera frame
    covariance_rad2: np.ndarray  # (3, 3) S = P_att + R
    nis: float                   # residualᵀ S⁻¹ residual, χ²(3) when consistent


# --- kernels -----------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _coefficients(theta):
    """``c₁ = sin θ/θ``, ``c₂ … c₅`` of the module docstring."""
    if theta == 0.0:
        return 1.0, 0.5, 1.0 / 6.0, 1.0 / 24.0, 1.0 / 60.0
    s = math.sin(theta)
    half = math.sin(0.5 * theta)
    t2 = theta * theta
    c1 = s / theta
    c2 = 2.0 * half * half / t2
    if theta < _SERIES_BELOW:
        t4 = t2 * t2
        t6 = t4 * t2
        t8 = t4 * t4
        c3 = 1 / 6 - t2 / 120 + t4 / 5040 - t6 / 362880 + t8 / 39916800
        c4 = 1 / 24 - t2 / 720 + t4 / 40320 - t6 / 3628800 + t8 / 479001600
        c5 = 1 / 60 - t2 / 2520 + t4 / 181440 - t6 / 19958400 + t8 / 3113510400
    else:
        c3 = (theta - s) / (t2 * theta)
        c4 = (0.5 * t2 - 2.0 * half * half) / (t2 * t2)
        c5 = (1.0 / 3.0 - 2.0 * c3) / t2
    return c1, c2, c3, c4, c5


@njit(cache=True)
def interval_model(rate_rad_s, dt_s):
    """The four 3 × 3 matrices of the exact discretisation over ``dt_s`` at rate ``ω̂``, as a
    (4, 3, 3) array: ``R(−ω̂ T)``, ``M(T)``, ``∫₀ᵀ M`` and ``∫₀ᵀ M Mᵀ`` (module docstring); each
    is ``α I + β W + γ W²`` with ``W = [ω̂×]`` (``W³ = −|ω̂|² W``)."""
    wx, wy, wz = rate_rad_s[0], rate_rad_s[1], rate_rad_s[2]
    w2 = wx * wx + wy * wy + wz * wz
    T = dt_s
    c1, c2, c3, c4, c5 = _coefficients(math.sqrt(w2) * T)
    T2 = T * T
    T3 = T2 * T
    coef = ((1.0, -T * c1, T2 * c2), (T, -T2 * c2, T3 * c3), (0.5 * T2, -T3 * c3, T3 * T * c4),
            (T3 / 3.0, 0.0, T3 * T2 * c5))
    W = np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])
    w = (wx, wy, wz)
    out = np.empty((4, 3, 3))
    for k in range(4):
        a, b, c = coef[k]
        for i in range(3):
            for j in range(3):
                W2 = w[i] * w[j] - (w2 if i == j else 0.0)
                out[k, i, j] = (a if i == j else 0.0) + b * W[i, j] + c * W2
    return out


@njit(cache=True)
def propagate_estimate(A, P, omega, dt, q_rate, q_att, sign):
    """``(R(−ω̂ T) A, Φ P Φᵀ + Q)`` over ``dt`` (``sign`` −1: rate model, +1: gyro model)."""
    m = interval_model(omega, dt)
    Phi = np.eye(6)
    Q = np.zeros((6, 6))
    for i in range(3):
        Q[i, i] = q_att * dt
        Q[3 + i, 3 + i] = q_rate * dt
        for j in range(3):
            Phi[i, j] = m[0, i, j]
            Phi[i, 3 + j] = sign * m[1, i, j]
            Q[i, j] += q_rate * m[3, i, j]
            Q[i, 3 + j] = sign * q_rate * m[2, i, j]
            Q[3 + j, i] = Q[i, 3 + j]
    PhiP = np.zeros((6, 6))
    for i in range(6):
        for k in range(6):
            f = Phi[i, k]
            if f != 0.0:
                for j in range(6):
                    PhiP[i, j] += f * P[k, j]
    P_new = np.empty((6, 6))
    for i in range(6):
        for j in range(i, 6):
            t = Q[i, j]
            for k in range(6):
                t += PhiP[i, k] * Phi[j, k]
            P_new[i, j] = t
            P_new[j, i] = t
    A_new = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            A_new[i, j] = m[0, i, 0] * A[0, j] + m[0, i, 1] * A[1, j] + m[0, i, 2] * A[2, j]
    return A_new, P_new


@njit(cache=True, inline="always")
def _times3(K, M):
    """``K M`` of a (6, 3) and a 3 × 3 matrix, by loops (the gain's products)."""
    out = np.zeros((6, 3))
    for i in range(6):
        for j in range(3):
            out[i, j] = K[i, 0] * M[0, j] + K[i, 1] * M[1, j] + K[i, 2] * M[2, j]
    return out


@njit(cache=True, inline="always")
def _corrected_attitude(dx, A_pred):
    """``R(δθ) A_pred`` for the state correction ``dx`` (its first three: ``δθ``)."""
    Rc = rodrigues(dx[:3])
    A_new = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            A_new[i, j] = Rc[i, 0] * A_pred[0, j] + Rc[i, 1] * A_pred[1, j] + Rc[i, 2] * A_pred[2, j]
    return A_new


@njit(cache=True)
def _innovation(A_pred, P, A_meas, R):
    """``z`` (rotation vector of ``A_meas A_predᵀ``), ``S = P[:3, :3] + R``, ``S⁻¹``, whether
    ``S`` is positive definite, and ``zᵀ S⁻¹ z``."""
    D = np.empty((3, 3))
    S = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            D[i, j] = A_meas[i, 0] * A_pred[j, 0] + A_meas[i, 1] * A_pred[j, 1] + A_meas[i, 2] * A_pred[j, 2]
            S[i, j] = P[i, j] + R[i, j]
    z = rotation_vector(D)
    S_inv, ok = spd_inverse(S)
    nis = 0.0
    for i in range(3):
        for j in range(3):
            nis += z[i] * S_inv[i, j] * z[j]
    return z, S, S_inv, ok, nis


@njit(cache=True)
def _correct(A_pred, P, A_meas, R):
    """The measurement update: (whether S was positive definite, corrected attitude, state
    correction dx (6,), Joseph-form covariance, NIS)."""
    z, S, S_inv, ok, nis = _innovation(A_pred, P, A_meas, R)
    if not ok:
        return False, A_pred, np.zeros(6), P, nis
    K = _times3(P, S_inv)  # P Hᵀ S⁻¹
    dx = np.zeros(6)
    IKH = np.eye(6)
    for i in range(6):
        for j in range(3):
            dx[i] += K[i, j] * z[j]
            IKH[i, j] -= K[i, j]
    IKHP = np.zeros((6, 6))
    for i in range(6):
        for k in range(6):
            f = IKH[i, k]
            if f != 0.0:
                for j in range(6):
                    IKHP[i, j] += f * P[k, j]
    KR = _times3(K, R)
    P_new = np.empty((6, 6))
    for i in range(6):
        for j in range(i, 6):
            t = 0.0
            for k in range(6):
                t += IKHP[i, k] * IKH[j, k]
            for k in range(3):
                t += KR[i, k] * K[j, k]
            P_new[i, j] = t
            P_new[j, i] = t
    A_new = _corrected_attitude(dx, A_pred)
    return True, A_new, dx, P_new, nis


@njit(cache=True)
def _rotation_code(A):
    """0 for a finite proper rotation (orthonormal to 1e-6, det > 0), else an error code."""
    for i in range(3):
        for j in range(3):
            if not np.isfinite(A[i, j]):
                return _NOT_FINITE
    for i in range(3):
        for j in range(3):
            d = A[i, 0] * A[j, 0] + A[i, 1] * A[j, 1] + A[i, 2] * A[j, 2] - (1.0 if i == j else 0.0)
            if abs(d) > 1e-6:
                return _NOT_ROTATION
    det = (A[0, 0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1])
           - A[0, 1] * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
           + A[0, 2] * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]))
    return _OK if det > 0.0 else _NOT_ROTATION


@njit(cache=True)
def _symmetrize_code(C):
    """Symmetrise ``C`` in place; 0 when it is finite and positive definite, else an error code."""
    for i in range(3):
        for j in range(3):
            if not np.isfinite(C[i, j]):
                return _NOT_FINITE
    for i in range(3):
        for j in range(i + 1, 3):
            m = 0.5 * (C[i, j] + C[j, i])
            C[i, j] = m
            C[j, i] = m
    return _OK if spd_inverse(C)[1] else _NOT_SPD


@njit(cache=True)
def gated_correct(A_pred, P, A_meas, R, nis_gate):
    """:meth:`AttitudeFilter.update_gated` in one kernel: the checks of :func:`as_rotation` on
    ``A_meas`` and of :func:`as_covariance` on ``R`` (symmetrised in place), the innovation, and
    the measurement update of :func:`_correct` when the NIS is within ``nis_gate``. Returns
    (the error codes of ``A_meas`` and of ``R``, whether ``S`` was positive definite, ``z``,
    ``S``, NIS, whether it was corrected, the corrected attitude, state correction, covariance)."""
    rotation_code = _rotation_code(A_meas)
    covariance_code = _symmetrize_code(R)
    z, S, _, ok, nis = _innovation(A_pred, P, A_meas, R)
    if rotation_code != _OK or covariance_code != _OK or not ok or not nis <= nis_gate:
        return rotation_code, covariance_code, ok, z, S, nis, False, A_pred, np.zeros(6), P
    _, A_new, dx, P_new, _ = _correct(A_pred, P, A_meas, R)
    return rotation_code, covariance_code, ok, z, S, nis, True, A_new, dx, P_new


@njit(cache=True)
def corrected_rate(omega, g, bias, dx, gyro):
    """The body rate and gyro bias after a measurement's state correction ``dx`` (6,):
    ``ω̂ + δω`` (the rate model; ``bias`` unchanged), or in gyro mode the bias ``β̂ + δβ`` and
    the rate ``g − β̂`` it leaves of the gyro rate ``g``. Returns ``(rate, bias)``."""
    if gyro:
        new_bias = np.empty(3)
        rate = np.empty(3)
        for i in range(3):
            new_bias[i] = bias[i] + dx[3 + i]
            rate[i] = g[i] - new_bias[i]
        return rate, new_bias
    rate = np.empty(3)
    for i in range(3):
        rate[i] = omega[i] + dx[3 + i]
    return rate, bias


@njit(cache=True)
def propagate_cross(omega, dt, X, sign):
    """``Φ X`` over ``dt`` (module docstring: the cross-covariance (6, n) of the filter's errors
    with the consider states; ``sign`` as :func:`propagate_estimate`'s)."""
    m = interval_model(omega, dt)
    n = X.shape[1]
    out = X.copy()
    for i in range(3):
        for j in range(n):
            t = 0.0
            for k in range(3):
                t += m[0, i, k] * X[k, j] + sign * m[1, i, k] * X[3 + k, j]
            out[i, j] = t
    return out


@njit(cache=True)
def consider_correct(A_pred, P, X, C, A_meas, R, G, nis_gate):
    """The measurement update with consider states (module docstring): the prediction ``A_pred``,
    ``P`` (6, 6), cross-covariance ``X`` (6, n), the consider states' covariance ``C`` (n, n), the
    star fit ``A_meas`` with covariance ``R`` (symmetrised in place) and its sensitivity ``G``
    (3, n) to the consider states. The checks and results of :func:`gated_correct`, and the new
    cross-covariance last."""
    rotation_code = _rotation_code(A_meas)
    covariance_code = _symmetrize_code(R)
    n = C.shape[0]
    Y = np.empty((3, n))  # cov(the measurement's error, the camera's) = X_att + G C
    for i in range(3):
        for j in range(n):
            t = X[i, j]
            for k in range(n):
                t += G[i, k] * C[k, j]
            Y[i, j] = t
    Pxy = np.empty((6, 3))  # cov(the state's error, the innovation's) = P Hᵀ + X Gᵀ
    for i in range(6):
        for j in range(3):
            t = P[i, j]
            for k in range(n):
                t += X[i, k] * G[j, k]
            Pxy[i, j] = t
    R_all = np.empty((3, 3))  # S − P_att: R + X_att Gᵀ + G Yᵀ
    for i in range(3):
        for j in range(3):
            t = R[i, j]
            for k in range(n):
                t += X[i, k] * G[j, k] + G[i, k] * Y[j, k]
            R_all[i, j] = t
    for i in range(3):
        for j in range(i + 1, 3):
            m = 0.5 * (R_all[i, j] + R_all[j, i])
            R_all[i, j] = m
            R_all[j, i] = m
    z, S, S_inv, ok, nis = _innovation(A_pred, P, A_meas, R_all)
    if rotation_code != _OK or covariance_code != _OK or not ok or not nis <= nis_gate:
        return rotation_code, covariance_code, ok, z, S, nis, False, A_pred, np.zeros(6), P, X
    K = _times3(Pxy, S_inv)
    dx = np.zeros(6)
    for i in range(6):
        dx[i] = K[i, 0] * z[0] + K[i, 1] * z[1] + K[i, 2] * z[2]
    KS = _times3(K, S)
    P_new = np.empty((6, 6))
    for i in range(6):
        for j in range(i, 6):
            t = P[i, j]
            for k in range(3):
                t += -K[i, k] * Pxy[j, k] - Pxy[i, k] * K[j, k] + KS[i, k] * K[j, k]
            P_new[i, j] = t
            P_new[j, i] = t
    X_new = X.copy()
    for i in range(6):
        for j in range(n):
            X_new[i, j] -= K[i, 0] * Y[0, j] + K[i, 1] * Y[1, j] + K[i, 2] * Y[2, j]
    A_new = _corrected_attitude(dx, A_pred)
    return rotation_code, covariance_code, ok, z, S, nis, True, A_new, dx, P_new, X_new
