"""The ``skyfix`` command.

Exit codes: 0 all images solved; 1 some image failed to solve (its reason is printed);
2 bad input (unreadable file, bad option, corrupt database) with a one-line error — a batch
goes on past a bad file and exits 2 at the end; 130 interrupted. No command prints a
traceback unless asked with ``-vv`` (:mod:`skyfix.cli_support`).
"""

from __future__ import annotations

import functools
import math
import re
import sys
from pathlib import Path

import typer

from skyfix import __version__
from skyfix.cli_observation import observation_option, observation_options, summary_suffix
from skyfix.cli_support import (
    VERBOSE,
    add_verbosity,
    compile_notice,
    error_line,
    fail,
    guarded,
    load_database,
    output_paths,
    prepare_outputs,
    reset_verbosity,
)
from skyfix.errors import ImageReadError, SkyfixError
from skyfix.validate import (
    check_count,
    check_fov_range,
    check_positive,
    check_solve_options,
)


class _Skyfix(typer.Typer):
    """typer's app, with one shortcut: a plain ``skyfix solve IMAGE… [OPTIONS]`` (what
    :func:`_plain_solve` accepts) calls the command directly, skipping typer's value coercion,
    which imports pydantic and builds a validator per option (~0.15 s of CPU of the process).
    Anything else — help, a bad or unusual value, another command — goes through typer as before,
    so its messages and help are typer's own (tests/cli/test_cli_fast_path.py: the shortcut passes the
    command what typer would)."""

    def __call__(self, *args, **kwargs):
        argv = None  # the shortcut only for app() and app(ARGS[, prog_name=…]), as click reads them
        if not args and not kwargs:
            argv = sys.argv[1:]
        elif len(args) == 1 and isinstance(args[0], (list, tuple)) and set(kwargs) <= {"prog_name"}:
            argv = list(args[0])
        plain = _plain_solve(argv) if argv is not None and all(isinstance(a, str) for a in argv) else None
        if plain is None:
            return super().__call__(*args, **kwargs)
        verbose, options = plain
        try:
            main_options(version=False, verbose=verbose)
            solve(**options)
        except typer.Exit as exc:  # as click's standalone mode does
            sys.exit(exc.exit_code)
        sys.exit(0)


# rich_markup_mode=None: help and usage errors as plain text (click's formatter), without rich's
# import (0.11 s of `skyfix -h`)
app = _Skyfix(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
              rich_markup_mode=None, context_settings={"help_option_names": ["-h", "--help"]},
              help="skyfix — a star tracker: solve sky images for the camera's attitude.")
database_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None,
                           help="Build or inspect the pattern database.")
app.add_typer(database_app, name="database")


def _register_analyze() -> None:
    from skyfix.cli_analyze import analyze_app

    app.add_typer(analyze_app, name="analyze")


_register_analyze()


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"skyfix {__version__}")
        raise typer.Exit()


@app.callback()
def main_options(
    version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True,
                                 help="Print the version and exit."),
    verbose: int = VERBOSE,
) -> None:
    """skyfix — a star tracker: solve sky images for the camera's attitude."""
    reset_verbosity()
    add_verbosity(verbose)


_OUTPUT_NAMES_HELP = ("Outputs are named after each image: put {stem} in the name (out/{stem}.png). "
                      "Images that share a name get their folder's name in front if the folders differ "
                      "(a/sky.png → a-sky, b/sky.png → b-sky), their extension behind if the extensions "
                      "differ (sky-png, sky-fits), -2 for a file given twice. Missing folders are "
                      "created; no output overwrites an input or another output.")


@app.command(epilog=_OUTPUT_NAMES_HELP)
@guarded
def solve(
    images: list[Path] = typer.Argument(..., help="Image files (FITS, PNG, TIFF, JPEG)."),
    fov: float = typer.Option(None, "--fov", help="Horizontal field of view, degrees (optional)."),
    fov_tolerance: float = typer.Option(None, "--fov-tolerance",
                                        help="Allowed error of --fov, degrees (default 10%)."),
    camera_file: str = typer.Option(None, "--camera", help="Camera TOML file or preset name."),
    epoch: float = typer.Option(None, "--epoch", help="Observation epoch, Julian year (default: now)."),
    method: str = typer.Option("svd", "--attitude", help="Wahba solver: svd, quest, esoq2, q-method, triad."),
    identify_method: str = typer.Option(
        "quad-hash", "--method", metavar="NAME",
        help="Identification method (skyfix.identify.METHODS; docs/identification-methods.md). The default "
             "tries the triangle method on sparse frames when --camera or --fov gives the scale."),
    json_out: bool = typer.Option(False, "--json", help="One JSON Solution per image per line."),
    wcs: Path = typer.Option(None, "--wcs", help="Write a FITS WCS header (use {stem} for many images)."),
    plot: Path = typer.Option(None, "--plot", help="Write a PNG with identified stars circled."),
    database_file: Path = typer.Option(None, "--database", help="Pattern database file (default: cached)."),
    calibration: Path = typer.Option(None, "--calibration", help="Maps from `skyfix calibrate frames`."),
    dark: Path = typer.Option(None, "--dark", help="Master dark image to subtract."),
    flat: Path = typer.Option(None, "--flat", help="Master flat image to divide by (normalised to 1)."),
    attitude_hint: str = typer.Option(
        None, "--attitude-hint", metavar="RA,DEC,ROLL[,UNCERTAINTY_DEG]",
        help="A rough attitude, degrees (uncertainty: the largest error, default 1): identify the stars "
             "near it first, falling back to lost in space. Needs --camera or --fov for the scale."),
    centroid_sigma: float = typer.Option(
        None, "--centroid-sigma", metavar="PX",
        help="The centroids' noise, pixels, when known (a calibrated tracker's): the search's "
             "tolerances, and with --camera a prior on the noise the error bars rest on — three or "
             "four stars' residuals cannot bound it alone (docs/identification-methods.md#triangle)."),
    smear: str = typer.Option(
        None, "--smear", metavar="DX,DY",
        help="The stars' streak over the exposure when the camera turned, pixels (a gyro's rate × the "
             "exposure): stars are found in the frame averaged along it."),
    obs_time: str = observation_option("--time"),
    velocity_kms: str = observation_option("--velocity-kms"),
    site: str = observation_option("--site"),
    weather: str = observation_option("--weather"),
    refraction: str = observation_option("--refraction"),
    mounting: str = observation_option("--mounting"),
    apparent: bool = observation_option("--apparent"),
    verbose: int = VERBOSE,
) -> None:
    """Solve sky images lost in space (or near --attitude-hint): print RA, Dec, roll and the error bars."""
    add_verbosity(verbose)
    # Every option is checked, and every output folder made, before any work.
    check_solve_options(fov, fov_tolerance, epoch, method,
                        ("--fov", "--fov-tolerance", "--epoch", "--attitude"))
    hint = _attitude_hint(attitude_hint)
    smear_px = _smear(smear)
    noise = {} if centroid_sigma is None else {"centroid_sigma_px": check_positive(centroid_sigma,
                                                                                   "--centroid-sigma")}
    _identify_method(identify_method)
    wcs_paths, plot_paths = output_paths(wcs, images, ".wcs"), output_paths(plot, images, ".png")
    prepare_outputs({"--wcs": wcs_paths, "--plot": plot_paths}, inputs=images)
    maps = _calibration_maps(calibration, dark, flat)
    try:
        camera = _load_camera(camera_file) if camera_file is not None else None
    except SkyfixError as exc:
        fail(error_line(exc, camera_file))
    observation = observation_options(obs_time, velocity_kms, site, weather, refraction, mounting, apparent,
                                      camera_file, epoch)  # after the camera: its file is reported first
    database = load_database(database_file, _solve_paths(identify_method, method, hint is not None))
    if hint is not None and camera is None and fov is None:
        typer.echo("skyfix: note: --attitude-hint needs the image scale (--camera or --fov); "
                   "solving lost in space", err=True)

    from skyfix.pipeline import solve as solve_image

    any_failed = any_error = False
    progress = _progress(len(images), json_out)
    with compile_notice(progress):
        for path, wcs_path, plot_path in zip(images, wcs_paths, plot_paths, strict=True):
            try:
                sol = solve_image(path, fov_deg=fov, fov_tolerance_deg=fov_tolerance, camera=camera,
                                  database=database, epoch=epoch, attitude_method=method, attitude_hint=hint,
                                  identify_method=identify_method, smear_px=smear_px, **maps, **noise,
                                  **observation)
                any_failed |= not sol.solved
                typer.echo(sol.to_json() if json_out else _summary(sol))
                if sol.solved and wcs_path is not None:
                    from skyfix.wcs import write_wcs

                    write_wcs(wcs_path, sol.A_apparent_to_cam, sol.camera)  # against catalogue places
                if plot_path is not None:
                    from skyfix.io import read_image
                    from skyfix.plot import plot_solution

                    plot_solution(read_image(path), sol, plot_path)
            except Exception as exc:  # this image's error line, then the next image
                any_error = True
                typer.echo(f"skyfix: error: {error_line(exc, path)}{_count_flag_hint(exc, path)}", err=True)
            if progress is not None:
                progress.advance(0)
    if progress is not None:
        progress.stop()
    raise typer.Exit(2 if any_error else 1 if any_failed else 0)


_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_COUNTED = re.compile(r"-v+|--verbose")


def _plain_solve(argv: list[str]) -> tuple[int, dict] | None:
    """``skyfix solve`` arguments that need none of typer's checks, read straight into the
    command's keywords: ``(-v count before the command, {parameter: value})``; None for anything
    else (typer then parses them). Plain means: ``-v``/``-vv``/``--verbose`` before ``solve``;
    after it image paths and solve's options, each at most once, as ``--name VALUE`` or
    ``--name=VALUE``, every value non-empty and not starting with ``-``, every number a plain
    decimal (``10``, ``-2.5``, ``1e-3``: no ``nan``, no ``1_0``), flags without a value. Each
    option's name, type and default come from the signature of :func:`solve`; an option of a
    type not handled here turns the shortcut off."""
    pre, i = 0, 0
    while i < len(argv) and _COUNTED.fullmatch(argv[i]):
        pre += _count(argv[i])
        i += 1
    if argv[i:i + 1] != ["solve"]:
        return None
    params = _solve_parameters()
    if params is None:
        return None
    options = {name: default for name, (_, _, default) in params.items()}
    by_flag = {flag: name for name, (flags, _, _) in params.items() for flag in flags}
    images, given, verbose = [], set(), 0
    rest = argv[i + 1:]
    k = 0
    while k < len(rest):
        arg = rest[k]
        k += 1
        if not arg:
            return None
        if not arg.startswith("-"):
            images.append(Path(arg))
            continue
        if _COUNTED.fullmatch(arg):
            verbose += _count(arg)
            continue
        flag, eq, value = arg.partition("=")
        name = by_flag.get(flag)
        if name is None or name in given:
            return None
        given.add(name)
        kind = params[name][1]
        if kind is bool:
            if eq:
                return None
            options[name] = True
            continue
        if not eq:
            if k == len(rest):
                return None
            value = rest[k]
            k += 1
        if not value or value.startswith("-") and not (kind is float and _NUMBER.fullmatch(value)):
            return None
        if kind is float:
            if not _NUMBER.fullmatch(value):
                return None
            options[name] = float(value)
        else:
            options[name] = kind(value)
    if not images:
        return None
    options["images"], options["verbose"] = images, verbose
    return pre, options


def _count(arg: str) -> int:
    return 1 if arg == "--verbose" else len(arg) - 1


@functools.cache
def _solve_parameters() -> dict[str, tuple[tuple[str, ...], type, object]] | None:
    """solve's options as ``{parameter: (flags, type, default)}`` (images and -v apart), read
    from its signature (annotations are strings here: ``from __future__ import annotations``);
    None if one is of a kind :func:`_plain_solve` does not read."""
    import inspect

    kinds = {"float": float, "str": str, "Path": Path, "bool": bool}
    out = {}
    for name, p in inspect.signature(solve).parameters.items():
        info = p.default
        if name in ("images", "verbose"):
            continue
        kind = kinds.get(p.annotation) if isinstance(p.annotation, str) else None
        decls = tuple(getattr(info, "param_decls", None) or ())
        if (kind is None or not isinstance(info, typer.models.OptionInfo) or not decls
                or not all(d.startswith("--") and "/" not in d for d in decls)
                or info.callback is not None or info.envvar is not None or info.count):
            return None
        out[name] = (decls, kind, info.default)
    return out


def _solve_paths(identify_method: str, attitude_method: str, hint: bool) -> list[str]:
    """The warm-up paths (:mod:`skyfix.warmup`) a solve with these options runs: the default
    solve's, and the method's, solver's and hint's when they are not the defaults."""
    paths = ["solve"]
    if identify_method.lower() not in ("quad-hash", "hash"):
        paths.append(f"method-{identify_method.lower()}")
    if attitude_method.lower() != "svd":
        paths.append("attitude")
    if hint:
        paths.append("hint")
    return paths


def _attitude_hint(text: str | None):
    """``--attitude-hint RA,DEC,ROLL[,UNCERTAINTY_DEG]`` checked before any work (None: no hint)."""
    if text is None:
        return None
    from skyfix.identify.hint import check_attitude_hint

    return check_attitude_hint(text, "--attitude-hint")


def _smear(text: str | None):
    """``--smear DX,DY`` checked before any work (None: no smear)."""
    if text is None:
        return None
    try:
        parts = [float(p) for p in text.split(",")]
    except ValueError:
        parts = []
    if len(parts) != 2 or not all(math.isfinite(p) for p in parts):
        fail(f"--smear wants two numbers of pixels DX,DY, got {text!r}")
    return parts


def _identify_method(name: str) -> None:
    """``--method NAME`` checked before any work: a registered identification method."""
    from skyfix.identify import METHODS

    if name.lower() not in METHODS:
        fail(f"--method: unknown identification method {name!r}; choose one of {', '.join(METHODS)}")


def _count_flag_hint(exc: BaseException, path: Path) -> str:
    """``skyfix solve -v 1 x.png`` reads "1" as an image: say why."""
    if isinstance(exc, ImageReadError) and str(path).isdigit() and not path.exists():
        return " (-v takes no value: write -v or -vv)"
    return ""


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
    path = " | near the attitude hint" if sol.method == "attitude-hint" else ""
    sig = [v**0.5 for v in (sol.covariance_arcsec2[0][0], sol.covariance_arcsec2[1][1],
                            sol.covariance_arcsec2[2][2])]
    return (f"{sol.image}: solved RA {sol.ra_deg:.5f}° Dec {sol.dec_deg:+.5f}° roll {sol.roll_deg:.3f}° "
            f"FOV {sol.fov_deg:.3f}° | {sol.n_matched}/{sol.n_detected} stars, rmse {sol.rmse_arcsec:.1f}″, "
            f"σ(x,y,roll) {sig[0]:.1f}″ {sig[1]:.1f}″ {sig[2]:.0f}″, P(false) {sol.prob_false:.1e} | "
            f"{sol.time_ms.get('total', 0):.1f} ms{path}{summary_suffix(sol)}")


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
        import time

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


@app.command()
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
    import json

    import numpy as np

    import skyfix.detect as det
    from skyfix.io import read_image

    add_verbosity(verbose)
    sigma = check_positive(sigma, "--sigma")
    max_stars = check_count(max_stars, "--max-stars")
    if method not in det.METHODS:
        fail(f"unknown detection method {method!r}; choose one of {', '.join(det.METHODS)}")
    if centroid not in det.CENTROIDERS:
        fail(f"unknown centroider {centroid!r}; choose one of {', '.join(det.CENTROIDERS)}")
    maps = _calibration_maps(calibration, None, None)
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
                typer.echo(f"skyfix: error: {error_line(exc, path)}", err=True)
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


calibrate_app = typer.Typer(no_args_is_help=True, rich_markup_mode=None,
                            help="Calibrate the sensor (dark, flat, hot pixels) and the camera (from stars).")
app.add_typer(calibrate_app, name="calibrate")


def _register_calibration() -> None:
    from skyfix.calibration.commands import register

    register(calibrate_app)  # `skyfix calibrate stars`: skyfix/calibration/commands.py


_register_calibration()


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
@guarded
def simulate(
    out_dir: Path = typer.Argument(None, metavar="[OUT_DIR]",
                                   help="Folder for the frames (frame-0000.fits … with NAME.truth.json "
                                        "beside each); or give one image file with -o."),
    ra: float = typer.Option(..., "--ra", help="Boresight right ascension, degrees."),
    dec: float = typer.Option(..., "--dec", help="Boresight declination, degrees."),
    roll: float = typer.Option(0.0, "--roll", help="Roll (PA of image-up from north through east), degrees."),
    camera: str = typer.Option("generic", "--camera", help="Camera preset name or TOML file."),
    sensor: str = typer.Option(None, "--sensor", help="Sensor preset name or TOML file."),
    exposure: float = typer.Option(None, "--exposure", help="Exposure, seconds (default: the preset's)."),
    time: str = typer.Option(None, "--time",
                             help="Mid-exposure time of the first frame, ISO 8601 (default: now)."),
    seed: int = typer.Option(0, "--seed", help="Noise seed (same seed, same image, bit for bit)."),
    false_stars: int = typer.Option(0, "--false-stars", help="False stars / debris to add."),
    hot_pixels: int = typer.Option(0, "--hot-pixels", help="Hot pixels to add."),
    frames: int = typer.Option(1, "--frames", help="Number of frames (a sequence when > 1)."),
    fps: float = typer.Option(10.0, "--fps", help="Frame rate of a sequence, frames per second."),
    output: Path = typer.Option(None, "--output", "-o",
                                help="Image file: .fits, .png or .tif (a sequence: NAME-0000.fits …)."),
    profile: str = typer.Option(None, "--profile", rich_help_panel="Motion",
                                help="How the camera turns: constant (--rate-dps), inertial-axis, slew, "
                                     "pendulum (docs/simulating.md). Default: constant."),
    rate_dps: str = typer.Option(None, "--rate-dps", rich_help_panel="Motion",
                                 help="constant: body rate wx,wy,wz about the camera axes, deg/s; "
                                      "inertial-axis: the rate about --axis, deg/s."),
    axis: str = typer.Option(None, "--axis", rich_help_panel="Motion",
                             help="inertial-axis: the ICRS axis as RA,DEC, degrees."),
    rotation_deg: str = typer.Option(None, "--rotation-deg", rich_help_panel="Motion",
                                     help="slew: the turn as a rotation vector x,y,z in the camera axes, "
                                          "degrees (0,10,0: 10° about camera y). Default 0,10,0."),
    max_rate_dps: float = typer.Option(None, "--max-rate-dps", rich_help_panel="Motion",
                                       help="slew: the coasting rate, deg/s (default 2)."),
    accel_dps2: float = typer.Option(None, "--accel-dps2", rich_help_panel="Motion",
                                     help="slew: the (peak) acceleration, deg/s² (default 1)."),
    smooth: bool = typer.Option(False, "--smooth", rich_help_panel="Motion",
                                help="slew: ramp the rate as a half cosine (no jump in acceleration) "
                                     "instead of a trapezoid."),
    start: float = typer.Option(None, "--start", rich_help_panel="Motion",
                                help="slew: when it starts, seconds after the first frame (default 0)."),
    amplitude_deg: str = typer.Option(None, "--amplitude-deg", rich_help_panel="Motion",
                                      help="pendulum: amplitude about camera x,y,z, degrees (default "
                                           "0.5,2,0.2: mostly pitch, as thesis 002's air bearing)."),
    period: float = typer.Option(None, "--period", rich_help_panel="Motion",
                                 help="pendulum: the damped period, seconds (default 8)."),
    damping: float = typer.Option(None, "--damping", rich_help_panel="Motion",
                                  help="pendulum: the damping ratio, 0 to < 1 (default 0.05)."),
    phase_deg: str = typer.Option(None, "--phase-deg", rich_help_panel="Motion",
                                  help="pendulum: phase of each axis, degrees (default 0,0,90: through "
                                       "equilibrium at the first frame, yaw a quarter period behind)."),
    verbose: int = VERBOSE,
) -> None:
    """Render a simulated star image, or a sequence of frames as the camera turns, and write the
    truth beside each image (NAME.truth.json: attitude, body rate, time, every star)."""
    from skyfix.geometry import attitude_from_radec_roll
    from skyfix.simulate import render, render_sequence, write_frame

    add_verbosity(verbose)
    if not (math.isfinite(ra) and math.isfinite(roll)):
        fail("--ra and --roll must be finite numbers of degrees")
    if not -90.0 <= dec <= 90.0:
        fail(f"--dec {dec:g} is outside -90..90 degrees")
    frames = check_count(frames, "--frames")
    check_positive(fps, "--fps")
    if exposure is not None:
        check_positive(exposure, "--exposure")
    for name, value in (("--false-stars", false_stars), ("--hot-pixels", hot_pixels), ("--seed", seed)):
        check_count(value, name, minimum=0)
    A = attitude_from_radec_roll(math.radians(ra), math.radians(dec), math.radians(roll))
    motion_options = {"--rate-dps": rate_dps, "--axis": axis, "--rotation-deg": rotation_deg,
                      "--max-rate-dps": max_rate_dps, "--accel-dps2": accel_dps2, "--smooth": smooth or None,
                      "--start": start, "--amplitude-deg": amplitude_deg, "--period": period,
                      "--damping": damping, "--phase-deg": phase_deg}
    motion = _simulate_profile(profile, A, {k: v for k, v in motion_options.items() if v is not None})
    if (out_dir is None) == (output is None):
        fail("give an output folder (OUT_DIR) or an image file (-o FILE), not both" if out_dir is not None
             else "give an output folder (OUT_DIR) or an image file (-o FILE)")
    if out_dir is not None:
        if out_dir.exists() and not out_dir.is_dir():
            fail(f"OUT_DIR {out_dir} is a file; give a folder (or write one image with -o {out_dir})")
        paths = [out_dir / f"frame-{k:04d}.fits" for k in range(frames)]
    elif frames == 1:
        paths = [output]
    else:
        paths = [output.with_name(f"{output.stem}-{k:04d}{output.suffix}") for k in range(frames)]
    prepare_outputs({"--output" if out_dir is None else "OUT_DIR": paths})
    kw = dict(sensor=_sensor_arg(sensor), exposure_s=exposure, epoch=time, seed=seed,
              false_stars=false_stars, hot_pixels=hot_pixels)
    cam = _camera_arg(camera)
    progress = _simulate_progress(frames)
    try:
        with compile_notice(progress):
            if frames == 1 and out_dir is None and motion is None:
                image, truth = write_frame(render(A, cam, **kw), output)
                typer.echo(f"wrote {image} and {truth}")
                return
            sequence = render_sequence(A, cam, n_frames=frames, fps=fps, profile=motion, **kw)
            for path, frame in zip(paths, sequence, strict=True):
                write_frame(frame, path)
                if progress is not None:
                    progress.advance(0)
    except ValueError as exc:  # the simulator's own checks of sensor and preset values
        fail(f"bad value: {exc}")
    finally:
        if progress is not None:
            progress.stop()
    if frames == 1:
        typer.echo(f"wrote {paths[0]} and {paths[0].with_suffix('.truth.json')}")
    else:
        where = out_dir if out_dir is not None else paths[0].parent
        typer.echo(f"wrote {frames} frames to {where} ({paths[0].name} … {paths[-1].name}, "
                   "truth beside each)")


#: Each profile's options on the command line, with their defaults (None: required).
_PROFILE_OPTIONS: dict[str, dict[str, object]] = {
    "constant": {"--rate-dps": "0,0,0"},
    "inertial-axis": {"--axis": None, "--rate-dps": None},
    "slew": {"--rotation-deg": "0,10,0", "--max-rate-dps": 2.0, "--accel-dps2": 1.0, "--smooth": False,
             "--start": 0.0},
    "pendulum": {"--amplitude-deg": "0.5,2,0.2", "--period": 8.0, "--damping": 0.05, "--phase-deg": "0,0,90"},
}


def _simulate_profile(name: str | None, A, given: dict):
    """The simulate command's attitude profile from ``--profile`` and its options (None: a camera
    at rest); an option of another profile, or a value that makes no sense, fails (exit 2)."""
    from skyfix.errors import SimulationError, UnknownNameError
    from skyfix.simulate import PROFILES, make_profile

    if name is None:
        if not given:
            return None
        name = "constant"
    if name not in PROFILES:
        fail(f"--profile {name!r} is not a motion profile; choose one of {', '.join(PROFILES)}")
    allowed = _PROFILE_OPTIONS[name]
    for option in given:
        if option not in allowed:
            fail(f"{option} is not an option of --profile {name} (its options: {', '.join(allowed)})")
    opts = {**allowed, **given}
    for option, value in opts.items():
        if value is None:
            fail(f"--profile {name} needs {option}")
    def radians(option: str, n: int, form: str) -> list[float]:
        return [math.radians(v) for v in _numbers(opts[option], n, option, form)]

    def positive_radians(option: str) -> float:
        return math.radians(check_positive(opts[option], option))

    try:
        if name == "constant":
            params = dict(rate_rad_s=radians("--rate-dps", 3, "wx,wy,wz"))
        elif name == "inertial-axis":
            ra_rad, dec_rad = radians("--axis", 2, "RA,DEC")
            if not abs(dec_rad) <= math.pi / 2:
                fail(f"--axis declination {math.degrees(dec_rad):g} is outside -90..90 degrees")
            from skyfix.geometry import radec_to_vector

            params = dict(axis_icrs=radec_to_vector(ra_rad, dec_rad),
                          rate_rad_s=radians("--rate-dps", 1, "W")[0])
        elif name == "slew":
            params = dict(rotation_rad=radians("--rotation-deg", 3, "x,y,z"),
                          max_rate_rad_s=positive_radians("--max-rate-dps"),
                          accel_rad_s2=positive_radians("--accel-dps2"),
                          start_s=opts["--start"], shape="smooth" if opts["--smooth"] else "trapezoid")
        else:
            if not 0.0 <= opts["--damping"] < 1.0:
                fail(f"--damping {opts['--damping']:g} must be a damping ratio from 0 to below 1")
            params = dict(amplitude_rad=radians("--amplitude-deg", 3, "ax,ay,az"),
                          period_s=check_positive(opts["--period"], "--period"),
                          damping_ratio=opts["--damping"], phase_rad=radians("--phase-deg", 3, "px,py,pz"))
        return make_profile(name, A, **params)
    except (SimulationError, UnknownNameError) as exc:  # a parameter out of range, in the profile's own words
        fail(f"--profile {name}: {exc}")


def _numbers(text: str, n: int, option: str, form: str) -> list[float]:
    """``n`` finite comma-separated numbers, or fail saying ``option`` takes ``form``."""
    try:
        values = [float(v) for v in str(text).split(",")]
    except ValueError:
        values = []
    if len(values) != n or not all(map(math.isfinite, values)):
        fail(f"{option} takes {n} number{'s' if n > 1 else ''}: {form} (got {text!r})")
    return values


def _simulate_progress(n: int):
    """A progress bar on stderr while a sequence renders (not for one frame, nor off a terminal)."""
    if n < 2 or not sys.stderr.isatty():
        return None
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    progress = Progress(TextColumn("rendering"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                        console=Console(stderr=True), transient=True)
    progress.add_task("rendering", total=n)
    progress.start()
    return progress


@app.command("warmup")
@guarded
def warmup_command(
    paths: list[str] = typer.Argument(None, metavar="PATH",
                                      help="What to compile (default: everything): see --list."),
    list_paths: bool = typer.Option(False, "--list", help="List the paths, whether each is compiled; exit."),
    workers: int = typer.Option(None, "--workers", help="Processes at once (default: every CPU)."),
    verbose: int = VERBOSE,
) -> None:
    """Compile skyfix's kernels now, on every core, instead of on each feature's first use (once)."""
    add_verbosity(verbose)
    from skyfix import warmup

    names = list(paths) if paths else list(warmup.PATHS)
    unknown = [p for p in names if p not in warmup.PATHS]
    if unknown:
        fail(f"unknown warm-up path {unknown[0]!r}; choose from {', '.join(warmup.PATHS)}")
    if workers is not None:
        workers = check_count(workers, "--workers")
    if list_paths:
        n = workers or warmup.default_workers()
        for name in names:
            state = ("compiled" if warmup.is_warm(name) else
                     f"to compile: about {warmup.estimate_s(warmup.pending([name]), n):.0f} s on {n} cores")
            typer.echo(f"{name:28s} {state}")
        raise typer.Exit(0)
    from skyfix.identify import default_database, default_database_path

    building = not default_database_path().exists()
    alongside = functools.partial(default_database, progress=False) if building else None
    done = warmup.warm(names, workers=workers, alongside=alongside,
                       also="building the pattern database" if building else "")
    left = [p for p in names if not warmup.is_warm(p)]
    if left:
        fail(f"could not compile {', '.join(left)} ahead of use (see -v); they compile on first use", code=1)
    typer.echo(f"skyfix: {len(names)} path(s) compiled" + ("" if done else " already"))


def _register_track() -> None:
    from skyfix.track.cli import register

    register(app, _load_camera)  # `skyfix track`: skyfix/track/cli.py, with the camera loader of --camera


_register_track()


def _register_montecarlo() -> None:
    from skyfix.montecarlo.command import register

    register(app)  # `skyfix montecarlo`: skyfix/montecarlo/command.py


_register_montecarlo()


def main() -> None:  # pragma: no cover - console entry point
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
