"""A mask of the pixels that show sky: stars found elsewhere (a horizon, trees, a building, a
caption burned into a photograph, the dark corners outside an all-sky lens's circle) are dropped.

A mask is an image of the frame's size: non-zero (white) where the sky is to be used, zero
(black) where it is not — the convention of all-sky camera masks and of weight maps. A star is
kept when every pixel within :data:`MASK_MARGIN_PX` of its centroid is sky, so the glow at a
mask's edge (a lit roof line, a tree's fringe) does not make stars.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skyfix.detect.centroids import Centroids
from skyfix.errors import InputError

__all__ = ["MASK_MARGIN_PX", "as_mask", "sky_only"]

MASK_MARGIN_PX = 3
"""Stars closer than this to a masked pixel are dropped, pixels."""


def as_mask(mask: np.ndarray | str | Path, shape: tuple[int, int] | None = None,
            margin_px: int = MASK_MARGIN_PX) -> np.ndarray:
    """``mask`` (an array or an image file) as a boolean (H, W) array, True where a star may be:
    sky, and no masked pixel within ``margin_px``.

    Raises
    ------
    InputError
        Not a 2-D image, not of ``shape`` (the frame's (H, W)) when given, or it masks everything.
    ImageReadError
        The file cannot be read.
    """
    if isinstance(mask, (str, Path)):
        from skyfix.io import read_image

        mask = read_image(mask)
    m = np.asarray(mask)
    if m.ndim == 3:  # a colour mask: any channel lit is sky
        m = m.any(axis=-1)
    if m.ndim != 2:
        raise InputError(f"a mask is a 2-D image, not an array of shape {m.shape}")
    if shape is not None and m.shape != tuple(shape):
        raise InputError(f"the mask is {m.shape[1]}×{m.shape[0]} pixels, the image {shape[1]}×{shape[0]}: "
                         "a mask must be the image's size")
    sky = np.nan_to_num(m.astype(np.float64, copy=False), nan=0.0) != 0.0
    if not sky.any():
        raise InputError("the mask hides every pixel (white = sky to use, black = ignore)")
    if margin_px > 0:
        from scipy.ndimage import binary_erosion

        sky = binary_erosion(sky, np.ones((2 * margin_px + 1,) * 2, bool), border_value=1)
    return sky


def sky_only(centroids: Centroids, usable: np.ndarray) -> Centroids:
    """The centroids whose nearest pixel is True in ``usable`` (:func:`as_mask`, the frame's
    shape). Order kept (brightest first)."""
    if len(centroids) == 0:
        return centroids
    h, w = usable.shape
    col = np.clip(np.rint(centroids.x).astype(np.int64), 0, w - 1)
    row = np.clip(np.rint(centroids.y).astype(np.int64), 0, h - 1)
    return centroids.subset(np.flatnonzero(usable[row, col]))
