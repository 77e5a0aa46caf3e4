"""``skyfix solve --workers N`` / ``--scheduler ADDRESS`` (issue 27 part 6): the inputs solved on a
Dask cluster in batches, one record per input in input order, a bad input a record with its
reason; a scheduler that cannot be reached is a one-line error."""

from __future__ import annotations

import json
import shutil

import pytest
from typer.testing import CliRunner

from skyfix.cli import app
from tests.conftest import EXAMPLES

SKY = EXAMPLES / "sky.png"


@pytest.mark.slow
def test_a_batch_on_two_workers_gives_the_records_of_one_process_in_input_order(tmp_path):
    inputs = []
    for k in range(5):  # two batches of BATCH = 4 and a broken file in between
        if k == 2:
            broken = tmp_path / "broken.png"
            broken.write_bytes(b"\x89PNG\r\n\x1a\n not a png")
            inputs.append(broken)
        copy = tmp_path / f"sky{k}.png"
        shutil.copy(SKY, copy)
        inputs.append(copy)
    args = ["solve", *map(str, inputs), "--json"]
    alone = CliRunner().invoke(app, args)
    batch = CliRunner().invoke(app, [*args, "--workers", "2"])
    assert alone.exit_code == batch.exit_code == 2  # an input could not be read
    one = [json.loads(line) for line in alone.stdout.splitlines()]
    two = [json.loads(line) for line in batch.stdout.splitlines()]
    assert [r["image"] for r in two] == [str(p) for p in inputs]
    assert [r["status"] for r in two] == ["solved"] * 2 + ["error"] + ["solved"] * 3
    for a, b in zip(one, two, strict=True):
        assert a["status"] == b["status"] and a["reason"] == b["reason"]
        if a["status"] == "solved":
            assert a["quaternion_xyzw"] == b["quaternion_xyzw"]  # bit for bit, on a worker


@pytest.mark.parametrize(("args", "message"), [
    (["--workers", "0"], "--workers must be ≥ 1, got 0"),
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:8786"], "give --workers or --scheduler, not both"),
    (["--scheduler", "nowhere"], "--scheduler 'nowhere' is not a Dask scheduler's address"),
])
def test_bad_cluster_options_are_one_line(args, message):
    result = CliRunner().invoke(app, ["solve", str(SKY), *args])
    assert result.exit_code == 2 and message in result.output
    assert len(result.output.strip().splitlines()) == 1


@pytest.mark.slow
def test_an_unreachable_scheduler_is_one_line():
    result = CliRunner().invoke(app, ["solve", str(SKY), "--scheduler", "tcp://127.0.0.1:9"])
    assert result.exit_code == 2, result.output
    assert "cannot reach the Dask scheduler at tcp://127.0.0.1:9" in result.output
    assert len(result.output.strip().splitlines()) == 1
