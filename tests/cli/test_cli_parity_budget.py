"""The command line's image-centre summary, --parity and `skyfix analyze budget` (issues 26, 27)."""

import json
import re

import pytest
from PIL import Image
from typer.testing import CliRunner

from skyfix.cli import app
from tests.conftest import EXAMPLES

runner = CliRunner()
EXAMPLE = EXAMPLES / "sky.png"
_RA_DEC = re.compile(r"solved RA ([0-9.]+)° Dec ([+-][0-9.]+)° roll ([0-9.]+)°")


def _numbers(line: str) -> tuple[float, float, float]:
    m = _RA_DEC.search(line)
    assert m, line
    return float(m[1]), float(m[2]), float(m[3])


def test_mirror_image_solves_with_parity_and_says_so(tmp_path, database):
    mirrored = tmp_path / "mirrored.png"
    with Image.open(EXAMPLE) as im:
        im.transpose(Image.Transpose.FLIP_LEFT_RIGHT).save(mirrored)
    normal = runner.invoke(app, ["solve", str(EXAMPLE)])
    assert normal.exit_code == 0, normal.stdout
    for parity in ("mirrored", "either"):
        result = runner.invoke(app, ["solve", str(mirrored), "--parity", parity])
        assert result.exit_code == 0, result.stdout
        assert "| mirror image" in result.stdout
        ra, dec, roll = _numbers(result.stdout)
        ra0, dec0, roll0 = _numbers(normal.stdout)
        assert abs(ra - ra0) < 1e-3 and abs(dec - dec0) < 1e-3 and abs(roll - roll0) < 0.01
    j = json.loads(runner.invoke(app, ["solve", str(mirrored), "--parity", "mirrored", "--json"]).stdout)
    assert j["mirrored"] is True and j["status"] == "solved"
    bad = runner.invoke(app, ["solve", str(mirrored), "--parity", "sideways"])
    assert bad.exit_code == 2
    lines = bad.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("skyfix: error: --parity") and "either" in lines[0]


def test_summary_gives_the_image_centre_and_names_an_off_centre_boresight(real_dir, database):
    """orion_trees.jpg: the stars fit the principal point 98 px above the centre; the summary's
    RA/Dec are the centre's (astrometry.net's reference: 86.85181°, +0.49933°) and the boresight
    is named beside them."""
    result = runner.invoke(app, ["solve", str(real_dir / "cedar-solve" / "orion_trees.jpg")])
    assert result.exit_code == 0, result.stdout
    ra, dec, _ = _numbers(result.stdout)
    assert abs(ra - 86.85181) < 0.01 and abs(dec - 0.49933) < 0.01
    assert "| boresight at (" in result.stdout
    plain = runner.invoke(app, ["solve", str(EXAMPLE)])
    assert "boresight at" not in plain.stdout


def test_analyze_budget_prints_and_exports_the_camera_budget():
    result = runner.invoke(app, ["analyze", "budget", "--camera", "sunsat", "--pointings", "30"])
    assert result.exit_code == 0, result.stdout
    assert "limiting magnitude 7." in result.stdout and "Droid X2: total 5.4" in result.stdout
    j = json.loads(runner.invoke(app, ["analyze", "budget", "--camera", "sunsat", "--pointings", "30",
                                       "--json"]).stdout)
    assert 6.5 <= j["limiting_mag"] <= 8.0 and j["saturation_mag"] == pytest.approx(3.0)
    assert len(j["rows"]) > 20 and j["rows"][0]["mag"] == -1.0
    bad = runner.invoke(app, ["analyze", "budget", "--camera", "nope"])
    assert bad.exit_code == 2 and bad.stderr.strip().startswith("skyfix: error: --camera")
