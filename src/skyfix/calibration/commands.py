"""``skyfix calibrate stars`` and ``skyfix calibrate checkerboard``: the commands, registered on
the CLI's ``calibrate`` group by :func:`register` (``skyfix/cli.py`` calls it).

It writes the camera file (docs/design.md#camera-file-toml: a ``[camera]`` table that
:meth:`skyfix.camera.Camera.from_toml` reads back bit for bit, and a ``[calibration]`` table of how
it was made) and print each fitted number with its 1σ. Bad input — too few images, stars or boards, a
degenerate set, images of different sizes, a bad pattern, an unknown model — is one line
naming the image or parameter, exit status 2, and no camera file is written. Neither command
imports its implementation (nor OpenCV) until it runs.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import typer

from skyfix.cli.common import VERBOSE, add_verbosity, guarded, prepare_outputs

__all__ = ["calibrate_checkerboard_command", "calibrate_stars_command", "register"]


def _print_parameters(rows: list[tuple[str, float, float]]) -> None:
    typer.echo("parameter            value            1σ")
    for name, value, sigma in rows:
        typer.echo(f"{name:<10} {value:>18.8g} {sigma:>13.3g}")


@guarded
def calibrate_stars_command(
    images: list[Path] = typer.Argument(..., help="Star images of one camera (three or more, at different "
                                        "pointings)."),
    output: Path = typer.Option(..., "--output", "-o", help="Camera file to write (.toml)."),
    model: str = typer.Option("brown-conrady", "--model",
                              help="pinhole | brown-conrady | fisheye: the family; the terms within it are "
                              "chosen by BIC and those the stars cannot constrain are refused."),
    skew: bool = typer.Option(False, "--skew", help="Fit the pixel skew too (off by default)."),
    max_stars: int = typer.Option(300, "--max-stars", help="Centroids per image."),
    plot: Path | None = typer.Option(None, "--plot", help="PNG of the residuals across the frame, before and "
                                     "after."),
    verbose: int = VERBOSE,
) -> None:
    """Calibrate a camera from star images: solve each, fit one camera and one attitude per image
    jointly, re-identify stars through the camera until it converges."""
    from skyfix.calibration.stars import calibrate_stars, calibration_model, parameter_table

    add_verbosity(verbose)
    calibration_model(model)
    outputs = {"--output": [output]} | ({"--plot": [plot]} if plot else {})
    prepare_outputs(outputs, inputs=images)
    cal = calibrate_stars(images, model=model, skew=skew, max_stars=max_stars)
    _print_parameters(parameter_table(cal))
    for name, why in cal.refused.items():
        typer.echo(f"refused {name}: {why}")
    typer.echo(f"model {' + '.join(cal.fit.params)} (BIC, {cal.rounds} round(s)); {cal.fit.n_stars} stars, "
               f"σ {cal.fit.sigma_px:.3f} px per axis")
    typer.echo("image  rms_before_arcsec  rms_solve_arcsec  rms_after_arcsec  stars")
    for name, b, s, a, k in zip(cal.fit.names, cal.before.rms_arcsec(), cal.solve_rms_arcsec,
                                cal.fit.rms_arcsec(), cal.fit.inliers, strict=True):
        typer.echo(f"{name}  {b:.2f}  {s:.2f}  {a:.2f}  {int(k.sum())}")
    output.write_text(cal.to_toml())
    if plot:
        from skyfix.calibration.plot import plot_residuals

        plot_residuals(cal, plot)
    typer.echo(f"wrote {output}" + (f" and {plot}" if plot else ""))


@guarded
def calibrate_checkerboard_command(
    images: list[Path] = typer.Argument(..., help="Images of a checkerboard at different poses (three or "
                                        "more; 20–30 filling the frame between them is better)."),
    output: Path = typer.Option(..., "--output", "-o", help="Camera file to write (.toml)."),
    pattern: str = typer.Option("9x6", "--pattern", help="Inner corners per row x per column (9x6: a board "
                                "of 10 × 7 squares)."),
    square_mm: float = typer.Option(25.0, "--square-mm", help="Side of a square, mm (sets the boards' "
                                    "distances only; the camera does not depend on it)."),
    model: str = typer.Option("brown-conrady", "--model",
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
    checkerboard_model(model)
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


def register(calibrate_app: typer.Typer) -> None:
    """Add ``stars`` and ``checkerboard`` to the ``skyfix calibrate`` group."""
    calibrate_app.command("stars")(calibrate_stars_command)
    calibrate_app.command("checkerboard")(calibrate_checkerboard_command)
