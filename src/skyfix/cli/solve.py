"""``skyfix solve IMAGE…``: lost in space (or near ``--attitude-hint``), one line or one JSON
Solution per image; and the shortcut that runs a plain solve without typer's value coercion.

Exit codes: 0 all images solved; 1 some image failed to solve (its reason is printed); 2 bad
input, with a one-line error — a batch goes on past a bad file and exits 2 at the end.

Imports of what a solve runs (the pipeline, the identification registry, the WCS writer, the
plot) sit inside the functions that use them: this module is loaded by every ``skyfix`` start,
``--version`` and ``-h`` included, which must stay light (tests/cli/test_cli_start.py).
"""

from __future__ import annotations

import functools
import inspect
import itertools
import json
import math
import re
import sys
from pathlib import Path

import typer

from skyfix.cli.common import (
    EPOCH_HELP,
    VERBOSE,
    add_verbosity,
    calibration_maps,
    check_cluster,
    checking,
    compile_notice,
    counter_bar,
    fail,
    guarded,
    load_camera,
    load_database,
    output_paths,
    prepare_outputs,
)
from skyfix.cli.inputs import expand_inputs, frame_size
from skyfix.cli.observation import observation_option, observation_options, summary_suffix
from skyfix.cli.records import CentroidTable, InputOutputs, solve_input
from skyfix.validate import check_positive, check_solve_options

__all__ = ["CENTROIDS_HELP", "OUTPUT_NAMES_HELP", "plain_solve", "solve", "solve_parameters"]

#: The epilog of ``skyfix solve -h``: how output files are named.
OUTPUT_NAMES_HELP = ("Outputs are named after each image: put {stem} in the name (out/{stem}.png). "
                     "Images that share a name get their folder's name in front if the folders differ "
                     "(a/sky.png → a-sky, b/sky.png → b-sky), their extension behind if the extensions "
                     "differ (sky-png, sky-fits), -2 for a file given twice. Missing folders are "
                     "created; no output overwrites an input or another output.")

#: ``--centroids``: what the table holds (README's "Solving images").
CENTROIDS_HELP = ("Solve a table of centroids instead of an image: columns x,y[,flux], pixels, (0,0) the "
                  "centre of the top-left pixel, brightest first unless flux is given. Needs --size.")


@guarded
def solve(
    images: list[Path] = typer.Argument(
        None, show_default=False,
        help="Image files (FITS, PNG, TIFF, JPEG), folders (their images, sorted by name) and list "
             "files @LIST.txt (one path a line, relative to the list's folder)."),
    centroids: Path = typer.Option(None, "--centroids", metavar="FILE.csv", help=CENTROIDS_HELP),
    size: str = typer.Option(None, "--size", metavar="W,H",
                             help="The frame's width and height, pixels, for --centroids."),
    fov: float = typer.Option(None, "--fov", help="Horizontal field of view, degrees (optional)."),
    fov_tolerance: float = typer.Option(None, "--fov-tolerance",
                                        help="Allowed error of --fov, degrees (default 10%)."),
    camera_file: str = typer.Option(None, "--camera", help="Camera TOML file or preset name."),
    epoch: float = typer.Option(None, "--epoch", help=EPOCH_HELP),
    method: str = typer.Option("svd", "--attitude", help="Wahba solver: svd, quest, esoq2, q-method, triad."),
    identify_method: str = typer.Option(
        "quad-hash", "--method", metavar="NAME",
        help="Identification method (skyfix.identify.METHODS; docs/identification-methods.md). The default "
             "tries the triangle method on sparse frames when --camera or --fov gives the scale."),
    json_out: bool = typer.Option(
        False, "--json", help="One JSON record per input per line, in input order, errors included "
                              "(fields: docs/design.md#the-solution)."),
    parquet: Path = typer.Option(
        None, "--parquet", metavar="FILE",
        help="Also write the records as one Parquet table, a row per input in input order, errors "
             "included (the --json fields; nested ones as JSON text)."),
    save_camera: Path = typer.Option(
        None, "--save-camera", metavar="FILE.toml",
        help="Write the camera fitted on the frame (a --camera file for the next frame of that camera; "
             "use {stem} for many images)."),
    wcs: Path = typer.Option(None, "--wcs", help="Write a FITS WCS header (use {stem} for many images)."),
    plot: Path = typer.Option(None, "--plot", help="Write a PNG with identified stars circled."),
    database_file: Path = typer.Option(None, "--database", help="Pattern database file (default: cached)."),
    calibration: Path = typer.Option(None, "--calibration", help="Maps from `skyfix calibrate frames`."),
    dark: Path = typer.Option(None, "--dark", help="Master dark image to subtract."),
    flat: Path = typer.Option(None, "--flat", help="Master flat image to divide by (normalised to 1)."),
    workers: int = typer.Option(1, "--workers", metavar="N",
                                help="Solve the inputs on N local worker processes (Dask), in batches; "
                                     "the records still come in input order."),
    scheduler: str = typer.Option(None, "--scheduler", metavar="ADDRESS",
                                  help="Solve on a running Dask scheduler's workers (tcp://HOST:8786); "
                                       "they must import the same skyfix and see the same files."),
    mask: Path = typer.Option(None, "--mask", metavar="FILE",
                              help="Image of the frame's size: white (non-zero) = sky to use, black = "
                                   "ignore (horizon, trees, a caption, outside an all-sky lens)."),
    attitude_hint: str = typer.Option(
        None, "--attitude-hint", metavar="RA,DEC,ROLL[,UNCERTAINTY_DEG]",
        help="A rough attitude, degrees (uncertainty: the largest error, default 1): identify the stars "
             "near it first, falling back to lost in space. Needs --camera or --fov for the scale."),
    centroid_sigma: float = typer.Option(
        None, "--centroid-sigma", metavar="PX",
        help="The centroids' noise, pixels, when known (a calibrated tracker's): the search's "
             "tolerances, and with --camera a prior on the noise the error bars rest on — three or "
             "four stars' residuals cannot bound it alone (docs/identification-methods.md#triangle)."),
    parity: str = typer.Option(
        None, "--parity", metavar="normal|mirrored|either",
        help="Whether the image may be a mirror image (a star diagonal, rows stored bottom-up): "
             "normal, mirrored, or either (tries both; the default for FITS files, normal for the rest)."),
    smear: str = typer.Option(
        None, "--smear", metavar="DX,DY",
        help="The stars' streak over the exposure when the camera turned, pixels (a gyro's rate × the "
             "exposure): stars are found in the frame averaged along it."),
    obs_time: str = observation_option("--time"),
    velocity_kms: str = observation_option("--velocity-kms"),
    position_km: str = observation_option("--position-km"),
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
    check_cluster(None if workers == 1 else workers, scheduler)
    if parity is not None:
        from skyfix.parity import check_parity

        with checking("--parity", parity):
            check_parity(parity)
    smear_px = _smear(smear)
    noise = {} if centroid_sigma is None else {"centroid_sigma_px": check_positive(centroid_sigma,
                                                                                   "--centroid-sigma")}
    _identify_method(identify_method)
    sources = _sources(images, centroids, size, plot)
    names = [s.path if isinstance(s, CentroidTable) else s for s in sources]
    outputs = {"--wcs": output_paths(wcs, names, ".wcs"), "--plot": output_paths(plot, names, ".png"),
               "--save-camera": output_paths(save_camera, names, ".toml")}
    prepare_outputs(outputs if parquet is None else {**outputs, "--parquet": [parquet]}, inputs=names)
    maps = calibration_maps(calibration, dark, flat)
    if mask is not None:
        from skyfix.detect.mask import as_mask

        with checking("--mask", mask):
            maps["mask"] = as_mask(mask, margin_px=0)  # read once; each image checks its size
    with checking("--camera", camera_file):
        camera = load_camera(camera_file) if camera_file is not None else None
    observation = observation_options(obs_time, velocity_kms, site, weather, refraction, mounting, apparent,
                                      camera_file, epoch, position_km)  # after --camera: its tables
    database = load_database(database_file, _solve_paths(identify_method, method, hint is not None))
    if hint is not None and camera is None and fov is None:
        typer.echo("skyfix: note: --attitude-hint needs the image scale (--camera or --fov); "
                   "solving lost in space", err=True)
    options = dict(fov_deg=fov, fov_tolerance_deg=fov_tolerance, camera=camera, database=database,
                   epoch=epoch, attitude_method=method, attitude_hint=hint, identify_method=identify_method,
                   **noise, **observation)
    if parity is not None:
        options["parity"] = parity
    if centroids is None:
        options.update(smear_px=smear_px, **maps)
    elif maps or smear_px is not None:
        fail("--calibration, --dark, --flat and --smear work on an image; a --centroids table has none")

    items = [(source, InputOutputs(*paths))
             for source, *paths in zip(sources, *outputs.values(), strict=True)]
    if workers > 1 or scheduler is not None:
        from skyfix.cli.batch import solve_on_cluster

        with checking("--scheduler", scheduler):
            outcomes = solve_on_cluster(items, options, workers=workers, scheduler=scheduler,
                                        database_file=database_file)
            first = next(outcomes, None)  # connects (an unreachable scheduler fails here, one line)
        outcomes = itertools.chain([first] if first is not None else [], outcomes)
    else:
        outcomes = (solve_input(source, paths, options) for source, paths in items)
    any_failed = any_error = False
    progress = _progress(len(sources), json_out)
    table = [] if parquet is not None else None
    with compile_notice(progress):
        for record, sol in outcomes:
            if table is not None:
                table.append(record)
            any_error |= sol is None
            any_failed |= sol is not None and not sol.solved
            if sol is None:  # on stderr with --json too, where a reader watching the batch sees it
                typer.echo(f"skyfix: error: {record['image']}: {record['reason']}", err=True)
            if json_out:
                typer.echo(json.dumps(record, separators=(", ", ": ")))
            elif sol is not None:
                typer.echo(_summary(sol))
            if progress is not None:
                progress.advance(0)
    if progress is not None:
        progress.stop()
    if table is not None:
        from skyfix.cli.records import write_parquet

        write_parquet(table, parquet)
    raise typer.Exit(2 if any_error else 1 if any_failed else 0)


_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_COUNTED = re.compile(r"-v+|--verbose")


def plain_solve(argv: list[str]) -> tuple[int, dict] | None:
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
    params = solve_parameters()
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
        elif kind is int:
            if not value.isdigit():  # plain decimal digits; anything else is typer's to judge
                return None
            options[name] = int(value)
        else:
            options[name] = kind(value)
    if not images:
        return None
    options["images"], options["verbose"] = images, verbose
    return pre, options


def _count(arg: str) -> int:
    return 1 if arg == "--verbose" else len(arg) - 1


@functools.cache
def solve_parameters() -> dict[str, tuple[tuple[str, ...], type, object]] | None:
    """solve's options as ``{parameter: (flags, type, default)}`` (images and -v apart), read
    from its signature (annotations are strings here: ``from __future__ import annotations``);
    None if one is of a kind :func:`plain_solve` does not read."""
    kinds = {"float": float, "int": int, "str": str, "Path": Path, "bool": bool}
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


def _sources(images: list[Path] | None, centroids: Path | None, size: str | None,
             plot: Path | None) -> list[Path | CentroidTable]:
    """The inputs in order: images (folders and @lists expanded), or the one --centroids table."""
    if centroids is None:
        if size is not None:
            fail("--size is the frame size of a --centroids table; an image gives its own")
        if not images:
            fail("give images to solve (files, folders, @LIST.txt) or --centroids FILE.csv --size W,H")
        return expand_inputs(images)
    if images:
        fail("--centroids takes the place of images: give one or the other")
    if size is None:
        fail("--centroids needs --size W,H (the frame's width and height, pixels)")
    if plot is not None:
        fail("--plot draws on an image; a --centroids table has none")
    width, height = frame_size(size)
    return [CentroidTable(centroids, width, height)]


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


def _progress(n: int, quiet: bool):
    """Progress on stderr for batches of 5 inputs or more: a bar on a terminal (not under
    --json), a line per input off one (``skyfix: solving 3/20 (4 s)``)."""
    if n < 5 or quiet and sys.stderr.isatty():
        return None
    return counter_bar("solving", n)


def _summary(sol) -> str:
    if not sol.solved:
        from skyfix.failures import step_to_add

        step = step_to_add(sol.reason)
        return f"{sol.image}: failed: {sol.reason}" + (f" — try: {step}" if step else "")
    path = " | near the attitude hint" if sol.method == "attitude-hint" else ""
    # The image centre's numbers and their σ, as other plate solvers give them; the boresight named
    # where the stars put the principal point elsewhere (docs/design.md#the-solution).
    sig = sol.center_sigma_arcsec
    bx, by = sol.boresight_px
    where = ""
    if sol.boresight_off_centre:
        where = f" | boresight at ({bx:.1f}, {by:.1f}) px: RA {sol.ra_deg:.5f}° Dec {sol.dec_deg:+.5f}°"
    mirrored = " | mirror image" if sol.mirrored else ""
    return (f"{sol.image}: solved RA {sol.center_ra_deg:.5f}° Dec {sol.center_dec_deg:+.5f}° "
            f"roll {sol.center_roll_deg:.3f}° "
            f"FOV {sol.fov_deg:.3f}° | {sol.n_matched}/{sol.n_detected} stars, rmse {sol.rmse_arcsec:.1f}″, "
            f"σ(x,y,roll) {sig[0]:.1f}″ {sig[1]:.1f}″ {sig[2]:.0f}″, P(false) {sol.prob_false:.1e} | "
            f"{sol.time_ms.get('total', 0):.1f} ms{path}{mirrored}{where}{summary_suffix(sol)}"
            + "".join(f" | {w}" for w in sol.warnings))

