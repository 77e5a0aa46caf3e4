"""Catalogue directions as the camera sees them at the observation time.

A catalogue position (ICRS, astrometric, at the observation epoch: :meth:`Catalog.at_epoch`)
becomes the direction the camera sees in three steps, ERFA's for a star (``atciqz``):

1. **Parallax** (stars with one, when asked): seen from the observer's barycentric position
   ``o`` (au) a star of parallax ϖ (rad) is at ``normalize(p − ϖ o)``; up to 0.77″ (Proxima).
2. **Light deflection** by the Sun (ERFA ``ldsun``): 1.75″ at the limb, 16 mas at 28°, 4 mas at 90°.
3. **Aberration** by the observer's barycentric velocity (the Earth's plus the observer's own,
   :mod:`skyfix.corrections.aberration`): up to 20.5″ + 5″.

The result is the GCRS direction: astropy's ICRS → GCRS with the same ``obsgeoloc`` and
``obsgeovel`` (tests/corrections/test_aberration.py: 1000 random stars, dates and velocities, within 1 µas).
What depends on the time and the observer alone is computed once (:func:`apparent_frame`, the
ephemeris cached per time); applying it to a solve's few hundred stars is one compiled call
(:func:`apparent_directions`: ERFA's ``ldsun`` and ``ab`` written out in
:mod:`skyfix._kernels.places`, a few µs; ERFA stays the tests' reference).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._kernels.places import apparent_stars
from skyfix.corrections.aberration import AU_KM, earth_state, lorentz
from skyfix.corrections.observer import GEOCENTRE, Observer
from skyfix.errors import InputError
from skyfix.obstime import ObservationTime

__all__ = ["ApparentFrame", "apparent_frame", "apparent_directions"]

_NO_OFFSET = np.zeros(3)  # an observer at the Earth's centre


class ApparentFrame(NamedTuple):
    """What the corrections of one observation need, ICRS axes.

    Attributes
    ----------
    velocity_km_s : (3,) float64 — the observer's barycentric velocity, km/s.
    barycentric_au : (3,) float64 — the observer's barycentric position, au.
    sun_to_observer : (3,) float64 — unit vector from the Sun to the observer.
    sun_distance_au : float — the Sun–observer distance, au.
    beta : (3,) float64 — ``velocity_km_s`` in units of c (:func:`~skyfix.corrections.aberration.lorentz`).
    beta_factor : float — ``√(1 − β²)``.
    """

    velocity_km_s: np.ndarray
    barycentric_au: np.ndarray
    sun_to_observer: np.ndarray
    sun_distance_au: float
    beta: np.ndarray
    beta_factor: float


def apparent_frame(time: ObservationTime, observer: Observer = GEOCENTRE) -> ApparentFrame:
    """The :class:`ApparentFrame` of an observation: the Earth's state at ``time`` (cached per
    time) plus the observer's geocentric position and velocity.

    Raises :class:`~skyfix.errors.InputError` without a time (:data:`skyfix.obstime.NO_TIME`) or
    for a total speed of c or more.
    """
    if not time.known:
        raise InputError("no observation time: aberration and the Sun's deflection need one "
                         "(give --time, or an image with DATE-OBS or EXIF)")
    earth = earth_state(time.jd_tt)
    velocity = earth.velocity_km_s + observer.velocity_km_s
    beta, beta_factor = lorentz(velocity, "the observer's barycentric speed")
    offset = _NO_OFFSET if observer.position_km is None else observer.position_km / AU_KM
    heliocentric = earth.heliocentric_au + offset  # new arrays: the kernels take no read-only ones
    barycentric = earth.barycentric_au + offset
    distance = math.hypot(*heliocentric.tolist())
    return ApparentFrame(velocity, barycentric, heliocentric / distance, distance, beta, beta_factor)


def apparent_directions(vectors: np.ndarray, frame: ApparentFrame,
                        parallax: np.ndarray | None = None) -> np.ndarray:
    """Apparent (GCRS) directions of catalogue ``vectors`` ((N, 3) unit, ICRS, at the
    observation epoch) in ``frame``: parallax (``parallax``, (N,) rad, when given), the Sun's
    light deflection, aberration — the module's three steps."""
    p = np.ascontiguousarray(vectors, dtype=np.float64)
    shape = p.shape
    p = p.reshape(-1, 3)
    parallax = (np.zeros(len(p)) if parallax is None
                else np.ascontiguousarray(parallax, dtype=np.float64).reshape(-1))
    return apparent_stars(p, parallax, frame.barycentric_au, frame.sun_to_observer, frame.sun_distance_au,
                          frame.beta, frame.beta_factor).reshape(shape)
