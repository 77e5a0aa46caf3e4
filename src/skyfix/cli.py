"""The ``skyfix`` command.

Exit codes: 0 all images solved; 1 some image failed to solve (its reason is printed);
2 bad input (unreadable file, bad option, corrupt database) with a one-line error.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import typer

from skyfix.errors import SkyfixError

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="skyfix — a star tracker: solve sky images for the camera's attitude.")
database_app = typer.Typer(no_args_is_help=True, help="Build or inspect the pattern database.")
app.add_typer(database_app, name="database")


def _register_analyze() -> None:
    from skyfix.cli_analyze import analyze_app

    app.add_typer(analyze_app, name="analyze")


_register_analyze()


def _fail(message: str, code: int = 2) -> None:
    typer.echo(f"skyfix: error: {message}", err=True)
    raise typer.Exit(code)


def _setup_logging(verbose: int) -> None:
    level = logging.WARNING if verbose == 0 else logging.INFO if verbose == 1 else logging.DEBUG
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)


def _output_path(template: Path | None, image: Path, n_images: int, suffix: str) -> Path | None:
    """One output per image: the path itself for one image, else ``{stem}`` filled or the stem appended."""
    if template is None:
        return None
    text = str(template)
    if "{stem}" in text:
        return Path(text.replace("{stem}", image.stem))
    if n_images == 1:
        return template
    return template.with_name(f"{template.stem}-{image.stem}{template.suffix or suffix}")


@app.command()
def solve(
    images: list[Path] = typer.Argument(..., help="Image files (FITS, PNG, TIFF, JPEG)."),
    fov: float = typer.Option(None, "--fov", help="Horizontal field of view, degrees (optional)."),
    fov_tolerance: float = typer.Option(None, "--fov-tolerance",
                                        help="Allowed error of --fov, degrees (default 10%)."),
    camera_file: str = typer.Option(None, "--camera", help="Camera TOML file or preset name."),
    epoch: float = typer.Option(None, "--epoch", help="Observation epoch, Julian year (default: now)."),
    method: str = typer.Option("svd", "--attitude", help="Wahba solver: svd, quest, esoq2, q-method, triad."),
    json_out: bool = typer.Option(False, "--json", help="One JSON Solution per image per line."),
    wcs: Path = typer.Option(None, "--wcs", help="Write a FITS WCS header (use {stem} for many images)."),
    plot: Path = typer.Option(None, "--plot", help="Write a PNG with identified stars circled."),
    database_file: Path = typer.Option(None, "--database", help="Pattern database file (default: cached)."),
    calibration: Path = typer.Option(None, "--calibration", help="Maps from `skyfix calibrate frames`."),
    dark: Path = typer.Option(None, "--dark", help="Master dark image to subtract."),
    flat: Path = typer.Option(None, "--flat", help="Master flat image to divide by (normalised to 1)."),
    verbose: int = typer.Option(0, "--verbose", "-v", count=True, help="Log what each stage decided."),
) -> None:
    """Solve sky images lost in space: print RA, Dec, roll and the error bars."""
    _setup_logging(verbose)
    from skyfix.pipeline import solve as solve_image

    try:
        maps = _calibration_maps(calibration, dark, flat)
        camera = None
        if camera_file is not None:
            camera = _load_camera(camera_file)
        if fov is not None and not 0.1 <= fov <= 120:
            _fail(f"--fov {fov} is not a plausible field of view (0.1–120 degrees)")
        from skyfix.identify import PatternDatabase, default_database

        database = default_database() if database_file is None else PatternDatabase.load(database_file)
    except SkyfixError as exc:
        _fail(str(exc))

    any_failed = False
    progress = _progress(len(images), json_out)
    for path in images:
        try:
            sol = solve_image(path, fov_deg=fov, fov_tolerance_deg=fov_tolerance, camera=camera,
                              database=database, epoch=epoch, attitude_method=method, **maps)
        except SkyfixError as exc:
            _fail(f"{path}: {exc}")
        any_failed |= not sol.solved
        if json_out:
            typer.echo(sol.to_json())
        else:
            typer.echo(_summary(sol))
        if sol.solved:
            wcs_path = _output_path(wcs, path, len(images), ".wcs")
            if wcs_path is not None:
                from skyfix.wcs import write_wcs

                write_wcs(wcs_path, sol.A_icrs_to_cam, sol.camera)
        plot_path = _output_path(plot, path, len(images), ".png")
        if plot_path is not None:
            from skyfix.io import read_image
            from skyfix.plot import plot_solution

            plot_solution(read_image(path), sol, plot_path)
        if progress is not None:
            progress.advance(0)
    if progress is not None:
        progress.stop()
    raise typer.Exit(1 if any_failed else 0)


def _calibration_maps(calibration: Path | None, dark: Path | None, flat: Path | None) -> dict:
    """``dark``, ``flat`` and ``bad_pixels`` for :func:`skyfix.pipeline.solve`; files given
    one by one override those in the calibration file."""
    from skyfix.io import read_image

    maps: dict = {}
    if calibration is not None:
        from skyfix.detect import load_calibration

        maps.update(load_calibration(calibration))
    if dark is not None:
        maps["dark"] = read_image(dark)
    if flat is not None:
        maps["flat"] = read_image(flat)
    return maps


def _progress(n: int, quiet: bool):
    """A progress bar on stderr for long batches (not for one image, not when piping JSON)."""
    if n < 5 or quiet or not sys.stderr.isatty():
        return None
    from rich.console import Console
    from rich.progress import Progress

    progress = Progress(console=Console(stderr=True), transient=True)
    progress.add_task("solving", total=n)
    progress.start()
    return progress


def _summary(sol) -> str:
    if not sol.solved:
        return f"{sol.image}: failed: {sol.reason}"
    sig = [v**0.5 for v in (sol.covariance_arcsec2[0][0], sol.covariance_arcsec2[1][1],
                            sol.covariance_arcsec2[2][2])]
    return (f"{sol.image}: solved RA {sol.ra_deg:.5f}° Dec {sol.dec_deg:+.5f}° roll {sol.roll_deg:.3f}° "
            f"FOV {sol.fov_deg:.3f}° | {sol.n_matched}/{sol.n_detected} stars, rmse {sol.rmse_arcsec:.1f}″, "
            f"σ(x,y,roll) {sig[0]:.1f}″ {sig[1]:.1f}″ {sig[2]:.0f}″, P(false) {sol.prob_false:.1e} | "
            f"{sol.time_ms.get('total', 0):.1f} ms")


@database_app.command("build")
def database_build(
    fov_min: float = typer.Option(10.0, help="Smallest field of view, degrees."),
    fov_max: float = typer.Option(30.0, help="Largest field of view, degrees."),
    output: Path = typer.Option(None, "--output", "-o", help="Where to write (default: user cache)."),
    verbose: int = typer.Option(0, "--verbose", "-v", count=True),
) -> None:
    """Build the lost-in-space pattern database for a FOV range."""
    _setup_logging(verbose)
    from skyfix.identify import PatternDatabase, default_database_path

    try:
        if not 0.5 <= fov_min <= fov_max <= 100:
            _fail(f"need 0.5 <= fov-min <= fov-max <= 100, got {fov_min}..{fov_max}")
        db = PatternDatabase.build(fov_min_deg=fov_min, fov_max_deg=fov_max, progress=True)
        path = output or default_database_path()
        db.save(path)
    except SkyfixError as exc:
        _fail(str(exc))
    typer.echo(f"wrote {path} ({len(db)} patterns of {len(db.star_ids)} stars, FOV {db.fov_min_deg:g}–"
               f"{db.fov_max_deg:g}°)")


@app.command()
def detect(
    images: list[Path] = typer.Argument(..., help="Image files (FITS, PNG, TIFF, JPEG)."),
    method: str = typer.Option("components", "--method", help="Detection method (skyfix.detect.METHODS)."),
    centroid: str = typer.Option("com", "--centroid", help="Centroider: com, iwcog, gaussian."),
    sigma: float = typer.Option(5.0, "--sigma", help="Detection threshold, noise σ above the background."),
    max_stars: int = typer.Option(200, "--max-stars", help="Keep the brightest N."),
    calibration: Path = typer.Option(None, "--calibration", help="Maps from `skyfix calibrate frames`."),
    json_out: bool = typer.Option(False, "--json", help="One JSON line per image with its centroids."),
) -> None:
    """Find stars and print their centroids (DESIGN.md pixels), brightest first."""
    import json

    import numpy as np

    from skyfix.detect import calibrate_frame, extract_centroids
    from skyfix.io import read_image

    try:
        maps = _calibration_maps(calibration, None, None)
        for path in images:
            data = read_image(path)
            if maps:
                data = calibrate_frame(data, **maps)
            c = extract_centroids(data, method=method, centroid=centroid, sigma=sigma, max_stars=max_stars)
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
    except SkyfixError as exc:
        _fail(str(exc))
    except ValueError as exc:  # an unknown method or centroider name
        _fail(str(exc))


calibrate_app = typer.Typer(no_args_is_help=True, help="Calibrate the sensor (dark, flat, hot pixels).")
app.add_typer(calibrate_app, name="calibrate")


@calibrate_app.command("frames")
def calibrate_frames(
    darks: list[Path] = typer.Option(None, "--darks", help="Dark frames (shutter closed)."),
    flats: list[Path] = typer.Option(None, "--flats", help="Flat-field frames (uniform illumination)."),
    nsigma: float = typer.Option(5.0, "--nsigma", help="Hot pixel: this many σ above the dark level."),
    output: Path = typer.Option(..., "--output", "-o", help="Maps file (.fits or .npz)."),
) -> None:
    """Master dark, master flat and hot/dead-pixel map from frame stacks, with a dark report."""
    from skyfix.detect import (
        dark_report,
        dead_pixel_map,
        hot_pixel_map,
        master_dark,
        master_flat,
        save_calibration,
    )

    if not darks and not flats:
        _fail("give --darks and/or --flats")
    try:
        dark = master_dark(darks) if darks else None
        flat = master_flat(flats, dark=dark) if flats else None
        bad = None
        if dark is not None:
            bad = hot_pixel_map(dark, nsigma)
        if flat is not None:
            bad = dead_pixel_map(flat) if bad is None else bad | dead_pixel_map(flat)
        save_calibration(output, dark=dark, flat=flat, bad_pixels=bad)
        if darks:
            by_exposure: dict[float, list[Path]] = {}
            for p in darks:
                by_exposure.setdefault(_exposure_s(p), []).append(p)
            typer.echo("exposure_s  frames  dark_level_adu  dark_noise_adu  dsnu_adu  hot_pixels")
            for row in dark_report(by_exposure, nsigma):
                typer.echo(f"{row['exposure_s']:10.4g}  {row['n_frames']:6d}  {row['dark_level_adu']:14.2f}  "
                           f"{row['dark_noise_adu']:14.2f}  {row['dsnu_adu']:8.2f}  {row['hot_pixels']:10d}")
    except SkyfixError as exc:
        _fail(str(exc))
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


def _load_camera(value: str):
    """A Camera from a TOML file or a preset name (simulator presets included)."""
    from skyfix.camera import Camera

    if value.endswith(".toml") or Path(value).is_file():
        return Camera.load(value)
    from skyfix.simulate import load_preset, preset_names

    if value.lower() in preset_names():
        return Camera.from_dict(load_preset(value)["camera"])
    from skyfix.camera import camera_from_preset

    return camera_from_preset(value)


def _camera_arg(value: str):
    """A camera preset name, or a TOML file (which may also hold [sensor] and [optics] tables)."""
    if value.endswith(".toml") or Path(value).is_file():
        from skyfix.camera import Camera

        return Camera.load(value)
    return value


def _sensor_arg(value: str | None):
    if value is None:
        return None
    from skyfix.simulate import Sensor

    return Sensor.load(value) if value.endswith(".toml") or Path(value).is_file() else value


@app.command()
def simulate(
    ra: float = typer.Option(..., "--ra", help="Boresight right ascension, degrees."),
    dec: float = typer.Option(..., "--dec", help="Boresight declination, degrees."),
    roll: float = typer.Option(0.0, "--roll", help="Roll (PA of image-up from north through east), degrees."),
    camera: str = typer.Option("generic", "--camera", help="Camera preset name or TOML file."),
    sensor: str = typer.Option(None, "--sensor", help="Sensor preset name or TOML file."),
    rate_dps: str = typer.Option(None, "--rate-dps", help="Body rate wx,wy,wz about camera axes, deg/s."),
    exposure: float = typer.Option(None, "--exposure", help="Exposure, seconds (default: the preset's)."),
    time: str = typer.Option(None, "--time", help="Mid-exposure time, ISO 8601 (default: now)."),
    seed: int = typer.Option(0, "--seed", help="Noise seed (same seed, same image, bit for bit)."),
    false_stars: int = typer.Option(0, "--false-stars", help="False stars / debris to add."),
    hot_pixels: int = typer.Option(0, "--hot-pixels", help="Hot pixels to add."),
    frames: int = typer.Option(1, "--frames", help="Number of frames (a sequence when > 1)."),
    fps: float = typer.Option(10.0, "--fps", help="Frame rate of a sequence, frames per second."),
    output: Path = typer.Option(..., "--output", "-o", help="Image file: .fits, .png or .tif."),
) -> None:
    """Render a simulated star image and write its truth beside it (NAME.truth.json)."""
    import math

    import numpy as np

    from skyfix.geometry import attitude_from_radec_roll
    from skyfix.simulate import render, render_sequence, write_frame

    try:
        rate = None
        if rate_dps is not None:
            parts = [float(v) for v in rate_dps.split(",")]
            if len(parts) != 3:
                _fail("--rate-dps takes three numbers: wx,wy,wz")
            rate = np.radians(parts)
        if not -90.0 <= dec <= 90.0:
            _fail(f"--dec {dec} is outside -90..90 degrees")
        if frames < 1 or not (fps > 0 and math.isfinite(fps)):
            _fail("--frames must be >= 1 and --fps > 0")
        A = attitude_from_radec_roll(math.radians(ra), math.radians(dec), math.radians(roll))
        kw = dict(sensor=_sensor_arg(sensor), exposure_s=exposure, epoch=time, seed=seed,
                  rate_rad_s=rate, false_stars=false_stars, hot_pixels=hot_pixels)
        cam = _camera_arg(camera)
        if frames == 1:
            image, truth = write_frame(render(A, cam, **kw), output)
            typer.echo(f"wrote {image} and {truth}")
            return
        for k, frame in enumerate(render_sequence(A, cam, n_frames=frames, fps=fps, **kw)):
            path = output.with_name(f"{output.stem}-{k:04d}{output.suffix}")
            write_frame(frame, path)
        typer.echo(f"wrote {frames} frames {output.stem}-0000{output.suffix} … with truth beside each")
    except SkyfixError as exc:
        _fail(str(exc))
    except ValueError as exc:
        _fail(f"bad value: {exc}")


def main() -> None:  # pragma: no cover - console entry point
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
