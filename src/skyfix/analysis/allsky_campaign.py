"""The all-sky campaign: simulated fisheye frames of the whole sky (:mod:`skyfix.simulate.allsky`),
solved with no hint and no camera file, judged against their truth (:mod:`skyfix.analysis.truth`).

Each frame draws (from its own seed) a frame size of 2–4 MP (:data:`SIZES`), a lens
(:data:`LENSES`: equidistant 180° and 190°, Kannala–Brandt equisolid 180°, and a Kannala–Brandt
lens with random k1, k2, 185°), the image circle's offset from the frame's centre (±25 px), the
boresight's tilt from the zenith (0–4°, any azimuth) and roll, the site (latitude ±60°) and a
time in 2026, the sky's brightness (19.5–21.5 mag/arcsec²) and a landscape
(:func:`~skyfix.simulate.allsky.random_landscape`: hills, one to three groups of trees or
buildings, half of the frames with one lit, a light dome). docs/all-sky.md gives the results.
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import numpy as np

__all__ = ["LENSES", "SIZES", "AllSkyResult", "allsky_campaign", "allsky_frame", "summarise"]

#: Frame sizes (width, height): 1.9–4.2 MP (no 16:9 frame: docs/all-sky.md#limits-not-done-yet).
SIZES = ((1600, 1200), (2048, 1536), (2048, 2048))
#: Lenses by name: (field across the image circle, degrees; Kannala–Brandt k1, k2; None: drawn).
LENSES = {
    "equidistant 180°": (180.0, (0.0, 0.0)),
    "equidistant 190°": (190.0, (0.0, 0.0)),
    "KB equisolid 180°": (180.0, (-1.0 / 24.0, 1.0 / 1920.0)),
    "KB random 185°": (185.0, None),
}


class AllSkyResult(NamedTuple):
    """One frame of the campaign: its kind, and the solve's outcome against the truth."""

    seed: int
    size: tuple[int, int]
    lens: str
    solved: bool
    wrong: bool
    boresight_arcsec: float  # NaN when not solved
    roll_deg: float
    n_matched: int
    time_s: float
    reason: str
    # the camera axes' error against the truth's quaternion (x, y, roll: the optical axis's
    # direction and the roll about it) over the σ the solution reports (NaN when not solved)
    axis_error_sigmas: tuple[float, float, float] = (math.nan, math.nan, math.nan)


def allsky_frame(seed: int):
    """The campaign's frame ``seed``: (SimulatedFrame, the true camera, the lens's name)."""
    from skyfix.simulate.allsky import all_sky_camera, random_landscape, render_allsky

    rng = np.random.default_rng([26, 3, seed])
    width, height = SIZES[int(rng.integers(len(SIZES)))]
    lens = list(LENSES)[int(rng.integers(len(LENSES)))]
    fov, k = LENSES[lens]
    if k is None:
        k = (float(rng.uniform(-0.05, 0.05)), float(rng.uniform(-0.01, 0.01)))
    camera = all_sky_camera(width, height, fov, offset_px=tuple(rng.uniform(-25, 25, 2)), k=k)
    day = rng.uniform(0, 365)
    stamp = np.datetime64("2026-01-01T00:00:00") + np.timedelta64(int(day * 86400), "s")
    frame = render_allsky(camera, site=(float(rng.uniform(-60, 60)), float(rng.uniform(-180, 180))),
                          time=str(stamp), landscape=random_landscape(rng), fov_deg=fov,
                          tilt_deg=float(rng.uniform(0, 4)), tilt_az_deg=float(rng.uniform(0, 360)),
                          roll_deg=float(rng.uniform(0, 360)), seed=seed,
                          sky_mag_arcsec2=float(rng.uniform(19.5, 21.5)))
    return frame, camera, lens


def allsky_campaign(seeds, **solve_options) -> list[AllSkyResult]:
    """Render and solve the campaign's frames ``seeds`` (no hint, no camera; ``solve_options`` are
    :func:`skyfix.solve`'s)."""
    from skyfix.analysis.truth import judge
    from skyfix.attitude import RAD_TO_ARCSEC, attitude_error
    from skyfix.geometry import attitude_from_quaternion
    from skyfix.pipeline import solve

    out = []
    for seed in seeds:
        frame, camera, lens = allsky_frame(int(seed))
        t0 = time.perf_counter()
        sol = solve(frame.image, **solve_options)
        dt = time.perf_counter() - t0
        if sol.solved:
            A_true = attitude_from_quaternion(np.asarray(frame.truth["quaternion_xyzw"]))
            j = judge(sol.A_icrs_to_cam, sol.camera, A_true, camera)
            sigma = np.sqrt(np.diag(np.asarray(sol.covariance_arcsec2))) / RAD_TO_ARCSEC
            z = attitude_error(A_true, sol.A_icrs_to_cam) / sigma
            out.append(AllSkyResult(int(seed), (camera.width, camera.height), lens, True, j.wrong,
                                    j.boresight_arcsec, j.roll_deg, sol.n_matched, dt, "",
                                    (float(z[0]), float(z[1]), float(z[2]))))
        else:
            out.append(AllSkyResult(int(seed), (camera.width, camera.height), lens, False, False, math.nan,
                                    math.nan, 0, dt, sol.reason))
    return out


def summarise(results: list[AllSkyResult]) -> dict:
    """Solved share, wrong count, the boresight's median and largest error (″), the median
    time of ``results``, and the RMS of the camera axes' errors over their reported σ
    (``normalised_rms``: x, y, roll; 1 for an honest error bar)."""
    solved = [r for r in results if r.solved]
    errors = [r.boresight_arcsec for r in solved]
    z = np.array([r.axis_error_sigmas for r in solved]).reshape(-1, 3)
    return dict(n=len(results), solved=len(solved), solved_pct=100.0 * len(solved) / max(len(results), 1),
                wrong=sum(r.wrong for r in results),
                boresight_median_arcsec=float(np.median(errors)) if errors else math.nan,
                boresight_max_arcsec=float(np.max(errors)) if errors else math.nan,
                time_median_s=float(np.median([r.time_s for r in results])) if results else math.nan,
                normalised_rms=np.sqrt(np.mean(z**2, axis=0)).tolist() if errors else [math.nan] * 3)
