"""Suite h's probes, each run in a fresh process that imports one side's skyfix (``PYTHONPATH``).

    python benchmarks/startup_probe.py in-process IMAGE N     # import, then N solves: ms each
    python benchmarks/startup_probe.py warm IMAGE             # one solve (compiles the solve path)
    python benchmarks/startup_probe.py paths                  # the paths first-use can probe
    python benchmarks/startup_probe.py first-use PATH IMAGE JPEG

``first-use`` solves IMAGE (the solve path, compiled beforehand), then calls PATH twice and
reports both wall times: the first use's extra cost is the first less the second. The paths:
``jpeg`` (solve a JPEG file), ``uint16`` (``extract_centroids`` on the raw 16-bit array),
``hint`` (solve with an attitude hint and the FOV), ``tracker`` (three frames through a new
``Tracker``: lost, acquiring, tracking), ``centroid-<name>`` (``extract_centroids`` with each
centroider), ``method-<name>`` (``solve_centroids`` with each identification method, FOV
given). Only APIs that skyfix had at 1a5d56b are called, as an older side runs this too.
The answer is one JSON line on stdout after ``PROBE-RESULT``.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

MARK = "PROBE-RESULT "
CENTROIDERS = ("com", "iwcog", "gaussian")


def _ms(t0: float) -> float:
    return 1e3 * (time.perf_counter() - t0)


def in_process(image: str, n: int) -> dict:
    t0 = time.perf_counter()
    import skyfix

    out = {"import_ms": _ms(t0), "solve_ms": [], "solved": [], "skyfix_file": skyfix.__file__}
    for _ in range(n):
        t = time.perf_counter()
        sol = skyfix.solve(image)
        out["solve_ms"].append(_ms(t))
        out["solved"].append(sol.status == "solved")
    return out


def warm(image: str) -> dict:
    return in_process(image, 1)


def methods() -> list[str]:
    """Identification methods other than the default, one name per method (aliases dropped)."""
    from skyfix.identify import DEFAULT_METHOD, METHODS

    seen = {id(METHODS[DEFAULT_METHOD])}
    out = []
    for name, fn in METHODS.items():
        if id(fn) not in seen:
            seen.add(id(fn))
            out.append(name)
    return out


def paths() -> dict:
    return {"paths": ["jpeg", "uint16", "hint", "tracker"] + [f"centroid-{c}" for c in CENTROIDERS]
            + [f"method-{m}" for m in methods()]}


def _raw(image: str) -> np.ndarray:
    from PIL import Image

    with Image.open(image) as im:
        return np.asarray(im)


def first_use(path: str, image: str, jpeg: str) -> dict:
    import skyfix
    from skyfix.detect import extract_centroids
    from skyfix.io import read_image

    t = time.perf_counter()
    sol = skyfix.solve(image)
    warm_ms = _ms(t)
    if sol.status != "solved":
        raise RuntimeError(f"{image} not solved: {sol.reason}")
    data = read_image(image)
    if path == "jpeg":
        def run():
            return skyfix.solve(jpeg).status
    elif path == "uint16":
        raw = _raw(image)
        if raw.dtype != np.uint16:
            raw = (raw.astype(np.float64) * 257).astype(np.uint16)

        def run():
            return len(extract_centroids(raw))
    elif path == "hint":
        def run():
            return skyfix.solve(image, fov_deg=sol.fov_deg,
                                attitude_hint=(sol.ra_deg, sol.dec_deg, sol.roll_deg)).method
    elif path == "tracker":
        from skyfix.track import Tracker

        def run():
            tracker = Tracker(sol.camera)
            return [tracker.update(data, t_s).mode for t_s in (0.0, 0.1, 0.2)]
    elif path.startswith("centroid-"):
        name = path.split("-", 1)[1]

        def run():
            return len(extract_centroids(data, centroid=name))
    elif path.startswith("method-"):
        name = path.split("-", 1)[1]
        xy = np.asarray(extract_centroids(data).xy, float)
        h, w = data.shape

        def run():
            return skyfix.solve_centroids(xy, w, h, fov_deg=sol.fov_deg, identify_method=name).status
    else:
        raise ValueError(f"unknown path {path!r}")
    times, answers = [], []
    for _ in range(2):
        t = time.perf_counter()
        answers.append(run())
        times.append(_ms(t))
    return {"path": path, "warm_solve_ms": warm_ms, "first_ms": times[0], "later_ms": times[1],
            "answer": repr(answers[-1])[:200], "skyfix_file": skyfix.__file__}


def main(argv: list[str]) -> int:
    probe, args = argv[0], argv[1:]
    if probe == "in-process":
        out = in_process(args[0], int(args[1]))
    elif probe == "warm":
        out = warm(args[0])
    elif probe == "paths":
        out = paths()
    elif probe == "first-use":
        out = first_use(*args[:3])
    else:
        raise SystemExit(f"unknown probe {probe!r}")
    sys.stdout.write(MARK + json.dumps(out) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
