"""Image reading: every format to 2-D float32 luminance in file units; bad files → ImageReadError."""

import numpy as np
import pytest
import tifffile
from astropy.io import fits
from PIL import Image

from skyfix.errors import ImageReadError
from skyfix.io import as_image, read_image


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
