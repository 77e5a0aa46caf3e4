"""When a match of image stars to catalogue stars counts as an identification.

A match is accepted only when chance cannot explain it. The test is the same wherever a set of
matches is judged — after a pattern's refit (:mod:`skyfix.identify.quad`) and after the final
fit with a camera model fitted to the same stars (:mod:`skyfix.final_fit`):

*Chance.* ``n_cat`` catalogue stars are predicted in the frame; each lands within ``radius``
pixels of one of ``n_img`` centroids scattered over ``area`` pixels with probability
``p = n_img·π·radius² / area`` (capped at 1). ``k`` or more chance matches out of ``n_cat``
is a binomial tail, and the match is accepted when that tail is below ``exp(log_threshold)``
(``prob_threshold`` of :func:`skyfix.identify.identify`, 1e-9 by default).

*Freedom paid for.* A camera model fitted to the matched stars can bend to fit them: each
number it fits beyond the focal length can put about half a star (two coordinates) where it
wants. The test therefore discounts ``ceil(n_extra / 2)`` matches, ``n_extra`` being the
effective number of camera numbers the fit took beyond the focal length (the trace of its hat
matrix less the rotations and the focal length). Without this a sparse field whose model was
chosen from the same few stars it was verified against was accepted with wrong stars
(``tests/test_final_fit.py::test_sparse_non_square_never_wrong``).

*Precise enough to be right.* Identification can be sure of the stars while the attitude is
not sure enough to be called right: a sparse field from an unknown camera (aspect, distortion
and principal point unknown) can leave the boresight uncertain by more than a pixel. A solution
counts as solved only when twice its reported σ is within what would make it wrong —
boresight max(60″, 1 px), roll 0.5° (:func:`precision_failure`); otherwise it fails with the
σ in the reason. On 1000 blind uncalibrated sparse fields this turned the three solutions that
were wrong (with honest error bars of 140–200″) and 53 imprecise ones into failures.
"""

from __future__ import annotations

import math

import numpy as np

from skyfix.identify.verify import log_binom_sf

__all__ = ["chance_log_probability", "is_beyond_chance", "precision_failure"]

# What makes an attitude wrong (the campaigns' and the benchmarks' bar): boresight error beyond
# max(WRONG_BORESIGHT_ARCSEC, one pixel), or roll error beyond WRONG_ROLL_DEG.
WRONG_BORESIGHT_ARCSEC = 60.0
WRONG_ROLL_DEG = 0.5
_ARCSEC = math.pi / (180.0 * 3600.0)


def chance_log_probability(n_pairs: int, n_cat: int, n_img: int, radius_px: float, area_px2: float,
                           n_extra: float = 0.0) -> float:
    """log P(a match at least this good by chance), see the module text.

    Parameters
    ----------
    n_pairs : int — catalogue stars matched.
    n_cat : int — catalogue stars predicted in the frame (the trials).
    n_img : int — centroids they could match.
    radius_px : float — match radius, px.
    area_px2 : float — frame area, px².
    n_extra : float — camera numbers fitted to these stars beyond the focal length.
    """
    p_chance = min(1.0, n_img * math.pi * radius_px**2 / max(area_px2, 1e-300))
    k = n_pairs - math.ceil(max(n_extra, 0.0) / 2.0 - 1e-9)
    return float(log_binom_sf(k, int(n_cat), p_chance))


def is_beyond_chance(n_pairs: int, n_cat: int, n_img: int, radius_px: float, area_px2: float,
                     log_threshold: float, n_extra: float = 0.0) -> bool:
    """Whether a match passes :func:`chance_log_probability` ``<= log_threshold``."""
    return chance_log_probability(n_pairs, n_cat, n_img, radius_px, area_px2, n_extra) <= log_threshold


def precision_failure(covariance_rad2: np.ndarray, plate_scale_rad: float) -> str:
    """Why an attitude is too uncertain to report as solved ("" when it is not): 2σ of the
    boresight (both cross axes) beyond max(60″, 1 px), or 2σ of the roll beyond 0.5°."""
    c = np.asarray(covariance_rad2, dtype=np.float64)
    sigma_bore = math.sqrt(max(c[0, 0] + c[1, 1], 0.0)) / _ARCSEC
    sigma_roll = math.degrees(math.sqrt(max(c[2, 2], 0.0)))
    bound = max(WRONG_BORESIGHT_ARCSEC, plate_scale_rad / _ARCSEC)
    if not (2.0 * sigma_bore <= bound and 2.0 * sigma_roll <= WRONG_ROLL_DEG):  # NaN fails too
        return (f"attitude too uncertain: σ boresight {sigma_bore:.0f}″, roll {sigma_roll:.2f}° "
                "(the stars matched do not pin down an unknown camera: give --camera FILE or --fov)")
    return ""
