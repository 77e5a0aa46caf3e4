"""Frames around the camera: body (a mounting), orbit, true of date; Euler 1-2-3 angles, quaternion
averaging, and attitudes named by the frames they join (docs/frames-and-refraction.md).

Every rotation here is a matrix ``A_<from>_to_<to>`` taking the components of a direction in one
frame into another, ``v_to = A v_from`` — the convention of ``A_icrs_to_cam``
(docs/design.md#attitude-matrix); its quaternion is the scalar-last ``[x, y, z, w]`` of that
matrix in scipy's convention with ``w >= 0`` (:func:`skyfix.geometry.quaternion_from_attitude`).

- **Elementary rotations and Euler 1-2-3** — thesis 004's direction cosine matrices (1.10)–(1.12)
  (:func:`elementary_rotation`: a *frame* rotation, ``A_x(φ) = [[1,0,0],[0,cφ,sφ],[0,−sφ,cφ]]``)
  and ``A(φ, θ, ψ) = A_z(ψ)·A_y(θ)·A_x(φ)`` (1.13) (:func:`matrix_from_euler123`,
  :func:`euler123_from_matrix`). As 004 uses it, ``A_orbit_to_body = A(roll, pitch, yaw)``.
- **Mounting** — the camera → body rotation ``A_cam_to_body`` (:class:`Mounting`), from a
  quaternion or Euler 1-2-3 angles, a string (``--mounting``) or a ``[mounting]`` TOML table;
  ``A_icrs_to_body = A_cam_to_body · A_icrs_to_cam``. Thesis 004's star sensor on Sunsat is
  :func:`sunsat_mounting`: its sensor → body matrix (1.14) with the 180° rotation about x that
  the printed matrix drops.
- **Orbit frame** — :func:`orbit_frame` from a position and velocity (``z_o`` nadir, ``y_o``
  against the orbit normal, ``x_o`` completing the triad: the velocity on a circular orbit) and
  :func:`orbit_frame_from_elements`, 004's four rotations (1.18) with the last one's sign
  corrected (``A_y(−ω′)``: the printed ``+ω′`` runs the satellite backwards).
- **True of date** — :func:`true_of_date`: ``A_tod_to_cam = A_icrs_to_cam · Nᵀ`` with ``N``
  ERFA's IAU 2006/2000A bias-precession-nutation matrix (``erfa.pnm06a``, equinox based: the
  frame of astropy's TETE and of "JNow").
- **Averaging** — :func:`average_quaternions`, Markley et al. (2007): the eigenvector of the
  largest eigenvalue of ``M = Σ wᵢ qᵢ qᵢᵀ`` (sign-blind), with the scatter about it and the
  covariance of the mean in the axes of docs/design.md#attitude-error-and-covariance.
- **Named output** — :func:`attitude_frames` gives the attitude in the reference frame asked for
  (ICRS, the default, or true of date), in the body frame and relative to the orbit frame, each
  number labelled with the two frames it joins.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import erfa
import numpy as np
import tomllib

from skyfix.attitude import attitude_error
from skyfix.errors import InputError
from skyfix.geometry import attitude_from_quaternion, quaternion_from_attitude, radec_roll_from_attitude

__all__ = [
    "AttitudeFrames", "FrameAttitude", "Mounting", "QuaternionAverage", "REFERENCE_FRAMES",
    "SUNSAT_CAMERA_TO_SENSOR", "attitude_frames", "average_quaternions", "elementary_rotation",
    "euler123_from_matrix", "matrix_from_euler123", "orbit_frame", "orbit_frame_from_elements",
    "sunsat_mounting", "sunsat_sensor_to_body", "true_of_date", "true_of_date_matrix",
]

#: The frames an attitude can be given relative to (:func:`attitude_frames`).
REFERENCE_FRAMES = ("icrs", "true-of-date")

#: How far from 1 the norm of a quaternion given by hand may be (4 printed digits: 2e-5) before it
#: is refused as not a unit quaternion; within it the quaternion is normalised.
UNIT_QUATERNION_TOLERANCE = 1e-3

#: Thesis 004's star sensor frame in skyfix's camera frame: the sensor's boresight is ``y_ss``,
#: its image width runs along ``x_ss`` (u) and its height along ``z_ss`` (v), so skyfix's camera
#: axes are ``(x_ss, −z_ss, y_ss)``: ``v_cam = SUNSAT_CAMERA_TO_SENSOR.T @ v_ss``.
SUNSAT_CAMERA_TO_SENSOR = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
SUNSAT_CAMERA_TO_SENSOR.setflags(write=False)


# --- elementary rotations and Euler 1-2-3 -----------------------------------------------------
def elementary_rotation(axis: int, angle_rad: float | np.ndarray) -> np.ndarray:
    """Thesis 004's direction cosine matrix about ``axis`` (0 = x, 1 = y, 2 = z) by ``angle_rad``.

    A frame rotation (1.10)–(1.12): ``A_x(φ) = [[1,0,0],[0,cφ,sφ],[0,−sφ,cφ]]``,
    ``A_y(θ) = [[cθ,0,−sθ],[0,1,0],[sθ,0,cθ]]``, ``A_z(ψ) = [[cψ,sψ,0],[−sψ,cψ,0],[0,0,1]]``: the
    components of a fixed vector in the frame turned by the angle (right-handed) about the axis.
    A scalar angle gives (3, 3), an array of angles (..., 3, 3).
    """
    angle = np.asarray(angle_rad, dtype=np.float64)
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros(angle.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., i, j] = s
    R[..., j, i] = -s
    return R


def matrix_from_euler123(phi_rad: float | np.ndarray, theta_rad: float | np.ndarray,
                         psi_rad: float | np.ndarray) -> np.ndarray:
    """Thesis 004's Euler 1-2-3 matrix ``A(φ, θ, ψ) = A_z(ψ)·A_y(θ)·A_x(φ)`` (1.13): about x by
    φ, then the new y by θ, then the new z by ψ. Equal to scipy's
    ``Rotation.from_euler("XYZ", [φ, θ, ψ]).as_matrix().T``. Arrays broadcast to (..., 3, 3)."""
    return (elementary_rotation(2, psi_rad) @ elementary_rotation(1, theta_rad)
            @ elementary_rotation(0, phi_rad))


def euler123_from_matrix(A: np.ndarray) -> np.ndarray:
    """The Euler 1-2-3 angles ``[φ, θ, ψ]`` (radians; φ, ψ in (−π, π], θ in [−π/2, π/2]) of a
    rotation matrix (..., 3, 3): the inverse of :func:`matrix_from_euler123`.

    From 1.13's product: ``A[2,0] = sin θ``, ``A[2,1] = −cos θ sin φ``, ``A[2,2] = cos θ cos φ``,
    ``A[1,0] = −sin ψ cos θ``, ``A[0,0] = cos ψ cos θ``. At θ = ±90° only φ ± ψ is defined; φ = 0
    is taken and ψ found from ``A[0,1] = sin(ψ ± φ)``, ``A[1,1] = cos(ψ ± φ)``.
    """
    A = np.asarray(A, dtype=np.float64)
    theta = np.arcsin(np.clip(A[..., 2, 0], -1.0, 1.0))
    locked = np.hypot(A[..., 2, 1], A[..., 2, 2]) < 1e-12
    phi = np.where(locked, 0.0, np.arctan2(-A[..., 2, 1], A[..., 2, 2]))
    psi = np.where(locked, np.arctan2(A[..., 0, 1], A[..., 1, 1]), np.arctan2(-A[..., 1, 0], A[..., 0, 0]))
    return np.stack([phi, theta, psi], axis=-1)


# --- mounting -----------------------------------------------------------------------------------
def _numbers(value: object, name: str) -> np.ndarray:
    """A 1-D array of finite floats from a sequence, or an InputError naming ``name``."""
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"{name} {value!r} is not a list of numbers") from None
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} {value!r} has a number that is not finite")
    return arr


@dataclass(frozen=True)
class Mounting:
    """The camera → body rotation ``A_cam_to_body`` (``v_body = A_cam_to_body @ v_cam``).

    Make one with :meth:`from_quaternion` (scalar last, of ``A_cam_to_body`` in the convention of
    docs/design.md#quaternion), :meth:`from_euler123_deg` (thesis 004's 1-2-3 sequence:
    ``A_cam_to_body = A(φ, θ, ψ)``), :meth:`parse` (``"x,y,z,w"`` or ``"φ,θ,ψ"`` degrees) or
    :meth:`from_toml` (a ``[mounting]`` table with ``quaternion_xyzw = [...]`` or
    ``euler123_deg = [...]``). A malformed mounting is an :class:`~skyfix.errors.InputError`.
    """

    A_cam_to_body: np.ndarray

    def __post_init__(self) -> None:
        A = np.array(self.A_cam_to_body, dtype=np.float64)
        if A.shape != (3, 3) or not np.all(np.isfinite(A)):
            raise InputError("mounting matrix must be 3 × 3 finite numbers")
        if np.max(np.abs(A @ A.T - np.eye(3))) > 1e-9 or np.linalg.det(A) < 0:
            raise InputError("mounting matrix is not a rotation (orthonormal, determinant +1)")
        A.setflags(write=False)
        object.__setattr__(self, "A_cam_to_body", A)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Mounting) and bool(np.array_equal(self.A_cam_to_body, other.A_cam_to_body))

    def __hash__(self) -> int:
        return hash(self.A_cam_to_body.tobytes())

    @classmethod
    def from_quaternion(cls, quaternion_xyzw: object) -> Mounting:
        """From the scalar-last quaternion of ``A_cam_to_body``; its norm must be 1 within
        :data:`UNIT_QUATERNION_TOLERANCE` (it is then normalised)."""
        q = _numbers(quaternion_xyzw, "mounting quaternion")
        if len(q) != 4:
            raise InputError(f"mounting quaternion needs 4 numbers x,y,z,w, not {len(q)}")
        norm = float(np.linalg.norm(q))
        if abs(norm - 1.0) > UNIT_QUATERNION_TOLERANCE:
            raise InputError(f"mounting quaternion {','.join(f'{x:g}' for x in q)} is not a unit "
                             f"quaternion (norm {norm:.6g})")
        return cls(attitude_from_quaternion(q / norm))

    @classmethod
    def from_euler123_deg(cls, angles_deg: object) -> Mounting:
        """From thesis 004's Euler 1-2-3 angles ``[φ, θ, ψ]``, degrees: ``A(φ, θ, ψ)``."""
        a = _numbers(angles_deg, "mounting Euler angles")
        if len(a) != 3:
            raise InputError(f"mounting Euler 1-2-3 angles need 3 numbers, not {len(a)}")
        return cls(matrix_from_euler123(*np.radians(a)))

    @classmethod
    def parse(cls, text: str, name: str = "mounting") -> Mounting:
        """From ``"x,y,z,w"`` (a quaternion) or ``"φ,θ,ψ"`` (Euler 1-2-3, degrees)."""
        parts = [p.strip() for p in str(text).split(",")]
        try:
            values = [float(p) for p in parts]
        except ValueError:
            raise InputError(f"{name} {text!r} is not comma-separated numbers") from None
        if len(values) == 4:
            return cls.from_quaternion(values)
        if len(values) == 3:
            return cls.from_euler123_deg(values)
        raise InputError(f"{name} {text!r} has {len(values)} numbers: give a quaternion x,y,z,w (4) "
                         "or Euler 1-2-3 angles in degrees (3)")

    @classmethod
    def from_table(cls, table: object) -> Mounting:
        """From a ``[mounting]`` table: exactly one of ``quaternion_xyzw`` and ``euler123_deg``."""
        if not isinstance(table, dict):
            raise InputError("[mounting] must be a table")
        unknown = set(table) - {"quaternion_xyzw", "euler123_deg"}
        if unknown:
            raise InputError(f"unknown [mounting] keys: {', '.join(sorted(unknown))} "
                             "(known: quaternion_xyzw, euler123_deg)")
        if len(table) != 1:
            raise InputError("[mounting] needs exactly one of quaternion_xyzw and euler123_deg")
        if "quaternion_xyzw" in table:
            return cls.from_quaternion(table["quaternion_xyzw"])
        return cls.from_euler123_deg(table["euler123_deg"])

    @classmethod
    def from_toml(cls, text: str) -> Mounting | None:
        """The ``[mounting]`` table of a TOML text (a camera file may carry one), or None."""
        try:
            doc = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise InputError(f"mounting file is not valid TOML: {exc}") from None
        return cls.from_table(doc["mounting"]) if "mounting" in doc else None

    @classmethod
    def load(cls, path: str | Path) -> Mounting | None:
        """The ``[mounting]`` table of a TOML file, or None when it has none."""
        try:
            text = Path(path).read_text(encoding="utf-8")
        except OSError as exc:
            raise InputError(f"cannot read mounting file {path}: {exc.strerror or exc}") from None
        return cls.from_toml(text)

    @property
    def quaternion_xyzw(self) -> np.ndarray:
        """Scalar-last quaternion of ``A_cam_to_body``, ``w >= 0``."""
        return quaternion_from_attitude(self.A_cam_to_body)

    @property
    def euler123_deg(self) -> np.ndarray:
        """Thesis 004's Euler 1-2-3 angles of ``A_cam_to_body``, degrees."""
        return np.degrees(euler123_from_matrix(self.A_cam_to_body))

    def body_attitude(self, A_ref_to_cam: np.ndarray) -> np.ndarray:
        """``A_ref_to_body = A_cam_to_body · A_ref_to_cam`` (any reference frame)."""
        return self.A_cam_to_body @ np.asarray(A_ref_to_cam, dtype=np.float64)

    def camera_attitude(self, A_ref_to_body: np.ndarray) -> np.ndarray:
        """``A_ref_to_cam = A_cam_to_bodyᵀ · A_ref_to_body``: the inverse of :meth:`body_attitude`."""
        return self.A_cam_to_body.T @ np.asarray(A_ref_to_body, dtype=np.float64)

    def to_table(self) -> dict:
        """A ``[mounting]`` table (the quaternion)."""
        return {"quaternion_xyzw": [float(x) for x in self.quaternion_xyzw]}


def sunsat_sensor_to_body(psi_rad: float = -math.pi / 4) -> np.ndarray:
    """Thesis 004's ``A_ss→b = A_z(ψ)·A_x(180°)`` (1.14 corrected), ψ = −45° on Sunsat.

    The printed (1.14) is ``A_z(ψ)`` alone: it drops the 180° rotation about x, and puts the
    boresight ``y_ss`` between ``−x_b`` and ``+y_b``; the corrected matrix
    ``[[cψ, −sψ, 0], [−sψ, −cψ, 0], [0, 0, −1]]`` puts it at ``(0.707, −0.707, 0)_b``, between
    ``x_b`` and ``−y_b``, as 004's text says.
    """
    return elementary_rotation(2, psi_rad) @ elementary_rotation(0, math.pi)


def sunsat_mounting() -> Mounting:
    """Thesis 004's star sensor on Sunsat as a camera → body mounting:
    ``A_cam_to_body = A_ss→b · A_cam→ss`` (:func:`sunsat_sensor_to_body`,
    :data:`SUNSAT_CAMERA_TO_SENSOR`)."""
    return Mounting(sunsat_sensor_to_body() @ SUNSAT_CAMERA_TO_SENSOR)


# --- orbit frame --------------------------------------------------------------------------------
def orbit_frame(position_km: object, velocity_km_s: object) -> np.ndarray:
    """``A_icrs_to_orbit`` (3 × 3) of thesis 004's roll-pitch-yaw frame for a spacecraft at
    ``position_km`` moving at ``velocity_km_s`` (geocentric, ICRS axes; any one length unit).

    Rows: ``x_o = y_o × z_o`` (roll; the velocity on a circular orbit), ``y_o = −(r × v)/|r × v|``
    (pitch, against the orbit normal), ``z_o = −r/|r|`` (yaw, nadir). 004's sign check holds: at
    the ascending node ``z_o`` is minus the node direction and ``x_o`` the velocity
    (``tests/core/test_frames.py`` checks it against :func:`orbit_frame_from_elements`).
    """
    r = _numbers(position_km, "position")
    v = _numbers(velocity_km_s, "velocity")
    if len(r) != 3 or len(v) != 3:
        raise InputError(f"position and velocity need 3 numbers each, not {len(r)} and {len(v)}")
    h = np.cross(r, v)
    rn, vn, hn = (float(np.linalg.norm(x)) for x in (r, v, h))
    if rn == 0.0 or hn <= 1e-9 * rn * vn or vn == 0.0:
        raise InputError("position and velocity are zero or parallel: they define no orbit plane")
    z = -r / rn
    y = -h / hn
    return np.vstack([np.cross(y, z), y, z])


def orbit_frame_from_elements(node_rad: float | np.ndarray, incl_rad: float | np.ndarray,
                              arg_lat_rad: float | np.ndarray) -> np.ndarray:
    """``A_icrs_to_orbit`` from thesis 004's orbit angles: right ascension of the ascending node
    Ω, inclination i, argument of latitude ω′ (perigee + true anomaly), radians; arrays give
    (..., 3, 3).

    004's (1.18) with its last sign corrected (Appendix Z.3):
    ``A_c→o = A_y(−ω′)·A_x(−90°)·A_y(−i)·A_z(90° + Ω)`` — the printed ``A_y(+ω′)`` moves the
    frame backwards along the orbit.
    """
    u = np.asarray(arg_lat_rad, dtype=np.float64)
    return (elementary_rotation(1, -u) @ elementary_rotation(0, -math.pi / 2)
            @ elementary_rotation(1, -np.asarray(incl_rad, dtype=np.float64))
            @ elementary_rotation(2, math.pi / 2 + np.asarray(node_rad, dtype=np.float64)))


# --- true of date -----------------------------------------------------------------------------
def true_of_date_matrix(jd_tt: float) -> np.ndarray:
    """ERFA's IAU 2006/2000A bias-precession-nutation matrix ``N`` (``erfa.pnm06a``) at the TT
    Julian date ``jd_tt``: ``r_tod = N r_icrs`` (true equator and equinox of date, astropy's TETE)."""
    jd = float(jd_tt)
    if not math.isfinite(jd):
        raise InputError(f"TT Julian date {jd_tt!r} is not a number")
    return erfa.pnm06a(2400000.5, jd - 2400000.5)


def true_of_date(A_icrs_to_cam: np.ndarray, jd_tt: float) -> np.ndarray:
    """The attitude relative to the true equator and equinox of date:
    ``A_tod_to_cam = A_icrs_to_cam · Nᵀ`` (:func:`true_of_date_matrix`)."""
    return np.asarray(A_icrs_to_cam, dtype=np.float64) @ true_of_date_matrix(jd_tt).T


# --- averaging ----------------------------------------------------------------------------------
class QuaternionAverage(NamedTuple):
    """The average of many attitudes (:func:`average_quaternions`).

    quaternion_xyzw : (4,) — the average, scalar last, ``w >= 0``.
    A : (3, 3) — its matrix.
    deviations_rad : (n, 3) — each attitude's rotation vector about the average,
        ``A_i = R(δθ_i) A`` (docs/design.md#attitude-error-and-covariance: the axes of the
        frame the attitudes map into).
    scatter_rad2 : (3, 3) — the weighted covariance of the deviations (bias-corrected for the
        effective number of attitudes); NaN for one attitude.
    covariance_rad2 : (3, 3) — the covariance of the average: ``scatter / n_effective``.
    n : int — attitudes averaged.
    n_effective : float — ``(Σw)² / Σw²`` (n for equal weights).
    """

    quaternion_xyzw: np.ndarray
    A: np.ndarray
    deviations_rad: np.ndarray
    scatter_rad2: np.ndarray
    covariance_rad2: np.ndarray
    n: int
    n_effective: float


def average_quaternions(quaternions_xyzw: object, weights: object | None = None) -> QuaternionAverage:
    """Markley, Cheng, Crassidis & Oshman (2007): the average quaternion is the unit eigenvector
    of the largest eigenvalue of ``M = Σ wᵢ qᵢ qᵢᵀ`` (4 × 4); ``q`` and ``−q`` count the same.
    It minimises the weighted sum of squared Frobenius distances of the attitude matrices
    (thesis 003 §7, Eqs. 7.12–7.13).

    Parameters
    ----------
    quaternions_xyzw : (n, 4) — scalar-last quaternions (normalised here).
    weights : (n,), optional — relative weights ≥ 0, not all 0 (default: equal).

    Returns
    -------
    QuaternionAverage — the average with the scatter of the attitudes about it and the covariance
    of the average (scatter / effective count), radians².
    """
    q = np.asarray(quaternions_xyzw, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 4 or len(q) == 0:
        raise InputError(f"quaternions must be an (n, 4) array with n >= 1, not shape {q.shape}")
    norms = np.linalg.norm(q, axis=1)
    if not np.all(np.isfinite(q)) or np.any(norms == 0):
        raise InputError("quaternions must be finite and non-zero")
    q = q / norms[:, None]
    w = np.ones(len(q)) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    if len(w) != len(q) or not np.all(np.isfinite(w)) or np.any(w < 0) or not np.any(w > 0):
        raise InputError("weights must be one finite number >= 0 per quaternion, not all 0")
    M = (q * w[:, None]).T @ q
    _, vecs = np.linalg.eigh(M)
    mean = vecs[:, -1] * (1.0 if vecs[3, -1] >= 0 else -1.0)
    A = attitude_from_quaternion(mean)
    mats = attitude_from_quaternion(q).reshape(-1, 3, 3)
    dev = np.array([attitude_error(A, Ai) for Ai in mats])
    n_eff = float(w.sum() ** 2 / np.sum(w**2))
    if len(q) > 1:
        scatter = (dev * w[:, None]).T @ dev / w.sum() * n_eff / (n_eff - 1.0)
    else:
        scatter = np.full((3, 3), np.nan)
    return QuaternionAverage(quaternion_from_attitude(A), A, dev, scatter, scatter / n_eff, len(q), n_eff)


# --- named output -------------------------------------------------------------------------------
class FrameAttitude(NamedTuple):
    """One rotation named by the frames it joins: ``matrix`` is ``A_<from_frame>_to_<to_frame>``."""

    from_frame: str
    to_frame: str
    matrix: np.ndarray

    @property
    def quaternion_xyzw(self) -> np.ndarray:
        return quaternion_from_attitude(self.matrix)

    @property
    def euler123_deg(self) -> np.ndarray:
        return np.degrees(euler123_from_matrix(self.matrix))

    def to_json(self) -> dict:
        """``from``, ``to``, ``quaternion_xyzw``, ``euler123_deg``; for a celestial frame to the
        camera also the boresight's ``ra_deg``, ``dec_deg`` and ``roll_deg`` in that frame."""
        out = {"from": self.from_frame, "to": self.to_frame,
               "quaternion_xyzw": [round(float(x), 10) for x in self.quaternion_xyzw],
               "euler123_deg": [round(float(x), 8) for x in self.euler123_deg]}
        if self.to_frame == "camera" and self.from_frame in REFERENCE_FRAMES:
            ra, dec, roll = radec_roll_from_attitude(self.matrix)
            out.update(ra_deg=round(math.degrees(ra), 8), dec_deg=round(math.degrees(dec), 8),
                       roll_deg=round(math.degrees(roll), 6))
        return out


class AttitudeFrames(NamedTuple):
    """An attitude in every frame asked for (:func:`attitude_frames`).

    reference_frame : ``"icrs"`` or ``"true-of-date"``.
    camera : reference → camera.
    body : reference → body, or None without a mounting.
    body_in_orbit : orbit → body (its Euler 1-2-3 angles are 004's roll, pitch, yaw), or None
        without a mounting and an orbit.
    """

    reference_frame: str
    camera: FrameAttitude
    body: FrameAttitude | None
    body_in_orbit: FrameAttitude | None

    def to_json(self) -> dict:
        out: dict = {"reference_frame": self.reference_frame, "camera": self.camera.to_json()}
        for key in ("body", "body_in_orbit"):
            value = getattr(self, key)
            if value is not None:
                out[key] = value.to_json()
        return out


def attitude_frames(A_icrs_to_cam: np.ndarray, *, reference: str = "icrs", jd_tt: float | None = None,
                    mounting: Mounting | None = None,
                    A_icrs_to_orbit: np.ndarray | None = None) -> AttitudeFrames:
    """The attitude ``A_icrs_to_cam`` in ``reference`` (``"icrs"`` or ``"true-of-date"``, which
    needs ``jd_tt``), in the body frame with ``mounting``, and relative to the orbit frame with
    ``A_icrs_to_orbit`` (:func:`orbit_frame`) as well."""
    if reference not in REFERENCE_FRAMES:
        raise InputError(f"reference frame {reference!r} is not one of {', '.join(REFERENCE_FRAMES)}")
    A = np.asarray(A_icrs_to_cam, dtype=np.float64)
    if reference == "true-of-date":
        if jd_tt is None:
            raise InputError("a true-of-date attitude needs the time (jd_tt)")
        A_ref = true_of_date(A, jd_tt)
    else:
        A_ref = A
    camera = FrameAttitude(reference, "camera", A_ref)
    body = None if mounting is None else FrameAttitude(reference, "body", mounting.body_attitude(A_ref))
    in_orbit = None
    if mounting is not None and A_icrs_to_orbit is not None:
        in_orbit = FrameAttitude("orbit", "body",
                                 mounting.body_attitude(A) @ np.asarray(A_icrs_to_orbit, dtype=np.float64).T)
    return AttitudeFrames(reference, camera, body, in_orbit)
