"""Speed of ``skyfix.simulate.render``: ms per megapixel, this tree's detector against another
commit's, in the same run (issue 27 part 5, throughput).

Run: ``PYTHONPATH=src .venv/bin/python benchmarks/bench_render.py [--against main] [--repeat N]
[--camera generic]``

The other commit's ``src/skyfix/simulate/sensor.py`` (``git show REF:…``) is loaded as a module
of its own and its ``apply_detector`` swapped into ``render`` for the "before" rows, so both
renders share everything but the detector (catalogue, PSF, truth). Whole renders and the
detector alone on the same expected image are timed alternately, before and after, after one
warm-up each (numba compiles and caches on first use); medians over ``--repeat`` calls. The
machine is shared: compare the two columns of one run, not runs.
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def sensor_at(ref: str):
    """``skyfix.simulate.sensor`` as it is at commit ``ref``, as a separate module."""
    text = subprocess.run(["git", "-C", str(ROOT), "show", f"{ref}:src/skyfix/simulate/sensor.py"],
                          check=True, capture_output=True, text=True).stdout
    folder = Path(tempfile.mkdtemp(prefix="skyfix-sensor-"))
    path = folder / "sensor_before.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location("sensor_before", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["sensor_before"] = module
    spec.loader.exec_module(module)
    return module


def streams(seed: int) -> dict:
    children = np.random.SeedSequence(seed).spawn(4)
    names = ("shot", "dark", "read", "ktc")
    return {k: np.random.default_rng(s) for k, s in zip(names, children, strict=True)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", default="main", help="the commit to compare with (default main)")
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--camera", default="generic", help="a camera preset (default generic, 1280 × 960)")
    args = ap.parse_args()

    from skyfix.geometry import attitude_from_radec_roll
    from skyfix.simulate import render, resolve_setup
    from skyfix.simulate.sensor import apply_detector

    render_module = sys.modules["skyfix.simulate.render"]  # the package's ``render`` is the function
    before = sensor_at(args.against)
    camera, sensor, _, exposure = resolve_setup(args.camera, None, None, None)
    mp = camera.width * camera.height / 1e6
    A = attitude_from_radec_roll(1.4, 0.1, 0.3)
    expected = render(A, args.camera, epoch=2025.0, seed=1).expected_e
    detectors = {"before": before.apply_detector, "after": apply_detector}

    def whole(which: str, seed: int) -> float:
        render_module.apply_detector = detectors[which]
        try:
            t0 = time.perf_counter()
            render(A, args.camera, epoch=2025.0, seed=seed)
            return (time.perf_counter() - t0) * 1e3
        finally:
            render_module.apply_detector = apply_detector

    def detector(which: str, seed: int) -> float:
        t0 = time.perf_counter()
        detectors[which](expected, sensor, exposure, streams(seed))
        return (time.perf_counter() - t0) * 1e3

    times: dict[tuple[str, str], list[float]] = {}
    for what, fn in (("render", whole), ("detector", detector)):
        for which in detectors:
            fn(which, 0)  # warm-up: compile or load the kernels
        for k in range(args.repeat):
            for which in detectors:
                times.setdefault((what, which), []).append(fn(which, k + 1))
    print(f"{args.camera}: {camera.width} × {camera.height} ({mp:.2f} MP), medians of {args.repeat}, "
          f"before = {args.against}")
    print(f"{'':10s} {'before ms':>10s} {'after ms':>10s} {'before ms/MP':>13s} {'after ms/MP':>12s} "
          f"{'ratio':>6s}")
    for what in ("render", "detector"):
        b, a = (float(np.median(times[(what, w)])) for w in ("before", "after"))
        print(f"{what:10s} {b:10.1f} {a:10.1f} {b / mp:13.1f} {a / mp:12.1f} {b / a:6.2f}")


if __name__ == "__main__":
    main()
