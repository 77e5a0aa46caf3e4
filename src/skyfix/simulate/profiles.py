"""Attitude profiles: how the camera turns over a simulated sequence.

Every profile is a turn ``φ(t)`` of the camera since ``t = 0``, a rotation vector in the camera
axes of ``t = 0`` (radians), applied to the attitude ``A0`` it starts from:

    A(t) = R(−φ(t)) · A0                      (skyfix.simulate.motion.turn)

with the convention of :mod:`skyfix.simulate.motion`: a body rate ``ω`` (camera frame) moves a
fixed ICRS direction as ``ḃ = −ω × b``, so a constant rate is ``φ(t) = ω t``. The body rate of
any profile follows exactly from ``φ`` and ``φ̇`` (the right Jacobian of the rotation vector):

    ω(t) = φ̇ − (1 − cos θ)/θ² · φ × φ̇ + (θ − sin θ)/θ³ · φ × (φ × φ̇),     θ = |φ|

which is ``φ̇`` itself whenever the turn keeps one axis (constant rate, slew); the pendulum's
axes swing out of phase, so its rate needs the two extra terms. ``attitude(t)`` and ``rate(t)``
are closed forms, exact to rounding; ``tests/simulate/test_simulate_profiles.py`` checks every profile's
rate against the numerical derivative of its attitude.

Profiles by name (:data:`PROFILES`, :func:`make_profile`):

``"constant"``  — a constant body rate ``rate_rad_s`` (3,) about the camera axes.
``"inertial-axis"`` — ``rate_rad_s`` (a number) about a fixed ICRS axis ``axis_icrs`` (3,). A
    constant body rate turns about a fixed inertial axis too (its axis ``A(t)ᵀω`` does not move),
    so this is the constant profile with ``ω = rate · A0 · axis``: the way to say "scan along a
    great circle" or "hold orbit-rate pitch about the orbit normal".
``"slew"`` — a rest-to-rest turn by the rotation vector ``rotation_rad`` (3,): accelerate at
    ``accel_rad_s2`` up to ``max_rate_rad_s``, coast, decelerate, from ``start_s``. ``shape``
    ``"trapezoid"`` (constant acceleration: the rate is a trapezoid) or ``"smooth"`` (the rate
    ramps as a half cosine, so the acceleration has no jump and peaks at ``accel_rad_s2``). When
    the angle is too small to reach the maximum rate the ramps meet (a triangle).
    :meth:`Slew.between` makes the slew from one attitude to another.
``"pendulum"`` — the damped pendulum of thesis 002's air bearing (seed 002 §4.3, §5.4: a light
    push, then a damped oscillation about equilibrium, mostly in pitch): about each camera axis
    ``φ_i(t) = a_i · e^(−σ t) · sin(2π t / P + p_i)`` with amplitudes ``amplitude_rad`` (3,),
    damped period ``period_s``, phases ``phase_rad`` (3,) and damping ratio ``ζ``
    (``σ = ζ ω_n``, ``ω_n = 2π / (P √(1 − ζ²))``). With zero phases the platform passes its
    equilibrium ``A0`` at ``t = 0`` at its fastest (the push).

>>> import numpy as np
>>> from skyfix.simulate.profiles import make_profile
>>> slew = make_profile("slew", np.eye(3), rotation_rad=[0, 0.2, 0], max_rate_rad_s=0.05,
...                     accel_rad_s2=0.02)
>>> slew.duration_s, slew.rate([1.0, 3.0, 5.0])[:, 1].round(4).tolist()
(6.5, [0.02, 0.05, 0.03])
"""

from __future__ import annotations

import math
import re
from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from skyfix._kernels.rotation import rotation_vector
from skyfix.errors import SimulationError, unknown_name
from skyfix.simulate.motion import attitude_at, turn

__all__ = ["PROFILES", "Profile", "ConstantRate", "InertialAxis", "Slew", "Pendulum", "make_profile",
           "profile_of", "rate_of_turn", "SLEW_SHAPES"]

#: Slew ramp shapes: the rate's rise from 0 to the coast rate.
SLEW_SHAPES = ("trapezoid", "smooth")


def rate_of_turn(rotvec_rad: np.ndarray, rotvec_rate_rad_s: np.ndarray) -> np.ndarray:
    """Body rate ``ω`` (rad/s, camera frame) of the attitude ``R(−φ)·A0`` from ``φ`` and ``φ̇``
    (module docstring); arrays of shape (..., 3)."""
    phi = np.asarray(rotvec_rad, dtype=np.float64)
    dphi = np.asarray(rotvec_rate_rad_s, dtype=np.float64)
    theta2 = np.sum(phi * phi, axis=-1)[..., None]
    theta = np.sqrt(theta2)
    small = theta < 1e-3
    safe = np.where(small, 1.0, theta)
    # (1 − cos θ)/θ² and (θ − sin θ)/θ³, by their series where they cancel
    c1 = np.where(small, 0.5 - theta2 / 24.0 + theta2**2 / 720.0, (1.0 - np.cos(safe)) / safe**2)
    c2 = np.where(small, 1.0 / 6.0 - theta2 / 120.0 + theta2**2 / 5040.0, (safe - np.sin(safe)) / safe**3)
    cross = np.cross(phi, dphi)
    return dphi - c1 * cross + c2 * np.cross(phi, cross)


def _vector(value, name: str, n: int = 3) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64).reshape(n)
    except (TypeError, ValueError):
        raise SimulationError(f"{name} must be {n} numbers, got {value!r}") from None
    if not np.all(np.isfinite(v)):
        raise SimulationError(f"{name} must be finite, got {v.tolist()}")
    return v


def _number(value, name: str, *, positive: bool = False, minimum: float | None = None,
            below: float | None = None) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise SimulationError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or (positive and not v > 0) or (minimum is not None and v < minimum) \
            or (below is not None and not v < below):
        need = ("a positive number" if positive else f"a number >= {minimum:g}" if minimum is not None
                else "a finite number")
        if below is not None:
            need += f" below {below:g}"
        raise SimulationError(f"{name} must be {need}, got {value!r}")
    return v


def _attitude(A) -> np.ndarray:
    A = np.asarray(A, dtype=np.float64)
    if A.shape != (3, 3) or not np.all(np.isfinite(A)) or np.max(np.abs(A @ A.T - np.eye(3))) > 1e-6 \
            or np.linalg.det(A) < 0:
        raise SimulationError("a profile's start attitude must be a 3x3 rotation matrix")
    return A


class Profile(ABC):
    """An attitude profile: ``attitude(t)`` and ``rate(t)`` for a scalar or array ``t`` (s).

    Subclasses give the turn ``φ(t)`` and its derivative (:meth:`turn`); ``A0`` is the attitude
    at ``φ = 0``: where a constant rate or a slew starts, a pendulum's equilibrium. :meth:`to_dict`
    is what a frame's truth records.
    """

    name: ClassVar[str]
    A0: np.ndarray

    @abstractmethod
    def turn(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``φ(t)`` and ``φ̇(t)``, each of shape ``t.shape + (3,)`` (rad, rad/s, camera axes at 0)."""

    @abstractmethod
    def params(self) -> dict:
        """The profile's parameters, SI units, as JSON-able numbers and lists."""

    def attitude(self, t_s: np.ndarray | float) -> np.ndarray:
        """``A(t) = R(−φ(t))·A0``: (3, 3) for a scalar ``t``, ``t.shape + (3, 3)`` for an array."""
        return turn(self.A0, self.turn(np.asarray(t_s, dtype=np.float64))[0])

    def rate(self, t_s: np.ndarray | float) -> np.ndarray:
        """Body rate ``ω(t)`` (rad/s, camera frame at ``t``): (3,) or ``t.shape + (3,)``."""
        phi, dphi = self.turn(np.asarray(t_s, dtype=np.float64))
        return rate_of_turn(phi, dphi)

    def to_dict(self) -> dict:
        """``{"name": ..., **params}`` for a frame's truth."""
        return {"name": self.name, **self.params()}

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.params()})"


class ConstantRate(Profile):
    """A constant body rate ``rate_rad_s`` (3,) about the camera axes: ``A(t) = R(−ω t)·A0``."""

    name = "constant"

    def __init__(self, A0: np.ndarray, rate_rad_s) -> None:
        self.A0 = _attitude(A0)
        self.rate_rad_s = _vector(rate_rad_s, "rate_rad_s")

    def turn(self, t_s):
        t = np.asarray(t_s, dtype=np.float64)[..., None]
        return t * self.rate_rad_s, np.broadcast_to(self.rate_rad_s, t.shape[:-1] + (3,)).copy()

    def attitude(self, t_s):
        return attitude_at(self.A0, self.rate_rad_s, t_s)  # the render's own constant-rate motion

    def rate(self, t_s):
        return np.broadcast_to(self.rate_rad_s, np.shape(t_s) + (3,)).copy()

    def params(self) -> dict:
        return {"rate_rad_s": self.rate_rad_s.tolist()}


class InertialAxis(ConstantRate):
    """``rate_rad_s`` (rad/s, a number; its sign turns the other way) about the fixed ICRS axis
    ``axis_icrs`` (3,): the constant body rate ``rate · A0 · axis`` (module docstring)."""

    name = "inertial-axis"

    def __init__(self, A0: np.ndarray, axis_icrs, rate_rad_s: float) -> None:
        axis = _vector(axis_icrs, "axis_icrs")
        norm = float(np.linalg.norm(axis))
        if not norm > 0:
            raise SimulationError("axis_icrs must be a nonzero vector")
        self.axis_icrs = axis / norm
        self.speed_rad_s = _number(rate_rad_s, "rate_rad_s")
        A0 = _attitude(A0)
        super().__init__(A0, self.speed_rad_s * (A0 @ self.axis_icrs))

    def params(self) -> dict:
        return {"axis_icrs": self.axis_icrs.tolist(), "rate_rad_s": self.speed_rad_s}


class Slew(Profile):
    """A rest-to-rest turn by ``rotation_rad`` (3,), camera axes: accelerate, coast, decelerate
    (module docstring). ``duration_s``, ``coast_rate_rad_s`` and ``ramp_s`` say what it became."""

    name = "slew"

    def __init__(self, A0: np.ndarray, rotation_rad, max_rate_rad_s: float, accel_rad_s2: float, *,
                 start_s: float = 0.0, shape: str = "trapezoid") -> None:
        self.A0 = _attitude(A0)
        self.rotation_rad = _vector(rotation_rad, "rotation_rad")
        self.angle_rad = float(np.linalg.norm(self.rotation_rad))
        if not self.angle_rad > 0:
            raise SimulationError("a slew's rotation must be nonzero")
        if self.angle_rad > math.pi + 1e-12:
            raise SimulationError(f"a slew's rotation must be at most 180 degrees, got "
                                  f"{math.degrees(self.angle_rad):g}")
        self.axis = self.rotation_rad / self.angle_rad
        self.max_rate_rad_s = _number(max_rate_rad_s, "max_rate_rad_s", positive=True)
        self.accel_rad_s2 = _number(accel_rad_s2, "accel_rad_s2", positive=True)
        self.start_s = _number(start_s, "start_s")
        if shape not in SLEW_SHAPES:
            raise unknown_name("slew shape", shape, SLEW_SHAPES)
        self.shape = shape
        # A ramp from rest to the rate v takes T = k·v/a (k = 1, or π/2 for the half cosine whose
        # peak acceleration is a) and turns v·T/2; two ramps must fit in the angle.
        k = 1.0 if shape == "trapezoid" else math.pi / 2
        peak = math.sqrt(self.accel_rad_s2 * self.angle_rad / k)  # the ramps meet at this rate
        v = min(self.max_rate_rad_s, peak)
        self.coast_rate_rad_s = v
        self.ramp_s = k * v / self.accel_rad_s2
        self.coast_s = 0.0 if v == peak else (self.angle_rad - v * self.ramp_s) / v
        self.duration_s = 2 * self.ramp_s + self.coast_s

    @classmethod
    def between(cls, A_from: np.ndarray, A_to: np.ndarray, max_rate_rad_s: float, accel_rad_s2: float,
                **kw) -> Slew:
        """The slew from attitude ``A_from`` to ``A_to`` (the shorter way round)."""
        dA = _attitude(A_to) @ _attitude(A_from).T  # = R(−φ)
        return cls(A_from, -rotation_vector(dA), max_rate_rad_s, accel_rad_s2, **kw)

    def _ramp(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Angle and rate a time ``s`` into a ramp from rest (``0 <= s <= ramp_s``)."""
        v, T = self.coast_rate_rad_s, self.ramp_s
        if self.shape == "trapezoid":
            a = v / T
            return 0.5 * a * s * s, a * s
        x = math.pi * s / T
        return 0.5 * v * (s - T / math.pi * np.sin(x)), 0.5 * v * (1.0 - np.cos(x))

    def turn(self, t_s):
        tau = np.asarray(t_s, dtype=np.float64) - self.start_s
        v, T, C = self.coast_rate_rad_s, self.ramp_s, self.coast_s
        up_angle, up_rate = self._ramp(np.clip(tau, 0.0, T))
        down_angle, down_rate = self._ramp(np.clip(2 * T + C - tau, 0.0, T))
        ramp_angle = self._ramp(np.float64(T))[0]
        angle = np.where(tau <= T, up_angle,
                         np.where(tau <= T + C, ramp_angle + v * (tau - T), self.angle_rad - down_angle))
        rate = np.where(tau <= 0, 0.0, np.where(tau <= T, up_rate, np.where(tau <= T + C, v, down_rate)))
        return angle[..., None] * self.axis, rate[..., None] * self.axis

    def params(self) -> dict:
        return {"rotation_rad": self.rotation_rad.tolist(), "max_rate_rad_s": self.max_rate_rad_s,
                "accel_rad_s2": self.accel_rad_s2, "start_s": self.start_s, "shape": self.shape,
                "duration_s": self.duration_s, "coast_rate_rad_s": self.coast_rate_rad_s}


class Pendulum(Profile):
    """Damped oscillation about ``A0`` on each camera axis (module docstring)."""

    name = "pendulum"

    def __init__(self, A0: np.ndarray, amplitude_rad, period_s: float, damping_ratio: float, *,
                 phase_rad=(0.0, 0.0, 0.0)) -> None:
        self.A0 = _attitude(A0)
        self.amplitude_rad = _vector(amplitude_rad, "amplitude_rad")
        if float(np.linalg.norm(self.amplitude_rad)) > math.pi / 2:
            raise SimulationError("a pendulum's amplitude must be at most 90 degrees")
        self.period_s = _number(period_s, "period_s", positive=True)
        self.damping_ratio = _number(damping_ratio, "damping_ratio", minimum=0.0, below=1.0)
        self.phase_rad = _vector(phase_rad, "phase_rad")
        self.omega_d = 2 * math.pi / self.period_s  # damped angular frequency, rad/s
        self.decay_per_s = self.damping_ratio * self.omega_d / math.sqrt(1.0 - self.damping_ratio**2)

    def turn(self, t_s):
        t = np.asarray(t_s, dtype=np.float64)[..., None]
        arg = self.omega_d * t + self.phase_rad
        envelope = self.amplitude_rad * np.exp(-self.decay_per_s * t)
        sin, cos = np.sin(arg), np.cos(arg)
        return envelope * sin, envelope * (self.omega_d * cos - self.decay_per_s * sin)

    def params(self) -> dict:
        return {"amplitude_rad": self.amplitude_rad.tolist(), "period_s": self.period_s,
                "damping_ratio": self.damping_ratio, "phase_rad": self.phase_rad.tolist()}


#: Attitude profiles by name (:func:`make_profile` builds one).
PROFILES: dict[str, type[Profile]] = {
    "constant": ConstantRate,
    "inertial-axis": InertialAxis,
    "slew": Slew,
    "pendulum": Pendulum,
}


def make_profile(name: str, A0: np.ndarray, **params) -> Profile:
    """The profile ``name`` of :data:`PROFILES` starting at ``A0`` with its parameters (SI units;
    see each class). Unknown names and parameters are a :class:`~skyfix.errors.SimulationError`."""
    try:
        cls = PROFILES[name]
    except (KeyError, TypeError):
        raise unknown_name("motion profile", name, PROFILES) from None
    try:
        return cls(A0, **params)
    except TypeError as exc:  # a missing or unknown parameter
        what = re.sub(r"^\S*__init__[(][)] ", "", str(exc))
        raise SimulationError(f"profile {name!r}: {what}") from None


def profile_of(value: Profile | str | None, A0: np.ndarray, params: Mapping | None = None) -> Profile | None:
    """A Profile from a Profile, or from a name and its parameters (None stays None)."""
    if value is None or isinstance(value, Profile):
        if params:
            raise SimulationError("profile parameters given without a profile name")
        return value
    return make_profile(value, A0, **dict(params or {}))
