"""``skyfix warmup [PATH…]``: compile the numba kernels of every path (or the paths named) now,
in parallel, with the standard band's database built alongside (docs/design.md#compiled-kernels).

:mod:`skyfix.warmup` and the identification package are imported when the command runs: every
``skyfix`` start loads this module.
"""

from __future__ import annotations

import functools

import typer

from skyfix.cli.common import VERBOSE, add_verbosity, fail, guarded
from skyfix.errors import unknown_name
from skyfix.validate import check_count

__all__ = ["warmup_command"]


@guarded
def warmup_command(
    paths: list[str] = typer.Argument(None, metavar="PATH",
                                      help="What to compile (default: everything): see --list."),
    list_paths: bool = typer.Option(False, "--list", help="List the paths, whether each is compiled; exit."),
    workers: int = typer.Option(None, "--workers", help="Processes at once (default: every CPU)."),
    verbose: int = VERBOSE,
) -> None:
    """Compile skyfix's kernels now, on every core, instead of on each feature's first use (once)."""
    add_verbosity(verbose)
    from skyfix import warmup

    names = list(paths) if paths else list(warmup.PATHS)
    unknown = [p for p in names if p not in warmup.PATHS]
    if unknown:
        fail(str(unknown_name("warm-up path", unknown[0], warmup.PATHS)))
    if workers is not None:
        workers = check_count(workers, "--workers")
    if list_paths:
        n = workers or warmup.default_workers()
        for name in names:
            state = ("compiled" if warmup.is_warm(name) else
                     f"to compile: about {warmup.estimate_s(warmup.pending([name]), n):.0f} s on {n} cores")
            typer.echo(f"{name:28s} {state}")
        raise typer.Exit(0)
    from skyfix.identify import default_database, default_database_path

    building = not default_database_path().exists()
    alongside = functools.partial(default_database, progress=False) if building else None
    done = warmup.warm(names, workers=workers, alongside=alongside,
                       also="building the pattern database" if building else "")
    left = [p for p in names if not warmup.is_warm(p)]
    if left:
        fail(f"could not compile {', '.join(left)} ahead of use (see -v); they compile on first use", code=1)
    typer.echo(f"skyfix: {len(names)} path(s) compiled" + ("" if done else " already"))
