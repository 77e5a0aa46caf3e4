"""Where a catalogue star is seen, per star, compiled: proper motion, parallax, the Sun's light
deflection and aberration — the arithmetic behind :func:`skyfix.catalog.propagate`,
:func:`skyfix.corrections.aberrate` and :func:`skyfix.corrections.apparent_directions`, once.

The deflection and the aberration are ERFA's ``ldsun``/``ld`` and ``ab`` written out (the
formulas of the SOFA/ERFA routines, in their order of operations), so that a solve's few hundred
stars cost a few microseconds instead of the ~40 µs of numpy and ERFA's Python wrappers;
ERFA itself stays the reference (tests/corrections/test_aberration.py, test_places_kernel.py:
within 1e-15 rad of it).
"""

from __future__ import annotations

import math

import numpy as np

from skyfix._jit import njit

__all__ = ["SCHWARZSCHILD_SUN_AU", "aberrate_stars", "apparent_stars", "move_stars", "seen_bodies"]

SCHWARZSCHILD_SUN_AU = 1.97412574336e-8
"""The Sun's Schwarzschild radius 2GM/c² in au (ERFA's ``ERFA_SRS``)."""


@njit(cache=True, inline="always")
def moved(x, y, z, a, d, r):
    """The unit vector ``u = (x, y, z)`` moved by ``a`` east and ``d`` north (radians, proper
    motion times the time) and ``r`` along itself (the distance's relative change), renormalised
    (:func:`skyfix.catalog.propagate`'s straight line). East and north come from the vector
    itself, no angles: ``e = (−y, x, 0) / ρ``, ``n = (−z x, −z y, ρ²) / ρ`` with ``ρ = √(x² + y²)``
    (at a pole, where RA is 0 by convention, ``x/ρ = 1``, ``y/ρ = 0``)."""
    rho = math.hypot(x, y)
    cos_ra, sin_ra = (1.0, 0.0) if rho == 0.0 else (x / rho, y / rho)
    px = x + (-a * sin_ra - d * z * cos_ra + r * x)
    py = y + (a * cos_ra - d * z * sin_ra + r * y)
    pz = z + (d * rho + r * z)
    n = math.sqrt(px * px + py * py + pz * pz)
    return px / n, py / n, pz / n


@njit(cache=True)
def move_stars(vectors, pm_ra, pm_dec, rate, dt):
    """Unit vectors ``vectors`` (N, 3) moved over ``dt`` years by proper motions ``pm_ra``,
    ``pm_dec`` and distance rates ``rate`` ((N,) each, rad/yr and 1/yr); a star that does not
    move keeps its vector bit for bit."""
    out = np.empty_like(vectors)
    for i in range(vectors.shape[0]):
        a, d, r = pm_ra[i] * dt, pm_dec[i] * dt, rate[i] * dt
        if pm_ra[i] == 0.0 and pm_dec[i] == 0.0 and rate[i] == 0.0:
            out[i, 0], out[i, 1], out[i, 2] = vectors[i, 0], vectors[i, 1], vectors[i, 2]
        else:
            out[i, 0], out[i, 1], out[i, 2] = moved(vectors[i, 0], vectors[i, 1], vectors[i, 2], a, d, r)
    return out


@njit(cache=True, inline="always")
def deflected(px, py, pz, e, em):
    """ERFA ``ldsun``: the direction ``p`` bent by the Sun's gravity for an observer at unit vector
    ``e`` from the Sun, ``em`` au away (``ld`` with ``bm = 1``, ``q = p``, and the limit
    ``1e-6 / max(em², 1)``)."""
    em2 = em * em
    dlim = 1e-6 / (em2 if em2 > 1.0 else 1.0)
    qpe0, qpe1, qpe2 = px + e[0], py + e[1], pz + e[2]
    qdqpe = px * qpe0 + py * qpe1 + pz * qpe2
    w = SCHWARZSCHILD_SUN_AU / em / max(qdqpe, dlim)
    eq0, eq1, eq2 = e[1] * pz - e[2] * py, e[2] * px - e[0] * pz, e[0] * py - e[1] * px
    peq0, peq1, peq2 = py * eq2 - pz * eq1, pz * eq0 - px * eq2, px * eq1 - py * eq0
    return px + w * peq0, py + w * peq1, pz + w * peq2


@njit(cache=True, inline="always")
def aberrated(px, py, pz, v, srs_over_s, bm1):
    """ERFA ``ab``: the natural direction ``p`` seen by an observer moving at ``v`` (β, in units
    of c; ``bm1 = √(1 − |v|²)``); ``srs_over_s`` is the Sun's Schwarzschild radius over its
    distance in au (0: ERFA's gravitational term left out)."""
    pdv = px * v[0] + py * v[1] + pz * v[2]
    w1 = 1.0 + pdv / (1.0 + bm1)
    w0 = px * bm1 + w1 * v[0] + srs_over_s * (v[0] - pdv * px)
    w1_ = py * bm1 + w1 * v[1] + srs_over_s * (v[1] - pdv * py)
    w2 = pz * bm1 + w1 * v[2] + srs_over_s * (v[2] - pdv * pz)
    r = math.sqrt(w0 * w0 + w1_ * w1_ + w2 * w2)
    return w0 / r, w1_ / r, w2 / r


@njit(cache=True)
def aberrate_stars(vectors, beta, bm1):
    """:func:`aberrated` for each of ``vectors`` (N, 3), no gravitational term."""
    out = np.empty_like(vectors)
    for i in range(vectors.shape[0]):
        x, y, z = vectors[i, 0], vectors[i, 1], vectors[i, 2]
        out[i, 0], out[i, 1], out[i, 2] = aberrated(x, y, z, beta, 0.0, bm1)
    return out


@njit(cache=True)
def apparent_stars(vectors, parallax, barycentric_au, sun_to_observer, sun_distance_au, beta, bm1):
    """The GCRS directions of catalogue ``vectors`` (N, 3): each moved by its ``parallax`` (N,)
    (rad; 0: none) from the barycentre to ``barycentric_au``, bent by the Sun (:func:`deflected`)
    and aberrated (:func:`aberrated`, no gravitational term) — ERFA's ``atciqz`` steps."""
    out = np.empty_like(vectors)
    for i in range(vectors.shape[0]):
        px, py, pz = vectors[i, 0], vectors[i, 1], vectors[i, 2]
        if parallax[i] != 0.0:
            px -= parallax[i] * barycentric_au[0]
            py -= parallax[i] * barycentric_au[1]
            pz -= parallax[i] * barycentric_au[2]
            n = math.sqrt(px * px + py * py + pz * pz)
            px, py, pz = px / n, py / n, pz / n
        px, py, pz = deflected(px, py, pz, sun_to_observer, sun_distance_au)
        out[i, 0], out[i, 1], out[i, 2] = aberrated(px, py, pz, beta, 0.0, bm1)
    return out


@njit(cache=True)
def seen_bodies(heliocentric, offset, earth_velocity, moon, beta, bm1, light_days_per_au):
    """The Sun's and the Moon's apparent directions (2, 3) from an observer at ``heliocentric``
    (3,), au, ``offset`` (3,) au from the Earth's centre, given the Earth's barycentric velocity
    (au/day) and the Moon's geocentric position and velocity ``moon`` (2, 3) (au, au/day; ERFA
    ``moon98``): each body taken back to where it was when its light left it
    (``light_days_per_au`` days of light per au of distance; the Sun's velocity taken as 0, and
    one step: a path bends negligibly in the light time), then aberrated by the observer's
    velocity ``beta`` (:func:`aberrated`, no gravitational term)."""
    out = np.empty((2, 3))
    for i in range(2):
        d = np.empty(3)
        v = np.zeros(3)
        for k in range(3):
            if i == 0:  # the Sun
                d[k] = -heliocentric[k]
            else:
                d[k] = moon[0, k] - offset[k]
                v[k] = earth_velocity[k] + moon[1, k]
        t = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) * light_days_per_au
        dx, dy, dz = d[0] - t * v[0], d[1] - t * v[1], d[2] - t * v[2]
        n = math.sqrt(dx * dx + dy * dy + dz * dz)
        out[i, 0], out[i, 1], out[i, 2] = aberrated(dx / n, dy / n, dz / n, beta, 0.0, bm1)
    return out
