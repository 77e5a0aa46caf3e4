"""Image reading: FITS, PNG, TIFF and JPEG files (or arrays) to one 2-D float32 luminance frame.

Pixel values keep the file's own units (ADU): an 8-bit file gives 0–255, a 16-bit file
0–65535, a FITS file its stored physical values. Colour images become luminance with the
ITU-R BT.601 weights (0.299 R + 0.587 G + 0.114 B), which sum to one, so a saturated
colour pixel stays at full scale. A colour JPEG is decoded straight to its stored luminance
plane (JPEG's Y is the same BT.601 luma), which is faster and skips a colour round trip.

Pixels are returned as stored: no EXIF rotation is applied (a star camera's rows are its
readout rows). Non-finite pixels (NaN, ±Inf: masked or dead pixels in FITS) are replaced by
the median of the finite pixels, which the background estimate then treats as plain sky; a frame in which
more than half of the pixels are non-finite is rejected (it carries no usable sky). Every
problem with the input raises :class:`skyfix.errors.ImageReadError` with a one-line message.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from skyfix.errors import ImageReadError

__all__ = ["read_image", "as_image", "MAX_NONFINITE_FRACTION"]

log = logging.getLogger(__name__)

#: A frame with more than this fraction of non-finite pixels is rejected.
MAX_NONFINITE_FRACTION = 0.5

_LUMA = np.array([0.299, 0.587, 0.114], dtype=np.float32)
_FITS_SUFFIXES = (".fits", ".fit", ".fts", ".fits.gz", ".fit.gz", ".fts.gz")
_TIFF_SUFFIXES = (".tif", ".tiff")


def read_image(path: str | os.PathLike | np.ndarray) -> np.ndarray:
    """Read an image file (or validate an array) as a 2-D float32 luminance frame.

    Parameters
    ----------
    path : str, os.PathLike or ndarray
        A FITS, PNG, TIFF or JPEG file (8- or 16-bit, grey or colour), or an array that is
        passed through :func:`as_image`.

    Returns
    -------
    ndarray of float32, shape (height, width)
        Luminance in the file's units (ADU). ``image[y, x]`` is the pixel in row ``y``,
        column ``x``.

    Raises
    ------
    ImageReadError
        Missing, empty, truncated or non-image file; data that is not one 2-D frame; a
        frame that is mostly NaN.
    """
    if isinstance(path, np.ndarray):
        return as_image(path)
    p = Path(path)
    if not p.exists():
        raise ImageReadError(f"{p}: no such file")
    if p.is_dir():
        raise ImageReadError(f"{p}: is a directory, not an image")
    try:
        if p.stat().st_size == 0:
            raise ImageReadError(f"{p}: empty file")
        with open(p, "rb") as fh:
            magic = fh.read(8)
    except OSError as exc:
        raise ImageReadError(f"{p}: cannot read ({exc.strerror or type(exc).__name__})") from None
    name = p.name.lower()
    if name.endswith(_FITS_SUFFIXES) or magic.startswith(b"SIMPLE  "):
        data = _read_fits(p)
    elif name.endswith(_TIFF_SUFFIXES) or magic[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
        data = _read_tiff(p)
    else:
        data = _read_pillow(p)
    return as_image(data, name=str(p))


def as_image(data: np.ndarray, *, name: str = "image", replace_nonfinite: bool = True) -> np.ndarray:
    """Validate an array as one frame and return it as 2-D float32 luminance.

    Parameters
    ----------
    data : ndarray
        2-D grey frame, or (H, W, 3|4) colour (RGB[A], alpha ignored). Integer, boolean or
        floating dtype. Singleton leading axes (e.g. a (1, H, W) FITS cube) are squeezed.
    name : str
        What to call the input in error messages.
    replace_nonfinite : bool
        Check for and replace non-finite pixels (a full pass over the frame). A caller that
        finds them more cheaply itself (the extractor, while smoothing) passes False.

    Returns
    -------
    ndarray of float32, shape (H, W)
        A new array unless ``data`` already was a finite, C-contiguous 2-D float32 frame.
        Non-finite pixels are replaced by the median of the finite ones.

    Raises
    ------
    ImageReadError
        Not numeric, not one 2-D frame, empty, or more than half non-finite.
    """
    a = np.asarray(data)
    if a.dtype.kind not in "biuf":
        raise ImageReadError(f"{name}: pixel data of type {a.dtype} is not numeric")
    while a.ndim > 2 and a.shape[0] == 1:
        a = a[0]
    if a.ndim == 3 and a.shape[2] in (3, 4):
        a = _luminance(a[..., :3])
    if a.ndim != 2:
        raise ImageReadError(f"{name}: expected one 2-D frame, got data of shape {a.shape}")
    if a.size == 0:
        raise ImageReadError(f"{name}: image has no pixels (shape {a.shape})")
    img = np.ascontiguousarray(a, dtype=np.float32)
    if replace_nonfinite and a.dtype.kind == "f" and not np.isfinite(img.sum(dtype=np.float64)):
        if np.may_share_memory(img, a):  # never write into the caller's array
            img = img.copy()
        img = _replace_nonfinite(img, name)
    return img


def _luminance(rgb: np.ndarray) -> np.ndarray:
    """BT.601 luma of an (H, W, 3) array as float32; exact integer weights for integer data."""
    if rgb.dtype.kind in "ub" and rgb.dtype.itemsize <= 2:
        acc = rgb[..., 0].astype(np.uint32) * 299
        acc += rgb[..., 1].astype(np.uint32) * 587
        acc += rgb[..., 2].astype(np.uint32) * 114
        return acc.astype(np.float32) * np.float32(1e-3)
    return np.tensordot(rgb.astype(np.float32, copy=False), _LUMA, axes=([2], [0]))


def _replace_nonfinite(img: np.ndarray, name: str) -> np.ndarray:
    """Replace NaN/Inf pixels by the median of the finite ones (in place); reject mostly-bad frames."""
    bad = ~np.isfinite(img)
    n_bad = int(bad.sum())
    if n_bad == 0:  # the sum overflowed, the pixels are fine
        return img
    if n_bad > MAX_NONFINITE_FRACTION * img.size:
        raise ImageReadError(f"{name}: {n_bad} of {img.size} pixels are NaN or infinite")
    img[bad] = np.median(img[~bad])
    log.info("%s: replaced %d non-finite pixels by the frame median", name, n_bad)
    return img


def _read_fits(p: Path) -> np.ndarray:
    """First HDU with 2-D (or squeezable) image data."""
    import warnings

    from astropy.io import fits

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with fits.open(p, memmap=False) as hdul:
                for hdu in hdul:
                    if not getattr(hdu, "is_image", False) or hdu.data is None:
                        continue
                    shape = tuple(s for s in hdu.data.shape if s != 1)
                    if len(shape) == 2:
                        return np.array(hdu.data, dtype=np.float32).reshape(shape)
                shapes = [getattr(h.data, "shape", None) for h in hdul]
    except ImageReadError:
        raise
    except Exception as exc:  # astropy raises OSError, ValueError, TypeError... on bad files
        raise ImageReadError(f"{p}: unreadable or truncated FITS file ({_first_line(exc)})") from None
    raise ImageReadError(f"{p}: FITS file has no 2-D image HDU (data shapes: {shapes})")


def _read_tiff(p: Path) -> np.ndarray:
    import tifffile

    try:
        data = tifffile.imread(p)
    except Exception as exc:
        raise ImageReadError(f"{p}: unreadable or truncated TIFF file ({_first_line(exc)})") from None
    if data.ndim == 3 and data.shape[0] in (3, 4) and data.shape[2] not in (3, 4):
        data = np.moveaxis(data, 0, -1)  # planar RGB
    return data


def _read_pillow(p: Path) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(p) as im:
            if im.format == "JPEG" and im.mode in ("RGB", "YCbCr"):
                # decode only the stored luminance plane (JPEG's Y is BT.601's luma): half the
                # decoding time and no colour round trip; draft keeps the full size here
                im.draft("L", im.size)
            im.load()
            if im.mode in ("P", "PA", "CMYK", "YCbCr", "LAB", "HSV"):
                im = im.convert("RGB")
            elif im.mode == "LA":
                im = im.convert("L")
            data = np.asarray(im)
    except UnidentifiedImageError:
        raise ImageReadError(f"{p}: not an image file (unknown format)") from None
    except Exception as exc:  # truncated data: OSError, SyntaxError, ValueError...
        raise ImageReadError(f"{p}: unreadable or truncated image ({_first_line(exc)})") from None
    if data.dtype == np.uint16 or data.dtype.kind in "iu" and data.dtype.itemsize > 1:
        data = data.astype(np.float32)
    return data


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
