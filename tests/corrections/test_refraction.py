"""A camera on the ground (skyfix.corrections.refraction): ERFA's engine against astropy's AltAz
and ERFA's own atco13, thesis 003's Bennett formula and its corrected sign, refraction per star,
the attitude fitted to observed directions, the boresight's places, bad input, speed.

Measured (2024-03-20 04:00 UTC, 40.7° N 111.8° W 1400 m, 850 hPa 10 °C): against astropy's ICRS →
AltAz with the same UT1 − UTC and polar motion, 0.2 mas above 15° altitude and 0.6 mas above 5°
(the 1″ the issue asks); JNow against astropy's topocentric TETE 1e-7″.
"""

from __future__ import annotations

import math
import time

import erfa
import numpy as np
import pytest

from skyfix.attitude import solve_attitude
from skyfix.corrections import refraction as rf
from skyfix.errors import InputError
from skyfix.geometry import angle_between, attitude_from_radec_roll, vector_to_radec

ARCSEC = math.radians(1.0 / 3600.0)
SITE = rf.Site(40.7, -111.8, 1400.0)
WEATHER = rf.Weather(10.0, 850.0, 0.5)
JD_UTC = sum(erfa.dtf2d("UTC", 2024, 3, 20, 4, 0, 0.0))


def _random_vectors(n: int, seed: int = 1) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _enu(alt_deg: np.ndarray, az_deg: np.ndarray) -> np.ndarray:
    alt, az = np.radians(alt_deg), np.radians(az_deg)
    return np.stack([np.cos(alt) * np.sin(az), np.cos(alt) * np.cos(az), np.sin(alt)], axis=-1)


@pytest.fixture(scope="module")
def astropy_time():
    """The test time in astropy, with its bundled IERS table only (never a download)."""
    from astropy.time import Time
    from astropy.utils import iers

    with iers.conf.set_temp("auto_download", False):
        t = Time("2024-03-20T04:00:00", scale="utc")
        dut1 = float(t.delta_ut1_utc)
        xp, yp = iers.earth_orientation_table.get().pm_xy(t)
        yield t, dut1, (float(xp.to_value("arcsec")), float(yp.to_value("arcsec")))


# --- Bennett's formula (thesis 003 Eq. 5.1, §5.10) ---------------------------------------------------
def test_bennett_reproduces_thesis_003():
    # 101 kPa, 10 °C: 9.883′ at 5°, 1.1848′ at 40° (§5.10); the seed's table at 10°–60°
    assert rf.bennett_refraction_arcmin(5.0) == pytest.approx(9.883, abs=5e-4)
    assert rf.bennett_refraction_arcmin(40.0) == pytest.approx(1.1848, abs=5e-5)
    table = {10: 5.39, 20: 2.70, 30: 1.72, 45: 0.99, 60: 0.57}
    got = rf.bennett_refraction_arcmin(np.array(list(table), float))
    assert np.allclose(got, list(table.values()), atol=0.006)
    # ~1 % per 0.9 kPa and ~1 % per 3 °C (§2.6)
    assert rf.bennett_refraction_arcmin(40.0, 1019.0) / rf.bennett_refraction_arcmin(40.0) == pytest.approx(
        1.0089, abs=1e-4)
    assert rf.bennett_refraction_arcmin(40.0, 1010.0, 13.0) / rf.bennett_refraction_arcmin(40.0) == \
        pytest.approx(283 / 286, abs=1e-12)


def test_bennett_option_raises_stars_by_the_thesis_values():
    r = rf.Refraction.for_weather(rf.Weather(10.0, 1010.0), "bennett")
    # a star seen at 5° and at 40° lies 9.883′ and 1.1848′ lower (the seed's corrected sign)
    seen = _enu(np.array([5.0, 40.0]), np.array([30.0, 200.0]))
    true = rf.unrefract_enu(seen, r)
    drop_arcmin = np.degrees(np.arcsin(seen[:, 2]) - np.arcsin(true[:, 2])) * 60
    assert drop_arcmin == pytest.approx([9.8831, 1.18482], abs=1e-4)
    assert np.degrees(np.arctan2(true[:, 0], true[:, 1])) % 360 == pytest.approx([30.0, 200.0], abs=1e-12)
    # and the forward direction puts the true place back where it is seen, to 1e-11 rad
    assert np.max(angle_between(rf.refract_enu(true, r), seen)) < 1e-11
    # the printed Eq. 5.5 (rotation about t = v × z by +ζ) would have raised the apparent star
    v, z = seen[0], np.array([0.0, 0.0, 1.0])
    t = np.cross(v, z) / np.linalg.norm(np.cross(v, z))
    zeta = math.radians(9.8831 / 60)
    printed = v * math.cos(zeta) + np.cross(t, v) * math.sin(zeta) + t * (t @ v) * (1 - math.cos(zeta))
    assert math.degrees(math.asin(printed[2])) == pytest.approx(5.0 + 9.8831 / 60, abs=1e-6)


def test_bennett_and_erfa_models_agree_above_15_degrees():
    # two models of the same air (1010 hPa, 10 °C, RH 0.5, 0.55 µm): Bennett's is 2–3 % above
    # ERFA's, 5.0″ at 15°, 1.7″ at 45° (thesis 003 gives Bennett 4.2″ = 0.07′ of accuracy)
    w = rf.Weather(10.0, 1010.0, 0.5)
    alt = np.radians(np.linspace(15.0, 85.0, 71))
    lift = {m: rf.Refraction.for_weather(w, m).lift_rad(np.sin(alt), np.cos(alt))
            for m in ("erfa", "bennett")}
    diff = (lift["bennett"] - lift["erfa"]) / ARCSEC
    assert diff[0] == pytest.approx(4.99, abs=0.01) and diff[30] == pytest.approx(1.73, abs=0.01)
    assert np.all(diff > 0) and np.all(diff < 5.0)
    assert np.all(lift["bennett"] / lift["erfa"] < 1.031)
    assert lift["erfa"][30] / ARCSEC == pytest.approx(57.92, abs=0.01)  # 45°


# --- ERFA's engine against astropy and atco13 --------------------------------------------------------
def test_observed_directions_match_astropy_altaz(astropy_time):
    import astropy.units as u
    from astropy.coordinates import AltAz, EarthLocation, SkyCoord

    t, dut1, pm = astropy_time
    frame = rf.ground_frame(SITE, t.jd, WEATHER, dut1_s=dut1, polar_motion_arcsec=pm)
    v = _random_vectors(1000)
    ra, dec = vector_to_radec(v)
    loc = EarthLocation.from_geodetic(SITE.lon_deg * u.deg, SITE.lat_deg * u.deg, SITE.height_m * u.m)
    aa = SkyCoord(ra * u.rad, dec * u.rad, frame="icrs").transform_to(
        AltAz(obstime=t, location=loc, pressure=850 * u.hPa, temperature=10 * u.deg_C,
              relative_humidity=0.5, obswl=0.55 * u.micron))
    err = angle_between(rf.observed_enu(v, frame), _enu(aa.alt.deg, aa.az.deg)) / ARCSEC
    above = aa.alt.deg > 15.0
    assert above.sum() > 300
    assert err[above].max() < 0.002  # measured 0.0002″; the issue asks 1″
    assert err[aa.alt.deg > 5.0].max() < 0.002
    # the physical directions in ICRS axes are the same directions
    d = rf.observed_directions(v, frame)
    alt, az = rf.altaz_of(d, frame)
    assert np.max(np.abs(alt - aa.alt.deg)[above]) * 3600 < 0.002
    # without UT1 − UTC and polar motion (the defaults) the Earth's rotation is off by dut1·15″
    plain = rf.ground_frame(SITE, t.jd, WEATHER)
    shift = angle_between(rf.observed_enu(v, plain), _enu(aa.alt.deg, aa.az.deg))[above] / ARCSEC
    assert 0.5 * abs(dut1) * 15.04 * math.cos(math.radians(40.7)) < np.median(shift) < abs(dut1) * 15.04 + 0.5


def test_observed_enu_is_erfa_atco13():
    v = _random_vectors(500, seed=2)
    ra, dec = vector_to_radec(v)
    frame = rf.ground_frame(SITE, JD_UTC, WEATHER, dut1_s=0.1, polar_motion_arcsec=(0.05, 0.3))
    aob, zob = erfa.atco13(ra, dec, 0.0, 0.0, 0.0, 0.0, 2400000.5, JD_UTC - 2400000.5, 0.1,
                           math.radians(SITE.lon_deg), math.radians(SITE.lat_deg), SITE.height_m,
                           math.radians(0.05 / 3600), math.radians(0.3 / 3600), 850.0, 10.0, 0.5, 0.55)[:2]
    alt = 90.0 - np.degrees(zob)
    err = angle_between(rf.observed_enu(v, frame), _enu(alt, np.degrees(aob))) / ARCSEC
    assert err[alt > 5.0].max() < 0.001  # ERFA's cos δ ≈ 1 − δ²/2, sin δ ≈ δ against exact: 0.5 mas at 5°
    assert err[alt > 0.0].max() < 0.5


def test_refraction_is_applied_per_star_across_a_low_frame():
    # a 20°-tall field from 5° to 25° altitude: the refraction differs by 7′ across it, and each
    # star is lifted by the model's refraction at its own altitude, not the boresight's
    frame = rf.ground_frame(SITE, JD_UTC, rf.Weather(10.0, 1010.0, 0.5))
    alt_true = np.linspace(5.0, 25.0, 41)
    geom = _enu(alt_true, np.full_like(alt_true, 150.0))
    seen = rf.refract_enu(geom, frame.refraction)
    lift = np.degrees(np.arcsin(seen[:, 2])) - alt_true
    model = frame.refraction.lift_rad(np.sin(np.radians(alt_true)), np.cos(np.radians(alt_true)))
    assert np.allclose(np.radians(lift), model, atol=1e-12)
    assert (lift[0] - lift[-1]) * 60 > 7.0
    # through the whole chain: catalogue stars at those places are seen there
    astrometric = np.array([_astrometric(g, frame) for g in geom])
    apparent = rf.apparent_enu(astrometric, frame)
    assert np.max(angle_between(apparent, geom)) < 1e-10
    assert np.max(angle_between(rf.observed_enu(astrometric, frame), seen)) < 1e-10


def _astrometric(u_geom_enu: np.ndarray, frame: rf.GroundFrame) -> np.ndarray:
    """The catalogue direction of a geometric ENU direction (ERFA's aticq)."""
    ri, di = erfa.c2s(frame.A_cirs_to_enu.T @ u_geom_enu)
    return erfa.s2c(*erfa.aticq(ri, di, frame.astrom))


# --- the attitude and the boresight ---------------------------------------------------------------------
def test_attitude_fitted_to_observed_directions_is_the_physical_one():
    frame = rf.ground_frame(SITE, JD_UTC, WEATHER, dut1_s=0.1)
    # a camera pointing at 20° altitude, azimuth 100°, with a 40° field of catalogue stars
    boresight_enu = _enu(np.array(20.0), np.array(100.0))
    boresight = frame.A_icrs_to_enu.T @ boresight_enu
    A_true = attitude_from_radec_roll(*vector_to_radec(boresight), math.radians(30.0))
    cat = _random_vectors(20000, seed=3)
    seen = rf.observed_directions(cat, frame)
    b = seen @ A_true.T
    in_view = b[:, 2] > math.cos(math.radians(20.0))
    assert in_view.sum() > 200
    b, r, d = b[in_view], cat[in_view], seen[in_view]
    A_fit = solve_attitude(b, d)
    assert np.max(np.abs(A_fit - A_true)) < 1e-12
    # fitted to the catalogue directions instead, the attitude is off by the refraction (~2.5′)
    naive = solve_attitude(b, r)
    off = np.degrees(np.arccos((np.trace(naive @ A_true.T) - 1) / 2)) * 60
    assert 1.5 < off < 4.0
    # Alt/Az of the boresight, and the camera in the local frame exactly
    alt, az = rf.altaz_of(A_fit[2], frame)
    assert (alt, az) == pytest.approx((20.0, 100.0), abs=1e-9)
    A_enu_to_cam = A_fit @ frame.A_icrs_to_enu.T
    assert np.allclose(A_enu_to_cam[2], boresight_enu, atol=1e-12)


def test_boresight_places(astropy_time):
    import astropy.units as u
    from astropy.coordinates import TETE, EarthLocation, SkyCoord

    t, dut1, pm = astropy_time
    frame = rf.ground_frame(SITE, t.jd, WEATHER, dut1_s=dut1, polar_motion_arcsec=pm)
    stars = _random_vectors(200, seed=4)
    seen = rf.observed_directions(stars, frame)
    alt = rf.altaz_of(seen, frame).alt_deg
    picks = np.flatnonzero(alt > 10.0)[:5]
    loc = EarthLocation.from_geodetic(SITE.lon_deg * u.deg, SITE.lat_deg * u.deg, SITE.height_m * u.m)
    for i in picks:
        # a camera whose boresight sees star i
        A = attitude_from_radec_roll(*vector_to_radec(seen[i]), 1.0)
        places = rf.boresight_places(A, frame)
        ra, dec = (math.degrees(x) for x in vector_to_radec(stars[i]))
        assert places.ra_deg == pytest.approx(ra, abs=1e-9)  # its catalogue place, to 4 µas
        assert places.dec_deg == pytest.approx(dec, abs=1e-9)
        assert places.alt_deg == pytest.approx(alt[i], abs=1e-9)
        jnow = SkyCoord(ra * u.deg, dec * u.deg, frame="icrs").transform_to(TETE(obstime=t, location=loc))
        assert abs(places.ra_jnow_deg - jnow.ra.deg) * 3600 * math.cos(math.radians(dec)) < 0.001
        assert abs(places.dec_jnow_deg - jnow.dec.deg) * 3600 < 0.001


# --- bad input --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("make, match", [
    (lambda: rf.Site(100.0, 0.0, 0.0), "site latitude 100.0 is not in -90..90 degrees"),
    (lambda: rf.Site.parse("40,-111,x"), "is not LAT,LON,HEIGHT_M"),
    (lambda: rf.Site.parse("40,-111,1400,5"), "is not LAT,LON,HEIGHT_M"),
    (lambda: rf.Site(40.0, float("nan")), "site longitude nan"),
    (lambda: rf.Weather.parse("10,850,50"), r"relative humidity 50.0 is not in 0..1 \(a fraction"),
    (lambda: rf.Weather(-300.0, 850.0), "temperature -300.0"),
    (lambda: rf.check_site_weather(None, "10,850,0.5"), "weather needs a site"),
    (lambda: rf.check_site_weather(None, rf.Weather()), "weather needs a site"),
    (lambda: rf.ground_frame(SITE, JD_UTC, model="saemundsson"), "refraction model 'saemundsson'"),
    (lambda: rf.ground_frame(SITE, float("nan")), "UTC Julian date nan"),
    (lambda: rf.ground_frame(SITE, JD_UTC, dut1_s=3.0), "UT1 - UTC"),
])
def test_bad_input_is_one_line(make, match):
    with pytest.raises(InputError, match=match) as info:
        make()
    assert "\n" not in str(info.value)


def test_parse_and_defaults():
    site, weather = rf.check_site_weather("40.7,-111.8,1400", "10,850,0.5")
    assert site == SITE and weather == WEATHER
    assert rf.check_site_weather(None, None) == (None, None)
    assert rf.Site.parse("-33.9, 18.4") == rf.Site(-33.9, 18.4, 0.0)
    # no weather: a standard atmosphere at the site's height (ERFA's rule: 1400 m → 858.4 hPa)
    frame = rf.ground_frame(SITE, JD_UTC)
    assert frame.weather.pressure_hpa == pytest.approx(858.42, abs=0.01)
    assert rf.ground_frame(SITE, JD_UTC) is frame  # cached per time, site and weather
    none = rf.ground_frame(SITE, JD_UTC, model="none")
    u = _random_vectors(50)
    assert np.array_equal(rf.observed_enu(u, none), rf.apparent_enu(u, none))


# --- speed -----------------------------------------------------------------------------------------
def test_per_star_refraction_speed():
    """A few hundred catalogue directions for a solve, the frame set up: measured 0.13 ms best of
    30 on the shared 2-core machine under load (~0.05 ms idle); the set-up ~0.2 ms, once per
    time and site. The bound here is loose: the machine is shared."""
    frame = rf.ground_frame(SITE, JD_UTC, WEATHER)
    v = _random_vectors(300)
    rf.observed_directions(v, frame)
    best = math.inf
    for _ in range(30):
        t0 = time.perf_counter()
        for _ in range(20):
            rf.observed_directions(v, frame)
        best = min(best, (time.perf_counter() - t0) / 20)
    assert best < 1e-3, f"{best * 1e3:.3f} ms"
