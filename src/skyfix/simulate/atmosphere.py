"""The atmosphere over a ground camera: seeing (a broader PSF) and scintillation (each star's
flux jitter), both off unless asked for (docs/simulating.md#what-real-frames-carry).

- **Seeing**: the long-exposure seeing disc of FWHM ``seeing_fwhm_arcsec`` is a Gaussian added in
  quadrature to the optics' PSF (its σ² to both axes' variances). It moves no centroid: a
  symmetric blur only spreads the light, so what it costs is SNR (and merged close pairs).
- **Scintillation**: Young's formula (Young 1967, in Dravins et al. 1998 Eq. 10) for the relative
  flux σ of a star in an exposure ``t`` through an aperture ``D``::

      σ_I / I = 0.09 · D_cm^(-2/3) · X^(7/4) · exp(-h / 8000 m) · (2 t)^(-1/2)

  ``X`` the airmass, ``h`` the site's altitude. Each star's electrons are multiplied by a
  log-normal factor of mean 1 and that σ (``exp(s·z − s²/2)``, ``s² = ln(1 + σ²)``: never
  negative, however short the exposure), drawn from the frame's ``scintillation`` stream.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix.errors import SimulationError
from skyfix.simulate.optics import FWHM_TO_SIGMA

__all__ = ["Atmosphere", "scintillate", "seeing_sigma_px", "young_scintillation"]

_ARCSEC = math.pi / (180.0 * 3600.0)
_SCALE_HEIGHT_M = 8000.0


class Atmosphere(NamedTuple):
    """What the air adds to a ground frame: the seeing disc's FWHM (arcsec, 0: none), Young's
    scintillation on or off, the airmass of the field and the site's altitude (m)."""

    seeing_fwhm_arcsec: float = 0.0
    scintillation: bool = False
    airmass: float = 1.0
    altitude_m: float = 0.0

    def checked(self) -> Atmosphere:
        """Itself, or a SimulationError naming the bad value."""
        for name, value, ok, what in (
                ("seeing_fwhm_arcsec", self.seeing_fwhm_arcsec, lambda v: v >= 0, "≥ 0"),
                ("airmass", self.airmass, lambda v: 1 <= v <= 40, "from 1 to 40"),
                ("altitude_m", self.altitude_m, lambda v: -500 <= v <= 10000, "from −500 to 10000 m")):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and ok(value)):
                raise SimulationError(f"atmosphere {name} must be {what}, got {value!r}")
        return self


def seeing_sigma_px(seeing_fwhm_arcsec: float, plate_scale_rad: float) -> float:
    """The seeing disc's Gaussian σ in pixels of ``plate_scale_rad`` radians."""
    return seeing_fwhm_arcsec * _ARCSEC * FWHM_TO_SIGMA / plate_scale_rad


def young_scintillation(aperture_mm: float, exposure_s: float, airmass: float = 1.0,
                        altitude_m: float = 0.0) -> float:
    """Relative flux σ of scintillation by Young's formula (module text)."""
    d_cm = aperture_mm / 10.0
    return (0.09 * d_cm ** (-2.0 / 3.0) * airmass ** 1.75 * math.exp(-altitude_m / _SCALE_HEIGHT_M)
            / math.sqrt(2.0 * exposure_s))


def scintillate(electrons: np.ndarray, sigma_rel: float, rng: np.random.Generator) -> np.ndarray:
    """``electrons`` each times a log-normal factor of mean 1 and relative σ ``sigma_rel``."""
    electrons = np.asarray(electrons, dtype=np.float64)
    if sigma_rel <= 0 or electrons.size == 0:
        return electrons
    s = math.sqrt(math.log1p(sigma_rel * sigma_rel))
    return electrons * np.exp(s * rng.standard_normal(electrons.shape) - 0.5 * s * s)
