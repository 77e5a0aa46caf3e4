"""A multiplicative extended Kalman filter (MEKF) for the attitude and body rate of a tracker.

The estimate is a full attitude ``Â`` (``A_icrs_to_cam``) and a 6-vector state of small errors
with covariance ``P`` (6 × 6): the attitude error ``δθ`` (rad, camera frame, ``Â = R(δθ) A``,
``docs/design.md#attitude-error-and-covariance``) and the error of the body rate ``ω`` (rad/s,
camera frame) — or, fed gyro rates, of the gyro bias ``β``. The attitude itself is never a state
vector (no quaternion normalisation, no Euler singularity): each measurement's small correction
rotates ``Â`` and is then reset to zero (Markley & Crassidis, *Fundamentals of Spacecraft
Attitude Determination and Control*, §6.2).

**Motion** (``skyfix.simulate.motion``): ``Ȧ = −[ω×] A``, so over ``T`` at a constant rate
``A(t + T) = R(−ω T) A(t)``. Writing the correction ``a = −δθ`` (``A = R(a) Â``) and
``b = ω − ω̂``, the errors obey ``ȧ = −[ω̂×] a − b``.

- *Constant-rate model* (no gyro): ``ḃ`` is white angular acceleration of density
  ``accel_psd`` (rad²/s³); ``ω̂`` stays constant between measurements.
- *Gyro model*: ``ω̂ = g − β̂`` from the gyro rate ``g`` held over the interval; the gyro's
  white rate noise (angle random walk ``gyro_noise``, rad/√s) enters ``ȧ`` and its bias walks
  (``bias_walk``, rad/s/√s); the second state is ``β − β̂`` and ``ȧ = −[ω̂×] a + (β − β̂) − η``.

Both share one exact discretisation over ``T`` (the rotation is about the fixed axis ``ω̂``).
With ``W = [ω̂×]``, ``θ = |ω̂| T`` and ``M(s) = ∫₀ˢ exp(−W u) du``:

    Φ = [[R(−ω̂T), ∓M(T)], [0, I]],   Q = q [[∫MMᵀ, ∓∫M], [∓∫Mᵀ, T I]]  (+ σ_v² T on the
                                                                         attitude in gyro mode)
    M(T)    = T I − T² c₂ W + T³ c₃ W²
    ∫₀ᵀ M   = T²/2 I − T³ c₃ W + T⁴ c₄ W²
    ∫₀ᵀ MMᵀ = T³/3 I + T⁵ c₅ W²

(upper signs for the rate model, lower for the gyro model) with ``c₂ = (1 − cos θ)/θ²``,
``c₃ = (θ − sin θ)/θ³``, ``c₄ = (θ²/2 − 1 + cos θ)/θ⁴``, ``c₅ = (1/3 − 2 c₃)/θ²`` (series
below θ = 0.3, where the closed forms cancel). ``P ← Φ P Φᵀ + Q`` is then exact for the linear
error model — no Euler step, so the filter is consistent at any frame rate and any rate.

**Measurement**: a star fit's ``A_meas = R(ν) A`` with the 3 × 3 covariance of ``ν``
(``Solution.covariance_arcsec2`` in rad²). The innovation ``z`` is the rotation vector of
``A_meas Âᵀ`` (``z ≈ a + ν``, ``H = [I 0]``), ``S = P_att + R``, gain ``K = P Hᵀ S⁻¹``,
correction ``Â ← R(K_att z) Â``, ``ω̂ ← ω̂ + K_rate z`` (or ``β̂``), and Joseph's form
``P ← (I − K H) P (I − K H)ᵀ + K R Kᵀ`` keeps ``P`` symmetric and positive definite.
``zᵀ S⁻¹ z`` (NIS) is χ² with 3 degrees of freedom for a consistent measurement:
:meth:`AttitudeFilter.innovation_nis` lets a tracker refuse one above :data:`NIS_GATE`.

**The camera's uncertainty** (a tracker that calibrated its own camera,
:mod:`skyfix.track.self_calibration`): its ``n`` free camera numbers are *consider* states
(Schmidt–Kalman; Markley & Crassidis §6.2's consider form, Tapley, Schutz & Born §6.4): not
estimated — their covariance ``C`` (n × n, the joint fit's) never changes — but carried with the
cross-covariance ``X`` (6 × n) between the filter's state (the corrections ``a``, ``b``: truth −
estimate) and the camera's error. A star fit through a camera off by ``δc`` errs by
``ν + G δc`` (``G``, 3 × n: what each number does to the frame's fitted attitude,
:func:`skyfix.track.self_calibration.camera_attitude_sensitivity`), the same ``δc`` for every
frame: a bias, not white noise. Then ``X ← Φ X`` over an interval,
``P_xy = P Hᵀ + X Gᵀ``, ``S = P_att + X_att Gᵀ + G X_attᵀ + G C Gᵀ + R``, ``K = P_xy S⁻¹`` (no gain
on the camera), ``P ← P − K P_xyᵀ − P_xy Kᵀ + K S Kᵀ`` and ``X ← X − K (X_att + G C)``. The
attitude's covariance ``P_att`` then holds what the camera leaves unknown, and a filter fed many
frames through one camera does not average that part away. Without a camera covariance the filter
is the plain MEKF above, its kernels untouched.

The arithmetic is three small numba kernels (propagate, correct, and the input checks) on
fixed-size arrays, with the shared ``rodrigues``, ``rotation_vector`` and ``spd_inverse`` of
:mod:`skyfix._kernels.rotation`: numpy's per-call overhead on 3 × 3 and 6 × 6 arrays (1–7 µs an
operation) would cost ~150 µs an update, scipy's Rotation ~50 µs a call.
"""

from __future__ import annotations

import math

import numpy as np

from skyfix.errors import InputError
from skyfix.track._mekf import (
    _NOT_FINITE,
    _NOT_ROTATION,
    _NOT_SPD,
    FilterState,
    Innovation,
    _correct,
    _innovation,
    _rotation_code,
    _symmetrize_code,
    consider_correct,
    corrected_rate,
    gated_correct,
    interval_model,
    propagate_cross,
    propagate_estimate,
)

__all__ = [
    "AttitudeFilter",
    "FilterState",
    "Innovation",
    "NIS_GATE",
    "as_covariance",
    "as_rotation",
    "as_time",
    "consider_correct",
    "corrected_rate",
    "gate_innovation",
    "gated_correct",
    "innovation",
    "interval_model",
    "propagate_cross",
    "propagate_estimate",
]

NIS_GATE = 16.27
"""χ² with 3 degrees of freedom at probability 0.999: a consistent measurement's NIS exceeds it
once in a thousand."""

DEFAULT_RATE_SIGMA_RAD_S = 0.1
"""Initial σ per axis of an unknown body rate (rad/s, 5.7 °/s)."""
DEFAULT_ACCEL_PSD = 1e-4
"""White angular-acceleration density (rad²/s³): the rate wanders by √(q t), 0.57 °/s in 1 s.
Measured on slews (accelerate, coast, decelerate) with 2"/30" fits: consistent (NEES ≈ 3) up to
~5 °/s² at 10–100 Hz, conservative below (NIS ≈ 1 at 1 °/s²); 1e-5 suits 1 °/s² and is
overconfident at 5 °/s² (NEES 12). Roughly ``q ≈ α² · 0.03 s``."""
DEFAULT_GYRO_NOISE = 1e-4
"""Gyro angle random walk σ_v, rad/√s (0.34 °/√h, a MEMS gyro)."""
DEFAULT_BIAS_WALK = 1e-6
"""Gyro bias random walk σ_u, rad/s/√s."""
DEFAULT_BIAS_SIGMA_RAD_S = 0.01
"""Initial σ per axis of the gyro bias, rad/s (0.57 °/s)."""

# The one-line messages the checking kernels' error codes (skyfix.track._mekf) become.
_ROTATION_MESSAGES = {_NOT_FINITE: "{} must be a finite 3x3 rotation matrix",
                      _NOT_ROTATION: "{} is not a rotation matrix (not orthonormal or improper)"}
_NO_BIAS = np.zeros(3)  # the bias a compiled step is given without a gyro (no kernel writes it)
_COVARIANCE_MESSAGES = {_NOT_FINITE: "{} must be a finite 3x3 covariance (rad²)",
                        _NOT_SPD: "{} must be positive definite"}


# --- checks and the innovation -----------------------------------------------------------------
def as_time(t_s, name: str = "filter time") -> float:
    """A finite time in seconds as a float; InputError otherwise."""
    try:
        t = float(t_s)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number of seconds, got {t_s!r}") from None
    if not math.isfinite(t):
        raise InputError(f"{name} must be finite, got {t_s!r}")
    return t


def _matrix3(M, messages: dict, name: str, copy: bool = True) -> np.ndarray:
    """A float64 3 × 3 matrix (a copy, or ``M`` itself when it is one and ``copy`` is False);
    InputError (``messages[_NOT_FINITE]``) otherwise."""
    try:
        M = np.array(M, dtype=np.float64) if copy else np.asarray(M, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(messages[_NOT_FINITE].format(name)) from None
    if M.shape != (3, 3):
        raise InputError(messages[_NOT_FINITE].format(name))
    return M


def as_rotation(A, name: str = "attitude") -> np.ndarray:
    """A copy of a finite proper rotation matrix (3, 3), float64, C-contiguous; InputError
    otherwise."""
    A = _matrix3(A, _ROTATION_MESSAGES, name)
    code = _rotation_code(A)
    if code:
        raise InputError(_ROTATION_MESSAGES[code].format(name))
    return A


def as_covariance(C, name: str = "covariance") -> np.ndarray:
    """A symmetrised copy of a finite positive definite 3 × 3 covariance; InputError otherwise."""
    C = _matrix3(C, _COVARIANCE_MESSAGES, name)
    code = _symmetrize_code(C)
    if code:
        raise InputError(_COVARIANCE_MESSAGES[code].format(name))
    return C


def _vector3(v, name: str) -> np.ndarray:
    try:
        v = np.array(v, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be 3 finite numbers (rad/s)") from None
    if v.shape != (3,) or not (math.isfinite(v[0]) and math.isfinite(v[1]) and math.isfinite(v[2])):
        raise InputError(f"{name} must be 3 finite numbers (rad/s)")
    return v


def _positive(x, name: str) -> float:
    x = float(x)
    if not (math.isfinite(x) and x > 0):
        raise InputError(f"{name} must be a positive number, got {x!r}")
    return x


def _consider_states(covariance, cross) -> tuple[np.ndarray, np.ndarray]:
    """The consider states' covariance (n, n), checked (finite, symmetric, no negative variance),
    and the cross-covariance (6, n) of the filter's state — the corrections ``a = −δθ`` and
    ``ω − ω̂``, truth − estimate — with them: ``−cross`` on the attitude's rows, zeros below."""
    try:
        C = np.array(covariance, dtype=np.float64)
        X3 = np.zeros((3, len(C))) if cross is None else np.array(cross, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("camera_covariance and camera_cross_rad must be arrays of numbers") from None
    n = C.shape[0] if C.ndim == 2 else 0
    if C.shape != (n, n) or n == 0 or not np.all(np.isfinite(C)) or np.any(np.diagonal(C) < 0):
        raise InputError(f"camera_covariance must be a finite (n, n) covariance, got shape {C.shape}")
    if X3.shape != (3, n) or not np.all(np.isfinite(X3)):
        raise InputError(f"camera_cross_rad must be a finite (3, {n}) array, got shape {X3.shape}")
    X = np.zeros((6, n))
    X[:3] = -X3
    return np.ascontiguousarray(0.5 * (C + C.T)), X


def innovation(A_pred: np.ndarray, P_att_rad2: np.ndarray, A_meas: np.ndarray, cov_meas_rad2: np.ndarray
               ) -> Innovation:
    """The innovation of an attitude measurement against a prediction with covariance
    ``P_att`` (3 × 3, rad²): residual ``z`` with ``A_meas = R(z) A_pred`` (``z ≈ ν − δθ_pred``),
    ``S = P_att + R`` and the normalised innovation squared ``zᵀ S⁻¹ z``."""
    z, S, _, ok, nis = _innovation(as_rotation(A_pred, "predicted attitude"),
                                   as_covariance(P_att_rad2, "predicted covariance"),
                                   as_rotation(A_meas, "measured attitude"),
                                   as_covariance(cov_meas_rad2, "measurement covariance"))
    if not ok:
        raise InputError("attitude innovation covariance is not positive definite")
    return Innovation(z, S, float(nis))


def gate_innovation(rotation_code: int, covariance_code: int, ok: bool, z: np.ndarray, S: np.ndarray,
                    nis: float) -> Innovation:
    """The Innovation of :func:`gated_correct`'s first six results, or its InputError: a
    measured attitude that is not a rotation, a covariance that is not positive definite, or an
    innovation covariance that is not."""
    if rotation_code:
        raise InputError(_ROTATION_MESSAGES[rotation_code].format("measured attitude"))
    if covariance_code:
        raise InputError(_COVARIANCE_MESSAGES[covariance_code].format("measurement covariance"))
    if not ok:
        raise InputError("attitude innovation covariance is not positive definite")
    return Innovation(z, S, float(nis))


class AttitudeFilter:
    """Multiplicative EKF: attitude + body rate (constant-rate model), or attitude + gyro bias
    (``gyro=True``: propagated with the gyro rates given to :meth:`predict`/:meth:`update`).

    Parameters
    ----------
    A_icrs_to_cam : (3, 3) the initial attitude (a first star fit).
    t_s : its time, s.
    attitude_cov_rad2 : (3, 3) its covariance (rad², camera frame, ``δθ``).
    rate_rad_s : (3,) initial body rate, camera frame (default 0 with σ ``rate_sigma_rad_s``).
    rate_sigma_rad_s : initial σ per axis of the rate (:data:`DEFAULT_RATE_SIGMA_RAD_S`).
    accel_psd : white angular-acceleration density, rad²/s³ (:data:`DEFAULT_ACCEL_PSD`).
    gyro : propagate with gyro rates and estimate the gyro bias instead of the rate.
    gyro_noise : gyro angle random walk σ_v, rad/√s (:data:`DEFAULT_GYRO_NOISE`).
    bias_walk : gyro bias random walk σ_u, rad/s/√s (:data:`DEFAULT_BIAS_WALK`).
    gyro_bias_rad_s : initial bias (default 0) and ``bias_sigma_rad_s`` its σ per axis.
    camera_covariance : (n, n), optional — the covariance of the camera's ``n`` free numbers
        (consider states, module docstring; the camera's units). Then every measurement needs its
        ``camera_sensitivity`` (3, n). None: no consider states, the plain MEKF.
    camera_cross_rad : (3, n), optional — the cross-covariance of the initial attitude's error
        ``δθ`` with the camera numbers' errors (rad × the camera's units; default zeros): ``G C``
        when ``A_icrs_to_cam`` was fitted through the camera (and ``attitude_cov_rad2`` then
        holds ``R + G C Gᵀ``).

    Raises
    ------
    InputError
        A non-finite time, a matrix that is not a rotation, a covariance that is not positive
        definite, a non-positive noise setting.
    """

    def __init__(self, A_icrs_to_cam: np.ndarray, t_s: float, attitude_cov_rad2: np.ndarray, *,
                 rate_rad_s: np.ndarray | None = None,
                 rate_sigma_rad_s: float = DEFAULT_RATE_SIGMA_RAD_S,
                 accel_psd: float = DEFAULT_ACCEL_PSD, gyro: bool = False,
                 gyro_noise: float = DEFAULT_GYRO_NOISE, bias_walk: float = DEFAULT_BIAS_WALK,
                 gyro_bias_rad_s: np.ndarray | None = None,
                 bias_sigma_rad_s: float = DEFAULT_BIAS_SIGMA_RAD_S,
                 camera_covariance: np.ndarray | None = None,
                 camera_cross_rad: np.ndarray | None = None) -> None:
        self._t = as_time(t_s)
        self._A = as_rotation(A_icrs_to_cam, "attitude")
        self._gyro = bool(gyro)
        P = np.zeros((6, 6))
        P[:3, :3] = as_covariance(attitude_cov_rad2, "attitude covariance")
        if self._gyro:
            self._q_rate = _positive(bias_walk, "bias_walk") ** 2
            self._q_att = _positive(gyro_noise, "gyro_noise") ** 2
            self._bias = np.zeros(3) if gyro_bias_rad_s is None else _vector3(gyro_bias_rad_s, "gyro bias")
            self._omega = np.zeros(3) if rate_rad_s is None else _vector3(rate_rad_s, "rate")
            self._gyro_rate = self._omega + self._bias
            P[3:, 3:] = _positive(bias_sigma_rad_s, "bias_sigma_rad_s") ** 2 * np.eye(3)
        else:
            self._q_rate = _positive(accel_psd, "accel_psd")
            self._q_att = 0.0
            self._bias = None
            self._omega = np.zeros(3) if rate_rad_s is None else _vector3(rate_rad_s, "rate")
            self._gyro_rate = None
            P[3:, 3:] = _positive(rate_sigma_rad_s, "rate_sigma_rad_s") ** 2 * np.eye(3)
        self._P = P
        self._C: np.ndarray | None = None  # the consider states' covariance (n, n), or None
        self._X: np.ndarray | None = None  # the state's errors' cross-covariance with them (6, n)
        if camera_covariance is not None:
            self._C, self._X = _consider_states(camera_covariance, camera_cross_rad)
        self._cached: tuple | None = None  # (key, (A, P, ω̂, gyro rate)) of the last prediction
        self.last_nis = float("nan")
        """NIS of the last committed measurement."""

    # --- state ---------------------------------------------------------------------------------
    @property
    def gyro(self) -> bool:
        """Whether the filter runs on gyro rates (state: attitude + gyro bias)."""
        return self._gyro

    @property
    def camera_covariance(self) -> np.ndarray | None:
        """The consider states' covariance (n, n, a copy), or None without them."""
        return None if self._C is None else self._C.copy()

    def camera_cross(self, t_s: float, gyro_rate_rad_s: np.ndarray | None = None) -> np.ndarray | None:
        """The cross-covariance (6, n) of the state's errors (the attitude's ``δθ``, then the
        rate's or bias's estimate − truth) with the camera numbers' errors, propagated to ``t_s``,
        or None without consider states."""
        if self._X is None:
            return None
        _, _, omega, _ = self._predicted(t_s, gyro_rate_rad_s)
        return -self._cross_at(as_time(t_s), omega)  # the state inside is truth − estimate

    def _cross_at(self, t: float, omega: np.ndarray) -> np.ndarray:
        """The cross-covariance propagated from the state's time to ``t`` at the rate ``omega``."""
        dt = t - self._t
        if dt == 0.0:
            return self._X
        return propagate_cross(omega, dt, self._X, 1.0 if self._gyro else -1.0)

    def _sensitivity(self, camera_sensitivity) -> np.ndarray:
        """A measurement's sensitivity to the consider states, checked: (3, n) finite."""
        n = self._C.shape[0]
        if camera_sensitivity is None:
            raise InputError(f"this filter carries {n} camera numbers: a measurement needs its "
                             f"camera_sensitivity (3, {n})")
        G = np.ascontiguousarray(camera_sensitivity, dtype=np.float64)
        if G.shape != (3, n) or not np.all(np.isfinite(G)):
            raise InputError(f"camera_sensitivity must be a finite (3, {n}) array, got shape {G.shape}")
        return G

    def _consider_correct(self, t: float, A_meas, R: np.ndarray, camera_sensitivity, nis_gate: float,
                          gyro_rate_rad_s) -> tuple:
        """:func:`consider_correct` at ``t`` against the prediction; its results and the
        prediction's (ω̂, gyro rate)."""
        G = self._sensitivity(camera_sensitivity)
        A_pred, P, omega, g = self._predicted(t, gyro_rate_rad_s)
        X = self._cross_at(t, omega)
        A_meas = _matrix3(A_meas, _ROTATION_MESSAGES, "measured attitude", copy=False)
        return consider_correct(A_pred, P, X, self._C, A_meas, R, G, float(nis_gate)), omega, g

    @property
    def state(self) -> FilterState:
        """The committed estimate (copies)."""
        bias = None if self._bias is None else self._bias.copy()
        return FilterState(self._t, self._A.copy(), self._omega.copy(), bias, self._P.copy())

    # --- time update -------------------------------------------------------------------------
    def _gyro_key(self, gyro_rate_rad_s) -> tuple | None:
        if gyro_rate_rad_s is None:
            return None
        if not self._gyro:
            raise InputError("this filter has no gyro (build it with gyro=True to feed gyro rates)")
        return tuple(_vector3(gyro_rate_rad_s, "gyro rate").tolist())

    def _predicted(self, t_s: float, gyro_rate_rad_s) -> tuple:
        """(A, P, ω̂, gyro rate) propagated to ``t_s`` (cached for the same time and gyro rate)."""
        t = as_time(t_s)
        dt = t - self._t
        if dt < 0:
            raise InputError(f"filter time must not go back: t={t!r} s is before the state's {self._t!r} s")
        key = (t, self._gyro_key(gyro_rate_rad_s))
        if self._cached is not None and self._cached[0] == key:
            return self._cached[1]
        if self._gyro:
            g = self._gyro_rate if key[1] is None else np.array(key[1])
            omega = g - self._bias
        else:
            g, omega = None, self._omega
        if dt == 0.0:
            out = (self._A, self._P, omega, g)
        else:
            A, P = propagate_estimate(self._A, self._P, omega, dt, self._q_rate, self._q_att,
                              1.0 if self._gyro else -1.0)
            out = (A, P, omega, g)
        self._cached = (key, out)
        return out

    def predict(self, t_s: float, gyro_rate_rad_s: np.ndarray | None = None) -> FilterState:
        """The estimate propagated to ``t_s`` (≥ the state's time), not committed.

        In gyro mode ``gyro_rate_rad_s`` is the gyro's rate over the interval (held constant;
        default: the last one given)."""
        A, P, omega, _ = self._predicted(t_s, gyro_rate_rad_s)
        bias = None if self._bias is None else self._bias.copy()
        return FilterState(as_time(t_s), A.copy(), omega.copy(), bias, P.copy())

    def prediction(self, t_s: float, gyro_rate_rad_s: np.ndarray | None = None) -> tuple:
        """:meth:`predict`'s estimate as the four blocks a tracker uses each frame, copies: the
        attitude (3, 3), its covariance (3, 3), the rate (3,) and its covariance (3, 3) — half the
        cost of the FilterState and its covariance's blocks."""
        A, P, omega, _ = self._predicted(t_s, gyro_rate_rad_s)
        return A.copy(), P[:3, :3].copy(), omega.copy(), P[3:, 3:].copy()

    def propagate(self, t_s: float, gyro_rate_rad_s: np.ndarray | None = None) -> FilterState:
        """Commit the prediction to ``t_s`` without a measurement (a frame with no fit; in gyro
        mode, each gyro sample between measurements)."""
        A, P, omega, g = self._predicted(t_s, gyro_rate_rad_s)
        if self._X is not None:
            self._X = self._cross_at(as_time(t_s), omega)
        self._t, self._A, self._P, self._omega = as_time(t_s), A, P, omega
        if g is not None:
            self._gyro_rate = g
        self._cached = None
        return self.state

    # --- measurement update ------------------------------------------------------------------
    def innovation(self, t_s: float, A_meas: np.ndarray, cov_meas_rad2: np.ndarray,
                   gyro_rate_rad_s: np.ndarray | None = None, camera_sensitivity: np.ndarray | None = None
                   ) -> Innovation:
        """The measurement ``A_meas`` (covariance ``cov_meas_rad2``, rad²) at ``t_s`` against the
        prediction, not committed; with consider states, ``camera_sensitivity`` is its ``G``."""
        if self._C is not None:
            R = _matrix3(cov_meas_rad2, _COVARIANCE_MESSAGES, "measurement covariance")
            # a gate no NIS passes: the innovation alone, nothing corrected
            out, _, _ = self._consider_correct(as_time(t_s), A_meas, R, camera_sensitivity, -1.0,
                                               gyro_rate_rad_s)
            return gate_innovation(*out[:6])
        A_pred, P, _, _ = self._predicted(t_s, gyro_rate_rad_s)
        z, S, _, ok, nis = _innovation(A_pred, P, as_rotation(A_meas, "measured attitude"),
                                       as_covariance(cov_meas_rad2, "measurement covariance"))
        if not ok:
            raise InputError("attitude innovation covariance is not positive definite")
        return Innovation(z, S, float(nis))

    def innovation_nis(self, t_s: float, A_meas: np.ndarray, cov_meas_rad2: np.ndarray,
                       gyro_rate_rad_s: np.ndarray | None = None,
                       camera_sensitivity: np.ndarray | None = None) -> float:
        """Normalised innovation squared of a measurement: χ²(3) when it agrees with the
        prediction; above :data:`NIS_GATE` it is inconsistent at the 0.999 level."""
        return self.innovation(t_s, A_meas, cov_meas_rad2, gyro_rate_rad_s, camera_sensitivity).nis

    def update(self, t_s: float, A_meas: np.ndarray, cov_meas_rad2: np.ndarray,
               gyro_rate_rad_s: np.ndarray | None = None, camera_sensitivity: np.ndarray | None = None
               ) -> FilterState:
        """Propagate to ``t_s`` (> the state's time) and correct with the star fit ``A_meas`` of
        covariance ``cov_meas_rad2`` (rad², camera frame); commits and returns the new state.
        With consider states ``camera_sensitivity`` (3, n) is the fit's ``G`` (module docstring).

        Raises
        ------
        InputError
            A time that does not increase or is not finite, a non-rotation, a covariance that is
            not positive definite, non-finite gyro rates.
        """
        t = as_time(t_s)
        if not t > self._t:
            raise InputError(f"filter time must increase: t={t!r} s after the state's {self._t!r} s")
        A_meas = as_rotation(A_meas, "measured attitude")
        R = as_covariance(cov_meas_rad2, "measurement covariance")
        if self._C is not None:
            out, omega, g = self._consider_correct(t, A_meas, R, camera_sensitivity, math.inf,
                                                   gyro_rate_rad_s)
            if not out[2]:
                raise InputError("attitude innovation covariance is not positive definite")
            self._commit(t, out[7], out[8], out[9], g, omega, out[5], out[10])
            return self.state
        A_pred, P, omega, g = self._predicted(t, gyro_rate_rad_s)
        ok, A_new, dx, P_new, nis = _correct(A_pred, P, A_meas, R)
        if not ok:
            raise InputError("attitude innovation covariance is not positive definite")
        self._commit(t, A_new, dx, P_new, g, omega, nis)
        return self.state

    def update_gated(self, t_s: float, A_meas: np.ndarray, cov_meas_rad2: np.ndarray, nis_gate: float,
                     gyro_rate_rad_s: np.ndarray | None = None, camera_sensitivity: np.ndarray | None = None
                     ) -> tuple[bool, Innovation]:
        """:meth:`update` only when the measurement agrees with the prediction, its NIS at most
        ``nis_gate`` (a tracker's check, :meth:`innovation`, and its update in one call; with
        consider states ``camera_sensitivity`` is the fit's ``G``).
        Returns whether it was committed (else the state is unchanged) and the innovation; the
        new estimate is :attr:`state`, or :meth:`prediction` at ``t_s``.

        Raises
        ------
        InputError
            As :meth:`update`.
        """
        t = as_time(t_s)
        if not t > self._t:
            raise InputError(f"filter time must increase: t={t!r} s after the state's {self._t!r} s")
        A_meas = _matrix3(A_meas, _ROTATION_MESSAGES, "measured attitude", copy=False)  # only read
        R = _matrix3(cov_meas_rad2, _COVARIANCE_MESSAGES, "measurement covariance")  # symmetrised
        if self._C is not None:
            out, omega, g = self._consider_correct(t, A_meas, R, camera_sensitivity, nis_gate,
                                                   gyro_rate_rad_s)
            inn = gate_innovation(*out[:6])
            if out[6]:
                self._commit(t, out[7], out[8], out[9], g, omega, out[5], out[10])
            return bool(out[6]), inn
        A_pred, P, omega, g = self._predicted(t, gyro_rate_rad_s)
        rotation_code, covariance_code, ok, z, S, nis, done, A_new, dx, P_new = gated_correct(
            A_pred, P, A_meas, R, float(nis_gate))
        inn = gate_innovation(rotation_code, covariance_code, ok, z, S, nis)
        if done:
            self._commit(t, A_new, dx, P_new, g, omega, nis)
        return bool(done), inn

    def _commit(self, t: float, A_new: np.ndarray, dx: np.ndarray, P_new: np.ndarray, g, omega, nis,
                X_new: np.ndarray | None = None) -> None:
        """Take a corrected estimate at ``t`` (:func:`_correct`'s, or :func:`consider_correct`'s
        with its cross-covariance ``X_new``) as the state."""
        bias = self._bias if self._gyro else _NO_BIAS
        rate, bias = corrected_rate(omega, omega if g is None else g, bias, dx, self._gyro)
        self.take(t, A_new, P_new, rate, bias, g, nis)
        if X_new is not None:
            self._X = X_new

    # --- one compiled step (skyfix.track.step) -------------------------------------------------
    def step_inputs(self, t_s: float, gyro_rate_rad_s: np.ndarray | None = None) -> tuple:
        """What a compiled tracking step (:func:`skyfix.track.step.track_step`) needs to predict
        and correct in one call, after :meth:`update`'s checks on ``t_s``: the prediction at
        ``t_s`` — attitude (3, 3), covariance (6, 6), rate (3,) — the gyro rate held over the
        interval and the bias (the rate and zeros without a gyro), and whether in gyro mode.
        The arrays are the filter's own (cached), not copies: read, never written."""
        t = as_time(t_s)
        if not t > self._t:
            raise InputError(f"filter time must increase: t={t!r} s after the state's {self._t!r} s")
        if self._C is not None:
            raise InputError("a filter with camera consider states is updated by update_gated with each "
                             "fit's camera_sensitivity, not by a compiled step")
        A, P, omega, g = self._predicted(t, gyro_rate_rad_s)
        if self._gyro:
            return A, P, omega, g, self._bias, True
        return A, P, omega, omega, _NO_BIAS, False

    def take(self, t: float, A: np.ndarray, P: np.ndarray, rate: np.ndarray, bias: np.ndarray, g,
             nis: float) -> None:
        """Take the estimate at ``t`` a compiled step corrected (:func:`gated_correct`, then
        :func:`corrected_rate`): attitude, covariance (6, 6), rate, bias (gyro mode), the gyro
        rate ``g`` held over the interval, and the measurement's NIS."""
        self._t = t
        self._A = A
        self._P = P
        self._omega = rate
        if self._gyro:
            self._bias = bias
            self._gyro_rate = g
        self.last_nis = float(nis)
        self._cached = None
