"""Point-spread function: Gaussians integrated over each pixel, added to an image.

Pixel ``(col, row)`` covers ``[col - 0.5, col + 0.5] × [row - 0.5, row + 0.5]`` (docs/design.md:
``(0, 0)`` is the centre of the top-left pixel). A round Gaussian is separable, so a pixel's
share is a product of error-function differences, exact at any sub-pixel phase (thesis 002
sampled a 5×5 grid and renormalised a truncated 5×5 stamp; both biases are gone here).

An elliptical, rotated Gaussian is not separable. Each pixel row is cut into strips; a strip's
share is exact (the y marginal, by erf), and x within the strip follows the exact conditional
Gaussian about the strip's conditional mean ``E[y | strip]`` — so total flux and both centroid
coordinates stay exact; only the x profile inside a strip is approximated.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import erf

from skyfix._jit import njit

__all__ = ["pixel_integrated_stamps", "add_gaussians"]

_SQRT2 = math.sqrt(2.0)
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


def _cdf(z: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + erf(z / _SQRT2))


def pixel_integrated_stamps(x: np.ndarray, y: np.ndarray, sxx: np.ndarray, syy: np.ndarray,
                            sxy: np.ndarray, half: int, strips: int = 1
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit-flux Gaussian stamps integrated over pixels.

    Parameters
    ----------
    x, y : (N,) arrays
        Centres, pixels.
    sxx, syy, sxy : (N,) arrays
        Covariance entries, px².
    half : int
        Stamp half-size; stamps are ``(2·half + 1)²`` pixels around the nearest pixel.
    strips : int
        Strips per pixel row for elliptical PSFs (1 is exact when ``sxy == 0``).

    Returns
    -------
    stamps : (N, S, S) float64
        Fraction of each source's light in each stamp pixel.
    row0, col0 : (N,) int64
        Row and column of each stamp's top-left pixel.
    """
    p, wx, row0, col0 = _shares(x, y, sxx, syy, sxy, half, strips)
    size = 2 * half + 1
    stamps = (p[:, :, None] * wx).reshape(len(p), size, strips, size).sum(axis=2)
    return stamps, row0, col0


def _shares(x: np.ndarray, y: np.ndarray, sxx: np.ndarray, syy: np.ndarray, sxy: np.ndarray, half: int,
            strips: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The factors of :func:`pixel_integrated_stamps`: each strip's share ``p`` (N, S·strips) and
    the x shares ``wx`` within it (N, S·strips, S) — (N, 1, S) for round Gaussians, the same in
    every row — with the stamps' top-left rows and columns; a stamp is their product."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    size = 2 * half + 1
    col0 = np.rint(x).astype(np.int64) - half
    row0 = np.rint(y).astype(np.int64) - half
    sy = np.sqrt(syy)[:, None]
    k = (sxy / syy)[:, None]  # regression of x on y
    sc = np.sqrt(np.maximum(sxx - sxy * sxy / syy, 1e-12))[:, None]  # conditional σ of x
    # strip edges in y, relative to the source centre
    edges = (row0[:, None] - 0.5 + np.arange(size * strips + 1)[None, :] / strips) - y[:, None]
    za = edges / sy
    cdf = _cdf(za)
    p = np.diff(cdf, axis=1)  # (N, S·strips) exact strip shares
    if strips > 1 or np.any(sxy != 0):
        pdf = np.exp(-0.5 * za * za) * _INV_SQRT_2PI
        mid = 0.5 * (edges[:, 1:] + edges[:, :-1])
        with np.errstate(invalid="ignore", divide="ignore"):
            ey = sy * (pdf[:, :-1] - pdf[:, 1:]) / p  # E[y - μy | strip]
        ey = np.where(p > 1e-300, ey, mid)
        mx = x[:, None] + k * ey  # (N, S·strips) conditional means of x
    else:  # a round Gaussian: x's profile is the same in every row, computed once (S× fewer erfs)
        mx = x[:, None]
    xe = (col0[:, None] - 0.5 + np.arange(size + 1)[None, :]).astype(np.float64)  # (N, S+1)
    cx = _cdf((xe[:, None, :] - mx[:, :, None]) / sc[:, :, None])  # (N, S·strips or 1, S+1)
    wx = np.diff(cx, axis=2)  # (N, S·strips or 1, S)
    return p, wx, row0, col0


@njit(cache=True, nogil=True)
def _scatter(image, p, wx, flux, row0, col0):
    """Add stamp ``i`` times ``flux[i]`` to ``image`` at (``row0[i]``, ``col0[i]``), the pixels
    outside the frame left out. A stamp is given as factors: its pixel (a, b) is
    ``p[i, a] * wx[i, a, b]`` — or ``p[i, a] * wx[i, 0, b]`` when ``wx`` has one row (a round
    Gaussian, separable: the (N, S, S) stamps are never made); a whole stamp is ``p`` = 1 and
    ``wx`` the stamps (1 × x is x: the same numbers)."""
    h, w = image.shape
    n, s = p.shape
    one_row = wx.shape[1] == 1
    for i in range(n):
        f = flux[i]
        r0 = row0[i]
        c0 = col0[i]
        for a in range(s):
            r = r0 + a
            if r < 0 or r >= h:
                continue
            ra = 0 if one_row else a
            for b in range(s):
                c = c0 + b
                if 0 <= c < w:
                    image[r, c] += f * (p[i, a] * wx[i, ra, b])


def add_gaussians(image: np.ndarray, x: np.ndarray, y: np.ndarray, flux: np.ndarray,
                  sxx: np.ndarray, syy: np.ndarray, sxy: np.ndarray, *, strips: int = 4,
                  n_sigma: float = 6.0, chunk: int = 4096) -> np.ndarray:
    """Add pixel-integrated Gaussians of total ``flux`` at ``(x, y)`` to ``image`` in place.

    Light falling outside the image is lost, as on a real detector. ``n_sigma`` sets the stamp
    half-size (the light beyond 6σ is < 1e-8 of the total). Returns ``image``.
    """
    x = np.atleast_1d(np.asarray(x, dtype=np.float64))
    y = np.atleast_1d(np.asarray(y, dtype=np.float64))
    n = len(x)
    flux = np.broadcast_to(np.asarray(flux, dtype=np.float64), (n,))
    sxx = np.broadcast_to(np.asarray(sxx, dtype=np.float64), (n,))
    syy = np.broadcast_to(np.asarray(syy, dtype=np.float64), (n,))
    sxy = np.broadcast_to(np.asarray(sxy, dtype=np.float64), (n,))
    h, w = image.shape
    # Sources whose stamp cannot touch the frame are skipped.
    reach = n_sigma * np.sqrt(np.maximum(sxx, syy)) + 1.0
    keep = ((x > -0.5 - reach) & (x < w - 0.5 + reach) & (y > -0.5 - reach) & (y < h - 0.5 + reach)
            & (flux != 0))
    idx = np.flatnonzero(keep)
    if idx.size == 0:
        return image
    elliptical = bool(np.any(sxy[idx] != 0))
    for start in range(0, idx.size, chunk):
        j = idx[start:start + chunk]
        half = int(math.ceil(n_sigma * math.sqrt(float(max(sxx[j].max(), syy[j].max())))))
        half = max(half, 1)
        if elliptical:
            wx, row0, col0 = pixel_integrated_stamps(x[j], y[j], sxx[j], syy[j], sxy[j], half, strips)
            p = np.ones(wx.shape[:2])
        else:  # separable: the stamps' two factors scattered, never the (N, S, S) stamps
            p, wx, row0, col0 = _shares(x[j], y[j], sxx[j], syy[j], sxy[j], half, 1)
        _scatter(image, p, np.ascontiguousarray(wx), np.ascontiguousarray(flux[j]), row0, col0)
    return image
