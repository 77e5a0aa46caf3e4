"""The final fit's numba kernels against the plain numpy arithmetic they replace.

Each kernel does in one call what a chain of small numpy operations did (and what the public
functions of camera, geometry and calibrate still define); these tests hold them equal to
rounding, on cameras with every distortion term and on awkward attitudes (poles, 180°).
"""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skyfix import attitude, calibrate, final_fit, pipeline
from skyfix.camera import Camera
from skyfix.geometry import quaternion_from_attitude, radec_roll_from_attitude, vector_to_radec

CAMERAS = [
    Camera.from_fov(1280, 960, 15.0),
    Camera(width=752, height=582, fx=3846.0, fy=4000.0, cx=375.5, cy=290.5, skew=0.7, k1=-0.3, k2=0.1,
           k3=0.02, p1=1e-3, p2=-2e-3),
    Camera(width=640, height=480, fx=500.0, fy=500.0, cx=330.0, cy=230.0, k1=0.2),
]


def _field(camera, rng, n=60):
    """Pixels, their catalogue vectors and an attitude with ~0.5 px of noise."""
    A = Rotation.random(random_state=rng).as_matrix()
    xy = rng.uniform([0, 0], [camera.width - 1, camera.height - 1], (n, 2))
    r = camera.pixel_to_ray(xy) @ A  # b = A r
    return xy + rng.normal(0, 0.5, xy.shape), r, A


@pytest.mark.parametrize("camera", CAMERAS)
def test_rays_equal_camera_pixel_to_ray(camera):
    rng = np.random.default_rng(3)
    xy, r, A = _field(camera, rng)
    b, keep, n_kept = final_fit._rays_and_inliers(xy, r, A, final_fit._camera_array(camera))
    assert np.abs(b - camera.pixel_to_ray(xy)).max() < 1e-15
    ref = final_fit.inliers(final_fit.angles(camera.pixel_to_ray(xy), r, A), 0.1 * camera.plate_scale_rad)
    assert np.array_equal(keep, ref) and n_kept == ref.sum() > 30


def test_inliers_drop_outliers_keep_half():
    resid = np.r_[np.full(20, 1.0), 50.0, 60.0]
    assert final_fit.inliers(resid, 0.1).sum() == 20
    assert final_fit.inliers(np.array([1.0, 1.0, 100.0]), 0.1).all()  # three stars are always kept
    assert final_fit.inliers(np.array([1.0, 2.0, 3.0, 50.0]), 20.0).all()  # σ floored at 20


def _scores_numpy(xy, r, camera, A, models):
    """The model scores with numpy's J (calibrate's analytic Jacobian) and LU inverses."""
    union = tuple(dict.fromkeys(p for m in models for p in m))
    rays0 = r @ A.T
    res = calibrate._residuals(camera, union, np.zeros(3 + sum(calibrate.PARAMETERS[p] for p in union)),
                               rays0, xy)
    J = calibrate._jacobian_at_start(camera, union, rays0)
    columns, i = {}, 3
    for name in union:
        columns[name] = list(range(i, i + calibrate.PARAMETERS[name]))
        i += calibrate.PARAMETERS[name]
    out = []
    n = res.size
    for m in models:
        cols = [0, 1, 2] + [c for name in m for c in columns[name]]
        if n <= len(cols) or (len(xy) < 2 * len(cols) and out):
            continue
        inv = calibrate._inverse(J[:, cols].T @ J[:, cols])
        g = J[:, cols].T @ res
        rss = res @ res - g @ inv @ g
        bic = n * math.log(rss / n) + len(cols) * math.log(n)
        out.append((m, bic, rss, rss / (n - len(cols)) * inv[:3, :3]))
    return out


@pytest.mark.parametrize("camera", CAMERAS)
@pytest.mark.parametrize("n_stars", [60, 7])
def test_model_scores_equal_numpy(camera, n_stars):
    rng = np.random.default_rng(4)
    xy, r, A = _field(camera, rng, n_stars)
    A = Rotation.from_rotvec([2e-4, -1e-4, 3e-4]).as_matrix() @ A  # start off the optimum
    models = calibrate.MODEL_LADDER + (("f", "principal_point"), ("f", "tangential", "k1"))
    got = calibrate.score_camera_models(xy, r, camera, A, models)
    ref = _scores_numpy(xy, r, camera, A, models)
    assert [s.params for s in got] == [m for m, *_ in ref]
    assert len(got) == (len(models) if n_stars == 60 else 1)
    for s, (_, bic, rss, cov) in zip(got, ref, strict=True):
        assert s.bic == pytest.approx(bic, rel=1e-9, abs=1e-6)
        assert s.rss_px2 == pytest.approx(rss, rel=1e-8)
        np.testing.assert_allclose(s.attitude_covariance_rad2, cov, rtol=1e-7, atol=1e-9 * np.abs(cov).max())


def test_singular_blocks_fall_back_to_numpy():
    # Every star on the optical axis: the focal-length column is zero, each block singular.
    camera = CAMERAS[0]
    rng = np.random.default_rng(10)
    xy = np.array([camera.cx, camera.cy]) + rng.normal(0, 0.3, (12, 2))
    r = np.tile([0.0, 0.0, 1.0], (12, 1))
    got = calibrate.score_camera_models(xy, r, camera, np.eye(3))
    ref = _scores_numpy(xy, r, camera, np.eye(3), calibrate.MODEL_LADDER)
    assert [s.params for s in got] == [m for m, *_ in ref]
    for s, (_, bic, rss, cov) in zip(got, ref, strict=True):
        assert s.bic == pytest.approx(bic, rel=1e-9)
        assert s.rss_px2 == pytest.approx(rss, rel=1e-9)
        np.testing.assert_allclose(s.attitude_covariance_rad2, cov, rtol=1e-7, atol=1e-12)


def test_spd_inverse_and_its_refusal():
    rng = np.random.default_rng(5)
    M = rng.normal(size=(7, 7))
    M = M @ M.T + 1e-3 * np.eye(7)
    inv, ok = calibrate._spd_inverse(M)
    assert ok and np.abs(inv @ M - np.eye(7)).max() < 1e-9
    assert not calibrate._spd_inverse(np.diag([1.0, -1.0, 1.0]))[1]


@pytest.mark.parametrize("fov_deg", [0.5, 15.0, 90.0])
@pytest.mark.parametrize("n", [3, 50])
def test_polar_newton_equals_svd(fov_deg, n):
    rng = np.random.default_rng(6)
    for _ in range(20):
        A = Rotation.random(random_state=rng).as_matrix()
        half = math.radians(fov_deg) / 2
        v = np.column_stack([rng.uniform(-half, half, n), rng.uniform(-half, half, n), np.ones(n)])
        b = v / np.linalg.norm(v, axis=1, keepdims=True)
        r = b @ A
        b = b + rng.normal(0, 1e-5, b.shape)
        w = rng.uniform(0.1, 1.0, n)
        bb, rr, ww = attitude._prepare(b, r, w)
        B = (bb * ww[:, None]).T @ rr
        U, _, Vt = np.linalg.svd(B)
        ref = U @ np.diag([1.0, 1.0, np.linalg.det(U) * np.linalg.det(Vt)]) @ Vt
        got = attitude.svd_attitude(b, r, w)
        tol = 1e-10 if fov_deg < 1 else 1e-12  # rounding over the field's conditioning
        assert np.linalg.norm(Rotation.from_matrix(got @ ref.T).as_rotvec()) < tol
        assert np.linalg.norm(Rotation.from_matrix(got @ A.T).as_rotvec()) < 1e-2


def test_polar_newton_refuses_improper_and_singular():
    assert attitude._polar_newton(np.diag([1.0, 1.0, -1.0])).shape == (0, 3)
    assert attitude._polar_newton(np.diag([1.0, 1.0, 0.0])).shape == (0, 3)
    R = Rotation.from_rotvec([3.1, 0.2, -0.1]).as_matrix()
    assert np.abs(attitude._polar_newton(R @ np.diag([1.0, 0.3, 0.01])) - R).max() < 1e-12


def _attitudes(rng):
    yield from Rotation.random(50, random_state=rng).as_matrix()
    for dec in (math.pi / 2, -math.pi / 2):  # boresight at the poles
        z = np.array([0.0, 0.0, math.copysign(1.0, dec)])
        x = np.array([math.cos(0.3), math.sin(0.3), 0.0])
        yield np.vstack([x, np.cross(z, x), z])
    yield np.diag([1.0, -1.0, -1.0])  # 180° rotations: Shepperd's other branches
    yield np.diag([-1.0, 1.0, -1.0])
    yield np.diag([-1.0, -1.0, 1.0])
    yield np.eye(3)


def test_pointing_equals_geometry():
    for A in _attitudes(np.random.default_rng(7)):
        out = pipeline._pointing(np.ascontiguousarray(A))
        ra, dec, roll = radec_roll_from_attitude(A)
        np.testing.assert_allclose(out[:3], np.degrees([ra, dec, roll]), rtol=0, atol=1e-12)
        q = quaternion_from_attitude(A)
        np.testing.assert_allclose(out[3:], q, rtol=0, atol=1e-15)


def test_solution_numbers_equal_geometry():
    rng = np.random.default_rng(8)
    v = rng.normal(size=(40, 3))
    v[0] = [0.0, 0.0, 1.0]
    v[1] = [-1.0, -0.0, 0.0]
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    resid = rng.uniform(0, 1e-4, 40)
    xy = rng.uniform(0, 1000, (60, 2))
    idx = rng.permutation(60)[:40]
    mag = rng.uniform(2, 8, 40)
    A = Rotation.random(random_state=rng).as_matrix()
    pointing, table, rmse = pipeline._solution_numbers(A, xy, idx, v, mag, resid)
    np.testing.assert_array_equal(pointing, pipeline._pointing(A))
    ra_ref, dec_ref = vector_to_radec(v)
    np.testing.assert_array_equal(table[:2], xy[idx].T)
    np.testing.assert_allclose(table[2], np.degrees(ra_ref), rtol=0, atol=1e-12)
    np.testing.assert_allclose(table[3], np.degrees(dec_ref), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(table[4], mag)
    np.testing.assert_allclose(table[5], resid / math.radians(1 / 3600), rtol=1e-15)
    assert rmse == pytest.approx(math.sqrt(np.mean(resid**2)), rel=1e-14)
    assert np.all((table[2] >= 0) & (table[2] < 360))


def test_covariance_equals_numpy():
    rng = np.random.default_rng(9)
    b = rng.normal([0, 0, 1], 0.1, (30, 3))
    sig = rng.uniform(1e-5, 2e-5, 30)
    bn = b / np.linalg.norm(b, axis=1, keepdims=True)
    w = 1 / sig**2
    P = np.linalg.inv(w.sum() * np.eye(3) - (bn * w[:, None]).T @ bn)
    np.testing.assert_allclose(attitude.attitude_covariance(np.eye(3), b, sig), P, rtol=1e-9)
    with pytest.raises(ValueError, match="unbounded"):
        attitude.attitude_covariance(np.eye(3), np.tile([0.0, 0.0, 1.0], (5, 1)), 1e-5)


@pytest.mark.parametrize("params", [("f",), ("f", "k1"), ("aspect", "f", "k2"),
                                    ("f", "aspect", "principal_point", "k1", "k2", "tangential")])
def test_fit_residuals_equal_numpy(params):
    camera = CAMERAS[1]
    rng = np.random.default_rng(11)
    xy = rng.uniform(0, 580, (50, 2))
    rays0 = camera.pixel_to_ray(xy)
    ps = rng.normal(0, 1e-3, (5, 3 + sum(calibrate.PARAMETERS[p] for p in params)))
    ps[0] = 0.0
    ps[1, :3] = 1e-14  # below Rodrigues' small-angle switch
    ref = calibrate._residuals_batch(camera, params, ps, rays0, xy)
    got = calibrate._residuals_fast(camera, params, ps, rays0, xy)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-11)
    assert np.abs(ref[2:]).max() > 1.0  # the steps do move the stars
