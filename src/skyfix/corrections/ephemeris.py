"""The Earth's ERFA ephemeris at any time from a few calls: cubic Hermite interpolation.

Every image has its own time, and ERFA's ``epv00`` costs 60–100 µs a call — a third of what a
time adds to a solve. The Earth moves smoothly on the scale of hours, so ``epv00`` is evaluated at
nodes every :data:`NODE_DAYS` (3 h) of TT, each interval's cubic cached, and the state at a time
interpolated with the cubic that matches position and velocity at both ends (Hermite). Its error,
``h⁴/384·|x⁗|``, is below 3 cm and 10⁻⁵ m/s for the Earth's orbit with its monthly wobble about
the Earth–Moon barycentre — far inside ``epv00``'s own accuracy (13 km, 5 mm/s against JPL
DE405); ``tests/corrections/test_ephemeris.py`` checks it against ``epv00`` called at the time
itself. A night of frames, or a tracker's, then calls ERFA a few times in all. (The Moon's
``moon98`` costs 11 µs, no more than the interpolation: it is called directly.)
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import NamedTuple

import numpy as np

__all__ = ["NODE_DAYS", "EarthEphemeris", "earth_ephemeris", "hermite_weights"]

#: Spacing of the interpolation nodes, days of TT (a power of two: every node is exact in float64).
NODE_DAYS = 0.125


class EarthEphemeris(NamedTuple):
    """The Earth's state from ``epv00`` (BCRS axes): au and au/day, (3,) each."""

    barycentric_au: np.ndarray
    velocity_au_day: np.ndarray  #: barycentric
    heliocentric_au: np.ndarray


def hermite_weights(s: float) -> tuple[np.ndarray, np.ndarray]:
    """The cubic Hermite basis at the fraction ``s`` ∈ [0, 1] of an interval, for the rows
    ``[x₀, h·ẋ₀, x₁, h·ẋ₁]``: the weights of the value (4,) and of its derivative times ``h`` (4,)."""
    s2, s3 = s * s, s * s * s
    return (np.array([2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, 3 * s2 - 2 * s3, s3 - s2]),
            np.array([6 * s2 - 6 * s, 3 * s2 - 4 * s + 1, 6 * s - 6 * s2, 3 * s2 - 2 * s]))


@lru_cache(maxsize=64)
def _node(node: float) -> np.ndarray:
    """``epv00`` at a node: rows position, velocity; columns barycentric (3), heliocentric (3)."""
    import erfa

    day = math.floor(node - 0.5) + 0.5
    pvh, pvb = erfa.epv00(day, node - day)  # TDB wanted; TT differs by < 1.7 ms
    return np.array([[*pvb[0], *pvh[0]], [*pvb[1], *pvh[1]]])


@lru_cache(maxsize=64)
def _interval(node: float) -> np.ndarray:
    """The rows ``[x₀, h·ẋ₀, x₁, h·ẋ₁]`` (4, 6) of the interval starting at ``node``."""
    a, b = _node(node), _node(node + NODE_DAYS)
    return np.array([a[0], NODE_DAYS * a[1], b[0], NODE_DAYS * b[1]])


def earth_ephemeris(jd_tt: float) -> EarthEphemeris:
    """The Earth's barycentric position and velocity and its heliocentric position at ``jd_tt``
    (ERFA ``epv00``, interpolated: the module text)."""
    jd_tt = float(jd_tt)
    node = math.floor(jd_tt / NODE_DAYS) * NODE_DAYS
    value, slope = hermite_weights((jd_tt - node) / NODE_DAYS)
    rows = _interval(node)
    x = value @ rows
    v = (slope @ rows[:, :3]) / NODE_DAYS
    return EarthEphemeris(x[:3], v, x[3:])
