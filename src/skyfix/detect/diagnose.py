"""Why a frame holds no usable stars: blank, saturated or too small — one phrase for a
failure reason (``solve``'s and ``skyfix analyze``'s)."""

from __future__ import annotations

import numpy as np

from skyfix.detect.saturation import saturation_level

__all__ = ["MIN_FRAME_PX", "SATURATED_FRACTION", "frame_problem"]

#: A frame narrower or lower than this, pixels, cannot hold the three or more stars a solve
#: needs, each a few pixels wide and apart from the others.
MIN_FRAME_PX = 32

#: A frame with at least this fraction of its pixels at full scale is called saturated.
SATURATED_FRACTION = 0.25


def frame_problem(image: np.ndarray) -> str:
    """What is wrong with a frame as a star image, or ``""`` when nothing obvious is.

    In this order: smaller than :data:`MIN_FRAME_PX` on a side; at least
    :data:`SATURATED_FRACTION` of the pixels at a full-scale value
    (:func:`~skyfix.detect.saturation_level`); every pixel the same.
    """
    img = np.asarray(image)
    if img.ndim != 2 or img.size == 0:
        return ""
    h, w = img.shape
    if h < MIN_FRAME_PX or w < MIN_FRAME_PX:
        side = f"{MIN_FRAME_PX}×{MIN_FRAME_PX}"
        return (f"the image is {w}×{h} pixels, too small for any star field (a solve needs three or "
                f"more stars, a few pixels apart: give the whole frame, at least {side})")
    full = saturation_level(img)
    if np.isfinite(full):
        fraction = np.count_nonzero(img >= full) / img.size
        if fraction >= SATURATED_FRACTION:
            return f"saturated frame: {fraction:.0%} of the pixels at full scale {full:g} (overexposed?)"
    lo, hi = np.min(img), np.max(img)
    if lo == hi:
        return f"blank frame: every pixel is {float(lo):g} (lens cap on, or no exposure?)"
    return ""
