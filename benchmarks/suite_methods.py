"""Suite (g): the identification methods' speed from centroids (issue 11), each against the
default in the same run.

Every method registered in :data:`skyfix.identify.METHODS` identifies the same simulated
centroid sets (``skyfix.analysis.synthetic_centroids``: Hipparcos to magnitude 6.5, 1280×960,
15°, σ = 0.5 px, 2 false stars), once with the FOV known to 10 % and once with the calibrated
camera. Methods run interleaved field by field (the machine's load falls on all alike); the
first pass over the fields warms every method's tables and compiled kernels and is not timed.
Reported per method: solved, wrong (boresight > 60″ or roll > 0.5°), median and p99 time, and
the median's ratio to the default's (target: ≤ 10×; the default's p99 ≤ 5 ms).

    python benchmarks/suite_methods.py [--fields 40] [--methods a,b]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import median, write_json  # noqa: E402
from report import print_table, say  # noqa: E402

W, H, FOV = 1280, 960, 15.0


def _fields(n: int) -> list:
    from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
    from skyfix.camera import Camera
    from skyfix.catalog import load_hipparcos

    cat = load_hipparcos()
    cam = Camera.from_fov(W, H, FOV)
    return cam, [synthetic_centroids(cam, A, cat, mag_limit=6.5, sigma_px=0.5, n_false=2, rng=i)
                 for i, A in enumerate(random_attitudes(n, 2026))]


def _wrong(A_true: np.ndarray, A: np.ndarray) -> bool:
    from skyfix.analysis.truth import judge_error
    from skyfix.attitude import attitude_error

    return judge_error(attitude_error(A_true, A)).wrong


def run(n_fields: int = 40, methods: list[str] | None = None) -> dict:
    from skyfix.identify import DEFAULT_METHOD, METHODS, default_database, identify

    db = default_database(progress=False)
    names = [m for m in (methods or METHODS) if m != "hash"]
    if DEFAULT_METHOD not in names:
        names.insert(0, DEFAULT_METHOD)
    cam, fields = _fields(n_fields)
    rows = {}
    for scale in ("fov", "camera"):
        kw = {"fov_deg": FOV} if scale == "fov" else {"camera": cam}
        times = {m: [] for m in names}
        solved = dict.fromkeys(names, 0)
        wrong = dict.fromkeys(names, 0)
        for rep in range(2):
            for f in fields:
                for m in names:
                    t0 = time.perf_counter()
                    ident = identify(f.xy, W, H, method=m, database=db, **kw)
                    dt = 1e3 * (time.perf_counter() - t0)
                    if rep == 0:
                        continue
                    times[m].append(dt)
                    if ident.success:
                        solved[m] += 1
                        wrong[m] += _wrong(f.A_icrs_to_cam, ident.A_icrs_to_cam)
        base = median(times[DEFAULT_METHOD])
        for m in names:
            rows[f"{m} ({scale})"] = {"method": m, "scale": scale, "fields": len(fields), "solved": solved[m],
                                      "wrong": wrong[m], "median_ms": median(times[m]),
                                      "p99_ms": float(np.percentile(times[m], 99)),
                                      "ratio_to_default": median(times[m]) / base}
    print_table(f"identification methods from centroids ({W}×{H}, {FOV:g}°, σ 0.5 px, 2 false stars)",
                ["method", "solved", "wrong", "median ms", "p99 ms", "× default"],
                [[k, f"{v['solved']}/{v['fields']}", v["wrong"], v["median_ms"], v["p99_ms"],
                  v["ratio_to_default"]] for k, v in rows.items()],
                note="targets: each median ≤ 10× the default's; the default's p99 ≤ 5 ms")
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--fields", type=int, default=40)
    ap.add_argument("--methods", type=str, default=None, help="comma-separated names (default: all)")
    args = ap.parse_args(argv)
    say("[bold]suite g: identification methods[/bold]")
    write_json("methods", run(args.fields, args.methods.split(",") if args.methods else None))
    return 0


if __name__ == "__main__":
    sys.exit(main())
