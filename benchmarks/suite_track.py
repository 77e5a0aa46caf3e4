"""Suite (f): tracking speed and accuracy (issue 9) — skyfix alone, as no peer tracks.

One tracking update (prediction, 16 windows, centroids, match, attitude, filter) against a
lost-in-space solve of the same frame, in the same run: simulated 1280×960 frames of a 15°
camera at 10 Hz (``skyfix.simulate.render_sequence``, the generic sensor's noise), at rest and
at 1 °/s. Every frame is tracked by a fresh :class:`skyfix.track.Tracker` per repeat (the first
repeat warms up and is not timed); then every tracked frame is solved lost in space
(:func:`skyfix.solve` with the same camera and epoch). Two loops, not interleaved, so each runs
as it would in flight (a lost-in-space solve between two tracking updates would evict the
tracker's data from the caches). Medians; the targets: ≤ 1 ms a tracking update and ≥ 20× a
lost-in-space solve. Boresight errors of both against the truth are reported beside.

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

from common import median, now_ms, write_json  # noqa: E402
from report import print_table, say  # noqa: E402

RATE_AXIS = np.array([0.6, -0.75, 0.28]) / np.linalg.norm([0.6, -0.75, 0.28])
EPOCH = 2025.5


def _frames(rate_dps: float, n: int) -> list:
    from skyfix.camera import Camera
    from skyfix.geometry import attitude_from_radec_roll
    from skyfix.simulate import render_sequence

    camera = Camera.from_fov(1280, 960, 15.0)
    A0 = attitude_from_radec_roll(math.radians(84.0), math.radians(-2.0), math.radians(20.0))
    rate = np.radians(RATE_AXIS * rate_dps) if rate_dps else None
    frames = render_sequence(A0, camera, n_frames=n, fps=10.0, rate_rad_s=rate, epoch=EPOCH, seed=3)
    return camera, list(frames)


def _boresight_arcsec(frame, sol) -> float:
    from skyfix.attitude import attitude_error
    from skyfix.geometry import attitude_from_quaternion

    e = attitude_error(attitude_from_quaternion(frame.truth["quaternion_xyzw"]), sol.A_icrs_to_cam)
    return math.degrees(math.hypot(e[0], e[1])) * 3600


def run_case(rate_dps: float, n_frames: int, repeats: int) -> dict:
    import skyfix
    from skyfix.track import Tracker

    camera, frames = _frames(rate_dps, n_frames)
    track_ms, lis_ms, track_err, lis_err = [], [], [], []
    for rep in range(repeats + 1):
        tracker = Tracker(camera, epoch=EPOCH)
        tracked = []
        for f in frames:
            t0 = time.perf_counter()
            sol = tracker.update(f.image, f.truth["t_s"])
            dt = 1e3 * (time.perf_counter() - t0)
            if sol.mode == "tracking" and rep > 0:
                track_ms.append(dt)
                tracked.append(f)
                if rep == 1:
                    track_err.append(_boresight_arcsec(f, sol))
        for f in tracked:
            t0 = now_ms()
            sol = skyfix.solve(f.image, camera=camera, epoch=EPOCH)
            lis_ms.append(now_ms() - t0)
            if rep == 1:
                lis_err.append(_boresight_arcsec(f, sol) if sol.solved else float("nan"))
    t, s = median(track_ms), median(lis_ms)
    return {"rate_dps": rate_dps, "tracked_frames": len(track_err), "track_ms_median": t,
            "track_ms_p90": float(np.percentile(track_ms, 90)), "lis_ms_median": s, "speedup": s / t,
            "track_boresight_arcsec_median": median(track_err),
            "lis_boresight_arcsec_median": median(lis_err)}


def run(n_frames: int = 20, repeats: int = 5, rates=(0.0, 1.0)) -> dict:
    rows = {f"{r:g} deg/s": run_case(r, n_frames, repeats) for r in rates}
    print_table("tracking: one update vs lost in space on the same frames (1280×960, 15°, 10 Hz)",
                ["case", "frames", "update ms", "p90 ms", "lost-in-space ms", "speed-up", "bore ″ track",
                 "bore ″ LIS"],
                [[k, v["tracked_frames"], v["track_ms_median"], v["track_ms_p90"], v["lis_ms_median"],
                  v["speedup"], v["track_boresight_arcsec_median"], v["lis_boresight_arcsec_median"]]
                 for k, v in rows.items()],
                note="targets: update ≤ 1 ms, ≥ 20× lost in space; medians over repeats")
    return rows


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
