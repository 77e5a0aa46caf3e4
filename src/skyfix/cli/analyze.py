"""``skyfix analyze``: centroid accuracy vs. the Cramér–Rao bound, PSF across the field, photometry,
tracking against lost in space and thesis 002, the seed presets solved lost in space, the mounting
of a fixed ground camera from a night of images.

Registered in :mod:`skyfix.cli` with ``app.add_typer(analyze_app, name="analyze")``. Errors are
one line, as everywhere in the CLI (:mod:`skyfix.cli.common`). Each study is imported when its
command runs, not when the command table is set up: every ``skyfix`` start loads this module.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import typer

from skyfix.cli.common import (
    EPOCH_HELP,
    VERBOSE,
    LineProgress,
    OneLineErrors,
    add_verbosity,
    check_cluster,
    checking,
    compile_notice,
    error_line,
    fail,
    guarded,
    input_error_line,
    load_camera,
    load_database,
    prepare_outputs,
)
from skyfix.errors import InputError, SkyfixError, unknown_name
from skyfix.validate import check_count, check_epoch, check_fov, check_positive

analyze_app = typer.Typer(cls=OneLineErrors, no_args_is_help=True, pretty_exceptions_enable=False,
                          rich_markup_mode=None,
                          help="Analyses: centroid accuracy vs. the Cramér–Rao bound, PSF over the field, "
                               "photometry against the catalogue, tracking against lost in space, the seed "
                               "presets solved lost in space.")


def _progress(total: int, quiet: bool):
    """Progress on stderr (not when ``quiet``): a transient bar on a terminal, a line per step
    off one (:class:`~skyfix.cli.common.LineProgress`: ``skyfix: what 3/20 (12 s)``)."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    console = Console(stderr=True)
    if not quiet and not console.is_terminal:
        return LineProgress()
    return Progress(TextColumn("[progress.description]{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TimeRemainingColumn(), console=console, transient=True,
                    disable=quiet or not console.is_terminal)


def _each_image(images: list[Path], quiet: bool, title: str, work, errors: list):
    """``work(path)`` for each image under a progress bar, yielding ``(path, result)``; an image
    whose work raises gets its one error line (and is added to ``errors``), and the next goes on."""
    with _progress(len(images), quiet) as bar, compile_notice(bar):
        task = bar.add_task(title, total=len(images))
        for path in images:
            try:
                result = work(path)
            except Exception as exc:  # this image's error line, then the next image
                errors.append(path)
                typer.echo(f"skyfix: error: {input_error_line(exc, path)}", err=True)
                continue
            finally:
                bar.update(task, advance=1)
            yield path, result


@analyze_app.command()
@guarded
def centroids(
    out: Path = typer.Option(Path("centroid-study"), "--out", help="Output directory (JSON, Markdown, PNG)."),
    trials: int = typer.Option(2000, "--trials", min=10, help="Simulated stars per centroider, σ and SNR."),
    quick: bool = typer.Option(False, "--quick", help="Small grid and 200 trials (a smoke run, ~10 s)."),
    seed: int = typer.Option(0, "--seed", help="Random seed."),
    methods: str = typer.Option("", "--methods", help="Comma-separated centroiders and extraction methods "
                                "(default: com, iwcog, gaussian, components, threshold_hillclimb, "
                                "region_grow)."),
    verbose: int = VERBOSE,
) -> None:
    """Run each centroider on simulated stars over SNR × PSF σ × sub-pixel phase; error vs. bound."""
    from skyfix.analysis import centroid_study as cs
    from skyfix.detect import CENTROIDERS

    add_verbosity(verbose)
    trials = check_count(trials, "--trials", minimum=10)

    names = tuple(m.strip() for m in methods.split(",") if m.strip()) or cs.DEFAULT_CENTROIDERS
    known = (*CENTROIDERS, *cs.EXTRACTORS)
    bad = [m for m in names if m not in known]
    if bad or not names:
        fail(f"--methods: {unknown_name('centroider', ', '.join(bad) or '(none)', known)}")
    sigmas, snrs = cs.DEFAULT_SIGMA, cs.DEFAULT_SNR
    if quick:
        sigmas, snrs, trials = (0.5, 1.0, 2.0), (10.0, 50.0, 500.0), min(trials, 200)
    n_steps = len(names) * (len(sigmas) * len(snrs) + 1)
    command = "skyfix analyze centroids" + (" --quick" if quick else f" --trials {trials}") + (
        f" --seed {seed}" if seed else "")
    prepare_outputs({"--out": [out / "centroid-study.json"]})
    with _progress(n_steps, False) as bar, compile_notice(bar):
        task = bar.add_task("centroid study", total=n_steps)
        study = cs.run_study(names, sigmas, snrs, n_trials=trials, seed=seed,
                             progress=lambda what: bar.update(task, advance=1, description=what))
    paths = cs.write_study(study, out, command=command)
    typer.echo(paths[1].read_text())
    for p in paths:
        typer.echo(f"wrote {p}")


@analyze_app.command()
@guarded
def tracking(
    out: Path = typer.Option(Path("tracking-study"), "--out", help="Output directory (JSON, Markdown, PNG, "
                             "Parquet)."),
    quick: bool = typer.Option(False, "--quick", help="16-frame sequences, 24 pendulum frames, 3 ROIs "
                               "(a smoke run, ~25 s on 2 cores)."),
    seed: int = typer.Option(0, "--seed", min=0, help="Random seed (pointings, noise)."),
    workers: int = typer.Option(None, "--workers", metavar="N", help="Local Dask worker processes for the "
                                "sequences (0: one after another in this process; default 2)."),
    scheduler: str = typer.Option(None, "--scheduler", metavar="ADDRESS",
                                  help="Run the sequences on a running Dask scheduler (tcp://HOST:8786) "
                                       "instead of local workers."),
    verbose: int = VERBOSE,
) -> None:
    """Tracking against lost in space and its own error bars, and thesis 002's findings (prediction
    error vs. rate and acceleration, windowed vs. full-frame time) with skyfix's numbers beside."""
    from skyfix.analysis import tracking_report, tracking_runs
    from skyfix.analysis import tracking_study as ts

    add_verbosity(verbose)
    check_cluster(workers, scheduler, minimum=0)
    n_workers = 2 if workers is None else workers
    settings = (ts.QUICK if quick else ts.FULL)._replace(seed=int(seed), workers=n_workers)
    command = ("skyfix analyze tracking" + (" --quick" if quick else "") + (f" --seed {seed}" if seed else "")
               + (f" --workers {workers}" if workers not in (None, 2) else "")
               + (f" --scheduler {scheduler}" if scheduler else ""))
    rows = out / "tracking_study.parquet"
    prepare_outputs({"--out": [out / "tracking_study.json", rows]})
    n_steps = tracking_runs.study_steps(settings)
    client = None
    if scheduler is not None:  # out of reach: its one line now, before the bar's first
        from skyfix.montecarlo.engine import connect

        client = connect(0, scheduler)[0]
    try:
        with _progress(n_steps, False) as bar, compile_notice(bar):
            task = bar.add_task("tracking study", total=n_steps)
            study = tracking_runs.run_study(settings, progress=_steps(bar, task), output=rows,
                                            scheduler=scheduler, client=client)
    finally:
        if client is not None:
            client.close()
    paths = tracking_report.write_study(study, out, command=command)
    typer.echo(paths[1].read_text())
    for p in [*paths, rows]:
        typer.echo(f"wrote {p}")


def _steps(bar, task: int):
    """A ``progress(done, total)`` callback (the campaign engine's) advancing ``task`` of ``bar``."""
    seen = [0]

    def update(done: int, total: int) -> None:
        bar.update(task, advance=done - seen[0], total=total)
        seen[0] = done

    return update


@analyze_app.command()
@guarded
def presets(
    out: Path = typer.Option(Path("preset-campaign"), "--out",
                             help="Output directory (JSON, Markdown, PNG; the frames as Parquet)."),
    n: int = typer.Option(100, "--n", min=1, help="Frames per preset configuration."),
    seed: int = typer.Option(0, "--seed", min=0, help="Random seed (attitudes, noise)."),
    only: str = typer.Option("", "--presets", help="Comma-separated presets (default: every configuration)."),
    database: Path = typer.Option(None, "--database", help="Solve with this pattern database instead of "
                                  "skyfix's FOV bands (fields it does not serve also with one built for "
                                  "them)."),
    workers: int = typer.Option(0, "--workers", help="Local worker processes on the campaign engine "
                                "(0: in this process)."),
    scheduler: str = typer.Option(None, "--scheduler", metavar="ADDRESS",
                                  help="Run on a running Dask scheduler's workers (tcp://HOST:8786)."),
    verbose: int = VERBOSE,
) -> None:
    """Each seed camera preset rendered at random attitudes and solved with no hint and with its
    camera given: solved, wrong, boresight and roll errors against the truth, honesty of the error
    bars, time."""
    from skyfix.analysis import preset_campaign as pc
    from skyfix.simulate import preset_names

    add_verbosity(verbose)
    n = check_count(n, "--n", minimum=1)
    workers = check_count(workers, "--workers", minimum=0)
    check_cluster(workers or None, scheduler)
    names = [p.strip().lower() for p in only.split(",") if p.strip()]
    bad = [p for p in names if p not in preset_names()]
    if bad:
        fail(f"--presets: {unknown_name('preset', ', '.join(bad), preset_names())}")
    rows = tuple(r for r in pc.CAMPAIGN_ROWS if not names or r.preset in names)
    rows += tuple(pc.CampaignRow(p) for p in names if p not in {r.preset for r in pc.CAMPAIGN_ROWS})
    command = (f"skyfix analyze presets --n {n}" + (f" --seed {seed}" if seed else "")
               + (f" --presets {','.join(names)}" if names else "")
               + (f" --database {database}" if database is not None else ""))
    table = out / "presets.parquet"
    prepare_outputs({"--out": [out / "presets.json", table]})
    if database is not None:
        load_database(database)  # a missing or bad file fails here, in one line
    table.unlink(missing_ok=True)  # a finished run's rows are run again; an interrupted one's continue
    try:  # a scheduler out of reach is the engine's CampaignError: one line (guarded)
        with _progress(n * len(rows), False) as bar, compile_notice(bar):
            task = bar.add_task("preset campaign", total=n * len(rows))
            campaign = pc.run_campaign(n, seed, rows=rows, database=database, workers=workers,
                                       scheduler=scheduler, output=table, progress=_frames_done(bar, task))
    except KeyboardInterrupt:
        typer.echo(f"skyfix: interrupted: the finished frames are kept in {table}.parts; the same "
                   "command continues the campaign", err=True)
        raise typer.Exit(130) from None
    paths = pc.write_campaign(campaign, out, command=command)
    typer.echo(paths[1].read_text())
    for p in [*paths, table]:
        typer.echo(f"wrote {p}")


def _frames_done(bar, task: int):
    """The engine's ``progress(done, total)`` advancing ``task`` of ``bar`` (a rich Progress or a
    :class:`~skyfix.cli.common.LineProgress`) to ``done``."""
    shown = [0]

    def update(done: int, total: int) -> None:
        if done > shown[0]:
            bar.update(task, advance=done - shown[0])
            shown[0] = done

    return update


@analyze_app.command()
@guarded
def psf(
    image: Path = typer.Argument(..., help="Sky image (FITS, PNG, TIFF, JPEG)."),
    out: Path = typer.Option(None, "--out", help="Write the field map (PNG)."),
    json_out: bool = typer.Option(False, "--json", help="Print the summary as one JSON line."),
    min_snr: float = typer.Option(10.0, "--min-snr", help="Use stars above this SNR."),
    verbose: int = VERBOSE,
) -> None:
    """Measure FWHM and ellipticity of isolated, unsaturated stars across the field.

    A frame with no such star fails (exit 1) with the reason on one line."""
    from skyfix.analysis.psf_field import measure_psf_field, plot_psf_field
    from skyfix.detect import frame_problem
    from skyfix.io import read_image

    add_verbosity(verbose)
    check_positive(min_snr, "--min-snr")
    prepare_outputs({"--out": [out]}, inputs=[image])
    img = read_image(image)
    with compile_notice():
        field = measure_psf_field(img, min_snr=min_snr)
    if field.n == 0:
        problem = frame_problem(img)
        reason = (f"no isolated unsaturated stars above SNR {min_snr:g} to measure"
                  + (f": {problem}" if problem else ""))
        typer.echo(json.dumps({"image": str(image), "status": "failed", "reason": reason}) if json_out
                   else f"{image}: failed: {reason}")
        raise typer.Exit(1)
    summary = field.summary()
    summary["image"] = str(image)
    if json_out:
        typer.echo(json.dumps(summary))
    else:
        typer.echo(field.format_summary(str(image)))
    if out is not None:
        plot_psf_field(field, out, title=image.name)
        if not json_out:
            typer.echo(f"wrote {out}")


@analyze_app.command()
@guarded
def photometry(
    images: list[Path] = typer.Argument(..., help="Sky images to solve and calibrate."),
    epoch: float = typer.Option(None, "--epoch", help=EPOCH_HELP),
    fov: float = typer.Option(None, "--fov", help="Horizontal field of view, degrees (optional)."),
    flux: str = typer.Option("psf", "--flux", help="Flux estimator: psf, aperture, extractor."),
    json_out: bool = typer.Option(False, "--json", help="One JSON line per image, then one for the set."),
    verbose: int = VERBOSE,
) -> None:
    """Instrumental magnitudes of identified stars vs. catalogue Hp: zero point and RMS per frame,
    then a shared colour term (B−V) and vignetting (ρ²) fitted over all frames. A frame that
    cannot be read is reported and skipped (exit 2 at the end); with no frame solved, exit 1."""
    from skyfix.analysis.photometry import fit_field_calibration, frame_photometry, summarize

    add_verbosity(verbose)
    if flux not in ("psf", "aperture", "extractor"):
        fail(f"--flux: {unknown_name('flux estimator', flux, ('psf', 'aperture', 'extractor'))}")
    check_epoch(epoch, "--epoch")
    if fov is not None:
        check_fov(fov, "--fov")
    load_database(None)  # says so when it has to be built first
    results, errors = [], []

    def measured(path):
        return frame_photometry(path, epoch=epoch, fov_deg=fov, flux=flux)

    for _, res in _each_image(images, json_out, "photometry", measured, errors):
        results.append(res)
        typer.echo(json.dumps(res.summary()) if json_out else res.format_line())
    any_error = bool(errors)
    total = summarize(results)
    if total["n_frames_solved"] == 0:
        if not json_out:
            typer.echo("no frame solved: no photometry")
        raise typer.Exit(2 if any_error else 1)
    cal = fit_field_calibration(results)
    total["field_calibration"] = {"colour_slope_mag_per_bv": cal.colour_slope,
                                  "vignetting_mag": cal.vignetting, "rms_mag": cal.rms_mag,
                                  "rms_clipped_mag": cal.rms_clipped_mag,
                                  "n_stars": cal.n_stars, "n_clipped": cal.n_clipped,
                                  "rms_hp_lt_6_mag": cal.rms_brighter_than(6.0)}
    if json_out:
        typer.echo(json.dumps(total))
    else:
        typer.echo(f"all: {total['n_frames_solved']}/{total['n_frames']} frames, {total['n_stars']} stars; "
                   f"per-frame zero point only: RMS {total['rms_mag']:.3f} mag "
                   f"(clipped {total['rms_clipped_mag']:.3f}, "
                   f"median per frame {total['median_frame_rms_mag']:.3f})")
        if math.isfinite(cal.rms_mag):
            typer.echo(f"with colour term {cal.colour_slope:+.3f} mag/(B−V) and vignetting "
                       f"{cal.vignetting:+.3f} mag at the corner: RMS {cal.rms_mag:.3f} mag "
                       f"(clipped {cal.rms_clipped_mag:.3f}, "
                       f"{cal.n_clipped} out; Hp < 6: {cal.rms_brighter_than(6.0):.3f})")
        else:
            typer.echo(f"colour term and vignetting: too few stars to fit ({cal.n_stars})")
    if any_error:
        raise typer.Exit(2)
    if total["n_frames_solved"] < total["n_frames"]:
        raise typer.Exit(1)


@analyze_app.command()
@guarded
def budget(
    camera: str = typer.Option("generic", "--camera", help="Camera preset name or TOML file (its [sensor], "
                               "[optics] and [defaults] tables, else the generic preset's)."),
    exposure: float = typer.Option(None, "--exposure", help="Exposure, seconds (default: the preset's)."),
    snr: float = typer.Option(5.0, "--snr", help="Detection threshold, SNR (skyfix's extractor: 5)."),
    sky_mag: float = typer.Option(22.0, "--sky-mag", help="Sky surface brightness, mag/arcsec² "
                                  "(22: a dark site; in orbit fainter)."),
    pointings: int = typer.Option(400, "--pointings", help="Random pointings for the star counts and "
                                  "the attitude."),
    json_out: bool = typer.Option(False, "--json", help="Print the budget as one JSON line."),
    verbose: int = VERBOSE,
) -> None:
    """A camera's budget: limiting and saturation magnitude, stars in view, and the Cramér–Rao
    attitude error they give (thesis 004 §8.3, thesis 000 §2.9); thesis 003's Table 9.5 combined
    in quadrature beside it."""
    from skyfix.analysis import budget as bd

    add_verbosity(verbose)
    if exposure is not None:
        check_positive(exposure, "--exposure")
    check_positive(snr, "--snr")
    pointings = check_count(pointings, "--pointings", minimum=1)
    with checking("--camera", camera):
        b = bd.camera_budget(camera, exposure_s=exposure, snr_threshold=snr, sky_mag_arcsec2=sky_mag,
                             n_pointings=pointings)
    if json_out:
        typer.echo(json.dumps(bd.budget_json(b)))
        return
    typer.echo(bd.format_budget(b))


@analyze_app.command()
@guarded
def coverage(
    fov: str = typer.Option(..., "--fov", metavar="W,H",
                            help="Field width,height in degrees, e.g. 11.17,8.32 (one number: a square "
                                 "field)."),
    mag: float = typer.Option(None, "--mag", help="Faintest catalogue magnitude (Hipparcos Hp)."),
    n: int = typer.Option(100_000, "--n", min=1, help="Random pointings (uniform attitudes: pointing and "
                          "roll)."),
    seed: int = typer.Option(0, "--seed", min=0, help="Random seed."),
    brightest: int = typer.Option(None, "--brightest", min=1, help="Use the N brightest stars instead "
                                  "(e.g. 5026: thesis 004's V ≤ 6 catalogue; overrides --mag)."),
    plot: Path = typer.Option(None, "--plot", help="Write the histogram of stars per field (PNG)."),
    json_out: bool = typer.Option(False, "--json", help="Print the summary as one JSON line."),
    verbose: int = VERBOSE,
) -> None:
    """Catalogue stars per rectangular field over random pointings and rolls (thesis 004 §5.1):
    P(< 3, 4, 5 stars), mean, maximum, and the histogram."""
    from skyfix.analysis import coverage as cv

    add_verbosity(verbose)
    parts = [p.strip() for p in fov.split(",") if p.strip()]
    try:
        w, h = (float(parts[0]), float(parts[-1])) if len(parts) in (1, 2) else (None, None)
    except ValueError:
        w = h = None
    if w is None:
        fail(f"--fov {fov!r} is not W,H in degrees (e.g. 11.17,8.32)")
    check_fov(w, "--fov width")
    check_fov(h, "--fov height")
    if brightest is None and (mag is None or not math.isfinite(mag)):
        fail("give --mag M (a finite Hp magnitude) or --brightest N")
    n = check_count(n, "--n", minimum=1)
    prepare_outputs({"--plot": [plot]})
    catalog = cv.coverage_catalog(30.0 if brightest else mag)
    if brightest:
        mag = cv.limit_for_count(catalog, brightest)
    with _progress(n, json_out or n < 200_000) as bar:
        task = bar.add_task("stars per field", total=n)
        counts = cv.star_counts(w, h, mag, n, seed, catalog=catalog,
                                progress=lambda k: bar.update(task, advance=k))
    summary = counts.summary()
    if json_out:
        typer.echo(json.dumps(summary))
    else:
        typer.echo(cv.format_counts(counts))
    if plot is not None:
        cv.plot_counts(counts, plot)
        if not json_out:
            typer.echo(f"wrote {plot}")


@analyze_app.command()
@guarded
def identification(
    out: Path = typer.Option(Path("identification-study"), "--out", help="Output directory (JSON, Markdown, "
                             "PNG)."),
    quick: bool = typer.Option(False, "--quick", help="15° only, noise-free and all-errors cells, 20 fields, "
                               "20 safety frames against the standard database alone, no seed experiments "
                               "(a smoke run for CI)."),
    methods: str = typer.Option("", "--methods", help="Comma-separated identification methods (default: "
                                "every registered one)."),
    trials: int = typer.Option(None, "--trials", min=1, help="Fields per FOV and condition (default 100; "
                               "--quick: 20)."),
    safety_trials: int = typer.Option(None, "--safety-trials", min=0, help="Frames of the safety case, each "
                                      "solved by every method (default: 1000 in the whole study, 10000 "
                                      "with --case safety; --quick: 20; 0: none)."),
    safety_first: int = typer.Option(0, "--safety-first", min=0, help="Number of the first safety frame (a "
                                     "campaign split in parts: frames N … N + --safety-trials − 1)."),
    seed: int = typer.Option(0, "--seed", min=0, help="Random seed (attitudes, noise)."),
    workers: int = typer.Option(0, "--workers", min=0, help="Local Dask worker processes for the grid, the "
                                "safety frames and the seed experiments (0: in this process)."),
    scheduler: str = typer.Option(None, "--scheduler", metavar="ADDRESS", help="A running Dask scheduler "
                                  "(tcp://HOST:8786) to run them on instead."),
    case: str = typer.Option("", "--case", help="Run only these (comma-separated): safety, quest-catalogue, "
                             "three-star-frames, sparse-fields, perturbation, table-3-7."),
    verbose: int = VERBOSE,
) -> None:
    """Every identification method on the same simulated centroids (FOV 8°, 15°, 30°; centroid
    noise, false stars, dropped stars, magnitude noise): solved %, wrong % with its 95 % upper
    bound, median and p99 time, table size and build time; the safety case (≥ 10⁴ random noisy
    frames per method through the solve, every wrong attitude kept to replay); and the seeds'
    experiments — each a study on the campaign engine, its rows written as Parquet. Without
    --case and --quick: all of them."""
    from skyfix.analysis import identification_safety as sf
    from skyfix.analysis import identification_study as st
    from skyfix.analysis.identification_cases import CASES, run_cases
    from skyfix.analysis.identification_jobs import method_names

    add_verbosity(verbose)
    names = tuple(m.strip().lower() for m in methods.split(",") if m.strip())
    with checking("--methods", methods):
        method_list = method_names(names)
    cases = [c.strip().lower() for c in case.split(",") if c.strip()]
    bad = [c for c in cases if c not in CASES and c != "safety"]
    if bad:
        fail(f"--case: {unknown_name('case', ', '.join(bad), ('safety', *CASES))}")
    base = st.QUICK if quick else st.FULL
    workers = check_count(workers, "--workers", minimum=0)
    check_cluster(workers or None, scheduler)
    settings = base._replace(methods=tuple(method_list), seed=int(seed), workers=workers,
                             trials=check_count(trials, "--trials") if trials is not None else base.trials)
    safety_base = sf.SAFETY_QUICK if quick else sf.SAFETY_FULL if cases else sf.SAFETY_STUDY
    n_safety = (check_count(safety_trials, "--safety-trials", minimum=0) if safety_trials is not None
                else safety_base.trials)
    safety = safety_base._replace(trials=n_safety, methods=tuple(method_list), seed=int(seed),
                                  workers=workers,
                                  first=check_count(safety_first, "--safety-first", minimum=0))
    command = ("skyfix analyze identification" + (" --quick" if quick else "")
               + (f" --methods {','.join(names)}" if names else "")
               + (f" --trials {trials}" if trials else "")
               + (f" --safety-trials {safety_trials}" if safety_trials is not None else "")
               + (f" --safety-first {safety_first}" if safety_first else "")
               + (f" --seed {seed}" if seed else "") + (f" --workers {workers}" if workers else "")
               + (f" --scheduler {scheduler}" if scheduler else "")
               + (f" --case {','.join(cases)}" if cases else ""))
    prepare_outputs({"--out": [out / "identification_study.json"]})
    seed_cases = [c for c in cases if c != "safety"]
    if "safety" in cases and n_safety:
        with _progress(0, False) as bar, compile_notice(bar):
            stage = _stages(bar)
            result = sf.run_safety(safety, lambda done, total: stage("safety frames", done, total),
                                   out=out / "identification_safety.parquet", scheduler=scheduler)
        paths = sf.write_safety(result, out, command=command)
        typer.echo(paths[1].read_text())
        for p in [*paths, out / "identification_safety.parquet"]:
            typer.echo(f"wrote {p}")
    if seed_cases:
        with _progress(0, False) as bar, compile_notice(bar):
            stage = _stages(bar)
            results = run_cases(seed_cases, workers, scheduler, out=out / "identification_cases.parquet",
                                progress=lambda done, total: stage("seed experiments", done, total))
        path = out / "identification_cases.json"
        path.write_text(json.dumps(results, indent=1))
        typer.echo(json.dumps(results, indent=1))
        typer.echo(f"wrote {path}")
        typer.echo(f"wrote {out / 'identification_cases.parquet'}")
    if cases:
        return
    all_cases = () if quick else tuple(CASES)
    study_safety = safety if n_safety else None
    with _progress(0, False) as bar, compile_notice(bar):
        study = st.run_study(settings, progress=_stages(bar), safety=study_safety, cases=all_cases, out=out,
                             scheduler=scheduler)
    paths = st.write_study(study, out, command=command)
    typer.echo(paths[1].read_text())
    parquet = [out / f"identification_{n}.parquet" for n, run in
               (("study", True), ("safety", study_safety is not None), ("cases", bool(all_cases))) if run]
    for p in [*paths, *parquet]:
        typer.echo(f"wrote {p}")


def _stages(bar) -> Callable[[str, int, int], None]:
    """``progress(stage, done, total)`` for a study on the campaign engine: a task of ``bar`` per
    stage, advanced to ``done`` of its ``total`` batches."""
    tasks: dict[str, list[int]] = {}

    def update(stage: str, done: int, total: int) -> None:
        if stage not in tasks:
            tasks[stage] = [bar.add_task(stage, total=total), 0]
        task, last = tasks[stage]
        if done > last:
            bar.update(task, advance=done - last)
            tasks[stage][1] = done

    return update


@analyze_app.command()
@guarded
def mounting(
    images: list[Path] = typer.Argument(..., help="A night of images from a camera fixed on the ground, "
                                                  "each with its time (FITS DATE-OBS or EXIF)."),
    site: str = typer.Option(..., "--site", metavar="LAT,LON,HEIGHT_M",
                             help="Where the camera is: latitude, east longitude (degrees), height (m)."),
    weather: str = typer.Option(None, "--weather", metavar="T_C,P_HPA,RH",
                                help="The air at the site: °C, hPa, relative humidity 0-1."),
    camera_file: Path = typer.Option(None, "--camera", help="Camera TOML file."),
    fov: float = typer.Option(None, "--fov", help="Horizontal field of view, degrees (optional)."),
    json_out: bool = typer.Option(False, "--json", help="One JSON line per image, then the mounting."),
    verbose: int = VERBOSE,
) -> None:
    """The camera's orientation in the local frame (east, north, up) from a night of images
    (thesis 003 §2.9–2.10): each solved at the site at its own time, their Markley average and
    its standard error. An image that cannot be read, has no time or does not solve is reported
    and left out; fewer than two left: exit 1."""
    import numpy as np

    from skyfix.analysis.mounting import estimate_mounting, image_to_enu
    from skyfix.corrections.refraction import check_site_weather

    add_verbosity(verbose)
    try:
        the_site, the_weather = check_site_weather(site, weather, names=("--site", "--weather"))
        with checking("--camera", camera_file):
            camera = load_camera(str(camera_file)) if camera_file is not None else None
        if fov is not None:
            check_fov(fov, "--fov")
    except (InputError, SkyfixError) as exc:
        fail(error_line(exc))
    load_database(None)
    rows, names, errors = [], [], []

    def solved(path):
        return image_to_enu(path, the_site, the_weather, camera=camera, fov_deg=fov)

    for path, (sol, A) in _each_image(images, json_out, "solving", solved, errors):
        if A is None:
            typer.echo(f"{path}: failed: {sol.reason}", err=True)
            continue
        rows.append(A)
        names.append((str(path), sol))
    any_error = bool(errors)
    if len(rows) < 2:
        fail(f"{len(rows)} image(s) solved with a time: the mounting needs two or more",
             code=2 if any_error else 1)
    est = estimate_mounting(np.array(rows))
    for (name, sol), dev in zip(names, est.deviations_arcsec, strict=True):
        if json_out:
            row = {"image": name, "time": sol.time, "alt_deg": sol.alt_deg, "az_deg": sol.az_deg,
                   "deviation_arcsec": [round(float(d), 4) for d in dev]}
            typer.echo(json.dumps(row))
        else:
            typer.echo(f"{name}: {sol.time} Alt {sol.alt_deg:.4f}° Az {sol.az_deg:.4f}° | off the average "
                       f"{dev[0]:+.1f}″ {dev[1]:+.1f}″ {dev[2]:+.1f}″ (about E, N, up)")
    if json_out:
        typer.echo(json.dumps(est.to_json()))
    else:
        q, e = est.quaternion_xyzw, est.euler123_deg
        typer.echo(f"mounting (camera → ENU) from {est.n_images} images: quaternion "
                   f"{q[0]:.8f} {q[1]:.8f} {q[2]:.8f} {q[3]:.8f}; Euler 1-2-3 {e[0]:.5f}° {e[1]:.5f}° "
                   f"{e[2]:.5f}°; standard error {est.standard_error_arcsec:.2f}″ "
                   f"(per angle {' '.join(f'{x:.2f}' for x in est.euler_standard_error_arcsec)}″)")
    if any_error:
        raise typer.Exit(2)


@analyze_app.command()
@guarded
def seeds(
    only: str = typer.Option(None, "--only", metavar="KEY,...",
                             help="Run only these reproductions (keys as the table prints them)."),
    quick: bool = typer.Option(False, "--quick", help="Small runs (each under a minute), not the "
                               "theses' sizes."),
    json_out: Path = typer.Option(None, "--json", metavar="FILE", help="Also write the rows as JSON."),
    verbose: int = VERBOSE,
) -> None:
    """The seed theses' numbers beside skyfix's (docs/seeds.md): each reproduction run at the
    thesis's size (``--quick``: small), or the one command that reproduces it named."""
    from skyfix.analysis import seeds as sd

    add_verbosity(verbose)
    keys = None
    if only is not None:
        keys = [k.strip() for k in only.split(",") if k.strip()]
        known = sd.reproduction_keys()
        bad = [k for k in keys if k not in known]
        if bad or not keys:
            fail(f"--only: {unknown_name('reproduction', ', '.join(bad) or '(none)', known)}")
    if json_out is not None:
        prepare_outputs({"--json": [json_out]})
    n = len(keys) if keys is not None else len(sd.REPRODUCTIONS)
    with _progress(n, False) as bar, compile_notice(bar):
        task = bar.add_task("seed reproductions", total=n)
        results = sd.run_reproductions(keys, quick=quick,
                                       progress=lambda rep: bar.update(task, advance=1, description=rep.key))
    rows = sd.as_rows(results)
    for row in rows:
        typer.echo(f"{row['key']}: {row['what']}")
        typer.echo(f"  thesis: {row['thesis_value']}")
        typer.echo(f"  skyfix: {row['skyfix'] if row['skyfix'] is not None else '—'}  [{row['verdict']}]")
        if row["note"]:
            typer.echo(f"  why: {row['note']}")
        typer.echo(f"  command: {row['command']}")
    if json_out is not None:
        json_out.write_text(json.dumps({"quick": quick, "rows": rows}, indent=1))
        typer.echo(f"wrote {json_out}")
