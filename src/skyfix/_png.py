"""PNG row unfiltering and sample conversion (the steps after inflating the image data), as one
numba kernel.

A PNG stores each row as a filter-type byte and the row's bytes predicted from already decoded
neighbours (PNG specification § 9): 0 None, 1 Sub (the byte ``bpp`` to the left), 2 Up (the byte
above), 3 Average (of left and above, rounded down), 4 Paeth (whichever of left, above and
upper-left is closest to left + above − upper-left). Decoding adds the prediction back, mod 256.
Sub, Average and Paeth carry a dependency along the row from one pixel to the next, so the loop
runs along byte lanes (``i ≡ lane mod bpp``), two at a time, keeping their left bytes in
registers; Up and None are plain vector loops.

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
        elif kind == 1 and bpp == 2:  # Sub of 16-bit grey (or 8-bit grey + alpha): both lanes in one word
            for i in range(row_bytes):
                cur[i] = src[i]
            words = cur.view(np.uint16)
            left = np.uint32(0)
            for x in range(width):
                v = np.uint32(words[x])
                # each byte plus the byte to its left, mod 256, without a carry between the two
                left = (((v & 0xFF) + (left & 0xFF)) & 0xFF) | (((v & 0xFF00) + (left & 0xFF00)) & 0xFF00)
                words[x] = left
        elif kind == 1:
            _along_lanes(_sub, src, up, cur, row_bytes, bpp)
        elif kind == 3:
            _along_lanes(_average, src, up, cur, row_bytes, bpp)
        elif kind == 4:
            _along_lanes(_paeth, src, up, cur, row_bytes, bpp)
        else:
            return r
        dst = out[r]
        if channels > 2:  # colour: the row's bytes as they are
            for i in range(row_bytes):
                dst[i] = cur[i]
        elif bpp == 1:  # 8-bit grey (a loop of its own: a contiguous one vectorises)
            for x in range(width):
                dst[x] = cur[x]
        elif sample_bytes == 1:  # 8-bit grey + alpha
            for x in range(width):
                dst[x] = cur[2 * x]
        elif bpp == 2:  # 16-bit grey: one big-endian uint16 a pixel
            pairs = cur.view(np.uint16)
            for x in range(width):
                v = pairs[x]
                dst[x] = ((v & 255) << 8) | (v >> 8)
        else:  # 16-bit grey + alpha
            for x in range(width):
                dst[x] = (np.int32(cur[x * 4]) << 8) | np.int32(cur[x * 4 + 1])
    return -1


@njit(cache=True, inline="always")
def _along_lanes(predict, src, up, cur, row_bytes, bpp):
    """A Sub, Average or Paeth row: each byte plus ``predict(left, above, upper_left)``, mod 256.

    The chain runs along each byte lane, two lanes at a time so that their two chains overlap
    (one lane at a time waits on each step), keeping the left bytes in registers. ``predict``
    is a kernel: numba compiles this loop once for each, with the prediction written in.
    """
    for lane in range(0, bpp - 1, 2):
        left0 = left1 = upper_left0 = upper_left1 = np.int64(0)
        for i in range(lane, row_bytes, bpp):
            above0, above1 = np.int64(up[i]), np.int64(up[i + 1])
            left0 = (np.int64(src[i]) + predict(left0, above0, upper_left0)) & 255
            left1 = (np.int64(src[i + 1]) + predict(left1, above1, upper_left1)) & 255
            upper_left0, upper_left1 = above0, above1
            cur[i] = left0
            cur[i + 1] = left1
    if bpp % 2:  # the last lane, alone
        left0 = upper_left0 = np.int64(0)
        for i in range(bpp - 1, row_bytes, bpp):
            above0 = np.int64(up[i])
            left0 = (np.int64(src[i]) + predict(left0, above0, upper_left0)) & 255
            upper_left0 = above0
            cur[i] = left0


@njit(cache=True, inline="always")
def _sub(left, above, upper_left):
    """Sub's prediction: the byte to the left."""
    return left


@njit(cache=True, inline="always")
def _average(left, above, upper_left):
    """Average's prediction: the mean of left and above, rounded down."""
    return (left + above) >> 1


@njit(cache=True, inline="always")
def _paeth(left, above, upper_left):
    """Paeth's prediction: whichever of left, above and upper-left is closest to
    p = left + above − upper-left (ties in that order)."""
    pa = abs(above - upper_left)  # |p - left|
    pb = abs(left - upper_left)  # |p - above|
    pc = abs(left + above - 2 * upper_left)  # |p - upper_left|
    return left if (pa <= pb and pa <= pc) else (above if pb <= pc else upper_left)
