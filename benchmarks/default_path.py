"""The default path on suite b's 8-false-star sets: centroids → attitude with no FOV and no database.

Suite b (``suite_synthetic.py``) hands skyfix its standard database; a user who names none is
searched through every default FOV band (``skyfix.identify.catalogue.bands``), the bands taking
turns. This script solves suite b's two 8-false-star configurations (σ 0.5 and 1 px, the same
seeds and sets) that way — ``skyfix.pipeline.solve_centroids(xy, 1280, 960)`` — and prints, per
configuration and side, solved, wrong (boresight > 60″ or roll > 0.5°, ``common.is_wrong``), and
the median / p99 / max of the call's wall time (the first call, and the fastest of ``--best-of``
calls in a row, as suite b does).

One command::

    PYTHONPATH=src .venv/bin/python benchmarks/default_path.py --n 300 [--against main]

With ``--against REF`` the working tree and REF each run in a worker process of their own
(``remote.Worker``, REF's worktree made as ``benchmarks/run --against`` makes it), given the same
sets in alternating batches of ``--batch``, the order reversed every batch; the ratios tree / REF
are printed. Every time is measured inside the worker, around the call. The default bands must
be in the user cache (a solve builds them on first need; ``skyfix database build --default-bands``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import boresight_error_arcsec, is_wrong, median, pct, ratio, roll_error_deg  # noqa: E402
from suite_synthetic import configs  # noqa: E402
from synthetic import centroid_sets  # noqa: E402


def solve_default(xy: np.ndarray, width: int, height: int, reps: int = 1) -> dict:
    """``reps`` solves of ``xy`` in a row with no FOV and no database (the default bands), each timed
    (ms); the first solve's attitude (None if it failed). Runs in a side's process."""
    from skyfix.pipeline import solve_centroids

    times, first = [], None
    for _ in range(reps):
        t = time.perf_counter()
        sol = solve_centroids(xy, width, height)
        times.append((time.perf_counter() - t) * 1e3)
        if first is None:
            first = sol
    solved = first.status == "solved"
    A = np.asarray(first.attitude_at_pixel((width - 1) / 2.0, (height - 1) / 2.0), float) if solved else None
    return {"times_ms": times, "solved": solved, "A": A}


def _row(answers: list[dict], sets: list) -> dict:
    first = [a["times_ms"][0] for a in answers]
    best = [min(a["times_ms"]) for a in answers]
    wrong = 0
    for a, s in zip(answers, sets, strict=True):
        if a["solved"]:
            wrong += is_wrong(boresight_error_arcsec(a["A"], s.A_true), roll_error_deg(a["A"], s.A_true))
    return {"n": len(answers), "solved": sum(a["solved"] for a in answers), "wrong": wrong,
            "p50": median(first), "p99": pct(first, 99.0), "max": pct(first, 100.0),
            "best_p50": median(best), "best_p99": pct(best, 99.0)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=300, help="sets per configuration (suite b's first n)")
    ap.add_argument("--best-of", type=int, default=3, help="solves of each set in a row")
    ap.add_argument("--against", metavar="REF", help="also run commit REF, interleaved")
    ap.add_argument("--batch", type=int, default=10, help="sets a side solves before the other's turn")
    args = ap.parse_args(argv)

    from against import ref_side, tree_side
    from remote import Worker

    sides = [tree_side()] + ([ref_side(args.against)] if args.against else [])
    workers = [Worker(side.label, side.src) for side in sides]
    try:
        for spec in configs(args.n):
            if spec.n_false != 8:
                continue
            sets, _ = centroid_sets(spec)
            for w in workers:  # warm-up: kernels, catalogue and every band's database loaded
                w.call("default_path:solve_default", sets[0].xy, spec.width, spec.height)
            answers: dict[str, list] = {side.label: [] for side in sides}
            pairs = list(zip(sides, workers, strict=True))
            for k, start in enumerate(range(0, len(sets), args.batch)):
                chunk = sets[start:start + args.batch]
                for side, w in (pairs[::-1] if k % 2 else pairs):
                    calls = [((s.xy, spec.width, spec.height, args.best_of), {}) for s in chunk]
                    answers[side.label] += w.many("default_path:solve_default", calls)
            rows = {label: _row(a, sets) for label, a in answers.items()}
            print(f"\nsuite b {spec.label}, no FOV, no database (every default band), {len(sets)} sets:")
            print(f"{'side':>18} {'solved':>7} {'wrong':>5} {'p50 ms':>7} {'p99 ms':>7} {'max ms':>7}"
                  f" {'best p50':>8} {'best p99':>8}")
            for label, r in rows.items():
                print(f"{label:>18} {r['solved']:>7} {r['wrong']:>5} {r['p50']:7.2f} {r['p99']:7.2f} "
                      f"{r['max']:7.1f} {r['best_p50']:8.2f} {r['best_p99']:8.2f}")
            if len(sides) == 2:
                a, b = rows[sides[0].label], rows[sides[1].label]
                r = {key: ratio(a[key], b[key]) for key in ("p50", "p99", "max", "best_p50", "best_p99")}
                print(f"{'tree / ref':>18} {'':>13} {r['p50']:7.2f} {r['p99']:7.2f} {r['max']:7.2f} "
                      f"{r['best_p50']:8.2f} {r['best_p99']:8.2f}")
    finally:
        for w in workers:
            w.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
