"""Photometry: instrumental magnitudes of identified stars against catalogue magnitudes.

A solved frame's matched stars (:attr:`skyfix.solution.Solution.matches`) carry the catalogue
Hp magnitude; their flux is measured on the frame, turned into an instrumental magnitude
``m_inst = −2.5·log10(flux)``, and a zero point ``ZP`` is fitted per frame so that
``Hp ≈ m_inst + ZP``. The scatter about that line is the photometric consistency (thesis 004
calibrated its camera to σ = 0.2 Mv).

Flux estimators (``flux=``):

``"psf"`` (default)
    The flux of the pixel-integrated 2-D Gaussian fit (:mod:`skyfix.detect.centroid`,
    ``centroid="gaussian"``): optimal weighting, so the least noisy on faint stars.
``"aperture"``
    Sum in a circular aperture of radius ``2·FWHM`` (at least 3 px) about the centroid, minus
    the median sky of an annulus from ``radius + 2`` to ``radius + 6`` px. Collects the whole
    star whatever its brightness.
``"extractor"``
    The extractor's own flux (sum over the detected footprint grown by a pixel). The footprint
    shrinks for faint stars, so it loses their wings: a brightness-dependent bias.

The zero point is robust: the median of ``Hp − m_inst`` iterated with 3σ clipping (σ from the
MAD). Saturated stars (flagged by the extractor) are left out of the fit; their flux is a
lower bound. Hp is a broad blue-visual band; a sensor with a red-extended response sees red
stars brighter than Hp says, and an uncorrected lens vignettes the field edge.
:func:`fit_field_calibration` fits both (a B−V slope and a ρ² fall-off shared by the frames
of one camera) beside the per-frame zero points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from skyfix.detect import Centroids, extract_centroids
from skyfix.io import read_image

__all__ = [
    "FieldCalibration",
    "FramePhotometry",
    "ZeroPoint",
    "aperture_flux",
    "catalogue_colour",
    "fit_field_calibration",
    "fit_zero_point",
    "frame_photometry",
    "instrumental_magnitude",
    "summarize",
]


def instrumental_magnitude(flux: np.ndarray) -> np.ndarray:
    """``−2.5·log10(flux)``; NaN where the flux is not positive."""
    f = np.asarray(flux, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(f > 0, -2.5 * np.log10(np.where(f > 0, f, 1.0)), np.nan)


def aperture_flux(image: np.ndarray, x: np.ndarray, y: np.ndarray, radius: float,
                  annulus: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Sky-subtracted flux in circular apertures (whole pixels whose centre is inside).

    Parameters
    ----------
    image : (H, W) array
        The frame, ADU.
    x, y : (N,) arrays
        Aperture centres, pixels.
    radius : float
        Aperture radius, pixels.
    annulus : (inner, outer), optional
        Sky annulus radii, pixels (default ``radius + 2`` to ``radius + 6``); the sky is the
        median of its pixels.

    Returns
    -------
    flux : (N,) array
        ADU; NaN where the annulus leaves the frame.
    sky : (N,) array
        Sky level per pixel, ADU.
    """
    img = np.asarray(image, dtype=np.float64)
    h, w = img.shape
    r_in, r_out = annulus if annulus is not None else (radius + 2.0, radius + 6.0)
    hs = int(math.ceil(r_out)) + 1
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    cx, cy = np.rint(x).astype(np.int64), np.rint(y).astype(np.int64)
    inside = (cx - hs >= 0) & (cx + hs < w) & (cy - hs >= 0) & (cy + hs < h)
    off = np.arange(-hs, hs + 1)
    rows = np.clip(cy[:, None] + off, 0, h - 1)
    cols = np.clip(cx[:, None] + off, 0, w - 1)
    stamps = img[rows[:, :, None], cols[:, None, :]]
    dx = (cx[:, None] - x[:, None] + off)[:, None, :]
    dy = (cy[:, None] - y[:, None] + off)[:, :, None]
    r2 = dx * dx + dy * dy
    ap = r2 <= radius * radius
    ring = (r2 >= r_in * r_in) & (r2 <= r_out * r_out)
    sky = np.nanmedian(np.where(ring, stamps, np.nan).reshape(len(x), -1), axis=1) if len(x) else np.zeros(0)
    flux = np.sum(np.where(ap, stamps - sky[:, None, None], 0.0), axis=(1, 2))
    return np.where(inside, flux, np.nan), sky


@dataclass(frozen=True)
class ZeroPoint:
    """A robust zero point ``Hp = m_inst + zp``.

    Attributes
    ----------
    zp : float — magnitudes.
    rms_mag : float — RMS of ``Hp − m_inst − zp`` over all stars used (no clipping).
    rms_clipped_mag : float — the same over the inliers only.
    inliers : (N,) bool — stars kept by the 3σ clip.
    """

    zp: float
    rms_mag: float
    rms_clipped_mag: float
    inliers: np.ndarray


def fit_zero_point(inst_mag: np.ndarray, cat_mag: np.ndarray, clip: float = 3.0,
                   n_iter: int = 5) -> ZeroPoint:
    """Median zero point with iterated ``clip``·σ rejection (σ = 1.4826·MAD, at least 0.02 mag)."""
    d = np.asarray(cat_mag, np.float64) - np.asarray(inst_mag, np.float64)
    ok = np.isfinite(d)
    if ok.sum() == 0:
        return ZeroPoint(math.nan, math.nan, math.nan, ok)
    keep = ok.copy()
    zp = float(np.median(d[ok]))
    for _ in range(n_iter):
        zp = float(np.median(d[keep]))
        s = max(1.4826 * float(np.median(np.abs(d[keep] - zp))), 0.02)
        new = ok & (np.abs(d - zp) <= clip * s)
        if new.sum() < 2 or np.array_equal(new, keep):
            break
        keep = new
    zp = float(np.median(d[keep]))
    res = d - zp
    return ZeroPoint(zp=zp, rms_mag=float(np.sqrt(np.mean(res[ok] ** 2))),
                     rms_clipped_mag=float(np.sqrt(np.mean(res[keep] ** 2))), inliers=keep)


@lru_cache(maxsize=1)
def _hip_colours() -> tuple[np.ndarray, np.ndarray]:
    """HIP numbers and B−V from the bundled Hipparcos 2 file (column 24 of I/311)."""
    from skyfix.catalog import hip2_path

    table = np.loadtxt(hip2_path(), usecols=(0, 23), dtype=np.float64)
    return table[:, 0].astype(np.int64), table[:, 1]


def catalogue_colour(hip_ids: np.ndarray) -> np.ndarray:
    """Hipparcos B−V of the given HIP numbers, magnitudes (NaN when unknown)."""
    ids, bv = _hip_colours()
    q = np.asarray(hip_ids, np.int64)
    i = np.clip(np.searchsorted(ids, q), 0, len(ids) - 1)
    return np.where(ids[i] == q, bv[i], np.nan)


@dataclass
class FramePhotometry:
    """Photometry of one solved frame.

    Attributes
    ----------
    image : str — the frame's name.
    solved : bool — whether :func:`skyfix.pipeline.solve` identified it.
    x, y : (N,) — matched stars' centroids, pixels.
    hip_id : (N,) — Hipparcos numbers.
    cat_mag : (N,) — catalogue Hp, mag.
    inst_mag : (N,) — instrumental magnitude ``−2.5·log10(flux/ADU)``.
    saturated : (N,) bool — the extractor flagged the star saturated (left out of the fit).
    zero_point : ZeroPoint — fitted on the unsaturated stars with a finite flux.
    """

    image: str
    solved: bool
    x: np.ndarray = field(default_factory=lambda: np.zeros(0))
    y: np.ndarray = field(default_factory=lambda: np.zeros(0))
    hip_id: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    cat_mag: np.ndarray = field(default_factory=lambda: np.zeros(0))
    inst_mag: np.ndarray = field(default_factory=lambda: np.zeros(0))
    saturated: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    zero_point: ZeroPoint | None = None
    reason: str = ""
    image_shape: tuple[int, int] = (0, 0)

    @property
    def radius(self) -> np.ndarray:
        """Distance of each star from the frame centre over the half-diagonal."""
        h, w = self.image_shape
        return np.hypot(self.x - (w - 1) / 2, self.y - (h - 1) / 2) / max(0.5 * math.hypot(w, h), 1e-9)

    @property
    def used(self) -> np.ndarray:
        """Stars that entered the zero-point fit."""
        return ~self.saturated & np.isfinite(self.inst_mag)

    @property
    def residual_mag(self) -> np.ndarray:
        """``Hp − m_inst − zp`` per star (NaN without a zero point)."""
        zp = self.zero_point.zp if self.zero_point is not None else math.nan
        return self.cat_mag - self.inst_mag - zp

    def summary(self) -> dict:
        zp = self.zero_point
        return {"image": self.image, "solved": self.solved, "reason": self.reason,
                "n_matched": int(self.x.size), "n_used": int(self.used.sum()),
                "n_saturated": int(self.saturated.sum()),
                "n_clipped": int(self.used.sum() - zp.inliers.sum()) if zp is not None else 0,
                "zero_point_mag": zp.zp if zp else None, "rms_mag": zp.rms_mag if zp else None,
                "rms_clipped_mag": zp.rms_clipped_mag if zp else None}

    def format_line(self) -> str:
        s = self.summary()
        if not self.solved or self.zero_point is None:
            return f"{self.image}: failed: {self.reason}"
        return (f"{self.image}: {s['n_used']} stars ({s['n_saturated']} saturated left out), "
                f"ZP {s['zero_point_mag']:.3f}, RMS {s['rms_mag']:.3f} mag "
                f"(clipped {s['rms_clipped_mag']:.3f}, {s['n_clipped']} out)")


def _match_centroids(c: Centroids, xy: np.ndarray, tol_px: float = 1.0) -> np.ndarray:
    """Index into ``c`` of the centroid at each position (−1 if none within ``tol_px``)."""
    from scipy.spatial import cKDTree

    if len(c) == 0 or len(xy) == 0:
        return np.full(len(xy), -1)
    d, i = cKDTree(c.xy).query(xy)
    return np.where(d <= tol_px, i, -1)


def frame_photometry(image: str | Path | np.ndarray, *, epoch: float | None = None,
                     fov_deg: float | None = None, flux: str = "psf", solution=None,
                     name: str | None = None, max_stars: int = 50) -> FramePhotometry:
    """Solve a frame, measure its identified stars and fit the zero point.

    Parameters
    ----------
    image : path or (H, W) array
        The frame.
    epoch : float, optional
        Julian year for proper motion in the solve.
    fov_deg : float, optional
        Field-of-view hint for the solve, degrees.
    flux : {"psf", "aperture", "extractor"}
        Flux estimator (module docstring).
    solution : Solution, optional
        An existing solution of this frame (skips the solve).
    name : str, optional
        Label (default: the file name).
    max_stars : int
        Centroids extracted (as :func:`skyfix.pipeline.solve` does, so the matches' positions
        are these centroids).
    """
    from skyfix.pipeline import solve

    label = name or (Path(image).name if isinstance(image, (str, Path)) else "<array>")
    data = read_image(image)
    sol = solution if solution is not None else solve(data, epoch=epoch, fov_deg=fov_deg, name=label,
                                                      max_stars=max_stars)
    if sol.status != "solved" or not sol.matches:
        return FramePhotometry(image=label, solved=False, reason=sol.reason or "no matches")
    mxy = np.array([[m.x, m.y] for m in sol.matches], np.float64)
    hip = np.array([m.id for m in sol.matches], np.int64)
    cat = np.array([m.mag for m in sol.matches], np.float64)
    c = extract_centroids(data, max_stars=max(max_stars, 4 * len(mxy)))
    idx = _match_centroids(c, mxy)
    found = idx >= 0
    sat = np.where(found, c.saturated[np.maximum(idx, 0)], False)
    if flux == "extractor":
        f = np.where(found, c.flux[np.maximum(idx, 0)], np.nan)
    elif flux == "psf":
        g = extract_centroids(data, max_stars=max(max_stars, 4 * len(mxy)), centroid="gaussian")
        gi = _match_centroids(g, mxy)
        f = np.where(gi >= 0, g.flux[np.maximum(gi, 0)], np.nan)
    elif flux == "aperture":
        ok = found & ~c.saturated[np.maximum(idx, 0)]
        sel = np.maximum(idx, 0)[ok]
        fwhm = 2.3548 * float(np.median(np.sqrt(c.flux[sel] / (2 * np.pi * np.maximum(c.peak[sel], 1e-9))))) \
            if sel.size else 2.5
        f, _ = aperture_flux(data, mxy[:, 0], mxy[:, 1], radius=max(3.0, 2.0 * fwhm))
    else:
        raise ValueError(f"unknown flux estimator {flux!r}; choose 'aperture', 'extractor' or 'psf'")
    inst = instrumental_magnitude(f)
    res = FramePhotometry(image=label, solved=True, x=mxy[:, 0], y=mxy[:, 1], hip_id=hip, cat_mag=cat,
                          inst_mag=inst, saturated=sat, image_shape=data.shape)
    used = res.used
    zp = fit_zero_point(inst[used], cat[used])
    inl = np.zeros(len(cat), bool)
    inl[np.flatnonzero(used)] = zp.inliers
    res.zero_point = ZeroPoint(zp.zp, zp.rms_mag, zp.rms_clipped_mag, inl[used])
    return res


def summarize(results: list[FramePhotometry]) -> dict:
    """Pooled figures over frames: each frame keeps its own zero point."""
    solved = [r for r in results if r.zero_point is not None and np.isfinite(r.zero_point.zp)]
    res = np.concatenate([r.residual_mag[r.used] for r in solved]) if solved else np.zeros(0)
    inl = np.concatenate([r.residual_mag[r.used][r.zero_point.inliers] for r in solved]) if solved else res
    frame_rms = [r.zero_point.rms_mag for r in solved]
    return {"n_frames": len(results), "n_frames_solved": len(solved), "n_stars": int(res.size),
            "rms_mag": float(np.sqrt(np.mean(res**2))) if res.size else math.nan,
            "rms_clipped_mag": float(np.sqrt(np.mean(inl**2))) if inl.size else math.nan,
            "n_clipped": int(res.size - inl.size),
            "median_frame_rms_mag": float(np.median(frame_rms)) if frame_rms else math.nan,
            "zero_points_mag": [r.zero_point.zp for r in solved]}


@dataclass(frozen=True)
class FieldCalibration:
    """Joint fit over frames: ``Hp = m_inst + zp_frame + c·(B−V) + v·ρ²``.

    Attributes
    ----------
    zero_points : (F,) — per-frame zero points, mag.
    colour_slope : float — c, mag per mag of B−V (0 when not fitted).
    vignetting : float — v, mag at the frame corner (ρ = 1; 0 when not fitted).
    rms_mag, rms_clipped_mag : float — pooled RMS of the residuals, all stars / inliers.
    n_stars, n_clipped : int
    residual_mag, cat_mag : (N,) — pooled residuals and catalogue magnitudes (stars with a B−V).
    """

    zero_points: np.ndarray
    colour_slope: float
    vignetting: float
    rms_mag: float
    rms_clipped_mag: float
    n_stars: int
    n_clipped: int
    residual_mag: np.ndarray
    cat_mag: np.ndarray

    def rms_brighter_than(self, mag: float) -> float:
        """Pooled residual RMS of the stars brighter than ``mag``."""
        s = self.cat_mag < mag
        return float(np.sqrt(np.mean(self.residual_mag[s] ** 2))) if s.any() else math.nan


def fit_field_calibration(results: list[FramePhotometry], *, colour: bool = True, vignetting: bool = True,
                          clip: float = 3.0, fixed: tuple[float, float] | None = None) -> FieldCalibration:
    """Per-frame zero points plus a shared colour term and radial fall-off, least squares with
    iterated ``clip``·σ rejection (σ = 1.4826·MAD).

    The colour term absorbs the difference between Hp and the sensor's band; the ``ρ²`` term
    the vignetting of the lens (a flat field would remove it), ρ being the distance from the
    frame centre over the half-diagonal. Both are shared by all frames of one camera.
    ``fixed = (colour_slope, vignetting)`` applies a previous calibration and fits only the
    zero points (to check it on frames it was not fitted to).
    """
    frames = [r for r in results if r.zero_point is not None]
    cols, d, mags = [], [], []
    for k, r in enumerate(frames):
        u = r.used
        bv = catalogue_colour(r.hip_id[u]) if colour else np.zeros(u.sum())
        rows = np.zeros((u.sum(), len(frames) + 2))
        rows[:, k] = 1.0
        rows[:, -2] = bv
        rows[:, -1] = r.radius[u] ** 2
        cols.append(rows)
        d.append(r.cat_mag[u] - r.inst_mag[u])
        mags.append(r.cat_mag[u])
    if not frames:
        z = np.zeros(0)
        return FieldCalibration(z, math.nan, math.nan, math.nan, math.nan, 0, 0, z, z)
    a, d, mags = np.concatenate(cols), np.concatenate(d), np.concatenate(mags)
    ok = np.all(np.isfinite(a), axis=1) & np.isfinite(d)
    a, d, mags = a[ok], d[ok], mags[ok]
    use = np.ones(len(a), bool)
    use_cols = np.array([True] * len(frames) + [colour and fixed is None, vignetting and fixed is None])
    for _ in range(10):
        coef = np.zeros(a.shape[1])
        if fixed is not None:
            coef[-2:] = (fixed[0] if colour else 0.0, fixed[1] if vignetting else 0.0)
        dd = d - a[:, -2:] @ coef[-2:]
        coef[use_cols] = np.linalg.lstsq(a[use][:, use_cols], dd[use], rcond=None)[0]
        res = d - a @ coef
        s = max(1.4826 * float(np.median(np.abs(res[use] - np.median(res[use])))), 0.02)
        new = np.abs(res) <= clip * s
        if np.array_equal(new, use):
            break
        use = new
    return FieldCalibration(zero_points=coef[: len(frames)], colour_slope=float(coef[-2]),
                            vignetting=float(coef[-1]), rms_mag=float(np.sqrt(np.mean(res**2))),
                            rms_clipped_mag=float(np.sqrt(np.mean(res[use] ** 2))), n_stars=int(len(res)),
                            n_clipped=int((~use).sum()), residual_mag=res, cat_mag=mags)
