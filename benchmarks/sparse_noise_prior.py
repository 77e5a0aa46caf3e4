"""Three- to five-star frames with a calibrated camera, solved with and without the centroid
noise stated (``centroid_sigma_px``, :func:`skyfix.identify.accept.noise_posterior`): solved,
wrong, and the reported σ's honesty (normalised error RMS per axis x, y, roll).

    .venv/bin/python benchmarks/sparse_noise_prior.py --fields 300

Each field: a 30° 1280×960 camera at a random attitude, its ``n_true`` (3–5) brightest Hipparcos
stars to mag 8 with Gaussian centroid noise σ (0.1, 0.3 or 0.5 px), and 0–2 false stars;
``--stated-factor`` states a noise that many times the true one.
"""

from __future__ import annotations

import argparse

import numpy as np

from skyfix.analysis.blind_campaign import summarize, trial_result
from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
from skyfix.camera import Camera
from skyfix.catalog import load_hipparcos
from skyfix.identify.catalogue.bands import database_for_fov
from skyfix.pipeline import solve_centroids

W, H, FOV = 1280, 960, 30.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fields", type=int, default=300)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--stated-factor", type=float, default=1.0,
                    help="the noise stated is the true one times this (a mis-stated noise)")
    args = ap.parse_args()
    catalog = load_hipparcos()
    cam = Camera.from_fov(W, H, FOV)
    db = database_for_fov(FOV)
    rng = np.random.default_rng(args.seed)
    trials: dict[str, list] = {"stated": [], "not stated": []}
    for i, A in enumerate(random_attitudes(args.fields, rng)):
        sigma = (0.1, 0.3, 0.5)[i % 3]
        n_true, n_false = 3 + i % 5 % 3, (i // 3) % 3
        f = synthetic_centroids(cam, A, catalog, mag_limit=8.0, sigma_px=sigma, n_false=n_false, rng=rng)
        keep = np.sort(np.concatenate([np.flatnonzero(~f.is_false)[:n_true], np.flatnonzero(f.is_false)]))
        n_stars = int((~f.is_false[keep]).sum())
        for key, opts in (("stated", {"centroid_sigma_px": sigma * args.stated_factor}), ("not stated", {})):
            sol = solve_centroids(f.xy[keep], W, H, camera=cam, database=db, **opts)
            trials[key].append(trial_result(sol, A, cam, n_stars))
    for key, t in trials.items():
        s = summarize(t)
        print(f"{key:>10}: {s['solved']}/{s['n']} solved, {s['wrong']} wrong, normalised RMS "
              f"{s.get('normalised_rms')}, max boresight {s.get('max_boresight_arcsec', float('nan')):.1f}″")
        for n in (3, 4, 5):
            sub = [x for x in t if x.n_stars == n]
            if sub:
                s = summarize(sub)
                print(f"{'':>10}  {n} stars: {s['solved']}/{s['n']} solved, {s['wrong']} wrong, "
                      f"normalised RMS {s.get('normalised_rms')}")


if __name__ == "__main__":
    main()
