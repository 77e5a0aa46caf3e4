"""``skyfix cache info|clear``: where skyfix keeps what it builds on first use, how big it is,
and removing it.

Two places: the user cache (:func:`skyfix.cache.cache_dir`, ``$SKYFIX_CACHE`` overrides it) with
the parsed star catalogues and the pattern databases, each rebuilt on first need; and numba's
compiled kernels, ``*.nbi``/``*.nbc`` in the ``__pycache__`` folders beside skyfix's sources
(and under ``$NUMBA_CACHE_DIR`` when set), recompiled on first use, and the modules ``skyfix
warmup`` compiles ahead of time (:func:`skyfix._jit.aot_folder`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import typer

from skyfix.cli.common import VERBOSE, OneLineErrors, add_verbosity, fail, guarded

__all__ = ["CacheArea", "cache_app", "cache_areas", "cache_clear", "cache_info"]

cache_app = typer.Typer(cls=OneLineErrors, no_args_is_help=True, rich_markup_mode=None,
                        help="Where the user cache and the compiled kernels live; clear them.")

#: The areas ``--only`` names.
AREAS = ("data", "kernels")


class CacheArea(NamedTuple):
    """One place skyfix caches in: its name (:data:`AREAS`), what it holds, its folders and files."""

    name: str
    what: str
    folders: tuple[Path, ...]
    files: tuple[Path, ...]

    @property
    def size_bytes(self) -> int:
        return sum(_size(f) for f in self.files)


def cache_areas() -> list[CacheArea]:
    """The user cache (catalogues, pattern databases) and the compiled kernels, as they are now."""
    import skyfix
    from skyfix._jit import aot_folder
    from skyfix.cache import cache_dir

    user = cache_dir()
    ahead = aot_folder()  # the kernels compiled ahead of time (beside the sources, or in the user cache)
    data = tuple(sorted(p for p in user.rglob("*") if p.is_file() and ahead not in p.parents)) \
        if user.is_dir() else ()
    package = Path(skyfix.__file__).resolve().parent
    folders = [package] + ([ahead] if package not in ahead.parents else [])
    kernels = [p for p in package.rglob("__pycache__/*") if p.suffix in (".nbi", ".nbc")]
    kernels += [p for p in ahead.glob("*") if p.is_file()] if ahead.is_dir() else []
    extra = os.environ.get("NUMBA_CACHE_DIR")
    if extra and Path(extra).is_dir():
        folders.append(Path(extra))
        kernels += [p for p in Path(extra).rglob("*") if p.suffix in (".nbi", ".nbc")]
    return [CacheArea("data", "star catalogues and pattern databases", (user,), data),
            CacheArea("kernels", "compiled kernels (numba's cache and skyfix warmup's modules)",
                      tuple(folders), tuple(sorted(kernels)))]


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


def _chosen(only: str | None) -> list[CacheArea]:
    if only is not None and only.lower() not in AREAS:
        fail(f"--only takes one of {', '.join(AREAS)}, not {only!r}")
    return [a for a in cache_areas() if only is None or a.name == only.lower()]


@cache_app.command("info")
@guarded
def cache_info(
    only: str = typer.Option(None, "--only", metavar="data|kernels", help="One area: data or kernels."),
    verbose: int = VERBOSE,
) -> None:
    """Where the user cache (catalogues, pattern databases) and the compiled kernels live, and their sizes."""
    add_verbosity(verbose)
    for area in _chosen(only):
        where = ", ".join(map(str, area.folders))
        typer.echo(f"{area.name}: {area.what}: {len(area.files)} files, {_mb(area.size_bytes)} in {where}")
        if area.name == "data":
            for f in area.files:
                if f.suffix == ".npz":
                    typer.echo(f"  {f.name}  {_mb(_size(f))}")


@cache_app.command("clear")
@guarded
def cache_clear(
    only: str = typer.Option(None, "--only", metavar="data|kernels", help="One area: data or kernels."),
    dry_run: bool = typer.Option(False, "--dry-run", help="Say what would be removed; remove nothing."),
    verbose: int = VERBOSE,
) -> None:
    """Remove the user cache and the compiled kernels (rebuilt on first need: about a minute each);
    one line per area says what was removed."""
    add_verbosity(verbose)
    for area in _chosen(only):
        removed = 0
        size = area.size_bytes
        for f in area.files:
            if dry_run:
                continue
            try:
                f.unlink()
                removed += 1
            except FileNotFoundError:
                pass
            except OSError as exc:
                fail(f"cannot remove {f} ({exc.strerror or type(exc).__name__})")
        verb = "would remove" if dry_run else "removed"
        count = len(area.files) if dry_run else removed
        typer.echo(f"{area.name}: {verb} {count} files, {_mb(size)} ({area.what}) from "
                   f"{', '.join(map(str, area.folders))}")
