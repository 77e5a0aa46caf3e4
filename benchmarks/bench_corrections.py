"""The per-solve cost of issue 24's corrections: the Earth's state for a time, the apparent
directions of a solve's catalogue stars, the bright bodies, the times from headers.

Run: ``.venv/bin/python benchmarks/bench_corrections.py [--stars 300] [--repeat 200]``

Each figure is the median and the best of ``--repeat`` calls, in µs, all calls of one kind in a
row (the machine is shared: the best is the steadier figure). ``apparent_directions`` with the
frame made anew each call is the per-solve cost once the time's ephemeris is cached
(the issue's goal: 0.2 ms); ``earth_state, new time`` is ERFA ``epv00`` itself, paid once per
time; astropy's ``get_body_barycentric_posvel`` is there for scale.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from skyfix.corrections import (
    aberrate,
    apparent_directions,
    apparent_frame,
    body_angles,
    earth_state,
    observer_from_state,
)
from skyfix.geometry import normalize
from skyfix.obstime import ObservationTime, parse_time, time_from_fits_header


def timed(f, repeat: int) -> tuple[float, float]:
    """(median, best) of ``repeat`` calls of ``f``, µs."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) * 1e6, float(np.min(times)) * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--stars", type=int, default=300)
    parser.add_argument("--repeat", type=int, default=200)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    stars = normalize(rng.normal(size=(args.stars, 3)))
    parallax = rng.uniform(0.0, 1e-7, args.stars)
    observer = observer_from_state([7000.0, 0.0, 0.0], [0.0, 7.5, 0.0])
    t = parse_time("2026-03-01T22:00:00Z")
    frame = apparent_frame(t, observer)
    fresh = iter(2461041.5 + rng.uniform(0.0, 3650.0, 10 * args.repeat))

    from astropy.coordinates import get_body_barycentric_posvel
    from astropy.time import Time
    from astropy.utils import iers

    iers.conf.auto_download = False
    at = Time(t.jd_tt, format="jd", scale="tt")
    rows = [
        ("earth_state, new time (ERFA epv00)", lambda: earth_state(next(fresh))),
        ("earth_state, cached time", lambda: earth_state(t.jd_tt)),
        ("astropy get_body_barycentric_posvel", lambda: get_body_barycentric_posvel("earth", at)),
        ("apparent_frame, cached time", lambda: apparent_frame(t, observer)),
        (f"aberrate, {args.stars} stars", lambda: aberrate(stars, frame.velocity_km_s)),
        (f"apparent_directions, {args.stars} stars", lambda: apparent_directions(stars, frame)),
        ("  + parallax", lambda: apparent_directions(stars, frame, parallax)),
        (f"per solve: frame + apparent_directions, {args.stars} stars",
         lambda: apparent_directions(stars, apparent_frame(t, observer), parallax)),
        ("body_angles, new time",
         lambda: body_angles(stars[0], ObservationTime(next(fresh), "", ""), observer)),
        ("parse_time ISO", lambda: parse_time("2026-03-01T22:00:00.250+02:00")),
        ("time_from_fits_header", lambda: time_from_fits_header({"DATE-OBS": "2026-03-01T22:00:00",
                                                                 "EXPTIME": 10.0})),
    ]
    print(f"{'call':58s} {'median µs':>10s} {'best µs':>9s}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, f in rows:
            f()  # imports, caches
            median, best = timed(f, args.repeat)
            print(f"{name:58s} {median:10.1f} {best:9.1f}")


if __name__ == "__main__":
    main()
