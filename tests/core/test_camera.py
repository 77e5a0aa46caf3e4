"""Camera model: pixel <-> ray with distortion, construction, TOML round trip."""

import math

import numpy as np
import pytest

from skyfix.camera import PRESETS, Camera, camera_from_preset
from skyfix.errors import CameraError, UnknownNameError


@pytest.fixture
def distorted():
    return Camera(width=1280, height=960, fx=2400.0, fy=2390.0, cx=641.3, cy=478.9, skew=0.8,
                  k1=-0.12, k2=0.05, k3=-0.01, p1=1e-3, p2=-5e-4)


def test_pixel_centre_convention():
    cam = Camera.from_fov(640, 480, 20.0)
    assert (cam.cx, cam.cy) == (319.5, 239.5)  # (0, 0) is the centre of the top-left pixel
    np.testing.assert_allclose(cam.pixel_to_ray([[319.5, 239.5]]), [[0, 0, 1]], atol=1e-15)


def test_fov_from_focal():
    cam = Camera.from_fov(1280, 960, 15.0)
    assert cam.fov_deg == pytest.approx(15.0, abs=1e-12)
    assert cam.fx == pytest.approx(640 / math.tan(math.radians(7.5)))
    c2 = Camera.from_optics(752, 480, focal_length_mm=8.5, pixel_pitch_um=6.0)
    assert c2.fx == pytest.approx(8500 / 6.0)


def test_ray_pixel_round_trip_with_distortion(distorted):
    rng = np.random.default_rng(0)
    xy = rng.uniform([0, 0], [1279, 959], size=(2000, 2))
    rays = distorted.pixel_to_ray(xy)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, atol=1e-14)
    back, front = distorted.ray_to_pixel(rays)
    assert front.all()
    assert np.max(np.abs(back - xy)) < 1e-3  # undistortion converged to 1e-3 px


def test_distortion_matches_opencv(distorted):
    cv2 = pytest.importorskip("cv2")
    distorted = distorted.replace(skew=0.0)  # projectPoints ignores K[0, 1]
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(200, 3)) * [0.2, 0.15, 0.0] + [0, 0, 1]
    K = np.array([[distorted.fx, distorted.skew, distorted.cx], [0, distorted.fy, distorted.cy], [0, 0, 1]])
    dist = np.array([distorted.k1, distorted.k2, distorted.p1, distorted.p2, distorted.k3])
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, dist)
    mine, _ = distorted.ray_to_pixel(pts)
    np.testing.assert_allclose(mine, ref[:, 0, :], atol=1e-6)


def test_toml_round_trip_is_exact(distorted, tmp_path):
    p = tmp_path / "cam.toml"
    distorted.replace(name="test cam").save(p)
    assert Camera.load(p) == distorted.replace(name="test cam")


@pytest.mark.parametrize("fov", [0.0, -5.0, 179.0, float("nan")])
def test_impossible_fov_is_rejected(fov):
    with pytest.raises(CameraError):
        Camera.from_fov(100, 100, fov)


def test_bad_camera_files(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("this is = = not toml")
    with pytest.raises(CameraError):
        Camera.load(p)
    p.write_text("[camera]\nwidth = 10\n")
    with pytest.raises(CameraError):
        Camera.load(p)
    with pytest.raises(CameraError):
        Camera.load(tmp_path / "missing.toml")


def test_presets_load():
    for name in PRESETS:
        cam = camera_from_preset(name)
        assert 1.0 < cam.fov_deg < 90.0
    with pytest.raises(UnknownNameError, match="unknown camera preset 'no-such-camera'; choose one of "):
        camera_from_preset("no-such-camera")


def test_thesis_000_pixel_to_unit_vector_corrected_form():
    # thesis 000's pixel → unit vector (docs/seeds.md#thesis-000):
    # [x·P/F, y·P/F, 1] / sqrt(1 + (x²+y²)(P/F)²)
    # with (x, y) from the principal point, P the pixel pitch and F the focal length.
    cam = Camera.from_optics(752, 480, focal_length_mm=8.5, pixel_pitch_um=6.0)
    rng = np.random.default_rng(4)
    xy = rng.uniform([0, 0], [751, 479], size=(100, 2))
    x, y = xy[:, 0] - cam.cx, xy[:, 1] - cam.cy
    k = 6.0e-3 / 8.5
    expected = np.stack([x * k, y * k, np.ones_like(x)], axis=1) / np.sqrt(1 + (x**2 + y**2) * k**2)[:, None]
    np.testing.assert_allclose(cam.pixel_to_ray(xy), expected, atol=1e-15)
