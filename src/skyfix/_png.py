"""PNG row unfiltering (the step after inflating the image data), as one numba kernel.

A PNG stores each row as a filter-type byte and the row's bytes predicted from already decoded
neighbours (PNG specification § 9): 0 None, 1 Sub (the byte ``bpp`` to the left), 2 Up (the byte
above), 3 Average (of left and above, rounded down), 4 Paeth (whichever of left, above and
upper-left is closest to left + above − upper-left). Decoding adds the prediction back, mod 256.
Sub, Average and Paeth carry a dependency along the row from one pixel to the next, so the loop
runs one byte lane (``i ≡ lane mod bpp``) at a time and keeps the left byte in a register; Up
and None are plain vector loops. :mod:`skyfix.io` inflates and calls this.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["unfilter_rows"]


@njit(cache=True, nogil=True)
def unfilter_rows(raw: np.ndarray, height: int, row_bytes: int, bpp: int) -> tuple[np.ndarray, int]:
    """Undo the PNG row filters of a non-interlaced image.

    Parameters
    ----------
    raw : ndarray of uint8, shape (height * (row_bytes + 1),)
        The inflated image data: per row, the filter-type byte then ``row_bytes`` bytes.
    height, row_bytes : int
        Rows, and bytes per row (width × bytes per pixel).
    bpp : int
        Bytes per complete pixel (1–8): the distance to the "left" byte.

    Returns
    -------
    (ndarray of uint8, shape (height, row_bytes), int)
        The decoded rows, and -1, or the index of the first row whose filter type is not 0–4
        (the rows from it on are undefined).
    """
    out = np.empty((height, row_bytes), np.uint8)
    zero = np.zeros(row_bytes, np.uint8)
    stride = row_bytes + 1
    for r in range(height):
        kind = raw[r * stride]
        src = raw[r * stride + 1:(r + 1) * stride]
        cur = out[r]
        up = out[r - 1] if r > 0 else zero
        if kind == 0:
            cur[:] = src
        elif kind == 2:
            for i in range(row_bytes):
                cur[i] = (src[i] + up[i]) & 255
        elif kind == 1:
            for lane in range(bpp):
                left = 0
                for i in range(lane, row_bytes, bpp):
                    left = (src[i] + left) & 255
                    cur[i] = left
        elif kind == 3:
            for lane in range(bpp):
                left = 0
                for i in range(lane, row_bytes, bpp):
                    left = (src[i] + ((left + np.int32(up[i])) >> 1)) & 255
                    cur[i] = left
        elif kind == 4:
            for lane in range(bpp):
                left = 0
                upper_left = 0
                for i in range(lane, row_bytes, bpp):
                    above = np.int32(up[i])
                    p = left + above - upper_left
                    pa = abs(p - left)
                    pb = abs(p - above)
                    pc = abs(p - upper_left)
                    if pa <= pb and pa <= pc:
                        pred = left
                    elif pb <= pc:
                        pred = above
                    else:
                        pred = upper_left
                    left = (src[i] + pred) & 255
                    upper_left = above
                    cur[i] = left
        else:
            return out, r
    return out, -1
