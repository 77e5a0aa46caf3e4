"""The shortcut of a plain ``skyfix solve`` (skyfix.cli.solve.plain_solve): it hands the command
exactly what typer would, and leaves everything else to typer.

- For arguments it accepts, the keywords it passes equal the values typer's parser gives the
  command (typer's click context: same types, same numbers), over every option in both spellings
  (``--name VALUE``, ``--name=VALUE``) and two hundred random mixtures.
- What it refuses (help, a bad or odd value, an unknown or repeated option, another command)
  goes to typer, whose messages the other CLI tests check.
- End to end, in a fresh process: the same output and exit status through the shortcut and
  through typer, for a solve and for a missing file; and the shortcut imports no pydantic.
"""

from __future__ import annotations

import functools
import json
import random
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import typer.main

import skyfix
from skyfix.cli import app
from skyfix.cli.solve import plain_solve, solve_parameters
from tests.conftest import EXAMPLES

SRC = Path(skyfix.__file__).resolve().parents[1]
EXAMPLE = EXAMPLES / "sky.png"

#: A valid value for each of solve's options, by its type (the command checks them later).
VALUES = {float: ["10", "17.5", "1e1", "-2.5", "+3", ".5", "5.", "1E-3"], str: ["quest", "a,b", "x.toml"],
          Path: ["out/{stem}.png", "a b.fits", "x"], int: ["1", "2", "16"]}


@functools.cache
def _group():
    return typer.main.get_command(app)


def _typer_values(argv: list[str]) -> tuple[int, dict]:
    """(the -v count before the command, the command's keywords) as typer parses ``argv``."""
    group = _group()
    ctx = group.make_context("skyfix", list(argv))
    rest = [*getattr(ctx, "_protected_args", []), *ctx.args]
    assert rest[0] == "solve"
    sub = group.commands["solve"].make_context("solve", rest[1:], parent=ctx)
    return ctx.params["verbose"], dict(sub.params)


def _same(argv: list[str]) -> None:
    plain = plain_solve(argv)
    assert plain is not None, argv
    assert plain == _typer_values(argv), argv


def test_the_shortcut_reads_every_option_of_solve():
    params = solve_parameters()
    assert params is not None  # every option is of a kind it reads: the shortcut is on
    assert {"fov", "camera_file", "json_out", "plot", "attitude_hint", "smear"} <= set(params)
    for flags, kind, _ in params.values():
        if kind is bool:
            _same(["solve", "sky.png", flags[0]])
            continue
        for value in VALUES[kind]:
            _same(["solve", "sky.png", flags[0], value])
            _same(["solve", f"{flags[0]}={value}", "sky.png"])


def test_random_mixtures_match_typer():
    params = solve_parameters()
    rng = random.Random(22)
    for _ in range(200):
        argv = ["-v"] * rng.randint(0, 2) + ["solve"]
        items = [[f"img{i}.png"] for i in range(rng.randint(1, 3))]
        for name in rng.sample(sorted(params), rng.randint(0, len(params))):
            flags, kind, _ = params[name]
            if kind is bool:
                items.append([flags[0]])
            else:
                value = rng.choice(VALUES[kind])
                items.append([f"{flags[0]}={value}"] if rng.random() < 0.5 else [flags[0], value])
        items += [[rng.choice(["-v", "-vv", "--verbose"])] for _ in range(rng.randint(0, 2))]
        rng.shuffle(items)
        _same(argv + [a for item in items for a in item])


@pytest.mark.parametrize("argv", [
    [], ["--version"], ["-h"], ["solve"], ["solve", "-h"], ["solve", "a.png", "--help"],
    ["detect", "a.png"], ["solve", "a.png", "--fov", "nan"], ["solve", "a.png", "--fov", "1_0"],
    ["solve", "a.png", "--fov", "ten"], ["solve", "a.png", "--fov"], ["solve", "a.png", "--fov="],
    ["solve", "a.png", "--fov", "1", "--fov", "2"], ["solve", "a.png", "--json=1"],
    ["solve", "a.png", "--no-such"], ["solve", "--", "a.png"], ["solve", "-"], ["solve", ""],
    ["solve", "a.png", "--camera", "-x"], ["solve", "a.png", "-x"], ["--json", "solve", "a.png"],
    ["solve", "a.png", "--plot", "--json"], ["solve", "a.png", "--workers", "+2"],
    ["solve", "a.png", "--workers", "2.0"],
])
def test_anything_else_goes_to_typer(argv):
    assert plain_solve(argv) is None


_DRIVER = textwrap.dedent("""
    import contextlib, io, json, sys
    from skyfix.cli import app
    out = []
    for args, via_typer in json.loads(sys.argv[1]):
        o, e = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(o), contextlib.redirect_stderr(e):
            try:  # standalone_mode=True is typer's default: any keyword but prog_name skips the shortcut
                app(args, prog_name="skyfix", **({"standalone_mode": True} if via_typer else {}))
            except SystemExit as exc:
                code = exc.code
        out.append([code, o.getvalue(), e.getvalue()])
    print("\\nRESULT " + json.dumps({"runs": out, "pydantic": "pydantic" in sys.modules}))
""")


def _driver(runs: list) -> dict:
    run = subprocess.run([sys.executable, "-c", _DRIVER, json.dumps(runs)], cwd=SRC, capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(run.stdout.rstrip().rpartition("\nRESULT ")[2])


def _without_times(stdout: str) -> list:
    rows = [json.loads(line) for line in stdout.splitlines()]
    for row in rows:
        row.pop("time_ms", None)  # an error record has none
    return rows


def test_same_output_and_status_either_way(database):
    args = ["solve", str(EXAMPLE), "no-such-image.png", "--json", "--epoch", "2025.0"]
    shortcut = _driver([[args, False]])
    assert not shortcut["pydantic"]  # typer's coercion was skipped
    both = _driver([[args, True], [args, False]])["runs"]
    (code_t, out_t, err_t), (code_s, out_s, err_s) = both
    assert code_t == code_s == 2  # a missing file: exit 2, after the other image's line
    assert err_t == err_s and "no-such-image.png" in err_s
    assert _without_times(out_t) == _without_times(out_s)
    assert _without_times(out_s)[0]["status"] == "solved"
