"""Speed benchmark of the simulator (issue 3 targets: 1 Mpx, 100 stars, all noise ≤ 50 ms median;
a 10-frame smeared sequence ≤ 1 s).

    python -m skyfix.simulate.bench [--repeats 15]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from skyfix.camera import Camera
from skyfix.catalog import Catalog
from skyfix.geometry import attitude_from_radec_roll
from skyfix.simulate.optics import Optics
from skyfix.simulate.render import render
from skyfix.simulate.sensor import Sensor
from skyfix.simulate.sequence import render_sequence


def _timed(fn, repeats: int) -> tuple[float, float]:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times)), 1e3 * float(np.min(times))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args(argv)
    camera = Camera.from_fov(1024, 1024, 15.0)
    A = attitude_from_radec_roll(1.0, 0.3, 0.2)
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 1023, (100, 2))
    catalog = Catalog(np.arange(100), camera.pixel_to_ray(xy) @ A, rng.uniform(2, 7, 100).astype(np.float32),
                      np.zeros(100), np.zeros(100), 2025.0)
    kw = dict(sensor=Sensor.from_preset("has2"), optics=Optics.from_preset("has2"), exposure_s=0.1,
              epoch=2025.0, catalog=catalog, hot_pixels=50, cosmic_rays=3)
    rate = [0.0, math.radians(0.3), 0.0]
    render(A, camera, **kw)  # compile the numba kernels
    cases = [
        ("1 Mpx, 100 stars, all noise", lambda: render(A, camera, seed=1, **kw), args.repeats),
        ("1 Mpx, 100 stars, noise off", lambda: render(A, camera, seed=1, noise=False, **kw), args.repeats),
        ("1 Mpx, 100 stars, smeared 0.3°/s", lambda: render(A, camera, seed=1, rate_rad_s=rate, **kw),
         args.repeats),
        ("10-frame smeared sequence", lambda: list(render_sequence(A, camera, n_frames=10, fps=10.0,
                                                                     rate_rad_s=rate, seed=1, **kw)),
         max(3, args.repeats // 3)),
    ]
    for name, fn, n in cases:
        med, best = _timed(fn, n)
        print(f"{name:36s} median {med:7.1f} ms   best {best:7.1f} ms   ({n} runs)")


if __name__ == "__main__":
    main()
