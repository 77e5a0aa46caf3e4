"""Frame calibration: master dark/flat from stacks, hot/dead pixels, dark → flat → repair."""

import numpy as np
import pytest

from skyfix.detect import extract_centroids
from skyfix.detect.calibrate_frames import (
    calibrate_frame,
    dark_report,
    dead_pixel_map,
    hot_pixel_map,
    load_calibration,
    master_dark,
    master_flat,
    master_frame,
    save_calibration,
)
from skyfix.errors import ImageReadError

H, W = 120, 160


def _sensor(seed=0):
    rng = np.random.default_rng(seed)
    offset = 100.0 + rng.normal(0, 2.0, (H, W))  # bias + DSNU
    hot = np.zeros((H, W), bool)
    hot[rng.integers(0, H, 25), rng.integers(0, W, 25)] = True
    dark_current = np.where(hot, 400.0, 5.0)
    yy, xx = np.mgrid[0:H, 0:W]
    vignette = 1.0 - 0.3 * (((xx - W / 2) ** 2 + (yy - H / 2) ** 2) / (W / 2) ** 2)
    prnu = 1.0 + rng.normal(0, 0.01, (H, W))
    gain_map = vignette * prnu
    dead = np.zeros((H, W), bool)
    dead[10, 20] = dead[50, 70] = True
    gain_map[dead] = 0.05
    return rng, offset, dark_current, gain_map, hot, dead


def _expose(rng, offset, dark_current, gain_map, sky, n, read=3.0):
    return np.stack([offset + dark_current + gain_map * sky + rng.normal(0, read, (H, W)) for _ in range(n)])


def test_master_frame_clips_outliers():
    rng = np.random.default_rng(1)
    stack = rng.normal(50.0, 2.0, (9, H, W)).astype(np.float32)
    stack[3, 40:43, :] = 5000.0  # a satellite trail in one frame
    m = master_frame(stack)
    assert np.abs(m[40:43] - 50).max() < 3.0
    assert np.std(m) == pytest.approx(2.0 / 3.0, rel=0.15)  # noise of a mean of 9
    assert np.abs(master_frame(stack, combine="median")[40:43] - 50).max() < 4.0
    assert master_frame(stack, combine="mean")[41].mean() > 500  # a plain mean keeps the trail
    with pytest.raises(ValueError):
        master_frame(stack, combine="nope")


def test_dark_flat_hot_pipeline_recovers_a_flat_sky():
    rng, offset, dc, gain_map, hot, dead = _sensor()
    darks = _expose(rng, offset, dc, gain_map, 0.0, 8)
    flats = _expose(rng, offset, dc, gain_map, 20000.0, 8)
    dark = master_dark(darks)
    flat = master_flat(flats, dark=dark)
    assert np.median(flat) == pytest.approx(1.0, abs=1e-6)
    hot_map = hot_pixel_map(dark)
    assert np.array_equal(hot_map, hot)  # every hot pixel, nothing else
    dead_map = dead_pixel_map(flat)
    assert np.array_equal(dead_map, dead)
    sky = 500.0
    frame = _expose(rng, offset, dc, gain_map, sky, 1)[0]
    cal = calibrate_frame(frame, dark=dark, flat=flat, bad_pixels=hot_map | dead_map)
    # the flat is normalised to median 1, so the sky comes out at the median response
    assert np.median(cal) == pytest.approx(sky * np.median(gain_map), rel=0.01)
    # vignetting and PRNU gone: what is left is read + dark-subtraction noise, ~3 ADU
    assert np.std(cal) < 4.5
    expect = sky * np.median(gain_map)
    assert np.abs(cal[hot_map | dead_map] - expect).max() < 15.0  # repaired from neighbours
    raw_std = np.std(frame - offset - dc)
    assert raw_std > 10 * np.std(cal)


def test_calibration_removes_hot_pixel_detections():
    rng, offset, dc, gain_map, hot, dead = _sensor(2)
    darks = _expose(rng, offset, dc * 10, gain_map, 0.0, 6)  # long exposure: bright hot pixels
    frame = _expose(rng, offset, dc * 10, gain_map, 300.0, 1)[0]
    dark = master_dark(darks)
    assert len(extract_centroids(calibrate_frame(frame, dark=dark, bad_pixels=hot_pixel_map(dark)))) == 0


def test_dark_report_per_exposure():
    rng, offset, dc, gain_map, hot, dead = _sensor(3)
    darks = {t: _expose(rng, offset, dc * t, gain_map, 0.0, 5) for t in (0.1, 1.0)}
    rows = dark_report(darks)
    assert [r["exposure_s"] for r in rows] == [0.1, 1.0]
    assert rows[0]["dark_level_adu"] == pytest.approx(100.5, abs=1.0)
    assert rows[1]["dark_level_adu"] == pytest.approx(105.0, abs=1.0)
    assert rows[1]["hot_pixels"] == hot.sum()
    assert rows[1]["dark_noise_adu"] == pytest.approx(3.0, rel=0.1)
    assert rows[0]["dsnu_adu"] == pytest.approx(2.0, rel=0.15)  # the offset map's spread


def test_save_load_roundtrip_and_errors(tmp_path):
    dark = np.full((H, W), 3.0, np.float32)
    flat = np.ones((H, W), np.float32)
    bad = np.zeros((H, W), bool)
    bad[1, 2] = True
    for name in ("cal.npz", "cal.fits"):
        save_calibration(tmp_path / name, dark=dark, flat=flat, bad_pixels=bad)
        got = load_calibration(tmp_path / name)
        assert set(got) == {"dark", "flat", "bad_pixels"}
        assert np.array_equal(got["bad_pixels"], bad) and np.allclose(got["dark"], 3.0)
    with pytest.raises(ImageReadError):
        load_calibration(tmp_path / "missing.fits")
    (tmp_path / "junk.npz").write_text("not a file")
    with pytest.raises(ImageReadError):
        load_calibration(tmp_path / "junk.npz")
    with pytest.raises(ImageReadError):
        calibrate_frame(np.zeros((10, 10)), dark=dark)
    with pytest.raises(ImageReadError):
        master_flat(np.zeros((3, 10, 10)))
