"""The compiled per-star corrections (skyfix._kernels.places) against ERFA's own routines."""

import erfa
import numpy as np

from skyfix.catalog import propagate
from skyfix.corrections import ApparentFrame, aberrate, apparent_directions
from skyfix.corrections.aberration import lorentz


def _unit(rng, n):
    p = rng.normal(size=(n, 3))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def test_aberration_is_erfas_ab_bit_for_bit():
    rng = np.random.default_rng(7)
    p = _unit(rng, 2000)
    for speed in (0.0, 7.6, 30.0, 42.0, 3000.0):
        v = _unit(rng, 1)[0] * speed
        beta, bm1 = lorentz(v)
        assert np.array_equal(aberrate(p, v), erfa.ab(p, beta, np.inf, bm1))
        assert np.array_equal(aberrate(p[0], v), erfa.ab(p[0], beta, np.inf, bm1))  # one vector, (3,)


def test_apparent_directions_are_erfas_ldsun_then_ab():
    rng = np.random.default_rng(8)
    p = _unit(rng, 2000)
    parallax = np.where(rng.random(2000) < 0.5, rng.random(2000) * 4e-6, 0.0)  # up to 0.8″
    for em in (0.98, 1.0167, 1.5):
        e = _unit(rng, 1)[0]
        velocity = rng.normal(size=3) * 30.0
        beta, bm1 = lorentz(velocity)
        frame = ApparentFrame(velocity, rng.normal(size=3), e, em, beta, bm1)
        shifted = p - parallax[:, None] * frame.barycentric_au
        q = shifted / np.linalg.norm(shifted, axis=1, keepdims=True)
        want = erfa.ab(erfa.ldsun(q, e, em), beta, np.inf, bm1)
        got = apparent_directions(p, frame, parallax)
        assert np.abs(got - want).max() < 1e-15  # ~2e-10″: the same arithmetic, up to one rounding
        assert np.abs(np.arcsin(np.linalg.norm(np.cross(got, p), axis=1))).max() > 9e-5  # 19″ moved


def test_proper_motion_keeps_still_stars_and_matches_the_straight_line():
    rng = np.random.default_rng(9)
    p = _unit(rng, 500)
    pm_ra, pm_dec = rng.normal(size=500) * 5e-6, rng.normal(size=500) * 5e-6
    pm_ra[:100] = pm_dec[:100] = 0.0
    moved = propagate(p, pm_ra, pm_dec, 35.0)
    assert np.array_equal(moved[:100], p[:100])
    # the step east and north, renormalised, written out with numpy
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    rho = np.hypot(x, y)
    east = np.stack([-y / rho, x / rho, np.zeros(500)], axis=1)
    north = np.stack([-z * x / rho, -z * y / rho, rho], axis=1)
    want = p + 35.0 * (pm_ra[:, None] * east + pm_dec[:, None] * north)
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    assert np.abs(moved - want).max() < 1e-15
    pole = propagate(np.array([[0.0, 0.0, 1.0]]), np.array([1e-6]), np.array([0.0]), 10.0)
    assert np.allclose(pole, [[0.0, 1e-5, 1.0]], atol=1e-10)  # at a pole, east is +y (RA 0)
