"""PSF width and shape across the field: FWHM and ellipticity of isolated stars.

Thesis 000 §5.5 moved a point source over the sensor and found the PSF round at the centre and
lopsided toward the edge; thesis 003 measured the FWHM of focused stars as the optical
resolution. This module measures both on any sky frame.

Method: stars from :func:`skyfix.detect.extract_centroids` that are unsaturated, above an SNR
and isolated (no other detection within two stamp half-widths) are cut out as ``(N, k, k)``
stamps; the sky (median of each stamp's border) is subtracted, and the PSF covariance C comes
from one of two measurements, vectorised over the stars:

- ``"fit"`` (default): a least-squares fit of a rotated elliptical Gaussian integrated over
  the pixels (flux, centre, Cxx, Cxy, Cyy, residual sky). Right however undersampled the star
  is (the ESA frames have FWHM ≈ 1.3 px).
- ``"moments"``: **adaptive second moments** (an elliptical Gaussian weight iterated to match
  the star, Bernstein & Jarvis 2002). For a Gaussian star of covariance C the weighted moments
  converge to C/2 with the weight equal to C, so ``C = 2·M``; square pixels add ``1/12`` px² to
  each axis, which is removed. Fast and exact for well-sampled stars (FWHM ≳ 2.5 px); it
  collapses on undersampled ones, whose sampled moments shrink with the weight.

Either way the FWHM is the optics' (``FWHM = 2√(2 ln 2)·σ``, pixel box excluded), comparable
with a simulator's ``psf_fwhm_px``.

Ellipticity is ``1 − b/a`` (minor over major axis), the angle that of the major axis from +x
toward +y.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from skyfix.detect import Centroids, extract_centroids
from skyfix.io import as_image

__all__ = ["PsfField", "adaptive_moments", "fit_elliptical_gaussians", "measure_psf_field", "plot_psf_field",
           "ZONES"]

SIGMA_TO_FWHM = 2.0 * math.sqrt(2.0 * math.log(2.0))
_PIXEL_VAR = 1.0 / 12.0
#: Zones by normalised radius ρ (distance from the frame centre over the half-diagonal).
ZONES = {"centre": (0.0, 1 / 3), "middle": (1 / 3, 2 / 3), "edge": (2 / 3, 1.01)}


def adaptive_moments(stamps: np.ndarray, x0: np.ndarray, y0: np.ndarray, sigma0: float,
                     n_iter: int = 40) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Adaptive (Gaussian-weighted, iterated) second moments of sky-subtracted stamps.

    Parameters
    ----------
    stamps : (N, k, k) array
        Sky-subtracted star stamps.
    x0, y0 : (N,) arrays
        First-guess centres in stamp pixels.
    sigma0 : float
        First-guess PSF σ, pixels (the weight's starting width).
    n_iter : int
        Iterations (the weight's width converges by a factor 2 per iteration).

    Returns
    -------
    x, y : (N,) arrays
        Weighted centroids, stamp pixels.
    cov : (N, 2, 2) array
        Star covariance ``2·M`` (pixel box included), px²; NaN where it failed.
    """
    n, k, _ = stamps.shape
    img = np.asarray(stamps, np.float64)
    g = np.arange(k, dtype=np.float64)
    x = np.asarray(x0, np.float64).copy()
    y = np.asarray(y0, np.float64).copy()
    w = np.zeros((n, 2, 2))
    w[:, 0, 0] = w[:, 1, 1] = sigma0**2
    ok = np.ones(n, bool)
    cov = np.full((n, 2, 2), np.nan)
    for _ in range(n_iter):
        det = w[:, 0, 0] * w[:, 1, 1] - w[:, 0, 1] ** 2
        ia, ib, ic = w[:, 1, 1] / det, -w[:, 0, 1] / det, w[:, 0, 0] / det  # W⁻¹ entries
        dx = g[None, None, :] - x[:, None, None]
        dy = g[None, :, None] - y[:, None, None]
        q = ia[:, None, None] * dx * dx + 2 * ib[:, None, None] * dx * dy + ic[:, None, None] * dy * dy
        wi = img * np.exp(-0.5 * q)
        s = wi.sum(axis=(1, 2))
        ok &= s > 0
        s = np.where(s > 0, s, 1.0)
        mx = (wi * dx).sum(axis=(1, 2)) / s
        my = (wi * dy).sum(axis=(1, 2)) / s
        mxx = (wi * dx * dx).sum(axis=(1, 2)) / s - mx * mx
        myy = (wi * dy * dy).sum(axis=(1, 2)) / s - my * my
        mxy = (wi * dx * dy).sum(axis=(1, 2)) / s - mx * my
        x, y = x + mx, y + my
        new = np.stack([np.stack([mxx, mxy], -1), np.stack([mxy, myy], -1)], -2) * 2.0
        # keep the weight positive definite and not narrower than a pixel's box
        good = (new[:, 0, 0] > 0.05) & (new[:, 1, 1] > 0.05) & (
            new[:, 0, 0] * new[:, 1, 1] - new[:, 0, 1] ** 2 > 0.0025)
        ok &= good & np.isfinite(x) & np.isfinite(y)
        w = np.where(ok[:, None, None], new, w)
        x = np.clip(x, 0, k - 1)
        y = np.clip(y, 0, k - 1)
    cov[ok] = w[ok]
    return x, y, cov


def _elliptical_model(p: np.ndarray, k: int, sub: int) -> np.ndarray:
    """(N, k, k) elliptical Gaussians ``F·G(C) + B`` averaged over sub × sub points per pixel.

    ``p`` is (N, 7): F, x0, y0, Cxx, Cxy, Cyy, B (stamp pixels, px²).
    """
    s = (np.arange(sub) + 0.5) / sub - 0.5
    g = (np.arange(k)[:, None] + s[None, :]).ravel()
    dx = g[None, None, :] - p[:, 1, None, None]
    dy = g[None, :, None] - p[:, 2, None, None]
    det = p[:, 3] * p[:, 5] - p[:, 4] ** 2
    ia, ib, ic = p[:, 5] / det, -p[:, 4] / det, p[:, 3] / det
    q = ia[:, None, None] * dx * dx + 2 * ib[:, None, None] * dx * dy + ic[:, None, None] * dy * dy
    f = np.exp(-0.5 * q) / (2 * np.pi * np.sqrt(det))[:, None, None]
    f = f.reshape(len(p), k, sub, k, sub).mean(axis=(2, 4))
    return p[:, 0, None, None] * f + p[:, 6, None, None]


def fit_elliptical_gaussians(stamps: np.ndarray, x0: np.ndarray, y0: np.ndarray, sigma0: float,
                             sub: int = 5, n_iter: int = 30) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares fit of a rotated elliptical Gaussian integrated over pixels, all stamps at once.

    Levenberg–Marquardt with a forward-difference Jacobian, vectorised over stars. The pixel
    integral is a ``sub × sub`` midpoint sum; its own ``h²/12`` spread (h = 1/sub) is removed
    from the fitted covariance. Right for undersampled stars (FWHM ≲ 2 px), where moments are
    biased by the sampling.

    Parameters
    ----------
    stamps : (N, k, k) array
        Sky-subtracted star stamps (a residual constant is fitted).
    x0, y0 : (N,) arrays
        First-guess centres, stamp pixels.
    sigma0 : float
        First-guess PSF σ, pixels.

    Returns
    -------
    x, y : (N,) arrays
        Fitted centres, stamp pixels.
    cov : (N, 2, 2) array
        Optical PSF covariance (pixel box excluded), px²; NaN where the fit failed.
    """
    n, k, _ = stamps.shape
    data = np.asarray(stamps, np.float64).reshape(n, -1)
    p = np.zeros((n, 7))
    p[:, 0] = np.maximum(data.sum(axis=1), 1e-9)
    p[:, 1], p[:, 2] = x0, y0
    p[:, 3] = p[:, 5] = sigma0**2
    lam = np.full(n, 1e-2)

    def chi2(pp: np.ndarray, d: np.ndarray) -> np.ndarray:
        return np.sum((d - _elliptical_model(pp, k, sub).reshape(len(pp), -1)) ** 2, axis=1)

    cur = chi2(p, data)
    active = np.ones(n, bool)  # stars still improving; converged ones are not recomputed
    for _ in range(n_iter):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        pa, da, m = p[idx], data[idx], idx.size
        m0 = _elliptical_model(pa, k, sub).reshape(m, -1)
        jac = np.empty((m, k * k, 7))
        for j in range(7):
            h = 1e-4 * np.maximum(np.abs(pa[:, 0]), 1.0) if j == 0 else np.full(m, 1e-3 if j == 6 else 1e-4)
            q = pa.copy()
            q[:, j] += h
            jac[:, :, j] = (_elliptical_model(q, k, sub).reshape(m, -1) - m0) / h[:, None]
        jtj = np.einsum("nki,nkj->nij", jac, jac)
        jtr = np.einsum("nki,nk->ni", jac, da - m0)
        diag = np.diagonal(jtj, axis1=1, axis2=2)
        aug = jtj + lam[idx, None, None] * np.eye(7)[None] * np.maximum(diag, 1e-12)[:, None, :]
        q = pa + np.linalg.solve(aug, jtr[..., None])[..., 0]
        valid = ((q[:, 0] > 0) & (q[:, 3] > 0.01) & (q[:, 5] > 0.01)
                 & (q[:, 3] * q[:, 5] - q[:, 4] ** 2 > 1e-4))
        new = np.where(valid, chi2(np.where(valid[:, None], q, pa), da), np.inf)
        better = new < cur[idx]
        gain = np.where(better, (cur[idx] - new) / np.maximum(cur[idx], 1e-300), 0.0)
        p[idx] = np.where(better[:, None], q, pa)
        cur[idx] = np.where(better, new, cur[idx])
        lam[idx] = np.clip(np.where(better, lam[idx] * 0.3, lam[idx] * 10.0), 1e-7, 1e7)
        active[idx] = ~((better & (gain < 1e-9)) | (lam[idx] >= 1e7))
    box = 1.0 / (12.0 * sub * sub)
    cov = np.stack([np.stack([p[:, 3] - box, p[:, 4]], -1), np.stack([p[:, 4], p[:, 5] - box], -1)], -2)
    bad = ~np.all(np.isfinite(p), axis=1)
    cov[bad] = np.nan
    return p[:, 1], p[:, 2], cov


@dataclass(frozen=True)
class PsfField:
    """Per-star PSF measurements over one frame.

    Attributes
    ----------
    x, y : (N,) — star positions, pixels (docs/design.md#pixel-coordinates).
    fwhm_px : (N,) — FWHM of the optical PSF, geometric mean of the axes, pixels.
    fwhm_major_px, fwhm_minor_px : (N,) — FWHM along the major and minor axes, pixels.
    ellipticity : (N,) — ``1 − minor/major``.
    angle_rad : (N,) — major-axis angle from +x toward +y, radians in (−π/2, π/2].
    snr : (N,) — the extractor's SNR of each star.
    image_shape : (height, width).
    """

    x: np.ndarray
    y: np.ndarray
    fwhm_px: np.ndarray
    fwhm_major_px: np.ndarray
    fwhm_minor_px: np.ndarray
    ellipticity: np.ndarray
    angle_rad: np.ndarray
    snr: np.ndarray
    image_shape: tuple[int, int]

    @property
    def n(self) -> int:
        return int(self.x.size)

    @property
    def radius(self) -> np.ndarray:
        """Distance from the frame centre over the half-diagonal (0 centre, 1 corner)."""
        h, w = self.image_shape
        return np.hypot(self.x - (w - 1) / 2, self.y - (h - 1) / 2) / (0.5 * math.hypot(w, h))

    def summary(self) -> dict:
        """Medians over the frame and per zone (centre ρ < 1/3, middle, edge ρ > 2/3)."""
        out = {"n_stars": self.n, "median_fwhm_px": _median(self.fwhm_px),
               "median_ellipticity": _median(self.ellipticity), "zones": {}}
        rho = self.radius
        for name, (lo, hi) in ZONES.items():
            sel = (rho >= lo) & (rho < hi)
            out["zones"][name] = {"n_stars": int(sel.sum()), "median_fwhm_px": _median(self.fwhm_px[sel]),
                                  "median_ellipticity": _median(self.ellipticity[sel])}
        return out

    def format_summary(self, name: str = "") -> str:
        s = self.summary()
        lines = [f"{name}: {s['n_stars']} isolated unsaturated stars, median FWHM "
                 f"{s['median_fwhm_px']:.2f} px, ellipticity {s['median_ellipticity']:.3f}"]
        for zone, z in s["zones"].items():
            lines.append(f"  {zone:6s} n={z['n_stars']:4d}  FWHM {z['median_fwhm_px']:.2f} px  "
                         f"ellipticity {z['median_ellipticity']:.3f}")
        return "\n".join(lines)


def _median(a: np.ndarray) -> float:
    return float(np.median(a)) if np.size(a) else math.nan


def _select(c: Centroids, min_snr: float) -> np.ndarray:
    return np.flatnonzero(~c.saturated & (c.snr >= min_snr) & np.isfinite(c.x) & np.isfinite(c.y)
                          & (c.flux > 0) & (c.peak > 0))


def measure_psf_field(image: np.ndarray, centroids: Centroids | None = None, *, min_snr: float = 10.0,
                      half_size: int | None = None, max_stars: int = 2000, method: str = "fit") -> PsfField:
    """FWHM and ellipticity of the isolated, unsaturated stars of a frame.

    Parameters
    ----------
    image : (H, W) array
        The frame, ADU.
    centroids : Centroids, optional
        Detections to use (default: :func:`skyfix.detect.extract_centroids` with up to
        ``max_stars`` stars). All detections count for the isolation test.
    min_snr : float
        Smallest extractor SNR of a measured star (noise inflates faint stars' ellipticity).
    half_size : int, optional
        Stamp half-width, pixels; default ``ceil(5σ) + 2`` with σ from the median
        ``√(flux / 2π·peak)`` of the selected stars (4–25).
    max_stars : int
        Detections asked of the extractor.
    method : {"fit", "moments"}
        ``"fit"``: rotated elliptical Gaussian integrated over pixels
        (:func:`fit_elliptical_gaussians`), right at any sampling; ``"moments"``: adaptive
        second moments (:func:`adaptive_moments`), faster, biased for FWHM ≲ 2 px.

    Returns
    -------
    PsfField
        One entry per measured star (may be empty).
    """
    img = as_image(image)
    h, w = img.shape
    c = extract_centroids(img, max_stars=max_stars) if centroids is None else centroids
    sel = _select(c, min_snr)
    empty = PsfField(*(np.zeros(0) for _ in range(8)), image_shape=(h, w))
    if sel.size == 0:
        return empty
    sigma0 = float(np.median(np.sqrt(c.flux[sel] / (2 * np.pi * c.peak[sel]))))
    sigma0 = min(max(sigma0, 0.5), 5.0)
    hs = int(half_size) if half_size is not None else int(np.clip(math.ceil(5 * sigma0) + 2, 4, 25))
    # isolated: no other detection within 2·hs; the whole stamp inside the frame
    xy = c.xy
    finite = np.all(np.isfinite(xy), axis=1)
    tree = cKDTree(xy[finite])
    d, _ = tree.query(xy[sel], k=2)
    isolated = d[:, 1] > 2 * hs if d.ndim == 2 else np.ones(sel.size, bool)
    cx, cy = np.rint(c.x[sel]).astype(np.int64), np.rint(c.y[sel]).astype(np.int64)
    inside = (cx - hs >= 0) & (cx + hs < w) & (cy - hs >= 0) & (cy + hs < h)
    keep = isolated & inside
    sel, cx, cy = sel[keep], cx[keep], cy[keep]
    if sel.size == 0:
        return empty
    off = np.arange(-hs, hs + 1)
    stamps = img[(cy[:, None] + off)[:, :, None], (cx[:, None] + off)[:, None, :]].astype(np.float64)
    border = np.concatenate([stamps[:, 0, :], stamps[:, -1, :], stamps[:, 1:-1, 0], stamps[:, 1:-1, -1]],
                            axis=1)
    stamps -= np.median(border, axis=1)[:, None, None]
    if method == "fit":
        x, y, cov = fit_elliptical_gaussians(stamps, c.x[sel] - cx + hs, c.y[sel] - cy + hs, sigma0)
    elif method == "moments":
        x, y, cov = adaptive_moments(stamps, c.x[sel] - cx + hs, c.y[sel] - cy + hs, sigma0)
        cov = cov - _PIXEL_VAR * np.eye(2)[None]
    else:
        raise ValueError(f"unknown PSF method {method!r}; choose 'fit' or 'moments'")
    det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] ** 2
    good = (np.all(np.isfinite(cov), axis=(1, 2)) & (cov[:, 0, 0] > 0) & (det > 0)
            & (np.hypot(x - (c.x[sel] - cx + hs), y - (c.y[sel] - cy + hs)) < 2.0)
            & (cov[:, 0, 0] + cov[:, 1, 1] < (hs / 2.0) ** 2))
    cov = cov[good]
    lam, vec = np.linalg.eigh(cov)  # ascending
    lam = np.maximum(lam, 1e-6)
    major, minor = np.sqrt(lam[:, 1]), np.sqrt(lam[:, 0])
    angle = np.arctan2(vec[:, 1, 1], vec[:, 0, 1])
    angle = np.where(angle <= -np.pi / 2, angle + np.pi, np.where(angle > np.pi / 2, angle - np.pi, angle))
    return PsfField(x=x[good] + cx[good] - hs, y=y[good] + cy[good] - hs,
                    fwhm_px=SIGMA_TO_FWHM * np.sqrt(major * minor), fwhm_major_px=SIGMA_TO_FWHM * major,
                    fwhm_minor_px=SIGMA_TO_FWHM * minor, ellipticity=1.0 - minor / major, angle_rad=angle,
                    snr=c.snr[sel][good], image_shape=(h, w))


def plot_psf_field(field: PsfField, path: str | Path, title: str = "") -> Path:
    """Write a PNG: whisker map over the frame (length ∝ ellipticity, colour = FWHM), FWHM and
    ellipticity versus radius with binned medians."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    h, w = field.image_shape
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4), gridspec_kw={"width_ratios": [1.4, 1, 1]})
    ax = axes[0]
    if field.n:
        scale = 0.25 * max(w, h)  # whisker length for ellipticity 1
        half = 0.5 * np.maximum(field.ellipticity * scale, 0.004 * max(w, h))
        dx, dy = half * np.cos(field.angle_rad), half * np.sin(field.angle_rad)
        segs = np.stack([np.column_stack([field.x - dx, field.y - dy]),
                         np.column_stack([field.x + dx, field.y + dy])], axis=1)
        lc = LineCollection(segs, array=field.fwhm_px, cmap="viridis", linewidths=2)
        ax.add_collection(lc)
        fig.colorbar(lc, ax=ax, label="FWHM, px")
        ax.plot([0.05 * w, 0.05 * w + 0.1 * scale], [0.95 * h, 0.95 * h], "k-", lw=2)
        ax.text(0.05 * w, 0.93 * h, "ellipticity 0.1", fontsize=8)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("x, px")
    ax.set_ylabel("y, px")
    ax.set_title(f"{title} PSF over the field ({field.n} stars)".strip())
    rho = field.radius
    bins = np.linspace(0, 1, 7)
    panels = ((axes[1], field.fwhm_px, "FWHM, px"), (axes[2], field.ellipticity, "ellipticity 1 − b/a"))
    for ax, val, label in panels:
        ax.plot(rho, val, ".", alpha=0.5)
        idx = np.digitize(rho, bins) - 1
        med = [np.median(val[idx == i]) if np.any(idx == i) else np.nan for i in range(len(bins) - 1)]
        ax.plot(0.5 * (bins[1:] + bins[:-1]), med, "r-o", label="median")
        ax.set_xlabel("radius / half-diagonal")
        ax.set_ylabel(label)
        ax.set_xlim(0, 1)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
