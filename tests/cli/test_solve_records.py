"""``skyfix solve`` gives a record for every input (issue 28, part 3) and takes folders, list
files and centroid tables (part 7): one JSON line per input, in input order, unreadable files
(``status: "error"``) and blank frames (``"failed"``) included, each with ``status`` and
``reason`` (``""`` when solved); the fitted camera in the JSON and in ``--save-camera FILE.toml``,
which the next frame of that camera solves with."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from skyfix.camera import Camera
from skyfix.cli import app


def _run(*args) -> tuple[int, list[dict], str]:
    result = CliRunner().invoke(app, ["solve", *map(str, args), "--json"])
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    return result.exit_code, [json.loads(line) for line in result.stdout.splitlines()], result.stderr


@pytest.fixture
def bad_inputs(tmp_path):
    """An unreadable file (text named .png) and a blank frame."""
    broken = tmp_path / "broken.png"
    broken.write_text("not an image")
    blank = tmp_path / "blank.png"
    Image.fromarray(np.full((480, 640), 20, np.uint8)).save(blank)
    return broken, blank


@pytest.fixture(scope="module")
def esa(real_dir):
    return sorted((real_dir / "esa-tetra3").glob("*.tiff"))


def _check_records(records, inputs):
    assert [r["image"] for r in records] == [str(p) for p in inputs]
    for r in records:
        assert r["status"] in ("solved", "failed", "error") and isinstance(r["reason"], str)
        assert (r["reason"] == "") == (r["status"] == "solved"), r
        if r["status"] != "error":
            assert (r["camera"] is not None) == (r["status"] == "solved")


def test_a_record_for_every_input_in_order(esa, bad_inputs, tmp_path):
    broken, blank = bad_inputs
    missing = tmp_path / "missing.png"
    inputs = [broken, esa[0], blank, missing]
    code, records, stderr = _run(*inputs)
    said = [f"skyfix: error: {records[i]['image']}: {records[i]['reason']}" for i in (0, 3)]
    assert code == 2 and stderr.splitlines() == said  # the errors on stderr too
    _check_records(records, inputs)
    assert [r["status"] for r in records] == ["error", "solved", "failed", "error"]
    assert set(records[0]) == set(records[3]) == {"image", "status", "reason"}
    assert "not an image" in records[0]["reason"] and "blank frame" in records[2]["reason"]
    assert "no such file" in records[3]["reason"]


@pytest.mark.slow
def test_the_21_real_images_and_two_bad_inputs_give_23_records(real_dir, bad_inputs):
    """The issue's case: the shared real images (two folders, sorted), an unreadable file and a
    blank frame in one batch: 23 lines in input order, each with status and reason."""
    broken, blank = bad_inputs
    folders = [real_dir / "cedar-solve", real_dir / "esa-tetra3"]
    images = [p for f in folders for p in sorted(f.iterdir()) if p.suffix in (".jpg", ".tiff")]
    assert len(images) == 21
    code, records, _ = _run(*folders, broken, blank)
    assert len(records) == 23
    _check_records(records, [*images, broken, blank])
    assert [r["status"] for r in records] == ["solved"] * 21 + ["error", "failed"]
    assert code == 2


def _sigma(record) -> np.ndarray:
    return np.sqrt(np.diag(record["covariance_arcsec2"]))


def _offsets_arcsec(a, b) -> np.ndarray:
    """RA (on the sky), Dec and roll differences of two records, arcseconds."""
    d_ra = ((a["ra_deg"] - b["ra_deg"] + 180) % 360 - 180) * math.cos(math.radians(a["dec_deg"]))
    d_roll = (a["roll_deg"] - b["roll_deg"] + 180) % 360 - 180
    return np.array([d_ra, a["dec_deg"] - b["dec_deg"], d_roll]) * 3600


def test_save_camera_is_the_json_camera_and_solves_the_next_frame(esa, tmp_path):
    saved = tmp_path / "esa.toml"
    code, (first,), _ = _run(esa[0], "--save-camera", saved)
    assert code == 0
    camera = Camera.load(saved)
    assert Camera.from_dict(first["camera"]) == camera and camera.k1 != 0  # fitted, distortion too
    assert math.isclose(camera.fov_deg, first["fov_deg"], rel_tol=1e-12)
    code, (nxt,), _ = _run(esa[1], "--camera", saved)
    assert code == 0 and nxt["status"] == "solved" and Camera.from_dict(nxt["camera"]) == camera


@pytest.mark.slow
def test_the_camera_of_one_esa_frame_solves_the_other_seven(esa, tmp_path):
    """--save-camera from one ESA frame, then the other seven solved with that file: all solved,
    each attitude within 3σ (the two solves' σ combined) of the frame solved on its own camera."""
    saved = tmp_path / "esa.toml"
    assert CliRunner().invoke(app, ["solve", str(esa[0]), "--save-camera", str(saved)]).exit_code == 0
    code, with_file, _ = _run(*esa[1:], "--camera", saved)
    _, alone, _ = _run(*esa[1:])
    assert code == 0 and len(with_file) == 7
    for a, b in zip(with_file, alone, strict=True):
        assert a["status"] == b["status"] == "solved"
        combined, offsets = np.hypot(_sigma(a), _sigma(b)), _offsets_arcsec(a, b)
        assert np.all(np.abs(offsets) < 3 * combined), (a["image"], offsets, combined)
        assert np.all(_sigma(a) < 15)


def test_a_folder_is_its_images_sorted(esa, bad_inputs, tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    shutil.copy(esa[0], folder / "b.tiff")
    shutil.copy(bad_inputs[0], folder / "a.png")
    (folder / "notes.txt").write_text("not an input")
    code, records, _ = _run(folder)
    _check_records(records, [folder / "a.png", folder / "b.tiff"])
    assert [r["status"] for r in records] == ["error", "solved"] and code == 2


def test_a_list_file_names_paths_relative_to_itself(esa, bad_inputs, tmp_path):
    broken, blank = bad_inputs
    listing = tmp_path / "list.txt"
    listing.write_text(f"# tonight's frames\n{blank.name}\n\n{esa[0]}\n")
    code, records, _ = _run(f"@{listing}")
    _check_records(records, [blank, esa[0]])
    assert [r["status"] for r in records] == ["failed", "solved"] and code == 1


@pytest.mark.parametrize(("args", "words"), [
    (["@/nonexistent/list.txt"], "cannot read the list file"),
    (["--centroids", "c.csv"], "--centroids needs --size"),
    (["--size", "10,10", "x.png"], "--size is the frame size of a --centroids table"),
    (["--centroids", "c.csv", "--size", "10"], "--size wants"),
    ([], "give images to solve"),
])
def test_bad_inputs_are_one_line(args, words):
    result = CliRunner().invoke(app, ["solve", *args])
    assert result.exit_code == 2 and result.stdout == ""
    assert result.stderr.startswith("skyfix: error: ") and words in result.stderr
    assert len(result.stderr.splitlines()) == 1


def test_a_centroid_table_solves_as_its_image(esa, tmp_path):
    """The image's own centroids as x,y,flux (shuffled: flux sorts them) solve to the image's
    attitude."""
    detected = CliRunner().invoke(app, ["detect", str(esa[0]), "--json"])
    stars = json.loads(detected.stdout)["centroids"]
    rows = [f"{s['x']!r},{s['y']!r},{s['flux']!r}" for s in stars]
    rng = np.random.default_rng(1)
    table = tmp_path / "stars.csv"
    table.write_text("x,y,flux\n" + "\n".join(rng.permutation(rows)) + "\n")
    code, (from_table,), _ = _run("--centroids", table, "--size", "1024,768")
    _, (from_image,), _ = _run(esa[0])
    assert code == 0 and from_table["status"] == "solved" and from_table["image"] == str(table)
    assert from_table["n_matched"] == from_image["n_matched"]
    assert np.all(np.abs(_offsets_arcsec(from_table, from_image)) < 0.01)


def test_a_bad_centroid_row_is_an_error_record(tmp_path):
    table = tmp_path / "stars.csv"
    table.write_text("x,y\n1,2\n3,four\n")
    code, (record,), _ = _run("--centroids", table, "--size", "100,100")
    assert code == 2 and record["status"] == "error" and "row 2" in record["reason"]


def test_parquet_holds_the_json_records_row_for_row(bad_inputs, tmp_path):
    import pyarrow.parquet as pq

    from tests.conftest import EXAMPLES

    broken, blank = bad_inputs
    out = tmp_path / "batch.parquet"
    code, records, _ = _run(EXAMPLES / "sky.png", broken, blank, "--parquet", out)
    assert code == 2 and [r["status"] for r in records] == ["solved", "error", "failed"]
    table = pq.read_table(out).to_pylist()
    assert [row["image"] for row in table] == [r["image"] for r in records]
    assert [row["status"] for row in table] == ["solved", "error", "failed"]
    assert [row["reason"] for row in table] == [r["reason"] for r in records]
    solved = table[0]
    for key in ("ra_deg", "dec_deg", "roll_deg", "prob_false", "rmse_arcsec"):
        assert solved[key] == records[0][key]  # bit for bit
    assert solved["n_matched"] == records[0]["n_matched"] and isinstance(solved["n_matched"], int)
    assert json.loads(solved["quaternion_xyzw"]) == records[0]["quaternion_xyzw"]
    assert json.loads(solved["covariance_arcsec2"]) == records[0]["covariance_arcsec2"]
    assert table[1]["ra_deg"] is None and table[1]["reason"]  # the error's row: its reason, no numbers
