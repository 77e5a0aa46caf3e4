"""A frame averaged along a known smear: the matched filter for streaked stars.

When the camera turns during the exposure every star draws a streak; at 2 °/s, 0.1 s and
85 px/° a streak is 17 px long, its light spread over 17× the pixels of a still star, its
per-pixel signal-to-noise 17× lower, and the extractor finds a few bright stars broken into
pieces and none of the faint ones: lost in space fails. When the smear is known — a gyro's
rate, or the tracker's estimate, times the exposure (:func:`skyfix.detect.streak_motion`) —
averaging the frame along it (the mean of the frame shifted by each whole-pixel offset along
the segment) adds each streak's light back into one compact blob with the noise averaged
down: the matched filter of a line, on top of the extractor's own PSF smoothing.

The offsets are symmetric about zero (``±k``), so a streak's blob keeps its centre: the
centroid of the filtered streak is the star's mid-exposure position (as for
:func:`skyfix.detect.centroid_streaks`). A roll about the boresight smears the corners
differently from the centre; the filter is the centre's, which still concentrates the light
of the field's other streaks, if less.
"""

from __future__ import annotations

import math

import numpy as np

from skyfix.errors import InputError

__all__ = ["smear_filter", "smear_offsets"]


def smear_offsets(motion_px) -> np.ndarray:
    """The whole-pixel offsets (M, 2) ``(dx, dy)`` along a smear of displacement ``motion_px``
    (dx, dy) pixels: one per pixel of its length, symmetric about zero (``(0, 0)`` alone for a
    smear under a pixel)."""
    try:
        m = np.asarray(motion_px, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        m = np.full(1, np.nan)
    if m.shape != (2,) or not np.all(np.isfinite(m)):
        raise InputError(f"a smear is two finite numbers (dx, dy) in pixels, got {motion_px!r}")
    half = 0.5 * float(np.hypot(m[0], m[1]))
    k = int(math.floor(half))
    steps = np.arange(1, k + 1) / max(half, 1e-300) * 0.5  # fractions of the segment, one pixel apart
    ahead = np.unique(np.rint(np.outer(steps, m)).astype(np.int64), axis=0)
    ahead = ahead[np.any(ahead != 0, axis=1)]
    return np.concatenate([-ahead[::-1], np.zeros((1, 2), np.int64), ahead])


def smear_filter(image: np.ndarray, motion_px) -> np.ndarray:
    """The frame averaged along the smear ``motion_px`` (module docstring), float32, its size.

    Parameters
    ----------
    image : (H, W) array
        The frame, ADU.
    motion_px : (2,) array
        The stars' displacement over the exposure, end minus start, pixels.

    Returns
    -------
    (H, W) float32 array
        The mean of the frame at the offsets of :func:`smear_offsets` (the edge pixels repeated
        beyond the frame).
    """
    img = np.asarray(image)
    if img.ndim != 2 or img.dtype.kind not in "uif":
        raise InputError(f"image must be a 2-D array of numbers, got shape {img.shape} of {img.dtype}")
    offsets = smear_offsets(motion_px)
    r = int(np.abs(offsets).max(initial=0))
    h, w = img.shape
    padded = np.pad(img.astype(np.float32, copy=False), r, mode="edge") if r else img.astype(np.float32)
    out = np.zeros((h, w), np.float32)
    for dx, dy in offsets.tolist():
        out += padded[r + dy:r + dy + h, r + dx:r + dx + w]
    out *= np.float32(1.0 / len(offsets))
    return out
