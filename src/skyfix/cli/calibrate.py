"""``skyfix calibrate``: the camera from star images (``stars``: a joint fit, docs/calibration.md)
or from checkerboard images (``checkerboard``: OpenCV), and the sensor from frame stacks
(``frames``: master dark, master flat, hot/dead pixels).

``stars`` and ``checkerboard`` write the camera file (docs/design.md#camera-file-toml: a
``[camera]`` table that :meth:`skyfix.camera.Camera.from_toml` reads back bit for bit, and a
``[calibration]`` table of how it was made) and print each fitted number with its 1σ. Bad input —
too few images, stars or boards, a degenerate set, images of different sizes, a bad pattern, an
unknown model — is one line naming the image or parameter, exit status 2, and no camera file is
written.

Each command imports its implementation (the joint fit, OpenCV, the detectors' frame
statistics, astropy's FITS reader) when it runs, not when the command table is set up: every
``skyfix`` start loads this module.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import typer

from skyfix.cli.common import VERBOSE, OneLineErrors, add_verbosity, checking, fail, guarded, prepare_outputs
from skyfix.cli.observation import observation_option, observation_options
from skyfix.validate import check_positive

__all__ = ["calibrate_app", "calibrate_checkerboard_command", "calibrate_frames", "calibrate_stars_command"]

# -h lists the commands in the order they are defined here: stars, checkerboard, frames
calibrate_app = typer.Typer(cls=OneLineErrors, no_args_is_help=True, rich_markup_mode=None,
                            help="Calibrate the sensor (dark, flat, hot pixels) and the camera (from stars).")


def _print_parameters(rows: list[tuple[str, float, float]]) -> None:
    typer.echo("parameter            value            1σ")
    for name, value, sigma in rows:
        typer.echo(f"{name:<10} {value:>18.8g} {sigma:>13.3g}")


@calibrate_app.command("stars")
@guarded
def calibrate_stars_command(
    images: list[Path] = typer.Argument(..., help="Star images of one camera (three or more, at different "
                                        "pointings)."),
    output: Path = typer.Option(..., "--output", "-o", help="Camera file to write (.toml)."),
    model: str = typer.Option("brown-conrady", "--model", metavar="NAME",
                              help="pinhole | brown-conrady | fisheye: the family; the terms within it are "
                              "chosen by BIC and those the stars cannot constrain are refused."),
    skew: bool = typer.Option(False, "--skew", help="Fit the pixel skew too (off by default)."),
    max_stars: int = typer.Option(300, "--max-stars", help="Centroids per image."),
    centroid: str = typer.Option("gaussian", "--centroid", metavar="NAME",
                                 help="com | iwcog | gaussian: the centroider the stars are measured with "
                                 "(default gaussian, the most precise)."),
    plot: Path | None = typer.Option(None, "--plot", help="PNG of the residuals across the frame, before and "
                                     "after."),
    obs_time: str = observation_option("--time"),
    site: str = observation_option("--site"),
    weather: str = observation_option("--weather"),
    refraction: str = observation_option("--refraction"),
    verbose: int = VERBOSE,
) -> None:
    """Calibrate a camera from star images: solve each, fit one camera and one attitude per image
    jointly, re-identify stars through the camera until it converges. With --time (and --site for a
    camera on the ground) the catalogue is fitted as the camera saw it — aberrated, refracted — so
    the camera file holds the lens, not the atmosphere."""
    from skyfix.calibration.stars import (
        calibrate_stars,
        calibration_model,
        ground_observation,
        parameter_table,
    )
    from skyfix.detect.centroid import CENTROIDERS
    from skyfix.errors import unknown_name

    add_verbosity(verbose)
    with checking("--model", model):
        calibration_model(model)
    with checking("--centroid", centroid):
        if centroid not in CENTROIDERS:
            raise unknown_name("centroider", centroid, CENTROIDERS)
    given = observation_options(obs_time, None, site, weather, refraction, None, False)
    with checking("--site", site):
        observation = ground_observation(given["time"], given["site"], given["weather"], given["refraction"])
    outputs = {"--output": [output]} | ({"--plot": [plot]} if plot else {})
    prepare_outputs(outputs, inputs=images)
    cal = calibrate_stars(images, model=model, skew=skew, max_stars=max_stars, centroid=centroid,
                          observation=observation)
    if observation is not None:
        typer.echo(f"corrections: {', '.join(observation.applied) or 'none'}")
    _print_parameters(parameter_table(cal))
    for name, why in cal.refused.items():
        typer.echo(f"refused {name}: {why}")
    typer.echo(f"model {' + '.join(cal.fit.params)} (BIC, {cal.rounds} round(s)); {cal.fit.n_stars} stars, "
               f"σ {cal.fit.sigma_px:.3f} px per axis")
    altaz = cal.boresights_altaz()
    typer.echo("image  rms_before_arcsec  rms_solve_arcsec  rms_after_arcsec  stars"
               + ("  alt_deg  az_deg" if altaz else ""))
    for i, (name, b, s, a, k) in enumerate(zip(cal.fit.names, cal.before.rms_arcsec(), cal.solve_rms_arcsec,
                                               cal.fit.rms_arcsec(), cal.fit.inliers, strict=True)):
        where = f"  {altaz[i].alt_deg:.2f}  {altaz[i].az_deg:.2f}" if altaz else ""
        typer.echo(f"{name}  {b:.2f}  {s:.2f}  {a:.2f}  {int(k.sum())}{where}")
    output.write_text(cal.to_toml())
    if plot:
        from skyfix.calibration.plot import plot_residuals

        plot_residuals(cal, plot)
    typer.echo(f"wrote {output}" + (f" and {plot}" if plot else ""))


@calibrate_app.command("checkerboard")
@guarded
def calibrate_checkerboard_command(
    images: list[Path] = typer.Argument(..., help="Images of a checkerboard at different poses (three or "
                                        "more; 20–30 filling the frame between them is better)."),
    output: Path = typer.Option(..., "--output", "-o", help="Camera file to write (.toml)."),
    pattern: str = typer.Option("9x6", "--pattern", metavar="NxM",
                                help="Inner corners per row x per column (9x6: a board of 10 × 7 squares)."),
    square_mm: float = typer.Option(25.0, "--square-mm", help="Side of a square, mm (sets the boards' "
                                    "distances only; the camera does not depend on it)."),
    model: str = typer.Option("brown-conrady", "--model", metavar="NAME",
                              help="brown-conrady (OpenCV calibrateCamera) | fisheye (OpenCV "
                              "fisheye.calibrate, Kannala–Brandt)."),
    pixel_pitch_um: float | None = typer.Option(None, "--pixel-pitch-um",
                                                help="Pixel pitch, µm: prints the focal lengths in mm too."),
    plot: Path | None = typer.Option(None, "--plot", help="PNG of the reprojection errors."),
    verbose: int = VERBOSE,
) -> None:
    """Calibrate a camera from checkerboard images with OpenCV: find each board's corners, fit
    one camera, drop outlier images, fix insignificant distortion at 0."""
    from skyfix.calibration.checkerboard import (
        THESIS_000,
        calibrate_checkerboard,
        checkerboard_model,
        parse_pattern,
    )

    add_verbosity(verbose)
    with checking("--model", model):
        checkerboard_model(model)
    with checking("--pattern", pattern):
        parse_pattern(pattern)
    outputs = {"--output": [output]} | ({"--plot": [plot]} if plot else {})
    prepare_outputs(outputs, inputs=images)
    cal = calibrate_checkerboard(images, pattern=pattern, square_mm=square_mm, model=model)
    for name, why in cal.skipped.items():
        typer.echo(f"skipped {name}: {why}")
    for name, why in cal.rejected.items():
        typer.echo(f"rejected {name}: {why}")
    cam = cal.camera
    names = ("fx", "fy", "cx", "cy", *(k for k in ("k1", "k2", "k3", "p1", "p2", "k4")
                                       if k in _coefficients(cam.projection)))
    _print_parameters([(k, float(getattr(cam, k)), cal.sigma.get(k, float("nan"))) for k in names])
    for name, why in cal.fixed.items():
        typer.echo(f"fixed {name}: {why}")
    sx, sy = cal.pixel_error_px
    typer.echo(f"{len(cal.names)} images, {sum(len(c) for c in cal.corners)} corners; reprojection error std "
               f"({sx:.3f}, {sy:.3f}) px")
    typer.echo("image  rms_px  distance_mm")
    for name, rms, d in zip(cal.names, cal.rms_px(), cal.distance_mm, strict=True):
        typer.echo(f"{name}  {rms:.3f}  {d:.0f}")
    t = THESIS_000
    mm = (f"fx {cam.fx * pixel_pitch_um / 1000:.3f} mm, fy {cam.fy * pixel_pitch_um / 1000:.3f} mm"
          if pixel_pitch_um else f"fx {cam.fx:.1f} px, fy {cam.fy:.1f} px")
    rest = f"p = ({cam.p1:.4f}, {cam.p2:.4f})" if cam.projection == "pinhole" else f"k4 = {cam.k4:.4f}"
    typer.echo(f"this calibration: {mm}; k = ({cam.k1:.4f}, {cam.k2:.4f}, {cam.k3:.4f}), {rest}; "
               f"reprojection std ({sx:.3f}, {sy:.3f}) px")
    typer.echo(f"{t.source}: fx {t.fx_mm} mm, fy {t.fy_mm} mm; k = {t.k}, p = {t.p}; reprojection std "
               f"{t.pixel_error_px} px over {t.images} images")
    if pixel_pitch_um:
        cam = cam.replace(pixel_pitch_um=pixel_pitch_um)
        cal = replace(cal, camera=cam)
    output.write_text(cal.to_toml())
    if plot:
        from skyfix.calibration.plot import plot_reprojection

        plot_reprojection(cal, plot)
    typer.echo(f"wrote {output}" + (f" and {plot}" if plot else ""))


def _coefficients(projection: str) -> tuple[str, ...]:
    from skyfix.camera import PROJECTIONS

    return PROJECTIONS[projection].coefficients



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
    darks: list[Path] = typer.Option(None, "--darks", metavar="FILE...",
                                     help="Dark frames (shutter closed): --darks a.fits b.fits …"),
    flats: list[Path] = typer.Option(None, "--flats", metavar="FILE...",
                                     help="Flat-field frames (uniform illumination): --flats a.fits "
                                          "b.fits …"),
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

