"""Thesis 003's detector: optional smoothing or anisotropic diffusion, threshold, 8-connected
spots (``regionprops``), minimum/maximum area and an eccentricity limit.

Steps (thesis 003 §3.II.B and Fig. 3.1; docs/seeds.md#thesis-003):

1. Optional noise removal: a 3×3 binomial low-pass, or Perona–Malik anisotropic diffusion
   (edge-preserving), both described in the thesis though its results used neither.
2. Threshold ``T = level + k·RMS``: the thesis's rule of thumb is 3 × the RMS noise floor; the
   frame's median is taken as the level the floor is measured from (the thesis does not say).
   Level and floor are the raw frame's, also when the threshold is applied to a prefiltered one.
3. 8-connected spot clusters of the pixels above ``T`` (``scipy.ndimage.label``).
4. Spot size selection: ``min_area`` (camera-specific in the thesis) and an optional
   ``max_area`` (banding, compression blobs).
5. Eccentricity of the spot's equivalent ellipse (unweighted second moments, as regionprops):
   spots more eccentric than ``max_eccentricity`` (banding, Moon edges) are rejected.
6. Intensity-weighted centroid (Eq. 3.3). The thesis weighs by the thresholded pixel values
   with no background subtracted, which pulls the centroid toward the spot's area centroid; here
   the weights are ``value − level`` (noted as a correction).

All per-spot sums are vectorised with ``scipy.ndimage`` over the label image.
"""

from __future__ import annotations

import numpy as np

from skyfix.detect._stats import sum_sq_dev
from skyfix.detect.background import smooth3
from skyfix.detect.centroids import Centroids, background_snr
from skyfix.detect.hillclimb import global_background
from skyfix.detect.saturation import saturation_level
from skyfix.errors import unknown_name

__all__ = ["PREFILTERS", "extract_regionprops", "perona_malik"]


def perona_malik(image: np.ndarray, iterations: int = 5, kappa: float | None = None,
                 step: float = 0.2) -> np.ndarray:
    """Perona–Malik anisotropic diffusion (exponential conductance), float32.

    ``kappa`` is the edge threshold in ADU (default: 3 × the frame's noise): differences much
    larger than it (star edges) diffuse little, noise smooths out. ``step`` ≤ 0.25 keeps the
    explicit 4-neighbour scheme stable.
    """
    u = np.asarray(image, dtype=np.float32).copy()
    if kappa is None:
        kappa = 3.0 * max(global_background(u)[1], 1e-6)
    inv_k2 = 1.0 / float(kappa) ** 2
    for _ in range(int(iterations)):
        p = np.pad(u, 1, mode="edge")
        dn = p[:-2, 1:-1] - u
        ds = p[2:, 1:-1] - u
        de = p[1:-1, 2:] - u
        dw = p[1:-1, :-2] - u
        u += step * (np.exp(-dn * dn * inv_k2) * dn + np.exp(-ds * ds * inv_k2) * ds
                     + np.exp(-de * de * inv_k2) * de + np.exp(-dw * dw * inv_k2) * dw)
    return u


#: Noise removal before the threshold, by name (``prefilter=`` of :func:`extract_regionprops`;
#: ``None``: none).
PREFILTERS = {"smooth": smooth3, "diffusion": perona_malik}


def extract_regionprops(image: np.ndarray, *, sigma: float = 3.0, max_stars: int = 100, min_area: int = 4,
                        max_area: int | None = None, max_eccentricity: float | None = 0.95,
                        prefilter: str | None = None, saturation: float | None = None) -> Centroids:
    """Detect and centroid stars the way thesis 003 does (see the module docstring).

    Parameters
    ----------
    image : (H, W) float32 array
        The frame, ADU.
    sigma : float
        Threshold in RMS noise floors above the level (thesis rule of thumb: 3).
    max_stars : int
        Keep the brightest this many.
    min_area, max_area : int
        Spot size limits, pixels.
    max_eccentricity : float, optional
        Reject spots whose equivalent ellipse is more eccentric (0 = circle, → 1 = line).
    prefilter : {None, "smooth", "diffusion"}
        Noise removal before the threshold (3×3 binomial or Perona–Malik).
    saturation : float, optional
        Saturation level for the flag (default: :func:`skyfix.detect.saturation_level`).
    """
    if prefilter is not None and (not isinstance(prefilter, str) or prefilter not in PREFILTERS):
        raise unknown_name("prefilter", prefilter, ["None", *PREFILTERS])
    img = np.ascontiguousarray(image, dtype=np.float32)
    h, w = img.shape
    work = img if prefilter is None else PREFILTERS[prefilter](img)
    # the RMS noise floor is the sensor's (raw frame's); a prefilter only lowers the work image's
    level, noise = global_background(img)
    if not noise > 0:
        return Centroids.empty((h, w), level, noise, reason="flat frame")
    from scipy import ndimage

    labels, n = ndimage.label(work > level + sigma * noise, structure=np.ones((3, 3), bool))
    if n == 0:
        return Centroids.empty((h, w), level, noise)
    ys, xs = np.nonzero(labels)
    lv = labels[ys, xs]
    v = img[ys, xs].astype(np.float64)
    wv = np.maximum(v - level, 0.0)
    xs, ys = xs.astype(np.float64), ys.astype(np.float64)

    def per_spot(values=None):  # sums over each spot's pixels (bincount: no per-spot loop)
        return np.bincount(lv, weights=values, minlength=n + 1)[1:].astype(np.float64)

    area = per_spot()
    flux = per_spot(wv)
    # unweighted (area) moments → equivalent ellipse, as regionprops
    sx, sy = per_spot(xs), per_spot(ys)
    mx, my = sx / area, sy / area
    cxx = per_spot(xs * xs) / area - mx**2 + 1.0 / 12.0
    cyy = per_spot(ys * ys) / area - my**2 + 1.0 / 12.0
    cxy = per_spot(xs * ys) / area - mx * my
    half_tr, root = 0.5 * (cxx + cyy), np.sqrt(np.maximum(0.25 * (cxx - cyy) ** 2 + cxy**2, 0.0))
    lam1, lam2 = half_tr + root, np.maximum(half_tr - root, 1e-12)
    ecc = np.sqrt(np.maximum(1.0 - lam2 / lam1, 0.0))
    keep = (area >= min_area) & (flux > 0)
    if max_area is not None:
        keep &= area <= max_area
    if max_eccentricity is not None:
        keep &= ecc <= max_eccentricity
    sel = np.flatnonzero(keep)
    sel = sel[np.argsort(-flux[sel], kind="stable")][:max_stars]
    if sel.size == 0:
        return Centroids.empty((h, w), level, noise)
    f = flux[sel]
    x = per_spot(wv * xs)[sel] / f
    y = per_spot(wv * ys)[sel] / f
    peak = np.full(n + 1, -np.inf)
    np.maximum.at(peak, lv, v)
    peak = peak[1:][sel]
    sat = saturation_level(img) if saturation is None else float(saturation)
    # background-noise error of a weighted mean over the spot: σ·√Σ(x − x̄)² / F
    sxx = sum_sq_dev(per_spot(xs * xs)[sel], sx[sel], area[sel], x)
    syy = sum_sq_dev(per_spot(ys * ys)[sel], sy[sel], area[sel], y)
    return Centroids(
        x=x, y=y, flux=f, area=area[sel], snr=background_snr(f, noise, area[sel]),
        elongation=np.sqrt(lam1[sel] / lam2[sel]), peak=peak - level,
        sigma_x=noise * np.sqrt(sxx) / f, sigma_y=noise * np.sqrt(syy) / f,
        saturated=peak >= sat, image_shape=(h, w), background_level=level, noise=noise,
        angle=0.5 * np.arctan2(2.0 * cxy[sel], cxx[sel] - cyy[sel]),
        meta={"method": "regionprops", "prefilter": prefilter, "threshold": level + sigma * noise})
