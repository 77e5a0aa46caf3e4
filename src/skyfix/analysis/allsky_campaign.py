"""The all-sky campaign: simulated fisheye frames of the whole sky (:mod:`skyfix.simulate.allsky`),
solved with no hint and no camera file, judged against their truth (:mod:`skyfix.analysis.truth`).

Each frame draws (from its own seed) a frame size of 2–4 MP (:data:`SIZES`), a lens
(:data:`LENSES`: equidistant 180° and 190°, Kannala–Brandt equisolid 180°, and a Kannala–Brandt
lens with random k1, k2, 185°), the image circle's offset from the frame's centre (±25 px), the
boresight's tilt from the zenith (0–4°, any azimuth) and roll, the site (latitude ±60°) and a
time in 2026, the sky's brightness (19.5–21.5 mag/arcsec²) and a landscape
(:func:`~skyfix.simulate.allsky.random_landscape`: hills, one to three groups of trees or
buildings, half of the frames with one lit, a light dome). The frames are the trials of
:class:`AllSkyStudy` on the campaign engine (:func:`skyfix.montecarlo.engine.run_campaign`):
one Parquet row each, the same in this process or on any number of Dask workers.
docs/all-sky.md gives the results.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

import numpy as np

from skyfix.montecarlo.engine import run_rows, trial_progress
from skyfix.montecarlo.study import BatchedStudy

__all__ = ["LENSES", "SIZES", "AllSkyResult", "AllSkyStudy", "allsky_campaign", "allsky_frame", "result_of",
           "summarise"]

#: Frame sizes (width, height): 1.9–4.2 MP (no 16:9 frame: docs/all-sky.md#limits-not-done-yet).
SIZES = ((1600, 1200), (2048, 1536), (2048, 2048))
#: Lenses by name: (field across the image circle, degrees; Kannala–Brandt k1, k2; None: drawn).
LENSES = {
    "equidistant 180°": (180.0, (0.0, 0.0)),
    "equidistant 190°": (190.0, (0.0, 0.0)),
    "KB equisolid 180°": (180.0, (-1.0 / 24.0, 1.0 / 1920.0)),
    "KB random 185°": (185.0, None),
}


class AllSkyResult(NamedTuple):
    """One frame of the campaign: its kind, and the solve's outcome against the truth."""

    seed: int
    size: tuple[int, int]
    lens: str
    solved: bool
    wrong: bool
    boresight_arcsec: float  # NaN when not solved
    roll_deg: float
    n_matched: int
    time_s: float
    reason: str
    # the camera axes' error against the truth's quaternion (x, y, roll: the optical axis's
    # direction and the roll about it) over the σ the solution reports (NaN when not solved)
    axis_error_sigmas: tuple[float, float, float] = (math.nan, math.nan, math.nan)


def allsky_frame(seed: int):
    """The campaign's frame ``seed``: (SimulatedFrame, the true camera, the lens's name)."""
    from skyfix.simulate.allsky import all_sky_camera, random_landscape, render_allsky

    rng = np.random.default_rng([26, 3, seed])
    width, height = SIZES[int(rng.integers(len(SIZES)))]
    lens = list(LENSES)[int(rng.integers(len(LENSES)))]
    fov, k = LENSES[lens]
    if k is None:
        k = (float(rng.uniform(-0.05, 0.05)), float(rng.uniform(-0.01, 0.01)))
    camera = all_sky_camera(width, height, fov, offset_px=tuple(rng.uniform(-25, 25, 2)), k=k)
    day = rng.uniform(0, 365)
    stamp = np.datetime64("2026-01-01T00:00:00") + np.timedelta64(int(day * 86400), "s")
    frame = render_allsky(camera, site=(float(rng.uniform(-60, 60)), float(rng.uniform(-180, 180))),
                          time=str(stamp), landscape=random_landscape(rng), fov_deg=fov,
                          tilt_deg=float(rng.uniform(0, 4)), tilt_az_deg=float(rng.uniform(0, 360)),
                          roll_deg=float(rng.uniform(0, 360)), seed=seed,
                          sky_mag_arcsec2=float(rng.uniform(19.5, 21.5)))
    return frame, camera, lens


@dataclass(frozen=True)
class AllSkyStudy(BatchedStudy):
    """The campaign on the engine (:func:`skyfix.montecarlo.engine.run_campaign`): trial ``i`` is
    frame ``settings["seeds"][i]`` (:func:`allsky_frame`) solved with ``settings["solve_options"]``;
    its row holds the frame's kind, the truth's and the solution's quaternions, the outcome (the
    fields of :class:`AllSkyResult`, the axes' normalised errors as ``normalised_x``, ``_y``,
    ``_roll``) and the solve's time."""

    kind: ClassVar[str] = "all-sky campaign"
    columns: ClassVar[Mapping[str, str]] = {
        "trial": "int64", "seed": "int64", "width": "int64", "height": "int64", "lens": "string",
        "true_quaternion_xyzw": "list<float64>", "solved": "bool", "wrong": "bool",
        "quaternion_xyzw": "list<float64>", "boresight_arcsec": "float64", "roll_deg": "float64",
        "normalised_x": "float64", "normalised_y": "float64", "normalised_roll": "float64",
        "n_matched": "int64", "reason": "string", "time_s": "float64"}

    def run_trial(self, trial: int) -> dict[str, Any]:
        from skyfix.analysis.truth import judge
        from skyfix.attitude import RAD_TO_ARCSEC, attitude_error
        from skyfix.geometry import attitude_from_quaternion
        from skyfix.pipeline import solve

        seed = int(self.settings["seeds"][trial])
        frame, camera, lens = allsky_frame(seed)
        t0 = time.perf_counter()
        sol = solve(frame.image, **self.settings["solve_options"])
        dt = time.perf_counter() - t0
        q_true = [float(v) for v in frame.truth["quaternion_xyzw"]]
        row = dict(trial=trial, seed=seed, width=camera.width, height=camera.height, lens=lens,
                   true_quaternion_xyzw=q_true, solved=bool(sol.solved), wrong=False, quaternion_xyzw=None,
                   boresight_arcsec=math.nan, roll_deg=math.nan, normalised_x=math.nan,
                   normalised_y=math.nan, normalised_roll=math.nan, n_matched=0, reason=sol.reason, time_s=dt)
        if sol.solved:
            A_true = attitude_from_quaternion(np.asarray(frame.truth["quaternion_xyzw"]))
            j = judge(sol.A_icrs_to_cam, sol.camera, A_true, camera)
            sigma = np.sqrt(np.diag(np.asarray(sol.covariance_arcsec2))) / RAD_TO_ARCSEC
            z = attitude_error(A_true, sol.A_icrs_to_cam) / sigma
            row.update(wrong=bool(j.wrong), quaternion_xyzw=[float(v) for v in sol.quaternion_xyzw],
                       boresight_arcsec=float(j.boresight_arcsec), roll_deg=float(j.roll_deg),
                       normalised_x=float(z[0]), normalised_y=float(z[1]), normalised_roll=float(z[2]),
                       n_matched=int(sol.n_matched), reason="")
        return row

    def warm(self) -> None:
        from skyfix import warmup

        warmup.ensure(["solve", "simulate"], missing_ok=True)


def result_of(row: Mapping[str, Any]) -> AllSkyResult:
    """The :class:`AllSkyResult` a trial's row holds."""
    z = (row["normalised_x"], row["normalised_y"], row["normalised_roll"])
    return AllSkyResult(row["seed"], (row["width"], row["height"]), row["lens"], row["solved"],
                        row["wrong"], row["boresight_arcsec"], row["roll_deg"], row["n_matched"],
                        row["time_s"], row["reason"], z if row["solved"] else (math.nan, math.nan, math.nan))


def allsky_campaign(seeds: Iterable[int], *, workers: int = 0, scheduler: str | None = None,
                    output: str | Path | None = None, batch_size: int = 4,
                    progress: Callable[[int, int], None] | None = None,
                    **solve_options: Any) -> list[AllSkyResult]:
    """Render and solve the campaign's frames ``seeds`` (no hint, no camera; ``solve_options`` are
    :func:`skyfix.solve`'s, plain JSON values) on the campaign engine: ``workers=0`` in this
    process, else that many local worker processes, or the Dask ``scheduler``'s workers
    (:func:`skyfix.montecarlo.engine.run_rows`); ``output``: the trial rows' Parquet file
    (default: a temporary one); ``progress(frames done, frames)``."""
    study = AllSkyStudy(len(seeds := [int(s) for s in seeds]), batch_size,
                        {"seeds": seeds, "solve_options": dict(solve_options)})
    table = run_rows(study, output, workers=workers, scheduler=scheduler,
                     progress=trial_progress(study, progress))
    return [result_of(row) for row in table.to_pylist()]


def summarise(results: list[AllSkyResult]) -> dict:
    """Solved share, wrong count, the boresight's median and largest error (″), the median
    time of ``results``, and the RMS of the camera axes' errors over their reported σ
    (``normalised_rms``: x, y, roll; 1 for an honest error bar)."""
    solved = [r for r in results if r.solved]
    errors = [r.boresight_arcsec for r in solved]
    z = np.array([r.axis_error_sigmas for r in solved]).reshape(-1, 3)
    return dict(n=len(results), solved=len(solved), solved_pct=100.0 * len(solved) / max(len(results), 1),
                wrong=sum(r.wrong for r in results),
                boresight_median_arcsec=float(np.median(errors)) if errors else math.nan,
                boresight_max_arcsec=float(np.max(errors)) if errors else math.nan,
                time_median_s=float(np.median([r.time_s for r in results])) if results else math.nan,
                normalised_rms=np.sqrt(np.mean(z**2, axis=0)).tolist() if errors else [math.nan] * 3)
