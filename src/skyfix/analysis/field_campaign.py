"""The field-size campaign: random attitudes at fields from 2° to 90°, solved with no hint.

Each case is a camera (field of view, lens model) and a star field as its detector would see it:
the catalogue stars in view to a limiting magnitude, centroid noise, missed stars, false stars
(hot pixels, satellites, stars fainter than the catalogue) mixed into the brightness order, and
magnitude noise that reorders them (:func:`skyfix.analysis.synthetic_centroids.synthetic_centroids`).
Every frame is solved as a new user would, with no camera file and no FOV hint
(:func:`skyfix.solve_centroids`), and judged as the blind campaign judges
(:mod:`skyfix.analysis.blind_campaign`): **wrong** when the boresight is off by more than
max(60″, 1 px) or the roll by more than 0.5°, and the normalised error (error / reported σ per
axis) should have an RMS near 1.

The stars are Gaia DR3 to G 10 with Hipparcos for the brightest (:func:`skyfix.catalog.load_gaia`),
deeper than any case's limit, so the fields are the sky, not the solver's catalogue.
It runs on the campaign engine (:func:`skyfix.montecarlo.engine.run_campaign`) as
:class:`FieldStudy`: one Parquet row per frame, in this process or on Dask workers, the same
frames as the serial loop it replaced. ``python -m skyfix.analysis.field_campaign`` runs
:data:`CASES` and writes the rows, the table and the plots (docs/fields.md);
``benchmarks/suite_fields.py`` times them.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

import numpy as np

from skyfix.analysis.blind_campaign import (
    TRIAL_COLUMNS,
    Trial,
    sequence_batch,
    summarize,
    trial_of_row,
    trial_row,
)
from skyfix.camera import Camera
from skyfix.catalog import load_gaia
from skyfix.montecarlo.engine import run_rows
from skyfix.montecarlo.study import BatchedStudy

__all__ = ["CASES", "FieldCase", "FieldStudy", "FieldTrial", "campaign_trials", "case_camera", "field_study",
           "field_trials", "main", "summarize_case", "write_campaign"]


class FieldCase(NamedTuple):
    """A camera and the star fields it sees (see the module text)."""

    name: str
    fov_deg: float
    mag_limit: float  # the faintest stars detected (G)
    k1: float = 0.0  # Brown–Conrady radial distortion
    projection: str = "pinhole"  # or "kannala-brandt" (equidistant with k = 0)
    width: int = 1280
    height: int = 960
    sigma_px: float = 0.5  # centroid noise per axis
    max_false: int = 5  # false stars: 0..max_false per frame
    dropout: float = 0.05  # share of the stars in view that are missed
    mag_sigma: float = 0.3  # magnitude noise that reorders the stars
    min_stars: int = 6  # frames with fewer catalogue stars in view do not count against the solve rate


CASES: tuple[FieldCase, ...] = (
    FieldCase("1°", 1.0, 10.0, min_stars=8),
    FieldCase("1.5°", 1.5, 10.0, min_stars=8),
    FieldCase("2°", 2.0, 10.0),
    FieldCase("4°", 4.0, 10.0),
    FieldCase("6°", 6.0, 9.5),
    FieldCase("15°", 15.0, 7.0),
    FieldCase("45°, k1 −0.3", 45.0, 6.0, k1=-0.3),
    FieldCase("60°, k1 −0.3", 60.0, 5.5, k1=-0.3),
    FieldCase("90° fisheye", 90.0, 5.0, projection="kannala-brandt"),
)
"""The cases of issue 10's must-show (2°, 4°, 6°, 45° and 60° with k1 ≈ −0.3, a 90° fisheye), with
15° (the common case) beside them, and issue 26's 1° and 1.5° fields (stars to G 10; counted
where 8 or more are in view, as the issue counts them)."""


class FieldTrial(NamedTuple):
    """One frame: its :class:`~skyfix.analysis.blind_campaign.Trial`, the solve's wall time and
    the solving thread's CPU time (ms)."""

    trial: Trial
    time_ms: float
    cpu_ms: float = math.nan


def case_camera(case: FieldCase) -> Camera:
    """The case's true camera (centred, square pixels) whose frame is ``fov_deg`` wide edge to
    edge through its centre, distortion included (a barrel lens of k1 −0.3 needs a longer focal
    length than a pinhole of the same field)."""
    if case.projection != "pinhole":
        return Camera.from_fov(case.width, case.height, case.fov_deg, projection=case.projection)
    r = math.tan(math.radians(case.fov_deg) / 2.0)
    f = (case.width / 2.0) / (r * (1.0 + case.k1 * r * r))
    return Camera(case.width, case.height, f, f, (case.width - 1) / 2.0, (case.height - 1) / 2.0, k1=case.k1)


#: Per process: each (case, n, seed)'s attitudes and the generator's state after drawing them.
_ATTITUDES: dict[tuple, tuple[np.ndarray, dict]] = {}
#: Per process: the sequences (cases) whose first frame has been solved once, untimed.
_WARMED: set[tuple] = set()


def _attitudes(key: tuple, n: int, seed: int) -> tuple[np.ndarray, dict]:
    from skyfix.analysis.synthetic_centroids import random_attitudes

    found = _ATTITUDES.get(key)
    if found is None:
        rng = np.random.default_rng(seed)
        found = (random_attitudes(n, rng), rng.bit_generator.state)
        if len(_ATTITUDES) >= 16:
            _ATTITUDES.clear()
        _ATTITUDES[key] = found
    return found


@dataclass(frozen=True)
class FieldStudy(BatchedStudy):
    """The field campaign on the engine (settings ``cases``: :class:`FieldCase` tables, ``n``
    frames each, ``seed``, ``epoch``): trial ``i`` is frame ``i mod n`` of case ``i // n``, the
    frames of a case one random sequence from ``seed`` as :func:`field_trials` always drew them
    (:func:`skyfix.analysis.blind_campaign.sequence_batch`). A process solves its first frame of
    each case once untimed first (the case's FOV band loaded, the kernels loaded), so
    ``time_ms`` and ``cpu_ms`` time the solve alone."""

    kind: ClassVar[str] = "field-campaign"
    columns: ClassVar[Mapping[str, str]] = {"trial": "int64", "case": "string", "frame": "int32",
                                            "n_false": "int32", **TRIAL_COLUMNS, "cpu_ms": "float64"}

    @property
    def cases(self) -> list[FieldCase]:
        return [FieldCase(**c) for c in self.settings["cases"]]

    def run_batch(self, batch: int) -> list[dict[str, Any]]:
        n, rows = int(self.settings["n"]), []
        trials = self.batch_trials(batch)
        for c in range(trials.start // n, (trials.stop - 1) // n + 1):  # a batch may span cases
            first, stop = max(trials.start, c * n), min(trials.stop, (c + 1) * n)
            rows += self._case_rows(c, range(first - c * n, stop - c * n))
        return rows

    def _case_rows(self, c: int, frames: range) -> list[dict[str, Any]]:
        from skyfix.analysis.synthetic_centroids import synthetic_centroids
        from skyfix.pipeline import solve_centroids

        case, n = self.cases[c], int(self.settings["n"])
        seed, epoch = int(self.settings["seed"]), float(self.settings["epoch"])
        catalog, camera = load_gaia(epoch=epoch), case_camera(case)
        key = (self.kind, tuple(case), n, seed, epoch)
        attitudes, after = _attitudes(key, n, seed)

        def start() -> np.random.Generator:
            rng = np.random.Generator(np.random.PCG64())
            rng.bit_generator.state = after
            return rng

        def draw(rng: np.random.Generator, k: int):
            n_false = int(rng.integers(0, case.max_false + 1))
            return n_false, synthetic_centroids(camera, attitudes[k], catalog, mag_limit=case.mag_limit,
                                                sigma_px=case.sigma_px, n_false=n_false, dropout=case.dropout,
                                                mag_sigma=case.mag_sigma, rng=rng)

        def solve(k: int, drawn) -> dict[str, Any]:
            n_false, field = drawn
            xy = field.xy[:200]
            if key not in _WARMED:
                solve_centroids(xy, case.width, case.height, epoch=epoch)
                _WARMED.add(key)
            cpu, t0 = time.thread_time(), time.perf_counter()
            sol = solve_centroids(xy, case.width, case.height, epoch=epoch)
            ms, cpu_ms = 1e3 * (time.perf_counter() - t0), 1e3 * (time.thread_time() - cpu)
            row = trial_row(c * n + k, {"case": case.name, "frame": k, "n_false": n_false}, sol, attitudes[k],
                            camera, int((field.star_id != 0).sum()), ms)
            return {**row, "cpu_ms": cpu_ms}

        return sequence_batch(key, frames, start, draw, solve)

    def run_trial(self, trial: int) -> dict[str, Any]:
        return replace(self, batch_size=1).run_batch(trial)[0]

    def warm(self) -> None:
        from skyfix import warmup

        warmup.ensure(["solve"], missing_ok=True)


def field_study(cases: Sequence[FieldCase], n: int, seed: int = 0, *, epoch: float = 2025.0,
                batch_size: int | None = None) -> FieldStudy:
    """The :class:`FieldStudy` of ``n`` frames of each of ``cases`` (a batch a case by default:
    a case's frames are one random sequence)."""
    settings = {"cases": [c._asdict() for c in cases], "n": int(n), "seed": int(seed), "epoch": float(epoch)}
    return FieldStudy(n * len(cases), batch_size or n, settings)


def campaign_trials(cases: Sequence[FieldCase], n: int, seed: int = 0, *, epoch: float = 2025.0,
                    workers: int = 0, scheduler: str | None = None, output: str | Path | None = None,
                    progress: Callable[[int, int], None] | None = None
                    ) -> list[tuple[FieldCase, list[FieldTrial]]]:
    """``n`` frames of each of ``cases`` (:func:`field_study` on the engine: ``workers``
    processes, 0 this one, or the Dask ``scheduler``; the rows into ``output``, Parquet, or a
    temporary file; ``progress(done, total)`` counts finished batches), by case."""
    rows = run_rows(field_study(cases, n, seed, epoch=epoch), output, workers=workers, scheduler=scheduler,
                    progress=progress).to_pylist()
    trials = [FieldTrial(trial_of_row(r), r["time_ms"], r["cpu_ms"]) for r in rows]
    return [(case, trials[k * n:(k + 1) * n]) for k, case in enumerate(cases)]


def field_trials(case: FieldCase, n: int, seed: int = 0, *, epoch: float = 2025.0,
                 progress: Callable[[int], None] | None = None, workers: int = 0,
                 scheduler: str | None = None, output: str | Path | None = None) -> list[FieldTrial]:
    """``n`` frames of ``case`` at uniformly random attitudes (reproducible from ``seed``), each
    solved with no hint (:func:`campaign_trials` of the one case; ``progress(n)`` when done)."""
    [(_, trials)] = campaign_trials([case], n, seed, epoch=epoch, workers=workers, scheduler=scheduler,
                                   output=output)
    if progress is not None:
        progress(len(trials))
    return trials


def summarize_case(case: FieldCase, trials: Sequence[FieldTrial]) -> dict:
    """The case's numbers: frames, those with ≥ ``case.min_stars`` stars and how many of them solved,
    wrong solutions (among all frames), the normalised error RMS, median boresight and roll error,
    solve time median and 99th percentile (ms)."""
    countable = [t for t in trials if t.trial.n_stars >= case.min_stars]
    s = summarize([t.trial for t in trials])
    times = np.array([t.time_ms for t in trials])
    return {"case": case.name, "fov_deg": case.fov_deg, "k1": case.k1, "projection": case.projection,
            "mag_limit": case.mag_limit, "min_stars": case.min_stars, "frames": len(trials),
            "frames_min_stars": len(countable),
            "solved_min_stars": sum(t.trial.solved for t in countable),
            **{k: v for k, v in s.items() if k != "n"},
            "median_stars": float(np.median([t.trial.n_stars for t in trials])) if trials else math.nan,
            "time_median_ms": float(np.median(times)) if len(times) else math.nan,
            "time_p99_ms": float(np.percentile(times, 99)) if len(times) else math.nan}


def write_campaign(results: list[tuple[FieldCase, list[FieldTrial]]], out: Path, *,
                   command: str) -> list[Path]:
    """Write ``fields.json`` (every case's summary), ``fields.md`` (the table) and ``fields.png``
    (boresight error and normalised error histograms per case) into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    rows = [summarize_case(case, trials) for case, trials in results]
    (out / "fields.json").write_text(json.dumps({"command": command, "cases": rows}, indent=1))
    lines = [f"`{command}`", "",
             "| field | stars (median) | solved (≥ min stars) | wrong | boresight median | roll median | "
             "normalised RMS x, y, roll | time median / p99 |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        rms = ", ".join(f"{v:.2f}" for v in r.get("normalised_rms", [math.nan] * 3))
        pct = 100.0 * r["solved_min_stars"] / max(r["frames_min_stars"], 1)
        lines.append(f"| {r['case']} | {r['median_stars']:.0f} | "
                     f"{r['solved_min_stars']}/{r['frames_min_stars']} (≥ {r['min_stars']}) "
                     f"({pct:.1f} %) | {r['wrong']} | {r.get('median_boresight_arcsec', math.nan):.2f}″ | "
                     f"{r.get('median_roll_arcsec', math.nan):.1f}″ | {rms} | "
                     f"{r['time_median_ms']:.1f} / {r['time_p99_ms']:.0f} ms |")
    (out / "fields.md").write_text("\n".join(lines) + "\n")
    paths = [out / "fields.json", out / "fields.md", _plot(results, out / "fields.png")]
    return paths


def _plot(results: list[tuple[FieldCase, list[FieldTrial]]], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.5))
    arcsec = 180.0 * 3600.0 / math.pi
    for case, trials in results:
        solved = [t.trial for t in trials if t.trial.solved]
        if not solved:
            continue
        err = np.array([t.error_rad for t in solved])
        bore_px = np.hypot(err[:, 0], err[:, 1]) * arcsec / np.array([t.plate_scale_arcsec for t in solved])
        ax1.hist(bore_px, bins=np.logspace(-3, 1, 41), histtype="step", label=case.name)
        z = (err / np.array([t.sigma_rad for t in solved]))[:, :2].ravel()
        ax2.hist(z, bins=np.linspace(-5, 5, 41), histtype="step", density=True, label=case.name)
    ax1.set_xscale("log")
    ax1.set_xlabel("boresight error, pixels")
    ax1.set_ylabel("frames")
    ax1.set_title("Boresight error (no hint, no camera file)")
    zz = np.linspace(-5, 5, 201)
    ax2.plot(zz, np.exp(-zz**2 / 2) / math.sqrt(2 * math.pi), "k--", lw=1, label="N(0, 1)")
    ax2.set_xlabel("error / reported σ (x and y)")
    ax2.set_title("Normalised error: honest error bars follow N(0, 1)")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m skyfix.analysis.field_campaign [--n 100] [--seed 2026] [--out DIR] [--workers N |
    --scheduler ADDRESS]``: every case of :data:`CASES` on the campaign engine, with a progress
    bar; writes the rows (``DIR/fields.parquet``) and :func:`write_campaign`'s files and prints the
    table. Exit status 2 with one line for bad input or a scheduler out of reach."""
    import argparse
    import sys

    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from skyfix.errors import CampaignError

    ap = argparse.ArgumentParser(prog="python -m skyfix.analysis.field_campaign",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=100, help="random attitudes per case (default 100)")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--out", type=Path, default=Path("field-campaign"))
    ap.add_argument("--workers", type=int, default=None,
                    help="local worker processes (default 0: the cases one after another in this process)")
    ap.add_argument("--scheduler", metavar="ADDRESS", default=None,
                    help="a running Dask scheduler (tcp://HOST:8786) instead of local workers")
    args = ap.parse_args(argv)
    if args.n < 1:
        ap.error("--n must be at least 1")
    if args.workers is not None and args.workers < 0:
        ap.error(f"--workers must be ≥ 0, got {args.workers}")
    if args.workers and args.scheduler:
        ap.error("give --workers or --scheduler, not both")
    args.out.mkdir(parents=True, exist_ok=True)
    try:
        with Progress(TextColumn("field campaign, cases"), BarColumn(), MofNCompleteColumn(),
                      TimeRemainingColumn(), transient=True) as bar:
            task = bar.add_task("field campaign", total=len(CASES))
            results = campaign_trials(
                CASES, args.n, args.seed, workers=args.workers or 0, scheduler=args.scheduler,
                output=args.out / "fields.parquet",
                progress=lambda done, total: bar.update(task, completed=done, total=total))
    except CampaignError as exc:
        print(f"{ap.prog}: error: {exc}", file=sys.stderr)
        return 2
    command = f"python -m skyfix.analysis.field_campaign --n {args.n} --seed {args.seed}"
    paths = write_campaign(results, args.out, command=command)
    print(paths[1].read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
