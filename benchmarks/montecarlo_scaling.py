"""Monte Carlo engine scaling (issue 27): trials per second with 1 and 2 worker processes, and
the summary bit-identical across the worker counts.

    PYTHONPATH=src python benchmarks/montecarlo_scaling.py [--campaign campaigns/quick.toml]
        [--trials N] [--workers 1,2] [--json OUT.json]

Each worker count runs the whole campaign on a fresh :class:`dask.distributed.LocalCluster` of
single-threaded worker processes (:func:`skyfix.montecarlo.engine.run_campaign`) into its own
output. Reported per count: the wall time with the cluster's start and the workers' set-up
(catalogue, databases: the first batch on each worker), the steady throughput between the first
and the last batch finished, and per trial the median simulate and solve ms — 1000 / (their sum)
is the trials per second one core gives. Then the summaries (:func:`skyfix.montecarlo.results.
summarize`, times left out) are compared: they must be equal.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def run(campaign, workers: int, folder: Path) -> dict:
    """One run of ``campaign`` on ``workers`` processes: its times and summary."""
    from skyfix.montecarlo.engine import run_campaign
    from skyfix.montecarlo.results import summarize

    stamps: list[float] = []
    t0 = time.perf_counter()
    result = run_campaign(campaign, folder / f"w{workers}.parquet", workers=workers,
                          progress=lambda done, total: stamps.append(time.perf_counter()))
    wall = time.perf_counter() - t0
    stamps = stamps[1:]  # the first call is before any batch
    steady = float("nan")
    if len(stamps) > 2:
        steady = (len(stamps) - 1) * campaign.batch_size / (stamps[-1] - stamps[0])
    table = result.table
    sim = float(np.median(table.column("simulate_ms").to_numpy()))
    solve = float(np.median(table.column("time_ms").to_numpy()))
    return {"workers": workers, "trials": table.num_rows, "wall_s": wall,
            "trials_per_s": table.num_rows / wall,
            "steady_trials_per_s": steady, "median_simulate_ms": sim, "median_solve_ms": solve,
            "trials_per_s_per_core": 1000.0 / (sim + solve), "summary": summarize(table, campaign)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--campaign", type=Path, default=ROOT / "campaigns" / "quick.toml")
    ap.add_argument("--trials", type=int, default=None, help="override the campaign's trial count")
    ap.add_argument("--workers", default="1,2", help="worker counts, comma-separated")
    ap.add_argument("--json", type=Path, default=None, help="write the measurements here")
    args = ap.parse_args(argv)
    from skyfix.montecarlo.campaign import load_campaign

    campaign = load_campaign(args.campaign)
    if args.trials:
        campaign = dataclasses.replace(campaign, trials=args.trials)
    counts = [int(w) for w in args.workers.split(",")]
    print(f"{campaign.name}: {campaign.trials} trials, {campaign.level} level, "
          f"batches of {campaign.batch_size}; "
          f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}", flush=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for w in counts:
            r = run(campaign, w, Path(tmp))
            rows.append(r)
            print(f"  {w} worker(s): {r['wall_s']:.1f} s wall "
                  f"({r['trials_per_s']:.1f} trials/s with start-up), "
                  f"steady {r['steady_trials_per_s']:.1f} trials/s; per trial median simulate "
                  f"{r['median_simulate_ms']:.2f} ms + solve {r['median_solve_ms']:.2f} ms = "
                  f"{r['trials_per_s_per_core']:.0f} trials/s/core", flush=True)
    same = all(r["summary"] == rows[0]["summary"] for r in rows)
    print(f"  summaries identical across {counts} workers: {'yes' if same else 'NO'}")
    if args.json:
        from skyfix.analysis._json import strict_json

        args.json.write_text(json.dumps(strict_json({"campaign": campaign.name, "load": os.getloadavg()[0],
                                                     "runs": rows, "identical": same}), indent=1))
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
