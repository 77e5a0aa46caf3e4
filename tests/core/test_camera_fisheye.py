"""Kannala–Brandt / equidistant (OpenCV ``cv::fisheye``) projection of the camera model:
round trips, closed forms, OpenCV, derivatives, TOML, WCS (ARC), the simulator, and the pinhole
model unchanged to the bit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyfix._kernels import lens
from skyfix.camera import Camera
from skyfix.catalog import Catalog
from skyfix.errors import CameraError, UnknownNameError
from skyfix.geometry import angle_between, attitude_from_radec_roll, radec_to_vector, vector_to_radec
from skyfix.wcs import solution_wcs

OPENCV_K = dict(k1=-0.01, k2=0.002)  # OpenCV-like fisheye coefficients
CAMERAS = {
    "equidistant 90°": Camera.from_fov(1024, 768, 90.0, projection="equidistant"),
    "equidistant 150°": Camera.from_fov(1000, 1000, 150.0, projection="equidistant"),
    "kannala-brandt 120°": Camera.from_fov(1280, 960, 120.0, projection="kannala-brandt", **OPENCV_K),
    "kannala-brandt off-centre": Camera(1024, 768, 420.0, 417.0, 530.2, 371.9, skew=1.5, k1=0.02, k2=-0.01,
                                        k3=0.002, k4=-3e-4, projection="kannala-brandt"),
}


def _grid(cam: Camera, n: int = 41) -> np.ndarray:
    """Pixel positions over the whole frame, its outer edges included."""
    gx, gy = np.meshgrid(np.linspace(-0.5, cam.width - 0.5, n), np.linspace(-0.5, cam.height - 0.5, n))
    return np.column_stack([gx.ravel(), gy.ravel()])


def _theta_d(theta: np.ndarray, cam: Camera) -> np.ndarray:
    """OpenCV's θ polynomial, written out here (not the kernel's)."""
    return theta * (1 + cam.k1 * theta**2 + cam.k2 * theta**4 + cam.k3 * theta**6 + cam.k4 * theta**8)


# --- round trips and closed forms -------------------------------------------------------------
@pytest.mark.parametrize("name", list(CAMERAS))
def test_pixel_ray_pixel_round_trip(name: str) -> None:
    cam = CAMERAS[name]
    xy = _grid(cam)
    rays = cam.pixel_to_ray(xy)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, atol=1e-15)
    back, front = cam.ray_to_pixel(rays)
    assert np.array_equal(front, rays[:, 2] > 1e-9)  # in front = less than 90° from the boresight
    assert front.mean() > (0.6 if "150" in name else 0.999)
    assert np.max(np.abs(back[front] - xy[front])) < 1e-9
    # ...and ray -> pixel -> ray
    np.testing.assert_allclose(cam.pixel_to_ray(back[front]), rays[front], atol=1e-14)


@pytest.mark.parametrize("name", ["equidistant 90°", "equidistant 150°"])
def test_equidistant_angle_is_pixel_radius_over_f(name: str) -> None:
    cam = CAMERAS[name]
    xy = _grid(cam)
    dx, dy = xy[:, 0] - cam.cx, xy[:, 1] - cam.cy
    rays = cam.pixel_to_ray(xy)
    # The angle from the boresight is r_px / f exactly, in the pixel's direction, also past 90°
    # (the 150° frame's corners are at 106°).
    theta = np.hypot(dx, dy) / cam.fx
    assert theta.max() > (1.8 if "150" in name else 0.98)
    np.testing.assert_allclose(np.arctan2(np.hypot(rays[:, 0], rays[:, 1]), rays[:, 2]), theta, atol=1e-14)
    np.testing.assert_allclose(rays[:, 0] * dy - rays[:, 1] * dx, 0.0, atol=1e-12)
    assert np.all(rays[:, 0] * dx + rays[:, 1] * dy >= 0)
    # The field of view is (width / f) radians, the diagonal's hypot(width, height) / f.
    assert cam.fov_deg == pytest.approx(math.degrees(cam.width / cam.fx), abs=1e-12)
    assert cam.fov_diagonal_deg == pytest.approx(math.degrees(math.hypot(cam.width, cam.height) / cam.fx),
                                                 abs=1e-12)
    assert cam.fx == (cam.width / 2) / math.radians(cam.fov_deg / 2)


def test_kannala_brandt_projects_by_the_theta_polynomial() -> None:
    cam = CAMERAS["kannala-brandt off-centre"]
    rng = np.random.default_rng(3)
    theta = rng.uniform(0.0, math.radians(80.0), 500)
    phi = rng.uniform(0.0, 2 * math.pi, 500)
    rays = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    uv, front = cam.ray_to_pixel(rays)
    assert front.all()
    td = _theta_d(theta, cam)
    expected = np.column_stack([cam.fx * td * np.cos(phi) + cam.skew * td * np.sin(phi) + cam.cx,
                                cam.fy * td * np.sin(phi) + cam.cy])
    np.testing.assert_allclose(uv, expected, atol=1e-10)
    # From the field of view: f makes the side edge exactly fov/2 from the boresight.
    fov = Camera.from_fov(1280, 960, 120.0, projection="kannala-brandt", **OPENCV_K)
    assert fov.fov_deg == pytest.approx(120.0, abs=1e-10)
    assert fov.fx == pytest.approx(640.0 / _theta_d(math.radians(60.0), fov), rel=1e-15)


def test_matches_opencv_fisheye() -> None:
    cv2 = pytest.importorskip("cv2")
    cam = Camera(1280, 960, 500.0, 498.0, 641.3, 478.9, k1=-0.01, k2=0.002, k3=-3e-4, k4=2e-5,
                 projection="kannala-brandt")
    rng = np.random.default_rng(1)
    theta = rng.uniform(0.0, math.radians(80.0), 300)
    phi = rng.uniform(0.0, 2 * math.pi, 300)
    rays = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    K = np.array([[cam.fx, 0.0, cam.cx], [0.0, cam.fy, cam.cy], [0.0, 0.0, 1.0]])
    D = np.array([cam.k1, cam.k2, cam.k3, cam.k4])
    ref, _ = cv2.fisheye.projectPoints(rays[:, None, :], np.zeros(3), np.zeros(3), K, D)
    mine, _ = cam.ray_to_pixel(rays)
    np.testing.assert_allclose(mine, ref[:, 0, :], atol=1e-6)
    # cv2.fisheye.undistortPoints: normalised (X/Z, Y/Z) of the pixels (OpenCV iterates to ~1e-8).
    und = cv2.fisheye.undistortPoints(mine[:, None, :], K, D,
                                      criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12))
    np.testing.assert_allclose(cam.pixel_to_normalized(mine), und[:, 0, :], rtol=1e-6, atol=1e-9)


def test_past_ninety_degrees() -> None:
    cam = CAMERAS["equidistant 150°"]
    # A corner: 106° from the boresight. Its ray is right; it has no normalised coordinates, and a
    # ray there is not in front.
    corner = np.array([[-0.5, -0.5]])
    theta = math.hypot(cam.cx + 0.5, cam.cy + 0.5) / cam.fx
    assert theta > math.pi / 2
    ray = cam.pixel_to_ray(corner)
    assert math.acos(ray[0, 2]) == pytest.approx(theta, abs=1e-14)
    assert np.isnan(cam.pixel_to_normalized(corner)).all()
    assert not cam.ray_to_pixel(ray)[1][0]
    # 89.9° still round-trips.
    a = math.radians(89.9)
    uv, front = cam.ray_to_pixel(np.array([[math.sin(a), 0.0, math.cos(a)]]))
    assert front[0] and uv[0, 0] - cam.cx == pytest.approx(cam.fx * a, abs=1e-9)
    # A pixel that a folding polynomial never reaches has no ray.
    fold = Camera.from_fov(400, 400, 60.0, projection="kannala-brandt", k1=-0.2)  # θ_d ≤ 0.86 rad
    xy = np.array([[fold.cx + 0.5 * fold.fx, fold.cy], [fold.cx + 0.9 * fold.fx, fold.cy]])
    rays = fold.pixel_to_ray(xy)
    assert np.isfinite(rays[0]).all() and np.isnan(rays[1]).all()
    theta = math.acos(rays[0, 2])  # on the rising branch, below the fold at 1/sqrt(0.6) rad
    assert _theta_d(theta, fold) == pytest.approx(0.5, abs=1e-14) and theta < 1 / math.sqrt(0.6)
    with pytest.raises(CameraError, match="never reaches"):
        Camera(400, 400, 200.0, 200.0, 199.5, 199.5, k1=-0.2, projection="kannala-brandt")


# --- derivatives ------------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(CAMERAS))
def test_distort_jacobian_against_finite_differences(name: str) -> None:
    cam = CAMERAS[name].numbers()
    rng = np.random.default_rng(2)
    pts = np.vstack([[0.0, 0.0], [1e-9, -2e-9], [1e-4, 3e-4], rng.uniform(-3.0, 3.0, (40, 2))])
    h = 1e-6
    for x, y in pts:
        xd, yd, dxx, dxy, dyx, dyy, r2 = lens.distort_jacobian(x, y, cam)
        assert (xd, yd) == lens.distort(x, y, cam) and r2 == x * x + y * y
        px, mx = lens.distort(x + h, y, cam), lens.distort(x - h, y, cam)
        py, my = lens.distort(x, y + h, cam), lens.distort(x, y - h, cam)
        numeric = [(px[0] - mx[0]) / (2 * h), (py[0] - my[0]) / (2 * h),
                   (px[1] - mx[1]) / (2 * h), (py[1] - my[1]) / (2 * h)]
        np.testing.assert_allclose([dxx, dxy, dyx, dyy], numeric, atol=1e-8)


def test_coefficient_jacobian_against_finite_differences() -> None:
    cam = CAMERAS["kannala-brandt off-centre"]
    rng = np.random.default_rng(5)
    rays = rng.normal(size=(50, 3)) * [0.6, 0.6, 0.0] + [0.0, 0.0, 1.0]
    rays[0] = [0.0, 0.0, 1.0]
    J = lens.kb_pixel_jacobian(rays, cam.numbers())
    assert J.shape == (50, 2, 4) and np.all(J[0] == 0.0)
    h = 1e-7
    for j, k in enumerate(("k1", "k2", "k3", "k4")):
        up = cam.replace(**{k: getattr(cam, k) + h}).ray_to_pixel(rays)[0]
        down = cam.replace(**{k: getattr(cam, k) - h}).ray_to_pixel(rays)[0]
        np.testing.assert_allclose(J[:, :, j], (up - down) / (2 * h), atol=1e-5)
    assert np.max(np.abs(J[:, :, 0])) > 50.0  # a real derivative, not zeros


# --- the Camera: TOML, replace, errors --------------------------------------------------------
def test_toml_round_trip_is_exact(tmp_path) -> None:
    cam = CAMERAS["kannala-brandt off-centre"].replace(name="fisheye test", k1=0.1 / 3)
    p = tmp_path / "fisheye.toml"
    cam.save(p)
    text = p.read_text()
    assert 'projection = "kannala-brandt"' in text and "k4 = " in text and "p1" not in text
    assert Camera.load(p) == cam
    pin = Camera(640, 480, 1000.0 / 3, 1001.0, 320.1, 240.2, k1=0.1, p2=1e-3)
    assert "projection" not in pin.to_toml() and "k4" not in pin.to_toml()  # pinhole files as before
    assert Camera.from_toml(pin.to_toml()) == pin


def test_equidistant_alias_and_fov_key() -> None:
    cam = Camera.from_toml('[camera]\nwidth = 800\nheight = 600\nprojection = "equidistant"\n'
                           'fov_deg = 100.0\n')
    assert cam.projection == "kannala-brandt" and not cam.has_distortion
    assert cam.fx == cam.fy == 400.0 / math.radians(50.0)
    assert cam == Camera.from_fov(800, 600, 100.0, projection="kannala-brandt")
    kb = Camera.from_toml('[camera]\nwidth = 800\nheight = 600\nprojection = "kannala-brandt"\n'
                          'fov_deg = 100.0\nk1 = -0.01\n')
    assert kb.fov_deg == pytest.approx(100.0, abs=1e-10) and kb.k1 == -0.01


@pytest.mark.parametrize(("toml", "message"), [
    ('projection = "fisheye"',
     "unknown camera projection 'fisheye'; choose one of pinhole, kannala-brandt, equidistant"),
    ("projection = 1", "unknown camera projection '1'"),
    ('projection = "kannala-brandt"\np1 = 0.001', "p1 must be 0 for the kannala-brandt projection"),
    ("k4 = 0.001", "k4 must be 0 for the pinhole projection"),
    ('projection = "equidistant"\nk1 = 0.01', "an equidistant camera has k1 = k2 = k3 = k4 = 0"),
])
def test_bad_projection_is_a_one_line_error(toml: str, message: str) -> None:
    with pytest.raises((CameraError, UnknownNameError)) as err:  # a bad value, or a name no projection has
        Camera.from_toml(f"[camera]\nwidth = 800\nheight = 600\nfx = 500.0\n{toml}\n")
    assert message in str(err.value) and "\n" not in str(err.value)


def test_replace_and_numbers_keep_the_projection() -> None:
    cam = CAMERAS["kannala-brandt 120°"]
    numbers = cam.numbers()
    assert numbers.shape == (len(lens.CAMERA_NUMBERS),) and numbers[lens.PROJECTION] == lens.KANNALA_BRANDT
    assert numbers[lens.K1] == -0.01 and numbers[lens.K4] == 0.0
    assert cam.scaled_focal(1.1).projection == "kannala-brandt"
    assert cam.scaled_focal(1.1).fx == cam.fx * 1.1
    # What calibrate.py does: the kernels' numbers back through replace.
    again = cam.replace(**dict(zip(lens.CAMERA_NUMBERS, numbers.tolist(), strict=True)))
    assert again == cam
    assert Camera.from_fov(640, 480, 20.0).numbers()[lens.PROJECTION] == lens.PINHOLE
    with pytest.raises(UnknownNameError, match="unknown camera projection code"):
        cam.replace(projection_code=7.0)


# --- the pinhole, unchanged -------------------------------------------------------------------
PINHOLE_BEFORE = {  # float.hex of each number, flattened, as the code before Kannala–Brandt gave it
    "pixel_to_ray": [
        "-0x1.06891b3d7dd71p-2", "-0x1.8a2732d65fffap-3", "0x1.e4fa2ff1dc98bp-1", "0x0.0p+0", "0x0.0p+0",
        "0x1.0000000000000p+0", "0x1.055a0aa4b83f4p-2", "0x1.8b0ffa36fefcbp-3", "0x1.e51744c69386bp-1",
        "-0x1.c1cd39ef410ffp-3", "0x1.0c89b57b5da36p-3", "0x1.eef76e7979308p-1", "0x1.2bbcb9403db29p-3",
        "-0x1.80f2ff18a7d69p-3", "0x1.f1427d3acd6c2p-1",
    ],
    "ray_to_pixel": [
        "0x1.b86b62a5e9333p+9", "0x1.67a1d0e536501p+8", "0x1.40a6666666666p+9", "0x1.dee6666666666p+8",
        "0x1.2c28aebaef10ep+7", "0x1.a6fc54a8758bap+9", "0x1.51aeff61cf9ccp+10", "0x1.db18f94f61bd0p+9",
    ],
    "distort": [
        "0x1.98e19b0ab2e18p-4", "-0x1.96e0346dc5d64p-3", "0x0.0p+0", "0x1.37157e9585210p-2",
        "-0x1.98cdf1e0828c5p-5", "0x1.313ca2339c0ecp-3", "0x0.0p+0", "-0x1.0ed8ade9bd59ep-2",
    ],
    "undistort": [
        "0x1.9a5288409c7b8p-4", "-0x1.9c615b2a7f59dp-3", "0x0.0p+0", "0x1.442f42fd14e93p-2",
        "-0x1.9a664c286ca5bp-5", "0x1.35341e2c9bd15p-3", "0x0.0p+0", "-0x1.1a7559ac429b3p-2",
    ],
    "jac": [
        "0x1.98e19b0ab2e18p-4", "-0x1.98cdf1e0828c5p-5", "0x1.fdd0ad256798ap-1", "0x1.78d823422467dp-10",
        "0x1.78d823422467dp-10", "0x1.feba2856605efp-1", "0x1.999999999999bp-7", "-0x1.96e0346dc5d64p-3",
        "0x1.313ca2339c0ecp-3", "0x1.f80e3886594b0p-1", "0x1.9bb2fec56d5cfp-8", "0x1.9bb2fec56d5cfp-8",
        "0x1.fa32cd9e83e43p-1", "0x1.0000000000000p-4", "0x0.0p+0", "0x0.0p+0", "0x1.0000000000000p+0",
        "0x0.0p+0", "0x0.0p+0", "0x1.0000000000000p+0", "0x0.0p+0", "0x1.37157e9585210p-2",
        "-0x1.0ed8ade9bd59ep-2", "0x1.eb57267b73547p-1", "0x1.2bb3c6514984dp-6", "0x1.2bb3c6514984dp-6",
        "0x1.ed93187f82ac4p-1", "0x1.5a1cac083126fp-3",
    ],
}


def test_pinhole_results_are_bit_identical_to_before() -> None:
    cam = Camera(width=1280, height=960, fx=2400.0, fy=2390.0, cx=641.3, cy=478.9, skew=0.8,
                 k1=-0.12, k2=0.05, k3=-0.01, p1=1e-3, p2=-5e-4)
    xy = np.array([[0.0, 0.0], [641.3, 478.9], [1279.5, 959.5], [100.25, 800.75], [1000.0, 20.0]])
    rays = np.array([[0.1, -0.05, 1.0], [0.0, 0.0, 1.0], [-0.2, 0.15, 0.97], [0.3, 0.2, -0.5]])
    xn, yn = np.array([0.1, -0.2, 0.0, 0.31]), np.array([-0.05, 0.15, 0.0, -0.27])
    uv, front = cam.ray_to_pixel(rays)
    now = {
        "pixel_to_ray": cam.pixel_to_ray(xy),
        "ray_to_pixel": uv,
        "distort": np.stack(cam.distort(xn, yn)),
        "undistort": np.stack(cam.undistort(xn, yn)),
        "jac": np.array([lens.distort_jacobian(a, b, cam.numbers()) for a, b in zip(xn, yn, strict=True)]),
    }
    for key, values in now.items():
        assert [float(v).hex() for v in np.ravel(values)] == PINHOLE_BEFORE[key], key
    assert front.tolist() == [True, True, True, False]


# --- WCS: ARC, and SIP on ARC -----------------------------------------------------------------
@pytest.mark.parametrize("name", list(CAMERAS))
def test_wcs_is_arc_and_round_trips_with_astropy(name: str) -> None:
    cam = CAMERAS[name]
    A = attitude_from_radec_roll(*np.radians([200.0, -60.0, 123.0]))
    w = solution_wcs(A, cam)
    assert w.wcs.ctype[0] == ("RA---ARC-SIP" if cam.has_distortion else "RA---ARC")
    xy = _grid(cam, 29)
    r = cam.pixel_to_ray(xy) @ A  # each pixel's sky direction
    # pixel -> sky (astropy) against the camera model...
    ra_w, dec_w = w.all_pix2world(xy[:, 0] + 1, xy[:, 1] + 1, 1)
    sky = radec_to_vector(np.radians(ra_w), np.radians(dec_w))
    to_sky_px = np.max(angle_between(sky, r)) / cam.plate_scale_rad
    # ...and astropy's sky -> pixel back.
    ra, dec = vector_to_radec(r)
    px, py = w.all_world2pix(np.degrees(ra), np.degrees(dec), 1, tolerance=1e-10, maxiter=100)
    back_px = np.max(np.hypot(px - 1 - xy[:, 0], py - 1 - xy[:, 1]))
    tol = 0.005 if cam.has_distortion else 1e-8  # the TAN path's SIP tolerance; ARC exactly
    assert to_sky_px < tol and back_px < tol


# --- the simulator renders through the projection ---------------------------------------------
def test_simulator_renders_a_90_degree_fisheye() -> None:
    from skyfix.simulate import render

    cam = Camera.from_fov(512, 512, 90.0, projection="equidistant")
    A = attitude_from_radec_roll(1.0, 0.3, 0.2)
    alpha = np.radians([0.0, 10.0, 25.0, 40.0, 44.0, 55.0, 60.0, 30.0])
    phi = np.radians([0.0, 30.0, 100.0, 200.0, 0.0, 45.0, 225.0, 300.0])
    b = np.column_stack([np.sin(alpha) * np.cos(phi), np.sin(alpha) * np.sin(phi), np.cos(alpha)])
    n = len(b)
    catalog = Catalog(np.arange(n), b @ A, np.full(n, 3.0, np.float32), np.zeros(n), np.zeros(n), 2025.0)
    frame = render(A, cam, catalog=catalog, epoch=2025.0, noise=False, sky_mag_arcsec2=None, exposure_s=0.1,
                   sensor="has2", optics="has2")
    # Each star f·α from the centre (not the pinhole's f·tan α: 40° is 50 px farther out).
    expected = np.column_stack([cam.cx + cam.fx * alpha * np.cos(phi), cam.cy + cam.fy * alpha * np.sin(phi)])
    truth = {s["id"]: (s["x"], s["y"]) for s in frame.truth["stars"]}
    assert sorted(truth) == list(range(n))
    np.testing.assert_allclose([truth[i] for i in range(n)], expected, atol=1e-9)
    # The light lands there: the centre of mass of the expected electrons around each star.
    e = frame.expected_e.astype(np.float64)
    for x, y in expected:
        rows = slice(max(round(y) - 8, 0), min(round(y) + 9, cam.height))
        cols = slice(max(round(x) - 8, 0), min(round(x) + 9, cam.width))
        yy, xx = np.mgrid[rows, cols]
        w = e[rows, cols]
        assert np.hypot((w * xx).sum() / w.sum() - x, (w * yy).sum() / w.sum() - y) < 0.01
    assert Camera.from_dict(frame.truth["camera"]) == cam  # the truth's camera table reloads
