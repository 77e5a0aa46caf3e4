"""``skyfix calibrate stars``: the command, registered on the CLI's ``calibrate`` group by
:func:`register` (``skyfix/cli.py`` calls it; ``checkerboard`` will join it here).

It writes the camera file (docs/design.md#camera-file-toml: a ``[camera]`` table that
:meth:`skyfix.camera.Camera.from_toml` reads back bit for bit, and a ``[calibration]`` table of how
it was made) and print each fitted number with its 1σ. Bad input — too few images or stars, a
degenerate set, images of different sizes, an unknown model — is one line
naming the image or parameter, exit status 2, and no camera file is written.
"""

from __future__ import annotations

from pathlib import Path

import typer

from skyfix.cli_support import VERBOSE, add_verbosity, guarded, prepare_outputs

__all__ = ["calibrate_stars_command", "register"]


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


def register(calibrate_app: typer.Typer) -> None:
    """Add ``stars`` to the ``skyfix calibrate`` group."""
    calibrate_app.command("stars")(calibrate_stars_command)
