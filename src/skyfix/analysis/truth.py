"""A solve against its truth: the one definition of a **wrong attitude** every study, campaign,
benchmark and test uses.

An attitude reported as solved is **wrong** when its boresight error exceeds
max(:data:`~skyfix.identify.accept.WRONG_BORESIGHT_ARCSEC` (60″), one pixel) or its roll error
exceeds :data:`~skyfix.identify.accept.WRONG_ROLL_DEG` (0.5°) — :func:`is_wrong`. The pixel
floor keeps a wide lens's right answer (a 90° field has 4′ pixels) from counting as wrong for
a sub-pixel error; the thresholds live in :mod:`skyfix.identify.accept` beside the precision
rule that bounds the chance of crossing them.

The error itself is taken at the pixel the solution calls its boresight (its principal point,
:func:`attitude_error_rad`): with no camera file the optical axis is not known, but the sky
direction of that pixel and the roll there are. Where both sides share one camera this is the
plain camera-frame error :func:`skyfix.attitude.attitude_error`.

How often a method is wrong is bounded by :func:`upper_bound_95` (Clopper–Pearson), the bound
every study's and campaign's wrong rate carries.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix.calibrate import frame_rotation_at_pixel
from skyfix.camera import Camera
from skyfix.identify.accept import WRONG_BORESIGHT_ARCSEC, WRONG_ROLL_DEG

__all__ = ["Judgement", "WRONG_BORESIGHT_ARCSEC", "WRONG_ROLL_DEG", "attitude_error_rad", "is_wrong",
           "judge", "judge_error", "upper_bound_95"]

_ARCSEC = math.pi / (180.0 * 3600.0)


def is_wrong(boresight_arcsec: float, roll_deg: float, plate_scale_arcsec: float = 0.0) -> bool:
    """True when a solved attitude's boresight error (″) exceeds max(60″, one pixel of
    ``plate_scale_arcsec``) or its roll error (°, absolute) exceeds 0.5°. NaN errors are wrong."""
    return not (boresight_arcsec <= max(WRONG_BORESIGHT_ARCSEC, plate_scale_arcsec)
                and abs(roll_deg) <= WRONG_ROLL_DEG)


class Judgement(NamedTuple):
    """A solved attitude against its truth (:func:`judge`)."""

    wrong: bool
    boresight_arcsec: float
    roll_deg: float  # absolute
    error_rad: np.ndarray  # (x, y, roll) about the solution's camera axes


def attitude_error_rad(A_est: np.ndarray, camera_est: Camera, A_true: np.ndarray, camera_true: Camera
                       ) -> np.ndarray:
    """Rotation vector (3,) rad from the true frame to the estimated one, about the estimated
    camera's axes, both frames taken at the estimated principal point's pixel: z the sky
    direction of that pixel, x the direction in which the column grows there
    (:func:`skyfix.calibrate.frame_rotation_at_pixel`)."""
    return frame_rotation_at_pixel(A_est, camera_est, A_true, camera_true, (camera_est.cx, camera_est.cy))


def judge_error(error_rad: np.ndarray, plate_scale_arcsec: float = 0.0) -> Judgement:
    """:class:`Judgement` of an error rotation vector (x, y, roll) rad."""
    bore = math.hypot(float(error_rad[0]), float(error_rad[1])) / _ARCSEC
    roll = abs(math.degrees(float(error_rad[2])))
    err = np.asarray(error_rad, dtype=np.float64)
    return Judgement(is_wrong(bore, roll, plate_scale_arcsec), bore, roll, err)


def judge(A_est: np.ndarray, camera_est: Camera | None, A_true: np.ndarray, camera_true: Camera) -> Judgement:
    """A solved attitude ``A_est`` (through ``camera_est``, the solution's camera; None: the true
    one) against the truth; one pixel is the true camera's."""
    err = attitude_error_rad(A_est, camera_est or camera_true, A_true, camera_true)
    return judge_error(err, math.degrees(camera_true.plate_scale_rad) * 3600.0)


def upper_bound_95(k: int, n: int) -> float:
    """One-sided 95 % Clopper–Pearson upper bound of a rate seen ``k`` times in ``n`` (with
    ``k = 0``: 1 − 0.05^(1/n) ≈ 3/n, the rule of three)."""
    from scipy.stats import beta

    if n <= 0:
        return 1.0
    return 1.0 if k >= n else float(beta.ppf(0.95, k + 1, n - k))
