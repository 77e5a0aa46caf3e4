"""One image's observation (skyfix.corrections.observation): which corrections apply, the
directions the camera sees catalogue stars in, and what the Solution reports (issue 24).

astropy is the reference, offline: TT times, ``iers.conf.auto_download`` off.
"""

import math

import numpy as np
import pytest
from astropy.utils import iers

from skyfix.catalog import hipparcos_parallax, load_hipparcos
from skyfix.corrections import apparent_directions, apparent_frame
from skyfix.corrections.observation import CORRECTIONS, apparent_attitude, observe
from skyfix.corrections.refraction import Site, observed_directions
from skyfix.errors import InputError
from skyfix.geometry import angle_between, attitude_from_radec_roll
from skyfix.obstime import jd_utc, julian_year, later, parse_time
from skyfix.solution import Solution

iers.conf.auto_download = False
pytestmark = pytest.mark.filterwarnings("ignore::erfa.ErfaWarning")

ARCSEC = math.radians(1 / 3600)
T = "2026-03-01T22:00:00Z"


@pytest.fixture(scope="module")
def bright():
    """The 300 brightest Hipparcos stars at 2026.16, with their numbers."""
    cat = load_hipparcos(epoch=julian_year(parse_time(T)))
    order = np.argsort(cat.mag)[:300]
    return cat.vectors[order], cat.ids[order]


def test_no_time_applies_nothing_and_says_why():
    obs = observe()
    assert obs.applied == ()
    assert set(obs.not_applied) == {"proper_motion", "parallax", "light_deflection", "aberration"}
    assert all(reason.startswith("no observation time") for reason in obs.not_applied.values())
    assert obs.attitude_frame == "apparent" and not obs.moves_stars
    v = np.eye(3)
    assert obs.seen(v, np.array([1, 2, 3])) is v
    # a site without a time: refraction is named too
    assert "refraction" in observe(site="40.7,-111.8,1400").not_applied
    # an epoch alone moves the catalogue, nothing else
    assert observe(epoch=2020.0).applied == ("proper_motion",)


def test_time_and_velocity_give_the_gcrs_directions_of_astropy(bright):
    """The seen directions of the 300 brightest stars (parallax by their Hipparcos numbers) equal
    astropy's ICRS → GCRS with the same observer velocity, within 1 mas; the shift is aberration's
    20″ and more."""
    import astropy.units as u
    from astropy.coordinates import GCRS, CartesianRepresentation, SkyCoord
    from astropy.time import Time

    vectors, ids = bright
    obs = observe(T, observer="7.5,-1.2,0.4")
    assert obs.applied == ("proper_motion", "parallax", "light_deflection", "aberration")
    assert obs.epoch == pytest.approx(julian_year(obs.time)) and obs.attitude_frame == "ICRS"
    seen = obs.seen(vectors, ids)
    parallax = hipparcos_parallax(ids)
    frame = GCRS(obstime=Time(obs.time.jd_tt, format="jd", scale="tt"),
                 obsgeoloc=CartesianRepresentation([0, 0, 0] * u.km),
                 obsgeovel=CartesianRepresentation([7.5, -1.2, 0.4] * u.km / u.s))
    rep = CartesianRepresentation(vectors.T) * (parallax * u.rad).to(u.pc, u.parallax())
    g = SkyCoord(rep, frame="icrs").transform_to(frame).cartesian.xyz.value.T
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    assert np.max(angle_between(seen, g)) / ARCSEC < 1e-3
    shift = angle_between(seen, vectors) / ARCSEC
    assert 20.0 < shift.max() < 26.0 and np.median(shift) > 10.0  # β sin θ, θ from the apex
    np.testing.assert_allclose(seen, apparent_directions(vectors, apparent_frame(obs.time, obs.observer),
                                                         parallax), atol=1e-15)


def test_ground_path_aberrates_once(bright):
    """At a site, the seen directions with refraction 'none' are the topocentric GCRS ones: the
    space path with the site's own geocentric velocity gives them within 5 mas (the site's
    position's parallax, below 1e-5″ for stars, is the rest). Aberrating again would miss by 20″."""
    vectors, ids = bright
    site = Site(40.7, -111.8, 1400.0)
    obs = observe("2024-03-20T04:00:00Z", site=site, refraction="none")
    assert obs.applied == ("proper_motion", "parallax", "light_deflection", "aberration")
    assert obs.not_applied == {"refraction": "refraction model 'none'"}
    seen = obs.seen(vectors, ids)
    np.testing.assert_allclose(seen, observed_directions(_parallax_shifted(vectors, ids, obs), obs.ground),
                               atol=1e-15)
    v_site = _site_velocity_gcrs(site, obs.time)
    space = observe(obs.time, observer=v_site).seen(vectors, ids)
    assert np.max(angle_between(seen, space)) / ARCSEC < 0.005
    twice = apparent_directions(seen, apparent_frame(obs.time))
    assert np.median(angle_between(twice, space)) / ARCSEC > 5.0


def _parallax_shifted(vectors, ids, obs):
    eb = np.asarray(obs.ground.astrom["eb"]).reshape(3)
    p = vectors - hipparcos_parallax(ids)[:, None] * eb
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def _site_velocity_gcrs(site, t):
    import astropy.units as u
    from astropy.coordinates import EarthLocation
    from astropy.time import Time

    loc = EarthLocation.from_geodetic(site.lon_deg * u.deg, site.lat_deg * u.deg, site.height_m * u.m)
    _, vel = loc.get_gcrs_posvel(Time(t.jd_tt, format="jd", scale="tt"))
    return vel.xyz.to(u.km / u.s).value


def test_refraction_lifts_stars_and_the_attitude_frame_stays_icrs():
    cat = load_hipparcos(mag_limit=5.0)
    vectors, ids = cat.vectors, cat.ids
    obs = observe("2024-03-20T04:00:00Z", site="40.7,-111.8,1400", weather="10,850,0.5")
    assert "refraction" in obs.applied and obs.attitude_frame == "ICRS"
    flat = observe("2024-03-20T04:00:00Z", site="40.7,-111.8,1400", refraction="none")
    up = obs.ground.A_icrs_to_enu[2]
    alt = np.degrees(np.arcsin(flat.seen(vectors, ids) @ up))
    lift = (np.degrees(np.arcsin(obs.seen(vectors, ids) @ up)) - alt) * 60  # arcmin
    at20 = (alt > 19.9) & (alt < 20.1)
    assert at20.any() and np.all((lift[at20] > 2.15) & (lift[at20] < 2.25))  # ERFA, 850 hPa: 2.2′
    assert np.all(lift[alt > 60] < 0.6)


def test_bad_input_is_one_line():
    cases = {
        "outside 1900–2100": dict(time="1899-12-31T00:00:00"),
        "2101": dict(time="2101-01-01T00:00:00"),
        "site latitude 100.0 is not in -90..90": dict(site="100,0,0"),
        "weather needs a site": dict(weather="10,1000"),
        "not below the speed of light": dict(observer="300000,0,0"),
        "has 5 numbers": dict(mounting="1,0,0,0,0"),
        "not a unit quaternion": dict(mounting="0,0,0,2"),
        "give one or the other": dict(observer="7,0,0", site="40,0"),
        "refraction model": dict(refraction="saemundsson"),
    }
    for words, kwargs in cases.items():
        with pytest.raises(InputError) as err:
            observe(**kwargs)
        message = str(err.value)
        assert "\n" not in message and words in message, (kwargs, message)


def test_report_fills_the_solution():
    t = parse_time(T)
    obs = observe(t, observer="7.5,0,0", mounting="180,0,-45", exclusion="sunsat")
    sun = obs.body_directions.sun
    A = attitude_from_radec_roll(math.atan2(sun[1], sun[0]) + math.radians(20), math.asin(sun[2]), 0.0)
    sol = Solution()
    obs.report(sol, A)
    assert sol.time == "2026-03-01T22:00:00.000Z" and sol.time_source == "--time"
    assert sol.corrections == list(obs.applied) and sol.corrections_not_applied == {}
    assert sol.attitude_frame == "ICRS" and sol.observer_velocity_km_s == [7.5, 0.0, 0.0]
    assert 18.0 < sol.bodies["sun_deg"] < 20.01 and sol.bodies["earth_limb_deg"] is not None
    assert any(w.startswith("the Sun is") and "28.1° exclusion" in w for w in sol.warnings)
    # an all-sky camera (no baffle) gets the angles but no exclusion warnings; a narrow one both
    from skyfix.camera import Camera
    from skyfix.simulate.allsky import all_sky_camera

    for camera, warned in ((all_sky_camera(1280, 960), False), (Camera.from_fov(1280, 960, 15.0), True)):
        other = Solution()
        obs.report(other, A, camera=camera)
        assert other.bodies == sol.bodies
        assert any("exclusion" in w for w in other.warnings) is warned
    assert sol.frames["body"]["from"] == "icrs" and sol.frames["camera"]["ra_deg"] == pytest.approx(
        math.degrees(math.atan2(A[2, 1], A[2, 0])) % 360, abs=1e-6)
    d = sol.to_dict()
    assert d["bodies"]["earth_limb_deg"] is None  # NaN: no observer position
    for key in ("alt_deg", "az_deg", "ra_jnow_deg", "dec_jnow_deg"):
        assert key not in d  # no site
    # a frame of a tracked sequence reports its own time
    sol2 = Solution()
    obs.report(sol2, A, time=later(t, 12.25))
    assert sol2.time == "2026-03-01T22:00:12.250Z"
    # apparent: the frames are named for it
    app = observe(t, mounting="0,0,0", apparent=True)
    sol3 = Solution()
    app.report(sol3, A)
    assert sol3.attitude_frame == "apparent" and sol3.frames["reference_frame"] == "apparent"


def test_site_report_gives_altaz():
    obs = observe("2024-03-20T04:00:00Z", site="40.7,-111.8,1400")
    zenith = obs.ground.A_icrs_to_enu[2]
    A = attitude_from_radec_roll(math.atan2(zenith[1], zenith[0]), math.asin(zenith[2]), 0.0)
    sol = Solution()
    obs.report(sol, A)
    assert sol.alt_deg == pytest.approx(90.0, abs=1e-6)
    assert sol.ra_jnow_deg is not None and sol.dec_jnow_deg == pytest.approx(40.7, abs=0.3)


def test_apparent_attitude_is_the_fit_to_the_catalogue_places(bright):
    """``A · R`` (R: catalogue places → seen directions) against the attitude fitted to the
    catalogue places themselves: the same within 0.01″ for a 10° field, while the two
    attitudes differ by the aberration (β = |v|/c for a boresight square to the velocity)."""
    from skyfix.attitude import attitude_error, solve_attitude

    vectors, ids = bright
    obs = observe(T, observer="0,7.5,0")
    v = obs.space.velocity_km_s  # a boresight square to the velocity: the full 20.5″ and more
    z = np.cross(v, [0.0, 0.0, 1.0])
    A = attitude_from_radec_roll(math.atan2(z[1], z[0]), math.asin(z[2] / np.linalg.norm(z)), 0.5)
    cat = load_hipparcos(epoch=obs.epoch, mag_limit=7.0)
    near = cat.vectors @ A[2] > math.cos(math.radians(5))
    places, numbers = cat.vectors[near], cat.ids[near]
    seen = obs.seen(places, numbers)
    b = seen @ A.T  # the image rays of the physical attitude
    A_plain = solve_attitude(b, places)
    A_app = apparent_attitude(A, places, seen)
    assert np.degrees(np.linalg.norm(attitude_error(A_app, A_plain))) * 3600 < 0.01
    beta = np.linalg.norm(v) / 299792.458
    assert np.degrees(np.linalg.norm(attitude_error(A_app, A)[:2])) * 3600 == pytest.approx(
        math.degrees(beta) * 3600, rel=0.01)


def test_later_and_utc():
    t = parse_time("2026-03-01T22:00:00Z")
    assert later(t, 0.001).iso == "2026-03-01T22:00:00.001Z"
    assert later(t, -3600).iso == "2026-03-01T21:00:00.000Z"
    assert later(t, 86400.0).jd_tt == pytest.approx(t.jd_tt + 1.0, abs=1e-9)
    # UTC is 69.184 s behind TT in 2026
    assert (t.jd_tt - jd_utc(t)) * 86400 == pytest.approx(69.184, abs=1e-3)
    with pytest.raises(InputError):
        jd_utc(observe().time)


def test_corrections_are_named_once():
    assert CORRECTIONS == ("proper_motion", "parallax", "light_deflection", "aberration", "refraction")
    assert set(observe(T, site="0,0").applied) == set(CORRECTIONS)
