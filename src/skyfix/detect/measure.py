"""Measurement: centroid, flux, peak, moments and hot-pixel sharpness of each candidate.

Step 5 of the default extractor (:mod:`skyfix.detect.components`): each candidate is measured on
the raw frame minus the interpolated sky, over its component grown by one pixel so that faint
wings count — intensity-weighted centroid (negative residuals weigh zero), flux (plain sum),
peak, second moments (→ elongation and direction), and the unweighted spreads that give the
centroid's noise σ. A peak sharper than optics allow is a hot pixel (:func:`sharpness`): it is
left out and the star measured again.
"""

from __future__ import annotations

import numpy as np

from skyfix._jit import njit
from skyfix.detect._grid import grid_at
from skyfix.detect._stats import sum_sq_dev

__all__ = ["MEASUREMENT", "measure", "residual", "sharpness"]


#: What :func:`measure` finds for a candidate (all zeros: nothing above the sky), float64: the
#: flux (sum of the pixels minus the sky, ADU); the intensity-weighted centroid ``x, y``
#: (positive residuals, pixels); ``npix`` pixels measured; the ``peak`` residual (ADU) and its
#: :func:`sharpness`; the intensity-weighted second central moments ``mxx, myy, mxy`` (px²);
#: the unweighted spreads ``Σ(x − x̄)², Σ(y − ȳ)²`` about the centroid (px², for its noise σ);
#: ``nsat`` pixels at or above the saturation level; ``n_hot`` hot pixels left out.
MEASUREMENT = np.dtype([(name, np.float64) for name in (
    "flux", "x", "y", "npix", "peak", "sharpness", "mxx", "myy", "mxy", "spread_x", "spread_y", "nsat",
    "n_hot")])


@njit(cache=True, inline="always")
def residual(img, sky, y, x):
    """The raw frame minus its sky (``sky.level``, interpolated) at pixel (y, x)."""
    return img[y, x] - grid_at(sky.level, sky.weights, y, x)


@njit(cache=True)
def sharpness(img, sky, py, px, peak):
    """Mean of the neighbours of (py, px) but the brightest, over the peak, above the sky.

    ``peak`` is the residual at (py, px). Leaving out the brightest neighbour makes two
    adjacent hot pixels as sharp as one, while a star centred between two pixels keeps its
    other neighbours.
    """
    h, w = img.shape
    nb = 0.0
    top = -np.inf
    cnt = 0
    for qy in range(max(py - 1, 0), min(py + 2, h)):
        for qx in range(max(px - 1, 0), min(px + 2, w)):
            if qy != py or qx != px:
                r = residual(img, sky, qy, qx)
                nb += r
                top = max(top, r)
                cnt += 1
    if cnt < 2 or peak <= 0:
        return 0.0
    return ((nb - top) / (cnt - 1)) / peak


@njit(cache=True)
def measure(img, labels, cand, sky, saturation, min_sharpness):
    """Centroid and moments of each candidate grown by one pixel, on the raw frame minus sky.

    ``labels`` as the labelling (and deblending) left them; ``cand`` the candidates (a
    :data:`~skyfix.detect.labelling.CANDIDATE` array); ``sky`` the
    :class:`~skyfix.detect._grid.SkyGrid` (its raw-frame level is subtracted). A peak sharper
    than ``min_sharpness`` is a hot pixel: it is left out and the component measured again (up
    to 3 times), so a hot pixel on a star does not take the star with it. A candidate with no
    light above the sky keeps zeros. Returns a :data:`MEASUREMENT` array.
    """
    h, w = img.shape
    m = np.zeros(cand.size, MEASUREMENT)
    skip_y = np.empty(4, np.int64)
    skip_x = np.empty(4, np.int64)
    for c in range(cand.size):
        lab = cand[c].id
        y0, y1 = max(cand[c].y0 - 1, 0), min(cand[c].y1 + 1, h - 1)
        x0, x1 = max(cand[c].x0 - 1, 0), min(cand[c].x1 + 1, w - 1)
        nskip = 0
        for _attempt in range(4):
            sw = swx = swy = swxx = swyy = swxy = 0.0
            total = 0.0  # plain sum: clipping negative pixels would bias faint fluxes up
            sx = sy = sxx = syy = 0.0
            npix = 0
            nsat = 0
            peak = -np.inf
            py, px = y0, x0  # (not a literal 0: sharpness would compile for it too)
            for y in range(y0, y1 + 1):
                for x in range(x0, x1 + 1):
                    lv = labels[y, x]
                    if lv != lab:
                        if lv != 0:
                            continue
                        near = False
                        for qy in range(max(y - 1, 0), min(y + 2, h)):
                            for qx in range(max(x - 1, 0), min(x + 2, w)):
                                if labels[qy, qx] == lab:
                                    near = True
                                    break
                            if near:
                                break
                        if not near:
                            continue
                    skipped = False
                    for i in range(nskip):
                        if skip_y[i] == y and skip_x[i] == x:
                            skipped = True
                    if skipped:
                        continue
                    r = residual(img, sky, y, x)
                    npix += 1
                    total += r
                    sx += x
                    sy += y
                    sxx += x * x
                    syy += y * y
                    if img[y, x] >= saturation:
                        nsat += 1
                    if r > peak:
                        peak, py, px = r, y, x
                    if r > 0.0:
                        sw += r
                        swx += r * x
                        swy += r * y
                        swxx += r * x * x
                        swyy += r * y * y
                        swxy += r * x * y
            if sw <= 0.0:
                break
            sharp = sharpness(img, sky, py, px, peak)
            if sharp >= min_sharpness or nskip == skip_y.size:
                break
            skip_y[nskip] = py
            skip_x[nskip] = px
            nskip += 1
        if sw <= 0.0:
            continue
        xc, yc = swx / sw, swy / sw
        m[c].flux = total
        m[c].x = xc
        m[c].y = yc
        m[c].npix = npix
        m[c].peak = peak
        m[c].sharpness = sharp
        m[c].mxx = max(swxx / sw - xc * xc, 0.0)
        m[c].myy = max(swyy / sw - yc * yc, 0.0)
        m[c].mxy = swxy / sw - xc * yc
        m[c].spread_x = sum_sq_dev(sxx, sx, npix, xc)
        m[c].spread_y = sum_sq_dev(syy, sy, npix, yc)
        m[c].nsat = nsat
        m[c].n_hot = nskip
    return m
