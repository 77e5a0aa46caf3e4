"""``skyfix detect IMAGE…``: star extraction alone, the centroids of each image brightest first
(one summary or one JSON line per image).

numpy and the detectors are imported when the command runs, not when the command table is set
up: every ``skyfix`` start loads this module.
"""

from __future__ import annotations

import json
from pathlib import Path

import typer

from skyfix.cli.common import (
    VERBOSE,
    add_verbosity,
    calibration_maps,
    compile_notice,
    fail,
    guarded,
    input_error_line,
)
from skyfix.errors import unknown_name
from skyfix.validate import check_count, check_positive

__all__ = ["detect"]


@guarded
def detect(
    images: list[Path] = typer.Argument(..., help="Image files (FITS, PNG, TIFF, JPEG)."),
    method: str = typer.Option("components", "--method", help="Detection method (skyfix.detect.METHODS)."),
    centroid: str = typer.Option("com", "--centroid", help="Centroider: com, iwcog, gaussian."),
    sigma: float = typer.Option(5.0, "--sigma", help="Detection threshold, noise σ above the background."),
    max_stars: int = typer.Option(200, "--max-stars", help="Keep the brightest N."),
    calibration: Path = typer.Option(None, "--calibration", help="Maps from `skyfix calibrate frames`."),
    json_out: bool = typer.Option(False, "--json", help="One JSON line per image with its centroids."),
    verbose: int = VERBOSE,
) -> None:
    """Find stars and print their centroids (docs/design.md#pixel-coordinates), brightest first."""
    import numpy as np

    import skyfix.detect as det
    from skyfix.io import read_image

    add_verbosity(verbose)
    sigma = check_positive(sigma, "--sigma")
    max_stars = check_count(max_stars, "--max-stars")
    if method not in det.METHODS:
        fail(f"--method: {unknown_name('detection method', method, det.METHODS)}")
    if centroid not in det.CENTROIDERS:
        fail(f"--centroid: {unknown_name('centroider', centroid, det.CENTROIDERS)}")
    maps = calibration_maps(calibration, None, None)
    any_error = False
    with compile_notice():
        for path in images:
            try:
                data = read_image(path)
                if maps:
                    data = det.calibrate_frame(data, **maps)
                c = det.extract_centroids(data, method=method, centroid=centroid, sigma=sigma,
                                          max_stars=max_stars)
            except Exception as exc:  # this image's error line, then the next image
                any_error = True
                typer.echo(f"skyfix: error: {input_error_line(exc, path)}", err=True)
                continue
            if not json_out:
                typer.echo(f"{path}: {len(c)} stars, background {c.background_level:.1f}, "
                           f"noise {c.noise:.2f}")
                for i in range(min(len(c), 10)):
                    typer.echo(f"  x {c.x[i]:8.2f}  y {c.y[i]:8.2f}  flux {c.flux[i]:10.1f}  "
                               f"snr {c.snr[i]:7.1f}")
                continue
            cols = {k: np.asarray(getattr(c, k), float).tolist()
                    for k in ("x", "y", "flux", "snr", "area", "sigma_x", "sigma_y")}
            rows = [dict(zip(cols, vals, strict=True)) for vals in zip(*cols.values(), strict=True)]
            typer.echo(json.dumps({"image": str(path), "n": len(c), "background": float(c.background_level),
                                   "noise": float(c.noise), "centroids": rows}))
    if any_error:
        raise typer.Exit(2)
