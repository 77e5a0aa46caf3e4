"""``skyfix track FRAMES…``: follow a sequence of frames with :class:`skyfix.track.Tracker`
(docs/tracking.md#the-command).

``--camera`` takes a file or a preset name, as ``skyfix solve --camera``. One line per frame: a
summary, or with ``--json`` the Solution (``mode``, ``frame_time_s``, ``rate_dps``, …; ``time_ms``
holds ``read`` apart from the processing, and ``total``). A frame that cannot be read, or whose
time is out of order, gets a one-line error and the sequence goes on. Without ``--camera`` the
tracker calibrates its own camera from the frames (:mod:`skyfix.track.self_calibration`) and says
on stderr, at the end, which camera it used. Exit codes as for
``skyfix solve``: 0 every frame has an attitude, 1 some frame has none, 2 bad input.

The tracker, numpy, astropy's FITS header reader and matplotlib are imported inside the
functions that use them: every ``skyfix`` start loads this module, ``-h`` included.
"""

from __future__ import annotations

import math
import sys
import time
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from skyfix.cli.common import (
    EPOCH_HELP,
    VERBOSE,
    add_verbosity,
    checking,
    compile_notice,
    counter_bar,
    fail,
    guarded,
    input_error_line,
    load_camera,
    load_database,
    prepare_outputs,
)
from skyfix.cli.observation import observation_option, observation_options, summary_suffix
from skyfix.errors import InputError, SkyfixError, unknown_name

if TYPE_CHECKING:
    import numpy as np

__all__ = ["frame_times", "gyro_rates", "plot_track", "read_gyro", "track"]

_FITS = (".fits", ".fit", ".fts")


@guarded
def track(
    frames: list[Path] = typer.Argument(..., help="Frames in time order (FITS, PNG, TIFF, JPEG)."),
    camera_file: str = typer.Option(None, "--camera", help="Camera TOML file or preset name (default: "
                                                           "calibrated from the frames themselves)."),
    fps: float = typer.Option(None, "--fps", help="Frame rate, Hz: frame k at k/FPS s (default: each "
                                                  "FITS frame's DATE-OBS)."),
    gyro: Path = typer.Option(None, "--gyro", help="CSV of gyro rates: t_s, x, y, z (rad/s about camera "
                                                   "x, y, z; t_s on the frames' clock, 0 at the first)."),
    epoch: float = typer.Option(None, "--epoch", help=EPOCH_HELP),
    database_file: Path = typer.Option(None, "--database",
                                       help="Pattern database file (default: cached)."),
    predictor: str = typer.Option("mekf", "--predictor", help="mekf, small-angle, three-point, "
                                                              "three-point-thesis."),
    windows: int = typer.Option(16, "--windows", help="Stars tracked per frame."),
    streak_windows: int = typer.Option(None, "--streak-windows",
                                       help="Stars tracked per frame while they streak (at most "
                                            "--windows; default --windows)."),
    exposure: float = typer.Option(None, "--exposure", help="Exposure, s (default: the frame period)."),
    line_time: float = typer.Option(0.0, "--line-time",
                                    help="Rolling shutter: seconds per row (0: global)."),
    json_out: bool = typer.Option(False, "--json", help="One JSON Solution per frame per line."),
    plot: Path = typer.Option(None, "--plot",
                              help="Write a PNG: attitude error bars, rate and star count vs time."),
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
    """Track a sequence of frames: lost in space first, then windows around the predicted stars."""
    add_verbosity(verbose)
    from skyfix.track import PREDICTORS, Tracker

    camera = None  # calibrated from the frames (skyfix.track.self_calibration)
    if camera_file is not None:
        with checking("--camera", camera_file):
            camera = load_camera(camera_file)
    if predictor.lower() not in PREDICTORS:
        fail(f"--predictor: {unknown_name('predictor', predictor, PREDICTORS)}")
    times = frame_times(frames, fps)
    observation = observation_options(obs_time, velocity_kms, site, weather, refraction, mounting,
                                      apparent, camera_file, epoch, position_km)  # after --camera: its tables
    if observation["time"] is None:  # the first frame's own time is the time of t = 0
        observation["time"] = _first_frame_time(frames[0])
    samples = read_gyro(gyro) if gyro is not None else None
    rates = gyro_rates(samples, times) if samples is not None else [None] * len(frames)
    if plot is not None and plot.suffix.lower() != ".png":
        fail(f"--plot {plot}: give a .png file")
    prepare_outputs({"--plot": [plot]}, inputs=frames)
    database = load_database(database_file, ("track",))
    tracker = Tracker(camera, database=database, predictor=predictor, epoch=epoch,
                      n_windows=windows, streak_windows=streak_windows, exposure_s=exposure,
                      line_time_s=line_time, **observation)
    from skyfix.io import read_image

    any_failed = any_error = False
    sols = []
    progress = _progress(len(frames), json_out)
    with compile_notice(progress):
        for path, t, rate in zip(frames, times, rates, strict=True):
            try:
                t0 = time.perf_counter()
                image = read_image(path)
                t_read = 1e3 * (time.perf_counter() - t0)
                sol = tracker.update(image, t, gyro_rate_rad_s=rate)
                sol.image = str(path)
                work = {k: v for k, v in sol.time_ms.items() if k != "total"}
                sol.time_ms = {"read": t_read, **work, "total": t_read + sol.time_ms.get("total", 0.0)}
                any_failed |= not sol.solved
                sols.append(sol)
                typer.echo(sol.to_json() if json_out else _summary(sol))
            except SkyfixError as exc:  # this frame's error line, then the next frame
                any_error = True
                typer.echo(f"skyfix: error: {input_error_line(exc, path)}", err=True)
            if progress is not None:
                progress.advance(0)
    if progress is not None:
        progress.stop()
    if tracker.calibration is not None:  # which camera it used
        typer.echo(f"skyfix: {tracker.calibration.describe()}", err=True)
    if plot is not None and sols:
        plot_track(sols, plot)
    raise typer.Exit(2 if any_error else 1 if any_failed else 0)


def frame_times(frames: list[Path], fps: float | None) -> list[float]:
    """Each frame's time, seconds from the first: ``k / fps``, or from FITS ``DATE-OBS``."""
    if fps is not None:
        if not (math.isfinite(fps) and fps > 0):
            raise InputError(f"--fps {fps} must be a positive number")
        return [k / fps for k in range(len(frames))]
    stamps = []
    for path in frames:
        stamp = _date_obs(path)
        if stamp is None:
            raise InputError(f"{path}: no DATE-OBS to time the frame by; give --fps")
        stamps.append(stamp)
    return [(s - stamps[0]).total_seconds() for s in stamps]


def _date_obs(path: Path) -> datetime | None:
    if path.suffix.lower() not in _FITS:
        return None
    try:
        from astropy.io import fits

        value = fits.getheader(path).get("DATE-OBS")
        if value is None:
            return None
        return datetime.fromisoformat(str(value).strip().replace("Z", "+00:00"))
    except (OSError, ValueError, TypeError):
        return None  # the frame itself is read (and its errors reported) in order


def _first_frame_time(path: Path):
    """The first frame's observation time (FITS DATE-OBS with EXPTIME, EXIF), None when it has
    none or cannot be read (the frame's own error comes in order)."""
    from skyfix.obstime import time_from_image

    own = time_from_image(path)
    return own if own.known else None


def read_gyro(path: Path) -> np.ndarray:
    """Gyro samples (N, 4): ``t_s, x, y, z`` (rad/s), from a CSV file (a header line allowed),
    sorted by time."""
    import numpy as np

    try:
        lines = Path(path).read_text().splitlines()
    except OSError as exc:
        raise InputError(f"--gyro {path}: {exc.strerror or exc}") from None
    rows = []
    for number, line in enumerate(lines, 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            values = [float(v) for v in line.split(",")]
        except ValueError:
            if not rows and number == 1:
                continue  # a header
            raise InputError(f"--gyro {path}:{number}: not four numbers: {line[:60]!r}") from None
        if len(values) != 4 or not all(map(math.isfinite, values)):
            raise InputError(f"--gyro {path}:{number}: need t_s, x, y, z (four finite numbers)")
        rows.append(values)
    if not rows:
        raise InputError(f"--gyro {path}: no samples")
    samples = np.array(rows)
    return samples[np.argsort(samples[:, 0], kind="stable")]


def gyro_rates(samples: np.ndarray, times: list[float]) -> list[np.ndarray | None]:
    """The gyro rate for each frame: the mean of the samples since the previous frame
    (``(t_{k−1}, t_k]``; the first frame: the last sample at or before it). A gap with no sample
    gives None, and the tracker holds the last rate it was given."""
    out: list[np.ndarray | None] = []
    t_prev = -math.inf
    for t in times:
        inside = (samples[:, 0] > t_prev) & (samples[:, 0] <= t)
        if t_prev == -math.inf:
            inside = samples[:, 0] <= t
            inside &= samples[:, 0] >= (samples[inside, 0].max() if inside.any() else math.inf)
        out.append(samples[inside, 1:].mean(axis=0) if inside.any() else None)
        t_prev = t
    return out


def _progress(n: int, quiet: bool):
    """Progress on stderr for sequences of 20 frames or more: a bar on a terminal (not under
    --json), a line per frame off one."""
    if n < 20 or quiet and sys.stderr.isatty():
        return None
    return counter_bar("tracking", n)


def _summary(sol) -> str:
    head = f"{sol.image}: t {sol.frame_time_s:.3f} s {sol.mode}"
    if not sol.solved:
        return f"{head}: failed: {sol.reason}"
    sig = [math.sqrt(sol.covariance_arcsec2[i][i]) for i in range(3)]
    rate = "" if sol.rate_dps is None else " | rate {:+.4f} {:+.4f} {:+.4f} °/s".format(*sol.rate_dps)
    coast = f" | {sol.reason}" if sol.reason else ""
    return (f"{head}: RA {sol.ra_deg:.5f}° Dec {sol.dec_deg:+.5f}° roll {sol.roll_deg:.3f}° | "
            f"{sol.n_matched} stars, σ(x,y,roll) {sig[0]:.1f}″ {sig[1]:.1f}″ {sig[2]:.0f}″{rate} | "
            f"{sol.time_ms.get('total', 0):.2f} ms{coast}{summary_suffix(sol)}")


def plot_track(sols: list, path: Path) -> None:
    """A PNG of the sequence against the frame time: the attitude's 1-σ error bars (x, y, roll),
    the rate with its σ, and the stars in each fit coloured by mode."""
    import matplotlib
    import numpy as np

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.array([s.frame_time_s for s in sols])
    sigma = np.full((len(sols), 3), np.nan)
    rate = np.full((len(sols), 3), np.nan)
    rate_sigma = np.full((len(sols), 3), np.nan)
    for k, s in enumerate(sols):
        if s.solved:
            sigma[k] = np.sqrt(np.diag(np.asarray(s.covariance_arcsec2)))
        if s.rate_dps is not None:
            rate[k] = s.rate_dps
            rate_sigma[k] = np.sqrt(np.diag(np.asarray(s.rate_covariance_dps2)))
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for i, label in enumerate(("x", "y", "roll")):
        axes[0].semilogy(t, sigma[:, i], ".-", ms=3, label=f"σ {label}")
    axes[0].set_ylabel("attitude 1-σ error bar (″)")
    axes[0].legend(loc="upper right", fontsize=8)
    for i, label in enumerate("xyz"):
        axes[1].errorbar(t, rate[:, i], yerr=rate_sigma[:, i], fmt=".-", ms=3, label=f"ω{label}")
    axes[1].set_ylabel("rate (°/s)")
    axes[1].legend(loc="upper right", fontsize=8)
    colours = {"calibrating": "C0", "lost": "C3", "acquiring": "C1", "tracking": "C2"}
    n = np.array([s.n_matched for s in sols])
    for mode, colour in colours.items():
        pick = np.array([s.mode == mode for s in sols])
        axes[2].plot(t[pick], n[pick], "o", ms=3, color=colour, label=mode)
    axes[2].set_ylabel("stars in the fit")
    axes[2].set_xlabel("frame time (s)")
    axes[2].legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
