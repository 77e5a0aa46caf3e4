"""A frame's no-hint solution does not depend on how fast the machine runs.

The FOV bands take turns in the 4-star search by the work each has done
(``skyfix.identify.methods.quad.search_work``), not by the clock: with the clock, the same 45° frames gave
another attitude in 12 of 100 when run beside other work. Here the search's clock runs erratically
(0–3 ms a reading, far more than the searches' real pace); the solutions must stay equal to the bit.
"""

from __future__ import annotations

import time

import numpy as np

import skyfix.identify.methods.quad as quad
from skyfix.analysis.field_campaign import CASES, case_camera
from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
from skyfix.catalog import load_gaia
from skyfix.pipeline import solve_centroids


class _ErraticClock:
    """``time`` with a ``perf_counter`` that jumps 0–3 ms at each reading (seeded)."""

    def __init__(self, seed: int) -> None:
        self._rng = np.random.default_rng(seed)
        self._t = time.perf_counter()

    def perf_counter(self) -> float:
        self._t += float(self._rng.uniform(0.0, 3e-3))
        return self._t

    def __getattr__(self, name: str):
        return getattr(time, name)


def test_no_hint_solutions_do_not_depend_on_the_clock(monkeypatch):
    case = next(c for c in CASES if c.fov_deg == 45.0)
    camera = case_camera(case)
    catalog = load_gaia(epoch=2025.0)
    rng = np.random.default_rng(1)
    frames = []
    for A in random_attitudes(12, rng):
        field = synthetic_centroids(camera, A, catalog, mag_limit=case.mag_limit, sigma_px=case.sigma_px,
                                    n_false=int(rng.integers(0, case.max_false + 1)), dropout=case.dropout,
                                    mag_sigma=case.mag_sigma, rng=rng)
        frames.append(field.xy[:200])
    steady = [solve_centroids(xy, case.width, case.height, epoch=2025.0) for xy in frames]
    assert sum(s.solved for s in steady) == len(frames)
    for seed in (1, 2):
        monkeypatch.setattr(quad, "time", _ErraticClock(seed))
        erratic = [solve_centroids(xy, case.width, case.height, epoch=2025.0) for xy in frames]
        for i, (a, b) in enumerate(zip(steady, erratic, strict=True)):
            assert b.solved, (seed, i, b.reason)
            np.testing.assert_array_equal(a.A_icrs_to_cam, b.A_icrs_to_cam, err_msg=f"clock {seed} frame {i}")
