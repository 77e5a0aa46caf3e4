"""Progress everywhere (issue 28, part 6): off a terminal (a pipe, a log file, CliRunner's
stderr) long steps report one line per step on stderr — ``skyfix: TITLE N/M: STEP (S s)`` — where
a terminal shows a transient bar; a batch of five inputs or more counts N/M."""

from __future__ import annotations

import re
import shutil

from typer.testing import CliRunner

from skyfix.cli import app
from skyfix.cli.common import LineProgress
from tests.conftest import EXAMPLES


def test_line_progress_says_a_line_per_step(capsys):
    with LineProgress() as bar:
        task = bar.add_task("identification study", total=3)
        spinner = bar.add_task("compiling", total=None)  # a spinner prints nothing
        bar.update(spinner, description="compiling… 3 compiled")
        bar.update(task, advance=1, description="15° noise-free")
        bar.update(task, description="safety frames 0–9")  # no advance: no line
        bar.advance(task)
    lines = capsys.readouterr().err.splitlines()
    assert [re.sub(r" \(\d+ s\)$", "", line) for line in lines] == [
        "skyfix: identification study 0/3",
        "skyfix: identification study 1/3: 15° noise-free",
        "skyfix: identification study 2/3: safety frames 0–9",
    ]
    assert all(re.search(r" \(\d+ s\)$", line) for line in lines)


def test_a_batch_counts_its_inputs_on_a_pipe(tmp_path, database):
    for k in range(5):
        shutil.copy(EXAMPLES / "sky.png", tmp_path / f"sky{k}.png")
    result = CliRunner().invoke(app, ["solve", str(tmp_path), "--json"])
    assert result.exit_code == 0, result.output
    assert len(result.stdout.splitlines()) == 5
    counts = [re.fullmatch(r"skyfix: solving (\d)/5 \(\d+ s\)", line) for line in result.stderr.splitlines()]
    assert all(counts) and [int(m.group(1)) for m in counts] == [0, 1, 2, 3, 4, 5], result.stderr


def test_four_inputs_are_not_a_batch(tmp_path, database):
    result = CliRunner().invoke(app, ["solve", *[str(EXAMPLES / "sky.png")] * 2])
    assert result.exit_code == 0 and result.stderr == ""
