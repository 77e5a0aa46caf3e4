"""``skyfix warmup [PATH…]``: compile skyfix's kernels now — by default every kernel ahead of time
into extension modules (:mod:`skyfix.aot`), after which no ``skyfix`` process imports numba for
them; with PATHs (or ``--jit``, or without a C compiler) the numba kernels of those paths into
numba's cache — in parallel, with the standard band's database built alongside
(docs/design.md#compiled-kernels).

:mod:`skyfix.warmup`, :mod:`skyfix.aot` and the identification package are imported when the
command runs: every ``skyfix`` start loads this module.
"""

from __future__ import annotations

import functools
import sys
import time
from collections.abc import Callable

import typer

from skyfix.cli.common import VERBOSE, add_verbosity, fail, guarded
from skyfix.errors import unknown_name
from skyfix.validate import check_count

__all__ = ["warmup_command"]


@guarded
def warmup_command(
    paths: list[str] = typer.Argument(None, metavar="PATH",
                                      help="What to compile with numba (default: everything, ahead of time): "
                                           "see --list."),
    list_paths: bool = typer.Option(False, "--list", help="List the paths, whether each is compiled; exit."),
    jit: bool = typer.Option(False, "--jit", help="Compile into numba's cache instead of ahead of time."),
    workers: int = typer.Option(None, "--workers", help="Processes at once (default: every CPU)."),
    verbose: int = VERBOSE,
) -> None:
    """Compile skyfix's kernels now, on every core, instead of on each feature's first use (once)."""
    add_verbosity(verbose)
    from skyfix import aot, warmup

    names = list(paths) if paths else list(warmup.PATHS)
    unknown = [p for p in names if p not in warmup.PATHS]
    if unknown:
        fail(str(unknown_name("warm-up path", unknown[0], warmup.PATHS)))
    if workers is not None:
        workers = check_count(workers, "--workers")
    n = workers or warmup.default_workers()
    if list_paths:
        if aot.is_built():
            typer.echo(f"{'(every path)':28s} compiled ahead of time")
        for name in names:
            state = ("compiled" if warmup.is_warm(name) else
                     f"to compile: about {warmup.estimate_s(warmup.pending([name]), n):.0f} s on {n} cores")
            typer.echo(f"{name:28s} {state}")
        raise typer.Exit(0)
    from skyfix.identify import default_database, default_database_path

    building = not default_database_path().exists()
    alongside = functools.partial(default_database, progress=False) if building else None
    if not paths and not jit:
        if aot.is_built():
            if alongside is not None:
                alongside()
            typer.echo("skyfix: every kernel compiled ahead of time already")
            return
        try:
            _compile_ahead(n, alongside, "building the pattern database" if building else "")
            return
        except RuntimeError as exc:  # no C compiler, a compile error: numba's cache instead
            typer.echo(f"skyfix: {exc}; compiling with numba instead", err=True)
            alongside = None
    done = warmup.warm(names, workers=workers, alongside=alongside,
                       also="building the pattern database" if building else "")
    left = [p for p in names if not warmup.is_warm(p)]
    if left:
        fail(f"could not compile {', '.join(left)} ahead of use (see -v); they compile on first use", code=1)
    typer.echo(f"skyfix: {len(names)} path(s) compiled" + ("" if done else " already"))


def _compile_ahead(workers: int, alongside: Callable[[], object] | None, also: str) -> None:
    """:func:`skyfix.aot.build` with its notice: a bar on a terminal, a line an area on a pipe."""
    from rich.console import Console

    from skyfix import aot

    eta = aot.estimate_s(workers)
    what = "compiling every kernel ahead of time" + (f", {also}" if also else "")
    line = f"{what} (once; about {eta / 60:.0f} min on {workers} cores)…"
    console = Console(stderr=True)
    t0 = time.perf_counter()
    if console.is_terminal:
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        columns = (TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                   TimeElapsedColumn())
        with Progress(*columns, console=console, transient=True) as bar:
            task = bar.add_task(f"skyfix: {line}", total=len(aot.AREAS))
            aot.build(workers=workers, alongside=alongside, on_area=lambda area, s: bar.advance(task))
    else:
        print(f"skyfix: {line}", file=sys.stderr, flush=True)
        aot.build(workers=workers, alongside=alongside,
                  on_area=lambda area, s: print(f"skyfix: compiled the {area} kernels ({s:.0f} s of CPU)",
                                                file=sys.stderr, flush=True))
    typer.echo(f"skyfix: every kernel compiled ahead of time in {time.perf_counter() - t0:.0f} s "
               f"({aot.folder_text()})")
