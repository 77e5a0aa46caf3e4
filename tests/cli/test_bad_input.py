"""Bad input: a clear one-line error (exit 2) or ``status: failed`` with a reason — never a
traceback, never a solved wrong attitude."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from skyfix.cli import app
from skyfix.errors import DatabaseError, ImageReadError
from skyfix.geometry import radec_to_vector
from skyfix.pipeline import solve

runner = CliRunner()
ESA = "esa-tetra3/2019-07-29T204726_Alt60_Azi45_Try1.tiff"


def _cli(*args):
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    return result


@pytest.fixture
def bad_files(tmp_path):
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    text = tmp_path / "notes.png"
    text.write_text("this is not an image\n")
    fits = tmp_path / "cut.fits"
    from astropy.io import fits as pyfits

    pyfits.PrimaryHDU(np.ones((200, 300), np.float32)).writeto(fits)
    fits.write_bytes(fits.read_bytes()[:5000])
    return {"empty": empty, "text": text, "truncated_fits": fits, "missing": tmp_path / "nope.png"}


@pytest.mark.parametrize("kind", ["empty", "text", "truncated_fits", "missing"])
def test_unreadable_files_raise_one_line(bad_files, kind):
    with pytest.raises(ImageReadError) as info:
        solve(bad_files[kind])
    assert "\n" not in str(info.value) and str(info.value)


@pytest.mark.parametrize("kind", ["empty", "text", "truncated_fits", "missing"])
def test_cli_unreadable_exit_2(bad_files, kind, database):
    result = _cli("solve", bad_files[kind])
    assert result.exit_code == 2
    assert "Traceback" not in result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("skyfix: error:")


@pytest.mark.parametrize("frame", ["black", "saturated", "constant", "noise", "nan"])
def test_featureless_frames_fail_with_reason(frame, database):
    rng = np.random.default_rng(7)
    image = {
        "black": np.zeros((960, 1280)),
        "saturated": np.full((960, 1280), 255.0),
        "constant": np.full((960, 1280), 1234.0),
        "noise": rng.normal(100, 10, (960, 1280)),
        "nan": np.full((960, 1280), np.nan),
    }[frame]
    try:
        sol = solve(image, database=database)
    except ImageReadError as exc:  # an all-NaN frame may be refused as unreadable
        assert frame == "nan" and str(exc)
        return
    assert sol.status == "failed"
    assert sol.reason


def test_fov_hint_wrong_by_2x_does_not_solve_wrong(real_dir, real_solutions, database):
    """A FOV hint wrong by 2× matches nothing; the frame is then solved without it (issue 28):
    right, or failed — never wrong — and the Solution says the hint was not used."""
    ref = real_solutions[ESA]
    for factor in (0.5, 2.0):
        sol = solve(real_dir / ESA, fov_deg=ref["fov_w_deg"] * factor, database=database)
        if not sol.solved:
            assert sol.reason
            continue
        off = np.degrees(np.arccos(np.clip(np.dot(radec_to_vector(np.radians(sol.center_ra_deg),
                                                                  np.radians(sol.center_dec_deg)),
                                                  radec_to_vector(np.radians(ref["ra_deg"]),
                                                                  np.radians(ref["dec_deg"]))), -1, 1)))
        assert off * 3600 < 60, (factor, sol.center_ra_deg, sol.center_dec_deg)
        assert sol.warnings and sol.warnings[0].startswith(f"the FOV hint {ref['fov_w_deg'] * factor:g}° "
                                                            "was not used")


def test_corrupt_database_file(tmp_path):
    from skyfix.identify import PatternDatabase

    bad = tmp_path / "db.npz"
    bad.write_bytes(b"PK\x03\x04 definitely not a database")
    with pytest.raises(DatabaseError):
        PatternDatabase.load(bad)


def test_cli_json_one_line_per_image(real_dir, database):
    result = _cli("solve", "--json", real_dir / ESA, real_dir / ESA)
    lines = result.stdout.strip().splitlines()
    assert result.exit_code == 0
    assert len(lines) == 2
    for line in lines:
        d = json.loads(line)
        assert d["status"] == "solved"
        for key in ("image", "ra_deg", "dec_deg", "roll_deg", "fov_deg", "quaternion_xyzw",
                    "covariance_arcsec2", "n_detected", "n_matched", "prob_false", "rmse_arcsec",
                    "method", "time_ms", "matches"):
            assert key in d
        assert set(d["time_ms"]) >= {"extract", "identify", "attitude", "total"}
        assert {"x", "y", "id", "ra_deg", "dec_deg", "mag", "residual_arcsec"} <= set(d["matches"][0])


def _registries():
    """A call per registry with a name it does not have (cheap: each fails before any work)."""
    from skyfix.attitude import solve_attitude
    from skyfix.camera import Camera, camera_from_preset
    from skyfix.detect.background import estimate_background
    from skyfix.detect.calibrate_frames import master_frame
    from skyfix.detect.centroid import centroider
    from skyfix.detect.extract import extract_centroids
    from skyfix.detect.regionprops import extract_regionprops
    from skyfix.detect.streak import centroid_streaks
    from skyfix.identify import get_method
    from skyfix.io import read_image_with_header
    from skyfix.simulate.presets import load_preset
    from skyfix.simulate.profiles import make_profile
    from skyfix.track.predictors import make_predictor
    from skyfix.track.rate import three_point
    from skyfix.warmup import ensure

    img = np.zeros((32, 32), np.float32)
    v = np.eye(3)
    return {
        "identification method": lambda: get_method("nope"),
        "attitude method": lambda: solve_attitude(v, v, method="nope"),
        "background method": lambda: estimate_background(img, method="nope"),
        "combine": lambda: master_frame(np.zeros((2, 4, 4)), combine="nope"),
        "centroider": lambda: centroider("nope"),
        "detection method": lambda: extract_centroids(img, method="nope"),
        "streak centroider": lambda: centroid_streaks(img, np.zeros((1, 2)), np.zeros(2), method="nope"),
        "prefilter": lambda: extract_regionprops(img, prefilter="nope"),
        "image decoder": lambda: read_image_with_header(img, decoder="nope"),
        "camera preset": lambda: camera_from_preset("nope"),
        "camera projection": lambda: Camera(64, 64, 100.0, 100.0, 31.5, 31.5, projection="nope"),
        "preset": lambda: load_preset("nope"),
        "motion profile": lambda: make_profile("nope", v),
        "predictor": lambda: make_predictor("nope", v, 0.0, np.eye(3)),
        "three-point weights": lambda: three_point(1.0, 2.0, 3.0, "nope"),
        "warm-up path": lambda: ensure("nope"),
    }


@pytest.mark.parametrize("what", list(_registries()))
def test_every_registry_refuses_an_unknown_name_alike(what):
    """One error type (UnknownNameError, an InputError) and one message form for a name that no
    registry entry has — whichever stage's registry it is."""
    from skyfix.errors import InputError, UnknownNameError

    with pytest.raises(UnknownNameError, match=f"^unknown {what} 'nope'; choose one of [^;]+$") as info:
        _registries()[what]()
    assert isinstance(info.value, InputError)
