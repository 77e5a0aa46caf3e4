"""Issue 11's first target: every identification method on the same noise-free fields with at
least five stars, with the camera given and with the FOV only: solved (right attitude), wrong.

    .venv/bin/python benchmarks/noise_free_fields.py --fields 300 --fov 15

Fields: 1280x960, random attitudes (``random_attitudes(fields, 4242)``), Hipparcos to Hp 6.5 at
the FOV given, no centroid noise; a field with fewer than 5 stars is skipped. Wrong: boresight
beyond 60" or roll beyond 0.5 deg from the truth.
"""

from __future__ import annotations

import argparse
import collections
import math

from rich.progress import track

from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
from skyfix.attitude import attitude_error
from skyfix.camera import Camera
from skyfix.catalog import load_hipparcos
from skyfix.identify import METHODS, default_database, identify

W, H = 1280, 960


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fields", type=int, default=300)
    ap.add_argument("--fov", type=float, default=15.0)
    args = ap.parse_args()
    db, catalog = default_database(), load_hipparcos()
    cam = Camera.from_fov(W, H, args.fov)
    names = [m for m in METHODS if m != "hash"]  # "hash" is the default's other name
    count: collections.Counter = collections.Counter()
    failed: dict = collections.defaultdict(list)
    fields = 0
    for i, A in enumerate(track(random_attitudes(args.fields, 4242), description="fields")):
        field = synthetic_centroids(cam, A, catalog, mag_limit=6.5, sigma_px=0.0, rng=i)
        if len(field.xy) < 5:
            continue
        fields += 1
        for given, kw in (("camera", {"camera": cam}), ("fov", {"fov_deg": args.fov})):
            for m in names:
                r = identify(field.xy, W, H, method=m, database=db, **kw)
                wrong = False
                if r.success:
                    e = attitude_error(A, r.A_icrs_to_cam)
                    wrong = math.hypot(e[0], e[1]) > math.radians(60 / 3600) or abs(e[2]) > math.radians(0.5)
                    count[(m, given, "wrong")] += wrong
                count[(m, given, "solved")] += r.success and not wrong
                if not r.success:
                    failed[(m, given)].append(f"field {i} ({len(field.xy)} stars): {r.reason[:70]}")
    print(f"{args.fov:g} deg, noise-free, fields with >= 5 stars: {fields}")
    print("| method | camera: solved | wrong | FOV only: solved | wrong |\n|---|---|---|---|---|")
    for m in names:
        cells = [f"{count[(m, g, 'solved')]} ({100 * count[(m, g, 'solved')] / max(fields, 1):.1f} %) | "
                 f"{count[(m, g, 'wrong')]}" for g in ("camera", "fov")]
        print(f"| {m} | {cells[0]} | {cells[1]} |")
    for (m, g), why in failed.items():
        print(f"{m}, {g}: " + "; ".join(why[:3]))


if __name__ == "__main__":
    main()
