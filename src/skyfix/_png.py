"""PNG row unfiltering and sample conversion (the steps after inflating the image data), as one
numba kernel.

A PNG stores each row as a filter-type byte and the row's bytes predicted from already decoded
neighbours (PNG specification § 9): 0 None, 1 Sub (the byte ``bpp`` to the left), 2 Up (the byte
above), 3 Average (of left and above, rounded down), 4 Paeth (whichever of left, above and
upper-left is closest to left + above − upper-left). Decoding adds the prediction back, mod 256.
Sub, Average and Paeth carry a dependency along the row from one pixel to the next, so the loop
runs one byte lane (``i ≡ lane mod bpp``) at a time and keeps the left byte in a register; Up
and None are plain vector loops.

Each decoded row of a grey image, still in the cache, is then written out as float32 samples
(big-endian 16-bit samples combined): the frame the extraction reads comes out of this one
pass, with no full-size byte buffer and no conversion pass after it. A colour image's rows are
written out as bytes. :mod:`skyfix.io` inflates and calls this.

Compiling it takes 2–4 s on a loaded 2-core machine (once: numba caches it). Written with
per-row views and scalar loops: a first version with slice assignments compiled 3× longer for
the same speed.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from skyfix._jit import njit

__all__ = ["PngLayout", "decode_rows"]


class PngLayout(NamedTuple):
    """How a non-interlaced PNG's inflated image data is laid out (from its IHDR chunk)."""

    height: int
    width: int
    #: samples per pixel: 1 grey, 2 grey + alpha, 3 RGB, 4 RGBA
    channels: int
    #: bytes per sample: 1 (8-bit) or 2 (16-bit, big-endian)
    sample_bytes: int


@njit(cache=True, nogil=True)
def decode_rows(raw: np.ndarray, layout: PngLayout, out: np.ndarray) -> int:
    """Undo the PNG row filters of a non-interlaced image and write out its samples.

    Parameters
    ----------
    raw : read-only ndarray of uint8, shape (height * (1 + width * channels * sample_bytes),)
        The inflated image data: per row, the filter-type byte then the row's bytes (read-only
        whatever its source, so that numba compiles one signature).
    layout : PngLayout
        The image's size and sample layout.
    out : ndarray
        Grey (``channels`` 1 or 2): float32, shape (height, width), receives each pixel's grey
        sample (the alpha sample left out) — the frame as the extraction reads it. Colour:
        uint8, shape (height, width * channels * sample_bytes), receives the decoded bytes of
        each row, for :func:`skyfix.io.as_image`'s integer luminance. Two compiled signatures.

    Returns
    -------
    int
        -1, or the index of the first row whose filter type is not 0–4 (``out`` is then
        undefined from that row on).
    """
    width, channels, sample_bytes = layout.width, layout.channels, layout.sample_bytes
    bpp = channels * sample_bytes  # bytes per complete pixel: the distance to the "left" byte
    row_bytes = width * bpp
    stride = row_bytes + 1
    rows = np.zeros((2, row_bytes), np.uint8)  # this row and the one above: zeros above the first
    for r in range(layout.height):
        kind = raw[r * stride]
        src = raw[r * stride + 1:(r + 1) * stride]
        cur = rows[(r + 1) & 1]
        up = rows[r & 1]
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
            return r
        dst = out[r]
        if channels > 2:  # colour: the row's bytes as they are
            for i in range(row_bytes):
                dst[i] = cur[i]
        elif sample_bytes == 1:  # 8-bit grey (+ alpha)
            for x in range(width):
                dst[x] = cur[x * bpp]
        elif bpp == 2:  # 16-bit grey: one big-endian uint16 a pixel
            pairs = cur.view(np.uint16)
            for x in range(width):
                v = pairs[x]
                dst[x] = ((v & 255) << 8) | (v >> 8)
        else:  # 16-bit grey + alpha
            for x in range(width):
                dst[x] = (np.int32(cur[x * 4]) << 8) | np.int32(cur[x * 4 + 1])
    return -1
