"""``skyfix solve`` and ``skyfix track`` with --time, --velocity-kms, --position-km, --site, --weather,
--mounting, --apparent (issue 24): the fields in the JSON, the WCS against catalogue places, and
each bad value one line with exit 2, nothing solved."""

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from skyfix.camera import Camera
from skyfix.cli import app
from skyfix.cli.solve import plain_solve
from skyfix.corrections import earth_state
from skyfix.geometry import attitude_from_radec_roll
from skyfix.obstime import parse_time
from tests.conftest import EXAMPLES

pytestmark = pytest.mark.filterwarnings("ignore::erfa.ErfaWarning")
EXAMPLE = EXAMPLES / "sky.png"
runner = CliRunner()
T0 = parse_time("2026-09-10T03:00:00Z")
V_ORBIT = (2.0, -6.9, 2.5)


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    """Four 8° FITS frames at 10 Hz (DATE-OBS), aberrated by the Earth's and an orbit's velocity,
    and their camera file with a [mounting] table."""
    from skyfix.simulate import render_sequence
    from skyfix.simulate.optics import Optics
    from skyfix.simulate.truth import write_frame

    folder = tmp_path_factory.mktemp("seq")
    cam = Camera.from_fov(1280, 960, 8.0)
    A = attitude_from_radec_roll(math.radians(40), math.radians(20), 0.3)
    v = earth_state(T0.jd_tt).velocity_km_s + np.array(V_ORBIT)
    paths = []
    for k, f in enumerate(render_sequence(A, cam, n_frames=4, fps=10, epoch=T0.iso, exposure_s=0.05,
                                          optics=Optics(aperture_mm=25.0, throughput=0.8, psf_fwhm_px=2.0),
                                          observer_velocity_km_s=v, seed=5)):
        paths.append(folder / f"frame-{k:04d}.fits")
        write_frame(f, paths[-1])
    camera = folder / "camera.toml"
    camera.write_text(cam.to_toml() + '\n[mounting]\neuler123_deg = [180.0, 0.0, -45.0]\n')
    return paths, camera, A


@pytest.mark.parametrize("args, words", [
    (["--time", "1899-12-31T23:00:00"], "outside 1900–2100"),
    (["--time", "2101-01-01"], "outside 1900–2100"),
    (["--time", "tomorrow"], "cannot read the time"),
    (["--site", "100,20,0"], "site latitude 100.0 is not in -90..90"),
    (["--weather", "10,1013"], "--weather needs a --site"),
    (["--velocity-kms", "3e5,0,0"], "not below the speed of light"),
    (["--velocity-kms", "7,0"], "--velocity-kms takes three numbers"),
    (["--mounting", "1,2"], "--mounting '1,2' has 2 numbers"),
    (["--mounting", "0,0,0,2"], "not a unit quaternion"),
    (["--velocity-kms", "7,0,0", "--site", "40,20"], "give one or the other"),
    (["--refraction", "magic", "--site", "40,20"], "refraction model 'magic'"),
    (["--refraction", "bennett"], "--refraction needs a --site"),
    (["--position-km", "7000,0,0"], "--position-km needs --velocity-kms"),
    (["--velocity-kms", "0,7.5,0", "--position-km", "7000,0"], "--position-km takes three numbers"),
    (["--velocity-kms", "0,7.5,0", "--position-km", "100,0,0"], "inside the Earth"),
])
@pytest.mark.parametrize("command", ["solve", "track"])
def test_bad_observation_options_are_one_line(tmp_path, args, words, command):
    extra = ["--camera", "generic", "--fps", "10"] if command == "track" else []
    result = runner.invoke(app, [command, str(EXAMPLE), *extra, *args, "--json"])
    assert result.exit_code == 2, result.output
    assert result.stdout == ""  # nothing solved half-way
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("skyfix: error:") and words in lines[0], lines


def test_solve_reads_the_time_and_reports_the_true_attitude(sequence, tmp_path):
    from skyfix.attitude import attitude_error
    from skyfix.geometry import attitude_from_quaternion
    from skyfix.wcs import read_wcs

    paths, camera, A = sequence
    wcs = tmp_path / "f.wcs"
    result = runner.invoke(app, ["solve", str(paths[0]), "--camera", str(camera), "--velocity-kms",
                                 ",".join(map(str, V_ORBIT)), "--json", "--wcs", str(wcs)])
    assert result.exit_code == 0, result.output
    sol = json.loads(result.stdout)
    assert sol["time_source"] == "DATE-AVG" and sol["time"].startswith("2026-09-10T03:00:00")
    assert sol["attitude_frame"] == "ICRS" and "aberration" in sol["corrections"]
    assert sol["observer_velocity_km_s"] == list(V_ORBIT)
    assert sol["frames"]["body"]["to"] == "body"  # the camera file's [mounting]
    err = attitude_error(attitude_from_quaternion(sol["quaternion_xyzw"]), A)[:2]
    assert np.degrees(np.linalg.norm(err)) * 3600 < 1.5
    # the WCS is against the catalogue places: the matched stars within their centroids' noise, where
    # one of the true attitude would miss them all by the aberration (8″, 0.4 px)
    from skyfix.wcs import solution_wcs

    sky = np.array([[m["ra_deg"], m["dec_deg"]] for m in sol["matches"]])
    xy = np.array([[m["x"], m["y"]] for m in sol["matches"]])
    miss = np.median(np.hypot(*(read_wcs(wcs).all_world2pix(sky, 0, maxiter=100) - xy).T))
    true = solution_wcs(attitude_from_quaternion(sol["quaternion_xyzw"]), Camera.load(camera))
    assert miss < 0.25 < np.median(np.hypot(*(true.all_world2pix(sky, 0, maxiter=100) - xy).T))
    # the summary line says the time; --apparent reports the attitude a plate solver gives
    line = runner.invoke(app, ["solve", str(paths[0]), "--camera", str(camera), "--apparent",
                               "--time", "2026-09-10T03:00:00Z"])
    assert line.exit_code == 0 and "2026-09-10T03:00:00.000Z (--time) | apparent attitude" in line.stdout


def test_the_plain_shortcut_reads_the_new_options():
    plain = plain_solve(["solve", "x.fits", "--time", "2026-01-01T00:00:00", "--velocity-kms", "7,0,0",
                          "--site", "40,20,100", "--weather", "10,1000,0.5", "--mounting", "0,0,0,1",
                          "--refraction", "bennett", "--apparent"])
    assert plain is not None
    options = plain[1]
    assert options["obs_time"] == "2026-01-01T00:00:00" and options["velocity_kms"] == "7,0,0"
    assert options["site"] == "40,20,100" and options["weather"] == "10,1000,0.5"
    assert options["mounting"] == "0,0,0,1" and options["refraction"] == "bennett" and options["apparent"]


def test_track_with_the_velocity(sequence):
    paths, camera, _ = sequence
    result = runner.invoke(app, ["track", *map(str, paths), "--camera", str(camera), "--velocity-kms",
                                 ",".join(map(str, V_ORBIT)), "--json"])
    assert result.exit_code == 0, result.output
    sols = [json.loads(line) for line in result.stdout.splitlines()]
    assert [s["time"] for s in sols] == [f"2026-09-10T03:00:00.{ms:03d}Z" for ms in (0, 100, 200, 300)]
    assert all(s["attitude_frame"] == "ICRS" and s["frames"]["body"] for s in sols)
    assert sols[-1]["mode"] == "tracking"


def test_position_gives_the_orbit_frame_and_the_earth_limb(sequence):
    """--position-km with --velocity-kms: the body's attitude in the orbit frame (the camera file's
    [mounting]) is ``A_body · A_icrs_to_orbitᵀ`` of the reported attitude to 1e-9, and the Earth
    limb's angle is reported; the attitude itself is the velocity-only solve's within 1 mas (the
    position adds only the stars' parallax, ~1e-9 of the aberration's)."""
    from skyfix.frames import Mounting, orbit_frame
    from skyfix.geometry import attitude_from_quaternion

    paths, camera, _ = sequence
    r = (4000.0, 3000.0, 4500.0)  # km: 6.7e3 from the centre, not parallel to V_ORBIT
    args = ["solve", str(paths[0]), "--camera", str(camera), "--velocity-kms", ",".join(map(str, V_ORBIT)),
            "--json"]
    with_r = runner.invoke(app, [*args, "--position-km", ",".join(map(str, r))])
    assert with_r.exit_code == 0, with_r.output
    sol = json.loads(with_r.stdout)
    plain = json.loads(runner.invoke(app, args).stdout)
    assert "body_in_orbit" not in (plain["frames"] or {}) or plain["frames"]["body_in_orbit"] is None
    assert plain["bodies"]["earth_limb_deg"] is None and sol["bodies"]["earth_limb_deg"] is not None
    A = attitude_from_quaternion(sol["quaternion_xyzw"])
    expected = Mounting.load(camera).body_attitude(A) @ orbit_frame(r, V_ORBIT).T
    got = attitude_from_quaternion(sol["frames"]["body_in_orbit"]["quaternion_xyzw"])
    np.testing.assert_allclose(got, expected, atol=1e-9)  # the JSON rounds to 10 digits
    from skyfix.attitude import attitude_error

    err = attitude_error(A, attitude_from_quaternion(plain["quaternion_xyzw"]))
    assert np.degrees(np.linalg.norm(err)) * 3600 < 1e-3


def _sep_arcsec(a_deg: np.ndarray, b_deg: np.ndarray) -> np.ndarray:
    from skyfix.geometry import radec_to_vector

    u = radec_to_vector(*np.radians(np.asarray(a_deg)).T)
    v = radec_to_vector(*np.radians(np.asarray(b_deg)).T)
    return np.degrees(np.arccos(np.clip(np.sum(u * v, axis=-1), -1, 1))) * 3600


def test_radec_of_pixel_is_against_the_catalogue_places_as_the_wcs(sequence):
    """With a time and a velocity the reported attitude is the true one, while ``radec_of_pixel``
    (and the plot's grid) maps pixels to catalogue places, as the WCS does: the matched stars'
    pixels give their catalogue RA/Dec within a quarter pixel (the true attitude's mapping misses
    them by the aberration, 8″ here), the WCS's own mapping agrees to 0.2″ (its SIP fit's 0.005 px),
    and the boresight pixel's RA/Dec is not the reported (true) boresight's."""
    import skyfix
    from skyfix.geometry import vector_to_radec
    from skyfix.wcs import solution_wcs

    paths, camera, _ = sequence
    sol = skyfix.solve(str(paths[0]), camera=Camera.load(camera), observer=V_ORBIT)
    assert sol.solved and sol.attitude_frame == "ICRS"
    xy = np.array([(m.x, m.y) for m in sol.matches])
    catalogue = np.array([(m.ra_deg, m.dec_deg) for m in sol.matches])
    pixel_arcsec = math.degrees(sol.camera.plate_scale_rad) * 3600
    got = sol.radec_of_pixels(xy)
    assert np.median(_sep_arcsec(got, catalogue)) < 0.25 * pixel_arcsec
    true = np.degrees(np.column_stack(vector_to_radec(sol.camera.pixel_to_ray(xy) @ sol.A_icrs_to_cam)))
    assert np.median(_sep_arcsec(true, catalogue)) > 0.25 * pixel_arcsec
    wcs = solution_wcs(sol.A_apparent_to_cam, sol.camera).all_pix2world(xy, 0)
    assert np.max(_sep_arcsec(got, wcs)) < 0.2
    assert np.allclose(sol.radec_of_pixel(*xy[0]), got[0], rtol=0, atol=1e-12)
    boresight = sol.radec_of_pixel(*sol.boresight_px)
    assert _sep_arcsec(np.array([boresight]), np.array([[sol.ra_deg, sol.dec_deg]]))[0] > 5.0
