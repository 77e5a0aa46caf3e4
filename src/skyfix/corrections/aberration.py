"""Stellar aberration: the directions of stars as a moving observer sees them.

The Earth's barycentric velocity (about 30 km/s) shifts every star by up to 20.5″ toward the
direction of motion; a satellite's orbital velocity adds up to 5″. A star in direction ``p``
seen by an observer moving at ``β = v/c`` appears in the direction of the Lorentz
transformation of its light ray (special relativity, exact):

    p' = normalize(√(1 − β²) p + (1 + p·β / (1 + √(1 − β²))) β)

so the angle θ from the velocity obeys cos θ' = (cos θ + β)/(1 + β cos θ). The first-order
form ``normalize(p + β)`` (thesis 004 §7.5) differs by less than β²: 1e-8 rad, 2 mas, at 30
km/s. ERFA's ``ab`` evaluates this formula (its gravitational term, 1e-12 rad, left out) and is
the engine: about 10 µs for 300 stars, faster than numpy written out.

The Earth's velocity comes from ERFA's ``epv00`` (the VSOP2000-based series astropy's
``builtin`` ephemeris uses; 1900–2100, offline), evaluated once per time and kept
(:func:`earth_state`): about 0.1 ms a call.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np

from skyfix.corrections.observer import SPEED_OF_LIGHT_KM_S
from skyfix.errors import InputError

# erfa is imported in the functions that call it: importing it takes ~150 ms.
__all__ = ["aberrate", "earth_state", "EarthState", "SPEED_OF_LIGHT_KM_S", "AU_KM", "DAY_S"]

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
    import erfa

    beta = np.asarray(velocity_km_s, dtype=np.float64).reshape(3) / SPEED_OF_LIGHT_KM_S
    b2 = float(beta @ beta)
    if not b2 < 1.0:
        raise InputError(f"an observer speed of {np.sqrt(b2) * SPEED_OF_LIGHT_KM_S:.6g} km/s is not "
                         f"below the speed of light ({SPEED_OF_LIGHT_KM_S} km/s)")
    return erfa.ab(np.asarray(vectors, dtype=np.float64), beta, np.inf, np.sqrt(1.0 - b2))
