"""Side-by-side timing of the no-hint solve from centroids, for comparing two commits on a busy
machine (docs/fields.md, "Speed"): the field campaign's frames of the chosen cases
(:data:`skyfix.analysis.field_campaign.CASES`, the same frames as ``field_trials(case, n, seed)``)
are generated first and then solved in a row (so generating them does not evict the solver's
caches between solves), after one untimed frame of each case; each solve's CPU time
(``time.process_time``) and wall time, its attitude and its result against the truth are
written to a JSON file. Run it once per commit and case, alternating the commits::

    PYTHONPATH=<worktree>/src python benchmarks/fields_ab.py OUT.json --cases 0,6 [--n 100] [--seed 1]
    python benchmarks/fields_ab.py --compare BEFORE.json AFTER.json
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def run(cases: list[int], n: int, seed: int) -> dict:
    from skyfix.analysis.blind_campaign import trial_result
    from skyfix.analysis.field_campaign import CASES, case_camera, field_trials
    from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
    from skyfix.analysis.truth import judge_error
    from skyfix.catalog import load_gaia
    from skyfix.pipeline import solve_centroids

    catalog = load_gaia(epoch=2025.0)
    for i in cases:  # warm-up, untimed: the bands loaded, the kernels compiled
        field_trials(CASES[i], 1, seed + 10_000)
    out = {}
    for i in cases:
        case = CASES[i]
        camera = case_camera(case)
        rng = np.random.default_rng(seed)  # as field_trials draws them
        frames = []
        for A in random_attitudes(n, rng):
            n_false = int(rng.integers(0, case.max_false + 1))
            field = synthetic_centroids(camera, A, catalog, mag_limit=case.mag_limit, sigma_px=case.sigma_px,
                                        n_false=n_false, dropout=case.dropout, mag_sigma=case.mag_sigma,
                                        rng=rng)
            frames.append((A, field.xy[:200], int((field.star_id != 0).sum())))
        rows = []
        for A, xy, n_stars in frames:
            c0, w0 = time.process_time(), time.perf_counter()
            sol = solve_centroids(xy, case.width, case.height, epoch=2025.0)
            cpu, wall = time.process_time() - c0, time.perf_counter() - w0
            trial = trial_result(sol, A, camera, n_stars)
            wrong = bool(sol.solved and judge_error(trial.error_rad, trial.plate_scale_arcsec).wrong)
            rows.append(dict(cpu_ms=1e3 * cpu, wall_ms=1e3 * wall, solved=bool(sol.solved), wrong=wrong,
                             n_matched=int(sol.n_matched or 0),
                             A=None if sol.A_icrs_to_cam is None else np.asarray(sol.A_icrs_to_cam).tolist(),
                             error_rad=np.asarray(trial.error_rad).tolist(),
                             sigma_rad=np.asarray(trial.sigma_rad).tolist()))
        out[case.name] = rows
    return out


def compare(before: dict, after: dict) -> None:
    """Per case and over all: CPU and wall median / p99, solved, wrong, attitudes equal to the bit."""
    cpu_b, cpu_a = [], []
    for name in before:
        b, a = before[name], after[name]
        cb, ca = [r["cpu_ms"] for r in b], [r["cpu_ms"] for r in a]
        wb, wa = [r["wall_ms"] for r in b], [r["wall_ms"] for r in a]
        cpu_b += cb
        cpu_a += ca
        same = sum(x["A"] == y["A"] for x, y in zip(b, a, strict=True))
        solved = [sum(r["solved"] for r in rows) for rows in (b, a)]
        wrong = [sum(r["wrong"] for r in rows) for rows in (b, a)]
        print(f"{name:14s} CPU {np.median(cb):6.1f} / {np.percentile(cb, 99):6.1f} -> {np.median(ca):6.1f} / "
              f"{np.percentile(ca, 99):6.1f}   wall {np.median(wb):6.1f} / {np.percentile(wb, 99):6.1f} -> "
              f"{np.median(wa):6.1f} / {np.percentile(wa, 99):6.1f}   solved {solved[0]} -> {solved[1]}   "
              f"wrong {wrong[0]} -> {wrong[1]}   identical {same}/{len(a)}")
    print(f"{'all':14s} CPU {np.median(cpu_b):6.1f} / {np.percentile(cpu_b, 99):6.1f} -> "
          f"{np.median(cpu_a):6.1f} / {np.percentile(cpu_a, 99):6.1f}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", nargs="?")
    ap.add_argument("--cases", default="0,1,2,3,4,5,6")
    ap.add_argument("--n", type=int, default=100)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--compare", nargs=2, metavar=("BEFORE", "AFTER"))
    args = ap.parse_args()
    if args.compare:
        compare(*(json.load(open(p)) for p in args.compare))
    else:
        result = run([int(c) for c in args.cases.split(",")], args.n, args.seed)
        with open(args.out, "w") as f:
            json.dump(result, f)
