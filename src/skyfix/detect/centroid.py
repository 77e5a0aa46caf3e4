"""Centroiders in small windows: centre of mass, iteratively weighted CoM, 2-D Gaussian fit.

All three work on a square window of the frame around a first guess, with a known sky level
and noise per window, and are run for N windows at once in numba (cost O(N·window²),
independent of the frame size):

``"com"``
    Centre of mass of the pixels above ``sky + k·σ`` with weights ``value − sky`` — thesis
    000/002's centroid with its printed equation corrected (docs/seeds.md#thesis-000-corrections):
    the background ``n`` is subtracted from every pixel's weight, not once from the sum, and the
    window offset is added back. Fast; biased toward the window centre when the threshold cuts
    the wings, and with a pixel-phase S-curve on narrow PSFs.
``"iwcog"``
    Iteratively weighted centre of gravity: weights ``(value − sky)·exp(−r²/2s²)`` about the
    current estimate with ``s`` the PSF σ, iterated to convergence. For a Gaussian PSF and
    background-limited noise it approaches the Cramér–Rao bound and has no threshold bias.
``"gaussian"``
    Least-squares fit of a pixel-integrated elliptical Gaussian (flux, x₀, y₀, σx, σy, sky) by
    Levenberg–Marquardt; the per-star covariance is ``s²·(JᵀJ)⁻¹`` with ``s²`` the residual
    variance. The most accurate; ~10× the cost of CoM.

:func:`centroid_windows` runs one of them at predicted positions (tracking); the extractor
uses the same kernels to refine its components; :func:`cramer_rao_centroid` gives the bound.

How close each comes to the bound, and its S-curve, is measured by ``skyfix analyze
centroids`` (:mod:`skyfix.analysis.centroid_study`; tables in ``docs/centroiding.md``). In short:
the fit reaches ~1.0–1.1 × CRB from σ = 0.5 px when the gain is given (~1.2 × at high SNR
without it, with honest sandwich errors); IWCoG ~1.1–1.2 × from σ = 0.8 px but an S-curve of
0.05 px at σ = 0.5 (its weight is floored at 0.8 px); the thresholded CoM 1.2–4 × (it drops the
wings), and thesis 000's 3×3-ROI CoM a −0.24 px pull toward the pixel centre at σ = 1.2 px.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix.detect._stats import robust_level_noise, window_border
from skyfix.detect.centroids import Centroids, background_snr
from skyfix.errors import unknown_name

__all__ = ["CENTROIDERS", "COM", "IWCOG", "GAUSSIAN", "Centroider", "Refined", "centroid_windows",
           "centroider", "refine_centroids", "refine_kernel", "refined_columns", "cramer_rao_centroid",
           "measure_psf", "Window"]

# The centroiders' codes inside the kernels (numba compiles module-level ints as constants).
COM, IWCOG, GAUSSIAN = 0, 1, 2
#: Centroiders by name (``method=`` here, ``centroid=`` of :func:`~skyfix.detect.extract_centroids`).
CENTROIDERS = {"com": COM, "iwcog": IWCOG, "gaussian": GAUSSIAN}


class Refined(NamedTuple):
    """The columns of :func:`refine_centroids`'s (N, 13) table, by name (:meth:`of` gives views)."""

    x: np.ndarray  #: centroid, pixels
    y: np.ndarray
    flux: np.ndarray  #: sum above the sky (CoM, IWCoG) or the fit's flux, ADU
    peak: np.ndarray  #: highest pixel above the sky, ADU
    sigma_x: np.ndarray  #: centroid's 1-σ error, pixels
    sigma_y: np.ndarray
    cov_xy: np.ndarray  #: its x–y covariance, px² (the fit only)
    npix: np.ndarray  #: pixels above the threshold
    psf_sx: np.ndarray  #: PSF σ along x and y (second moments, or the fit), pixels
    psf_sy: np.ndarray
    ok: np.ndarray  #: 1.0 where a centroid was found
    noise: np.ndarray  #: the window's noise σ and sky level, ADU
    sky: np.ndarray

    @classmethod
    def of(cls, table: np.ndarray) -> Refined:
        """The columns of an (N, 13) table (views, not copies)."""
        return cls(*np.asarray(table).T)

    @property
    def elongation(self) -> np.ndarray:
        """Long over short PSF axis (the short one floored at 1e-6 px)."""
        return np.maximum(self.psf_sx, self.psf_sy) / np.maximum(np.minimum(self.psf_sx, self.psf_sy), 1e-6)


# The kernels' columns, in the order of Refined's fields; a star's row holds the first _NROW
# (the window's noise and sky are added by refine_kernel).
(_X, _Y, _FLUX, _PEAK, _SIGMA_X, _SIGMA_Y, _COV_XY, _NPIX, _PSF_SX, _PSF_SY, _OK, _NOISE, _SKY) = range(13)
_NCOL = len(Refined._fields)
_NROW = _OK + 1


class Centroider(NamedTuple):
    """A centroider as the kernels run it (:func:`centroider` makes one from its name)."""

    code: int  # COM, IWCOG or GAUSSIAN
    k: float  # CoM threshold, in σ above the sky
    psf_sigma: float  # PSF σ for IWCoG's weight and the fit's first guess, px (≤ 0: measured)
    inv_gain: float  # ADU per electron (0: unknown)


class Window(NamedTuple):
    """A star's window, rows y0..y1 and columns x0..x1 inclusive, with its sky level and noise σ
    (here and in the streak fit's kernels, :mod:`skyfix.detect.streak_fit`)."""

    y0: int
    y1: int
    x0: int
    x1: int
    sky: float
    noise: float


class _Profiles(NamedTuple):
    """Scratch for the Gaussian fit: the pixel-integrated profile along x and y and their
    derivatives by the centre and by σ."""

    px: np.ndarray
    dpx_c: np.ndarray
    dpx_s: np.ndarray
    py: np.ndarray
    dpy_c: np.ndarray
    dpy_s: np.ndarray


class _Normal(NamedTuple):
    """The fit's weighted normal equations JᵀWJ (6×6), JᵀWr (6,) and the sandwich's meat (6×6)."""

    jtj: np.ndarray
    jtr: np.ndarray
    meat: np.ndarray


def centroid_windows(
    image: np.ndarray,
    xy_pred: np.ndarray,
    half_size: int = 8,
    *,
    method: str = "com",
    sigma: float = 3.0,
    psf_sigma: float | None = None,
    gain: float | None = None,
) -> Centroids:
    """Centroid one star in a square window around each predicted position (tracking mode).

    Parameters
    ----------
    image : (H, W) array
        The frame, ADU.
    xy_pred : (N, 2) array
        Predicted ``(x, y)`` positions, pixels (docs/design.md#pixel-coordinates).
    half_size : int
        The window is ``2·half_size`` pixels square, centred on the rounded prediction.
    method : {"com", "iwcog", "gaussian"}
        Centroider (see module docstring).
    sigma : float
        Noise threshold k for ``"com"``: pixels above ``sky + k·σ`` count.
    psf_sigma : float, optional
        PSF σ in pixels for ``"iwcog"``'s weight and the fit's first guess; by default it is
        measured from each window's second moments.
    gain : float, optional
        Electrons per ADU. With it, the star's own shot noise enters the weights of the
        Gaussian fit and every centroid's σ; without it the noise is taken as the sky's alone
        (background-limited), and the fit's covariance is the sandwich estimate from its
        residuals.

    Returns
    -------
    Centroids
        One entry per prediction, **in the order given** (not sorted by flux). The sky and
        noise come from each window's border pixels. A window with no pixel above the
        threshold, or outside the frame, gives ``x = y = nan`` and zero flux.
    """
    img = np.ascontiguousarray(image, dtype=np.float32)
    if img.ndim != 2:
        raise ValueError(f"image must be 2-D, got shape {img.shape}")
    xy = np.asarray(xy_pred, dtype=np.float64).reshape(-1, 2)
    how = centroider(method, sigma, psf_sigma, gain)
    hs = int(max(2, half_size))
    out = _windows(img, xy[:, 0].copy(), xy[:, 1].copy(), hs, how)
    return _to_centroids(out, img.shape, ordered=True)


def refine_centroids(
    image: np.ndarray,
    xy: np.ndarray,
    background: np.ndarray,
    noise: np.ndarray,
    half_size: np.ndarray,
    *,
    method: str = "gaussian",
    sigma: float = 3.0,
    psf_sigma: float | None = None,
    gain: float | None = None,
) -> np.ndarray:
    """Refine positions with a centroider given each window's sky level and noise.

    Returns an (N, 13) float64 array: x, y, flux, peak, sigma_x, sigma_y, cov_xy, npix,
    PSF σx, σy (second moments or fit), ok (1.0 where a centroid was found), noise, sky
    (:class:`Refined` names them: ``Refined.of(table).x``).
    """
    how = centroider(method, sigma, psf_sigma, gain)
    img = np.ascontiguousarray(image, dtype=np.float32)
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    n = len(xy)
    return refine_kernel(img, xy[:, 0].copy(), xy[:, 1].copy(), _per_star(background, n, np.float64),
                   _per_star(noise, n, np.float64), _per_star(half_size, n, np.int64), how)


def _per_star(value, n: int, dtype) -> np.ndarray:
    """``value`` as a contiguous (n,) array of ``dtype``: as it is when it already is one (a
    tracker's per-window buffers: no copy), else broadcast (a scalar for every star)."""
    a = np.asarray(value)
    if a.shape == (n,) and a.dtype == dtype and a.flags.c_contiguous:
        return a
    if a.ndim == 0:
        return np.full(n, a, dtype)
    return np.ascontiguousarray(np.broadcast_to(a, (n,)), dtype=dtype)


def measure_psf(image: np.ndarray, xy: np.ndarray, half_size: int = 8) -> dict[str, np.ndarray]:
    """PSF width and shape at given star positions from 2-D Gaussian fits.

    Parameters
    ----------
    image : (H, W) array
    xy : (N, 2) array
        Star positions (e.g. ``extract_centroids(image).xy``), pixels.
    half_size : int
        Fit window half size, pixels.

    Returns
    -------
    dict of (N,) arrays
        ``x``, ``y`` (fitted centre), ``sigma_x``, ``sigma_y`` (Gaussian σ along the pixel axes,
        pixels), ``fwhm`` (``2.3548·√(σx·σy)``, pixels), ``ellipticity`` (``1 − σmin/σmax``) and
        ``ok``. Thesis 000 §5.5 and thesis 003 measure the same across the field; the fit's axes
        are the pixel axes, so a PSF elongated at 45° shows as round but wide.
    """
    img = np.ascontiguousarray(image, dtype=np.float32)
    xyv = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    r = Refined.of(_windows(img, xyv[:, 0].copy(), xyv[:, 1].copy(), int(max(2, half_size)),
                            Centroider(GAUSSIAN, 3.0, -1.0, 0.0)))
    sx, sy, ok = r.psf_sx, r.psf_sy, r.ok > 0
    big, small = np.maximum(sx, sy), np.maximum(np.minimum(sx, sy), 1e-12)
    x, y = np.where(ok, r.x, np.nan), np.where(ok, r.y, np.nan)
    return {"x": x, "y": y, "sigma_x": np.where(ok, sx, np.nan), "sigma_y": np.where(ok, sy, np.nan),
            "fwhm": np.where(ok, 2.0 * math.sqrt(2.0 * math.log(2.0)) * np.sqrt(sx * sy), np.nan),
            "ellipticity": np.where(ok, 1.0 - small / big, np.nan), "ok": ok}


def cramer_rao_centroid(sigma_psf_px: float, flux_e: float, background_e: float = 0.0,
                        read_noise_e: float = 0.0, *, phase: tuple[float, float] = (0.0, 0.0)) -> float:
    """Cramér–Rao lower bound on the x (or y) error of a star position, pixels (1-σ).

    Model: a circular Gaussian PSF of σ ``sigma_psf_px`` integrated over square pixels, total
    ``flux_e`` electrons, ``background_e`` electrons of sky per pixel (Poisson), Gaussian read
    noise ``read_noise_e`` electrons per pixel. Pixel variance ``μ_i + b + r²``; the Fisher
    information for x₀ is ``Σ (∂μ_i/∂x₀)² / (μ_i + b + r²)`` (sky and flux known), and the bound
    is its inverse square root. ``phase`` is the star's offset from a pixel centre, pixels.

    Limits: background-limited and wide PSF → ``√(8π b)·σ²/F``; photon-limited → ``σ/√F``.
    """
    s = float(sigma_psf_px)
    f = float(flux_e)
    if not (s > 0 and f > 0):
        raise ValueError("sigma_psf_px and flux_e must be positive")
    var_floor = float(background_e) + float(read_noise_e) ** 2
    r = int(math.ceil(8 * s + 3))
    edges = np.arange(-r, r + 2, dtype=np.float64) - 0.5
    x0, y0 = phase
    from scipy.special import erf

    sq = math.sqrt(2.0) * s
    px = np.diff(0.5 * erf((edges - x0) / sq))
    py = np.diff(0.5 * erf((edges - y0) / sq))
    # d/dx0 of the pixel integral: −(g(right edge) − g(left edge))
    gx = np.exp(-0.5 * ((edges - x0) / s) ** 2) / (math.sqrt(2 * math.pi) * s)
    dpx = -np.diff(gx)
    mu = f * np.outer(py, px)
    dmu = f * np.outer(py, dpx)
    var = mu + var_floor
    # far pixels carry no information, and their erf differences cancel to zero
    use = mu > 1e-12 * f
    fisher = float(np.sum(dmu[use] ** 2 / var[use]))
    return 1.0 / math.sqrt(fisher) if fisher > 0 else math.inf


def _inv_gain(gain: float | None) -> float:
    if gain is None:
        return 0.0
    if not gain > 0:
        raise ValueError(f"gain must be positive (electrons per ADU), got {gain}")
    return 1.0 / float(gain)


def centroider(method: str, sigma: float = 3.0, psf_sigma: float | None = None, gain: float | None = None
               ) -> Centroider:
    """The :class:`Centroider` of ``method`` (a name of :data:`CENTROIDERS`) with the keywords of
    :func:`centroid_windows`; ValueError for an unknown name or a gain that is not positive."""
    try:
        code = CENTROIDERS[method]
    except (KeyError, TypeError):
        raise unknown_name("centroider", method, CENTROIDERS) from None
    return Centroider(code, float(sigma), -1.0 if psf_sigma is None else float(psf_sigma), _inv_gain(gain))


def _to_centroids(out: np.ndarray, shape, ordered: bool) -> Centroids:
    r = Refined.of(out)
    bad = r.ok == 0
    snr = background_snr(r.flux, r.noise, r.npix)
    return Centroids(
        x=np.where(bad, np.nan, r.x), y=np.where(bad, np.nan, r.y), flux=np.where(bad, 0.0, r.flux),
        area=r.npix, snr=np.where(bad, 0.0, snr), elongation=np.where(bad, np.nan, r.elongation), peak=r.peak,
        sigma_x=np.where(bad, np.nan, r.sigma_x), sigma_y=np.where(bad, np.nan, r.sigma_y),
        saturated=np.zeros(len(r.x), bool), image_shape=shape, cov_xy=np.where(bad, 0.0, r.cov_xy),
        background_level=float(np.median(r.sky)) if len(r.sky) else 0.0,
        noise=float(np.median(r.noise)) if len(r.noise) else 0.0, meta={"ordered": ordered})


# --- numba kernels ------------------------------------------------------------------------


@njit(cache=True)
def refined_columns(table):
    """The columns of :func:`refine_kernel`'s (N, 13) table as a :class:`Refined` of views
    (``Refined.of`` inside a kernel)."""
    return Refined(table[:, _X], table[:, _Y], table[:, _FLUX], table[:, _PEAK], table[:, _SIGMA_X],
                   table[:, _SIGMA_Y], table[:, _COV_XY], table[:, _NPIX], table[:, _PSF_SX],
                   table[:, _PSF_SY], table[:, _OK], table[:, _NOISE], table[:, _SKY])


@njit(cache=True)
def _windows(img, xs, ys, hs, how):
    """Sky and noise from each window's border, then the centroider ``how`` (a :class:`Centroider`)."""
    h, w = img.shape
    n = xs.size
    bg = np.zeros(n)
    nz = np.zeros(n)
    half = np.full(n, hs, np.int64)
    buf = np.empty(8 * hs + 8, np.float64)
    for i in range(n):
        if not (np.isfinite(xs[i]) and np.isfinite(ys[i])):
            continue
        cx, cy = int(round(xs[i])), int(round(ys[i]))
        y0, y1 = max(cy - hs, 0), min(cy + hs - 1, h - 1)
        x0, x1 = max(cx - hs, 0), min(cx + hs - 1, w - 1)
        if y1 - y0 < 2 or x1 - x0 < 2:
            continue
        m = window_border(img, y0, y1, x0, x1, buf)
        bg[i], nz[i] = robust_level_noise(buf[:m].copy(), 0.0, False)
    return refine_kernel(img, xs, ys, bg, nz, half, how)


@njit(cache=True)
def refine_kernel(img, xs, ys, bg, nz, half, how):
    """The centroider ``how`` (a :class:`Centroider`) in the window of half size ``half[i]``
    around each position ``(xs[i], ys[i])`` of the float32 image ``img``, with the sky ``bg[i]``
    and noise ``nz[i]``; returns the (N, 13) table of :class:`Refined` (:func:`refine_centroids`
    without its argument handling, for other kernels: the tracker's windows)."""
    h, w = img.shape
    n = xs.size
    out = np.zeros((n, _NCOL))
    for i in range(n):
        out[i, _NOISE] = nz[i]
        out[i, _SKY] = bg[i]
        if not (np.isfinite(xs[i]) and np.isfinite(ys[i])):
            continue
        hs = half[i]
        cx, cy = int(round(xs[i])), int(round(ys[i]))
        y0, y1 = max(cy - hs, 0), min(cy + hs - 1, h - 1)
        x0, x1 = max(cx - hs, 0), min(cx + hs - 1, w - 1)
        if y1 < y0 or x1 < x0:
            continue
        win = Window(y0, y1, x0, x1, bg[i], nz[i])
        res = _com(img, win, how.k, how.inv_gain)
        if res[_OK] == 0.0:
            continue
        if how.code == IWCOG:
            # a weight narrower than ~0.8 px locks onto pixel centres (S-curve): floor it
            s = how.psf_sigma
            if not s > 0:
                s = math.sqrt(0.5 * (res[_PSF_SX] ** 2 + res[_PSF_SY] ** 2))
            res = _iwcog(img, win, res, max(s, 0.8), how.inv_gain)
        elif how.code == GAUSSIAN:
            s = how.psf_sigma if how.psf_sigma > 0 else -1.0
            res = _gauss_fit(img, win, res, s, how.inv_gain)
        out[i, :_NROW] = res
    return out


@njit(cache=True)
def _com(img, win, k, ig):
    """Thresholded centre of mass in the window; also second-moment σx, σy. A row of :data:`_NROW`."""
    y0, y1, x0, x1, bg, nz = win
    r = np.zeros(_NROW)
    thr = k * nz
    sw = swx = swy = swxx = swyy = 0.0
    a = ax = ay = axx = ayy = 0.0  # Σ var, Σ var·x, ... for the centroid's σ
    npix = 0
    peak = -np.inf
    for y in range(y0, y1 + 1):
        for x in range(x0, x1 + 1):
            v = img[y, x] - bg
            if v > peak:
                peak = v
            if v > thr:
                sw += v
                swx += v * x
                swy += v * y
                swxx += v * x * x
                swyy += v * y * y
                var = nz * nz + v * ig
                a += var
                ax += var * x
                ay += var * y
                axx += var * x * x
                ayy += var * y * y
                npix += 1
    if sw <= 0.0 or npix == 0:
        return r
    xc, yc = swx / sw, swy / sw
    r[_X] = xc
    r[_Y] = yc
    r[_FLUX] = sw
    r[_PEAK] = peak
    # var(x̄) = Σ var_i (x_i − x̄)² / F²
    r[_SIGMA_X] = math.sqrt(max(axx - 2 * xc * ax + xc * xc * a, 0.0)) / sw
    r[_SIGMA_Y] = math.sqrt(max(ayy - 2 * yc * ay + yc * yc * a, 0.0)) / sw
    r[_NPIX] = npix
    r[_PSF_SX] = math.sqrt(max(swxx / sw - xc * xc, 0.0))
    r[_PSF_SY] = math.sqrt(max(swyy / sw - yc * yc, 0.0))
    r[_OK] = 1.0
    return r


@njit(cache=True)
def _iwcog(img, win, start, s, ig):
    """Gaussian-weighted centre of gravity iterated from the row ``start``; weights (v − bg)·W."""
    y0, y1, x0, x1, bg, nz = win
    r = start.copy()
    xc, yc = start[_X], start[_Y]
    inv = 1.0 / (2.0 * s * s)
    for _ in range(30):
        sw = swx = swy = 0.0
        sxx2 = syy2 = 0.0
        dxx = dyy = 0.0
        for y in range(y0, y1 + 1):
            dy2 = (y - yc) ** 2
            for x in range(x0, x1 + 1):
                v = img[y, x] - bg
                wgt = math.exp(-((x - xc) ** 2 + dy2) * inv)
                sw += v * wgt
                swx += v * wgt * x
                swy += v * wgt * y
                var = nz * nz + max(v, 0.0) * ig
                sxx2 += wgt * wgt * var * (x - xc) ** 2
                syy2 += wgt * wgt * var * (y - yc) ** 2
                dxx += v * wgt * (x - xc) ** 2
                dyy += v * wgt * (y - yc) ** 2
        if sw <= 0.0:
            return r
        nx_, ny_ = swx / sw, swy / sw
        if abs(nx_ - xc) > 3 * s or abs(ny_ - yc) > 3 * s:
            return r  # ran away from the star: keep the CoM
        done = abs(nx_ - xc) < 1e-5 and abs(ny_ - yc) < 1e-5
        xc, yc = nx_, ny_
        if done:
            break
    r[_X] = xc
    r[_Y] = yc
    # error of the fixed point Σ v·w(x̄)·(x − x̄) = 0 (implicit function theorem):
    # √Σ w² var (x − x̄)² / (Σ v·w − Σ v·w·(x − x̄)²/s²)
    r[_SIGMA_X] = math.sqrt(sxx2) / max(sw - dxx / (s * s), 0.1 * sw)
    r[_SIGMA_Y] = math.sqrt(syy2) / max(sw - dyy / (s * s), 0.1 * sw)
    return r


@njit(cache=True)
def _gauss_profile(n0, c, s, p, dp_dc, dp_ds):
    """Pixel-integrated 1-D Gaussian over pixels n0..n0+len-1 and its derivatives."""
    sq2 = math.sqrt(2.0) * s
    k = 1.0 / (math.sqrt(2.0 * math.pi) * s)
    for i in range(p.size):
        a = (n0 + i - 0.5 - c)
        b = (n0 + i + 0.5 - c)
        p[i] = 0.5 * (math.erf(b / sq2) - math.erf(a / sq2))
        ga = k * math.exp(-0.5 * (a / s) ** 2)
        gb = k * math.exp(-0.5 * (b / s) ** 2)
        dp_dc[i] = -(gb - ga)
        dp_ds[i] = -(b * gb - a * ga) / s


@njit(cache=True)
def _gauss_chi2(img, y0, x0, q, prof, nz, ig):
    """Σ (data − model)² / var of the model with parameters q in the window at (y0, x0).

    ``prof`` (:class:`_Profiles`) receives the model's x and y profiles.
    """
    px, dpx_c, dpx_s, py, dpy_c, dpy_s = prof
    _gauss_profile(x0, q[1], q[3], px, dpx_c, dpx_s)
    _gauss_profile(y0, q[2], q[4], py, dpy_c, dpy_s)
    acc = 0.0
    v0 = nz * nz if nz > 0 else 1.0
    for yy in range(py.size):
        for xx in range(px.size):
            star = q[0] * px[xx] * py[yy]
            d = img[y0 + yy, x0 + xx] - (star + q[5])
            acc += d * d / (v0 + max(star, 0.0) * ig)
    return acc


@njit(cache=True)
def _gauss_normal(img, y0, x0, p, prof, nz, ig, normal):
    """Weighted normal equations JᵀWJ, JᵀWr at p, and the sandwich's JᵀW diag(r²) WJ, into
    ``normal`` (:class:`_Normal`); ``prof`` (:class:`_Profiles`) receives the profiles."""
    px, dpx_c, dpx_s, py, dpy_c, dpy_s = prof
    jtj, jtr, meat = normal
    _gauss_profile(x0, p[1], p[3], px, dpx_c, dpx_s)
    _gauss_profile(y0, p[2], p[4], py, dpy_c, dpy_s)
    jtj[:, :] = 0.0
    jtr[:] = 0.0
    meat[:, :] = 0.0
    jrow = np.empty(6)
    v0 = nz * nz if nz > 0 else 1.0
    for yy in range(py.size):
        for xx in range(px.size):
            star = p[0] * px[xx] * py[yy]
            d = img[y0 + yy, x0 + xx] - (star + p[5])
            wgt = 1.0 / (v0 + max(star, 0.0) * ig)
            jrow[0] = px[xx] * py[yy]
            jrow[1] = p[0] * dpx_c[xx] * py[yy]
            jrow[2] = p[0] * px[xx] * dpy_c[yy]
            jrow[3] = p[0] * dpx_s[xx] * py[yy]
            jrow[4] = p[0] * px[xx] * dpy_s[yy]
            jrow[5] = 1.0
            wd2 = (wgt * d) ** 2
            for a in range(6):
                jtr[a] += wgt * jrow[a] * d
                for b in range(a, 6):
                    jtj[a, b] += wgt * jrow[a] * jrow[b]
                    meat[a, b] += wd2 * jrow[a] * jrow[b]
    for a in range(6):
        for b in range(a):
            jtj[a, b] = jtj[b, a]
            meat[a, b] = meat[b, a]


@njit(cache=True)
def _gauss_fit(img, win, start, s0, ig):
    """Levenberg–Marquardt fit of F·Px(x)·Py(y) + B; returns the CoM row ``start`` updated.

    Weights 1/(σ² + star/gain) (uniform when the gain is unknown). Covariance: (JᵀWJ)⁻¹ with a
    known gain, else the sandwich (JᵀJ)⁻¹·Jᵀdiag(r²)J·(JᵀJ)⁻¹, right whatever the noise.
    """
    y0, y1, x0, x1, bg, nz = win
    r = start.copy()
    nxp, nyp = x1 - x0 + 1, y1 - y0 + 1
    if nxp * nyp < 9:
        return r
    # parameters: flux, x₀, y₀, σx, σy, sky
    p = np.empty(6)
    p[0] = max(start[_FLUX], 1e-9)
    p[1] = start[_X]
    p[2] = start[_Y]
    p[3] = s0 if s0 > 0 else max(start[_PSF_SX], 0.4)
    p[4] = s0 if s0 > 0 else max(start[_PSF_SY], 0.4)
    p[5] = bg
    prof = _Profiles(np.empty(nxp), np.empty(nxp), np.empty(nxp), np.empty(nyp), np.empty(nyp), np.empty(nyp))
    normal = _Normal(np.empty((6, 6)), np.empty(6), np.empty((6, 6)))
    jtj, jtr, meat = normal
    lam = 1e-3
    cur = _gauss_chi2(img, y0, x0, p, prof, nz, ig)
    for _ in range(40):
        _gauss_normal(img, y0, x0, p, prof, nz, ig, normal)
        improved = False
        small = False
        for _try in range(10):
            aug = jtj.copy()
            for a in range(6):
                aug[a, a] += lam * max(jtj[a, a], 1e-12)
            step = np.linalg.lstsq(aug, jtr)[0]
            q = p + step
            if q[0] <= 0 or q[3] < 0.1 or q[4] < 0.1 or q[3] > 20 or q[4] > 20:
                lam *= 10.0
                continue
            new = _gauss_chi2(img, y0, x0, q, prof, nz, ig)
            if new <= cur:
                small = abs(step[1]) < 1e-6 and abs(step[2]) < 1e-6
                p = q
                cur = new
                lam = max(lam * 0.3, 1e-7)
                improved = True
                break
            lam *= 10.0
        if not improved or small:
            break
    # keep the fit only if it stayed on the star
    if not (abs(p[1] - start[_X]) < 3.0 and abs(p[2] - start[_Y]) < 3.0):
        return r
    _gauss_normal(img, y0, x0, p, prof, nz, ig, normal)
    for a in range(6):
        if not jtj[a, a] > 0.0:
            return r
    inv = np.linalg.pinv(jtj)  # no exception on a degenerate star (flat top, no wings)
    cov = inv if ig > 0 else inv @ meat @ inv
    r[_X] = p[1]
    r[_Y] = p[2]
    r[_FLUX] = p[0]
    r[_SIGMA_X] = math.sqrt(max(cov[1, 1], 0.0))
    r[_SIGMA_Y] = math.sqrt(max(cov[2, 2], 0.0))
    r[_COV_XY] = cov[1, 2]
    r[_PSF_SX] = p[3]
    r[_PSF_SY] = p[4]
    return r
