"""Thesis 004's detector: every-third-pixel scan, 4-connected region growing, size and shape tests.

Steps (thesis 004 §2.2; docs/seeds.md#thesis-004):

1. Threshold per row: the row's dark level plus ``Δth``. The thesis reads the dark level from
   43 light-shielded pixels per row; frames here have none, so the row's median stands in
   for it (it follows the same slow offset droop, plus the sky). ``Δth = k·σ`` with ``σ`` the
   frame's clipped-RMS noise about the row levels (the thesis set Δth by hand, 0–4 levels).
2. Scan every 3rd row and 3rd column (the smallest accepted star, 10 px, is 3 px across).
3. From a pixel above threshold, grow a 4-connected region (breadth-first), erasing as it goes
   so each region is found once; growth crosses nothing but the frame edge.
4. Accept ``min_area ≤ n ≤ max_area`` (thesis: 10–300 px) and regions not touching the frame
   edge.
5. Centroid weighted by ``b = value − threshold`` (Eq. 2.1–2.2; in skyfix's pixel convention,
   docs/design.md#pixel-coordinates, the pixel centre is the index itself, so the thesis's
   ``− 0.5`` is not applied).
6. Shape test: unweighted base centre and second moments give the long-axis direction λ;
   ``a`` and ``b`` are the region's extents along and across it; accept ``a − b < max_ab``
   (thesis: 12 px, its 10 px maximum smear plus 2).
7. Brightness ``Σb + k_area·n·Δth`` with ``k_area = 2`` (Eq. 2.11) is the reported flux.

The thesis keeps the first 20 regions found; here all are kept and sorted by brightness.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix.detect._stats import robust_level_noise
from skyfix.detect.centroids import Centroids, background_snr
from skyfix.detect.saturation import saturation_level

__all__ = ["extract_region_grow"]

K_AREA = 2.0  # thesis 004 Eq. 2.11: adds back the light between the dark level and the threshold


class _Regions(NamedTuple):
    """The regions :func:`_grow` accepts, (K,) float64 each."""

    x: np.ndarray  # centroid weighted by b = value − threshold, pixels
    y: np.ndarray
    brightness: np.ndarray  # Σb + K_AREA·n·Δth (Eq. 2.11)
    npix: np.ndarray  # region size n
    peak: np.ndarray  # highest pixel above the row's level
    along: np.ndarray  # extents along and across the long axis, pixels
    across: np.ndarray
    nsat: np.ndarray  # pixels at or above the saturation level


def extract_region_grow(image: np.ndarray, *, sigma: float = 5.0, max_stars: int = 100, min_area: int = 10,
                        max_area: int = 300, max_ab: float = 12.0,
                        saturation: float | None = None) -> Centroids:
    """Detect and centroid stars the way thesis 004 does (see the module docstring).

    Parameters
    ----------
    image : (H, W) float32 array
        The frame, ADU.
    sigma : float
        ``Δth = sigma·σ`` above each row's level.
    max_stars : int
        Keep the brightest this many.
    min_area, max_area : int
        Accepted region sizes, pixels (thesis: 10 and 300).
    max_ab : float
        Largest accepted difference of the long and short extents, pixels (thesis: 12).
    saturation : float, optional
        Saturation level for the flag (default: :func:`skyfix.detect.saturation_level`).
    """
    img = np.ascontiguousarray(image, dtype=np.float32)
    h, w = img.shape
    row_level = np.median(img, axis=1).astype(np.float64)
    step = max(1, int(math.sqrt(img.size / 65536)))
    sample = (img[::step, ::step] - row_level[::step, None]).astype(np.float64).ravel()
    quantum = 1.0 if np.all(img[::step, ::step] == np.floor(img[::step, ::step])) else 0.0
    _, noise = robust_level_noise(sample, quantum, False)
    if not noise > 0:
        return Centroids.empty((h, w), float(np.median(row_level)), noise, reason="flat frame")
    dth = sigma * noise
    sat = saturation_level(img) if saturation is None else float(saturation)
    r = _grow(img, row_level + dth, float(dth), int(min_area), int(max_area), float(max_ab), sat)
    level = float(np.median(row_level))
    if len(r.x) == 0:
        return Centroids.empty((h, w), level, noise)
    keep = np.argsort(-r.brightness, kind="stable")[:max_stars]
    flux = r.brightness[keep]
    n = np.maximum(r.npix[keep], 1.0)
    # centroid noise of a region-weighted mean: σ·√(n·(extent²/12)) / Σb, a rough figure
    sig = noise * np.sqrt(n * (np.maximum(r.along[keep], 1.0) ** 2 / 12.0)) / flux
    return Centroids(
        x=r.x[keep], y=r.y[keep], flux=flux, area=r.npix[keep], snr=background_snr(flux, noise, r.npix[keep]),
        elongation=np.maximum(r.along[keep], 1.0) / np.maximum(r.across[keep], 1.0), peak=r.peak[keep],
        sigma_x=sig, sigma_y=sig, saturated=r.nsat[keep] > 0, image_shape=(h, w),
        background_level=level, noise=noise, meta={"method": "region_grow", "delta_threshold": dth})


@njit(cache=True)
def _grow(img, thr_row, dth, min_area, max_area, max_ab, saturation):
    """Steps 2–7 of the module docstring: the accepted :class:`_Regions`."""
    h, w = img.shape
    erased = np.zeros((h, w), np.uint8)
    stack = np.empty(h * w, np.int64)
    members = np.empty(h * w, np.int64)
    rows = []
    for y0 in range(1, h, 3):
        for x0 in range(1, w, 3):
            if erased[y0, x0] or img[y0, x0] <= thr_row[y0]:
                continue
            # breadth-first growth over 4-neighbours, erasing as it goes
            erased[y0, x0] = 1
            stack[0] = y0 * w + x0
            top = 1
            n = 0
            edge = False
            while top > 0:
                top -= 1
                p = stack[top]
                members[n] = p
                n += 1
                py, px = p // w, p % w
                if py == 0 or px == 0 or py == h - 1 or px == w - 1:
                    edge = True
                for k in range(4):
                    qy = py + (1 if k == 0 else -1 if k == 1 else 0)
                    qx = px + (1 if k == 2 else -1 if k == 3 else 0)
                    if 0 <= qy < h and 0 <= qx < w and not erased[qy, qx] and img[qy, qx] > thr_row[qy]:
                        erased[qy, qx] = 1
                        stack[top] = qy * w + qx
                        top += 1
            if n < min_area or n > max_area or edge:
                continue
            sb = sbx = sby = 0.0
            ux = uy = 0.0
            peak = -np.inf
            nsat = 0
            for i in range(n):
                py, px = members[i] // w, members[i] % w
                b = img[py, px] - thr_row[py]
                sb += b
                sbx += b * px
                sby += b * py
                ux += px
                uy += py
                peak = max(peak, img[py, px] - (thr_row[py] - dth))
                if img[py, px] >= saturation:
                    nsat += 1
            if sb <= 0:
                continue
            ux /= n
            uy /= n
            m20 = m02 = m11 = 0.0
            for i in range(n):
                dx = members[i] % w - ux
                dy = members[i] // w - uy
                m20 += dx * dx
                m02 += dy * dy
                m11 += dx * dy
            lam = 0.5 * math.atan2(2.0 * m11, m20 - m02)
            c, s = math.cos(lam), math.sin(lam)
            amin = bmin = np.inf
            amax = bmax = -np.inf
            for i in range(n):
                dx = members[i] % w - ux
                dy = members[i] // w - uy
                along = dx * c + dy * s
                across = -dx * s + dy * c
                amin, amax = min(amin, along), max(amax, along)
                bmin, bmax = min(bmin, across), max(bmax, across)
            a_ext = amax - amin + 1.0
            b_ext = bmax - bmin + 1.0
            if a_ext - b_ext >= max_ab:
                continue
            brightness = sb + K_AREA * n * dth
            rows.append((sbx / sb, sby / sb, brightness, float(n), peak, a_ext, b_ext, float(nsat)))
    cols = np.empty((8, len(rows)))
    for i in range(len(rows)):
        for j in range(8):
            cols[j, i] = rows[i][j]
    return _Regions(cols[0], cols[1], cols[2], cols[3], cols[4], cols[5], cols[6], cols[7])
