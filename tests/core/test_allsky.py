"""All-sky fisheye frames (issue 26 part 3): the simulator's frame, its image circle and sky mask,
a solve with no camera file against the truth, the zenith's pixel, the camera model past 170°,
and a fisheye frame given a pinhole camera (a one-line error)."""

import math

import numpy as np
import pytest

from skyfix.analysis.truth import judge
from skyfix.camera import Camera
from skyfix.detect.sky_circle import find_image_circle, sky_mask
from skyfix.errors import CameraError
from skyfix.geometry import attitude_from_quaternion
from skyfix.pipeline import solve
from skyfix.simulate.allsky import Landscape, all_sky_camera, render_allsky

SITE, TIME = (40.0, -105.0), "2026-03-01T05:00:00"


def _landscape() -> Landscape:
    """Hills 2° high, dark trees 20° high over 40° of azimuth from 30°, lit ones 15° high over
    30° from 200°, a light dome toward 300°."""
    skyline = np.full(360, 2.0)
    skyline[30:70] = 20.0
    skyline[200:230] = 15.0
    lit = np.zeros(360, bool)
    lit[200:230] = True
    return Landscape(skyline, lit, 300.0, 4.0)


def _render(landscape: Landscape):
    cam = all_sky_camera(1024, 768, 185.0, offset_px=(9.0, -6.0), k=(-0.02, 0.003))
    fr = render_allsky(cam, site=SITE, time=TIME, landscape=landscape, fov_deg=185.0, tilt_deg=2.5,
                       tilt_az_deg=120.0, roll_deg=70.0, seed=3)
    return fr, cam


@pytest.fixture(scope="module")
def frame():
    return _render(_landscape())


def test_render_allsky_truth(frame):
    fr, cam = frame
    img = fr.image.astype(float)
    cx, cy, radius = fr.truth["image_circle"]
    assert (cx, cy) == (cam.cx, cam.cy) and radius == pytest.approx(0.96 * 768 / 2)
    # the zenith 2.5° off the boresight: f·θ_d(2.5°) from the principal point
    off = math.hypot(fr.truth["zenith_px"][0] - cam.cx, fr.truth["zenith_px"][1] - cam.cy)
    assert off == pytest.approx(cam.fx * math.radians(2.5), rel=0.01)
    # outside the image circle the lens passes no light: the corners are the bias and dark current
    assert abs(np.median(img[:40, :40]) - np.median(img[-40:, -40:])) <= 1.0
    h2, w2 = cam.height // 2, cam.width // 2
    assert np.median(img[h2 - 20:h2 + 20, w2 - 20:w2 + 20]) > np.median(img[:40, :40]) + 3.0
    assert np.all(fr.expected_e[:40, :40] == 0.0)


def test_image_circle_and_sky_mask(frame):
    fr, cam = frame
    circle = find_image_circle(fr.image)
    assert circle is not None
    # the lit disc is the sky above the horizon: its centre is near the zenith's pixel, its
    # radius near the horizon's (90° from the zenith)
    zx, zy = fr.truth["zenith_px"]
    horizon_px = cam.fx * math.pi / 2 * (1 - 0.02 * (math.pi / 2) ** 2)  # k1 -0.02 (k2 adds 0.4 %)
    assert math.hypot(circle.cx - zx, circle.cy - zy) < 0.03 * circle.radius
    assert circle.radius == pytest.approx(horizon_px, rel=0.04)
    mask = sky_mask(fr.image, circle)
    assert not mask[:60, :60].any()  # the dark corners
    assert mask[int(zy) - 50:int(zy) + 50, int(zx) - 50:int(zx) + 50].all()  # the zenith's sky
    assert 0.3 < mask.mean() < 0.6
    # the lit obstruction (200°–230° azimuth, the pixels that change when it is dark): masked
    unlit, _ = _render(_landscape()._replace(lit=np.zeros(360, bool)))
    lit = fr.expected_e != unlit.expected_e
    assert lit.sum() > 2000
    assert not (lit & mask).any()


def test_no_circle_on_ordinary_frames():
    rng = np.random.default_rng(0)
    sky = rng.normal(200.0, 6.0, (960, 1280))
    assert find_image_circle(sky.astype(np.uint16)) is None
    yy, xx = np.mgrid[0:960, 0:1280]
    vignetted = 60 + 140 * np.cos(np.hypot(xx - 640, yy - 480) / 800 * 0.9) ** 4
    vignetted += rng.normal(0, 4, (960, 1280))
    assert find_image_circle(vignetted.astype(np.uint16)) is None


def test_allsky_solves_without_camera(frame):
    fr, cam = frame
    sol = solve(fr.image)
    assert sol.solved, sol.reason
    A_true = attitude_from_quaternion(np.asarray(fr.truth["quaternion_xyzw"]))
    j = judge(sol.A_icrs_to_cam, sol.camera, A_true, cam)
    assert not j.wrong and j.boresight_arcsec < 30.0 and j.roll_deg < 0.01
    assert sol.camera.projection == "kannala-brandt" and sol.n_matched >= 100
    assert sol.camera.fx == pytest.approx(cam.fx, rel=0.002)
    assert math.hypot(sol.camera.cx - cam.cx, sol.camera.cy - cam.cy) < 1.0
    assert sol.zenith_px is None  # no site


def test_allsky_zenith_pixel(frame):
    fr, cam = frame
    sol = solve(fr.image, site=f"{SITE[0]},{SITE[1]}", time=TIME, refraction="none")
    assert sol.solved, sol.reason
    assert math.dist(sol.zenith_px, fr.truth["zenith_px"]) < 0.3
    assert '"zenith_px": [' in sol.to_json()


def test_allsky_through_its_fisheye_camera_file(frame):
    fr, cam = frame
    sol = solve(fr.image, camera=cam)
    assert sol.solved, sol.reason
    A_true = attitude_from_quaternion(np.asarray(fr.truth["quaternion_xyzw"]))
    assert judge(sol.A_icrs_to_cam, sol.camera, A_true, cam).boresight_arcsec < 30.0


def test_allsky_given_a_pinhole_camera_is_one_line_error(frame):
    fr, cam = frame
    pinhole = Camera.from_fov(cam.width, cam.height, 120.0)
    with pytest.raises(CameraError, match="all-sky fisheye frame .* pinhole") as err:
        solve(fr.image, camera=pinhole)
    assert "\n" not in str(err.value)


def test_camera_fisheye_past_170_degrees():
    cam = all_sky_camera(1920, 1080, 180.0)
    assert cam.fov_deg == pytest.approx(2 * math.degrees(960 / cam.fx), rel=1e-9) and cam.fov_deg > 180
    rays = cam.pixel_to_ray(np.array([[cam.cx + cam.fx * math.pi / 2, cam.cy]]))
    assert rays[0] == pytest.approx([1.0, 0.0, 0.0], abs=1e-12)  # the horizon, 90° off axis
    # equisolid: its polynomial reaches 180° at most; a 16:9 frame's sides lie beyond: all round
    assert all_sky_camera(1920, 1080, 180.0, k=(-1 / 24, 1 / 1920)).fov_deg == 360.0
    with pytest.raises(CameraError, match="0.01°–170° for the pinhole"):
        Camera.from_dict(dict(width=1920, height=1080, fx=50.0))


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32, np.float64])
def test_corner_check_median_is_numpys(dtype):
    from skyfix.detect.sky_circle import _median

    rng = np.random.default_rng(7)
    for shape in [(32, 32), (5, 5), (7, 3), (1, 1), (2, 1)]:
        a = (rng.random(shape) * 1000).astype(dtype)
        assert _median(a) == float(np.median(a))
