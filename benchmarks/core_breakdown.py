"""Where a solve from centroids spends its time: each compiled kernel against the Python around them.

Run: ``PYTHONPATH=src .venv/bin/python benchmarks/core_breakdown.py [--n 150] [--reps 3]``

Suite b's centroid sets (``suite_synthetic.configs``: 1280×960, 15°, Hipparcos to mag 8, four noise
configurations), each solved ``--reps`` times in a row with and without the FOV, in this process
with the kernels loaded. Every call from Python into a compiled kernel (a :class:`skyfix._jit.Kernel`)
is timed; per set the fastest repetition is kept (a loaded machine preempts calls, not work), and
the medians over sets are printed: the whole ``solve_centroids`` call, the kernels' share, the
rest (Python: argument checks, the pipeline, identification's and the final fit's set-up, the
Solution) and the kernels that cost the most. Kernels calling kernels inside numba count as
their outermost caller.
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict

import numpy as np

from suite_synthetic import configs
from synthetic import centroid_sets


def _timed_kernels(spent: dict[str, float]) -> None:
    """Time every call from Python into a kernel, by kernel name, into ``spent`` (seconds)."""
    from skyfix import _jit

    call = _jit.Kernel.__call__

    def timed(self, *args, **kwargs):
        t0 = time.perf_counter()
        try:
            return call(self, *args, **kwargs)
        finally:
            spent[self.key.rpartition(":")[2]] += time.perf_counter() - t0

    _jit.Kernel.__call__ = timed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=150, help="centroid sets per configuration")
    ap.add_argument("--reps", type=int, default=3, help="solves of each set (the fastest is kept)")
    args = ap.parse_args()

    from skyfix.identify import default_database
    from skyfix.pipeline import solve_centroids

    db = default_database()
    spent: dict[str, float] = defaultdict(float)
    _timed_kernels(spent)
    for spec in configs(args.n):
        sets, _ = centroid_sets(spec)
        for fov in (spec.fov_deg, None):
            def solve(s, fov=fov, spec=spec):
                return solve_centroids(s.xy, spec.width, spec.height, fov_deg=fov, database=db)

            for s in sets[:3]:  # loaded (or compiled) before the clock runs
                solve(s)
            totals, kernels, per_set = [], [], []
            for s in sets:
                best = None
                for _ in range(args.reps):
                    spent.clear()
                    t0 = time.perf_counter()
                    solve(s)
                    total = time.perf_counter() - t0
                    if best is None or total < best[0]:
                        best = (total, dict(spent))
                totals.append(best[0])
                kernels.append(sum(best[1].values()))
                per_set.append(best[1])
            ms = 1e3 * np.median(totals)
            k_ms = 1e3 * np.median(kernels)
            names = set().union(*per_set)
            by_kernel = {k: [d.get(k, 0.0) for d in per_set] for k in names}
            top = sorted(by_kernel.items(), key=lambda kv: -float(np.median(kv[1])))[:4]
            print(f"{spec.label:22s} {'FOV' if fov else 'no FOV':6s}: solve {ms:.3f} ms = kernels {k_ms:.3f} "
                  f"+ Python {1e3 * np.median(np.subtract(totals, kernels)):.3f}; "
                  + ", ".join(f"{k} {1e3 * np.median(v):.3f}" for k, v in top))


if __name__ == "__main__":
    main()
