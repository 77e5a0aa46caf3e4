"""Safety of ``parity="either"`` (issue 26 part 2): random synthetic centroid sets, half of them
mirrored left-right, solved with no camera file at random fields of view; counts solved, right
parity, and wrong attitudes (``skyfix.analysis.truth``: boresight > max(60″, 1 px) or roll > 0.5°;
a solution of the wrong parity counts as wrong).

Run: ``python benchmarks/parity_either.py [--n 2000] [--workers 2] [--seed 26]``
"""

from __future__ import annotations

import argparse
import math
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np


def _chunk(args: tuple[int, int, int]) -> list[tuple[bool, bool, bool, bool]]:
    from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
    from skyfix.analysis.truth import judge
    from skyfix.camera import Camera
    from skyfix.catalog import load_hipparcos
    from skyfix.identify import default_database
    from skyfix.parity import mirror_xy
    from skyfix.pipeline import solve_centroids

    start, stop, seed = args
    database = default_database()
    catalog = load_hipparcos(epoch=database.epoch)
    out = []
    for i in range(start, stop):
        rng = np.random.default_rng([seed, i])
        fov = float(rng.uniform(10.0, 30.0))
        camera = Camera.from_fov(1280, 960, fov)
        A = random_attitudes(1, rng)[0]
        field = synthetic_centroids(camera, A, catalog, sigma_px=float(rng.uniform(0.2, 1.0)),
                                    n_false=int(rng.integers(0, 6)), dropout=0.1, rng=rng)
        flip = bool(i % 2)
        xy = mirror_xy(field.xy, 1280) if flip else field.xy
        sol = solve_centroids(xy, 1280, 960, database=database, parity="either")
        wrong = sol.solved and (sol.mirrored != flip or judge(sol.A_icrs_to_cam, sol.camera, A, camera).wrong)
        out.append((flip, sol.solved, sol.solved and sol.mirrored == flip, wrong))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=26)
    opts = ap.parse_args()
    step = max(1, math.ceil(opts.n / (4 * opts.workers)))
    chunks = [(a, min(a + step, opts.n), opts.seed) for a in range(0, opts.n, step)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(opts.workers) as pool:
        rows = [r for part in pool.map(_chunk, chunks) for r in part]
    rows_a = np.array(rows, dtype=bool).reshape(-1, 4)
    for name, sel in (("normal", ~rows_a[:, 0]), ("mirrored", rows_a[:, 0])):
        r = rows_a[sel]
        print(f"{name:8s}: {len(r)} frames, solved {r[:, 1].sum()} ({100 * r[:, 1].mean():.1f} %), "
              f"right parity {r[:, 2].sum()}, wrong {r[:, 3].sum()}")
    print(f"all: {len(rows_a)} frames, wrong {rows_a[:, 3].sum()}, {time.perf_counter() - t0:.0f} s "
          f"with {opts.workers} workers")


if __name__ == "__main__":
    main()
