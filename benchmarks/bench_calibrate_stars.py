"""Star-field calibration's speed: ``skyfix.calibration.stars.calibrate_stars`` on 12 rendered
1 MP frames (1280×960, 24°, issue 25's distorted camera), from the frames in memory to the
fitted camera — extraction, 12 blind solves, the joint fits along the model ladder and the
re-identification rounds — timed in one process after a warm-up run (kernels compiled, the
catalogue and pattern database loaded), the median of ``--repeat`` runs kept.

    PYTHONPATH=src python benchmarks/bench_calibrate_stars.py [--repeat 3] [--max-stars 600]

Prints the stages' times and the camera's errors against the truth.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--max-stars", type=int, default=600)
    parser.add_argument("--exposure", type=float, default=0.3)
    args = parser.parse_args(argv)

    from skyfix.calibration.stars import calibrate_frames, prepare_frames
    from skyfix.camera import Camera
    from skyfix.geometry import attitude_from_radec_roll
    from skyfix.simulate import render

    truth = Camera.from_fov(1280, 960, 24.0).replace(cx=660.5, cy=466.5, k1=-0.3686, k2=0.3148, p1=-0.0023,
                                                     p2=0.0003)
    rng = np.random.default_rng(1)
    attitudes = [attitude_from_radec_roll(rng.uniform(0, 2 * math.pi), math.asin(rng.uniform(-1, 1)),
                                          rng.uniform(0, 2 * math.pi)) for _ in range(12)]
    frames = [render(A, truth, sensor="generic", optics="generic", exposure_s=args.exposure, epoch=2025.0,
                     seed=100 + i).image for i, A in enumerate(attitudes)]
    calibrate_frames(prepare_frames(frames[:3], max_stars=args.max_stars))  # warm-up
    prep, fit, total = [], [], []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        prepared = prepare_frames(frames, max_stars=args.max_stars)
        t1 = time.perf_counter()
        cal = calibrate_frames(prepared)
        t2 = time.perf_counter()
        prep.append(t1 - t0)
        fit.append(t2 - t1)
        total.append(t2 - t0)
    cam = cal.camera
    print(f"12 frames 1280x960: total {statistics.median(total):.2f} s (extract + solve "
          f"{statistics.median(prep):.2f} s, joint fit + re-identification {statistics.median(fit):.2f} s), "
          f"median of {args.repeat}")
    print(f"  {cal.fit.n_stars} stars, {cal.rounds} rounds, model {' + '.join(cal.fit.params)}")
    print(f"  fx {cam.fx / truth.fx - 1:+.2e} relative, cx {cam.cx - truth.cx:+.3f} px, "
          f"cy {cam.cy - truth.cy:+.3f} px")


if __name__ == "__main__":
    main()
