"""Saturation: the pixel level at which a sensor clips, judged from the frame itself.

A frame whose brightest pixel sits at a full-scale value (1 for normalised floats, 255 … 65535
for 8- to 16-bit sensors) is taken to clip there, and the stars holding such pixels are
flagged saturated; a frame whose maximum is anywhere else has no saturated star. Every
detection method and :func:`~skyfix.detect.frame_problem` use this one rule.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["FULL_SCALES", "saturation_level", "full_scale"]

#: Full-scale values of common integer sensors and of normalised float images.
FULL_SCALES = (1.0, 255.0, 1023.0, 4095.0, 16383.0, 65535.0)


def saturation_level(image: np.ndarray) -> float:
    """The frame's saturation level: its maximum if that is a full-scale value, else +inf.

    Full scale means 1, 255, 1023, 4095, 16383 or 65535 within 0.5% (8- to 16-bit sensors and
    normalised floats). A frame whose brightest pixel is below full scale has no saturated star.
    """
    return full_scale(float(np.max(image)))


def full_scale(vmax: float) -> float:
    """``vmax`` if it is within 0.5% of one of :data:`FULL_SCALES`, else +inf."""
    near = any(abs(f - vmax) <= 0.005 * f for f in FULL_SCALES)  # six floats: no numpy call
    return vmax if near else math.inf
