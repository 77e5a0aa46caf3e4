"""``skyfix database build``: a lost-in-space pattern database for a FOV range, or the default
FOV bands into the user cache.

The identification package (numpy, numba) is imported when a build runs, not when the command
table is set up: every ``skyfix`` start loads this module.
"""

from __future__ import annotations

import time
from pathlib import Path

import typer

from skyfix.cli.common import VERBOSE, OneLineErrors, add_verbosity, guarded, prepare_outputs
from skyfix.validate import check_fov_range

__all__ = ["database_app", "database_build"]

database_app = typer.Typer(cls=OneLineErrors, no_args_is_help=True, rich_markup_mode=None,
                           help="Build or inspect the pattern database.")


@database_app.command("build")
@guarded
def database_build(
    fov_min: float = typer.Option(10.0, help="Smallest field of view, degrees."),
    fov_max: float = typer.Option(30.0, help="Largest field of view, degrees."),
    output: Path = typer.Option(None, "--output", "-o", help="Where to write (default: user cache)."),
    default_bands: bool = typer.Option(False, "--default-bands",
                                       help="Build every default FOV band (2–90°) into the user cache now, "
                                            "instead of on first need."),
    verbose: int = VERBOSE,
) -> None:
    """Build the lost-in-space pattern database for a FOV range (it serves fields about 1.35×
    beyond it on either side), or every default FOV band (--default-bands)."""
    add_verbosity(verbose)
    from skyfix.identify import PatternDatabase, default_database_path

    if default_bands:
        from skyfix.identify import BANDS, band_database

        for band in BANDS:
            t0 = time.perf_counter()
            db = band_database(band, progress=True)
            lo, hi = band.served_fov_deg
            typer.echo(f"{band.name}: {band.path} ({len(db)} patterns of {len(db.star_ids)} stars, serves "
                       f"{lo:.3g}–{hi:.3g}°, {band.path.stat().st_size / 1e6:.0f} MB, "
                       f"{time.perf_counter() - t0:.1f} s)")
        return

    check_fov_range(fov_min, fov_max, ("--fov-min", "--fov-max"))
    path = output or default_database_path(fov_min, fov_max)
    prepare_outputs({"--output": [path]})
    db = PatternDatabase.build(fov_min_deg=fov_min, fov_max_deg=fov_max, progress=True)
    db.save(path)
    typer.echo(f"wrote {path} ({len(db)} patterns of {len(db.star_ids)} stars, FOV {db.fov_min_deg:g}–"
               f"{db.fov_max_deg:g}°)")
