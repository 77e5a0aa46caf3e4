"""No tracebacks from the command line: every bad option, file or frame gives one
``skyfix: error:`` line (exit 2) or a ``failed: reason`` (exit 1), said before any work; a batch
goes on past a bad file; outputs land in folders that are created and never overwrite each other."""

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from skyfix.cli import app
from tests.conftest import EXAMPLES

EXAMPLE = EXAMPLES / "sky.png"
runner = CliRunner()


def _run(*args):
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in result.output
    return result


def _one_error(result, code=2) -> str:
    """The single stderr line of a failed command (and nothing on stdout)."""
    assert result.exit_code == code, result.output
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("skyfix: error: "), result.stderr
    assert result.stdout == ""
    return lines[0].removeprefix("skyfix: error: ")


@pytest.fixture
def black_png(tmp_path):
    from PIL import Image

    path = tmp_path / "black.png"
    Image.fromarray(np.zeros((480, 640), np.uint8)).save(path)
    return path


# --- options checked before any work --------------------------------------------------------------
def test_attitude_bogus_rejected_before_solving():
    msg = _one_error(_run("solve", EXAMPLE, "--attitude", "bogus"))
    assert msg == "--attitude 'bogus' is not a Wahba solver; choose one of svd, quest, esoq2, q-method, triad"


@pytest.mark.parametrize("epoch", ["nan", "inf", "-5000"])
def test_bad_epoch(epoch):
    msg = _one_error(_run("solve", EXAMPLE, "--epoch", epoch))
    assert msg == f"--epoch {float(epoch):g} is not a Julian year in 1000–3000 (e.g. 2024.5)"


def test_negative_fov_tolerance():
    assert _one_error(_run("solve", EXAMPLE, "--fov", "17", "--fov-tolerance", "-1")) == (
        "--fov-tolerance -1 must be a positive number")


def test_fov_out_of_range_same_words_for_solve_and_database_build():
    assert _one_error(_run("solve", EXAMPLE, "--fov", "0.1")) == (
        "--fov 0.1 is not a plausible field of view (0.5–100 degrees)")
    assert _one_error(_run("database", "build", "--fov-min", "0.2", "--fov-max", "10")) == (
        "--fov-min 0.2 is not a plausible field of view (0.5–100 degrees)")
    assert _one_error(_run("database", "build", "--fov-min", "30", "--fov-max", "10")) == (
        "--fov-min 30 is larger than --fov-max 10")


@pytest.mark.parametrize(("args", "message"), [
    (["--sigma", "-3"], "--sigma -3 must be a positive number"),
    (["--sigma", "nan"], "--sigma nan must be a positive number"),
    (["--max-stars", "-5"], "--max-stars -5 must be a whole number >= 1"),
])
def test_detect_bad_thresholds(args, message):
    assert _one_error(_run("detect", EXAMPLE, *args)) == message


# --- outputs --------------------------------------------------------------------------------------
def test_outputs_into_missing_folders_are_created(tmp_path, database):
    plot, wcs = tmp_path / "new" / "deeper" / "sky.png", tmp_path / "other" / "sky.wcs"
    result = _run("solve", EXAMPLE, "--plot", plot, "--wcs", wcs)
    assert result.exit_code == 0, result.output
    assert plot.is_file() and wcs.is_file()


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="needs a non-root POSIX user")
def test_unwritable_output_folder_said_before_solving(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        msg = _one_error(_run("solve", EXAMPLE, "--plot", locked / "sky.png"))
    finally:
        locked.chmod(0o700)
    assert msg == f"--plot: cannot write {locked / 'sky.png'} (permission denied)"


def test_output_never_overwrites_an_input(tmp_path):
    image = tmp_path / "sky.png"
    shutil.copy(EXAMPLE, image)
    msg = _one_error(_run("solve", image, "--plot", tmp_path / "{stem}.png"))
    assert msg == f"--plot {image} would overwrite the input image {image}"


def test_same_named_inputs_get_distinct_outputs(tmp_path, database):
    a, b = tmp_path / "a" / "sky.png", tmp_path / "b" / "sky.png"
    for p in (a, b):
        p.parent.mkdir()
        shutil.copy(EXAMPLE, p)
    out = tmp_path / "out"
    result = _run("solve", a, b, "--plot", out / "{stem}.png", "--wcs", out / "{stem}.wcs")
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in out.iterdir()) == ["a-sky.png", "a-sky.wcs", "b-sky.png", "b-sky.wcs"]


def test_output_names_scheme():
    from skyfix.cli.common import output_names

    names = output_names([Path("a/sky.png"), Path("b/sky.png"), Path("c/moon.png")])
    assert names == ["a-sky", "b-sky", "moon"]
    assert output_names([Path("x/sky.png"), Path("x/sky.fits")]) == ["sky-png", "sky-fits"]
    assert output_names([Path("x/sky.png"), Path("x/sky.png")]) == ["sky", "sky-2"]
    assert output_names([Path("a/sky.png"), Path("a/sky.fits"), Path("b/sky.png")]) == [
        "a-sky-png", "a-sky-fits", "b-sky-png"]


def test_missing_database_and_bad_camera_file_are_named(tmp_path):
    missing = tmp_path / "db.npz"
    assert _one_error(_run("solve", EXAMPLE, "--database", missing)) == (
        f"{missing}: no such pattern database (build one with "
        f"`skyfix database build --fov-min … --fov-max … -o {missing}`)")
    bad = tmp_path / "bad.toml"
    bad.write_text("garbage = [\n")
    msg = _one_error(_run("solve", EXAMPLE, "--camera", bad))
    assert msg.startswith(f"--camera {bad}: not a camera file"), msg
    assert _one_error(_run("solve", EXAMPLE, "--camera", tmp_path / "none.toml")) == (
        f"--camera: no such file {tmp_path / 'none.toml'}")  # named once (issue 28: it was three times)


# --- a batch goes on past a bad file --------------------------------------------------------------
def test_batch_goes_on_past_an_unreadable_file(tmp_path, database):
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    result = _run("solve", "--json", EXAMPLE, empty, EXAMPLE)
    assert result.exit_code == 2
    assert result.stderr.splitlines() == [f"skyfix: error: {empty}: empty file"]
    records = [json.loads(line) for line in result.stdout.splitlines()]
    assert [d["status"] for d in records] == ["solved", "error", "solved"]  # a record for every input
    assert records[1] == {"image": str(empty), "status": "error", "reason": "empty file"}
    # The error line comes between the two images' lines.
    lines = result.output.splitlines()
    assert lines[1].startswith("skyfix: error:") and len(lines) == 4


def test_missing_file_message_names_it_once(tmp_path):
    missing = tmp_path / "nope.png"
    assert _one_error(_run("solve", missing)) == f"{missing}: no such file"


def test_count_flag_given_a_value_says_so(database):
    result = _run("solve", "-v", "1", EXAMPLE)
    assert result.exit_code == 2
    assert "skyfix: error: 1: no such file (-v takes no value: write -v or -vv)" in result.stderr.splitlines()


def test_a_flag_given_a_value_says_so(database):
    # --json true: "true" is read as an image (a flag takes no value); the line says why
    result = _run("detect", "--json", "true", EXAMPLE)
    assert result.exit_code == 2 and result.stderr.splitlines() == [
        "skyfix: error: true: no such file (a flag takes no value: write --json, not --json true)"]


# --- nasty frames ---------------------------------------------------------------------------------
@pytest.mark.parametrize(("kind", "expected"), [
    ("directory", "no images in the folder (FITS, TIFF, PNG or JPEG:"),  # a folder is its images
    ("empty", "empty file"),
    ("nan", "10000 of 10000 pixels are NaN or infinite"),
])
def test_unusable_files_one_line(tmp_path, kind, expected):
    path = tmp_path / "x.fits"
    if kind == "directory":
        path.mkdir()
    elif kind == "empty":
        path.write_bytes(b"")
    else:
        from astropy.io import fits

        fits.PrimaryHDU(np.full((100, 100), np.nan, np.float32)).writeto(path)
    assert _one_error(_run("solve", path)).startswith(f"{path}: {expected}")


@pytest.mark.parametrize(("pixels", "reason"), [
    (np.zeros((480, 640), np.uint8), "blank frame: every pixel is 0 (lens cap on, or no exposure?)"),
    (np.full((480, 640), 255, np.uint8),
     "saturated frame: 100% of the pixels at full scale 255 (overexposed?)"),
    (np.zeros((1, 1), np.uint8),
     "the image is 1×1 pixels, too small for any star field (a solve needs three or "
     "more stars, a few pixels apart: give the whole frame, at least 32×32)"),
])
def test_featureless_frames_fail_saying_which(tmp_path, pixels, reason, database):
    from PIL import Image

    from skyfix.failures import step_to_add

    path = tmp_path / "frame.png"
    Image.fromarray(pixels).save(path)
    result = _run("solve", path)
    assert result.exit_code == 1
    why = f"too few stars detected (0; need at least 3): {reason}"
    step = step_to_add(why)  # the tiny frame's reason says it; a blank or saturated frame's does not
    assert result.stdout == f"{path}: failed: {why}" + (f" — try: {step}" if step else "") + "\n"
    assert bool(step) == ("too small" not in reason)


# --- calibrate frames -----------------------------------------------------------------------------
def _darks(tmp_path, n, exptime=0.1, suffix=".fits"):
    from astropy.io import fits
    from PIL import Image

    rng = np.random.default_rng(5)
    paths = []
    for i in range(n):
        d = rng.normal(30.0, 2.0, (60, 80))
        paths.append(tmp_path / f"dark{i}{suffix}")
        if suffix == ".fits":
            header = fits.Header({"EXPTIME": exptime}) if exptime is not None else None
            fits.PrimaryHDU(d.astype(np.float32), header=header).writeto(paths[-1])
        else:
            Image.fromarray(np.clip(d, 0, 255).astype(np.uint8)).save(paths[-1])
    return paths


def test_calibrate_darks_several_files_after_one_flag(tmp_path):
    darks = _darks(tmp_path, 3)
    result = _run("calibrate", "frames", "--darks", *darks, "-o", tmp_path / "maps" / "maps.fits")
    assert result.exit_code == 0, result.output
    rows = [ln.split() for ln in result.stdout.splitlines() if ln.strip().startswith("0.1")]
    assert len(rows) == 1 and rows[0][1] == "3"  # one exposure, three frames
    assert (tmp_path / "maps" / "maps.fits").is_file()


def test_calibrate_darks_without_exptime_say_so(tmp_path):
    darks = _darks(tmp_path, 3, suffix=".png")
    result = _run("calibrate", "frames", "--darks", *darks, "-o", tmp_path / "maps.fits")
    assert result.exit_code == 0, result.output
    assert result.stderr.splitlines() == [
        "skyfix: note: 3 darks have no exposure time (no EXPTIME or EXPOSURE in a FITS header): "
        "reported together as exposure 'unknown'"]
    rows = [ln.split() for ln in result.stdout.splitlines() if ln.strip().startswith("unknown")]
    assert len(rows) == 1 and rows[0][1] == "3"


def test_calibrate_darks_of_different_sizes(tmp_path):
    from astropy.io import fits

    darks = _darks(tmp_path, 2)
    odd = tmp_path / "odd.fits"
    fits.PrimaryHDU(np.zeros((50, 80), np.float32)).writeto(odd)
    msg = _one_error(_run("calibrate", "frames", "--darks", *darks, odd, "-o", tmp_path / "maps.fits"))
    assert msg == f"{odd}: 80×50 pixels, but {darks[0]} is 80×60: a stack needs frames of one size"


# --- analyses on star-less frames -----------------------------------------------------------------
def test_analyze_psf_on_a_starless_frame(black_png):
    result = _run("analyze", "psf", black_png)
    assert result.exit_code == 1
    assert result.stdout == (f"{black_png}: failed: no isolated unsaturated stars above SNR 10 to measure: "
                             "blank frame: every pixel is 0 (lens cap on, or no exposure?)\n")
    assert "nan" not in result.output


def test_analyze_photometry_on_a_starless_frame(black_png, database):
    result = _run("analyze", "photometry", black_png)
    assert result.exit_code == 1
    assert result.stdout == (f"{black_png.name}: failed: too few stars detected (0; need at least 3): "
                             "blank frame: every pixel is 0 (lens cap on, or no exposure?)\n"
                             "no frame solved: no photometry\n")
    assert "nan" not in result.output


# --- the top level: no traceback, whatever happens ------------------------------------------------
def test_unexpected_exception_is_one_line(monkeypatch):
    import skyfix.detect

    def boom(*args, **kwargs):
        raise RuntimeError("kaboom\nsecond line")

    monkeypatch.setattr(skyfix.detect, "extract_centroids", boom)
    msg = _one_error(_run("detect", EXAMPLE))
    assert msg == f"{EXAMPLE}: internal error: RuntimeError: kaboom (run with -vv for the traceback)"
    result = runner.invoke(app, ["-vv", "detect", str(EXAMPLE)])
    assert result.exit_code == 2
    assert "Traceback (most recent call last)" in result.stderr
    assert result.stderr.rstrip().splitlines()[-1] == (
        f"skyfix: error: {EXAMPLE}: internal error: RuntimeError: kaboom")


def test_interrupt_is_one_line(monkeypatch):
    import skyfix.detect

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(skyfix.detect, "extract_centroids", interrupted)
    result = _run("detect", EXAMPLE)
    assert result.exit_code == 130
    assert result.stderr == "skyfix: interrupted\n"
