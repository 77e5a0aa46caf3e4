"""Centroider accuracy against the Cramér–Rao bound, on simulated stars (for ``analyze centroids``).

A star here is a circular Gaussian PSF integrated over square pixels (``erf`` differences, so
the truth is exact at any sub-pixel phase), ``flux`` electrons with Poisson noise on a Poisson
sky of ``sky`` electrons per pixel plus Gaussian read noise; gain 1 (ADU = electrons). The
renderer is this module's own, independent of :mod:`skyfix.simulate`, so the two can check
each other.

- :func:`centroid_error_grid` — RMS error, bias and the bound for each centroider over a grid
  of PSF width and SNR, with random sub-pixel phase;
- :func:`s_curve` — the pixel-phase bias of each centroider (mean error at fixed phases);
- :func:`plot_centroid_study` — both as a PNG.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.special import erf

from skyfix.detect.centroid import CENTROIDERS, centroid_windows, cramer_rao_centroid

__all__ = ["render_star", "flux_for_snr", "centroid_error_grid", "s_curve", "plot_centroid_study"]

_WINDOW = 8  # half size of the square window, px
_SIZE = 2 * _WINDOW + 8


def flux_for_snr(snr: float, psf_sigma: float, sky: float, read_noise: float) -> float:
    """Star flux (e⁻) whose SNR is ``snr`` with noise ``√(F + 4πσ²(sky + r²))`` (aperture 4πσ²)."""
    a = 4.0 * math.pi * psf_sigma**2 * (sky + read_noise**2)
    s2 = float(snr) ** 2
    return 0.5 * (s2 + math.sqrt(s2 * s2 + 4.0 * s2 * a))


def render_star(x0: float, y0: float, flux: float, psf_sigma: float, sky: float, read_noise: float,
                rng: np.random.Generator, size: int = _SIZE) -> np.ndarray:
    """One noisy star in a ``size``² frame (float32, e⁻), centred at ``(x0, y0)``."""
    edges = np.arange(size + 1, dtype=np.float64) - 0.5
    sq = math.sqrt(2.0) * psf_sigma
    px = np.diff(0.5 * erf((edges - x0) / sq))
    py = np.diff(0.5 * erf((edges - y0) / sq))
    mu = flux * np.outer(py, px) + sky
    return (rng.poisson(mu) + rng.normal(0.0, read_noise, mu.shape)).astype(np.float32)


def _mosaic(offsets: np.ndarray, flux: float, psf_sigma: float, sky: float, read_noise: float,
            rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """All trial stars in one frame, one per ``_SIZE``² cell; returns the frame and the truths.

    ``offsets`` (N, 2) are each star's position relative to its cell centre, px.
    """
    n = len(offsets)
    cols = int(math.ceil(math.sqrt(n)))
    rows = int(math.ceil(n / cols))
    cell = np.arange(n)
    c0 = _SIZE / 2.0
    local = offsets + c0
    edges = np.arange(_SIZE + 1, dtype=np.float64) - 0.5
    sq = math.sqrt(2.0) * psf_sigma
    px = np.diff(0.5 * erf((edges[None, :] - local[:, :1]) / sq), axis=1)  # (N, SIZE)
    py = np.diff(0.5 * erf((edges[None, :] - local[:, 1:]) / sq), axis=1)
    stars = flux * py[:, :, None] * px[:, None, :]  # (N, SIZE, SIZE)
    mu = np.full((rows * cols, _SIZE, _SIZE), sky)
    mu[:n] += stars
    frame = mu.reshape(rows, cols, _SIZE, _SIZE).transpose(0, 2, 1, 3).reshape(rows * _SIZE, cols * _SIZE)
    frame = (rng.poisson(frame) + rng.normal(0.0, read_noise, frame.shape)).astype(np.float32)
    truth = local + np.column_stack([(cell % cols) * _SIZE, (cell // cols) * _SIZE])
    return frame, truth


def centroid_error_grid(psf_sigmas: Sequence[float] = (0.5, 0.8, 1.2, 2.0, 3.0),
                        snrs: Sequence[float] = (10, 20, 50, 100, 200),
                        methods: Sequence[str] = CENTROIDERS, n_trials: int = 100, sky: float = 50.0,
                        read_noise: float = 3.0, seed: int = 0) -> list[dict]:
    """RMS x error, bias and Cramér–Rao bound per centroider, PSF σ and SNR.

    Each trial puts a star at a random sub-pixel phase and starts the centroider 0.4 px (1σ)
    away from the truth, as a detection would. Returns one dict per (method, σ, SNR):
    ``method, psf_sigma, snr, flux_e, crb_px, rms_px, bias_px, ratio`` (rms / CRB) and
    ``failed`` (trials with no centroid).
    """
    rng = np.random.default_rng(seed)
    rows = []
    for s in psf_sigmas:
        for snr in snrs:
            flux = flux_for_snr(snr, s, sky, read_noise)
            frame, truth = _mosaic(rng.random((n_trials, 2)) - 0.5, flux, s, sky, read_noise, rng)
            guess = truth + rng.normal(0.0, 0.4, truth.shape)
            crb = cramer_rao_centroid(s, flux, sky, read_noise)
            for m in methods:
                err = centroid_windows(frame, guess, _WINDOW, method=m, gain=1.0).x - truth[:, 0]
                ok = np.isfinite(err)
                rms = float(np.sqrt(np.mean(err[ok] ** 2))) if ok.any() else math.nan
                rows.append({"method": m, "psf_sigma": float(s), "snr": float(snr), "flux_e": flux,
                             "crb_px": crb, "rms_px": rms, "bias_px": float(np.mean(err[ok])) if ok.any()
                             else math.nan, "ratio": rms / crb, "failed": int((~ok).sum())})
    return rows


def s_curve(psf_sigma: float, methods: Sequence[str] = CENTROIDERS,
            phases: Sequence[float] = tuple(np.linspace(-0.5, 0.5, 11)), snr: float = 200.0,
            n_trials: int = 50, sky: float = 50.0, read_noise: float = 3.0, seed: int = 1) -> dict:
    """Mean x error against the star's pixel phase (the S-curve), per centroider.

    Returns ``{"phase": array, method: array of mean errors (px)}``.
    """
    rng = np.random.default_rng(seed)
    flux = flux_for_snr(snr, psf_sigma, sky, read_noise)
    ph = np.repeat(np.asarray(phases, dtype=np.float64), n_trials)
    frame, truth = _mosaic(np.column_stack([ph, np.zeros_like(ph)]), flux, psf_sigma, sky, read_noise, rng)
    # each window starts on the cell centre's pixel, whatever the phase
    start = truth - np.column_stack([ph, np.zeros_like(ph)])
    out: dict = {"phase": np.asarray(phases, dtype=np.float64)}
    for m in methods:
        err = centroid_windows(frame, start, _WINDOW, method=m, gain=1.0).x - truth[:, 0]
        out[m] = np.nanmean(err.reshape(len(phases), n_trials), axis=1)
    return out


def plot_centroid_study(rows: list[dict], curves: dict[float, dict], path: str | Path) -> None:
    """PNG: RMS/CRB against SNR per PSF σ and centroider, and the S-curves."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    order = {m: i for i, m in enumerate(CENTROIDERS)}
    methods = sorted({r["method"] for r in rows}, key=lambda m: order.get(m, len(order)))
    sigmas = sorted({r["psf_sigma"] for r in rows})
    fig, axes = plt.subplots(1, len(methods) + 1, figsize=(4.2 * (len(methods) + 1), 3.8))
    for ax, m in zip(axes, methods, strict=False):
        for s in sigmas:
            sel = [r for r in rows if r["method"] == m and r["psf_sigma"] == s]
            ax.plot([r["snr"] for r in sel], [r["ratio"] for r in sel], "o-", label=f"σ = {s:g} px")
        ax.axhline(1.0, color="k", lw=0.8)
        ax.axhline(1.15, color="k", lw=0.8, ls=":")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("SNR")
        ax.set_ylabel("RMS error / Cramér–Rao bound")
        ax.set_title(m)
        ax.legend(fontsize=7)
    ax = axes[-1]
    for s, curve in sorted(curves.items()):
        for m in methods:
            if m in curve:
                ax.plot(curve["phase"], curve[m], label=f"{m}, σ = {s:g}")
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xlabel("sub-pixel phase (px)")
    ax.set_ylabel("mean error (px)")
    ax.set_title("pixel-phase bias (S-curve)")
    ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
