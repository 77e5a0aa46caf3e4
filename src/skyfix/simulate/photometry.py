"""Photometry: photo-electrons from stellar magnitudes and sky surface brightness.

Thesis 002 Eq. 3-3, with QE folded in (it applied QE later, Eq. 3-7) and the smear division
by ρ done by the renderer (each of ρ sub-steps gets 1/ρ of the light)::

    electrons = φ · 10^(−0.4 m) · A · n · γ · QE · τ

φ: zero-point photon flux of a magnitude-0 star, photons s⁻¹ m⁻² (``Optics.zero_point_photons_s_m2``);
A: aperture area, m²; n: optical throughput; γ: vignetting (``Optics.transmission``);
QE: electrons per photon; τ: exposure, s.

Sky background (Eq. 3-6, corrected): the light of a surface brightness ``μ`` mag arcsec⁻² that
falls on *one pixel* is ``φ · 10^(−0.4 μ) · A · n · QE · τ · Ω_px`` with ``Ω_px`` the pixel's solid
angle in arcsec² (thesis 002 added the whole field's total to every pixel).
"""

from __future__ import annotations

import math

import numpy as np

from skyfix.errors import SimulationError

__all__ = ["star_electrons", "sky_electrons_per_pixel", "magnitude_for_electrons", "ARCSEC_RAD"]

ARCSEC_RAD = math.pi / (180.0 * 3600.0)  # thesis 002's a2R


def star_electrons(mag: np.ndarray, optics, sensor, exposure_s: float,
                   transmission: np.ndarray | float = 1.0) -> np.ndarray:
    """Expected photo-electrons of stars of magnitude ``mag`` over ``exposure_s`` seconds.

    ``transmission`` is the vignetting factor γ per star (1 on axis).
    """
    if not (math.isfinite(exposure_s) and exposure_s >= 0):
        raise SimulationError(f"exposure must be a non-negative number of seconds, got {exposure_s}")
    mag = np.asarray(mag, dtype=np.float64)
    rate = (optics.zero_point_photons_s_m2 * optics.aperture_area_m2 * optics.throughput * sensor.qe)
    return rate * np.power(10.0, -0.4 * mag) * np.asarray(transmission, dtype=np.float64) * exposure_s


def magnitude_for_electrons(electrons: float, optics, sensor, exposure_s: float) -> float:
    """The magnitude whose on-axis star gives ``electrons`` photo-electrons (inverse of
    :func:`star_electrons`)."""
    e0 = float(star_electrons(0.0, optics, sensor, exposure_s))
    if electrons <= 0 or e0 <= 0:
        return math.inf
    return -2.5 * math.log10(electrons / e0)


def sky_electrons_per_pixel(sky_mag_arcsec2: float, optics, sensor, exposure_s: float,
                            plate_scale_rad: float) -> float:
    """Expected sky-background photo-electrons per pixel for a surface brightness in
    mag arcsec⁻², a pixel of ``plate_scale_rad`` radians on a side."""
    pixel_arcsec2 = (plate_scale_rad / ARCSEC_RAD) ** 2
    return float(star_electrons(sky_mag_arcsec2, optics, sensor, exposure_s)) * pixel_arcsec2
