"""What a phone or a cheap camera does to a frame before anyone sees it: 8-bit output and lossy
JPEG (thesis 003's Droid X2 delivered 8-bit JPEG only).

:func:`jpeg_roundtrip` scales a deeper image linearly to 8 bits (``round(ADU · 255 / max_adu)``:
the phone's own rescaling, without its tone curve), encodes it as a greyscale JPEG with Pillow at
``quality`` (1–95, libjpeg's scale; 4:2:0 chroma does not arise in one channel) and decodes it.
JPEG's 8 × 8 DCT quantisation rounds a faint star's high frequencies away and adds blocking; the
result is ``uint8``.
"""

from __future__ import annotations

import io

import numpy as np

from skyfix.errors import SimulationError

__all__ = ["JPEG_QUALITIES", "jpeg_roundtrip", "to_8bit"]

#: The qualities Pillow's JPEG encoder takes (above 95 it stops compressing and only grows).
JPEG_QUALITIES = range(1, 96)


def to_8bit(image: np.ndarray, max_adu: int) -> np.ndarray:
    """``image`` (ADU, 0 … ``max_adu``) as 8 bits, linearly: ``round(ADU · 255 / max_adu)``."""
    if max_adu == 255:
        return np.clip(np.rint(image), 0, 255).astype(np.uint8)
    return np.clip(np.rint(np.asarray(image, dtype=np.float64) * (255.0 / max_adu)), 0, 255).astype(np.uint8)


def jpeg_roundtrip(image: np.ndarray, quality: int, max_adu: int) -> np.ndarray:
    """``image`` through 8 bits and a JPEG at ``quality`` and back (``uint8``)."""
    from PIL import Image

    if int(quality) not in JPEG_QUALITIES:
        raise SimulationError(f"JPEG quality must be an integer from 1 to 95, got {quality!r}")
    buf = io.BytesIO()
    Image.fromarray(to_8bit(image, max_adu)).save(buf, format="JPEG", quality=int(quality))
    buf.seek(0)
    with Image.open(buf) as im:
        return np.asarray(im.convert("L"), dtype=np.uint8)
