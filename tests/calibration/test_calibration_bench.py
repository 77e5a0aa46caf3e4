"""Thesis 004's own calibration procedures (skyfix.calibration.bench): the optical centre from a
rotating camera, the focal length from a star pair, the tilted CCD with its lens polynomial, and
§6.3's statistics — each on data made with a known answer, and the thesis's own numbers pinned."""

import math

import numpy as np
import pytest

from skyfix.calibration.bench import (
    THESIS_004,
    TiltedSensor,
    distance_statistics,
    fit_lens_polynomial,
    fit_tilt,
    focal_length_from_star_pair,
    focal_length_from_star_pairs,
    lens_errors,
    magnitude_statistics,
    optical_centre_from_rotation,
)
from skyfix.camera import Camera
from skyfix.catalog import load_hipparcos
from skyfix.geometry import attitude_from_radec_roll

# Thesis 004's Sunsat camera: 25 mm, 6.5 µm (h) pixels, its CCD 752 × 582 at 6.5 × 6.25 µm.
F_MM = 25.0
W_MM, H_MM = 752 * 6.5e-3, 582 * 6.25e-3


def _turn(phi: float) -> np.ndarray:
    """The camera turned by ``phi`` about its optical axis: a fixed direction's camera-frame rays."""
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_optical_centre_of_a_dot_off_the_axis():
    """§6.2.1: a dot 6 px off the axis imaged at 36 turns of 10° (App. F.2) through a lens with
    thesis 000's distortion, 0.1 px of centroid noise: the circle's centre is the principal
    point within 0.05 px (its 1σ 0.024 px), the radius the dot's."""
    cam = Camera.from_fov(752, 480, 29.7).replace(cx=381.3, cy=233.8, k1=-0.3686, k2=0.3148, p1=-0.0023,
                                                   p2=0.0003)
    dot = cam.pixel_to_ray([[cam.cx + 6.0, cam.cy]])[0]
    rng = np.random.default_rng(1)
    xy = np.array([cam.ray_to_pixel(_turn(math.radians(10 * k)) @ dot)[0] for k in range(36)])
    xy += rng.normal(0, 0.1, xy.shape)
    centre = optical_centre_from_rotation(xy)
    assert math.hypot(centre.x - cam.cx, centre.y - cam.cy) < 0.05
    assert 0.015 < centre.sigma < 0.035 and abs(centre.radius - 6.0) < 0.05


def test_optical_centre_of_a_dot_on_the_axis_is_the_scatters_centre():
    """The thesis's case: the dot set onto the axis, the centroids a 12 × 12 px cloud (the camera
    twisting in its clamp): the centre of the cloud, not a circle through noise."""
    rng = np.random.default_rng(2)
    xy = np.array([400.0, 291.0]) + rng.uniform(-6, 6, (36, 2))
    centre = optical_centre_from_rotation(xy)
    assert centre.radius == 0.0
    assert (centre.x, centre.y) == pytest.approx(tuple(xy.mean(axis=0)))
    assert 0.4 < centre.sigma < 0.8  # 12 px / √12 / √36 = 0.58 px


def test_focal_length_from_a_known_star_pair_is_exact():
    """(6.4)–(6.6): two stars through a 25 mm pinhole, their catalogue separation known: the
    focal length to 1e-12. The other root of the quadratic in f² is not always negative, as the
    thesis says: for the third pair, on opposite sides of the centre, it is a 0.28 mm camera, far
    shorter than the stars' 2.5 mm from the centre; f₊ is the focal length."""
    other = []
    for uv1, uv2 in (((0.5, 0.3), (-0.4, 0.6)), ((1.2, -0.8), (0.1, 0.2)), ((-2.0, 1.5), (2.2, -1.7))):
        b1, b2 = np.array([*uv1, F_MM]), np.array([*uv2, F_MM])
        theta = math.acos(b1 @ b2 / np.linalg.norm(b1) / np.linalg.norm(b2))
        assert focal_length_from_star_pair(uv1, uv2, theta) == pytest.approx(F_MM, rel=1e-12)
        c2 = math.cos(theta) ** 2
        dot = uv1[0] * uv2[0] + uv1[1] * uv2[1]
        a = 1 / c2 - 1
        b = 2 * dot / c2 - sum(t * t for t in (*uv1, *uv2))
        c = dot * dot / c2 - (uv1[0] ** 2 + uv1[1] ** 2) * (uv2[0] ** 2 + uv2[1] ** 2)
        other.append((-b - math.sqrt(b * b - 4 * a * c)) / (2 * a))
    assert other[0] < 0 and other[1] < 0 and math.sqrt(other[2]) == pytest.approx(0.277, abs=1e-3)


def test_focal_length_averaged_over_images_of_real_stars():
    """``Estf.mod``'s use: in 20 images, the two catalogue stars nearest the centre through thesis
    004's camera, centroids with 0.05 px of noise: the mean within its 2.5σ of 25 mm."""
    stars = load_hipparcos(epoch=2025.0, mag_limit=6.0)
    cam = Camera(width=752, height=582, fx=F_MM / 6.5e-3, fy=F_MM / 6.5e-3, cx=375.5, cy=290.5)
    rng = np.random.default_rng(3)
    uv1, uv2, theta = [], [], []
    while len(theta) < 20:
        A = attitude_from_radec_roll(rng.uniform(0, 2 * math.pi), math.asin(rng.uniform(-1, 1)), 0.0)
        rays = stars.vectors @ A.T
        near = np.argsort(-rays[:, 2])[:2]
        if rays[near[1], 2] < math.cos(math.radians(2.5)):
            continue  # the thesis wants both near the centre
        uv = cam.ray_to_pixel(rays[near])[0] + rng.normal(0, 0.05, (2, 2)) - [cam.cx, cam.cy]
        uv1.append(uv[0] * 6.5e-3)
        uv2.append(uv[1] * 6.5e-3)
        theta.append(math.acos(np.clip(stars.vectors[near[0]] @ stars.vectors[near[1]], -1, 1)))
    f, sigma = focal_length_from_star_pairs(np.array(uv1), np.array(uv2), np.array(theta))
    assert abs(f - F_MM) < 2.5 * sigma and sigma < 0.02  # mm


def _tilted_plane_radius(r_a: np.ndarray, phi: np.ndarray, theta: float, phi_max: float) -> np.ndarray:
    """The exact radius on a plane through (0, 0, f) tilted by ``theta`` toward ``phi_max``."""
    t1 = np.array([math.cos(theta) * math.cos(phi_max), math.cos(theta) * math.sin(phi_max), math.sin(theta)])
    t2 = np.array([-math.sin(phi_max), math.cos(phi_max), 0.0])
    n = np.cross(t1, t2)
    origin = np.array([0.0, 0.0, F_MM])
    d = np.stack([r_a / F_MM * np.cos(phi), r_a / F_MM * np.sin(phi), np.ones_like(r_a)], -1)
    p = d * ((origin @ n) / (d @ n))[:, None] - origin
    return np.hypot(p @ t1, p @ t2)


def test_tilt_model_against_a_tilted_plane_and_its_inverse():
    """(6.12)–(6.14) at App. F.8's tilt (0.733° toward 306°): along φ_max exactly a ray meeting a
    tilted plane; over the whole CCD within 0.0002 µm of it where the tilt moves points by up to
    4.8 µm; (6.13) inverts (6.12) with the lens term; the lens term is (F.9)'s."""
    theta, phi_max = math.radians(THESIS_004.theta_max_deg), math.radians(THESIS_004.phi_max_deg)
    tilt = TiltedSensor(F_MM, theta, phi_max)
    g = np.stack(np.meshgrid(np.linspace(-W_MM / 2, W_MM / 2, 41), np.linspace(-H_MM / 2, H_MM / 2, 31)),
                 -1).reshape(-1, 2)
    phi, r_a = np.arctan2(g[:, 1], g[:, 0]), np.hypot(g[:, 0], g[:, 1])
    exact = _tilted_plane_radius(r_a, phi, theta, phi_max)
    assert np.abs(tilt.measured_radius(r_a, phi) - exact).max() < 2e-7  # mm: 0.0002 µm
    assert 4.5e-3 < np.abs(exact - r_a).max() < 5e-3
    along = np.linspace(0.1, 3.0, 10)
    np.testing.assert_allclose(tilt.measured_radius(along, np.full(10, phi_max)),
                               _tilted_plane_radius(along, np.full(10, phi_max), theta, phi_max), rtol=1e-14)
    full = TiltedSensor(F_MM, theta, phi_max, THESIS_004.k_mm)
    assert full.lens(3.0) == pytest.approx(-9.6e-3)  # the reading's check: −9.6 µm at 3 mm
    np.testing.assert_allclose(full.correct(full.distort(g)), g, atol=1e-12)


def test_tilt_fitted_from_a_rotating_dot_pair():
    """§6.2.3.1: a centre and an edge dot 2.4 mm apart, 36 turns of 10°, separations with 0.05 px
    (0.33 µm) of noise: App. F.8's tilt back within 0.02° and 1.5°."""
    theta, phi_max = math.radians(THESIS_004.theta_max_deg), math.radians(THESIS_004.phi_max_deg)
    tilt = TiltedSensor(F_MM, theta, phi_max)
    phi = np.radians(np.arange(36) * 10.0)
    rng = np.random.default_rng(4)
    r12 = tilt.measured_radius(np.full(36, 2.4), phi) + rng.normal(0, 0.05 * 6.5e-3, 36)
    theta_fit, phi_fit, r_a = fit_tilt(phi, r12, F_MM)
    assert abs(math.degrees(theta_fit) - THESIS_004.theta_max_deg) < 0.02
    assert abs(math.degrees(phi_fit) - THESIS_004.phi_max_deg) < 1.5
    assert abs(r_a - 2.4) < 1e-3


def test_lens_polynomial_from_star_distances_is_the_radial_distortion():
    """§6.2.3.1's lens data (6.17) from stars seen through a Brown–Conrady lens with k1 only,
    a star at the centre of each image: (6.16)'s third-order fit is that lens (k₁, k₂ ≈ 0,
    k₃ = k1/f² in pixels, within 1 %: the polynomial is in the measured radius, the lens's in the
    true one)."""
    k1 = -0.05
    cam = Camera(width=752, height=582, fx=F_MM / 6.5e-3, fy=F_MM / 6.5e-3, cx=375.5, cy=290.5, k1=k1)
    stars = load_hipparcos(epoch=2025.0, mag_limit=7.5)
    rng = np.random.default_rng(5)
    rs, drs = [], []
    for _ in range(12):
        i = rng.integers(len(stars))
        z = stars.vectors[i]
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        A = np.vstack([x, np.cross(z, x), z])  # the star on the boresight
        rays = stars.vectors @ A.T
        uv, front = cam.ray_to_pixel(rays)
        # within the field (a k1 < 0 folds stars from near 90° back into the frame), not the centre star
        seen = np.flatnonzero(front & cam.in_frame(uv) & (rays[:, 2] > 0.95) & (rays[:, 2] < 1 - 1e-12))
        r, dr = lens_errors((0.0, 0.0), uv[seen] - [cam.cx, cam.cy], z, stars.vectors[seen], cam.fx)
        rs.append(r)
        drs.append(dr)
    k = fit_lens_polynomial(np.concatenate(rs), np.concatenate(drs))
    assert abs(k[0]) < 1e-6 and abs(k[1]) < 1e-8
    assert k[2] == pytest.approx(k1 / cam.fx ** 2, rel=1e-2)


def test_statistics_of_stars_with_known_noise():
    """§6.3's statistics on 20 images of catalogue stars seen with 0.15 px of noise per axis:
    σ_pos = σ_dist/√2 is the noise's angle (within 5 %); magnitudes with 0.2 mag of scatter and
    two 2-magnitude blunders: σ_mag 0.2 (within 10 %), the two left out as the thesis's were."""
    cam = Camera.from_fov(752, 582, 11.17)
    stars = load_hipparcos(epoch=2025.0, mag_limit=6.5)
    rng = np.random.default_rng(6)
    images = []
    for _ in range(20):
        A = attitude_from_radec_roll(rng.uniform(0, 2 * math.pi), math.asin(rng.uniform(-1, 1)), 0.0)
        rays = stars.vectors @ A.T
        uv, front = cam.ray_to_pixel(rays)
        seen = np.flatnonzero(front & (rays[:, 2] > 0.9) & cam.in_frame(uv))
        images.append((cam.pixel_to_ray(uv[seen] + rng.normal(0, 0.15, (len(seen), 2))), rays[seen]))
    d = distance_statistics(images)
    assert d.pairs == sum(len(b) * (len(b) - 1) // 2 for b, _ in images) and d.images == 20
    assert d.sigma_pos_rad / (0.15 * cam.plate_scale_rad) == pytest.approx(1.0, abs=0.05)
    mag = rng.uniform(2.5, 6.0, 354)
    flux = 10 ** (-0.4 * (mag - 20.0) + rng.normal(0, 0.2 / 2.5, 354))
    flux[:2] *= 10 ** (-0.4 * 2.0)  # two stars 2 magnitudes too faint
    m = magnitude_statistics(flux, mag)
    assert m.left_out == 2 and m.stars == 352
    assert m.sigma_mag == pytest.approx(0.2, rel=0.1) and m.zero_point == pytest.approx(20.0, abs=0.05)
