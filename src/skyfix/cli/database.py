"""``skyfix database build``: a lost-in-space pattern database for a FOV range, or the default
FOV bands into the user cache.

The identification package (numpy, numba) is imported when a build runs, not when the command
table is set up: every ``skyfix`` start loads this module.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import typer

from skyfix.cli.common import VERBOSE, OneLineErrors, add_verbosity, checking, fail, guarded, prepare_outputs
from skyfix.validate import check_fov_range

__all__ = ["database_app", "database_build", "database_info"]

database_app = typer.Typer(cls=OneLineErrors, no_args_is_help=True, rich_markup_mode=None,
                           help="Build a pattern database, or say what one covers (info).")


@database_app.command("build")
@guarded
def database_build(
    fov_min: float = typer.Option(10.0, help="Smallest field of view, degrees."),
    fov_max: float = typer.Option(30.0, help="Largest field of view, degrees."),
    output: Path = typer.Option(None, "--output", "-o", help="Where to write (default: user cache)."),
    default_bands: bool = typer.Option(False, "--default-bands",
                                       help="Build every default FOV band (2–90°) into the user cache now, "
                                            "instead of on first need."),
    catalog: Path = typer.Option(None, "--catalog", metavar="FILE",
                                 help="Build from this star catalogue (CSV, ECSV, FITS or VOTable with "
                                      "ra, dec, mag columns; docs/catalogues.md#a-deeper-catalogue) "
                                      "instead of Hipparcos: for fields the bundled catalogues are too "
                                      "shallow for (under ~1°)."),
    catalog_epoch: float = typer.Option(2016.0, "--catalog-epoch", metavar="YEAR",
                                        help="Julian year of the --catalog file's positions "
                                             "(Gaia DR3: 2016.0)."),
    mag_limit: float = typer.Option(None, "--mag-limit", metavar="MAG",
                                    help="With --catalog: the faintest stars that form patterns "
                                         "(default: every star of the file)."),
    verbose: int = VERBOSE,
) -> None:
    """Build the lost-in-space pattern database for a FOV range (it serves fields about 1.35×
    beyond it on either side), from Hipparcos or a deeper catalogue file (--catalog), or every
    default FOV band (--default-bands)."""
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
    if catalog is None:
        if mag_limit is not None:
            fail("--mag-limit is for a --catalog file's build; give --catalog FILE too")
        path = output or default_database_path(fov_min, fov_max)
        prepare_outputs({"--output": [path]})
        db = PatternDatabase.build(fov_min_deg=fov_min, fov_max_deg=fov_max, progress=True)
    else:
        if not math.isfinite(catalog_epoch) or not 1900.0 <= catalog_epoch <= 2100.0:
            fail(f"--catalog-epoch must be a Julian year in 1900–2100, not {catalog_epoch:g}")
        if mag_limit is not None and not math.isfinite(mag_limit):
            fail(f"--mag-limit must be a finite magnitude, not {mag_limit}")
        if output is None:
            fail("--output FILE is needed with --catalog (where to write the database; then solve "
                 "with --database FILE)")
        from skyfix.catalog import epoch_now
        from skyfix.catalog_file import load_catalog_file
        from skyfix.identify import DEEP

        path = output
        prepare_outputs({"--output": [path]})
        with checking("--catalog", catalog):
            stars = load_catalog_file(catalog, position_epoch=catalog_epoch, epoch=epoch_now(),
                                      mag_limit=mag_limit)
        db = PatternDatabase.build(fov_min_deg=fov_min, fov_max_deg=fov_max, catalog=stars,
                                   band_ratio=DEEP.band_ratio, stars_per_field=DEEP.stars_per_field,
                                   lattice_step=DEEP.lattice_step, pattern_mag_limit=float(stars.mag.max()),
                                   progress=True, catalog_source=f"file:{catalog.name}")
    db.save(path)
    typer.echo(f"wrote {path} ({len(db)} patterns of {len(db.star_ids)} stars, FOV {db.fov_min_deg:g}–"
               f"{db.fov_max_deg:g}°)")


@database_app.command("info")
@guarded
def database_info(
    path: Path = typer.Argument(..., metavar="FILE", help="A pattern database (.npz)."),
    json_out: bool = typer.Option(False, "--json", help="The same as one JSON object."),
    verbose: int = VERBOSE,
) -> None:
    """What a pattern database covers: the FOV range it was built for and the fields it serves, the
    magnitude limit of its patterns, its stars and patterns, catalogue, epoch and file size."""
    add_verbosity(verbose)
    from skyfix.identify import PatternDatabase
    from skyfix.identify.catalogue.bands import served_fov_deg

    db = PatternDatabase.load(path)
    lo, hi = served_fov_deg(db)
    info = {"file": str(path), "size_bytes": path.stat().st_size, "fov_min_deg": db.fov_min_deg,
            "fov_max_deg": db.fov_max_deg, "served_fov_deg": [lo, hi],
            "pattern_mag_limit": db.meta.get("pattern_mag_limit"), "n_stars": len(db.star_ids),
            "n_patterns": len(db), "catalog": db.meta.get("catalog", ""), "epoch": db.epoch,
            "version": db.meta.get("version")}
    if json_out:
        import json

        typer.echo(json.dumps(info))
        return
    mag = info["pattern_mag_limit"]
    typer.echo(f"{path}: built for FOV {db.fov_min_deg:g}–{db.fov_max_deg:g}°, serves fields of "
               f"{lo:.3g}–{hi:.3g}°; {len(db)} patterns of {len(db.star_ids)} stars"
               f"{f' (patterns to magnitude {mag:g})' if mag is not None else ''}; catalogue "
               f"{info['catalog'] or 'unknown'} at epoch {db.epoch:.2f}; {info['size_bytes'] / 1e6:.0f} MB")
