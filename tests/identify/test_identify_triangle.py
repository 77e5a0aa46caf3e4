"""The triangle method (skyfix.identify.methods.triangle) and the default solve's fallback to it on
sparse frames: three stars identified when their triangle is unique, refused when not."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
from skyfix.analysis.truth import judge_error
from skyfix.attitude import attitude_error
from skyfix.camera import Camera
from skyfix.catalog import load_hipparcos
from skyfix.errors import InputError
from skyfix.geometry import attitude_from_radec_roll
from skyfix.identify import identify
from skyfix.pipeline import solve_centroids

W, H = 1280, 960
ORION = (27989, 24436, 25336)  # Betelgeuse, Rigel, Bellatrix


@pytest.fixture(scope="module")
def catalog():
    return load_hipparcos()


def _wrong(A_true: np.ndarray, A: np.ndarray, camera: Camera) -> bool:
    return judge_error(attitude_error(A_true, A), math.degrees(camera.plate_scale_rad) * 3600).wrong


def _orion(catalog, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    rows = np.array([int(np.flatnonzero(catalog.ids == hip)[0]) for hip in ORION])
    v = catalog.vectors[rows]
    c = v.mean(axis=0)
    c /= np.linalg.norm(c)
    A = attitude_from_radec_roll(math.atan2(c[1], c[0]), math.asin(c[2]), math.radians(10.0))
    xy, front = camera.ray_to_pixel(v @ A.T)
    assert front.all() and camera.in_frame(xy).all()
    return xy, A


def test_known_triangle_is_identified(database, catalog):
    cam = Camera.from_fov(W, H, 30.0)
    xy, A = _orion(catalog, cam)
    ident = identify(xy, W, H, method="triangle", camera=cam, database=database)
    assert ident.success, ident.reason
    found = dict(zip(ident.star_index.tolist(), ident.catalog_ids.tolist(), strict=True))
    assert found == dict(enumerate(ORION))
    assert not _wrong(A, ident.A_icrs_to_cam, cam)
    assert ident.prob_false < 1e-4 and ident.method == "triangle"


def test_mirrored_triangle_is_rejected(database, catalog):
    cam = Camera.from_fov(W, H, 30.0)
    xy, _ = _orion(catalog, cam)
    mirrored = xy.copy()
    mirrored[:, 0] = W - 1 - mirrored[:, 0]
    ident = identify(mirrored, W, H, method="triangle", camera=cam, database=database)
    assert not ident.success


def test_shape_only_triangle_is_ambiguous(database, catalog):
    """Three stars and a FOV known to 10 % only: only the triangle's shape counts, and over a
    hundred catalogue triangles have it within 1 px. With the brightness test off (no star is
    20 mag brighter than another) the method, accepting any chance at all, still refuses to
    choose between attitudes ("ambiguous"); with it on, its rivals are refuted by bright stars
    beside them but the chance left (8e-4) is above the threshold; with the calibrated camera
    the same three stars are unique."""
    cam = Camera.from_fov(W, H, 30.0)
    A = random_attitudes(10, 3)[2]
    f = synthetic_centroids(cam, A, catalog, mag_limit=8.0, sigma_px=0.0, rng=2)
    loose = identify(f.xy[:3], W, H, method="triangle", fov_deg=30.0, database=database,
                     centroid_sigma_px=1.0, lone_prob_threshold=1.0, missing_margin=20.0)
    assert not loose.success and loose.reason.startswith("ambiguous"), loose.reason
    shape = identify(f.xy[:3], W, H, method="triangle", fov_deg=30.0, database=database,
                     centroid_sigma_px=1.0)
    assert not shape.success and shape.reason.startswith("no triangle unique enough"), shape.reason
    known = identify(f.xy[:3], W, H, method="triangle", camera=cam, database=database)
    assert known.success and not _wrong(A, known.A_icrs_to_cam, cam)


def test_default_solve_identifies_three_star_fields(database, catalog):
    """Thesis 000's case: a 30° camera seeing only its three brightest stars, noise-free. The
    default method cannot (4-star patterns); the fallback to triangles identifies all 40. Their
    residuals (here 0) cannot bound their own noise, so σ is the final fit's floor
    (skyfix.attitude.CENTROID_NOISE_FLOOR_PX, 0.02 px) and the chance of an error beyond 84″ is
    taken from Student's tail (ν = 3): at most 5e-4 for these 40, all solved (at a 0.05 px
    floor five of them were 0.1–0.7 % and failed "attitude too uncertain"). With the centroid
    noise stated (0.1 px, a scaled-inverse-χ² prior of 10 dof:
    skyfix.identify.accept.noise_posterior) all 40 solve too, by the default solve and by the
    triangle method named."""
    cam = Camera.from_fov(W, H, 30.0)
    solved = {"residuals": 0, "stated": 0, "triangle": 0}
    runs = {"residuals": {}, "stated": {"centroid_sigma_px": 0.1},
            "triangle": {"centroid_sigma_px": 0.1, "identify_method": "triangle"}}
    for i, A in enumerate(random_attitudes(40, 11)):
        f = synthetic_centroids(cam, A, catalog, mag_limit=8.0, sigma_px=0.0, rng=i)
        for key, opts in runs.items():
            sol = solve_centroids(f.xy[:3], W, H, camera=cam, database=database, **opts)
            if sol.solved:
                solved[key] += 1
                assert not _wrong(A, sol.A_icrs_to_cam, cam), (key, i)
                assert sol.method == "triangle"
    assert solved["residuals"] >= 39, solved  # 40 measured
    assert solved["stated"] >= 39 and solved["triangle"] >= 39, solved  # 40 and 40 measured


def test_sparse_noisy_fields_with_false_stars_are_never_wrong(database, catalog):
    """Four or five centroids, one or two of them false, 0.5 px noise: whatever is solved is
    right (the sparse chance test and the final fit's precision rule together)."""
    cam = Camera.from_fov(W, H, 30.0)
    solved = 0
    for i, A in enumerate(random_attitudes(150, 23)):
        n_false = 1 + i % 2
        f = synthetic_centroids(cam, A, catalog, mag_limit=8.0, sigma_px=0.5, n_false=n_false, rng=1000 + i)
        keep = np.concatenate([np.flatnonzero(~f.is_false)[:3], np.flatnonzero(f.is_false)])
        keep.sort()
        sol = solve_centroids(f.xy[keep], W, H, camera=cam, database=database)
        if sol.solved:
            solved += 1
            assert not _wrong(A, sol.A_icrs_to_cam, cam), i
    print(f"sparse noisy fields solved: {solved}/150")
    # 1 measured: a lone noisy triangle at 30° is rarely unique (module text), and when it is,
    # three stars at 42″ each rarely pin the boresight within 84″ with a 1e-3 chance of error
    # under Student's tail (ν = 3). The point of this test is the 0 wrong above.
    assert solved >= 1, solved


def test_rich_fields_with_fov_only(database, catalog):
    cam = Camera.from_fov(W, H, 15.0)
    solved = 0
    for i, A in enumerate(random_attitudes(30, 7)):
        f = synthetic_centroids(cam, A, catalog, mag_limit=7.0, sigma_px=0.5, n_false=2, rng=i)
        ident = identify(f.xy, W, H, method="triangle", fov_deg=15.0, database=database)
        if ident.success:
            solved += 1
            assert not _wrong(A, ident.A_icrs_to_cam, cam)
    assert solved >= 29


def test_bad_input(database):
    with pytest.raises(InputError, match="triangle_stars must be 3–12"):
        identify(np.zeros((5, 2)), W, H, method="triangle", fov_deg=15.0, database=database, triangle_stars=2)
    no_scale = identify(np.random.default_rng(0).uniform(0, 900, (6, 2)), W, H, method="triangle",
                        database=database)
    assert not no_scale.success and "needs a field of view or a camera" in no_scale.reason
    two = identify(np.array([[1.0, 2.0], [300.0, 400.0]]), W, H, method="triangle", fov_deg=15.0,
                   database=database)
    assert not two.success and two.reason.startswith("too few stars")


def test_a_false_star_in_a_verified_triangle_is_caught():
    """The study's field that came back wrong (15°, 10 false stars, field 32): a triangle of two
    true stars and a false one, verified by eight true stars around it, 240″ and 1.7° off with
    P 2.5e-9. Each triangle star must now fit the attitude of the others without it."""
    from skyfix.analysis.identification_jobs import CONDITIONS
    from skyfix.analysis.identification_study import run_block

    (record,) = run_block(15.0, CONDITIONS[5], range(32, 33), ["triangle"], seed=0)
    assert CONDITIONS[5].n_false == 10
    assert not record.wrong, record


def test_sparse_frame_of_a_preset_size_solves_through_its_camera(catalog):
    """No camera, no FOV: a 752×480 frame of four stars is tried through the MT9V022 preset's
    camera (the only seed camera of that size) and solved with it; the same frames from a 25°
    lens on a sensor of that size are never wrong (the preset's scale is 19 % off: a random
    triangle to it)."""
    from skyfix.camera import camera_from_preset
    from skyfix.identify.lost import preset_cameras

    assert list(preset_cameras(752, 480)) == ["mt9v022"] and not preset_cameras(1000, 1000)
    preset = camera_from_preset("mt9v022")
    other = Camera.from_fov(752, 480, 25.0)
    solved = {"mt9v022": 0, "25°": 0}
    for i, A in enumerate(random_attitudes(30, 41)):
        for key, cam in (("mt9v022", preset), ("25°", other)):
            f = synthetic_centroids(cam, A, catalog, mag_limit=7.0, sigma_px=0.2, rng=i)
            if (~f.is_false).sum() < 4:
                continue
            sol = solve_centroids(f.xy[:4], 752, 480)
            if sol.solved:
                solved[key] += 1
                assert not _wrong(A, sol.A_icrs_to_cam, cam), (key, i)
                if key == "mt9v022":
                    assert sol.method == "triangle" and sol.camera == preset
    assert solved["mt9v022"] >= 13, solved  # 16 measured (0 of the 25° frames)
