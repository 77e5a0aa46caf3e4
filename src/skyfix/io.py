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

Decoders
--------
Each format has a chain of decoders in :data:`DECODER_CHAINS`, fastest first; a decoder that
does not handle a file's variant (or whose optional package is not installed) passes it on,
and the last one of the chain gives the verdict on a bad file. :data:`DECODERS` names them all
(``read_image_with_header(path, decoder=...)`` picks one):

- ``skyfix-png``: PNG's plain layouts (8- or 16-bit grey, grey + alpha, RGB, RGBA, not
  interlaced) — the chunks parsed here, the image data inflated by libdeflate (the ``deflate``
  package, a dependency; ``zlib``, which Python ships, if it is missing), the rows unfiltered
  by a numba kernel (:mod:`skyfix._png`) that writes a grey image's float32 frame itself: no
  full-size intermediate and no conversion pass. Its pixels are bit-exact with Pillow's, and
  16-bit colour keeps its 16 bits (Pillow reduces 16-bit colour and grey + alpha to 8 bits).
  The inflate is most of the time: on a 16-bit 1280 × 960 frame libdeflate takes 5.4 ms of
  the read's CPU, zlib 8.7, and Pillow, pyspng, OpenCV and imagecodecs' PNG decoder 12–13.5
  ms for the whole read (``benchmarks/bench_decode.py``).
- ``skyfix-fits``: an uncompressed FITS file's first 2-D image HDU (primary or ``IMAGE``
  extension), its header cards parsed here and its data memory-mapped and converted to native
  float32 in one pass, BZERO/BSCALE/BLANK applied as astropy applies them — without importing
  astropy (an import of about a second). Gzipped and tile-compressed files, random groups and
  headers it cannot parse go to ``astropy``.
- ``imagecodecs-jpeg``: libjpeg-turbo's Y plane (``imagecodecs``, optional), else ``pillow``,
  the universal fallback, which also reads every other format Pillow knows.
- ``tifffile`` for TIFF (it uses ``imagecodecs`` for compressed TIFF when installed).

``benchmarks/bench_decode.py`` measures these and the other decoders on PyPI side by side.
"""

from __future__ import annotations

import logging
import mmap
import os
import struct
import warnings
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from skyfix.errors import ImageReadError, unknown_name

__all__ = ["read_image", "read_image_with_header", "as_image", "file_format",
           "ImageFile", "DECODERS", "DECODER_CHAINS",
           "IMAGE_SUFFIXES", "MAX_NONFINITE_FRACTION"]

log = logging.getLogger(__name__)

#: A frame with more than this fraction of non-finite pixels is rejected.
MAX_NONFINITE_FRACTION = 0.5

_LUMA = np.array([0.299, 0.587, 0.114], dtype=np.float32)
_FITS_SUFFIXES = (".fits", ".fit", ".fts", ".fits.gz", ".fit.gz", ".fts.gz")
_TIFF_SUFFIXES = (".tif", ".tiff")
#: The file names taken as images when a folder is given (``skyfix solve FOLDER``), lower case.
IMAGE_SUFFIXES = (*_FITS_SUFFIXES, *_TIFF_SUFFIXES, ".png", ".jpg", ".jpeg")
_TIFF_MAGIC = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_JPEG_MAGIC = b"\xff\xd8\xff"


class ImageFile(NamedTuple):
    """An image file as read: the frame, the metadata, and what read it."""

    #: 2-D float32 luminance in file units, exactly what :func:`read_image` returns.
    data: np.ndarray
    #: FITS: the cards of the HDU read (keyword → value: bool, int, float, str or None for an
    #: empty value; COMMENT, HISTORY and blank cards left out), then the primary header's
    #: non-structural cards it lacks when the image is in an extension (e.g. DATE-OBS kept in
    #: the primary). Other formats: empty.
    header: dict[str, object]
    #: "fits", "png", "tiff", "jpeg", "image" (any other format Pillow reads) or "array".
    format: str
    #: The name in :data:`DECODERS` of the decoder that read it ("array" for an array).
    decoder: str


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
    return read_image_with_header(path).data


def read_image_with_header(path: str | os.PathLike | np.ndarray, *, decoder: str | None = None) -> ImageFile:
    """Read an image file as :func:`read_image` does, with its header and the decoder used.

    Parameters
    ----------
    path : str, os.PathLike or ndarray
        As for :func:`read_image`.
    decoder : str, optional
        A name in :data:`DECODERS` to use alone instead of the format's chain (for tests and
        benchmarks); an :class:`ImageReadError` if it does not read this file.

    Returns
    -------
    ImageFile
        ``data`` as :func:`read_image` returns it, the FITS ``header`` (empty for other
        formats), the ``format`` and the ``decoder`` that read it.

    Raises
    ------
    ImageReadError
        As for :func:`read_image`.
    InputError
        ``decoder`` is not a name in :data:`DECODERS`.
    """
    if decoder is not None and decoder not in DECODERS:
        raise unknown_name("image decoder", decoder, DECODERS)
    if isinstance(path, np.ndarray):
        return ImageFile(as_image(path), {}, "array", "array")
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
    fmt = _format(p.name.lower(), magic)
    chain = (decoder,) if decoder is not None else DECODER_CHAINS[fmt]
    for name in chain:
        got = DECODERS[name](p)
        if got is not None:
            data, header = got
            # a frame of whole numbers holds no NaN: no pass over it to look for one
            return ImageFile(as_image(data, name=str(p), replace_nonfinite=name not in _WHOLE_NUMBERS),
                             header, fmt, name)
    raise ImageReadError(f"{p}: the {' / '.join(chain)} decoder cannot read this {fmt} file")


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


def file_format(path: str | os.PathLike) -> str:
    """The format the file ``path`` is read as — ``"fits"``, ``"tiff"``, ``"png"``, ``"jpeg"`` or
    ``"image"`` (any other, for Pillow) — from its first bytes or its suffix, without reading
    the pixels; ``"image"`` for a file that cannot be opened (reading it says why)."""
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            magic = fh.read(8)
    except OSError:
        return "image"
    return _format(p.name.lower(), magic)


def _format(name: str, magic: bytes) -> str:
    """The format a file is read as: from its first bytes, or its suffix for FITS and TIFF."""
    if name.endswith(_FITS_SUFFIXES) or magic.startswith(b"SIMPLE  "):
        return "fits"
    if name.endswith(_TIFF_SUFFIXES) or magic[:4] in _TIFF_MAGIC:
        return "tiff"
    if magic.startswith(_PNG_MAGIC):
        return "png"
    if magic.startswith(_JPEG_MAGIC):
        return "jpeg"
    return "image"


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


# ---- PNG ----------------------------------------------------------------------------------

_PNG_CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}  # colour type → samples per pixel: grey, RGB, grey+A, RGBA
_PNG_MAX_PIXELS = 178_956_970  # larger: Pillow's decompression-bomb check gives the verdict


def _png_skyfix(p: Path) -> tuple[np.ndarray, dict] | None:
    """A plain PNG (8/16-bit grey, grey+alpha, RGB, RGBA; not interlaced); None for the rest.

    Any inconsistency (truncated chunk, bad IHDR checksum, image data that does not inflate to
    exactly the image's size or fails its Adler-32 check, an unknown row filter) also gives
    None: the next decoder gives the verdict on a damaged file.
    """
    buf = p.read_bytes()
    if not buf.startswith(_PNG_MAGIC):
        return None
    view = memoryview(buf)
    ihdr, idat, pos, end_of_file = None, [], 8, len(buf)
    while pos + 12 <= end_of_file:
        length, kind = struct.unpack_from(">I4s", buf, pos)
        start, end = pos + 8, pos + 8 + length
        if end + 4 > end_of_file:
            return None
        if kind == b"IHDR":
            if length != 13 or zlib.crc32(view[pos + 4:end]) != struct.unpack_from(">I", buf, end)[0]:
                return None
            ihdr = struct.unpack_from(">IIBBBBB", buf, start)
        elif kind == b"IDAT":
            idat.append(view[start:end])
        elif kind == b"IEND":
            break
        pos = end + 4
    if ihdr is None or not idat:
        return None
    width, height, depth, colour, compression, filter_method, interlace = ihdr
    if (depth not in (8, 16) or colour not in _PNG_CHANNELS or compression or filter_method or interlace
            or not 0 < width * height <= _PNG_MAX_PIXELS):
        return None
    from skyfix._png import PngLayout, decode_rows  # numba: imported on first use

    channels = _PNG_CHANNELS[colour]
    layout = PngLayout(height, width, channels, depth // 8)
    row_bytes = width * channels * depth // 8
    raw = _inflate(idat[0] if len(idat) == 1 else b"".join(idat), height * (1 + row_bytes))
    if raw is None:
        return None
    grey = channels <= 2
    # grey: the float32 frame itself (alpha left out); colour: the decoded bytes, for as_image's
    # integer luminance as from every decoder
    out = np.empty((height, width) if grey else (height, row_bytes), np.float32 if grey else np.uint8)
    pixels = np.frombuffer(raw, np.uint8)
    pixels.flags.writeable = False  # libdeflate's bytearray and zlib's bytes alike: one kernel signature
    if decode_rows(pixels, layout, out) >= 0:
        return None
    if grey:
        return out, {}
    return (out.view(">u2") if depth == 16 else out).reshape(height, width, channels)[..., :3], {}


def _inflate(stream: bytes | memoryview, size: int) -> bytes | bytearray | None:
    """A zlib stream inflated to exactly ``size`` bytes (libdeflate, the ``deflate`` package, if
    installed, else zlib); None if it is cut short, longer, or fails its Adler-32 check."""
    try:
        import deflate
    except ImportError:
        inflater = zlib.decompressobj()
        try:
            out = inflater.decompress(stream, size + 1)  # never more than the image (a zip bomb)
        except zlib.error:
            return None
        if not inflater.eof:  # cut short, or longer than the image
            return None
    else:
        try:
            out = deflate.zlib_decompress(stream, size)  # longer than ``size``: an error
        except deflate.DeflateError:
            return None
    return out if len(out) == size else None


# ---- JPEG, TIFF and everything else ---------------------------------------------------------

def _jpeg_imagecodecs(p: Path) -> tuple[np.ndarray, dict] | None:
    """libjpeg-turbo's luminance plane (Y only: the chroma planes are never decoded); None if
    imagecodecs is not installed, the file is not a plain 8-bit grey or YCbCr JPEG, or it does
    not end in the end-of-image marker (libjpeg fills a truncated image with grey and only
    warns; Pillow, which raises on truncation, then gives the verdict)."""
    try:
        import imagecodecs
    except ImportError:
        return None
    buf = p.read_bytes()
    if not buf.rstrip(b"\x00").endswith(b"\xff\xd9"):
        return None
    try:
        data = imagecodecs.jpeg8_decode(buf, outcolorspace="GRAY")
    except Exception:  # CMYK, 12-bit, damaged or truncated: Pillow gives the verdict
        return None
    return (data, {}) if data.ndim == 2 else None


def _tifffile(p: Path) -> tuple[np.ndarray, dict]:
    import tifffile

    try:
        data = tifffile.imread(p)
    except Exception as exc:
        raise ImageReadError(f"{p}: unreadable or truncated TIFF file ({_first_line(exc)})") from None
    if data.ndim == 3 and data.shape[0] in (3, 4) and data.shape[2] not in (3, 4):
        data = np.moveaxis(data, 0, -1)  # planar RGB
    return data, {}


def _pillow(p: Path) -> tuple[np.ndarray, dict]:
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
    return data, {}


# ---- FITS ---------------------------------------------------------------------------------

_FITS_BLOCK = 2880
_FITS_CARD = 80
_FITS_DTYPES = {8: ">u1", 16: ">i2", 32: ">i4", 64: ">i8", -32: ">f4", -64: ">f8"}
_FITS_STRUCTURAL = ("SIMPLE", "XTENSION", "BITPIX", "NAXIS", "EXTEND", "PCOUNT", "GCOUNT", "GROUPS",
                    "BZERO", "BSCALE", "BLANK", "EXTNAME", "EXTVER", "INHERIT")


def _fits_skyfix(p: Path) -> tuple[np.ndarray, dict] | None:
    """The first 2-D image HDU of an uncompressed FITS file, memory-mapped; None for the rest.

    HDUs are walked by their headers: each is a run of 2880-byte blocks of 80-character
    cards up to ``END``, then ``|BITPIX|/8 · GCOUNT · (PCOUNT + NAXIS1 ⋯ NAXISn)`` data bytes
    padded to a whole block (FITS 4.0 § 4.4.1). The first primary or IMAGE extension HDU whose
    data squeezes to two axes is read. Gzipped files, tile-compressed images (a ``ZIMAGE``
    table before the image), random groups and headers that do not parse give None (astropy
    reads them); data that ends before the header says raises :class:`ImageReadError`.
    """
    with open(p, "rb") as fh:
        size = os.fstat(fh.fileno()).st_size
        if fh.read(2) == b"\x1f\x8b":  # gzip
            return None
        offset, primary, shapes = 0, None, []
        while offset < size:
            fh.seek(offset)
            header, data_offset = _fits_header(fh, p, first=primary is None)
            if header is None:
                return None
            if primary is None:
                if header.get("SIMPLE") is not True or header.get("GROUPS") is True:
                    return None
                primary, is_image = header, True
            else:
                kind = header.get("XTENSION")
                if not isinstance(kind, str) or header.get("ZIMAGE") is True:
                    return None
                is_image = kind.strip() == "IMAGE"
            layout = _fits_layout(header)
            if layout is None:
                return None
            bitpix, axes, n_bytes = layout
            shape = tuple(reversed(axes))
            frame = tuple(s for s in shape if s != 1)
            if is_image and n_bytes and len(frame) == 2:
                if data_offset + n_bytes > size:
                    raise ImageReadError(f"{p}: unreadable or truncated FITS file (the data ends at byte "
                                         f"{size} of {data_offset + n_bytes})")
                data = _fits_pixels(fh, header, bitpix, data_offset, frame)
                return data, _fits_metadata(header, primary if header is not primary else None)
            if is_image:
                shapes.append(shape if n_bytes else None)
            offset = data_offset + -(-n_bytes // _FITS_BLOCK) * _FITS_BLOCK
    raise ImageReadError(f"{p}: FITS file has no 2-D image HDU (data shapes: {shapes})")


def _fits_header(fh, p: Path, first: bool) -> tuple[dict[str, object] | None, int]:
    """The cards of the header at the file position (keyword → value), and where its data starts.

    None for a header that is not plain ASCII cards ending in END (astropy then decides); a
    primary header cut short raises :class:`ImageReadError`.
    """
    header: dict[str, object] = {}
    while True:
        block = fh.read(_FITS_BLOCK)
        if len(block) < _FITS_BLOCK:
            if first:
                raise ImageReadError(f"{p}: unreadable or truncated FITS file (the header has no END card)")
            return None, 0
        try:
            text = block.decode("ascii")
        except UnicodeDecodeError:
            return None, 0
        for i in range(0, _FITS_BLOCK, _FITS_CARD):
            card = text[i:i + _FITS_CARD]
            key = card[:8].rstrip()
            if key == "END":
                return header, fh.tell()
            if card[8:10] == "= " and key not in header:
                header[key] = _fits_value(card[10:])
        if not header:  # a first block without a single keyword = value card is not a header
            return None, 0


def _fits_value(text: str) -> object:
    """A card's value as Python: 'string' (quotes doubled inside), T/F, integer, real; None if empty."""
    s = text.strip()
    if s.startswith("'"):
        parts, i = [], 1
        while True:
            j = s.find("'", i)
            if j < 0:
                return s[1:].rstrip()
            parts.append(s[i:j])
            if s[j + 1:j + 2] != "'":
                return "".join(parts).rstrip()
            parts.append("'")
            i = j + 2
    v = s.split("/", 1)[0].strip()
    if v in ("T", "F"):
        return v == "T"
    if not v:
        return None
    try:
        return int(v)
    except ValueError:
        pass
    try:
        return float(v.replace("D", "E").replace("d", "e"))
    except ValueError:
        return v  # a complex value or a malformed one: kept as its text


def _fits_layout(header: dict[str, object]) -> tuple[int, list[int], int] | None:
    """BITPIX, the axis lengths (NAXIS1 first) and the data size in bytes; None if malformed."""
    bitpix, naxis = header.get("BITPIX"), header.get("NAXIS")
    pcount, gcount = header.get("PCOUNT", 0), header.get("GCOUNT", 1)
    if (bitpix not in _FITS_DTYPES or not isinstance(naxis, int) or not 0 <= naxis <= 999
            or not isinstance(pcount, int) or not isinstance(gcount, int)):
        return None
    axes = [header.get(f"NAXIS{k}") for k in range(1, naxis + 1)]
    if not all(isinstance(a, int) and a >= 0 for a in axes):
        return None
    n_bytes = abs(bitpix) // 8 * gcount * (pcount + int(np.prod(axes, dtype=np.int64))) if naxis else 0
    return bitpix, axes, n_bytes


def _fits_pixels(fh, header: dict[str, object], bitpix: int, offset: int,
                 shape: tuple[int, int]) -> np.ndarray:
    """The stored pixels as physical float32 values, read through a memory map.

    BZERO/BSCALE/BLANK follow astropy's reading (so the values are bit-exact with
    ``astropy.io.fits`` read as float32): the unsigned-integer conventions (BITPIX 16/32/64 with
    BZERO 2^(BITPIX−1), BITPIX 8 with BZERO −128, BSCALE 1) are exact integers and ignore BLANK;
    other scaled or BLANK-carrying data is scaled in float32 (BITPIX 8, 16, −32) or float64
    (32, 64, −64) as ``value · BSCALE + BZERO`` with BLANK pixels set to NaN, then rounded to
    float32. One departure: astropy ignores ``BLANK = 0``; here it marks blanks as the standard
    says.
    """
    dtype = np.dtype(_FITS_DTYPES[bitpix])
    bscale, bzero, blank = header.get("BSCALE", 1), header.get("BZERO", 0), header.get("BLANK")
    if not isinstance(bscale, (int, float)) or not isinstance(bzero, (int, float)):
        bscale, bzero = 1, 0
    if bitpix < 0 or not isinstance(blank, int) or isinstance(blank, bool):
        blank = None
    n = shape[0] * shape[1]
    with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mapped:
        raw = np.frombuffer(mapped, dtype, count=n, offset=offset).reshape(shape)
        try:
            if bscale == 1 and bzero == 0 and blank is None:
                return raw.astype(np.float32)  # the one pass: byte order and type together
            if bitpix > 0 and bscale == 1 and bzero == (-128 if bitpix == 8 else 1 << (bitpix - 1)):
                if bitpix <= 16:  # exact in float32
                    out = raw.astype(np.float32)
                    out += np.float32(bzero)
                    return out
                sign = np.dtype(dtype.str.replace("i", "u"))
                flipped = raw.view(sign) ^ sign.type(1 << (bitpix - 1))  # the unsigned integer
                return flipped.astype(np.float32)
            work = np.float32 if bitpix in (8, 16, -32) else np.float64
            data = raw.astype(work)
            blanks = raw == blank if blank is not None else None
            if bscale != 1:
                np.multiply(data, bscale, out=data)
            if bzero != 0:
                data += bzero
            if blanks is not None:
                data[blanks] = np.nan
            return data.astype(np.float32, copy=False)
        finally:
            del raw  # the map closes only once no array looks into it


def _fits_metadata(header: dict[str, object], primary: dict[str, object] | None) -> dict[str, object]:
    """The image HDU's cards, then the primary header's non-structural cards it lacks."""
    out = dict(header)
    for key, value in (primary or {}).items():
        if key not in out and not key.startswith(_FITS_STRUCTURAL):
            out[key] = value
    return out


def _fits_astropy(p: Path) -> tuple[np.ndarray, dict]:
    """First HDU with 2-D (or squeezable) image data, by astropy (any FITS astropy reads)."""
    from astropy.io import fits

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with fits.open(p, memmap=False) as hdul:
                primary = _astropy_cards(hdul[0].header)
                for k, hdu in enumerate(hdul):
                    if not getattr(hdu, "is_image", False) or hdu.data is None:
                        continue
                    shape = tuple(s for s in hdu.data.shape if s != 1)
                    if len(shape) == 2:
                        data = np.array(hdu.data, dtype=np.float32).reshape(shape)
                        return data, _fits_metadata(_astropy_cards(hdu.header), primary if k else None)
                shapes = [getattr(h.data, "shape", None) for h in hdul]
    except ImageReadError:
        raise
    except Exception as exc:  # astropy raises OSError, ValueError, TypeError... on bad files
        raise ImageReadError(f"{p}: unreadable or truncated FITS file ({_first_line(exc)})") from None
    raise ImageReadError(f"{p}: FITS file has no 2-D image HDU (data shapes: {shapes})")


def _astropy_cards(header) -> dict[str, object]:
    out: dict[str, object] = {}
    for key, value in header.items():
        if key and key not in ("COMMENT", "HISTORY") and key not in out:
            out[key] = None if type(value).__name__ == "Undefined" else value
    return out


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


#: Every decoder by name: path → (raw frame, header), or None when it does not read this file.
DECODERS: dict[str, Callable[[Path], tuple[np.ndarray, dict] | None]] = {
    "skyfix-png": _png_skyfix,
    "skyfix-fits": _fits_skyfix,
    "imagecodecs-jpeg": _jpeg_imagecodecs,
    "tifffile": _tifffile,
    "astropy": _fits_astropy,
    "pillow": _pillow,
}

# Decoders whose frames hold stored integers only (as float32 or an integer type).
_WHOLE_NUMBERS = frozenset({"skyfix-png"})

#: The decoders tried for each format, in order (the first that reads the file wins).
DECODER_CHAINS: dict[str, tuple[str, ...]] = {
    "fits": ("skyfix-fits", "astropy"),
    "png": ("skyfix-png", "pillow"),
    "jpeg": ("imagecodecs-jpeg", "pillow"),
    "tiff": ("tifffile",),
    "image": ("pillow",),
}
