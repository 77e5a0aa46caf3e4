"""Two error bars against the truth (issue 26 part 1): rendered frames solved with no camera file,
each error divided by the σ its Solution reports — the camera axes' (the truth's quaternion) by
``covariance_arcsec2``, the image centre's frame (its direction and image-up's roll there, as
``center_*`` report) by ``center_covariance_arcsec2`` — and the RMS of those ratios per axis
(x, y, roll), the largest |x| or |y|, the median σ, and the wrong attitudes.

Frames: ``--pinhole N`` rendered 1280 × 960 pinhole frames, 18–30°, principal point 25–60 px off
the centre, k1 −0.25…−0.05 (tests/core/test_centre_covariance.py draws seeds 0–19 the same way;
the axes' ratios over the frames whose principal point was fitted); ``--allsky N`` the all-sky
campaign's ``allsky_frame(seed)``.

    PYTHONPATH=src python benchmarks/centre_covariance.py --pinhole 60 --allsky 40
"""

from __future__ import annotations

import argparse
import math

import numpy as np

ARCSEC = math.radians(1 / 3600)


def pinhole_frame(seed: int):
    """(frame, camera, attitude) of pinhole frame ``seed``."""
    from skyfix.camera import Camera
    from skyfix.geometry import attitude_from_radec_roll
    from skyfix.simulate import render

    rng = np.random.default_rng([26, 1, seed])
    camera = Camera.from_fov(1280, 960, rng.uniform(18, 30))
    distance, angle = rng.uniform(25, 60), rng.uniform(0, 2 * math.pi)
    off = distance * np.array([math.cos(angle), math.sin(angle)])
    camera = camera.replace(cx=camera.cx + off[0], cy=camera.cy + off[1], k1=float(rng.uniform(-0.25, -0.05)))
    A = attitude_from_radec_roll(*rng.uniform([0, -1.2, 0], [2 * math.pi, 1.2, 2 * math.pi]))
    return render(A, camera, seed=seed, exposure_s=0.1, epoch=2026.9), camera, A


def allsky(seed: int):
    """(frame, camera, attitude) of the all-sky campaign's frame ``seed``."""
    from skyfix.analysis.allsky_campaign import allsky_frame
    from skyfix.geometry import attitude_from_quaternion

    frame, camera, _ = allsky_frame(seed)
    return frame, camera, attitude_from_quaternion(np.asarray(frame.truth["quaternion_xyzw"]))


def judged(sol, camera, A) -> dict:
    """One solved frame: its wrongness, both errors over their σ, both σ (″)."""
    from skyfix._kernels.rotation import rotation_vector
    from skyfix.analysis.truth import judge
    from skyfix.attitude import attitude_error
    from skyfix.calibrate import frame_at_pixel

    centre = tuple(sol.center_px)
    F_est = frame_at_pixel(sol.A_icrs_to_cam, sol.camera, centre, "row")
    e_centre = rotation_vector(np.ascontiguousarray(F_est @ frame_at_pixel(A, camera, centre, "row").T))
    s_axes = np.sqrt(np.diag(np.asarray(sol.covariance_arcsec2)))
    s_centre = np.sqrt(np.diag(np.asarray(sol.center_covariance_arcsec2)))
    wrong = judge(sol.A_icrs_to_cam, sol.camera, A, camera).wrong
    return {"wrong": wrong, "fitted": sol.boresight_off_centre,
            "z_axes": attitude_error(A, sol.A_icrs_to_cam) / ARCSEC / s_axes,
            "z_centre": e_centre / ARCSEC / s_centre, "s_axes": s_axes, "s_centre": s_centre}


def report(kind: str, rows: list[dict], n: int) -> None:
    print(f"{kind}: {len(rows)}/{n} solved, {sum(r['wrong'] for r in rows)} wrong, "
          f"{sum(r['fitted'] for r in rows)} with the principal point fitted")
    for name, use in (("axes", [r for r in rows if r["fitted"]]), ("centre", rows)):
        if not use:
            continue
        z = np.array([r[f"z_{name}"] for r in use])
        s = np.array([r[f"s_{name}"] for r in use])
        rms = np.sqrt(np.mean(z**2, axis=0))
        sigma = " ".join(f"{v:.2f}" for v in np.median(s, axis=0))
        print(f"  {name:6s} ({len(use)}): normalised RMS {rms[0]:.2f} {rms[1]:.2f} {rms[2]:.2f}, "
              f"max |x|,|y| {np.abs(z[:, :2]).max():.2f}, median σ {sigma}″")


def main() -> None:
    import skyfix

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pinhole", type=int, default=20, help="rendered pinhole frames (seeds 0..N-1)")
    parser.add_argument("--allsky", type=int, default=12, help="all-sky frames (seeds 0..N-1)")
    args = parser.parse_args()
    for kind, n, draw, options in (("pinhole", args.pinhole, pinhole_frame, {"epoch": 2026.9}),
                                   ("all-sky", args.allsky, allsky, {})):
        rows = []
        for seed in range(n):
            frame, camera, A = draw(seed)
            sol = skyfix.solve(frame.image, **options)
            if sol.solved:
                rows.append(judged(sol, camera, A))
        if n:
            report(kind, rows, n)


if __name__ == "__main__":
    main()
