"""An all-sky fisheye frame on the command line (issue 26 part 3): solved with no camera file
and the zenith's pixel in the JSON; given a pinhole camera file, or a mask of another size, one
``skyfix: error:`` line (exit 2)."""

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from skyfix.camera import Camera
from skyfix.cli import app
from skyfix.simulate.allsky import all_sky_camera, random_landscape, render_allsky
from skyfix.simulate.truth import write_frame

runner = CliRunner()
SITE, TIME = "40,-105", "2026-03-01T05:00:00"


@pytest.fixture(scope="module")
def allsky_png(tmp_path_factory):
    cam = all_sky_camera(1024, 768, 185.0, offset_px=(9.0, -6.0))
    frame = render_allsky(cam, site=(40.0, -105.0), time=TIME, fov_deg=185.0, tilt_deg=2.5, seed=3,
                          landscape=random_landscape(np.random.default_rng(4)))
    path = tmp_path_factory.mktemp("allsky") / "allsky.png"
    write_frame(frame, path)
    return path, frame.truth


def _one_error(result) -> str:
    assert result.exit_code == 2, result.output
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("skyfix: error: "), result.stderr
    return lines[0]


def test_allsky_solve_json_zenith(allsky_png):
    path, truth = allsky_png
    result = runner.invoke(app, ["solve", str(path), "--site", SITE, "--time", TIME, "--refraction", "none",
                                 "--json"])
    assert result.exit_code == 0, result.output
    record = json.loads(result.stdout)
    assert record["status"] == "solved" and record["camera"]["projection"] == "kannala-brandt"
    assert math.dist(record["zenith_px"], truth["zenith_px"]) < 0.5


def test_allsky_with_pinhole_camera_file(allsky_png, tmp_path):
    path, _ = allsky_png
    camera = tmp_path / "pinhole.toml"
    Camera.from_fov(1024, 768, 120.0).save(camera)
    line = _one_error(runner.invoke(app, ["solve", str(path), "--camera", str(camera)]))
    assert "all-sky fisheye frame" in line and "kannala-brandt camera file" in line


def test_allsky_with_mask_of_another_size(allsky_png, tmp_path):
    from PIL import Image

    path, _ = allsky_png
    mask = tmp_path / "mask.png"
    Image.fromarray(np.full((500, 600), 255, np.uint8)).save(mask)
    line = _one_error(runner.invoke(app, ["solve", str(path), "--mask", str(mask)]))
    assert "a mask must be the image's size" in line
