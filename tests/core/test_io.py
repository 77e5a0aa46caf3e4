"""Image reading: every format to 2-D float32 luminance in file units; bad files → ImageReadError."""

import numpy as np
import pytest
import tifffile
from astropy.io import fits
from PIL import Image

from skyfix.errors import ImageReadError, UnknownNameError
from skyfix.io import DECODERS, as_image, read_image, read_image_with_header


@pytest.fixture
def frame():
    rng = np.random.default_rng(1)
    return (rng.random((40, 56)) * 60000).astype(np.uint16)


def test_fits_roundtrip(tmp_path, frame):
    fits.writeto(tmp_path / "a.fits", frame)
    img = read_image(tmp_path / "a.fits")
    assert img.dtype == np.float32 and img.shape == (40, 56)
    np.testing.assert_array_equal(img, frame.astype(np.float32))


def test_fits_first_2d_hdu_and_singleton_axes(tmp_path, frame):
    hdus = fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(frame[None, :, :].astype(np.float32))])
    hdus.writeto(tmp_path / "b.fits")
    np.testing.assert_array_equal(read_image(str(tmp_path / "b.fits")), frame)


def test_16bit_png_and_tiff(tmp_path, frame):
    Image.fromarray(frame).save(tmp_path / "a.png")
    tifffile.imwrite(tmp_path / "a.tiff", frame)
    for name in ("a.png", "a.tiff"):
        img = read_image(tmp_path / name)
        assert img.dtype == np.float32
        np.testing.assert_array_equal(img, frame)  # 16-bit values kept, not scaled to 8 bits


def test_8bit_colour_to_luminance(tmp_path):
    rgb = np.zeros((8, 9, 3), np.uint8)
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 100, 200, 50
    rgb[0, 0] = 255  # white stays at full scale
    Image.fromarray(rgb).save(tmp_path / "c.png")
    img = read_image(tmp_path / "c.png")
    assert img.shape == (8, 9)
    assert img[1, 1] == pytest.approx(0.299 * 100 + 0.587 * 200 + 0.114 * 50, abs=1e-3)
    assert img[0, 0] == pytest.approx(255.0, abs=1e-3)


def test_jpeg_reads(tmp_path):
    grey = np.tile(np.arange(64, dtype=np.uint8) * 3, (48, 1))
    Image.fromarray(grey).save(tmp_path / "g.jpg", quality=95)
    img = read_image(tmp_path / "g.jpg")
    assert img.shape == (48, 64)
    assert np.abs(img - grey).mean() < 2.0


@pytest.mark.parametrize("case", ["missing", "empty", "text_png", "trunc_fits", "trunc_png", "trunc_tiff",
                                  "trunc_jpg", "cube_fits", "directory", "header_only_fits"])
def test_bad_files_raise_one_line(tmp_path, frame, case):
    p = tmp_path / "x"
    if case == "missing":
        p = tmp_path / "nope.fits"
    elif case == "empty":
        p = tmp_path / "empty.png"
        p.write_bytes(b"")
    elif case == "text_png":
        p = tmp_path / "text.png"
        p.write_text("this is not an image\n")
    elif case in ("trunc_fits", "header_only_fits"):
        fits.writeto(tmp_path / "full.fits", frame)
        data = (tmp_path / "full.fits").read_bytes()
        p = tmp_path / "t.fits"
        p.write_bytes(data[: len(data) // 2] if case == "trunc_fits" else data[:2880])
    elif case in ("trunc_png", "trunc_jpg"):
        ext = case[-3:]
        Image.fromarray((frame // 256).astype(np.uint8)).save(tmp_path / f"full.{ext}")
        data = (tmp_path / f"full.{ext}").read_bytes()
        p = tmp_path / f"t.{ext}"
        p.write_bytes(data[: len(data) // 2])
    elif case == "trunc_tiff":
        tifffile.imwrite(tmp_path / "full.tiff", frame)
        data = (tmp_path / "full.tiff").read_bytes()
        p = tmp_path / "t.tiff"
        p.write_bytes(data[: len(data) // 2])
    elif case == "cube_fits":
        p = tmp_path / "cube.fits"
        fits.writeto(p, np.zeros((3, 10, 10), np.float32))
    elif case == "directory":
        p = tmp_path
    with pytest.raises(ImageReadError) as err:
        read_image(p)
    msg = str(err.value)
    assert "\n" not in msg and str(p.name) in msg


def test_array_passthrough_validates():
    a = np.arange(12, dtype=np.uint8).reshape(3, 4)
    img = read_image(a)
    assert img.dtype == np.float32 and img.shape == (3, 4) and img[2, 3] == 11
    f32 = np.ones((5, 5), np.float32)
    assert as_image(f32) is f32  # no copy when already a clean float32 frame
    for bad in (np.zeros(5), np.zeros((2, 3, 4, 5)), np.zeros((0, 4)), np.array([["a"]])):
        with pytest.raises(ImageReadError):
            read_image(bad)


def test_nan_pixels_replaced_by_median_without_touching_input():
    a = np.full((20, 20), 10.0, np.float32)
    a[5, 5] = np.nan
    a[6, 6] = np.inf
    a[0, 0] = 30.0
    img = read_image(a)
    assert np.isfinite(img).all() and img[5, 5] == 10.0 and img[6, 6] == 10.0
    assert np.isnan(a[5, 5])  # the caller's array is untouched


def test_mostly_nan_frame_rejected(tmp_path):
    a = np.full((10, 10), np.nan, np.float32)
    a[:4] = 1.0
    fits.writeto(tmp_path / "nan.fits", a)
    with pytest.raises(ImageReadError, match="NaN"):
        read_image(tmp_path / "nan.fits")


def test_colour_jpeg_decodes_to_bt601_luma(tmp_path):
    rng = np.random.default_rng(2)
    rgb = rng.integers(0, 256, (40, 48, 3), dtype=np.uint8)
    rgb = np.repeat(np.repeat(rgb[::8, ::8], 8, axis=0), 8, axis=1)[:40, :48]  # flat 8×8 blocks
    Image.fromarray(rgb).save(tmp_path / "c.jpg", quality=100, subsampling=0)
    img = read_image(tmp_path / "c.jpg")
    luma = rgb.astype(float) @ np.array([0.299, 0.587, 0.114])
    assert img.shape == (40, 48)
    assert np.median(np.abs(img - luma)) < 1.0


# ---- decoders: each against the pixels written and against the reference decoder --------------

def _png_file(path, pixels: np.ndarray, colour: int, filters=(0, 1, 2, 3, 4)) -> None:
    """Write a PNG by hand, row filter types cycling through ``filters`` (PNG spec § 9)."""
    import struct
    import zlib

    h, w = pixels.shape[:2]
    depth = 16 if pixels.dtype == np.uint16 else 8
    rows = pixels.astype(">u2" if depth == 16 else np.uint8).reshape(h, -1).view(np.uint8).astype(np.int32)
    bpp = rows.shape[1] // w
    out = []
    for r in range(h):
        kind = filters[r % len(filters)]
        x = rows[r]
        up = rows[r - 1] if r else np.zeros_like(x)
        left = np.concatenate([np.zeros(bpp, np.int32), x[:-bpp]])
        upleft = np.concatenate([np.zeros(bpp, np.int32), up[:-bpp]])
        p = left + up - upleft
        pa, pb, pc = np.abs(p - left), np.abs(p - up), np.abs(p - upleft)
        paeth = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, upleft))
        pred = [0, left, up, (left + up) // 2, paeth][kind] if kind <= 4 else 0  # 5+: not a PNG filter
        out.append(bytes([kind]) + ((x - pred) & 255).astype(np.uint8).tobytes())

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", w, h, depth, colour, 0, 0, 0)
    idat = zlib.compress(b"".join(out))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat[:50])
                     + chunk(b"IDAT", idat[50:]) + chunk(b"IEND", b""))


@pytest.mark.parametrize("depth", [8, 16])
@pytest.mark.parametrize("colour", [0, 2, 4, 6])  # grey, RGB, grey + alpha, RGBA
def test_png_every_filter_and_layout_bit_exact(tmp_path, depth, colour):
    rng = np.random.default_rng(depth + colour)
    channels = {0: 1, 2: 3, 4: 2, 6: 4}[colour]
    top = 65535 if depth == 16 else 255
    pixels = rng.integers(0, top + 1, (11, 13, channels)).astype(np.uint16 if depth == 16 else np.uint8)
    pixels[0, 0] = top  # full scale stays full scale
    _png_file(tmp_path / "f.png", pixels, colour)
    got = read_image_with_header(tmp_path / "f.png")
    assert got.decoder == "skyfix-png" and got.format == "png" and got.header == {}
    expected = as_image(pixels[..., 0] if channels <= 2 else pixels[..., :3])
    np.testing.assert_array_equal(got.data, expected)
    assert got.data[0, 0] == pytest.approx(top, abs=top * 1e-6)
    if depth == 8 or colour == 0:  # Pillow keeps these at their depth: the two agree bit for bit
        pillow = read_image_with_header(tmp_path / "f.png", decoder="pillow")
        np.testing.assert_array_equal(got.data, pillow.data)


@pytest.mark.parametrize("mode", ["L", "I;16", "RGB", "RGBA", "LA"])
def test_png_written_by_pillow_and_opencv_same_as_pillow(tmp_path, mode):
    rng = np.random.default_rng(5)
    shape = (37, 51, {"RGB": 3, "RGBA": 4, "LA": 2}.get(mode, 1))
    pixels = rng.integers(0, 65536 if mode == "I;16" else 256, shape).astype(
        np.uint16 if mode == "I;16" else np.uint8)
    pixels = pixels[..., 0] if pixels.shape[2] == 1 else pixels
    files = [tmp_path / "pil.png"]
    Image.fromarray(pixels, mode=mode if mode in ("LA",) else None).save(files[0])
    try:
        import cv2
    except ImportError:
        cv2 = None
    if cv2 is not None and mode != "LA":  # OpenCV writes Sub filters, Pillow mostly Up
        files.append(tmp_path / "cv.png")
        bgr = pixels[..., [2, 1, 0, 3][:pixels.shape[2]]] if pixels.ndim == 3 else pixels
        cv2.imwrite(str(files[1]), bgr)
    for f in files:
        got = read_image_with_header(f)
        assert got.decoder == "skyfix-png"
        np.testing.assert_array_equal(got.data, read_image_with_header(f, decoder="pillow").data)


def test_png_16bit_colour_keeps_16_bits(tmp_path):
    rgb = np.zeros((6, 7, 3), np.uint16)
    rgb[...] = 40000, 20000, 1000
    _png_file(tmp_path / "c16.png", rgb, 2)
    img = read_image(tmp_path / "c16.png")
    assert img[3, 3] == pytest.approx(0.299 * 40000 + 0.587 * 20000 + 0.114 * 1000, rel=1e-6)


def test_png_other_layouts_go_to_pillow(tmp_path):
    pal = Image.fromarray(np.arange(48, dtype=np.uint8).reshape(6, 8)).convert("P")
    pal.save(tmp_path / "p.png")
    got = read_image_with_header(tmp_path / "p.png")
    assert got.decoder == "pillow" and got.data.shape == (6, 8)
    with pytest.raises(ImageReadError, match="skyfix-png decoder cannot read"):
        read_image_with_header(tmp_path / "p.png", decoder="skyfix-png")


@pytest.mark.parametrize("damage", ["idat_byte", "filter_type"])
def test_png_damaged_data_is_not_decoded(tmp_path, damage):
    pixels = np.random.default_rng(3).integers(0, 256, (20, 30)).astype(np.uint8)
    _png_file(tmp_path / "ok.png", pixels, 0, filters=(7,) if damage == "filter_type" else (0, 1, 2, 3, 4))
    data = bytearray((tmp_path / "ok.png").read_bytes())
    if damage == "idat_byte":
        data[len(data) // 2] ^= 0x10  # the zlib stream's Adler-32 no longer matches
    (tmp_path / "bad.png").write_bytes(bytes(data))
    with pytest.raises(ImageReadError, match="skyfix-png decoder cannot read"):
        read_image_with_header(tmp_path / "bad.png", decoder="skyfix-png")
    with pytest.raises(ImageReadError) as err:  # and Pillow, the next in the chain, refuses it too
        read_image(tmp_path / "bad.png")
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("kind", ["grey", "colour420", "colour444"])
def test_jpeg_imagecodecs_matches_pillow(tmp_path, kind):
    pytest.importorskip("imagecodecs")
    rng = np.random.default_rng(4)
    sky = rng.normal(60, 12, (96, 120)).clip(0, 255)
    if kind == "grey":
        Image.fromarray(sky.astype(np.uint8)).save(tmp_path / "j.jpg", quality=90)
    else:
        rgb = sky[..., None] * [1.0, 0.9, 0.7] + rng.normal(0, 8, (96, 120, 3))
        rgb = rgb.clip(0, 255).astype(np.uint8)
        Image.fromarray(rgb).save(tmp_path / "j.jpg", quality=90, subsampling=0 if kind == "colour444" else 2)
    got = read_image_with_header(tmp_path / "j.jpg")
    ref = read_image_with_header(tmp_path / "j.jpg", decoder="pillow").data
    assert got.decoder == "imagecodecs-jpeg" and got.data.shape == ref.shape
    assert np.abs(got.data - ref).max() <= 1.0  # both libjpeg-turbo's integer IDCT: 0 measured
    data = (tmp_path / "j.jpg").read_bytes()
    (tmp_path / "t.jpg").write_bytes(data[: len(data) * 2 // 3])  # libjpeg would fill it with grey
    with pytest.raises(ImageReadError, match="imagecodecs-jpeg decoder cannot read"):
        read_image_with_header(tmp_path / "t.jpg", decoder="imagecodecs-jpeg")


def test_unknown_decoder_name_is_an_input_error(tmp_path, frame):
    Image.fromarray(frame).save(tmp_path / "a.png")
    with pytest.raises(UnknownNameError, match="unknown image decoder"):
        read_image_with_header(tmp_path / "a.png", decoder="libpng")


# ---- FITS: skyfix's memory-mapped reader against astropy ------------------------------------------

def _fits_file(path, stored: np.ndarray, bitpix: int, cards=(), extension=False, primary_cards=()) -> None:
    """Write a FITS file by hand: ``stored`` as BITPIX big-endian values, with extra header cards."""

    def header(lines):
        text = "".join(f"{line:80s}" for line in [*lines, "END"])
        return (text + " " * (-len(text) % 2880)).encode("ascii")

    def fmt(key, value):
        v = ("T" if value else "F") if isinstance(value, bool) else (
            f"'{value}'" if isinstance(value, str) else repr(value))
        return f"{key:8s}= {v:>20s}"

    h, w = stored.shape
    image = [fmt("BITPIX", bitpix), fmt("NAXIS", 2), fmt("NAXIS1", w), fmt("NAXIS2", h)]
    image += [fmt(k, v) for k, v in cards]
    dtype = {8: ">u1", 16: ">i2", 32: ">i4", 64: ">i8", -32: ">f4", -64: ">f8"}[bitpix]
    data = stored.astype(dtype).tobytes()
    data += b"\0" * (-len(data) % 2880)
    if extension:
        primary = header([fmt("SIMPLE", True), fmt("BITPIX", 8), fmt("NAXIS", 0), fmt("EXTEND", True),
                          *(fmt(k, v) for k, v in primary_cards)])
        ext = header([fmt("XTENSION", "IMAGE   "), *image[:4], fmt("PCOUNT", 0), fmt("GCOUNT", 1),
                      *image[4:]])
        path.write_bytes(primary + ext + data)
    else:
        path.write_bytes(header([fmt("SIMPLE", True), *image]) + data)


FITS_CASES = {  # name: (stored dtype, BITPIX, cards)
    "uint8": (np.uint8, 8, ()),
    "int8 (BZERO -128)": (np.uint8, 8, (("BZERO", -128),)),
    "int16": (np.int16, 16, ()),
    "uint16 (BZERO 32768)": (np.int16, 16, (("BZERO", 32768),)),
    "int16 scaled": (np.int16, 16, (("BSCALE", 0.37), ("BZERO", 1021.5))),
    "int16 BLANK": (np.int16, 16, (("BLANK", -999),)),
    "int16 scaled BLANK": (np.int16, 16, (("BSCALE", 2.5), ("BZERO", -3.0), ("BLANK", -999))),
    "int32": (np.int32, 32, ()),
    "uint32 (BZERO 2^31)": (np.int32, 32, (("BZERO", 2147483648),)),
    "int32 scaled": (np.int32, 32, (("BSCALE", 1.0e-3), ("BZERO", 7.25))),
    "uint64 (BZERO 2^63)": (np.int64, 64, (("BZERO", 9223372036854775808),)),
    "float32 NaN": (np.float32, -32, ()),
    "float32 scaled": (np.float32, -32, (("BSCALE", 3.0), ("BZERO", 0.5))),
    "float64": (np.float64, -64, ()),
}


@pytest.mark.parametrize("case", list(FITS_CASES))
@pytest.mark.parametrize("extension", [False, True])
def test_fits_memmap_reader_bit_exact_with_astropy(tmp_path, case, extension):
    dtype, bitpix, cards = FITS_CASES[case]
    rng = np.random.default_rng(len(case))
    info = np.iinfo(dtype) if np.dtype(dtype).kind in "iu" else None
    if info is not None:
        stored = rng.integers(info.min, info.max, (9, 14), endpoint=True, dtype=dtype)
    else:
        stored = rng.normal(500.0, 200.0, (9, 14)).astype(dtype)
    if "NaN" in case:
        stored[2, 3] = np.nan
    if "BLANK" in case:
        stored[4, 5] = -999
    _fits_file(tmp_path / "a.fits", stored, bitpix, cards, extension=extension)
    mine, header = DECODERS["skyfix-fits"](tmp_path / "a.fits")
    ref, _ = DECODERS["astropy"](tmp_path / "a.fits")
    assert mine.dtype == np.float32 and mine.shape == (9, 14)
    np.testing.assert_array_equal(mine, ref)  # NaN where astropy has NaN, every other value equal
    assert header["BITPIX"] == bitpix and header["NAXIS1"] == 14
    got = read_image_with_header(tmp_path / "a.fits")
    assert got.decoder == "skyfix-fits" and np.isfinite(got.data).all()
    if case == "uint16 (BZERO 32768)":
        np.testing.assert_array_equal(mine, stored.astype(np.int32) + 32768)
    if "BLANK" in case:
        assert np.isnan(mine[4, 5]) and np.isfinite(mine).sum() == mine.size - 1


def test_fits_blank_zero_marks_blanks(tmp_path):  # astropy ignores BLANK = 0; the standard does not
    stored = np.arange(12, dtype=np.int16).reshape(3, 4)
    _fits_file(tmp_path / "z.fits", stored, 16, (("BLANK", 0),))
    mine, _ = DECODERS["skyfix-fits"](tmp_path / "z.fits")
    assert np.isnan(mine[0, 0]) and np.isfinite(mine).sum() == 11


def test_fits_header_values_and_primary_cards(tmp_path, frame):
    cards = (("EXPTIME", 0.25), ("MJD-OBS", 60000.125), ("TIMESYS", "UTC"), ("OBJECT", "it''s M42"),
             ("FLIP", False), ("GAIN", "1.5D2"))
    _fits_file(tmp_path / "e.fits", frame.astype(np.int32), 32, cards, extension=True,
               primary_cards=(("DATE-OBS", "2026-11-28T06:19:00.5"), ("EXPTIME", 99.0)))
    got = read_image_with_header(tmp_path / "e.fits")
    assert got.decoder == "skyfix-fits"
    np.testing.assert_array_equal(got.data, frame)
    h = got.header
    assert h["DATE-OBS"] == "2026-11-28T06:19:00.5"  # from the primary header
    assert h["EXPTIME"] == 0.25  # the image HDU's own card wins
    assert h["MJD-OBS"] == 60000.125 and h["TIMESYS"] == "UTC" and h["OBJECT"] == "it's M42"
    assert h["FLIP"] is False and h["XTENSION"] == "IMAGE" and "SIMPLE" not in h
    ref = read_image_with_header(tmp_path / "e.fits", decoder="astropy").header
    for key in ("DATE-OBS", "EXPTIME", "MJD-OBS", "TIMESYS", "OBJECT", "FLIP", "NAXIS2"):
        assert h[key] == ref[key], key


def test_fits_gzip_and_tile_compressed_go_to_astropy(tmp_path, frame):
    import gzip

    fits.writeto(tmp_path / "a.fits", frame)
    (tmp_path / "a.fits.gz").write_bytes(gzip.compress((tmp_path / "a.fits").read_bytes()))
    fits.HDUList([fits.PrimaryHDU(), fits.CompImageHDU(frame.astype(np.int32))]).writeto(tmp_path / "c.fits")
    for name in ("a.fits.gz", "c.fits"):
        got = read_image_with_header(tmp_path / name)
        assert got.decoder == "astropy", name
        np.testing.assert_array_equal(got.data, frame)


def test_fits_nan_pixels_replaced(tmp_path):
    a = np.full((10, 12), 7.0, np.float32)
    a[3, 4] = np.nan
    fits.writeto(tmp_path / "n.fits", a)
    img = read_image(tmp_path / "n.fits")
    assert np.isfinite(img).all() and img[3, 4] == 7.0


@pytest.mark.parametrize("cut", ["data", "header"])
def test_fits_truncated_raises_without_astropy(tmp_path, frame, cut):
    fits.writeto(tmp_path / "full.fits", frame)
    data = (tmp_path / "full.fits").read_bytes()
    (tmp_path / "t.fits").write_bytes(data[:4000] if cut == "data" else data[:1000])
    with pytest.raises(ImageReadError, match="truncated") as err:
        read_image_with_header(tmp_path / "t.fits", decoder="skyfix-fits")
    assert "\n" not in str(err.value) and "t.fits" in str(err.value)


def test_reading_plain_fits_does_not_import_astropy(tmp_path, frame):
    import subprocess
    import sys

    fits.writeto(tmp_path / "a.fits", frame)
    code = ("import sys; from skyfix.io import read_image; img = read_image(sys.argv[1]); "
            "print(img.shape, 'astropy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "a.fits")], capture_output=True,
                         text=True, check=True).stdout
    assert out.strip() == "(40, 56) False"


def test_without_deflate_or_imagecodecs_png_inflates_with_zlib_and_jpeg_goes_to_pillow(tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "imagecodecs", None)  # `import imagecodecs` raises ImportError
    monkeypatch.setitem(sys.modules, "deflate", None)
    pixels = np.random.default_rng(8).integers(0, 65536, (15, 17)).astype(np.uint16)
    _png_file(tmp_path / "z.png", pixels, 0)
    got = read_image_with_header(tmp_path / "z.png")
    assert got.decoder == "skyfix-png"
    np.testing.assert_array_equal(got.data, pixels)
    Image.fromarray((pixels >> 8).astype(np.uint8)).save(tmp_path / "z.jpg")
    assert read_image_with_header(tmp_path / "z.jpg").decoder == "pillow"
    data = (tmp_path / "z.png").read_bytes()
    (tmp_path / "t.png").write_bytes(data[:-40])  # the zlib stream cut short
    with pytest.raises(ImageReadError, match="skyfix-png decoder cannot read"):
        read_image_with_header(tmp_path / "t.png", decoder="skyfix-png")


@pytest.mark.parametrize("inflater", ["deflate", "zlib"])
@pytest.mark.parametrize("extra", [1 << 20, 1, -1])  # bytes more (a zip bomb) or fewer than the image
def test_png_image_data_not_the_image_size_is_not_decoded(tmp_path, monkeypatch, inflater, extra):
    import struct
    import sys
    import zlib

    if inflater == "zlib":
        monkeypatch.setitem(sys.modules, "deflate", None)
    else:
        pytest.importorskip("deflate")

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    rows = b"".join(b"\0" + bytes(4) for _ in range(4))  # 4×4 grey
    rows = rows + bytes(extra) if extra > 0 else rows[:extra]
    ihdr = struct.pack(">IIBBBBB", 4, 4, 8, 0, 0, 0, 0)
    (tmp_path / "long.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
                                        + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))
    with pytest.raises(ImageReadError, match="skyfix-png decoder cannot read"):
        read_image_with_header(tmp_path / "long.png", decoder="skyfix-png")
