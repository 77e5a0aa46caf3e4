"""The final fit alone: its time per frame and its boresight error, on frames of a few kinds.

Each frame is a synthetic centroid field (``skyfix.analysis.synthetic_centroids``) from a known
camera and attitude, or the centroids skyfix extracts from an image of suite c's independent
renderer (``benchmarks/render.py``: kinds ``r8``, ``r15``, ``r30``), identified once
(``skyfix.identify.identify``, with or without the FOV); then ``skyfix.final_fit.final_fit``
(no camera file) is timed ``--repeat`` times on that identification and the median kept.
Reported per kind: frames identified, the median (and 90th percentile) over frames of the final
fit's ms, the median boresight error (″) at the image centre against the truth, the normalised
error's RMS per axis (x, y, roll) at the fit's boresight pixel, and, with ``--count``, how many
camera fits (``prior_gauss_newton``) and re-matches (``match_catalogue``) a frame took.

A/B against another tree, in the same run, interleaved (two processes per kind, alternately)::

    benchmarks/bench_final_fit.py --against /tmp/base/src      # this tree's src vs that one

One tree alone::

    PYTHONPATH=src python benchmarks/bench_final_fit.py --kinds 15,30n --frames 40
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np


class Kind(NamedTuple):
    name: str
    fov_deg: float
    mag_limit: float
    width: int = 1280
    height: int = 960
    k1: float = 0.0
    projection: str = "pinhole"
    sigma_px: float = 0.1
    catalog: str = "hip"  # "gaia" (deeper than the database: the real sky), or "render": images
    # from benchmarks/render.py (suite c's renderer, Hipparcos to 9) through skyfix's extraction
    fov_given: bool = True


# key: (name, fov, mag limit, ...); a trailing "n" in a key on the command line = no FOV given.
KINDS = {
    "8": Kind("8° 1280×960", 8.0, 9.0),
    "15": Kind("15° 1280×960", 15.0, 8.0),
    "30": Kind("30° 752×480", 30.0, 7.0, 752, 480),
    "30s": Kind("30° 752×480 sparse", 30.0, 5.0, 752, 480, sigma_px=0.3),
    "45": Kind("45° k1 −0.3", 45.0, 6.0, k1=-0.3, catalog="gaia", sigma_px=0.5),
    "90": Kind("90° fisheye", 90.0, 5.0, projection="kannala-brandt", catalog="gaia", sigma_px=0.5),
    "r8": Kind("8° rendered image", 8.0, 9.0, catalog="render"),
    "r15": Kind("15° rendered image", 15.0, 9.0, catalog="render"),
    "r30": Kind("30° rendered image", 30.0, 9.0, catalog="render"),
}
DEFAULT_KINDS = "r15,r15n,r8,r30,15,8,30,30n,30sn,45n,90n"
ARCSEC = math.pi / (180.0 * 3600.0)


def kind_of(key: str) -> Kind:
    k = KINDS[_key(key)]
    no_fov = _key(key) != key
    return k._replace(fov_given=not no_fov, name=k.name + (", no FOV" if no_fov else ""))


def _key(key: str) -> str:
    return key[:-1] if key.endswith("n") and key[:-1] in KINDS else key


def true_camera(k: Kind):
    from skyfix.camera import Camera

    if k.projection != "pinhole":
        return Camera.from_fov(k.width, k.height, k.fov_deg, projection=k.projection)
    r = math.tan(math.radians(k.fov_deg) / 2.0)
    f = (k.width / 2.0) / (r * (1.0 + k.k1 * r * r))
    return Camera(k.width, k.height, f, f, (k.width - 1) / 2.0, (k.height - 1) / 2.0, k1=k.k1)


def run_kind(key: str, n_frames: int, repeat: int, seed: int, count: bool) -> dict:
    """Frames of kind ``key``, identified once each; the final fit timed and checked."""
    import skyfix.final_fit as ff
    from skyfix import _rematch
    from skyfix._kernels import camera_fit
    from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
    from skyfix.analysis.truth import attitude_error_rad
    from skyfix.calibrate import frame_rotation_at_pixel
    from skyfix.catalog import load_gaia, load_hipparcos
    from skyfix.identify import identify

    k = kind_of(key)
    epoch = 2025.0
    rng = np.random.default_rng(seed)
    if k.catalog == "render":
        from render import RenderSpec, StarSky, render
        from skyfix.detect import extract_centroids

        spec = RenderSpec(width=k.width, height=k.height, fov_deg=k.fov_deg, mag_limit=k.mag_limit)
        sky = StarSky(mag_limit=k.mag_limit, epoch=epoch)
    else:
        catalog = load_gaia(epoch=epoch) if k.catalog == "gaia" else load_hipparcos(epoch=epoch)
    cam = true_camera(k)
    counts = {"fits": 0, "rematches": 0}
    if count:  # wrap the kernels the final fit calls by module attribute
        gn, mc = camera_fit.prior_gauss_newton, _rematch.match_catalogue

        def gn_counted(*a, **kw):
            counts["fits"] += 1
            return gn(*a, **kw)

        def mc_counted(*a, **kw):
            counts["rematches"] += 1
            return mc(*a, **kw)

        camera_fit.prior_gauss_newton = gn_counted
        ff.match_catalogue = _rematch.match_catalogue = mc_counted
    centre = ((k.width - 1) / 2.0, (k.height - 1) / 2.0)
    rows = []
    for A in random_attitudes(n_frames, rng):
        if k.catalog == "render":
            xy = extract_centroids(render(A, sky, spec, rng), max_stars=200).xy
        else:
            field = synthetic_centroids(cam, A, catalog, mag_limit=k.mag_limit, sigma_px=k.sigma_px,
                                        n_false=int(rng.integers(0, 4)), dropout=0.05, mag_sigma=0.2, rng=rng)
            xy = field.xy[:200]
        if len(xy) < 4:
            continue
        ident = identify(xy, k.width, k.height, fov_deg=cam.fov_deg if k.fov_given else None, epoch=epoch)
        if not ident.success:
            rows.append({"identified": False})
            continue
        before = dict(counts)
        fit = ff.final_fit(xy, ident, camera_given=False, epoch=epoch)
        per = {c: counts[c] - before[c] for c in counts}
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            ff.final_fit(xy, ident, camera_given=False, epoch=epoch)
            times.append(1e3 * (time.perf_counter() - t0))
        e_centre = frame_rotation_at_pixel(fit.A_icrs_to_cam, fit.camera, A, cam, centre)
        e_bore = attitude_error_rad(fit.A_icrs_to_cam, fit.camera, A, cam)
        # the error at the boresight pixel over that pixel's frame covariance (the axes' holds the
        # principal point's uncertainty too when it was fitted: issue 26 part 1)
        judged = getattr(fit, "precision_covariance_rad2", None)  # (a tree before it: None)
        sig = np.sqrt(np.diag(fit.covariance_rad2 if judged is None else judged))
        rows.append({"identified": True, "ms": float(np.median(times)), "n_stars": len(fit.star_index),
                     "bore_arcsec": math.hypot(e_centre[0], e_centre[1]) / ARCSEC,
                     "roll_arcsec": abs(e_centre[2]) / ARCSEC, "z": (e_bore / sig).tolist(),
                     "params": list(fit.camera_params), "pp_moved": bool(fit.camera.cx != centre[0]),
                     **per})
    ok = [r for r in rows if r["identified"]]
    z = np.array([r["z"] for r in ok]) if ok else np.full((0, 3), np.nan)
    return {"kind": k.name, "frames": len(rows), "identified": len(ok),
            "ms_median": float(np.median([r["ms"] for r in ok])) if ok else math.nan,
            "ms_p90": float(np.percentile([r["ms"] for r in ok], 90)) if ok else math.nan,
            "bore_median_arcsec": float(np.median([r["bore_arcsec"] for r in ok])) if ok else math.nan,
            "roll_median_arcsec": float(np.median([r["roll_arcsec"] for r in ok])) if ok else math.nan,
            "z_rms": np.sqrt(np.mean(z**2, axis=0)).tolist(),
            "stars_median": float(np.median([r["n_stars"] for r in ok])) if ok else math.nan,
            "fits_mean": float(np.mean([r["fits"] for r in ok])) if ok and count else math.nan,
            "rematches_mean": float(np.mean([r["rematches"] for r in ok])) if ok and count else math.nan,
            "rows": rows}


def _child(src: str, args: list[str]) -> dict:
    env = {**os.environ, "PYTHONPATH": src}
    out = subprocess.run([sys.executable, __file__, *args, "--json"], env=env, capture_output=True, text=True,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--kinds", default=DEFAULT_KINDS, help=f"comma-separated keys of {list(KINDS)}, "
                    "a trailing n for no FOV (default %(default)s)")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--count", action="store_true", help="count camera fits and re-matches per frame")
    ap.add_argument("--against", metavar="SRC", help="another tree's src: A/B, interleaved, same frames")
    ap.add_argument("--rounds", type=int, default=2, help="A/B rounds (each runs both trees once per kind)")
    ap.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    keys = args.kinds.split(",")
    if args.json:
        print(json.dumps([run_kind(key, args.frames, args.repeat, args.seed, args.count) for key in keys]))
        return 0
    common = ["--frames", str(args.frames), "--repeat", str(args.repeat), "--seed", str(args.seed)]
    if args.count:
        common.append("--count")
    here = str(Path(__file__).resolve().parents[1] / "src")
    trees = {"this": here} if not args.against else {"base": args.against, "this": here}
    results: dict = {t: {key: [] for key in keys} for t in trees}
    for _ in range(args.rounds if args.against else 1):
        for key in keys:
            for t, src in trees.items():
                results[t][key].append(_child(src, ["--kinds", key, *common])[0])
    head = (f"{'kind':28s} {'tree':5s} {'ident':>6s} {'ms med':>7s} {'ms p90':>7s} {'bore″':>6s} "
            f"{'roll″':>6s} {'z rms x,y,roll':>16s} {'stars':>5s} {'fits':>5s} {'rem.':>5s}")
    print(head)
    for key in keys:
        for t in trees:
            rs = results[t][key]
            r = rs[0]
            ms = float(np.median([x["ms_median"] for x in rs]))
            p90 = float(np.median([x["ms_p90"] for x in rs]))
            z = ",".join(f"{v:.2f}" for v in r["z_rms"])
            print(f"{r['kind']:28s} {t:5s} {r['identified']:>3d}/{r['frames']:<2d} {ms:7.2f} {p90:7.2f} "
                  f"{r['bore_median_arcsec']:6.2f} {r['roll_median_arcsec']:6.1f} {z:>16s} "
                  f"{r['stars_median']:5.0f} {r['fits_mean']:5.1f} {r['rematches_mean']:5.1f}")
        if args.against:
            pairs = zip(results["this"][key], results["base"][key], strict=True)
            per_round = [x["ms_median"] / y["ms_median"] for x, y in pairs]
            print(f"{'':28s} ratio this/base per round: {', '.join(f'{v:.2f}' for v in per_round)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
