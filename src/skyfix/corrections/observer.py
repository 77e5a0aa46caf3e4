"""Where the camera is and how it moves relative to the Earth's centre.

An :class:`Observer` holds a geocentric position (km) and velocity (km/s) in GCRS axes, which
are ICRS's (GCRS is the ICRS seen from the geocentre: no rotation between them). The velocity is
added to the Earth's barycentric velocity for aberration (:mod:`skyfix.corrections.apparent`);
the position moves the Moon and the Sun by their parallax and places the Earth's limb
(:mod:`skyfix.corrections.bodies`). Without one the observer is at the geocentre, at rest.

Made from ``--velocity-kms vx,vy,vz`` (:func:`parse_velocity`), with ``--position-km x,y,z``
too (:func:`parse_state`), or from an orbit state (:func:`observer_from_state`, e.g. a
propagated orbit's GCRS/J2000 position and velocity; J2000 mean-equator axes differ from GCRS's
by 23 mas, nothing here). A TLE is not read: no SGP4 library is installed (propagate it elsewhere
and pass the state).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix.errors import InputError

__all__ = ["Observer", "GEOCENTRE", "parse_velocity", "parse_state", "observer_from_state", "check_speed",
           "SPEED_OF_LIGHT_KM_S", "EARTH_EQUATORIAL_RADIUS_KM", "EARTH_POLAR_RADIUS_KM"]

SPEED_OF_LIGHT_KM_S = 299792.458
EARTH_EQUATORIAL_RADIUS_KM = 6378.137  # WGS 84
EARTH_POLAR_RADIUS_KM = 6356.752


class Observer(NamedTuple):
    """The camera's geocentric state, GCRS (= ICRS) axes.

    Attributes
    ----------
    position_km : (3,) float64 or None — from the Earth's centre, km (None: not given; the
        Earth's limb is then unknown).
    velocity_km_s : (3,) float64 — relative to the Earth's centre, km/s.
    source : str — where it came from: ``"--velocity-kms"``, ``"orbit state"``, ``"geocentre"``.
    """

    position_km: np.ndarray | None
    velocity_km_s: np.ndarray
    source: str = "orbit state"


GEOCENTRE = Observer(None, np.zeros(3), "geocentre")
"""An observer at the Earth's centre, at rest there (the corrections of the Earth's motion alone)."""


def _vector(value, what: str) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be three numbers, got {value!r}") from None
    if not np.all(np.isfinite(v)):
        raise InputError(f"{what} must be three finite numbers, got {value!r}")
    return v


def check_speed(v: np.ndarray, what: str) -> np.ndarray:
    """``v`` (km/s) if its length is below c, else an :class:`~skyfix.errors.InputError` naming ``what``."""
    speed = math.hypot(*np.ravel(v).tolist())
    if speed >= SPEED_OF_LIGHT_KM_S:
        raise InputError(f"{what} {speed:.6g} km/s is not below the speed of light "
                         f"({SPEED_OF_LIGHT_KM_S} km/s)")
    return v


def observer_from_state(position_km, velocity_km_s, source: str = "orbit state") -> Observer:
    """An :class:`Observer` from a geocentric position (km; None if unknown) and velocity (km/s),
    GCRS axes. Raises :class:`~skyfix.errors.InputError` for a velocity of c or more, or a
    position inside the Earth (below its polar radius)."""
    v = check_speed(_vector(velocity_km_s, "the observer's velocity"), "the observer's speed")
    if position_km is None:
        return Observer(None, v, source)
    r = _vector(position_km, "the observer's position")
    if float(np.linalg.norm(r)) < EARTH_POLAR_RADIUS_KM:
        raise InputError(f"the observer's position is {np.linalg.norm(r):.1f} km from the Earth's centre, "
                         f"inside the Earth (polar radius {EARTH_POLAR_RADIUS_KM} km); give it in km")
    return Observer(r, v, source)


def parse_velocity(text: str) -> Observer:
    """The :class:`Observer` of ``--velocity-kms vx,vy,vz``: a velocity relative to the Earth's
    centre, km/s, GCRS axes (position unknown).

    >>> parse_velocity("7.5,0,-0.2").velocity_km_s.tolist()
    [7.5, 0.0, -0.2]
    """
    return observer_from_state(None, _three_numbers(text, "--velocity-kms", "vx,vy,vz in km/s"),
                               "--velocity-kms")


def parse_state(velocity_text: str, position_text: str) -> Observer:
    """The :class:`Observer` of ``--velocity-kms vx,vy,vz --position-km x,y,z``: the camera's
    geocentric state, GCRS axes — what the orbit frame (:func:`skyfix.frames.orbit_frame`) and
    the Earth's limb need. A position inside the Earth is an :class:`~skyfix.errors.InputError`.

    >>> parse_state("0,7.5,0", "6878,0,0").position_km.tolist()
    [6878.0, 0.0, 0.0]
    """
    v = _three_numbers(velocity_text, "--velocity-kms", "vx,vy,vz in km/s")
    r = _three_numbers(position_text, "--position-km", "x,y,z in km from the Earth's centre")
    return observer_from_state(r, v, "--velocity-kms, --position-km")


def _three_numbers(text: str, flag: str, what: str) -> list[float]:
    """Three finite numbers ``a,b,c`` of the option ``flag``, else an InputError naming it."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        numbers = [float(p) for p in parts]
    except ValueError:
        numbers = []
    if len(numbers) != 3 or not all(math.isfinite(x) for x in numbers):
        raise InputError(f"{flag} takes three numbers {what} (GCRS axes), got {text!r}")
    return numbers
