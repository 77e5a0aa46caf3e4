"""Suite (f): tracking speed and accuracy (issue 9) — skyfix alone, as no peer tracks.

One tracking update (prediction, 16 windows, centroids, match, attitude, filter) against a
lost-in-space solve of the same frame, in the same run: simulated 1280×960 frames of a 15°
camera at 10 Hz (``skyfix.simulate.render_sequence``, the generic sensor's noise), at rest and
at 1 °/s. Every frame is tracked by a fresh :class:`skyfix.track.Tracker` per repeat (the first
repeat warms up and is not timed); then every tracked frame is solved lost in space
(:func:`skyfix.solve` with the same camera and epoch). Two loops, not interleaved, so each runs
as it would in flight (a lost-in-space solve between two tracking updates would evict the
tracker's data from the caches). Medians; the targets: ≤ 1 ms a tracking update and ≥ 20× a
lost-in-space solve. Boresight errors of both against the truth are reported beside. With
``--against REF`` each side's worker runs the rounds on the same frames, alternately.

    python benchmarks/suite_track.py [--frames 20] [--repeats 5]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import median, now_ms, pct, write_json  # noqa: E402
from report import print_table, say  # noqa: E402

RATE_AXIS = np.array([0.6, -0.75, 0.28]) / np.linalg.norm([0.6, -0.75, 0.28])
EPOCH = 2025.5


def _frames(rate_dps: float, n: int) -> list[tuple[np.ndarray, float, list]]:
    """The simulated frames: (image, t_s, true quaternion xyzw) — plain data, the same for both
    sides of ``--against`` (made once, by the working tree's simulator)."""
    from skyfix.geometry import attitude_from_radec_roll
    from skyfix.simulate import render_sequence

    A0 = attitude_from_radec_roll(math.radians(84.0), math.radians(-2.0), math.radians(20.0))
    rate = np.radians(RATE_AXIS * rate_dps) if rate_dps else None
    frames = render_sequence(A0, _camera(), n_frames=n, fps=10.0, rate_rad_s=rate, epoch=EPOCH, seed=3)
    return [(f.image, float(f.truth["t_s"]), list(f.truth["quaternion_xyzw"])) for f in frames]


def _camera():
    from skyfix.camera import Camera

    return Camera.from_fov(1280, 960, 15.0)


def _boresight_arcsec(q_xyzw, A: np.ndarray) -> float:
    from skyfix.attitude import attitude_error
    from skyfix.geometry import attitude_from_quaternion

    e = attitude_error(attitude_from_quaternion(q_xyzw), A)
    return math.degrees(math.hypot(e[0], e[1])) * 3600


def one_round(frames: list, timed: bool) -> dict:
    """Track every frame with a fresh :class:`skyfix.track.Tracker`, then (when ``timed``) solve
    each tracked frame lost in space: per-call ms and the attitudes. Runs in a ``--against``
    worker too, so it calls only what skyfix had at 1a5d56b."""
    import skyfix
    from skyfix.track import Tracker

    camera = _camera()
    tracker = Tracker(camera, epoch=EPOCH)
    out = {"track_ms": [], "track_index": [], "track_A": [], "lis_ms": [], "lis_A": []}
    for i, (image, t_s, _) in enumerate(frames):
        t0 = time.perf_counter()
        sol = tracker.update(image, t_s)
        dt = 1e3 * (time.perf_counter() - t0)
        if sol.mode == "tracking":
            out["track_ms"].append(dt)
            out["track_index"].append(i)
            out["track_A"].append(np.asarray(sol.A_icrs_to_cam, float))
    if timed:
        for i in out["track_index"]:
            t0 = now_ms()
            sol = skyfix.solve(frames[i][0], camera=camera, epoch=EPOCH)
            out["lis_ms"].append(now_ms() - t0)
            out["lis_A"].append(np.asarray(sol.A_icrs_to_cam, float) if sol.solved else None)
    return out


def _caller(tool):
    worker = getattr(tool, "worker", None)
    if worker is not None:
        return lambda frames, timed: worker.call("suite_track:one_round", frames, timed)
    return one_round


def run_case(rate_dps: float, n_frames: int, repeats: int, tools: dict | None = None) -> dict:
    """One case on each skyfix side (default: this process's skyfix as ``skyfix``); with two
    sides, the rounds alternate between them (A B, B A, ...). The first round warms up."""
    sides = {name: _caller(t) for name, t in (tools or {"skyfix": None}).items()
             if t is None or getattr(t, "is_skyfix", False)}
    frames = _frames(rate_dps, n_frames)
    acc = {name: {"track_ms": [], "lis_ms": [], "track_err": [], "lis_err": []} for name in sides}
    names = list(sides)
    for rep in range(repeats + 1):
        for name in (names[::-1] if rep % 2 else names):
            r = sides[name](frames, rep > 0)
            if rep == 0:
                continue
            a = acc[name]
            a["track_ms"] += r["track_ms"]
            a["lis_ms"] += r["lis_ms"]
            if rep == 1:
                a["track_err"] = [_boresight_arcsec(frames[i][2], A)
                                  for i, A in zip(r["track_index"], r["track_A"], strict=True)]
                a["lis_err"] = [_boresight_arcsec(frames[i][2], A) if A is not None else float("nan")
                                for i, A in zip(r["track_index"], r["lis_A"], strict=True)]
    out = {}
    for name, a in acc.items():
        t, s = median(a["track_ms"]), median(a["lis_ms"])
        out[name] = {"rate_dps": rate_dps, "tracked_frames": len(a["track_err"]), "track_ms_median": t,
                     "track_ms_p90": pct(a["track_ms"], 90.0),
                     "lis_ms_median": s, "speedup": s / t if t > 0 else float("nan"),
                     "track_boresight_arcsec_median": median(a["track_err"]),
                     "lis_boresight_arcsec_median": median(a["lis_err"])}
    return out


def run(n_frames: int = 20, repeats: int = 5, rates=(0.0, 1.0), tools: dict | None = None) -> dict:
    """``{case: the first side's figures, plus "by_side": every side's}`` (the first side is the
    working tree: ``skyfix``)."""
    cases = {f"{r:g} deg/s": run_case(r, n_frames, repeats, tools) for r in rates}
    rows = {case: {**next(iter(by.values())), "by_side": by} for case, by in cases.items()}
    table = [[case if len(by) == 1 else f"{case} {name}", v["tracked_frames"], v["track_ms_median"],
              v["track_ms_p90"], v["lis_ms_median"], v["speedup"], v["track_boresight_arcsec_median"],
              v["lis_boresight_arcsec_median"]]
             for case, by in cases.items() for name, v in by.items()]
    print_table("tracking: one update vs lost in space on the same frames (1280×960, 15°, 10 Hz)",
                ["case", "frames", "update ms", "p90 ms", "lost-in-space ms", "speed-up", "bore ″ track",
                 "bore ″ LIS"], table,
                note="targets: update ≤ 1 ms, ≥ 20× lost in space; medians over repeats")
    return rows


def against_measures(results: dict, tree: str, ref: str) -> list:
    """Tree vs REF per case (``against.Measure`` rows)."""
    from against import Measure

    out = []
    for case, v in results.items():
        by = v.get("by_side", {})
        a, b = by.get(tree), by.get(ref)
        if not (a and b):
            continue
        out += [Measure("f", f"{case}: tracking update median ms", a["track_ms_median"],
                        b["track_ms_median"]),
                Measure("f", f"{case}: tracking update p90 ms", a["track_ms_p90"], b["track_ms_p90"], "info"),
                Measure("f", f"{case}: lost in space median ms", a["lis_ms_median"], b["lis_ms_median"]),
                Measure("f", f"{case}: speed-up", a["speedup"], b["speedup"], "info", "higher"),
                Measure("f", f"{case}: tracked frames", a["tracked_frames"], b["tracked_frames"], "count",
                        "higher"),
                Measure("f", f"{case}: tracking boresight ″", a["track_boresight_arcsec_median"],
                        b["track_boresight_arcsec_median"])]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    say("[bold]suite f: tracking[/bold]")
    write_json("tracking", run(args.frames, args.repeats))
    return 0


if __name__ == "__main__":
    sys.exit(main())
