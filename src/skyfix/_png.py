"""PNG row unfiltering (the step after inflating the image data), as one numba kernel.

A PNG stores each row as a filter-type byte and the row's bytes predicted from already decoded
neighbours (PNG specification § 9): 0 None, 1 Sub (the byte ``bpp`` to the left), 2 Up (the byte
above), 3 Average (of left and above, rounded down), 4 Paeth (whichever of left, above and
upper-left is closest to left + above − upper-left). Decoding adds the prediction back, mod 256.
Sub, Average and Paeth carry a dependency along the row from one pixel to the next, so the loop
runs one byte lane (``i ≡ lane mod bpp``) at a time and keeps the left byte in a register; Up
and None are plain vector loops. :mod:`skyfix.io` inflates and calls this.

Compiling it takes 2–4 s on a loaded 2-core machine (once: numba caches it; a cached load is
≈ 60 ms). Written with per-row views and scalar loops: the first version, with slice
assignments, compiled 3× longer for the same speed.
"""

from __future__ import annotations

import numpy as np

from skyfix._jit import njit

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
    out = np.zeros((height + 1, row_bytes), np.uint8)  # row 0: the zero row "above" the image
    stride = row_bytes + 1
    for r in range(height):
        kind = raw[r * stride]
        src = raw[r * stride + 1:(r + 1) * stride]
        cur = out[r + 1]
        up = out[r]
        if kind == 0:
            for i in range(row_bytes):  # a loop: a slice assignment here triples the compile time
                cur[i] = src[i]
        elif kind == 2:
            for i in range(row_bytes):
                cur[i] = src[i] + up[i]
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
                    left = (src[i] + ((left + up[i]) >> 1)) & 255
                    cur[i] = left
        elif kind == 4:
            for lane in range(bpp):
                left = 0
                upper_left = 0
                for i in range(lane, row_bytes, bpp):
                    above = np.int64(up[i])
                    pa = abs(above - upper_left)  # |p - left| with p = left + above - upper_left
                    pb = abs(left - upper_left)  # |p - above|
                    pc = abs(left + above - 2 * upper_left)  # |p - upper_left|
                    pred = left if (pa <= pb and pa <= pc) else (above if pb <= pc else upper_left)
                    left = (src[i] + pred) & 255
                    upper_left = above
                    cur[i] = left
        else:
            return out[1:], r
    return out[1:], -1
