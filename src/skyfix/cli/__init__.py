"""The ``skyfix`` command: the command table, ``--version``, and the shortcut of a plain solve.

Exit codes: 0 all images solved; 1 some image failed to solve (its reason is printed);
2 bad input (unreadable file, bad option, corrupt database) with a one-line error — a batch
goes on past a bad file and exits 2 at the end; 130 interrupted. No command prints a
traceback unless asked with ``-vv`` (:mod:`skyfix.cli.common`).

One module a command or command group — :mod:`.solve`, :mod:`.detect`, :mod:`.simulate`,
:mod:`.warmup`, :mod:`.track`, :mod:`.montecarlo`, :mod:`.database`, :mod:`.analyze`,
:mod:`.calibrate` — and :mod:`.common` for what they share; no other skyfix module imports them
(tests/project/test_imports.py). Every ``skyfix`` start, ``--version`` and ``-h`` included,
imports all of them to build the table, so they import at their top only typer and skyfix's
light modules (:mod:`skyfix.cli.common`, :mod:`skyfix.errors`, :mod:`skyfix.validate`); what a
command runs is imported when it runs (tests/cli/test_cli_start.py).
"""

from __future__ import annotations

import sys

import typer

from skyfix import __version__
from skyfix.cli import analyze, cache, calibrate, database, detect, montecarlo, simulate, solve, track, warmup
from skyfix.cli.common import VERBOSE, OneLineErrors, add_verbosity, reset_verbosity

__all__ = ["app", "main"]


class _Skyfix(typer.Typer):
    """typer's app, with one shortcut: a plain ``skyfix solve IMAGE… [OPTIONS]`` (what
    :func:`skyfix.cli.solve.plain_solve` accepts) calls the command directly, skipping typer's
    value coercion, which imports pydantic and builds a validator per option (~0.15 s of CPU of
    the process). Anything else — help, a bad or unusual value, another command — goes through
    typer as before, so its messages and help are typer's own (tests/cli/test_cli_fast_path.py:
    the shortcut passes the command what typer would)."""

    def __call__(self, *args, **kwargs):
        argv = None  # the shortcut only for app() and app(ARGS[, prog_name=…]), as click reads them
        if not args and not kwargs:
            argv = sys.argv[1:]
        elif len(args) == 1 and isinstance(args[0], (list, tuple)) and set(kwargs) <= {"prog_name"}:
            argv = list(args[0])
        plain = None
        if argv is not None and all(isinstance(a, str) for a in argv):
            plain = solve.plain_solve(argv)
        if plain is None:
            return super().__call__(*args, **kwargs)
        verbose, options = plain
        try:
            main_options(version=False, verbose=verbose)
            solve.solve(**options)
        except typer.Exit as exc:  # as click's standalone mode does
            sys.exit(exc.exit_code)
        sys.exit(0)


# rich_markup_mode=None: help and usage errors as plain text (click's formatter), without rich's
# import (0.11 s of `skyfix -h`)
app = _Skyfix(cls=OneLineErrors, add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
              rich_markup_mode=None, context_settings={"help_option_names": ["-h", "--help"]},
              help="skyfix — a star tracker: solve sky images for the camera's attitude.")


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"skyfix {__version__}")
        raise typer.Exit()


@app.callback()
def main_options(
    version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True,
                                 help="Print the version and exit."),
    verbose: int = VERBOSE,
) -> None:
    """skyfix — a star tracker: solve sky images for the camera's attitude."""
    reset_verbosity()
    add_verbosity(verbose)


# The command table, in the order -h lists it (commands first, then the groups).
app.command("solve", epilog=solve.OUTPUT_NAMES_HELP)(solve.solve)
app.command("detect")(detect.detect)
app.command("simulate")(simulate.simulate)
app.command("warmup")(warmup.warmup_command)
app.command("track")(track.track)
app.command("montecarlo")(montecarlo.montecarlo)
app.add_typer(database.database_app, name="database")
app.add_typer(analyze.analyze_app, name="analyze")
app.add_typer(calibrate.calibrate_app, name="calibrate")
app.add_typer(cache.cache_app, name="cache")


def main() -> None:  # pragma: no cover - console entry point
    app()
