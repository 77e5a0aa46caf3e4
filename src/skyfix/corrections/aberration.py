"""Stellar aberration: the directions of stars as a moving observer sees them.

The Earth's barycentric velocity (about 30 km/s) shifts every star by up to 20.5″ toward the
direction of motion; a satellite's orbital velocity adds up to 5″. A star in direction ``p``
seen by an observer moving at ``β = v/c`` appears in the direction of the Lorentz
transformation of its light ray (special relativity, exact):

    p' = normalize(√(1 − β²) p + (1 + p·β / (1 + √(1 − β²))) β)

so the angle θ from the velocity obeys cos θ' = (cos θ + β)/(1 + β cos θ). The first-order
form ``normalize(p + β)`` (thesis 004 §7.5) differs by less than β²: 1e-8 rad, 2 mas, at 30
km/s. ERFA's ``ab`` evaluates this formula (its gravitational term, 1e-12 rad, left out); the
engine is the same arithmetic compiled (:mod:`skyfix._kernels.places`, ~1 µs for 300 stars
against ~10 µs through ERFA's Python wrapper), tested against ERFA.

The Earth's velocity comes from ERFA's ``epv00`` (the VSOP2000-based series astropy's
``builtin`` ephemeris uses; 1900–2100, offline), evaluated once per time and kept
(:func:`earth_state`): about 0.1 ms a call.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from skyfix._kernels.places import aberrate_stars
from skyfix.corrections.observer import SPEED_OF_LIGHT_KM_S, check_speed

# erfa is imported in the functions that call it: importing it takes ~150 ms.
__all__ = ["aberrate", "earth_state", "EarthState", "lorentz", "SPEED_OF_LIGHT_KM_S", "AU_KM", "DAY_S"]

AU_KM = 149597870.7
DAY_S = 86400.0
_AU_PER_DAY_TO_KM_S = AU_KM / DAY_S


class EarthState(NamedTuple):
    """The Earth's centre at one time, ICRS axes (ERFA ``epv00``).

    Attributes
    ----------
    velocity_km_s : (3,) float64 — barycentric velocity, km/s.
    barycentric_au : (3,) float64 — barycentric position, au.
    heliocentric_au : (3,) float64 — heliocentric position, au (the Sun is at ``−heliocentric_au``).
    """

    velocity_km_s: np.ndarray
    barycentric_au: np.ndarray
    heliocentric_au: np.ndarray


@lru_cache(maxsize=256)
def _earth_state(jd_tt: float) -> EarthState:
    from skyfix.corrections.ephemeris import earth_ephemeris

    e = earth_ephemeris(jd_tt)
    state = EarthState(e.velocity_au_day * _AU_PER_DAY_TO_KM_S, e.barycentric_au, e.heliocentric_au)
    for a in state:
        a.flags.writeable = False  # cached and shared
    return state


def earth_state(jd_tt: float) -> EarthState:
    """The Earth's barycentric velocity and position at Julian date ``jd_tt`` (TT), cached per
    time (ERFA ``epv00``, 1900–2100: within 13 km and 5 mm/s of JPL DE405; interpolated between
    3-hour nodes to within 3 cm and 10⁻⁵ m/s of it, :mod:`skyfix.corrections.ephemeris`)."""
    return _earth_state(float(jd_tt))


def aberrate(vectors: np.ndarray, velocity_km_s) -> np.ndarray:
    """Apparent directions of ``vectors`` (unit, (N, 3) or (3,)) for an observer moving at
    ``velocity_km_s`` ((3,), km/s, the same axes): the Lorentz form of the module's notes.

    Raises :class:`~skyfix.errors.InputError` for a speed of c or more.

    >>> import numpy as np
    >>> p = aberrate(np.array([1.0, 0.0, 0.0]), [0.0, 30.0, 0.0])
    >>> round(float(np.degrees(np.arctan2(p[1], p[0])) * 3600), 3)  # asin(β) toward +y, arcsec
    20.641
    """
    beta, bm1 = lorentz(velocity_km_s)
    p = np.asarray(vectors, dtype=np.float64)
    return aberrate_stars(np.ascontiguousarray(p.reshape(-1, 3)), beta, bm1).reshape(p.shape)


def lorentz(velocity_km_s, what: str = "an observer speed of") -> tuple[np.ndarray, float]:
    """``β`` (3,), the velocity ``velocity_km_s`` (km/s) in units of c, and ``√(1 − β²)``: what
    ERFA's ``ab`` takes. Raises :class:`~skyfix.errors.InputError` for a speed of c or more
    (``what`` names the speed in it)."""
    v = check_speed(np.asarray(velocity_km_s, dtype=np.float64).reshape(3), what)
    bx, by, bz = (c / SPEED_OF_LIGHT_KM_S for c in v.tolist())
    return np.array([bx, by, bz]), math.sqrt(1.0 - (bx * bx + by * by + bz * bz))
