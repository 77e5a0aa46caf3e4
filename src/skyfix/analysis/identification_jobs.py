"""What the identification study's grid (:mod:`skyfix.analysis.identification_study`), its seed
experiments (:mod:`skyfix.analysis.identification_cases`) and its safety case
(:mod:`skyfix.analysis.identification_safety`) share: the simulated frames' settings and
conditions, the methods run, a solve judged against its truth
(:func:`skyfix.analysis.truth.judge`, the one definition of a wrong attitude), the 95 % bound on a
rate, and the pool of warmed worker processes every job runs in.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
from skyfix.analysis.truth import Judgement, judge
from skyfix.camera import Camera
from skyfix.catalog import load_hipparcos
from skyfix.identify import METHODS, default_database, get_method, identify

__all__ = ["CONDITIONS", "Condition", "EPOCH", "HEIGHT", "MAG_LIMIT", "WARMED", "WIDTH", "condition_key",
           "judge_identification", "method_names", "pool_steps", "run_pool", "study_field", "table_nbytes",
           "upper_bound_95", "warm_methods"]

EPOCH = 2025.0
WIDTH, HEIGHT = 1280, 960
MAG_LIMIT = 6.5

class Condition(NamedTuple):
    """How a simulated frame departs from the truth."""

    name: str
    sigma_px: float = 0.0
    n_false: int = 0
    dropout: float = 0.0
    mag_sigma: float = 0.0


CONDITIONS = (
    Condition("noise-free"),
    Condition("σ 0.5 px", sigma_px=0.5),
    Condition("σ 1 px", sigma_px=1.0),
    Condition("σ 2 px", sigma_px=2.0),
    Condition("3 false stars", n_false=3),
    Condition("10 false stars", n_false=10),
    Condition("20 % dropped", dropout=0.2),
    Condition("0.5 mag noise", mag_sigma=0.5),
    Condition("all: σ 1 px, 5 false, 10 % dropped, 0.3 mag", 1.0, 5, 0.1, 0.3),
)


def method_names(methods: tuple[str, ...] | list[str] = ()) -> list[str]:
    """The methods to run: those named (checked), or every registered one; a name that is an
    alias of an earlier one's function (``hash`` of ``quad-hash``) is run once."""
    names = [m.strip().lower() for m in methods if m.strip()] or list(METHODS)
    seen: dict[int, str] = {}
    out = []
    for m in names:
        fn = get_method(m)  # InputError for an unknown name
        if id(fn) not in seen:
            seen[id(fn)] = m
            out.append(m)
    return out


def upper_bound_95(k: int, n: int) -> float:
    """One-sided 95 % Clopper–Pearson upper bound of a rate seen ``k`` times in ``n`` (with
    ``k = 0``: 1 − 0.05^(1/n) ≈ 3/n, the rule of three)."""
    from scipy.stats import beta

    if n <= 0:
        return 1.0
    return 1.0 if k >= n else float(beta.ppf(0.95, k + 1, n - k))


def study_field(fov: float, cond: Condition, trial: int, seed: int, catalog):
    rng = np.random.default_rng([seed, int(round(fov * 100)), condition_key(cond), trial])
    camera = Camera.from_fov(WIDTH, HEIGHT, fov)
    A = random_attitudes(1, rng)[0]
    f = synthetic_centroids(camera, A, catalog, mag_limit=MAG_LIMIT, sigma_px=cond.sigma_px,
                            n_false=cond.n_false, dropout=cond.dropout, mag_sigma=cond.mag_sigma, rng=rng)
    return camera, f


def condition_key(cond: Condition) -> int:
    return int(round(cond.sigma_px * 100)) * 10**7 + cond.n_false * 10**5 + int(round(
        cond.dropout * 100)) * 10**3 + int(round(cond.mag_sigma * 100))


def judge_identification(ident, A_true: np.ndarray, camera: Camera) -> Judgement:
    """A solved identification against the truth of a frame seen by ``camera``
    (:func:`skyfix.analysis.truth.judge`)."""
    return judge(ident.A_icrs_to_cam, ident.camera, A_true, camera)


def warm_methods(methods: list[str], fovs_deg: tuple[float, ...] = (8.0, 15.0, 30.0), cameras: bool = False
          ) -> dict[str, dict]:
    """Two calls per method and FOV outside the clock (the first builds the method's tables
    beside the shared database and loads its compiled kernels). Returns per method the bytes of
    the tables it added to the database (:meth:`~skyfix.identify.PatternDatabase.derived`) and
    its first calls' time beyond the second's (the build). With ``cameras``, then one call per
    method and FOV with the camera given (the tables a calibrated camera's search builds), not
    counted."""
    catalog = load_hipparcos(epoch=EPOCH, mag_limit=MAG_LIMIT + 1.0)
    db = default_database(progress=False)
    fields = [(fov, study_field(fov, CONDITIONS[0], 10**6 + 1, 12345, catalog)[1]) for fov in fovs_deg]
    out = {}
    for m in methods:
        before = set(db.__dict__.get("_derived", {}))
        build = 0.0
        for fov, f in fields:
            for k in range(2):
                t0 = time.perf_counter()
                identify(f.xy, WIDTH, HEIGHT, method=m, fov_deg=fov, fov_tolerance_deg=0.1 * fov, database=db,
                         epoch=EPOCH)
                build += (1 if k == 0 else -1) * (time.perf_counter() - t0)
        derived = db.__dict__.get("_derived", {})
        added = [v for key, v in derived.items() if key not in before]
        out[m] = {"bytes": table_nbytes(added), "tables": len(added), "build_s": max(build, 0.0)}
    for m in methods if cameras else ():
        for fov, f in fields:
            identify(f.xy, WIDTH, HEIGHT, method=m, camera=Camera.from_fov(WIDTH, HEIGHT, fov), database=db,
                     epoch=EPOCH)
    return out


def table_nbytes(value, seen: set | None = None) -> int:
    """Bytes of the numpy arrays in a (nested) table."""
    seen = set() if seen is None else seen
    if id(value) in seen:
        return 0
    seen.add(id(value))
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if isinstance(value, dict):
        return sum(table_nbytes(v, seen) for v in value.values())
    if isinstance(value, (list, tuple)):
        return sum(table_nbytes(v, seen) for v in value)
    if hasattr(value, "__dict__"):
        return sum(table_nbytes(v, seen) for v in vars(value).values())
    return 0


WARMED = "methods warmed (their tables built)"
"""The step :func:`run_pool` reports when it has warmed the methods in this process."""


def _pool_size(workers: int, n_jobs: int) -> int:
    return max(1, min(int(workers), n_jobs))


def pool_steps(n_jobs: int, workers: int) -> int:
    """How many times :func:`run_pool` calls ``progress`` for ``n_jobs`` jobs: once a job, and once
    for the warm-up when it runs them here (one worker)."""
    return n_jobs + (_pool_size(workers, n_jobs) == 1)


def run_pool(jobs: list[tuple], workers: int, methods: list[str], fovs_deg: tuple[float, ...],
          progress: Callable[[str], None] | None, label: Callable[[tuple], str],
          done: Callable[[object], None] | None = None, cameras: bool = True) -> list:
    """Run ``jobs`` — ``(function, *args)`` tuples — in ``workers`` spawned processes (each warmed
    by :func:`warm_methods`, calibrated cameras included unless ``cameras`` is False: no job gives
    a camera) or, with one worker, here (then the warm-up is a step of ``progress`` too:
    :data:`WARMED`); returns their results in the jobs' order (``done`` is given each result as
    it comes)."""
    results: list = [None] * len(jobs)
    workers = _pool_size(workers, len(jobs))
    if workers == 1:
        warm_methods(methods, fovs_deg, cameras=cameras)
        if progress is not None:
            progress(WARMED)
        for i, (fn, *args) in enumerate(jobs):
            results[i] = fn(*args)
            if done is not None:
                done(results[i])
            if progress is not None:
                progress(label(jobs[i]))
        return results
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    ctx = mp.get_context("spawn")  # no fork of a process holding numba's and rich's threads
    with ProcessPoolExecutor(workers, mp_context=ctx, initializer=warm_methods,
                             initargs=(methods, fovs_deg, cameras)) as pool:
        futures = {pool.submit(fn, *args): i for i, (fn, *args) in enumerate(jobs)}
        for fut in as_completed(futures):
            i = futures[fut]
            results[i] = fut.result()
            if done is not None:
                done(results[i])
            if progress is not None:
                progress(label(jobs[i]))
    return results
