"""Centroid accuracy against the Cramér–Rao bound, on simulated single stars.

Each centroider of :mod:`skyfix.detect.centroid` is run on stamps of one star: a circular
Gaussian PSF integrated over square pixels, Poisson photon noise on star + sky, Gaussian read
noise, gain 1 e⁻/ADU. Stars sit at random sub-pixel phases. For every (PSF σ, SNR) cell the
RMS position error (x and y pooled) is compared with the bound of
:func:`skyfix.detect.cramer_rao_centroid` averaged over the same phases:
``ratio = √(mean err² / mean CRB²)``; 1 is the physical limit.

The S-curve is the systematic error (bias) versus sub-pixel phase, measured on noise-free
stamps: a pixel-sampled CoM is pulled toward the pixel centre when the PSF is narrow.

The stamps of one cell are rendered as one ``(N, k, k)`` array and handed to the centroider
as a column mosaic of N windows (one numba call): no Python loop per trial.

SNR convention: ``SNR = F / √(F + A·(b + r²))`` with F the star's electrons, b the sky
electrons per pixel, r the read noise and ``A = 4π(σ² + 1/12)`` the noise-equivalent area of
the pixelated PSF.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy.special import erf

from skyfix.detect import METHODS, centroid_windows, cramer_rao_centroid, extract_centroids, refine_centroids

__all__ = [
    "CellResult",
    "CentroidStudy",
    "COMPONENTS",
    "DEFAULT_CENTROIDERS",
    "EXTRACTORS",
    "flux_for_snr",
    "noise_area_px",
    "star_snr",
    "numeric_crb",
    "expected_stamps",
    "render_stamps",
    "centroid_stamps",
    "mean_crb",
    "run_cell",
    "s_curve",
    "run_study",
    "write_study",
]

#: The extractor's own centroid (connected components, CoM over the grown component).
COMPONENTS = "components"
#: Full-frame detection methods of :func:`skyfix.detect.extract_centroids`, each with its own CoM:
#: ``components`` (default), ``threshold_hillclimb`` (thesis 000, 3×3 ROI), ``region_grow`` (thesis 004).
EXTRACTORS = tuple(METHODS)
DEFAULT_CENTROIDERS = ("com", "iwcog", "gaussian", *EXTRACTORS)
DEFAULT_SNR = (10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0)
DEFAULT_SIGMA = (0.5, 0.8, 1.0, 1.5, 2.0, 3.0)
#: Sky electrons per pixel and read noise (electrons) of the study: a modest dark-sky frame.
DEFAULT_SKY_E = 10.0
DEFAULT_READ_E = 5.0


def noise_area_px(sigma_px: float) -> float:
    """The noise-equivalent area of a pixelated Gaussian PSF of σ ``sigma_px``, pixels:
    ``A = 4π(σ² + 1/12)``."""
    return 4.0 * math.pi * (sigma_px**2 + 1.0 / 12.0)


def star_snr(flux_e, sigma_px: float, sky_e: float = DEFAULT_SKY_E, read_e: float = DEFAULT_READ_E):
    """A star's SNR under the module's convention, ``F / √(F + A·(b + r²))`` (``F`` its
    electrons, scalar or array; :func:`noise_area_px`); :func:`flux_for_snr` inverts it."""
    f = np.asarray(flux_e, dtype=np.float64)
    return f / np.sqrt(f + noise_area_px(sigma_px) * (sky_e + read_e**2))


def flux_for_snr(snr: float, sigma_px: float, sky_e: float = DEFAULT_SKY_E,
                 read_e: float = DEFAULT_READ_E) -> float:
    """Star electrons that give ``snr`` under the module's SNR convention (:func:`star_snr`).

    Solves ``F² = SNR²·(F + A·(b + r²))`` with ``A = 4π(σ² + 1/12)``.
    """
    v = noise_area_px(sigma_px) * (sky_e + read_e**2)
    s2 = float(snr) ** 2
    return 0.5 * (s2 + math.sqrt(s2 * s2 + 4.0 * s2 * v))


def _half_size(sigma_px: float) -> int:
    return int(math.ceil(4.0 * sigma_px)) + 2


def _profiles(centre: np.ndarray, sigma_px: float, size: int) -> np.ndarray:
    """(N, size) pixel-integrated 1-D Gaussian shares for centres given in stamp pixels."""
    edges = np.arange(size + 1, dtype=np.float64) - 0.5
    z = (edges[None, :] - centre[:, None]) / (math.sqrt(2.0) * sigma_px)
    return np.diff(0.5 * erf(z), axis=1)


def expected_stamps(x: np.ndarray, y: np.ndarray, flux_e: np.ndarray | float, sigma_px: float,
                    size: int, sky_e: float = 0.0) -> np.ndarray:
    """Noise-free stamps (N, size, size), electrons: pixel-integrated Gaussian + flat sky.

    Parameters
    ----------
    x, y : (N,) arrays
        Star centres in stamp pixels (``(0, 0)`` = centre of the stamp's top-left pixel).
    flux_e : float or (N,) array
        Total star electrons (the part outside the stamp is lost).
    sigma_px : float
        Gaussian PSF σ, pixels.
    size : int
        Stamp side, pixels.
    sky_e : float
        Sky electrons per pixel.
    """
    x = np.atleast_1d(np.asarray(x, np.float64))
    y = np.atleast_1d(np.asarray(y, np.float64))
    f = np.broadcast_to(np.asarray(flux_e, np.float64), x.shape)
    px = _profiles(x, sigma_px, size)
    py = _profiles(y, sigma_px, size)
    return f[:, None, None] * py[:, :, None] * px[:, None, :] + sky_e


def render_stamps(x: np.ndarray, y: np.ndarray, flux_e: float, sigma_px: float, size: int,
                  sky_e: float, read_e: float, rng: np.random.Generator) -> np.ndarray:
    """Noisy stamps (N, size, size), ADU at gain 1 e⁻/ADU: Poisson(star + sky) + N(0, r²)."""
    lam = expected_stamps(x, y, flux_e, sigma_px, size, sky_e)
    img = rng.poisson(lam).astype(np.float64)
    if read_e > 0:
        img += rng.normal(0.0, read_e, img.shape)
    return img


def numeric_crb(sigma_px: float, flux_e: float, sky_e: float = 0.0, read_e: float = 0.0,
                phase: tuple[float, float] = (0.0, 0.0), step: float = 1e-4) -> float:
    """Cramér–Rao bound on x (pixels, 1-σ) from a numeric Fisher sum over pixels.

    Independent of :func:`skyfix.detect.cramer_rao_centroid`: the derivative ``∂μ_i/∂x₀`` is a
    central finite difference of :func:`expected_stamps`, and the information is
    ``Σ (∂μ_i/∂x₀)² / (μ_i + b + r²)`` over a stamp of ±(6σ + 3) pixels (sky and flux known).
    """
    hs = int(math.ceil(6 * sigma_px)) + 3
    size = 2 * hs + 1
    x0, y0 = hs + phase[0], hs + phase[1]
    plus = expected_stamps(np.array([x0 + step]), np.array([y0]), flux_e, sigma_px, size)[0]
    minus = expected_stamps(np.array([x0 - step]), np.array([y0]), flux_e, sigma_px, size)[0]
    mu = expected_stamps(np.array([x0]), np.array([y0]), flux_e, sigma_px, size)[0]
    d = (plus - minus) / (2 * step)
    var = mu + sky_e + read_e**2
    use = var > 0  # photon-limited: far pixels hold nothing and tell nothing
    fisher = float(np.sum(d[use] ** 2 / var[use]))
    return 1.0 / math.sqrt(fisher)


def mean_crb(sigma_px: float, flux_e: float, sky_e: float, read_e: float, n_phase: int = 6) -> float:
    """RMS of the x bound over a uniform grid of sub-pixel phases (x and y), pixels."""
    ph = (np.arange(n_phase) + 0.5) / n_phase - 0.5
    b2 = [cramer_rao_centroid(sigma_px, flux_e, sky_e, read_e, phase=(float(a), float(b))) ** 2
          for a in ph for b in ph]
    return math.sqrt(float(np.mean(b2)))


def centroid_stamps(stamps: np.ndarray, method: str, sigma_px: float | None = None,
                    gain: float | None = 1.0, threshold: float = 3.0, *, sky: float | None = None,
                    noise: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Centroid one star per stamp with a :mod:`skyfix.detect` centroider.

    The stamps are stacked into a column mosaic and passed to
    :func:`skyfix.detect.centroid_windows` with windows centred on each stamp's centre (not on
    the truth); the sky and noise come from each window's border, as in tracking, unless
    both ``sky`` and ``noise`` are given (then :func:`skyfix.detect.refine_centroids` uses them).

    Parameters
    ----------
    stamps : (N, k, k) array
        One star per stamp, ADU; k even.
    method : str
        Centroider name (``"com"``, ``"iwcog"``, ``"gaussian"``), or a full-frame detection
        method of :func:`skyfix.detect.extract_centroids` (:data:`EXTRACTORS`; ``"components"``
        is the default extractor, 5σ, intensity-weighted CoM over the grown component) run on a
        square mosaic of the stamps with its own centre of mass; a stamp where it finds nothing
        gives NaN.
    sigma_px : float, optional
        PSF σ given to the centroider (IWCoG's weight width, the fit's first guess).
    gain : float, optional
        Electrons per ADU (enables shot-noise weights).
    threshold : float
        k of the CoM's ``sky + k·σ`` threshold.
    sky, noise : float, optional
        Known sky level and per-pixel noise σ, ADU.

    Returns
    -------
    x, y : (N,) arrays
        Centroids in stamp pixels; NaN where the centroider found nothing.
    """
    n, k, k2 = stamps.shape
    if k != k2 or k % 2:
        raise ValueError(f"stamps must be (N, k, k) with k even, got {stamps.shape}")
    if method in EXTRACTORS:
        return _extract_stamps(stamps, method)
    hs = k // 2
    mosaic = np.ascontiguousarray(stamps.reshape(n * k, k), dtype=np.float32)
    pred = np.column_stack([np.full(n, float(hs)), hs + k * np.arange(n, dtype=np.float64)])
    if sky is not None and noise is not None:
        r = refine_centroids(mosaic, pred, np.full(n, float(sky)), np.full(n, float(noise)),
                             np.full(n, hs), method=method, sigma=threshold, psf_sigma=sigma_px, gain=gain)
        ok = r[:, 10] > 0
        x, y = np.where(ok, r[:, 0], np.nan), np.where(ok, r[:, 1], np.nan)
    else:
        c = centroid_windows(mosaic, pred, half_size=hs, method=method, sigma=threshold,
                             psf_sigma=sigma_px, gain=gain)
        x, y = c.x, c.y
    return x, y - k * np.arange(n)


def _extract_stamps(stamps: np.ndarray, method: str = "components") -> tuple[np.ndarray, np.ndarray]:
    """Run a full-frame extraction method on a square mosaic of the stamps; centroids per stamp."""
    n, k, _ = stamps.shape
    side = int(math.ceil(math.sqrt(n)))
    # empty slots get a copy of a star-free border row so the sky statistics stay uniform
    filler = np.broadcast_to(np.median(stamps[:, 0, :]), (k, k))
    tiles = np.concatenate([stamps, np.broadcast_to(filler, (side * side - n, k, k))])
    mosaic = tiles.reshape(side, side, k, k).transpose(0, 2, 1, 3).reshape(side * k, side * k)
    c = extract_centroids(mosaic.astype(np.float32), max_stars=4 * n, max_noise_ratio=None,
                          max_diffuseness=None, method=method)
    x = np.full(n, np.nan)
    y = np.full(n, np.nan)
    ix, iy = np.floor(c.x / k).astype(np.int64), np.floor(c.y / k).astype(np.int64)
    idx = iy * side + ix
    keep = (idx >= 0) & (idx < n)
    # brightest first: the first detection in each stamp wins
    idx_k, first = np.unique(idx[keep], return_index=True)
    src = np.flatnonzero(keep)[first]
    x[idx_k] = c.x[src] - ix[src] * k
    y[idx_k] = c.y[src] - iy[src] * k
    return x, y


@dataclass(frozen=True)
class CellResult:
    """Accuracy of one centroider at one (σ, SNR)."""

    method: str
    sigma_px: float
    snr: float
    flux_e: float
    n_trials: int
    rms_px: float
    crb_px: float
    ratio: float
    bias_px: float
    fail_fraction: float


def run_cell(method: str, sigma_px: float, snr: float, n_trials: int, rng: np.random.Generator, *,
             sky_e: float = DEFAULT_SKY_E, read_e: float = DEFAULT_READ_E) -> CellResult:
    """Centroid ``n_trials`` simulated stars at random sub-pixel phases; RMS vs the bound.

    ``bias_px`` is the mean error along x and y (pooled): the phase-averaged bias, which is
    near zero even when the S-curve is large (see :func:`s_curve`). Stars the centroider
    misses (NaN) or that land > 3 px off are counted in ``fail_fraction`` and left out of the
    RMS.
    """
    hs = _half_size(sigma_px)
    size = 2 * hs
    flux = flux_for_snr(snr, sigma_px, sky_e, read_e)
    phase = rng.uniform(-0.5, 0.5, (2, n_trials))
    xt, yt = hs + phase[0], hs + phase[1]
    stamps = render_stamps(xt, yt, flux, sigma_px, size, sky_e, read_e, rng)
    x, y = centroid_stamps(stamps, method, sigma_px)
    err = np.concatenate([x - xt, y - yt])
    ok = np.isfinite(err) & (np.abs(err) < 3.0)
    ok2 = ok[:n_trials] & ok[n_trials:]
    err = np.concatenate([(x - xt)[ok2], (y - yt)[ok2]])
    rms = float(np.sqrt(np.mean(err**2))) if err.size else math.nan
    crb = mean_crb(sigma_px, flux, sky_e, read_e)
    return CellResult(method=method, sigma_px=float(sigma_px), snr=float(snr), flux_e=float(flux),
                      n_trials=int(n_trials), rms_px=rms, crb_px=crb, ratio=rms / crb,
                      bias_px=float(np.mean(err)) if err.size else math.nan,
                      fail_fraction=float(1.0 - ok2.mean()))


def s_curve(method: str, sigma_px: float, phases: np.ndarray | None = None, *, snr: float = 200.0,
            sky_e: float = DEFAULT_SKY_E, read_e: float = DEFAULT_READ_E, repeats: int = 100
            ) -> tuple[np.ndarray, np.ndarray]:
    """Systematic x error versus sub-pixel phase, on noise-free stamps.

    The star's flux is the one for ``snr``, and the centroider is told the true sky level and
    noise σ, so the CoM threshold (``sky + 3σ``) and the fit's weights are those of a real
    star of that SNR; only the noise itself is left out. The extractor (``"components"``)
    estimates its own noise, so it gets noisy stamps and the mean of ``repeats`` stars per
    phase (its curve carries ~``rms/√repeats`` of scatter).

    Returns
    -------
    phases : (M,) array
        Star offset from the pixel centre along x, pixels (y phase 0).
    bias : (M,) array
        Measured minus true x, pixels.
    """
    ph = np.linspace(-0.5, 0.5, 41) if phases is None else np.asarray(phases, np.float64)
    hs = _half_size(sigma_px)
    size = 2 * hs
    flux = flux_for_snr(snr, sigma_px, sky_e, read_e)
    xt = hs + ph
    yt = np.full_like(xt, float(hs))
    if method in EXTRACTORS:
        # the extractor measures its own noise: give it noisy stamps and average the repeats
        rng = np.random.default_rng(12345)
        xr, yr = np.tile(xt, repeats), np.tile(yt, repeats)
        stamps = render_stamps(xr, yr, flux, sigma_px, size, sky_e, read_e, rng)
        x, _ = centroid_stamps(stamps, method, sigma_px)
        err = (x - xr).reshape(repeats, -1)
        n_ok = np.isfinite(err).sum(axis=0)
        return ph, np.where(n_ok > 0, np.nansum(err, axis=0) / np.maximum(n_ok, 1), np.nan)
    stamps = expected_stamps(xt, yt, flux, sigma_px, size, sky_e)
    x, _ = centroid_stamps(stamps, method, sigma_px, sky=sky_e, noise=math.sqrt(sky_e + read_e**2))
    return ph, x - xt


@dataclass
class CentroidStudy:
    """All cells of a study plus its S-curves and settings."""

    cells: list[CellResult]
    s_curves: dict[str, dict[str, list[float]]] = field(default_factory=dict)
    settings: dict = field(default_factory=dict)

    def table(self, method: str) -> np.ndarray:
        """(n_sigma, n_snr) array of error/bound ratios for one centroider."""
        sig = sorted({c.sigma_px for c in self.cells})
        snr = sorted({c.snr for c in self.cells})
        out = np.full((len(sig), len(snr)), np.nan)
        for c in self.cells:
            if c.method == method:
                out[sig.index(c.sigma_px), snr.index(c.snr)] = c.ratio
        return out

    def to_json(self) -> dict:
        """Plain data for ``json.dumps`` (NaN → None, so the file is strict JSON)."""

        def clean(v):
            if isinstance(v, float) and not math.isfinite(v):
                return None
            if isinstance(v, dict):
                return {k: clean(x) for k, x in v.items()}
            if isinstance(v, list):
                return [clean(x) for x in v]
            return v

        return clean({"settings": self.settings, "cells": [asdict(c) for c in self.cells],
                      "s_curves": self.s_curves})


def run_study(methods: Sequence[str] = DEFAULT_CENTROIDERS, sigmas: Sequence[float] = DEFAULT_SIGMA,
              snrs: Sequence[float] = DEFAULT_SNR, n_trials: int = 2000, seed: int = 0, *,
              sky_e: float = DEFAULT_SKY_E, read_e: float = DEFAULT_READ_E,
              s_curve_sigmas: Sequence[float] = (0.35, 0.5, 0.65, 0.8, 1.0),
              s_curve_snrs: Sequence[float] = (20.0, 200.0),
              progress: Callable[[str], None] | None = None) -> CentroidStudy:
    """Run every centroider over the (σ, SNR) grid and the S-curves.

    ``progress`` is called once per finished cell with a short description (for a progress
    bar). Each (σ, SNR) cell draws its stars from a generator keyed by ``seed``, σ and SNR, so
    every method is measured on the same stars and a cell's result does not depend on which
    other cells or methods run.
    """
    cells = []
    for s in sigmas:
        for r in snrs:
            # one stream per (σ, SNR), the same for every method: all see the same stars
            key = (int(round(1000 * s)), int(round(1000 * r)))
            for m in methods:
                rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))
                cells.append(run_cell(m, s, r, n_trials, rng, sky_e=sky_e, read_e=read_e))
                if progress is not None:
                    progress(f"{m} σ={s:g} SNR={r:g}")
    curves: dict[str, dict[str, list[float]]] = {}
    for m in methods:
        for r in s_curve_snrs:
            for s in s_curve_sigmas:
                ph, b = s_curve(m, s, snr=r, sky_e=sky_e, read_e=read_e)
                curves.setdefault(m, {})[_curve_key(r, s)] = b.tolist()
                curves["phase"] = {"x": ph.tolist()}
        if progress is not None:
            progress(f"{m} S-curve")
    settings = dict(methods=list(methods), sigmas=list(map(float, sigmas)), snrs=list(map(float, snrs)),
                    n_trials=int(n_trials), seed=int(seed), sky_e=sky_e, read_e=read_e, gain_e_per_adu=1.0,
                    s_curve_sigmas=list(map(float, s_curve_sigmas)),
                    s_curve_snrs=list(map(float, s_curve_snrs)))
    return CentroidStudy(cells=cells, s_curves=curves, settings=settings)


def _peak(values: list) -> float:
    """Largest |bias| of a curve, ignoring phases where the method found nothing (None/NaN)."""
    a = np.array([np.nan if v is None else v for v in values], dtype=np.float64)
    return float(np.nanmax(np.abs(a))) if np.isfinite(a).any() else math.nan


def _curve_key(snr: float, sigma: float) -> str:
    return f"snr{snr:g}_sigma{sigma:g}"


def _markdown(study: CentroidStudy, command: str) -> str:
    sig = sorted({c.sigma_px for c in study.cells})
    snr = sorted({c.snr for c in study.cells})
    st = study.settings
    lines = [f"Generated by `{command}` ({st['n_trials']} trials per cell, seed {st['seed']}, "
             f"sky {st['sky_e']:g} e⁻/px, read noise {st['read_e']:g} e⁻, gain 1 e⁻/ADU).", ""]
    for m in st["methods"]:
        tab = study.table(m)
        lines += [f"**{m}** — RMS error / Cramér–Rao bound (rows: PSF σ in px; columns: SNR)", "",
                  "| σ \\ SNR | " + " | ".join(f"{r:g}" for r in snr) + " |",
                  "|---|" + "---|" * len(snr)]
        for i, s in enumerate(sig):
            cells = " | ".join(f"{v:.2f}" if np.isfinite(v) else "—" for v in tab[i])
            lines.append(f"| {s:g} | {cells} |")
        fails = [c for c in study.cells if c.method == m and c.fail_fraction > 0.001]
        if fails:
            worst = max(fails, key=lambda c: c.fail_fraction)
            lines += ["", f"Missed or > 3 px off in {len(fails)} cells (worst "
                          f"{100 * worst.fail_fraction:.1f}% at σ={worst.sigma_px:g}, SNR={worst.snr:g}); "
                          "those trials are left out of the RMS."]
        lines.append("")
    sc = st["s_curve_sigmas"]
    lines += ["**S-curve** — peak systematic x error over sub-pixel phase (noise-free stamps, CoM threshold "
              "and fit weights of a star of the given SNR), px", "",
              "| centroider | SNR | " + " | ".join(f"σ={s:g}" for s in sc) + " |",
              "|---|---|" + "---|" * len(sc)]
    for m in st["methods"]:
        for r in st["s_curve_snrs"]:
            vals = [_peak(study.s_curves[m][_curve_key(r, s)]) for s in sc]
            lines.append(f"| {m} | {r:g} | " + " | ".join(f"{v:.3f}" if np.isfinite(v) else "—" for v in vals)
                         + " |")
    lines.append("")
    return "\n".join(lines)


def _plots(study: CentroidStudy, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    st = study.settings
    methods = st["methods"]
    sig = sorted({c.sigma_px for c in study.cells})
    snr = sorted({c.snr for c in study.cells})
    ncol = min(3, len(methods))
    nrow = math.ceil(len(methods) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.4 * ncol, 3.6 * nrow), sharey=True, squeeze=False)
    cmap = plt.get_cmap("viridis")
    for ax in axes.flat[len(methods):]:
        ax.set_visible(False)
    for ax, m in zip(axes.flat, methods, strict=False):
        tab = study.table(m)
        for i, s in enumerate(sig):
            ax.plot(snr, tab[i], "o-", color=cmap(i / max(len(sig) - 1, 1)), label=f"σ = {s:g} px", ms=3)
        ax.axhline(1.0, color="k", lw=0.8)
        ax.axhline(1.15, color="r", lw=0.8, ls="--")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("SNR")
        ax.set_title(m)
        ax.grid(True, which="both", alpha=0.3)
    for row in axes:
        row[0].set_ylabel("RMS error / Cramér–Rao bound")
    axes.flat[0].legend(fontsize=7)
    fig.tight_layout()
    p1 = out / "centroid_ratio_vs_snr.png"
    fig.savefig(p1, dpi=110)
    plt.close(fig)

    snrs_c = st["s_curve_snrs"]
    fig, axes = plt.subplots(len(methods), len(snrs_c), figsize=(4.4 * len(snrs_c), 2.7 * len(methods)),
                             sharex=True, squeeze=False)
    ph = np.asarray(study.s_curves["phase"]["x"])
    for row, m in enumerate(methods):
        for ax, r in zip(axes[row], snrs_c, strict=True):
            for j, s in enumerate(st["s_curve_sigmas"]):
                ax.plot(ph, study.s_curves[m][_curve_key(r, s)], label=f"σ = {s:g} px",
                        color=cmap(j / max(len(st["s_curve_sigmas"]) - 1, 1)))
            ax.axhline(0.0, color="k", lw=0.6)
            ax.set_title(f"{m}, SNR {r:g}", fontsize=9)
            ax.grid(True, alpha=0.3)
        axes[row, 0].set_ylabel("bias, px")
    for ax in axes[-1]:
        ax.set_xlabel("true sub-pixel phase, px")
    axes[0, -1].legend(fontsize=7)
    fig.tight_layout()
    p2 = out / "centroid_s_curve.png"
    fig.savefig(p2, dpi=110)
    plt.close(fig)
    return [p1, p2]


def write_study(study: CentroidStudy, out_dir: str | Path, command: str = "skyfix analyze centroids"
                ) -> list[Path]:
    """Write ``centroid_study.json``, ``centroid_study.md`` and the two PNG plots to ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    pj = out / "centroid_study.json"
    pj.write_text(json.dumps(study.to_json(), indent=1))
    pm = out / "centroid_study.md"
    pm.write_text(_markdown(study, command))
    return [pj, pm, *_plots(study, out)]
