"""Where a solve from centroids spends its time: each compiled kernel against the Python around them.

Run: ``PYTHONPATH=src .venv/bin/python benchmarks/core_breakdown.py [--n 150] [--reps 3]``

Suite b's centroid sets (``suite_synthetic.configs``: 1280×960, 15°, Hipparcos to mag 8, four noise
configurations), each solved ``--reps`` times in a row with and without the FOV, in this process
with the kernels loaded. Every call from Python into a compiled kernel (a :class:`skyfix._jit.Kernel`)
is timed; per set the fastest repetition is kept (a loaded machine preempts calls, not work), and
the medians over sets are printed: the whole ``solve_centroids`` call, the kernels' share, the
rest (Python: argument checks, the pipeline, identification's and the final fit's set-up, the
Solution) and the kernels that cost the most. Kernels calling kernels inside numba count as
their outermost caller. A second line per configuration splits the same solve by stage:
identification (``skyfix.identify.lost.identify_lost``: the search, the refit, the
Identification), the final fit (``skyfix.final_fit.final_fit``) and the rest of the call (the
argument checks, the observation, the precision rule, the Solution's numbers and fields), each
as total = kernels + Python.
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict

import numpy as np

from suite_synthetic import configs
from synthetic import centroid_sets

# The stages a solve from centroids goes through, by the name skyfix.pipeline calls each by.
STAGES = ("identify_lost", "final_fit")


def _timed_kernels(spent: dict[str, float]) -> None:
    """Time every call from Python into a kernel, by kernel name, into ``spent`` (seconds), and
    each stage of :data:`STAGES` (``stage:NAME``), with the kernels it called (``kernels:NAME``)."""
    from skyfix import _jit, pipeline

    call = _jit.Kernel.__call__
    current = [""]

    def timed(self, *args, **kwargs):
        t0 = time.perf_counter()
        try:
            return call(self, *args, **kwargs)
        finally:
            dt = time.perf_counter() - t0
            spent[self.key.rpartition(":")[2]] += dt
            spent[f"kernels:{current[0]}"] += dt

    def staged(name, func):
        def run(*args, **kwargs):
            outer, current[0] = current[0], name
            t0 = time.perf_counter()
            try:
                return func(*args, **kwargs)
            finally:
                spent[f"stage:{name}"] += time.perf_counter() - t0
                current[0] = outer
        return run

    _jit.Kernel.__call__ = timed
    for name in STAGES:
        setattr(pipeline, name, staged(name, getattr(pipeline, name)))


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
            totals, kernels, per_set, stages = [], [], [], []
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
                stages.append(best[1])
                kernel_times = {k: v for k, v in best[1].items() if ":" not in k}
                kernels.append(sum(kernel_times.values()))
                per_set.append(kernel_times)
            ms = 1e3 * np.median(totals)
            k_ms = 1e3 * np.median(kernels)
            names = set().union(*per_set)
            by_kernel = {k: [d.get(k, 0.0) for d in per_set] for k in names}
            top = sorted(by_kernel.items(), key=lambda kv: -float(np.median(kv[1])))[:4]
            print(f"{spec.label:22s} {'FOV' if fov else 'no FOV':6s}: solve {ms:.3f} ms = kernels {k_ms:.3f} "
                  f"+ Python {1e3 * np.median(np.subtract(totals, kernels)):.3f}; "
                  + ", ".join(f"{k} {1e3 * np.median(v):.3f}" for k, v in top))
            parts = []
            rest_total = np.array(totals)
            rest_kernels = np.array(kernels)
            for name in STAGES:
                total = np.array([d.get(f"stage:{name}", 0.0) for d in stages])
                inside = np.array([d.get(f"kernels:{name}", 0.0) for d in stages])
                rest_total, rest_kernels = rest_total - total, rest_kernels - inside
                parts.append(f"{name} {1e3 * np.median(total):.3f} = {1e3 * np.median(inside):.3f} "
                             f"+ {1e3 * np.median(total - inside):.3f}")
            parts.append(f"rest {1e3 * np.median(rest_total):.3f} = {1e3 * np.median(rest_kernels):.3f} "
                         f"+ {1e3 * np.median(rest_total - rest_kernels):.3f}")
            print(f"{'':22s} {'':6s}  by stage (total = kernels + Python): " + "; ".join(parts))


if __name__ == "__main__":
    main()
