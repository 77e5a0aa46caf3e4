"""Optics of the simulated camera: collecting area, throughput, PSF shape over the field,
defocus and vignetting. Geometry (focal length, distortion) lives in :class:`skyfix.camera.Camera`."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from skyfix.errors import SimulationError
from skyfix.simulate.presets import load_preset

__all__ = ["Optics", "FWHM_TO_SIGMA"]

#: σ = FWHM / (2 √(2 ln 2)) for a Gaussian.
FWHM_TO_SIGMA = 1.0 / (2.0 * math.sqrt(2.0 * math.log(2.0)))


@dataclass(frozen=True)
class Optics:
    """Lens and PSF parameters.

    Attributes
    ----------
    aperture_mm : float
        Entrance-pupil diameter, mm (focal length / f-number).
    throughput : float
        Optical transmission (lens + filter), 0–1.
    psf_fwhm_px : float
        Gaussian PSF full width at half maximum at the field centre, pixels.
        The covariance is ``diag(σ², σ²)`` (thesis 002 printed ``diag(σ, σ)``; corrected).
    defocus_px : float
        Radius of the geometric defocus disk convolved with the Gaussian, pixels (0: in focus).
    ellipticity_edge : float
        PSF elongation at the field corner: the radial σ grows as
        ``σ·(1 + ellipticity_edge·ρ²)`` with ρ the distance from the principal point over the
        half-diagonal; the tangential σ stays ``σ`` (round at the centre, lopsided at the edge,
        as thesis 000 measured).
    psf_growth_edge : float
        PSF growth at the field corner, both axes: σ becomes ``σ·(1 + psf_growth_edge·ρ²)``
        (before ``ellipticity_edge`` stretches the radial one) — a lens sharp in the centre and
        soft at the edge, as thesis 003's wide lenses. Symmetric: it moves no centroid.
    vignetting_per_rad : float
        Linear vignetting coefficient ν: transmission ``γ = 1 − ν·β`` at off-axis angle β, rad
        (thesis 002 Eq. 3-4).
    cos4_vignetting : bool
        Also apply the natural ``cos⁴ β`` fall-off.
    zero_point_photons_s_m2 : float
        Photon flux of a magnitude-0 star in the sensor's band, photons s⁻¹ m⁻² (thesis 002's
        φ, "flux Vega"; V band alone is ≈ 8.8e9, a 400–900 nm white band ≈ 1e10).
    """

    aperture_mm: float = 10.0
    throughput: float = 0.8
    psf_fwhm_px: float = 2.0
    defocus_px: float = 0.0
    ellipticity_edge: float = 0.0
    vignetting_per_rad: float = 0.0
    psf_growth_edge: float = 0.0
    cos4_vignetting: bool = False
    zero_point_photons_s_m2: float = 1.0e10

    def __post_init__(self) -> None:
        for key in ("aperture_mm", "throughput", "psf_fwhm_px", "zero_point_photons_s_m2"):
            v = float(getattr(self, key))
            if not (math.isfinite(v) and v > 0):
                raise SimulationError(f"optics {key} must be a positive number, got {v}")
        for key in ("defocus_px", "ellipticity_edge", "vignetting_per_rad", "psf_growth_edge"):
            v = float(getattr(self, key))
            if not (math.isfinite(v) and v >= 0):
                raise SimulationError(f"optics {key} must be a non-negative number, got {v}")
        if self.throughput > 1:
            raise SimulationError(f"optics throughput must be at most 1, got {self.throughput}")

    @property
    def psf_sigma_px(self) -> float:
        """Gaussian σ at the field centre, pixels."""
        return self.psf_fwhm_px * FWHM_TO_SIGMA

    @property
    def psf_sigma_max_px(self) -> float:
        """The PSF's largest σ anywhere in the field (the radial σ at the corner), pixels."""
        return self.psf_sigma_px * (1 + self.psf_growth_edge) * (1 + self.ellipticity_edge)

    @property
    def aperture_area_m2(self) -> float:
        """Collecting area of the circular entrance pupil, m²."""
        return math.pi * (self.aperture_mm * 1e-3) ** 2 / 4.0

    def replace(self, **changes) -> Optics:
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_dict(cls, table: Mapping) -> Optics:
        """Optics from an ``[optics]`` table (``psf_sigma_px`` may replace ``psf_fwhm_px``)."""
        table = dict(table)
        if "psf_sigma_px" in table:
            table["psf_fwhm_px"] = float(table.pop("psf_sigma_px")) / FWHM_TO_SIGMA
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(table) - known
        if unknown:
            raise SimulationError(f"unknown optics keys: {', '.join(sorted(unknown))}")
        try:
            kw = {k: (bool(v) if k == "cos4_vignetting" else float(v)) for k, v in table.items()}
        except (TypeError, ValueError) as exc:
            raise SimulationError(f"bad optics value: {exc}") from None
        return cls(**kw)

    @classmethod
    def from_preset(cls, name: str) -> Optics:
        return cls.from_dict(load_preset(name).get("optics", {}))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    # --- field dependence ----------------------------------------------------------------
    def transmission(self, off_axis_rad: np.ndarray) -> np.ndarray:
        """Vignetting factor γ (≤ 1) at off-axis angles β, radians."""
        beta = np.asarray(off_axis_rad, dtype=np.float64)
        gamma = np.clip(1.0 - self.vignetting_per_rad * beta, 0.0, 1.0)
        if self.cos4_vignetting:
            gamma = gamma * np.cos(beta) ** 4
        return gamma

    def covariance(self, xy: np.ndarray, camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """PSF covariance ``(sxx, syy, sxy)`` (px²) at pixel positions ``xy`` (N, 2)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        s2 = self.psf_sigma_px**2
        n = len(xy)
        if self.ellipticity_edge == 0.0 and self.psf_growth_edge == 0.0:
            return np.full(n, s2), np.full(n, s2), np.zeros(n)
        dx = xy[:, 0] - camera.cx
        dy = xy[:, 1] - camera.cy
        half_diag = 0.5 * math.hypot(camera.width, camera.height)
        rho2 = (dx * dx + dy * dy) / half_diag**2
        s2 = s2 * (1.0 + self.psf_growth_edge * rho2) ** 2  # (N,): the tangential σ², grown
        s_rad2 = s2 * (1.0 + self.ellipticity_edge * rho2) ** 2
        phi = np.arctan2(dy, dx)
        c, s = np.cos(phi), np.sin(phi)
        sxx = s_rad2 * c * c + s2 * s * s
        syy = s_rad2 * s * s + s2 * c * c
        sxy = (s_rad2 - s2) * c * s
        return sxx, syy, sxy

    def defocus_offsets(self) -> tuple[np.ndarray, np.ndarray]:
        """Offsets (K, 2) px and weights (K,) sampling the defocus disk (K = 1 in focus).

        Concentric rings of evenly spaced points with equal-area weights: the pattern is
        point-symmetric, so it leaves the centroid exactly where it was.
        """
        r = self.defocus_px
        if r <= 0:
            return np.zeros((1, 2)), np.ones(1)
        sigma = max(self.psf_sigma_px, 0.3)
        n_rings = max(1, math.ceil(2.0 * r / sigma))
        pts, wts = [np.zeros(2)], [0.75]  # annulus areas: centre π/4, each ring point π/3
        for i in range(1, n_rings + 1):
            m = 6 * i
            rad = r * i / n_rings
            ang = 2 * np.pi * (np.arange(m) + 0.5 * (i % 2)) / m
            pts += list(np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=-1))
            wts += [1.0] * m
        w = np.asarray(wts)
        return np.asarray(pts), w / w.sum()
