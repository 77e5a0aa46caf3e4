"""A camera's budgets (issue 27 part 4): what it detects, how many stars it sees, the attitude
error that follows — and an error budget of independent components beside a measured total.

**Detection** (thesis 004 §8.3's budget, for any camera). A star of magnitude ``m`` gives
``F = star_electrons(m)`` photo-electrons on axis (:func:`skyfix.simulate.photometry.star_electrons`:
aperture, throughput, QE, exposure). The noise under it, per pixel: sky
(:func:`~skyfix.simulate.photometry.sky_electrons_per_pixel`), dark current × exposure, DSNU,
read noise, and the ADC's quantisation (gain²/12) — ``b + r²`` in
:func:`skyfix.analysis.centroid_study.star_snr`'s convention ``SNR = F / √(F + A·(b + r²))``,
``A = 4π(σ² + 1/12)`` the PSF's noise-equivalent area. A star is *detected* at
``SNR ≥ snr_threshold`` (5: skyfix's extractor thresholds its smoothed frame at 5σ, and a
smoothing kernel matched to the PSF gives that frame the star's SNR); the limiting magnitude is
where the SNR crosses it. It *saturates* where the brightest pixel of a centred star
(a fraction ``erf(1/(2√2σ))²`` of ``F``) reaches the full well or the ADC's top.

**Stars in view.** The catalogue's stars between the saturation and limiting magnitudes that
fall inside the frame, counted at ``n_pointings`` random attitudes: mean, median, and the share
of pointings with fewer than 3 and 4 (a lost-in-space solve needs 4; thesis 004: P(< 3) =
0.0056 for Sunsat).

**Attitude.** Per pointing, the Cramér–Rao covariance of its detected stars
(:func:`skyfix.montecarlo.budget.predicted_covariance_rad2`), each star's centroid noise the
pixel-integrated Gaussian's bound at its flux (:func:`skyfix.detect.cramer_rao_centroid`; the
stars' mean variance is used, as the covariance function takes one σ): the median over pointings
of the cross-boresight (per axis) and roll 1σ; Liebe's rules of thumb
(:func:`skyfix.montecarlo.budget.liebe_sigma_rad`) beside it for the mean star count.

**Error budget** (thesis 003 Table 9.5). Independent components add in quadrature (RSS), not
linearly; :func:`combine_budget` gives both and says whether a measured total (mean ± σ) is
within two σ of the combination, the check thesis 003 made (it holds for the Aptina camera and
fails for the Droid X2 — the components explain a third and a sixth of the totals).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import NamedTuple

import numpy as np

__all__ = ["CameraBudget", "CombinedBudget", "MagnitudeRow", "THESIS_003_TABLE_9_5", "camera_budget",
           "budget_json", "combine_budget", "detection_rows", "format_budget",
           "pixel_noise_e"]


class MagnitudeRow(NamedTuple):
    """One magnitude of a camera's detection table."""

    mag: float
    electrons: float  #: on-axis photo-electrons over the exposure
    peak_e: float  #: in the brightest pixel of a centred star
    snr: float  #: star_snr's convention
    centroid_px: float  #: Cramér–Rao 1σ per axis, pixels (inf below detection)
    detected: bool
    saturated: bool


class CameraBudget(NamedTuple):
    """What :func:`camera_budget` finds for one camera (angles in arcseconds)."""

    name: str
    exposure_s: float
    fov_deg: float
    plate_scale_arcsec: float
    psf_sigma_px: float
    noise_e: float  #: per-pixel noise under a star, electrons (√(b + r²))
    limiting_mag: float
    saturation_mag: float
    rows: tuple[MagnitudeRow, ...]
    stars_mean: float
    stars_median: float
    fewer_than_3: float  #: share of pointings
    fewer_than_4: float
    cross_boresight_arcsec: float  #: Cramér–Rao, per axis, median over pointings
    roll_arcsec: float
    liebe_cross_arcsec: float
    liebe_roll_arcsec: float
    n_pointings: int


class CombinedBudget(NamedTuple):
    """Independent error components and a measured total (same unit)."""

    components: dict[str, float]
    rss: float  #: √Σ cᵢ², independent errors
    linear_sum: float  #: Σ cᵢ, as if fully correlated
    total_mean: float
    total_sigma: float
    rss_within_2_sigma: bool  #: total_mean − 2σ ≤ rss
    sum_within_2_sigma: bool  #: total_mean − 2σ ≤ linear_sum (thesis 003's own check)
    explained_share: float  #: rss / total_mean


#: Thesis 003 Table 9.5, arcminutes: total (mean, σ) and its components per camera.
THESIS_003_TABLE_9_5: dict[str, dict[str, float]] = {
    "Aptina": {"total": 1.5, "total_sigma": 0.6, "truth": 0.0163, "threshold": 0.15, "lens": 0.29,
               "atmosphere": 0.07},
    "Droid X2": {"total": 5.4, "total_sigma": 2.1, "truth": 0.1309, "threshold": 0.15, "lens": 0.58,
                 "atmosphere": 0.07},
}


def combine_budget(components: Mapping[str, float], total_mean: float = math.nan,
                   total_sigma: float = math.nan) -> CombinedBudget:
    """Independent ``components`` combined in quadrature and linearly, against a measured total
    ``total_mean ± total_sigma`` (see the module text)."""
    values = {str(k): float(v) for k, v in components.items()}
    if not values or any(not (math.isfinite(v) and v >= 0) for v in values.values()):
        raise ValueError("components must be non-negative finite numbers, at least one")
    rss = math.sqrt(sum(v * v for v in values.values()))
    linear = sum(values.values())
    floor = total_mean - 2.0 * total_sigma
    return CombinedBudget(values, rss, linear, float(total_mean), float(total_sigma), bool(floor <= rss),
                          bool(floor <= linear), rss / total_mean if total_mean > 0 else math.nan)


def pixel_noise_e(sensor, optics, exposure_s: float, plate_scale_rad: float,
                  sky_mag_arcsec2: float | None) -> tuple[float, float]:
    """``(b, r²)`` under a star, electrons: Poisson-like background per pixel ``b`` (sky + dark
    current) and the Gaussian variance ``r²`` (read noise, DSNU, quantisation gain²/12)."""
    from skyfix.simulate.photometry import sky_electrons_per_pixel

    sky = 0.0 if sky_mag_arcsec2 is None else sky_electrons_per_pixel(sky_mag_arcsec2, optics, sensor,
                                                                      exposure_s, plate_scale_rad)
    b = sky + sensor.dark_current_e_s * exposure_s
    r2 = sensor.read_noise_e**2 + sensor.dsnu_e**2 + sensor.gain_e_per_adu**2 / 12.0
    return b, r2


def _peak_fraction(sigma_px: float) -> float:
    """The share of a centred pixelated Gaussian's light in its brightest pixel."""
    return math.erf(1.0 / (2.0 * math.sqrt(2.0) * sigma_px)) ** 2


def detection_rows(mags: np.ndarray, sensor, optics, exposure_s: float, plate_scale_rad: float, *,
                   sky_mag_arcsec2: float | None = 22.0, snr_threshold: float = 5.0) -> list[MagnitudeRow]:
    """The detection table of a camera at the magnitudes ``mags`` (module text)."""
    from skyfix.analysis.centroid_study import star_snr
    from skyfix.detect import cramer_rao_centroid
    from skyfix.simulate.photometry import star_electrons

    sigma = optics.psf_sigma_px
    b, r2 = pixel_noise_e(sensor, optics, exposure_s, plate_scale_rad, sky_mag_arcsec2)
    top = min(sensor.full_well_e, (2**sensor.bit_depth - 1 - sensor.bias_adu) * sensor.gain_e_per_adu)
    electrons = star_electrons(np.asarray(mags, dtype=np.float64), optics, sensor, exposure_s)
    snr = star_snr(electrons, sigma, b, math.sqrt(r2))
    rows = []
    for m, f, s in zip(np.asarray(mags, float).tolist(), electrons.tolist(), snr.tolist(), strict=True):
        peak = f * _peak_fraction(sigma)
        detected = s >= snr_threshold
        crb = cramer_rao_centroid(sigma, f, b, math.sqrt(r2)) if detected and f > 0 else math.inf
        rows.append(MagnitudeRow(m, f, peak, s, crb, detected, peak + b >= top))
    return rows


def _crossing(mags: np.ndarray, values: np.ndarray, level: float) -> float:
    """The magnitude where ``values`` (falling with magnitude) cross ``level`` (log-linear)."""
    above = values >= level
    if not above.any():
        return -math.inf
    if above.all():
        return math.inf
    k = int(np.flatnonzero(~above)[0])
    if k == 0:
        return -math.inf
    lo, hi = math.log(values[k - 1]), math.log(values[k])
    t = (lo - math.log(level)) / (lo - hi)
    return float(mags[k - 1] + t * (mags[k] - mags[k - 1]))


def camera_budget(camera="generic", *, sensor=None, optics=None, exposure_s: float | None = None,
                  sky_mag_arcsec2: float | None = 22.0, snr_threshold: float = 5.0, n_pointings: int = 400,
                  catalog=None, seed: int = 0) -> CameraBudget:
    """The budgets of a camera: a preset name, a camera TOML file (with ``[sensor]``,
    ``[optics]``, ``[defaults]`` tables, or the ``generic`` preset's) or a Camera with
    ``sensor``/``optics`` (:func:`skyfix.simulate.render.resolve_setup`). See the module text."""
    from scipy.spatial.transform import Rotation

    from skyfix.catalog import load_hipparcos
    from skyfix.montecarlo.budget import liebe_sigma_rad, predicted_covariance_rad2
    from skyfix.simulate.render import resolve_setup

    cam, sen, opt, exposure = resolve_setup(camera, sensor, optics, exposure_s)
    scale = cam.plate_scale_rad
    mags = np.round(np.arange(-1.0, 16.0 + 1e-9, 0.25), 2)
    rows = detection_rows(mags, sen, opt, exposure, scale, sky_mag_arcsec2=sky_mag_arcsec2,
                          snr_threshold=snr_threshold)
    snr = np.array([r.snr for r in rows])
    limiting = _crossing(mags, snr, snr_threshold)
    saturated = np.array([r.saturated for r in rows])
    saturation = float(mags[np.flatnonzero(saturated)[-1]]) if saturated.any() else -math.inf
    b, r2 = pixel_noise_e(sen, opt, exposure, scale, sky_mag_arcsec2)
    # Stars in view at random pointings, and the Cramér–Rao attitude of each: a star's centroid
    # bound interpolated in magnitude from the detection table's.
    cat = catalog if catalog is not None else load_hipparcos()
    star_mag = np.asarray(cat.mag, dtype=np.float64)
    keep = (star_mag <= limiting) & (star_mag > saturation)
    vectors, star_mag = np.asarray(cat.vectors)[keep], star_mag[keep]
    crb = np.array([r.centroid_px for r in rows])
    known = np.isfinite(crb)
    star_var = (np.interp(star_mag, mags[known], crb[known] ** 2) if known.any()
                else np.full(len(star_mag), np.nan))
    attitudes = Rotation.random(int(n_pointings), random_state=np.random.default_rng(seed)).as_matrix()
    counts, cross, roll = [], [], []
    for A in attitudes:  # one pointing at a time: a few thousand stars each, vectorised
        body = vectors @ A.T
        xy, front = cam.ray_to_pixel(body)
        inside = front & (xy[:, 0] >= -0.5) & (xy[:, 0] <= cam.width - 0.5) & (xy[:, 1] >= -0.5) & (
            xy[:, 1] <= cam.height - 0.5)
        n = int(inside.sum())
        counts.append(n)
        if n >= 2:
            cov = predicted_covariance_rad2(cam, body[inside], math.sqrt(float(np.mean(star_var[inside]))))
            cross.append(math.sqrt(0.5 * (cov[0, 0] + cov[1, 1])))
            roll.append(math.sqrt(cov[2, 2]))
    counts_a = np.array(counts)
    arcsec = math.degrees(1.0) * 3600.0
    pixels_across = max(cam.width, cam.height)
    sigma_typ = math.sqrt(float(np.mean(star_var))) if len(star_var) else math.nan
    liebe = liebe_sigma_rad(cam.fov_deg, pixels_across, sigma_typ, float(counts_a.mean()))
    return CameraBudget(
        name=cam.name or str(camera), exposure_s=float(exposure), fov_deg=float(cam.fov_deg),
        plate_scale_arcsec=scale * arcsec, psf_sigma_px=float(opt.psf_sigma_px), noise_e=math.sqrt(b + r2),
        limiting_mag=limiting, saturation_mag=saturation, rows=tuple(rows),
        stars_mean=float(counts_a.mean()), stars_median=float(np.median(counts_a)),
        fewer_than_3=float(np.mean(counts_a < 3)), fewer_than_4=float(np.mean(counts_a < 4)),
        cross_boresight_arcsec=float(np.median(cross)) * arcsec if cross else math.nan,
        roll_arcsec=float(np.median(roll)) * arcsec if roll else math.nan,
        liebe_cross_arcsec=liebe[0] * arcsec, liebe_roll_arcsec=liebe[1] * arcsec,
        n_pointings=int(n_pointings))


def budget_json(b: CameraBudget) -> dict:
    """The budget as strict JSON data (its detection table as a list of rows; non-finite numbers
    as None: an unreached saturation, a star not detected)."""
    from skyfix.analysis._json import strict_json

    return strict_json(b)  # NamedTuples (the budget, its rows) become dicts


def format_budget(b: CameraBudget) -> str:
    """``skyfix analyze budget``'s text: the camera, the detection table around the limit, the
    stars in view and the attitude; thesis 003's Table 9.5 combined (:func:`combine_budget`)."""
    lines = [f"{b.name}: FOV {b.fov_deg:.2f}°, {b.plate_scale_arcsec:.1f}″/px, exposure {b.exposure_s:g} s, "
             f"PSF σ {b.psf_sigma_px:.2f} px, noise {b.noise_e:.1f} e⁻/px",
             f"  limiting magnitude {b.limiting_mag:.2f} (SNR threshold), saturation from "
             f"{b.saturation_mag:.2f}", "  mag   electrons   peak e⁻     SNR   centroid CRB px"]
    for r in b.rows:
        if b.limiting_mag - 4.0 <= r.mag <= b.limiting_mag + 1.0 and float(r.mag * 2).is_integer():
            flag = " saturated" if r.saturated else "" if r.detected else " not detected"
            lines.append(f"  {r.mag:4.1f} {r.electrons:11.4g} {r.peak_e:9.4g} {r.snr:7.1f} "
                         f"{r.centroid_px:10.3f}{flag}")
    lines += [f"  stars in view over {b.n_pointings} pointings: mean {b.stars_mean:.1f}, median "
              f"{b.stars_median:.0f}; fewer than 3: {100 * b.fewer_than_3:.2f} %, fewer than 4: "
              f"{100 * b.fewer_than_4:.2f} %",
              f"  attitude (Cramér–Rao, median): cross-boresight {b.cross_boresight_arcsec:.2f}″ per axis, "
              f"roll {b.roll_arcsec:.1f}″ (Liebe: {b.liebe_cross_arcsec:.2f}″, {b.liebe_roll_arcsec:.1f}″)",
              "thesis 003 Table 9.5 (arcmin), components combined:"]
    for camera, row in THESIS_003_TABLE_9_5.items():
        c = combine_budget({k: row[k] for k in ("truth", "threshold", "lens", "atmosphere")}, row["total"],
                           row["total_sigma"])
        verdict = "within" if c.sum_within_2_sigma else "NOT within"
        lines.append(f"  {camera}: total {c.total_mean:g} ± {c.total_sigma:g}; sum {c.linear_sum:.3f}, RSS "
                     f"{c.rss:.3f} ({100 * c.explained_share:.0f} % of the total): the sum is {verdict} 2σ")
    return "\n".join(lines)
