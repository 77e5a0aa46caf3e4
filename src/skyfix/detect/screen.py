"""Rejections: which measured candidates are stars (step 6 of the default extractor).

Hot pixels (too sharp even after leaving up to three out); particle tracks (narrower than
starlight); diffuse blobs (foliage, cloud, nebulae: far larger ``flux/peak`` than the frame's
typical star); anything in or next to a cluttered tile (tile noise > ``max_noise_ratio`` × the
median: lit trees, roofs, a comet). :func:`screen` runs them all in one kernel: dozens of small
numpy calls would cost more than the tests.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix.detect._grid import value_near
from skyfix.detect._stats import median, percentile_linear
from skyfix.detect.centroids import background_snr

__all__ = ["Rejections", "Screened", "screen", "particle_tracks", "diffuse", "cluttered"]

# A diffuse object must have a faint peak, below this many σ, to be dropped at the lower ratio.
_DIFFUSE_MAX_PEAK_SNR = 15.0
_DIFFUSE_PERCENTILE = 30
# A particle track's variance across, relative to a typical star's, is below this.
_TRACK_WIDTH_RATIO = 0.4


class Rejections(NamedTuple):
    """The tests of :func:`screen` (see :func:`skyfix.detect.extract_centroids` for each)."""

    sigma: float  #: a candidate that lost hot pixels must keep this SNR
    min_sharpness: float
    max_elongation: float  #: ``inf``: no limit
    reject_tracks: bool
    max_diffuseness: float  #: NaN: no test
    max_noise_ratio: float  #: NaN: no test


class Screened(NamedTuple):
    """Each candidate's noise σ at its centroid (ADU), elongation, SNR, and whether it is a star."""

    noise: np.ndarray
    elongation: np.ndarray
    snr: np.ndarray
    good: np.ndarray


@njit(cache=True, inline="always")
def screen(m, is_part, sky, rules):
    """Noise, elongation and SNR of the measured candidates, and which of them are stars.

    ``m`` are the measurements (a :data:`~skyfix.detect.measure.MEASUREMENT` array),
    ``is_part`` whether each is a deblended part, ``sky`` the
    :class:`~skyfix.detect._grid.SkyGrid`, ``rules`` the :class:`Rejections`. The tests run in
    this order, each on the survivors of the ones before: flux > 0, sharpness, hot pixels,
    ``max_elongation``, particle tracks (:func:`particle_tracks`), diffuse blobs
    (:func:`diffuse`), cluttered tiles (:func:`cluttered`). Returns the :class:`Screened`
    candidates. Written into its one caller, the extractor's kernel
    (:func:`~skyfix.detect.components._measure_and_screen` says why).
    """
    sigma, min_sharpness, max_elongation, reject_tracks, max_diffuseness, max_noise_ratio = rules
    n = m.size
    noise_px = np.empty(n)
    elong = np.empty(n)
    snr = np.empty(n)
    minor = np.empty(n)
    good = np.zeros(n, np.bool_)
    for c in range(n):
        flux, npix = m[c].flux, m[c].npix
        mxx, myy, mxy = m[c].mxx, m[c].myy, m[c].mxy
        noise_px[c] = value_near(sky.noise, sky.weights, m[c].x, m[c].y)
        tr = mxx + myy
        det = math.sqrt(max((mxx - myy) * (mxx - myy) + 4.0 * (mxy * mxy), 0.0))
        # the 1/12 px² of a uniform pixel keeps a one-pixel object's minor axis above zero
        lam1, lam2 = 0.5 * (tr + det) + 1.0 / 12.0, max(0.5 * (tr - det), 0.0) + 1.0 / 12.0
        elong[c] = math.sqrt(lam1 / lam2)
        minor[c] = 0.5 * (tr - det)
        snr[c] = background_snr(flux, noise_px[c], npix)
        # hot pixels: too sharp even after leaving out up to 3 of them, or nothing left but
        # noise; a deblended part around a hot pixel is only a neighbouring star's wing
        good[c] = (flux > 0) and (m[c].sharpness >= min_sharpness) and (
            m[c].n_hot == 0 or (snr[c] >= sigma and not is_part[c]))
        if elong[c] > max_elongation:
            good[c] = False
    if reject_tracks:
        good &= ~particle_tracks(minor, elong, snr, good)
    if not math.isnan(max_diffuseness):
        good &= ~diffuse(m.flux, m.peak, snr, m.peak / noise_px, m.nsat > 0, good, max_diffuseness)
    if not math.isnan(max_noise_ratio):
        good &= ~cluttered(sky.noise_smooth, sky.centers_y, sky.centers_x, m.x, m.y, max_noise_ratio)
    return Screened(noise_px, elong, snr, good)


@njit(cache=True)
def particle_tracks(minor_var, elong, snr, candidate):
    """Cosmic-ray and other particle tracks: narrower across than any starlight.

    Starlight passes the optics, so even a trailed star keeps the PSF's width across its
    trail; a particle track or hit is about one pixel wide. A candidate whose variance across
    is below ``_TRACK_WIDTH_RATIO`` of the frame's typical (compact, SNR > 10) star's and that is
    longer than 1.5:1 is a track; below half that ratio it is one whatever its length. Only
    candidates with SNR ≥ 20 are judged: a faint star's footprint holds just its core, so its
    moments look narrow too.
    """
    compact = candidate & (elong < 1.5) & (snr > 10.0)
    if compact.sum() < 3:
        return np.zeros(elong.size, np.bool_)
    rel = minor_var / median(minor_var[compact])
    narrow = ((elong > 1.5) & (rel < _TRACK_WIDTH_RATIO)) | (rel < 0.5 * _TRACK_WIDTH_RATIO)
    return narrow & (snr >= 20.0)


@njit(cache=True)
def diffuse(flux, peak, snr, peak_snr, saturated, candidate, ratio):
    """Objects far more spread out than the frame's typical star (see ``max_diffuseness``)."""
    aeff = flux / np.maximum(peak, 1e-30)
    typical = candidate & ~saturated & (snr > 10.0)
    if not typical.any():
        return np.zeros(flux.size, np.bool_)
    rel = aeff / percentile_linear(aeff[typical], _DIFFUSE_PERCENTILE / 100.0)
    return ((rel > ratio) & (peak_snr < _DIFFUSE_MAX_PEAK_SNR)) | ((rel > ratio * 10.0 / 3.0) & ~saturated)


@njit(cache=True)
def cluttered(noise_smooth, centers_y, centers_x, x, y, ratio):
    """Positions in or next to a tile whose noise exceeds ``ratio`` × the frame's median noise.

    The neighbouring tiles count too because lit foreground thins out at its edge (the last
    leaves of a tree) while its tile noise is already back to normal.
    """
    ny, nx = noise_smooth.shape
    noisy = noise_smooth > ratio * median(noise_smooth.ravel())
    out = np.zeros(x.size, np.bool_)
    if not noisy.any():
        return out
    if ny > 1 and nx > 1:
        grown = np.zeros_like(noisy)
        for i in range(ny):
            for j in range(nx):
                if noisy[i, j]:
                    grown[max(i - 1, 0):i + 2, max(j - 1, 0):j + 2] = True
        noisy = grown
    for c in range(x.size):
        out[c] = noisy[_nearest_index(centers_y, y[c]), _nearest_index(centers_x, x[c])]
    return out


@njit(cache=True)
def _nearest_index(centers, v):
    """Index of the nearest tile centre (the first one on a tie)."""
    best, bd = 0, abs(v - centers[0])
    for k in range(1, centers.size):
        d = abs(v - centers[k])
        if d < bd:
            best, bd = k, d
    return best
