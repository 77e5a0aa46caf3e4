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

``benchmarks/suite_blind.py`` runs them (``benchmarks/run --suites e``); the slow test suite pins
the results (``tests/analysis/test_blind_campaign.py``).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterator
from typing import NamedTuple

import numpy as np

from skyfix.analysis.truth import attitude_error_rad, judge_error
from skyfix.camera import Camera, camera_from_preset
from skyfix.catalog import load_hipparcos

__all__ = ["Trial", "UncalibratedField", "preset_image_trials",
           "random_uncalibrated_camera", "summarize", "trial_result", "uncalibrated_centroid_trials",
           "uncalibrated_fields"]

_ARCSEC = math.pi / (180.0 * 3600.0)


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
    sigma = np.sqrt(np.diag(np.asarray(sol.covariance_arcsec2))) * _ARCSEC
    return Trial(True, "", n_stars, camera_true.fov_deg, err, sigma, scale)


class UncalibratedField(NamedTuple):
    """One synthetic field of :func:`uncalibrated_fields`: the true camera and attitude, the
    centroids (``field.xy``, with ``field.star_id`` ≤ 0 for false stars) and how many are real."""

    camera: Camera
    A_icrs_to_cam: np.ndarray
    field: object
    n_stars: int


def uncalibrated_fields(seed: int = 0, *, epoch: float = 2025.0) -> Iterator[UncalibratedField]:
    """The endless, reproducible sequence of fields :func:`uncalibrated_centroid_trials` solves:
    a :func:`random_uncalibrated_camera`, a random attitude, 8–40 catalogue stars to a random
    limit 5–8 mag, 5% missed, 0–5 false stars, centroid noise 0.1–1 px."""
    from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids

    catalog = load_hipparcos(epoch=epoch)
    rng = np.random.default_rng(seed)
    while True:
        camera = random_uncalibrated_camera(rng)
        A = random_attitudes(1, rng)[0]
        field = synthetic_centroids(camera, A, catalog, mag_limit=rng.uniform(5.0, 8.0),
                                    sigma_px=rng.uniform(0.1, 1.0), n_false=int(rng.integers(0, 6)),
                                    dropout=0.05, rng=rng)
        n_real = int((field.star_id > 0).sum())
        if 8 <= n_real <= 40:
            yield UncalibratedField(camera, A, field, n_real)


def uncalibrated_centroid_trials(n: int, seed: int = 0, *, epoch: float = 2025.0,
                                 progress: Callable[[int], None] | None = None) -> list[Trial]:
    """``n`` blind solves of the fields of :func:`uncalibrated_fields`."""
    from skyfix.pipeline import solve_centroids

    trials: list[Trial] = []
    for f in itertools.islice(uncalibrated_fields(seed, epoch=epoch), n):
        sol = solve_centroids(f.field.xy, f.camera.width, f.camera.height, epoch=epoch)
        trials.append(trial_result(sol, f.A_icrs_to_cam, f.camera, f.n_stars))
        if progress is not None:
            progress(1)
    return trials


def preset_image_trials(preset: str, n: int, seed: int = 0, *, false_stars: int = 0, hot_pixels: int = 0,
                        epoch: float = 2025.0, progress: Callable[[int], None] | None = None) -> list[Trial]:
    """``n`` blind solves of images rendered with ``preset`` (its realistic exposure and noise)
    at uniformly random attitudes."""
    from skyfix.analysis.synthetic_centroids import random_attitudes
    from skyfix.pipeline import solve
    from skyfix.simulate import render

    camera = camera_from_preset(preset)
    rng = np.random.default_rng(seed)
    trials = []
    for k, A in enumerate(random_attitudes(n, rng)):
        frame = render(A, preset, epoch=epoch, seed=seed * 100003 + k, false_stars=false_stars,
                       hot_pixels=hot_pixels)
        sol = solve(frame.image, epoch=epoch)
        n_stars = sum(1 for s in frame.truth["stars"]
                      if -0.5 <= s["x"] <= camera.width - 0.5 and -0.5 <= s["y"] <= camera.height - 0.5)
        trials.append(trial_result(sol, A, camera, n_stars))
        if progress is not None:
            progress(1)
    return trials


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
