"""Blind-solve campaigns: is every "solved" right, and is its error bar honest?

Two kinds of trial, both solved with no camera file and no FOV hint, as a new user would:

- :func:`uncalibrated_centroid_trials` — synthetic centroids from random *uncalibrated* cameras
  (pixel aspect 0.95–1.05, principal point up to 20 px off centre, k1 within ±0.3, 8–40 stars,
  0–5 false stars, centroid noise 0.1–1 px, fields 8–35° wide);
- :func:`preset_image_trials` — images rendered by :mod:`skyfix.simulate` with a seed camera
  preset at random pointings, with or without false stars and hot pixels.

Each trial's error is the rotation between the reported attitude and the true one *at the pixel
the solution calls its boresight* (its principal point): with no camera file the optical axis
is not known, but the sky direction of that pixel and the roll there are
(:func:`skyfix.analysis.truth.attitude_error_rad`). A trial is **wrong** when that boresight
error exceeds max(60″, 1 px) or the roll error 0.5° (:func:`skyfix.analysis.truth.is_wrong`); the
**normalised error** is the error divided by the reported σ, per axis (cross-boresight x, y and
roll): honest error bars give an RMS near 1.

Both run on the campaign engine (:func:`skyfix.montecarlo.engine.run_campaign`) as the studies
:class:`UncalibratedStudy` and :class:`PresetImageStudy`: one Parquet row per trial
(:data:`TRIAL_COLUMNS` and the study's inputs), in this process (``workers=0``, the default),
on local worker processes or on a Dask scheduler; :func:`trial_of_row` turns a row back into
the :class:`Trial` the summary takes. The numbers are those of the serial loops they replaced:
a preset trial is seeded from (seed, trial) as before; the uncalibrated fields are one random
sequence (:func:`uncalibrated_fields`), so a batch starts from the generator's state at its
first trial (:func:`sequence_batch`: each process steps the sequence there once, without
solving, and remembers the states).

``benchmarks/suite_blind.py`` runs them (``benchmarks/run --suites e``); the slow test suite pins
the results (``tests/analysis/test_blind_campaign.py``).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Hashable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

import numpy as np

from skyfix.analysis.truth import attitude_error_rad, judge_error
from skyfix.camera import Camera, camera_from_preset
from skyfix.catalog import load_hipparcos
from skyfix.montecarlo.engine import run_rows
from skyfix.montecarlo.study import BatchedStudy

__all__ = ["TRIAL_COLUMNS", "PresetImageStudy", "Trial", "UncalibratedField", "UncalibratedStudy",
           "preset_image_trials", "random_uncalibrated_camera", "sequence_batch", "summarize",
           "trial_of_row", "trial_result", "trial_row", "uncalibrated_centroid_trials", "uncalibrated_fields"]

_ARCSEC = math.pi / (180.0 * 3600.0)
_AXES = ("x", "y", "roll")


class Trial(NamedTuple):
    """One blind solve and its truth.

    ``error_rad`` and ``sigma_rad`` are (x, y, roll) about the solution's camera axes (NaN when
    it failed); ``plate_scale_arcsec`` is one pixel of the true camera."""

    solved: bool
    reason: str
    n_stars: int
    fov_deg: float
    error_rad: np.ndarray
    sigma_rad: np.ndarray
    plate_scale_arcsec: float


#: The columns every blind-solve row has after its study's inputs (``{name: Arrow type}``): the
#: true camera's size and field, the true boresight, the stars in view, the status, the
#: solution's boresight, the error and reported σ per axis (rad, :class:`Trial`), the boresight
#: and roll errors, wrong (:func:`skyfix.analysis.truth.is_wrong`) and the solve's wall time.
TRIAL_COLUMNS: dict[str, str] = {
    "width": "int32", "height": "int32", "fov_deg": "float64", "plate_scale_arcsec": "float64",
    "ra_true_deg": "float64", "dec_true_deg": "float64", "roll_true_deg": "float64", "n_stars": "int32",
    "status": "string", "reason": "string", "ra_deg": "float64", "dec_deg": "float64", "roll_deg": "float64",
    **{f"error_{a}_rad": "float64" for a in _AXES}, **{f"sigma_{a}_rad": "float64" for a in _AXES},
    "boresight_error_arcsec": "float64", "roll_error_arcsec": "float64", "wrong": "bool",
    "time_ms": "float64",
}


def random_uncalibrated_camera(rng: np.random.Generator) -> Camera:
    """A camera as a user without a calibration might have: one of five sensor sizes, a field
    8–35° wide, pixel aspect 0.95–1.05, principal point up to 20 px off centre, k1 in ±0.3."""
    width, height = [(1280, 960), (1024, 1024), (752, 582), (640, 480), (2048, 1536)][rng.integers(5)]
    fov = rng.uniform(8.0, 35.0)
    f = width / 2.0 / math.tan(math.radians(fov) / 2.0)
    offset, angle = 20.0 * math.sqrt(rng.random()), rng.uniform(0.0, 2.0 * math.pi)
    return Camera(width, height, f, f * rng.uniform(0.95, 1.05), (width - 1) / 2.0 + offset * math.cos(angle),
                  (height - 1) / 2.0 + offset * math.sin(angle), k1=rng.uniform(-0.3, 0.3))


def trial_result(sol, A_true: np.ndarray, camera_true: Camera, n_stars: int) -> Trial:
    """A solve of a frame with ``n_stars`` catalogue stars in view judged against its truth."""
    scale = math.degrees(camera_true.plate_scale_rad) * 3600.0
    if sol.status != "solved":
        nan = np.full(3, np.nan)
        return Trial(False, sol.reason, n_stars, camera_true.fov_deg, nan, nan, scale)
    err = attitude_error_rad(sol.A_icrs_to_cam, sol.camera, A_true, camera_true)
    sigma = np.sqrt(np.diag(np.asarray(sol.frame_covariance_arcsec2))) * _ARCSEC  # the error's pixel
    return Trial(True, "", n_stars, camera_true.fov_deg, err, sigma, scale)


def trial_row(trial: int, inputs: Mapping[str, Any], sol, A_true: np.ndarray, camera_true: Camera,
              n_stars: int, time_ms: float) -> dict[str, Any]:
    """A judged solve as a row: ``trial``, ``inputs`` (the study's input columns), then
    :data:`TRIAL_COLUMNS`."""
    from skyfix.geometry import radec_roll_from_attitude

    t = trial_result(sol, A_true, camera_true, n_stars)
    j = judge_error(t.error_rad, t.plate_scale_arcsec)
    ra, dec, roll = np.degrees(radec_roll_from_attitude(A_true)).tolist()
    row = {"trial": trial, **inputs, "width": camera_true.width, "height": camera_true.height,
           "fov_deg": t.fov_deg, "plate_scale_arcsec": t.plate_scale_arcsec, "ra_true_deg": ra,
           "dec_true_deg": dec, "roll_true_deg": roll, "n_stars": t.n_stars,
           "status": "solved" if t.solved else "failed", "reason": t.reason,
           "ra_deg": sol.ra_deg if t.solved else math.nan, "dec_deg": sol.dec_deg if t.solved else math.nan,
           "roll_deg": sol.roll_deg if t.solved else math.nan}
    row.update({f"error_{a}_rad": float(v) for a, v in zip(_AXES, t.error_rad, strict=True)})
    row.update({f"sigma_{a}_rad": float(v) for a, v in zip(_AXES, t.sigma_rad, strict=True)})
    row.update(boresight_error_arcsec=j.boresight_arcsec, roll_error_arcsec=j.roll_deg * 3600.0,
               wrong=bool(t.solved and j.wrong), time_ms=time_ms)
    return row


def trial_of_row(row: Mapping[str, Any]) -> Trial:
    """The :class:`Trial` a row of :func:`trial_row` holds (the same numbers, bit for bit)."""
    return Trial(row["status"] == "solved", row["reason"], int(row["n_stars"]), row["fov_deg"],
                 np.array([row[f"error_{a}_rad"] for a in _AXES], dtype=np.float64),
                 np.array([row[f"sigma_{a}_rad"] for a in _AXES], dtype=np.float64),
                 row["plate_scale_arcsec"])


# --- running a study, in batches that continue one random sequence ---------------------------------
#: Per process: the generator's state at the start of trials of a sequence ({trial: state}, a key
#: per sequence), so a batch starts where the sequence is at its first trial (:func:`sequence_batch`).
_SEQUENCE_STATES: dict[Hashable, dict[int, dict]] = {}
_SEQUENCES_KEPT = 8
_LOCK = threading.Lock()  # Dask's threads (a LocalCluster without processes) share the memos


def sequence_batch(key: Hashable, trials: range, start: Callable[[], np.random.Generator],
                   draw: Callable[[np.random.Generator, int], Any],
                   solve: Callable[[int, Any], dict[str, Any]]) -> list[dict[str, Any]]:
    """The rows of ``trials`` of a study whose trials draw, one after another, from one random
    sequence: ``start()`` the generator before trial 0, ``draw(rng, i)`` trial ``i``'s inputs
    (what it draws moves ``rng`` on), ``solve(i, inputs)`` its row (drawing nothing). The
    generator's state before each trial is remembered in this process under ``key`` (what
    decides the sequence), so a batch steps from the nearest state known, drawing without
    solving: the rows are those of one loop over every trial, in any batch and process."""
    with _LOCK:
        states = _SEQUENCE_STATES.get(key)
        if states is None:
            while len(_SEQUENCE_STATES) >= _SEQUENCES_KEPT:
                _SEQUENCE_STATES.pop(next(iter(_SEQUENCE_STATES)))
            states = _SEQUENCE_STATES[key] = {0: start().bit_generator.state}
        first = max(k for k in list(states) if k <= trials.start)
        rng = np.random.Generator(np.random.PCG64())
        rng.bit_generator.state = states[first]
    rows = []
    for i in range(first, trials.stop):
        inputs = draw(rng, i)
        states.setdefault(i + 1, rng.bit_generator.state)
        if i >= trials.start:
            rows.append(solve(i, inputs))
    return rows


def _trial_counter(study: BatchedStudy, advance: Callable[[int], None] | None
                   ) -> Callable[[int, int], None] | None:
    """The engine's ``progress(done batches, total)`` as ``advance(trials)`` calls."""
    if advance is None:
        return None
    shown = [0]

    def progress(done: int, total: int) -> None:
        trials = min(done * study.batch_size, study.trials)
        if trials > shown[0]:
            advance(trials - shown[0])
            shown[0] = trials

    return progress


# --- the uncalibrated cameras ------------------------------------------------------------------------
class UncalibratedField(NamedTuple):
    """One synthetic field of :func:`uncalibrated_fields`: the true camera and attitude, the
    centroids (``field.xy``, with ``field.star_id`` ≤ 0 for false stars), how many are real, and
    the drawn magnitude limit, centroid noise (px) and false stars."""

    camera: Camera
    A_icrs_to_cam: np.ndarray
    field: object
    n_stars: int
    mag_limit: float = math.nan
    sigma_px: float = math.nan
    n_false: int = 0


def _next_uncalibrated_field(rng: np.random.Generator, catalog) -> UncalibratedField:
    """Draw fields from ``rng`` until one has 8–40 catalogue stars (see :func:`uncalibrated_fields`)."""
    from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids

    while True:
        camera = random_uncalibrated_camera(rng)
        A = random_attitudes(1, rng)[0]
        mag_limit, sigma_px, n_false = rng.uniform(5.0, 8.0), rng.uniform(0.1, 1.0), int(rng.integers(0, 6))
        field = synthetic_centroids(camera, A, catalog, mag_limit=mag_limit, sigma_px=sigma_px,
                                    n_false=n_false, dropout=0.05, rng=rng)
        n_real = int((field.star_id > 0).sum())
        if 8 <= n_real <= 40:
            return UncalibratedField(camera, A, field, n_real, mag_limit, sigma_px, n_false)


def uncalibrated_fields(seed: int = 0, *, epoch: float = 2025.0) -> Iterator[UncalibratedField]:
    """The endless, reproducible sequence of fields :func:`uncalibrated_centroid_trials` solves:
    a :func:`random_uncalibrated_camera`, a random attitude, 8–40 catalogue stars to a random
    limit 5–8 mag, 5% missed, 0–5 false stars, centroid noise 0.1–1 px."""
    catalog = load_hipparcos(epoch=epoch)
    rng = np.random.default_rng(seed)
    while True:
        yield _next_uncalibrated_field(rng, catalog)


@dataclass(frozen=True)
class UncalibratedStudy(BatchedStudy):
    """Blind solves of :func:`uncalibrated_fields` (settings ``seed``, ``epoch``): trial ``i`` is
    the ``i``-th field of the sequence seeded ``seed``."""

    kind: ClassVar[str] = "blind-uncalibrated"
    columns: ClassVar[Mapping[str, str]] = {
        "trial": "int64", "fx": "float64", "fy": "float64", "cx": "float64", "cy": "float64", "k1": "float64",
        "mag_limit": "float64", "sigma_px": "float64", "n_false": "int32", **TRIAL_COLUMNS}

    def run_batch(self, batch: int) -> list[dict[str, Any]]:
        from skyfix.pipeline import solve_centroids

        seed, epoch = int(self.settings["seed"]), float(self.settings["epoch"])
        catalog = load_hipparcos(epoch=epoch)

        def solve(i: int, f: UncalibratedField) -> dict[str, Any]:
            t0 = time.perf_counter()
            sol = solve_centroids(f.field.xy, f.camera.width, f.camera.height, epoch=epoch)
            ms = 1e3 * (time.perf_counter() - t0)
            c = f.camera
            inputs = {"fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy, "k1": c.k1,
                      "mag_limit": float(f.mag_limit), "sigma_px": float(f.sigma_px), "n_false": f.n_false}
            return trial_row(i, inputs, sol, f.A_icrs_to_cam, c, f.n_stars, ms)

        return sequence_batch((self.kind, seed, epoch), self.batch_trials(batch),
                              lambda: np.random.default_rng(seed),
                              lambda rng, i: _next_uncalibrated_field(rng, catalog), solve)

    def run_trial(self, trial: int) -> dict[str, Any]:
        return UncalibratedStudy(trial + 1, 1, self.settings).run_batch(trial)[0]

    def warm(self) -> None:
        from skyfix import warmup

        warmup.ensure(["solve"], missing_ok=True)


def uncalibrated_centroid_trials(n: int, seed: int = 0, *, epoch: float = 2025.0,
                                 progress: Callable[[int], None] | None = None, workers: int = 0,
                                 scheduler: str | None = None, client=None, output: str | Path | None = None,
                                 batch_size: int = 50) -> list[Trial]:
    """``n`` blind solves of the fields of :func:`uncalibrated_fields` (:class:`UncalibratedStudy`
    on the engine, :func:`skyfix.montecarlo.engine.run_rows`: ``workers``, ``scheduler``,
    ``client``, ``output``);
    ``progress(k)`` is told of every ``k`` trials finished."""
    study = UncalibratedStudy(n, batch_size, {"seed": int(seed), "epoch": float(epoch)})
    rows = run_rows(study, output, workers=workers, scheduler=scheduler, client=client,
                    progress=_trial_counter(study, progress)).to_pylist()
    return [trial_of_row(r) for r in rows]


# --- the seed camera presets -------------------------------------------------------------------------
_PRESET_ATTITUDES: dict[tuple[int, int], np.ndarray] = {}


@dataclass(frozen=True)
class PresetImageStudy(BatchedStudy):
    """Blind solves of images rendered with a camera preset (settings ``preset``, ``seed``,
    ``false_stars``, ``hot_pixels``, ``epoch``): trial ``k`` is the ``k``-th of ``trials``
    uniformly random attitudes drawn from ``seed``, its frame rendered with the seed
    ``seed · 100003 + k``."""

    kind: ClassVar[str] = "blind-preset"
    columns: ClassVar[Mapping[str, str]] = {"trial": "int64", "render_seed": "int64", **TRIAL_COLUMNS}

    def _attitude(self, trial: int) -> np.ndarray:
        from skyfix.analysis.synthetic_centroids import random_attitudes

        key = (int(self.settings["seed"]), self.trials)
        with _LOCK:
            if key not in _PRESET_ATTITUDES:
                _PRESET_ATTITUDES.clear()
                _PRESET_ATTITUDES[key] = random_attitudes(self.trials, np.random.default_rng(key[0]))
            return _PRESET_ATTITUDES[key][trial]

    def run_trial(self, trial: int) -> dict[str, Any]:
        from skyfix.pipeline import solve
        from skyfix.simulate import render

        s = self.settings
        camera = camera_from_preset(s["preset"])
        A = self._attitude(trial)
        render_seed = int(s["seed"]) * 100003 + trial
        frame = render(A, s["preset"], epoch=s["epoch"], seed=render_seed, false_stars=s["false_stars"],
                       hot_pixels=s["hot_pixels"])
        t0 = time.perf_counter()
        sol = solve(frame.image, epoch=s["epoch"])
        ms = 1e3 * (time.perf_counter() - t0)
        n_stars = sum(1 for st in frame.truth["stars"]
                      if -0.5 <= st["x"] <= camera.width - 0.5 and -0.5 <= st["y"] <= camera.height - 0.5)
        return trial_row(trial, {"render_seed": render_seed}, sol, A, camera, n_stars, ms)

    def warm(self) -> None:
        from skyfix import warmup

        warmup.ensure(["solve", "simulate"], missing_ok=True)


def preset_image_trials(preset: str, n: int, seed: int = 0, *, false_stars: int = 0, hot_pixels: int = 0,
                        epoch: float = 2025.0, progress: Callable[[int], None] | None = None,
                        workers: int = 0, scheduler: str | None = None, client=None,
                        output: str | Path | None = None, batch_size: int = 10) -> list[Trial]:
    """``n`` blind solves of images rendered with ``preset`` (its realistic exposure and noise)
    at uniformly random attitudes (:class:`PresetImageStudy` on the engine,
    :func:`skyfix.montecarlo.engine.run_rows`)."""
    settings = {"preset": preset, "seed": int(seed), "false_stars": int(false_stars),
                "hot_pixels": int(hot_pixels), "epoch": float(epoch)}
    study = PresetImageStudy(n, batch_size, settings)
    rows = run_rows(study, output, workers=workers, scheduler=scheduler, client=client,
                    progress=_trial_counter(study, progress)).to_pylist()
    return [trial_of_row(r) for r in rows]


def summarize(trials: list[Trial]) -> dict:
    """Solved and wrong counts, the normalised error's RMS per axis (x, y, roll) over the solved
    trials, and the largest boresight / roll errors."""
    solved = [t for t in trials if t.solved]
    out = {"n": len(trials), "solved": len(solved),
           "wrong": sum(judge_error(t.error_rad, t.plate_scale_arcsec).wrong for t in solved)}
    if solved:
        err = np.array([t.error_rad for t in solved])
        z = err / np.array([t.sigma_rad for t in solved])
        out["normalised_rms"] = np.sqrt(np.mean(z**2, axis=0)).round(3).tolist()
        out["median_boresight_arcsec"] = float(np.median(np.hypot(err[:, 0], err[:, 1])) / _ARCSEC)
        out["median_roll_arcsec"] = float(np.median(np.abs(err[:, 2])) / _ARCSEC)
        out["max_boresight_arcsec"] = float(np.max(np.hypot(err[:, 0], err[:, 1])) / _ARCSEC)
        out["max_roll_deg"] = float(np.degrees(np.max(np.abs(err[:, 2]))))
    return out
