"""Corrections between the catalogue's directions and the directions a camera sees (issue 24).

- :mod:`~skyfix.corrections.observer`: the camera's geocentric position and velocity
  (:class:`Observer`, from ``--velocity-kms`` or an orbit state).
- :mod:`~skyfix.corrections.aberration`: the Earth's barycentric state (ERFA ``epv00``, cached per
  time) and the relativistic aberration of directions (:func:`aberrate`).
- :mod:`~skyfix.corrections.apparent`: catalogue directions as the camera sees them (parallax, the
  Sun's light deflection, aberration): :func:`apparent_frame` once per observation, then
  :func:`apparent_directions` per set of stars.
- :mod:`~skyfix.corrections.bodies`: the Sun, the Moon and the Earth's limb from the boresight,
  and the exclusion angles.
- :mod:`~skyfix.corrections.refraction`: a camera on the ground — sites, weather, refraction per
  star, Alt/Az and JNow places (docs/frames-and-refraction.md).

The time comes from :mod:`skyfix.obstime`; docs/time-and-corrections.md has the numbers.
Nothing here downloads anything or reads IERS tables: the ephemerides are ERFA's built-in series.

The names below load their modules on first use (as :mod:`skyfix.track`'s): a solve with no
observation time imports the observer and the bright bodies (the exclusion angles) but not the
apparent places.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from skyfix.corrections.aberration import EarthState, aberrate, earth_state
    from skyfix.corrections.apparent import ApparentFrame, apparent_directions, apparent_frame
    from skyfix.corrections.bodies import (
        EXCLUSION_DEG,
        BodyAngles,
        BodyDirections,
        Exclusion,
        body_angles,
        body_directions,
        exclusion_for,
        exclusion_warnings,
    )
    from skyfix.corrections.observer import GEOCENTRE, Observer, observer_from_state, parse_velocity

__all__ = ["EarthState", "aberrate", "earth_state", "ApparentFrame", "apparent_directions", "apparent_frame",
           "EXCLUSION_DEG", "BodyAngles", "BodyDirections", "Exclusion", "body_angles", "body_directions",
           "exclusion_for", "exclusion_warnings", "GEOCENTRE", "Observer", "observer_from_state",
           "parse_velocity"]

_MODULES = {
    "skyfix.corrections.aberration": ("EarthState", "aberrate", "earth_state"),
    "skyfix.corrections.apparent": ("ApparentFrame", "apparent_directions", "apparent_frame"),
    "skyfix.corrections.bodies": ("EXCLUSION_DEG", "BodyAngles", "BodyDirections", "Exclusion", "body_angles",
                                  "body_directions", "exclusion_for", "exclusion_warnings"),
    "skyfix.corrections.observer": ("GEOCENTRE", "Observer", "observer_from_state", "parse_velocity"),
}
_LAZY = {name: module for module, names in _MODULES.items() for name in names}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'skyfix.corrections' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
