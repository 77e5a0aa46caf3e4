"""The seed camera presets against their theses: what a preset's frames show beside what the
thesis's images showed.

For a preset, :func:`check_preset` renders frames at its ``[defaults]`` exposure at random
attitudes, runs skyfix's extractor (:func:`skyfix.detect.extract_centroids`) and measures:
the FWHM of isolated stars near the centre (:func:`skyfix.analysis.psf_field.measure_psf_field`),
the noise of a lens-cap frame (no stars, no sky), the extractor's SNR of a star of the thesis's
reference magnitude, the limiting magnitude (half the stars of that magnitude detected), the
stars detected per frame, and — where the thesis says how it found its stars — the spots that
the thesis's own processing finds in the same frames (:func:`threshold_spots`).
:data:`THESIS_FIGURES` holds the thesis's numbers beside which these are read.

"Detectable" (:func:`detection_snr`) is decided from the truth the renderer writes, before any
noise: a star's expected peak in the extractor's 3×3-smoothed frame over that frame's noise,
the extractor's own detection statistic; a star is detectable when it reaches the extractor's
threshold (:data:`DETECTION_SIGMA`, its default ``sigma``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from scipy.special import ndtr

__all__ = ["DETECTION_SIGMA", "THESIS_FIGURES", "ThesisFigures", "ThesisRule", "PresetCheck", "check_preset",
           "detection_snr", "pixel_noise_adu", "smoothed_peak_fraction", "threshold_spots", "thesis_snr"]

#: The extractor's detection threshold in σ of the smoothed frame (``extract_centroids(sigma=5)``).
DETECTION_SIGMA = 5.0
#: Noise of white noise after the extractor's 3×3 binomial smoothing, per unit of pixel noise:
#: the root sum of squares of the weights [1 2 1]ᵀ[1 2 1]/16 = 6/16.
_SMOOTH_NOISE = 0.375
_BINOMIAL = np.array([0.25, 0.5, 0.25])
#: The brightest detections the FWHM is measured on (a wide-field frame has hundreds; fitting
#: them all takes a minute a frame).
_PSF_STARS = 80


class ThesisRule(NamedTuple):
    """How a thesis found its stars: pixels above a level, grouped 8-connected, spots of at
    least ``min_area`` pixels. The level is ``level`` ADU (``unit="adu"``) or ``level`` times the
    frame's noise σ (``unit="sigma"``), counted from zero (``above="zero"``: a raw count, as
    thesis 003's) or from the frame's sky level (``above="sky"``)."""

    level: float
    min_area: int
    unit: str = "adu"
    above: str = "zero"

    def level_adu(self, sky_adu: float, noise_adu: float) -> float:
        """The threshold in ADU for a frame of sky level ``sky_adu`` and noise ``noise_adu``."""
        step = self.level * (noise_adu if self.unit == "sigma" else 1.0)
        return step + (sky_adu if self.above == "sky" else 0.0)


class ThesisFigures(NamedTuple):
    """A thesis's own numbers for one camera (None where it gives none); ``notes`` says where
    each comes from."""

    thesis: str
    fwhm_px: float | None = None
    stars_per_frame: float | None = None
    rule: ThesisRule | None = None
    noise_floor_adu: float | None = None
    snr_reference: tuple[float, float] | None = None  # (SNR by the thesis's definition, magnitude)
    limiting_mag: float | None = None
    boresight_arcsec: float | None = None
    notes: str = ""


#: The thesis figures each preset is checked against (docs/presets.md).
THESIS_FIGURES: dict[str, ThesisFigures] = {
    "mt9v022": ThesisFigures(
        "000", stars_per_frame=4.0, rule=ThesisRule(3.0, 4, "sigma", "sky"), boresight_arcsec=11.4,
        notes="§4.5: camera tests showed at most ~4 (typically < 4) stars per frame; §4.2: threshold "
              "mean + 2-3 sigma, a star needs >= 4 pixels above it (rule level in units of the frame's "
              "noise sigma); §5.5: 4-9 pixels per star, mostly one pixel and a '+' halo; Table 7: the "
              "field stars identified are all V <= 3.48; §6.3: pointing 0.00318 deg = 11.4 arcsec "
              "(Liebe's estimate, not a measurement)"),
    "has2": ThesisFigures(
        "002", notes="Table 3-1: the detector; FWHM, magnitudes, aperture and focal length are not given"),
    "ov5642": ThesisFigures(
        "002", stars_per_frame=5.0,
        notes="§5.3: the air-bearing camera saw five stars of a monitor field cut at magnitude 8 "
              "(not the sky); f = 85 mm; '16 Hz integration time'"),
    "mt9p031": ThesisFigures(
        "003", fwhm_px=7.6151, stars_per_frame=16.23, rule=ThesisRule(1024.0, 6, "adu", "sky"),
        noise_floor_adu=35.21, snr_reference=(6.17, 2.07), boresight_arcsec=60.0,
        notes="§9.VIII.A FWHM 7.6151 px; Table 9.4: 16.23 starlight spots per image with result set 1's "
              "processing (Table 9.3: threshold 1024 counts, spots >= 6 px); Table 9.1: lens-cap RMS "
              "noise 35.21 counts (12-bit); Table 9.2: SNR (Eq. 3.1) 6.17 on a magnitude 2.07 star; "
              "§9.VI: pointing ~1' (total 1.5' +- 0.6')"),
    "droid_x2": ThesisFigures(
        "003", fwhm_px=3.0054, stars_per_frame=1.85, rule=ThesisRule(18.0, 15, "adu", "sky"),
        noise_floor_adu=1.51, snr_reference=(10.53, 1.64), limiting_mag=2.6, boresight_arcsec=150.0,
        notes="§9.VIII.A FWHM 3.0054 px (biased low by JPEG); Table 9.4: 1.85 starlight spots per image "
              "(set 8: threshold 18 counts, spots >= 15 px, green channel); no detected star fainter than "
              "2.6; Table 9.1: lens-cap RMS noise 1.51 counts (green, 8-bit JPEG); Table 9.2: SNR 10.53 "
              "(green) on a magnitude 1.64 star; exposure 66 ms; §9.VI: pointing ~2.5' (total 5.4')"),
    "sunsat": ThesisFigures(
        "004", rule=ThesisRule(2.0, 10, "adu", "sky"), noise_floor_adu=0.33, limiting_mag=6.0,
        notes="§8.5.2: 3 mV peak-to-peak CCD noise at 1.5 mV a level (about 2 levels p-p, sigma ~1/3 "
              "level); §8.6: Mv <= 3 start to saturate; §8.7 field test (T_int 0.984 s, threshold 2 levels "
              "over the row's dark level, >= 10 px): every Mv 6 star seen; §5.1: 5-15 stars a frame; "
              "§6.3: sigma_pos 55.3 urad = 11.4 arcsec per star (a calibration figure, not an attitude)"),
    "generic": ThesisFigures("-", notes="not from a thesis"),
}


# --- the detection statistic from the truth ------------------------------------------------
def smoothed_peak_fraction(psf_sigma_px: float, n_phase: int = 16) -> float:
    """The fraction of a star's light at its highest pixel of the 3×3-binomial-smoothed frame,
    averaged over a uniform sub-pixel phase (exact pixel integration of a round Gaussian)."""
    s = max(float(psf_sigma_px), 1e-6)
    phase = (np.arange(n_phase) + 0.5) / n_phase - 0.5
    j = np.arange(-6 - int(4 * s), 7 + int(4 * s))
    edges = (j[None, :] + 0.5 - phase[:, None]) / s
    pixel = ndtr(edges) - ndtr(edges - 1.0 / s)  # (phase, pixel) light of each pixel
    smooth = np.apply_along_axis(lambda p: np.convolve(p, _BINOMIAL, mode="same"), 1, pixel)
    per_axis = smooth.max(axis=1).mean()  # the round Gaussian is separable: product of the axes
    return float(per_axis**2)


def pixel_noise_adu(truth: dict) -> float:
    """The expected noise σ of one sky pixel, ADU, from a frame's truth: sky and dark shot noise,
    read and reset noise, DSNU (a fixed pattern, noise to a single frame) and quantisation."""
    sensor = truth["sensor"]
    noise = truth.get("noise", {})
    t = float(truth["exposure_s"])
    var_e = float(truth.get("background_e", 0.0)) if noise.get("shot", True) else 0.0
    if noise.get("dark", True):
        var_e += float(sensor["dark_current_e_s"]) * t
    if noise.get("read", True):
        var_e += float(sensor["read_noise_e"]) ** 2
    if noise.get("ktc", True):
        var_e += float(sensor.get("ktc_noise_e", 0.0)) ** 2
    if noise.get("dsnu", True):
        var_e += float(sensor["dsnu_e"]) ** 2
    gain = float(sensor["gain_e_per_adu"])
    quant = 1.0 / 12.0 if noise.get("quantization", True) else 0.0
    return math.sqrt(var_e / gain**2 + quant)


def detection_snr(truth: dict) -> np.ndarray:
    """Each truth star's expected peak in the extractor's smoothed frame over that frame's noise
    (:data:`DETECTION_SIGMA` or more: detectable), at the PSF's centre width and the mean
    sub-pixel phase; saturation and the PSF's growth toward the edge are not modelled."""
    stars = truth["stars"]
    if not stars:
        return np.zeros(0)
    electrons = np.array([s["electrons"] for s in stars], dtype=np.float64)
    sigma_px = float(truth["optics"]["psf_fwhm_px"]) / (2.0 * math.sqrt(2.0 * math.log(2.0)))
    peak_adu = electrons * smoothed_peak_fraction(sigma_px) / float(truth["sensor"]["gain_e_per_adu"])
    return peak_adu / (_SMOOTH_NOISE * pixel_noise_adu(truth))


# --- the theses' own star finding -----------------------------------------------------------
def threshold_spots(image: np.ndarray, level: float, min_area: int) -> tuple[np.ndarray, np.ndarray]:
    """Spots as thesis 003 (and, with a per-row level, 004) found them: pixels above ``level``
    grouped 8-connected, spots of at least ``min_area`` pixels. Returns the spots' intensity-
    weighted centres (N, 2) (weights ``value − level``) and their areas (N,)."""
    from scipy import ndimage

    img = np.asarray(image, dtype=np.float64)
    mask = img > level
    labels, n = ndimage.label(mask, structure=np.ones((3, 3), bool))
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0, np.int64)
    index = np.arange(1, n + 1)
    area = ndimage.sum_labels(np.ones_like(img), labels, index).astype(np.int64)
    weight = np.where(mask, img - level, 0.0)
    total = ndimage.sum_labels(weight, labels, index)
    rows, cols = np.indices(img.shape)
    cy = ndimage.sum_labels(weight * rows, labels, index) / np.maximum(total, 1e-300)
    cx = ndimage.sum_labels(weight * cols, labels, index) / np.maximum(total, 1e-300)
    keep = area >= int(min_area)
    return np.stack([cx[keep], cy[keep]], axis=1), area[keep]


def thesis_snr(image: np.ndarray, level: float, star_xy: tuple[float, float]) -> float:
    """Thesis 003's SNR (Eq. 3.1) of the star at ``star_xy``: the root mean square of the pixel
    values of its spot (pixels above ``level``, 8-connected) over the root mean square of all
    pixels in no spot. NaN when the star makes no spot."""
    from scipy import ndimage

    img = np.asarray(image, dtype=np.float64)
    mask = img > level
    labels, _ = ndimage.label(mask, structure=np.ones((3, 3), bool))
    x, y = int(round(star_xy[0])), int(round(star_xy[1]))
    h, w = img.shape
    y0, y1, x0, x1 = max(y - 3, 0), min(y + 4, h), max(x - 3, 0), min(x + 4, w)
    ids = np.unique(labels[y0:y1, x0:x1])
    ids = ids[ids > 0]
    if ids.size == 0:
        return math.nan
    spot = np.isin(labels, ids)
    return float(np.sqrt(np.mean(img[spot] ** 2)) / np.sqrt(np.mean(img[~mask] ** 2)))


# --- one preset's check ---------------------------------------------------------------------
class PresetCheck(NamedTuple):
    """What :func:`check_preset` measured on one preset's frames (docs/presets.md)."""

    preset: str
    exposure_s: float
    n_frames: int
    fwhm_px: float                 # median FWHM of isolated stars in the centre third of the field
    lens_cap_noise_adu: float      # σ of a frame with no stars and no sky
    sky_noise_adu: float           # the extractor's median noise σ in the frames
    limiting_mag: float            # magnitude at which half the stars are detected
    detected_per_frame: float      # mean stars detected (matched to truth within 2 px)
    detectable_per_frame: float    # mean stars detectable by the truth (detection_snr ≥ 5)
    frames_with_4_detected: float  # fraction of frames with ≥ 4 stars detected
    snr_at_mag: dict               # {magnitude: the extractor's SNR of a star of that magnitude}
    thesis_rule_spots: float       # mean starlight spots the thesis's rule finds (NaN: no rule)
    thesis_rule_limiting_mag: float  # faintest star (95th percentile) the thesis's rule finds
    thesis_snr: float              # thesis 003's Eq. 3.1 on its reference star (NaN: none)
    detection_by_snr: list         # [(detection_snr bin low, n stars, fraction detected)]
    saturated_mag: float           # brightest magnitude whose star stays unsaturated (NaN: none)


def _lens_cap_noise(preset: str, epoch: float) -> float:
    from skyfix.simulate import render

    frame = render(np.eye(3), preset, epoch=epoch, seed=7, mag_limit=-30.0, sky_mag_arcsec2=None)
    return float(np.std(frame.image.astype(np.float64)))


def _limiting_mag(mag: np.ndarray, detected: np.ndarray) -> float:
    """The magnitude where a logistic fit of detection against magnitude crosses one half."""
    from scipy.optimize import minimize

    if detected.all() or not detected.any():
        return math.nan

    def nll(p):
        z = np.clip((p[0] - mag) / max(abs(p[1]), 1e-3), -40, 40)
        q = 1.0 / (1.0 + np.exp(-z))
        return -np.sum(np.where(detected, np.log(q + 1e-12), np.log(1 - q + 1e-12)))

    start = np.array([float(np.median(mag[detected])) + 0.5, 0.3])
    return float(minimize(nll, start, method="Nelder-Mead").x[0])


def check_preset(preset: str, n_frames: int = 20, seed: int = 0, *, epoch: float = 2025.0,
                 exposure_s: float | None = None,
                 progress: Callable[[str], None] | None = None) -> PresetCheck:
    """Render ``n_frames`` frames of ``preset`` at random attitudes (seeded) and measure them
    (:class:`PresetCheck`) beside the thesis's figures (:data:`THESIS_FIGURES`)."""
    from scipy.spatial import cKDTree

    from skyfix.analysis.psf_field import measure_psf_field
    from skyfix.analysis.synthetic_centroids import random_attitudes
    from skyfix.detect import extract_centroids
    from skyfix.simulate import render

    figures = THESIS_FIGURES.get(preset, ThesisFigures("-"))
    rng = np.random.default_rng(seed)
    mags, dets, snrs, det_snr, fwhm, noise, n_det, n_able, spots, spot_mags, tsnr = ([] for _ in range(11))
    sat_mags, unsat_mags = [], []
    exposure = None
    for k, A in enumerate(random_attitudes(n_frames, rng)):
        frame = render(A, preset, epoch=epoch, seed=seed * 1000 + k, exposure_s=exposure_s)
        truth = frame.truth
        exposure = truth["exposure_s"]
        stars = truth["stars"]
        xy = np.array([[s["x"], s["y"]] for s in stars]).reshape(-1, 2)
        mag = np.array([s["mag"] for s in stars])
        c = extract_centroids(frame.image, max_stars=1000)
        hit = np.zeros(len(stars), bool)
        snr = np.full(len(stars), np.nan)
        if len(c.x) and len(stars):
            d, j = cKDTree(np.c_[c.x, c.y]).query(xy)
            hit = d < 2.0
            snr[hit] = c.snr[j[hit]]
            sat = np.zeros(len(stars), bool)
            sat[hit] = c.saturated[j[hit]]
            sat_mags.extend(mag[sat])
            unsat_mags.extend(mag[hit & ~sat])
        s_det = detection_snr(truth)
        mags.append(mag), dets.append(hit), snrs.append(snr), det_snr.append(s_det)
        n_det.append(int(hit.sum())), n_able.append(int((s_det >= DETECTION_SIGMA).sum()))
        noise.append(c.noise)
        psf = measure_psf_field(frame.image, min_snr=10.0, max_stars=_PSF_STARS)
        if psf.n:
            fwhm.extend(psf.fwhm_px[psf.radius < 1 / 3])
        if figures.rule is not None:
            level = figures.rule.level_adu(c.background_level, c.noise)
            centres, _ = threshold_spots(frame.image, level, figures.rule.min_area)
            found = np.zeros(len(stars), bool)
            if len(centres) and len(stars):
                d, j = cKDTree(xy).query(centres)
                found[j[d < 3.0]] = True
            spots.append(int(found.sum()))
            spot_mags.extend(mag[found])
            if figures.snr_reference is not None and len(stars):
                ref = int(np.argmin(np.abs(mag - figures.snr_reference[1])))
                if abs(mag[ref] - figures.snr_reference[1]) < 0.3:
                    tsnr.append(thesis_snr(frame.image, level, tuple(xy[ref])))
        if progress is not None:
            progress(f"{preset} frame {k + 1}/{n_frames}")
    mag, det, snr, s_det = (np.concatenate(v) for v in (mags, dets, snrs, det_snr))
    snr_at = {}
    ok = det & np.isfinite(snr) & (snr > 0)
    if ok.sum() >= 3:
        slope, icpt = np.polyfit(mag[ok], np.log10(snr[ok]), 1)
        for m in (0.0, 2.0, 4.0, 6.0, 8.0):
            snr_at[m] = float(10 ** (icpt + slope * m))
    bins = []
    edges = (0.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 12.0, 20.0, math.inf)
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (s_det >= lo) & (s_det < hi)
        if sel.any():
            bins.append((lo, int(sel.sum()), float(det[sel].mean())))
    return PresetCheck(
        preset=preset, exposure_s=float(exposure), n_frames=n_frames,
        fwhm_px=float(np.median(fwhm)) if fwhm else math.nan,
        lens_cap_noise_adu=_lens_cap_noise(preset, epoch) if exposure_s is None else math.nan,
        sky_noise_adu=float(np.median(noise)), limiting_mag=_limiting_mag(mag, det),
        detected_per_frame=float(np.mean(n_det)), detectable_per_frame=float(np.mean(n_able)),
        frames_with_4_detected=float(np.mean(np.array(n_det) >= 4)), snr_at_mag=snr_at,
        thesis_rule_spots=float(np.mean(spots)) if spots else math.nan,
        thesis_rule_limiting_mag=float(np.percentile(spot_mags, 95)) if spot_mags else math.nan,
        thesis_snr=float(np.nanmedian(tsnr)) if tsnr else math.nan, detection_by_snr=bins,
        saturated_mag=float(max(sat_mags)) if sat_mags else math.nan)
