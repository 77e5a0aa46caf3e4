"""The Earth's interpolated ephemeris against ERFA's epv00 called at the time itself."""

import math

import erfa
import numpy as np
import pytest

from skyfix.corrections.aberration import earth_state
from skyfix.corrections.ephemeris import NODE_DAYS, earth_ephemeris, hermite_weights

AU_M = 149597870700.0
DAY_S = 86400.0


def _epv00(jd: float):
    day = math.floor(jd - 0.5) + 0.5
    return erfa.epv00(day, jd - day)


def test_within_3_cm_and_1e_5_m_per_s_of_epv00_over_two_centuries():
    rng = np.random.default_rng(1)
    times = np.concatenate([2451545.0 + rng.uniform(-36500.0, 36500.0, 1500),
                            2461000.0 + NODE_DAYS * np.arange(-2, 3)])  # nodes themselves too
    for jd in times:
        pvh, pvb = _epv00(float(jd))
        e = earth_ephemeris(float(jd))
        assert np.abs(e.barycentric_au - pvb[0]).max() * AU_M < 0.03
        assert np.abs(e.heliocentric_au - pvh[0]).max() * AU_M < 0.03
        assert np.abs(e.velocity_au_day - pvb[1]).max() * AU_M / DAY_S < 1e-5


def test_earth_state_is_the_interpolated_ephemeris_in_km_per_s():
    jd = 2461008.3172
    pvh, pvb = _epv00(jd)
    s = earth_state(jd)
    assert s.velocity_km_s == pytest.approx(np.asarray(pvb[1]) * AU_M / 1e3 / DAY_S, abs=1e-8)
    assert s.barycentric_au == pytest.approx(pvb[0], abs=1e-12)


@pytest.mark.parametrize("s", [0.0, 0.3, 1.0])
def test_hermite_weights_reproduce_a_cubic(s):
    # x(t) = 1 + 2t − t² + 0.5t³ on [0, h]: the Hermite cubic is exact for it
    h = 0.125

    def x(t):
        return 1 + 2 * t - t * t + 0.5 * t**3

    def dx(t):
        return 2 - 2 * t + 1.5 * t * t

    rows = np.array([x(0.0), h * dx(0.0), x(h), h * dx(h)])
    value, slope = hermite_weights(s)
    assert value @ rows == pytest.approx(x(s * h), abs=1e-15)
    assert slope @ rows / h == pytest.approx(dx(s * h), abs=1e-14)
