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
and principal point unknown) can leave the boresight uncertain by tens of arcseconds. A
solution counts as solved only when its own covariance gives it a chance of at most
:data:`MAX_WRONG_PROBABILITY` (1e-3) of an error beyond what makes it wrong — boresight
max(60″, 1 px), roll 0.5° (:func:`wrong_probability`, :func:`precision_failure`); otherwise it
fails with the σ in the reason. A bar on 2σ (the first rule) let through solutions with a 1–10 %
chance of being wrong: on 10 000 blind uncalibrated sparse fields with honest error bars
(normalised RMS 1.02–1.08) that bound summed to 5.3 expected wrong attitudes and one came
70″ off at 2.6σ; at 1e-3 the bound sums to 0.24 and 667 of 8767 solutions (7.6 %) fail instead
(``tests/test_final_fit.py::test_precision_rule_bounds_the_chance_of_a_wrong_attitude``).
"""

from __future__ import annotations

import math

import numpy as np

from skyfix.identify.verify import log_binom_sf

__all__ = ["MAX_WRONG_PROBABILITY", "WRONG_BORESIGHT_ARCSEC", "WRONG_ROLL_DEG", "chance_log_probability",
           "is_beyond_chance", "precision_failure", "wrong_probability"]

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


def wrong_probability(covariance_rad2: np.ndarray, plate_scale_rad: float) -> float:
    """An upper bound on the chance, under the Gaussian error the covariance describes, that the
    attitude is wrong: boresight error beyond max(60″, 1 px) or roll error beyond 0.5°.

    The boresight error's length is bounded by a circular Gaussian with the larger eigenvalue
    λ of the cross-boresight block (``P(|e| > L) ≤ exp(−L²/2λ)``); the roll's is two-sided
    normal. NaN or negative variances give 1."""
    c = np.asarray(covariance_rad2, dtype=np.float64)
    if not np.all(np.isfinite(c)):
        return 1.0
    a, b, d = c[0, 0], c[0, 1], c[1, 1]
    lam = (a + d) / 2.0 + math.sqrt(max(((a - d) / 2.0) ** 2 + b * b, 0.0))
    bound = max(WRONG_BORESIGHT_ARCSEC * _ARCSEC, plate_scale_rad)
    p_bore = math.exp(-bound * bound / (2.0 * lam)) if lam > 0.0 else 0.0
    var_roll = c[2, 2]
    p_roll = math.erfc(math.radians(WRONG_ROLL_DEG) / math.sqrt(2.0 * var_roll)) if var_roll > 0.0 else 0.0
    return min(p_bore + p_roll, 1.0) if lam >= 0.0 and var_roll >= 0.0 else 1.0


# The largest chance of a wrong attitude (wrong_probability) a solution may carry.
MAX_WRONG_PROBABILITY = 1e-3


def precision_failure(covariance_rad2: np.ndarray, plate_scale_rad: float) -> str:
    """Why an attitude is too uncertain to report as solved ("" when it is not): its
    :func:`wrong_probability` beyond :data:`MAX_WRONG_PROBABILITY`."""
    p_wrong = wrong_probability(covariance_rad2, plate_scale_rad)
    if not p_wrong <= MAX_WRONG_PROBABILITY:  # NaN fails too
        c = np.asarray(covariance_rad2, dtype=np.float64)
        sigma_bore = math.sqrt(max(c[0, 0] + c[1, 1], 0.0)) / _ARCSEC
        sigma_roll = math.degrees(math.sqrt(max(c[2, 2], 0.0)))
        return (f"attitude too uncertain: σ boresight {sigma_bore:.0f}″, roll {sigma_roll:.2f}° "
                f"({p_wrong:.1g} chance of an error beyond {WRONG_BORESIGHT_ARCSEC:.0f}″ or "
                f"{WRONG_ROLL_DEG}°; the stars matched do not pin down an unknown camera: give "
                "--camera FILE or --fov)")
    return ""
