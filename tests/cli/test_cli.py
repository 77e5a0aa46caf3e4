"""The `skyfix` command on the bundled example: solve against its truth, WCS and plot outputs."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from skyfix.attitude import attitude_error
from skyfix.cli import app
from skyfix.geometry import attitude_from_quaternion, rotation_angle_between
from tests.conftest import EXAMPLES

EXAMPLE = EXAMPLES / "sky.png"
runner = CliRunner()


@pytest.fixture(scope="module")
def truth():
    return json.loads(EXAMPLE.with_name("sky.truth.json").read_text())


def test_example_solves_to_truth(tmp_path, truth, database):
    wcs_path, plot_path = tmp_path / "sky.wcs", tmp_path / "sky-solved.png"
    args = ["solve", "--json", str(EXAMPLE), "--wcs", str(wcs_path), "--plot", str(plot_path)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    sol = json.loads(result.stdout)
    err = rotation_angle_between(attitude_from_quaternion(truth["quaternion_xyzw"]),
                                 attitude_from_quaternion(sol["quaternion_xyzw"]))
    assert np.degrees(err) * 3600 < 20.0  # whole-attitude error, arcsec (roll dominates: σ ≈ 6″)
    axes = attitude_error(attitude_from_quaternion(truth["quaternion_xyzw"]),
                          attitude_from_quaternion(sol["quaternion_xyzw"])) / np.radians(1 / 3600)
    assert np.all(np.abs(axes) < 3 * np.sqrt(np.diag(sol["covariance_arcsec2"])))  # honest error bars
    assert abs(sol["ra_deg"] - truth["ra_deg"]) * 3600 * np.cos(np.radians(truth["dec_deg"])) < 2.0
    assert abs(sol["dec_deg"] - truth["dec_deg"]) * 3600 < 2.0
    assert sol["n_matched"] >= 20

    # The WCS maps every matched catalogue star onto its centroid within a pixel.
    from skyfix.wcs import read_wcs

    w = read_wcs(wcs_path)
    sky = np.array([[m["ra_deg"], m["dec_deg"]] for m in sol["matches"]])
    xy = np.array([[m["x"], m["y"]] for m in sol["matches"]])
    px = w.all_world2pix(sky, 0, maxiter=100)
    assert np.median(np.hypot(*(px - xy).T)) < 0.5

    from PIL import Image

    with Image.open(plot_path) as im:
        assert im.size == (1280, 960)


def test_cli_camera_file_and_failed_exit_code(tmp_path, database):
    black = tmp_path / "black.png"
    from PIL import Image

    Image.fromarray(np.zeros((480, 640), np.uint8)).save(black)
    result = runner.invoke(app, ["solve", str(black)])
    assert result.exit_code == 1
    assert "failed:" in result.output
    camera = EXAMPLE.with_name("sky.camera.toml")
    result = runner.invoke(app, ["solve", str(EXAMPLE), "--camera", str(camera)])
    assert result.exit_code == 0 and "solved" in result.output


def test_cli_simulate_writes_image_and_truth(tmp_path):
    out = tmp_path / "sim.fits"
    result = runner.invoke(app, ["simulate", "--ra", "10", "--dec", "20", "--roll", "30", "--camera", "has2",
                                 "--seed", "3", "-o", str(out)])
    assert result.exit_code == 0, result.output
    truth = json.loads(out.with_name("sim.truth.json").read_text())
    assert truth["ra_deg"] == pytest.approx(10.0) and truth["roll_deg"] == pytest.approx(30.0)
    assert len(truth["stars"]) > 0
    bad = runner.invoke(app, ["simulate", "--ra", "10", "--dec", "20", "--camera", "nope", "-o", str(out)])
    assert bad.exit_code == 2 and "unknown camera preset" in bad.output


def test_cli_simulate_takes_a_camera_files_sensor_and_optics(tmp_path):
    """A camera TOML with [sensor] and [optics] renders through them, not the generic preset's:
    a 6-bit sensor's frame never exceeds 63 ADU (the generic preset is 12-bit)."""
    from skyfix.camera import Camera
    from skyfix.io import read_image

    cam = tmp_path / "six-bit.toml"
    cam.write_text(Camera.from_fov(320, 240, 12.0).to_toml()
                   + "\n[sensor]\nbit_depth = 6\ngain_e_per_adu = 40.0\nbias_adu = 4.0\n"
                   + "\n[optics]\naperture_mm = 20.0\npsf_fwhm_px = 2.5\n")
    out = tmp_path / "six.fits"
    result = runner.invoke(app, ["simulate", "--ra", "84", "--dec", "-2", "--camera", str(cam),
                                 "-o", str(out)])
    assert result.exit_code == 0, result.output
    image = read_image(out)
    assert image.shape == (240, 320) and image.max() <= 63 and image.max() >= 40  # bright stars saturate


def test_cli_simulate_allsky_frame_solves_at_its_site(tmp_path):
    """skyfix simulate --allsky LAT,LON: an all-sky frame whose zenith the solve finds, from the
    site and the frame's time (its DATE-OBS: the frame shows the Earth's aberration then), within
    a tenth of a pixel of the truth; the boresight within half a pixel (8.4′ a pixel here: all-sky
    boresights on these frames are 20–160″ off, seeds 3–6)."""
    from skyfix.geometry import radec_to_vector

    out = tmp_path / "sky.fits"
    made = runner.invoke(app, ["simulate", "--allsky", "52.2,0.1", "--time", "2026-01-15T22:00:00",
                               "--camera", "generic", "--seed", "3", "-o", str(out)])
    assert made.exit_code == 0, made.output
    truth = json.loads(out.with_name("sky.truth.json").read_text())
    assert truth["site"] == [52.2, 0.1] and truth["lens_fov_deg"] == 180.0
    solved = runner.invoke(app, ["solve", str(out), "--site", "52.2,0.1", "--refraction", "none", "--json"])
    assert solved.exit_code == 0, solved.output
    r = json.loads(solved.stdout.splitlines()[0])
    assert r["status"] == "solved" and r["n_matched"] > 50
    got = radec_to_vector(np.radians(r["ra_deg"]), np.radians(r["dec_deg"]))
    want = radec_to_vector(np.radians(truth["ra_deg"]), np.radians(truth["dec_deg"]))
    assert np.arccos(np.clip(got @ want, -1, 1)) < 0.5 / truth["camera"]["fx"]
    assert np.hypot(*np.subtract(r["zenith_px"], truth["zenith_px"])) < 0.1
    assert r["time_source"] == "DATE-AVG"
    both = runner.invoke(app, ["simulate", "--allsky", "52.2,0.1", "--ra", "10", "-o", str(out)])
    assert both.exit_code == 2 and "--ra" in both.stderr
    none = runner.invoke(app, ["simulate", "-o", str(out)])
    assert none.exit_code == 2 and "--allsky" in none.stderr


def test_cli_detect_json_matches_truth():
    result = runner.invoke(app, ["detect", "--json", str(EXAMPLE)])
    assert result.exit_code == 0, result.output
    d = json.loads(result.stdout)
    assert d["n"] == len(d["centroids"]) >= 50
    truth = json.loads(EXAMPLE.with_name("sky.truth.json").read_text())
    # Rendered sources: catalogue stars, false stars and the cosmic-ray track's middle.
    stars = np.array([[s["x"], s["y"]] for s in truth["stars"] + truth["false_stars"]]
                     + [[(c["x0"] + c["x1"]) / 2, (c["y0"] + c["y1"]) / 2] for c in truth["cosmic_rays"]])
    fluxes = [c["flux"] for c in d["centroids"]]
    assert fluxes == sorted(fluxes, reverse=True)  # brightest first
    # The 20 brightest centroids each lie on a rendered source (a cosmic-ray streak's centroid
    # is only near its track's middle).
    for c in d["centroids"][:20]:
        assert np.min(np.hypot(stars[:, 0] - c["x"], stars[:, 1] - c["y"])) < 1.0
    bad = runner.invoke(app, ["detect", "--method", "nope", str(EXAMPLE)])
    assert bad.exit_code == 2 and "unknown detection method" in bad.output


def test_cli_calibrate_frames_then_solve(tmp_path):
    from astropy.io import fits

    rng = np.random.default_rng(5)
    darks = []
    for i in range(4):
        d = rng.normal(30.0, 2.0, (960, 1280)).astype(np.float32)
        d[100, 200] = d[700, 900] = 900.0  # two hot pixels
        darks.append(tmp_path / f"dark{i}.fits")
        fits.PrimaryHDU(d, header=fits.Header({"EXPTIME": 0.1})).writeto(darks[-1])
    maps = tmp_path / "maps.fits"
    args = ["calibrate", "frames", "-o", str(maps)]
    for p in darks:
        args += ["--darks", str(p)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    row = [ln.split() for ln in result.output.splitlines() if ln.strip().startswith("0.1")][0]
    assert float(row[2]) == pytest.approx(30.0, abs=0.1)
    # Both hot pixels, plus at most a few Gaussian-tail pixels of 1.2 Mpx at 5σ.
    assert 2 <= int(row[5]) <= 5
    from skyfix.detect import load_calibration

    bad = load_calibration(maps)["bad_pixels"]
    assert bad[100, 200] and bad[700, 900] and bad.sum() == int(row[5])
    # The example's camera has a 64 ADU bias: a 30 ADU dark still leaves it solvable.
    result = runner.invoke(app, ["solve", str(EXAMPLE), "--calibration", str(maps)])
    assert result.exit_code == 0 and "solved" in result.output


def test_cli_database_build_and_use(tmp_path):
    out = tmp_path / "db.npz"
    result = runner.invoke(app, ["database", "build", "--fov-min", "14", "--fov-max", "20", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "FOV 14–20°" in result.output
    result = runner.invoke(app, ["solve", "--json", "--database", str(out), str(EXAMPLE)])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["status"] == "solved"
    bad = tmp_path / "bad.npz"
    bad.write_text("junk")
    result = runner.invoke(app, ["solve", "--database", str(bad), str(EXAMPLE)])
    assert result.exit_code == 2 and "pattern database" in result.output
    result = runner.invoke(app, ["database", "build", "--fov-min", "30", "--fov-max", "10"])
    assert result.exit_code == 2


def test_centroid_sigma_reaches_the_error_bars(database):
    """--centroid-sigma with --camera is a prior on the noise the covariance rests on: stated 2 px
    (about 10× the example's), the boresight σ grows (measured 0.55″ → 1.26″); a value that is
    not a positive number is a one-line error, exit 2."""
    camera = str(EXAMPLE.with_name("sky.camera.toml"))
    sigma = {}
    for stated in (None, "2"):
        args = ["solve", "--json", "--camera", camera, str(EXAMPLE)] + ([] if stated is None else
                                                                         ["--centroid-sigma", stated])
        result = runner.invoke(app, args)
        assert result.exit_code == 0, result.output
        sol = json.loads(result.stdout.splitlines()[-1])
        sigma[stated] = np.sqrt(sol["covariance_arcsec2"][0][0])
    assert sigma["2"] > 1.5 * sigma[None], sigma
    for bad in ("0", "nan", "-1"):
        result = runner.invoke(app, ["solve", "--centroid-sigma", bad, str(EXAMPLE)])
        assert result.exit_code == 2, result.output
        assert "--centroid-sigma" in result.output and "Traceback" not in result.output
