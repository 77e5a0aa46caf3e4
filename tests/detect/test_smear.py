"""Solving a smeared frame: the frame averaged along the known streak (skyfix.detect.smear) and
``solve(smear_px=…)`` on simulated 2 °/s frames, where streaks are 17 px long."""

from __future__ import annotations

import math

import numpy as np
import pytest

import skyfix
from skyfix.attitude import attitude_error
from skyfix.camera import Camera
from skyfix.detect import streak_motion
from skyfix.detect.smear import smear_filter, smear_offsets
from skyfix.errors import InputError
from skyfix.geometry import attitude_from_quaternion, attitude_from_radec_roll
from skyfix.simulate import render_sequence

CAMERA = Camera.from_fov(1280, 960, 15.0)
EPOCH = 2025.5


def test_offsets_are_symmetric_and_one_per_pixel():
    off = smear_offsets([12.7, 10.2])  # 16.3 px long
    np.testing.assert_array_equal(off, -off[::-1])
    np.testing.assert_array_equal(off[-1], [6, 5])  # the segment's end, half of (12.7, 10.2)
    assert 13 <= len(off) <= 17 and len(np.unique(off, axis=0)) == len(off)  # one per pixel crossed
    np.testing.assert_array_equal(smear_offsets([0.4, -0.3]), [[0, 0]])
    with pytest.raises(InputError, match="two finite numbers"):
        smear_offsets([1.0, float("nan")])


def test_filter_keeps_a_streaks_centre_and_level():
    """A streak drawn along the filter's direction keeps its intensity centroid (to 0.01 px),
    its total light and most of its peak, while white noise drops by √M (M offsets): the
    matched filter's gain; a flat frame stays flat."""
    img = np.full((64, 80), 100.0, np.float32)
    yy, xx = np.mgrid[:64, :80]
    for s in np.linspace(-0.5, 0.5, 200):  # a 15 px streak of PSF σ 1 px about (40.3, 31.7)
        cx, cy = 40.3 + 12.0 * s, 31.7 + 9.0 * s
        img += np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / 2.0).astype(np.float32)
    out = smear_filter(img, [12.0, 9.0])
    light = out - 100.0
    assert abs(light.sum() - (img - 100.0).sum()) < 1e-3 * (img - 100.0).sum()
    assert abs((light * xx).sum() / light.sum() - 40.3) < 0.01
    assert abs((light * yy).sum() / light.sum() - 31.7) < 0.01
    assert light.max() > 0.8 * (img - 100.0).max() and out.dtype == np.float32  # the peak stays
    noise = np.random.default_rng(1).normal(0.0, 1.0, (200, 200))  # and the noise drops by √M
    m = len(smear_offsets([12.0, 9.0]))
    assert abs(smear_filter(noise, [12.0, 9.0])[20:-20, 20:-20].std() * math.sqrt(m) - 1.0) < 0.05
    np.testing.assert_array_equal(smear_filter(np.full((5, 6), 7, np.uint16), [3.0, 0.0]), 7.0)


def test_solve_along_the_smear_at_2_deg_s():
    """Frames at 2 °/s (0.1 s): told the smear, lost in space solves every one within 40″ with
    more stars than the plain solve (which fails on some)."""
    axis = np.array([0.6, -0.75, 0.28]) / np.linalg.norm([0.6, -0.75, 0.28])
    rate = np.radians(2.0) * axis
    A0 = attitude_from_radec_roll(math.radians(84.0), math.radians(-2.0), math.radians(20.0))
    frames = list(render_sequence(A0, CAMERA, n_frames=4, fps=10.0, rate_rad_s=rate, epoch=EPOCH, seed=21))
    smear = streak_motion(CAMERA, np.array([[CAMERA.cx, CAMERA.cy]]), rate, 0.1)[0]
    assert 15.0 < np.hypot(*smear) < 19.0
    for f in frames:
        aided = skyfix.solve(f.image, camera=CAMERA, epoch=EPOCH, smear_px=smear)
        plain = skyfix.solve(f.image, camera=CAMERA, epoch=EPOCH)
        assert aided.solved, aided.reason
        e = attitude_error(attitude_from_quaternion(f.truth["quaternion_xyzw"]), aided.A_icrs_to_cam)
        assert math.degrees(math.hypot(e[0], e[1])) * 3600 < 40.0
        assert aided.n_matched >= 15 and aided.n_matched > (plain.n_matched if plain.solved else 0)


def test_bad_smear_is_an_input_error():
    with pytest.raises(InputError, match="smear"):
        skyfix.solve(np.zeros((20, 20)), smear_px="fast")


@pytest.mark.parametrize("value", ["fast", "1,2,3", "1,nan"])
def test_cli_bad_smear_is_one_line(value):
    from typer.testing import CliRunner

    from skyfix.cli import app

    result = CliRunner().invoke(app, ["solve", "nowhere.png", "--smear", value])
    assert result.exit_code == 2 and "Traceback" not in result.output
    lines = result.stderr.splitlines()
    want = f"skyfix: error: --smear wants two numbers of pixels DX,DY, got {value!r}"
    assert lines == [want], result.stderr
