"""The Sun, the Moon and the Earth's limb seen from the camera, and their exclusion angles.

A bright body near the field floods the frame with stray light (thesis 004 §7.6): a star
tracker reports how far each is from its boresight and warns inside its exclusion angles.

- **Sun**: the Earth's heliocentric position from ERFA ``epv00`` (:func:`~skyfix.corrections.
  aberration.earth_state`, cached per time), reversed.
- **Moon**: ERFA ``moon98`` (Meeus's series; the one astropy's built-in ephemeris uses), about
  10″ from JPL's.
- Both are seen from the observer's position when it is known (the Moon moves by up to 1° for a
  satellite in low orbit), where they were when the light left them (light time: 1.3 s for the
  Moon, in which the Earth and the Moon move 40 km together), and aberrated by the observer's
  barycentric velocity, as astropy's ``get_body`` gives them in GCRS (tests/corrections/test_bodies.py:
  within 0.1″ from the geocentre, 1″ from low orbit).
- **Earth's limb** (with an observer position only): the Earth is a sphere of the equatorial
  radius seen from ``r``, centred on the nadir ``−r/|r|`` with angular radius ``asin(R/|r|)``;
  the boresight's angle from the limb is its angle from the nadir minus that radius (negative:
  the boresight is on the Earth). The flattening (21 km) moves the limb by at most 0.2° from
  low orbit.

Exclusion angles (:class:`Exclusion`) come from a preset's ``[exclusion]`` table
(:func:`exclusion_for`), else :data:`EXCLUSION_DEG`: thesis 004's baffle angle, 28.1° (Eq. 7.26:
no light from outside it reaches the Sunsat lens directly), for all three bodies.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._kernels.places import seen_bodies
from skyfix.corrections.aberration import AU_KM, DAY_S, earth_state, lorentz
from skyfix.corrections.observer import EARTH_EQUATORIAL_RADIUS_KM, GEOCENTRE, SPEED_OF_LIGHT_KM_S, Observer
from skyfix.errors import InputError
from skyfix.obstime import ObservationTime

# erfa is imported in the functions that call it: importing it takes ~150 ms.
__all__ = ["BodyDirections", "BodyAngles", "Exclusion", "EXCLUSION_DEG", "body_directions",
           "body_angles", "angles_from_directions", "exclusion_for", "exclusion_warnings"]


class BodyDirections(NamedTuple):
    """Apparent directions from the observer, GCRS (= ICRS) axes.

    Attributes
    ----------
    sun, moon : (3,) float64 — unit vectors.
    nadir : (3,) float64 or None — unit vector to the Earth's centre (None: no observer position).
    earth_radius_rad : float — the Earth's angular radius, rad (NaN: no observer position).
    """

    sun: np.ndarray
    moon: np.ndarray
    nadir: np.ndarray | None
    earth_radius_rad: float


class BodyAngles(NamedTuple):
    """Angles from the boresight, degrees.

    Attributes
    ----------
    sun_deg, moon_deg : float — to the centre of the Sun and of the Moon.
    earth_limb_deg : float — to the nearest point of the Earth's limb; negative when the
        boresight is on the Earth; NaN without an observer position.
    earth_radius_deg : float — the Earth's angular radius (NaN without an observer position).
    """

    sun_deg: float
    moon_deg: float
    earth_limb_deg: float
    earth_radius_deg: float


class Exclusion(NamedTuple):
    """Exclusion angles from the boresight, degrees: a body closer than its angle is warned of."""

    sun_deg: float
    moon_deg: float
    earth_limb_deg: float


EXCLUSION_DEG = Exclusion(28.1, 28.1, 28.1)
"""Default exclusion angles: thesis 004's baffle angle (§7.6, Eq. 7.26), for every bright body."""

_NO_OFFSET = np.zeros(3)  # an observer at the Earth's centre (the kernels never write it)
_NAMES = {"sun_deg": "the Sun", "moon_deg": "the Moon", "earth_limb_deg": "the Earth's limb"}


def body_directions(time: ObservationTime, observer: Observer = GEOCENTRE) -> BodyDirections:
    """The Sun's and Moon's apparent directions and the Earth's nadir and angular radius from
    ``observer`` at ``time`` (see the module's notes). An :class:`~skyfix.errors.InputError`
    without a time."""
    if not time.known:
        raise InputError("no observation time: the Sun's and the Moon's directions need one "
                         "(give --time, or an image with DATE-OBS or EXIF)")
    import erfa

    jd = time.jd_tt
    earth = earth_state(jd)
    day = math.floor(jd - 0.5) + 0.5
    moon = erfa.moon98(day, jd - day)[None].view(np.float64).reshape(2, 3)  # geocentric: au, au/day
    # The Sun and the Moon seen from the observer where they were when the light that arrives at
    # ``jd`` left them (the Sun's barycentric motion, at most 15 m/s, moves it 7 km in the light's
    # 8.3 minutes, 0.01″; the Moon's path bends by 2 m in its 1.3 s, so one ephemeris call serves),
    # aberrated by the observer's barycentric velocity.
    offset = _NO_OFFSET if observer.position_km is None else observer.position_km / AU_KM
    beta, beta_factor = lorentz(earth.velocity_km_s + observer.velocity_km_s)
    sun, moon_dir = seen_bodies(earth.heliocentric_au + offset, offset, earth.velocity_km_s * (DAY_S / AU_KM),
                                moon, beta, beta_factor, AU_KM / SPEED_OF_LIGHT_KM_S / DAY_S)
    if observer.position_km is None:
        return BodyDirections(sun, moon_dir, None, math.nan)
    distance = float(np.linalg.norm(observer.position_km))
    radius = math.asin(min(1.0, EARTH_EQUATORIAL_RADIUS_KM / distance))
    return BodyDirections(sun, moon_dir, -observer.position_km / distance, radius)


def body_angles(boresight: np.ndarray, time: ObservationTime, observer: Observer = GEOCENTRE) -> BodyAngles:
    """The angles of the Sun, the Moon and the Earth's limb from ``boresight`` (ICRS unit vector,
    ``A_icrs_to_cam[2]``) at ``time`` seen from ``observer``."""
    return angles_from_directions(boresight, body_directions(time, observer))


def angles_from_directions(boresight: np.ndarray, d: BodyDirections) -> BodyAngles:
    """:func:`body_angles` from directions already found (:func:`body_directions`): a tracker's
    frames, a few seconds apart, reuse one set (the Moon moves 0.5″ a second)."""
    b = np.asarray(boresight, dtype=np.float64).reshape(3).tolist()
    limb = radius = math.nan
    if d.nadir is not None:
        radius = math.degrees(d.earth_radius_rad)
        limb = _angle_deg(b, d.nadir) - radius
    return BodyAngles(_angle_deg(b, d.sun), _angle_deg(b, d.moon), limb, radius)


def _angle_deg(b: list[float], d: np.ndarray) -> float:
    """The angle (degrees) between ``b`` and ``d``, ``atan2(|b × d|, b · d)``: the formula of
    :func:`skyfix.geometry.angle_between` for one pair, in Python floats (a tracker's frame asks
    for three: numpy's cross product costs 20 µs a call, this 1)."""
    x, y, z = b
    u, v, w = d.tolist()
    cx, cy, cz = y * w - z * v, z * u - x * w, x * v - y * u
    return math.degrees(math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), x * u + y * v + z * w))


def exclusion_for(preset: str | None = None) -> Exclusion:
    """The exclusion angles of camera preset ``preset``: its ``[exclusion]`` table's
    ``sun_deg``, ``moon_deg``, ``earth_limb_deg``, each defaulting to :data:`EXCLUSION_DEG`'s
    (all of them for None)."""
    if preset is None:
        return EXCLUSION_DEG
    from skyfix.simulate.presets import load_preset

    table = load_preset(preset).get("exclusion", {})
    unknown = set(table) - set(Exclusion._fields)
    if unknown:
        raise InputError(f"preset {preset!r}: unknown [exclusion] keys {sorted(unknown)}; "
                         f"known: {', '.join(Exclusion._fields)}")
    values = EXCLUSION_DEG._replace(**table)
    for name, value in zip(Exclusion._fields, values, strict=True):
        if not (isinstance(value, (int, float)) and 0.0 <= value <= 180.0):
            raise InputError(f"preset {preset!r}: [exclusion] {name} must be 0–180 degrees, got {value!r}")
    return Exclusion(*(float(v) for v in values))


def exclusion_warnings(angles: BodyAngles, exclusion: Exclusion = EXCLUSION_DEG) -> list[str]:
    """One line for each body closer to the boresight than its exclusion angle (none: [])."""
    lines = []
    for name, limit in zip(Exclusion._fields, exclusion, strict=True):
        angle = getattr(angles, name)
        if math.isfinite(angle) and angle < limit:
            where = "on the Earth, " if name == "earth_limb_deg" and angle < 0 else ""
            lines.append(f"{_NAMES[name]} is {angle:.1f}° from the boresight ({where}inside its "
                         f"{limit:g}° exclusion angle): stray light may hide the stars")
    return lines
