"""Thesis 000's detector: global k·σ threshold, 3×3 hill climb, centre of mass in a 3×3 ROI.

Steps (thesis 000 §4.2–4.3, with the corrections of docs/seeds.md#thesis-000-corrections):

1. One global background ``n`` and noise ``σ`` for the whole frame. The thesis takes the frame
   mean and standard deviation; stars and hot pixels bias those, so the median and a clipped
   RMS are used here (the intended reading). Threshold ``T = n + k·σ``.
2. Raster scan visiting every other row and column (a star's 3×3 core always contains a visited
   pixel). From each pixel above ``T``, climb to the brightest of its 8 neighbours until the
   pixel is a local maximum; visited maxima are remembered so each star is climbed to once.
3. Cluster condition: at least ``min_pixels`` (thesis: 4) pixels of the 3×3 around the maximum
   are above ``T``; a lone hot pixel fails it.
4. Centre of mass over the 3×3 ROI, pixels above ``T`` only, weights ``I − n`` — the printed
   equation subtracts ``n`` once from the sum and omits the ROI offset; both are corrected.
   In skyfix's pixel convention (docs/design.md#pixel-coordinates) no ``+0.5`` is added.
5. Stars on the 1-pixel frame border are dropped (their 3×3 ROI is incomplete).

Maxima closer than 3 px to a brighter one are merged (a flat-topped saturated star has several).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix.detect._stats import robust_level_noise, sum_sq_dev
from skyfix.detect.centroids import Centroids, background_snr
from skyfix.detect.saturation import saturation_level

__all__ = ["extract_hillclimb", "global_background"]


class _Spots(NamedTuple):
    """The stars :func:`_hillclimb` finds, (K,) float64 each."""

    x: np.ndarray  # centre of mass over the 3×3 ROI, pixels
    y: np.ndarray
    flux: np.ndarray  # Σ (I − n) over the ROI pixels above T
    npix: np.ndarray  # ROI pixels above T
    peak: np.ndarray  # the maximum above the background
    spread_x: np.ndarray  # unweighted Σ(x − x̄)², Σ(y − ȳ)² of those pixels
    spread_y: np.ndarray
    nsat: np.ndarray  # ROI pixels at or above the saturation level


def global_background(image: np.ndarray, max_samples: int = 65536) -> tuple[float, float]:
    """Frame-wide sky level (median) and noise (clipped RMS) from a regular subsample, ADU."""
    img = np.asarray(image, dtype=np.float32)
    step = max(1, int(math.sqrt(img.size / max_samples)))
    sample = img[::step, ::step].astype(np.float64).ravel()
    quantum = 1.0 if np.all(sample == np.floor(sample)) else 0.0
    level, noise = robust_level_noise(sample, quantum, False)
    return float(level), float(noise)


def extract_hillclimb(image: np.ndarray, *, sigma: float = 5.0, max_stars: int = 100, min_pixels: int = 4,
                      saturation: float | None = None) -> Centroids:
    """Detect and centroid stars the way thesis 000 does (see the module docstring).

    Parameters
    ----------
    image : (H, W) float32 array
        The frame, ADU.
    sigma : float
        k in ``T = n + k·σ`` (the thesis used 2–3 on its calibrated frames; 5 suits
        uncalibrated ones).
    max_stars : int
        Keep the brightest this many.
    min_pixels : int
        Pixels of the 3×3 around the maximum that must exceed ``T``.
    saturation : float, optional
        Saturation level for the flag (default: :func:`skyfix.detect.saturation_level`).
    """
    img = np.ascontiguousarray(image, dtype=np.float32)
    h, w = img.shape
    level, noise = global_background(img)
    if not noise > 0:
        return Centroids.empty((h, w), level, noise, reason="flat frame")
    sat = saturation_level(img) if saturation is None else float(saturation)
    s = _hillclimb(img, level, level + sigma * noise, int(min_pixels), sat)
    if len(s.x) == 0:
        return Centroids.empty((h, w), level, noise)
    keep = _suppress_neighbours(s.x, s.y, s.flux, 3.0)
    keep = keep[np.argsort(-s.flux[keep], kind="stable")][:max_stars]
    flux = s.flux[keep]
    return Centroids(
        x=s.x[keep], y=s.y[keep], flux=flux, area=s.npix[keep], snr=background_snr(flux, noise, s.npix[keep]),
        elongation=np.ones(keep.size), peak=s.peak[keep],
        sigma_x=noise * np.sqrt(s.spread_x[keep]) / flux, sigma_y=noise * np.sqrt(s.spread_y[keep]) / flux,
        saturated=s.nsat[keep] > 0, image_shape=(h, w), background_level=level, noise=noise,
        meta={"method": "threshold_hillclimb", "threshold": level + sigma * noise})


def _suppress_neighbours(x, y, flux, radius):
    """Indices of maxima with no brighter one within ``radius`` px."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(np.column_stack([x, y])).query_pairs(radius, output_type="ndarray")
    drop = np.zeros(x.size, bool)
    if len(pairs):
        i, j = pairs.T
        drop[np.where(flux[i] < flux[j], i, j)] = True
    return np.flatnonzero(~drop)


@njit(cache=True)
def _hillclimb(img, level, thr, min_pixels, saturation):
    """Steps 2–4 of the module docstring: the :class:`_Spots` above threshold ``thr``."""
    h, w = img.shape
    seen = np.zeros((h, w), np.uint8)  # 1: on a climbed path, 2: a recorded maximum
    rows = []
    for y0 in range(1, h - 1, 2):
        for x0 in range(1, w - 1, 2):
            if img[y0, x0] <= thr or seen[y0, x0] != 0:
                continue
            y, x = y0, x0
            while True:
                seen[y, x] = max(seen[y, x], 1)
                by, bx = y, x
                for qy in range(max(y - 1, 0), min(y + 2, h)):
                    for qx in range(max(x - 1, 0), min(x + 2, w)):
                        if img[qy, qx] > img[by, bx]:
                            by, bx = qy, qx
                if by == y and bx == x:
                    break
                y, x = by, bx
            if seen[y, x] == 2:
                continue
            seen[y, x] = 2
            if y < 1 or x < 1 or y > h - 2 or x > w - 2:
                continue  # 3×3 ROI incomplete on the border
            sw = swx = swy = 0.0
            sx = sy = sxx = syy = 0.0
            npix = 0
            nsat = 0
            for qy in range(y - 1, y + 2):
                for qx in range(x - 1, x + 2):
                    v = img[qy, qx]
                    if v >= saturation:
                        nsat += 1
                    if v > thr:
                        wgt = v - level
                        sw += wgt
                        swx += wgt * qx
                        swy += wgt * qy
                        sx += qx
                        sy += qy
                        sxx += qx * qx
                        syy += qy * qy
                        npix += 1
            if npix < min_pixels or sw <= 0:
                continue
            xc, yc = swx / sw, swy / sw
            rows.append((xc, yc, sw, float(npix), img[y, x] - level, sum_sq_dev(sxx, sx, npix, xc),
                         sum_sq_dev(syy, sy, npix, yc), float(nsat)))
    cols = np.empty((8, len(rows)))
    for i in range(len(rows)):
        for j in range(8):
            cols[j, i] = rows[i][j]
    return _Spots(cols[0], cols[1], cols[2], cols[3], cols[4], cols[5], cols[6], cols[7])
