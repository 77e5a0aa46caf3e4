"""The Sun, the Moon and the Earth's limb from the boresight, and the exclusion angles (issue 24),
against astropy's ``get_body`` (built-in ephemeris: ERFA ``epv00`` and ``moon98``, offline; times
in TT, so no IERS table; ``iers.conf.auto_download`` off)."""

import math

import numpy as np
import pytest
from astropy.utils import iers

from skyfix.corrections import (
    EXCLUSION_DEG,
    BodyAngles,
    Exclusion,
    body_angles,
    body_directions,
    exclusion_for,
    exclusion_warnings,
    observer_from_state,
)
from skyfix.corrections.observer import EARTH_EQUATORIAL_RADIUS_KM
from skyfix.errors import InputError
from skyfix.geometry import angle_between, normalize, radec_to_vector
from skyfix.obstime import NO_TIME, ObservationTime, parse_time

iers.conf.auto_download = False
pytestmark = pytest.mark.filterwarnings("ignore::erfa.ErfaWarning")  # astropy's "dubious year"

ARCSEC = np.radians(1 / 3600)


def astropy_body(name, jd_tt, pos_km=None, vel_km_s=None):
    import astropy.units as u
    from astropy.coordinates import GCRS, CartesianRepresentation, get_body
    from astropy.time import Time

    t = Time(jd_tt, format="jd", scale="tt")
    body = get_body(name, t)  # geocentric GCRS
    if pos_km is not None:
        body = body.transform_to(GCRS(obstime=t, obsgeoloc=CartesianRepresentation(pos_km * u.km),
                                      obsgeovel=CartesianRepresentation(vel_km_s * u.km / u.s)))
    return radec_to_vector(body.ra.rad, body.dec.rad)


def test_sun_and_moon_match_astropy_get_body():
    rng = np.random.default_rng(24)
    worst = {"sun": 0.0, "moon": 0.0, "moon from orbit": 0.0}
    for jd in rng.uniform(2415020.5, 2488069.5, 20):  # 1900–2100
        pos = normalize(rng.normal(size=3)) * rng.uniform(6700.0, 8000.0)
        vel = normalize(rng.normal(size=3)) * 7.5
        t = ObservationTime(float(jd), "test", "")
        geo, orbit = body_directions(t), body_directions(t, observer_from_state(pos, vel))
        for name in ("sun", "moon"):
            worst[name] = max(worst[name], angle_between(getattr(geo, name), astropy_body(name, jd)) / ARCSEC)
        got = angle_between(orbit.moon, astropy_body("moon", jd, pos, vel)) / ARCSEC
        worst["moon from orbit"] = max(worst["moon from orbit"], got)
        assert angle_between(orbit.moon, geo.moon) > math.radians(0.5) * 6700 / 406700  # the Moon's parallax
    assert worst["sun"] < 0.1 and worst["moon"] < 0.1  # measured 0.02″, 0.002″
    assert worst["moon from orbit"] < 1.0  # measured 0.3″: astropy times the light from the geocentre


def test_earth_limb_from_low_orbit():
    r = 7000.0
    observer = observer_from_state([r, 0.0, 0.0], [0.0, 7.5, 0.0])
    t = parse_time("2026-03-21T12:00:00Z")
    radius = math.degrees(math.asin(EARTH_EQUATORIAL_RADIUS_KM / r))
    assert radius == pytest.approx(65.666, abs=1e-3)
    for boresight, limb in (([1.0, 0, 0], 180.0 - radius), ([0, 1.0, 0], 90.0 - radius),
                            ([-1.0, 0, 0], -radius), ([0, 0, 1.0], 90.0 - radius)):
        a = body_angles(np.array(boresight), t, observer)
        assert a.earth_limb_deg == pytest.approx(limb, abs=1e-9)
        assert a.earth_radius_deg == pytest.approx(radius)
    assert math.isnan(body_angles(np.array([1.0, 0, 0]), t).earth_limb_deg)  # no position, no limb


def test_body_angles_are_the_angles_to_the_bodies():
    t = parse_time("2026-03-21T12:00:00Z")
    d = body_directions(t)
    a = body_angles(d.sun, t)
    assert a.sun_deg < 1e-9 and a.moon_deg == pytest.approx(math.degrees(angle_between(d.sun, d.moon)))
    equinox_sun = radec_to_vector(0.0, 0.0)  # near the March equinox the Sun is near RA 0, Dec 0
    assert body_angles(equinox_sun, t).sun_deg < 1.0


def test_exclusion_angles_and_warnings():
    assert exclusion_for("sunsat") == Exclusion(28.1, 28.1, 28.1)  # thesis 004, Eq. 7.26
    assert exclusion_for("generic") == EXCLUSION_DEG == exclusion_for(None)
    angles = BodyAngles(sun_deg=12.0, moon_deg=40.0, earth_limb_deg=-3.0, earth_radius_deg=66.0)
    lines = exclusion_warnings(angles, exclusion_for("sunsat"))
    assert len(lines) == 2 and all("\n" not in line for line in lines)
    assert lines[0].startswith("the Sun is 12.0° from the boresight") and "28.1°" in lines[0]
    assert lines[1].startswith("the Earth's limb is -3.0° from the boresight (on the Earth")
    assert exclusion_warnings(BodyAngles(90.0, 90.0, math.nan, math.nan)) == []
    assert exclusion_warnings(angles, Exclusion(10.0, 10.0, -5.0)) == []


def test_without_a_time_nothing_is_computed():
    with pytest.raises(InputError, match="no observation time"):
        body_angles(np.array([0.0, 0.0, 1.0]), NO_TIME)
