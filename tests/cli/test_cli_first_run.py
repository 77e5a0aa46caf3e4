"""A command line that talks: --version, -h, counted -v/-vv, a notice while numba compiles (the
first run), and failure reasons that say what to try."""

import io
import logging

import numpy as np
import pytest
from typer.testing import CliRunner

import skyfix
from skyfix.cli import app
from skyfix.errors import DatabaseError
from tests.conftest import EXAMPLES

EXAMPLE = EXAMPLES / "sky.png"
runner = CliRunner()


def test_version():
    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0
    assert result.stdout == f"skyfix {skyfix.__version__}\n"


@pytest.mark.parametrize("args", [["-h"], ["solve", "-h"], ["database", "build", "-h"],
                                  ["analyze", "psf", "-h"]])
def test_short_help(args):
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "Usage:" in result.stdout and "--help" in result.stdout


def test_help_documents_the_output_names():
    result = runner.invoke(app, ["solve", "--help"])
    assert "a-sky" in result.stdout  # same-named inputs: the folder name in front


def test_verbose_is_counted_before_or_after_the_command(database):
    for args in (["-vv", "solve", str(EXAMPLE)], ["solve", "-vv", str(EXAMPLE)],
                 ["-v", "solve", "-v", str(EXAMPLE)]):
        result = runner.invoke(app, args)
        assert result.exit_code == 0, result.output
        assert "DEBUG skyfix" in result.stderr or "INFO skyfix" in result.stderr
        # -vv is skyfix's own debug output: numba's and Pillow's loggers stay quiet.
        logged = [ln.split()[1] for ln in result.stderr.splitlines() if ln.startswith(("DEBUG", "INFO"))]
        assert logged and all(name.startswith("skyfix") for name in logged), logged
    assert logging.getLogger("numba").getEffectiveLevel() >= logging.WARNING
    quiet = runner.invoke(app, ["solve", str(EXAMPLE)])
    assert quiet.exit_code == 0 and quiet.stderr == ""


def test_compile_notice_shows_only_while_numba_compiles():
    import numba
    from rich.console import Console

    from skyfix.cli.common import compile_notice

    out = io.StringIO()
    console = Console(file=out, force_terminal=True, width=100)
    with compile_notice(console=console):
        np.sum(np.arange(3))  # no compiling: no display
    assert out.getvalue() == ""
    fresh = numba.njit(lambda x: x + 1)  # never compiled: cache=False
    with compile_notice(console=console):
        assert fresh(1) == 2
    assert "compiling numba kernels (first use)" in out.getvalue()


def test_first_run_database_notice(tmp_path, monkeypatch):
    """With no cached database, solve says it is building one (here the build itself is faked)."""
    import skyfix.identify

    monkeypatch.setenv("SKYFIX_CACHE", str(tmp_path))

    def fake_default_database(*args, **kwargs):
        raise DatabaseError("stop here")

    monkeypatch.setattr(skyfix.identify, "default_database", fake_default_database)
    result = runner.invoke(app, ["solve", str(EXAMPLE)])
    assert result.stderr.splitlines() == [
        "skyfix: first run: building the pattern database (once; about 10 s)…",
        "skyfix: error: stop here"]


def test_fov_outside_database_range_says_how_to_build_one(database):
    """Below the fine band (0.74°) the bundled catalogue is too shallow: the advice is a database
    from a deeper catalogue file."""
    result = runner.invoke(app, ["solve", "--fov", "0.6", str(EXAMPLE)])
    assert result.exit_code == 1
    assert result.stdout == (
        f"{EXAMPLE}: failed: field of view 0.6° is outside every default FOV band "
        "(they serve 0.741–122°): a field this narrow holds about 3 stars of the bundled catalogue "
        "(Gaia to G 10), too few to identify; build a database from a deeper catalogue file "
        "(docs/catalogues.md#a-deeper-catalogue): "
        "`skyfix database build --fov-min 0.54 --fov-max 0.66 --catalog DEEP.csv "
        "-o patterns-0.54-0.66deg.npz`, "
        "then `skyfix solve --database patterns-0.54-0.66deg.npz ...`\n")


def test_mirror_image_is_named(tmp_path, database):
    from PIL import Image

    mirrored = tmp_path / "mirrored.png"
    with Image.open(EXAMPLE) as im:
        im.transpose(Image.Transpose.FLIP_LEFT_RIGHT).save(mirrored)
    result = runner.invoke(app, ["solve", str(mirrored)])
    assert result.exit_code == 1
    assert result.stdout.endswith("but the stars match the sky mirrored left-right: a mirror image "
                                  "(solve it with --parity mirrored or either; parity= in Python)\n")
