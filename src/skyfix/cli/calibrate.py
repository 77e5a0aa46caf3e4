"""``skyfix calibrate``: the sensor from frame stacks (``frames``: master dark, master flat,
hot/dead pixels) and the camera (``stars``, ``checkerboard``: :mod:`skyfix.calibration.commands`).

The detectors' frame statistics and astropy's FITS reader are imported when ``frames`` runs,
not when the command table is set up: every ``skyfix`` start loads this module.
"""

from __future__ import annotations

import math
from pathlib import Path

import typer

from skyfix.calibration.commands import register
from skyfix.cli.common import VERBOSE, add_verbosity, fail, guarded, prepare_outputs
from skyfix.validate import check_positive

__all__ = ["calibrate_app", "calibrate_frames"]

calibrate_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None,
                            help="Calibrate the sensor (dark, flat, hot pixels) and the camera (from stars).")
register(calibrate_app)  # `skyfix calibrate stars` and `checkerboard`, listed first in -h


class _ManyFilesCommand(typer.core.TyperCommand):
    """A command whose ``--darks``/``--flats`` take every file that follows, up to the next option
    (``--darks a.fits b.fits c.fits``), as well as one file per flag (``--darks a --darks b``):
    click options take a fixed number of values, so the flag is repeated before parsing."""

    many = ("--darks", "--flats")

    def parse_args(self, ctx, args: list[str]) -> list[str]:
        out: list[str] = []
        flag, n_values = None, 0
        for arg in args:
            if flag is not None and (n_values == 0 or not arg.startswith("-")):
                out += [flag, arg]
                n_values += 1
                continue
            flag = None
            if arg in self.many:
                flag, n_values = arg, 0
                continue
            out.append(arg)
        if flag is not None and n_values == 0:
            out.append(flag)  # no value: click says so
        return super().parse_args(ctx, out)


@calibrate_app.command("frames", cls=_ManyFilesCommand)
@guarded
def calibrate_frames(
    darks: list[Path] = typer.Option(None, "--darks",
                                     help="Dark frames (shutter closed): --darks a.fits b.fits …"),
    flats: list[Path] = typer.Option(None, "--flats", help="Flat-field frames (uniform illumination): "
                                     "--flats a.fits b.fits …"),
    nsigma: float = typer.Option(5.0, "--nsigma", help="Hot pixel: this many σ above the dark level."),
    output: Path = typer.Option(..., "--output", "-o", help="Maps file (.fits or .npz)."),
    verbose: int = VERBOSE,
) -> None:
    """Master dark, master flat and hot/dead-pixel map from frame stacks, with a dark report per
    exposure (read from the FITS header's EXPTIME or EXPOSURE)."""
    from skyfix.detect import (
        dark_report,
        dead_pixel_map,
        hot_pixel_map,
        master_dark,
        master_flat,
        save_calibration,
    )

    add_verbosity(verbose)
    if not darks and not flats:
        fail("give --darks and/or --flats")
    check_positive(nsigma, "--nsigma")
    prepare_outputs({"--output": [output]}, inputs=[*(darks or ()), *(flats or ())])
    dark = master_dark(darks) if darks else None
    flat = master_flat(flats, dark=dark) if flats else None
    bad = None
    if dark is not None:
        bad = hot_pixel_map(dark, nsigma)
    if flat is not None:
        bad = dead_pixel_map(flat) if bad is None else bad | dead_pixel_map(flat)
    save_calibration(output, dark=dark, flat=flat, bad_pixels=bad)
    if darks:
        unknown = math.nan  # one key for every dark without an exposure time
        by_exposure: dict[float, list[Path]] = {}
        for p in darks:
            exposure = _exposure_s(p)
            by_exposure.setdefault(unknown if math.isnan(exposure) else exposure, []).append(p)
        if unknown in by_exposure:
            n = len(by_exposure[unknown])
            typer.echo(f"skyfix: note: {n} dark{'s have' if n > 1 else ' has'} no exposure time (no EXPTIME "
                       f"or EXPOSURE in a FITS header): reported together as exposure 'unknown'", err=True)
        typer.echo("exposure_s  frames  dark_level_adu  dark_noise_adu  dsnu_adu  hot_pixels")
        for row in dark_report(by_exposure, nsigma):
            exposure = "unknown" if math.isnan(row["exposure_s"]) else f"{row['exposure_s']:.4g}"
            typer.echo(f"{exposure:>10}  {row['n_frames']:6d}  {row['dark_level_adu']:14.2f}  "
                       f"{row['dark_noise_adu']:14.2f}  {row['dsnu_adu']:8.2f}  {row['hot_pixels']:10d}")
    n_bad = 0 if bad is None else int(bad.sum())
    typer.echo(f"wrote {output} (dark: {dark is not None}, flat: {flat is not None}, bad pixels: {n_bad})")


def _exposure_s(path: Path) -> float:
    """Exposure of a frame from its FITS header (EXPTIME/EXPOSURE), NaN when unknown."""
    if path.suffix.lower() not in (".fits", ".fit", ".fts"):
        return float("nan")
    try:
        from astropy.io import fits

        header = fits.getheader(path)
        return float(header.get("EXPTIME", header.get("EXPOSURE", float("nan"))))
    except Exception:  # the frame itself is read (and its errors reported) by master_dark
        return float("nan")

