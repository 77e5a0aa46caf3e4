"""skyfix's shared kernels (``skyfix._kernels``) and the fits built on them, against plain
numpy references of the same formulas written here (the package keeps one copy of each formula;
these are the second, independent one), on cameras with every distortion term and on awkward
attitudes (poles, 180°).
"""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skyfix import attitude, calibrate, final_fit, pipeline
from skyfix._kernels import lens, rotation
from skyfix.camera import Camera

CAMERAS = [
    Camera.from_fov(1280, 960, 15.0),
    Camera(width=752, height=582, fx=3846.0, fy=4000.0, cx=375.5, cy=290.5, skew=0.7, k1=-0.3, k2=0.1,
           k3=0.02, p1=1e-3, p2=-2e-3),
    Camera(width=640, height=480, fx=500.0, fy=500.0, cx=330.0, cy=230.0, k1=0.2),
]


# --- numpy references ---------------------------------------------------------------------------

def _np_distort(camera, xn, yn):
    r2 = xn * xn + yn * yn
    radial = 1.0 + r2 * (camera.k1 + r2 * (camera.k2 + r2 * camera.k3))
    xd = xn * radial + 2.0 * camera.p1 * xn * yn + camera.p2 * (r2 + 2.0 * xn * xn)
    yd = yn * radial + camera.p1 * (r2 + 2.0 * yn * yn) + 2.0 * camera.p2 * xn * yn
    return xd, yd


def _np_pixel_to_ray(camera, xy):
    yd = (xy[:, 1] - camera.cy) / camera.fy
    xd = (xy[:, 0] - camera.cx - camera.skew * yd) / camera.fx
    xn, yn = xd.copy(), yd.copy()
    for _ in range(50):
        r2 = xn * xn + yn * yn
        radial = 1.0 + r2 * (camera.k1 + r2 * (camera.k2 + r2 * camera.k3))
        dx = 2.0 * camera.p1 * xn * yn + camera.p2 * (r2 + 2.0 * xn * xn)
        dy = camera.p1 * (r2 + 2.0 * yn * yn) + 2.0 * camera.p2 * xn * yn
        xn_new, yn_new = (xd - dx) / radial, (yd - dy) / radial
        step = np.max(np.abs(xn_new - xn) + np.abs(yn_new - yn), initial=0.0)
        xn, yn = xn_new, yn_new
        if step < 1e-5 / max(camera.fx, camera.fy):
            break
    v = np.column_stack([xn, yn, np.ones_like(xn)])
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _np_ray_to_pixel(camera, rays):
    xd, yd = _np_distort(camera, rays[:, 0] / rays[:, 2], rays[:, 1] / rays[:, 2])
    return np.column_stack([camera.fx * xd + camera.skew * yd + camera.cx, camera.fy * yd + camera.cy])


def _np_pointing(A):
    """RA, Dec, roll (rad) and the quaternion (w ≥ 0) by the definitions, with scipy."""
    z = A[2] / np.linalg.norm(A[2])
    ra, dec = math.atan2(z[1], z[0]) % (2 * math.pi), math.asin(max(-1.0, min(1.0, z[2])))
    east = np.array([-math.sin(ra), math.cos(ra), 0.0])
    north = np.array([-math.sin(dec) * math.cos(ra), -math.sin(dec) * math.sin(ra), math.cos(dec)])
    if abs(math.cos(dec)) < 1e-12:
        north = np.array([-np.sign(dec) * math.cos(ra), -np.sign(dec) * math.sin(ra), 0.0])
    roll = math.atan2(-A[1] @ east, -A[1] @ north) % (2 * math.pi)
    q = Rotation.from_matrix(A).as_quat()
    return np.r_[ra, dec, roll, q if q[3] >= 0 else -q]


def _rotvec_matrix(w: np.ndarray):
    """Rotation matrix of a rotation vector (Rodrigues); scipy's Rotation costs 50 µs a call."""
    theta = math.sqrt(float(w @ w))
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if theta < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + (math.sin(theta) / theta) * K + ((1.0 - math.cos(theta)) / theta**2) * (K @ K)


def _unpack(camera, params, p: np.ndarray):
    """Rotation (3, 3) and camera changes for the parameter vector ``p`` of ``params``; each
    parameter is scaled so that a unit step moves the frame's corner by about a focal length."""
    R = _rotvec_matrix(p[:3])
    rmax = math.hypot(camera.width, camera.height) / 2.0 / camera.fx
    ch: dict[str, float] = {}
    i = 3
    for name in params:
        if name == "f":
            ch["fx"] = camera.fx * (1.0 + p[i])
            ch["fy"] = camera.fy * (1.0 + p[i])
        elif name == "aspect":
            ch["fy"] = ch.get("fy", camera.fy) * (1.0 + p[i])
        elif name == "principal_point":
            ch["cx"], ch["cy"] = camera.cx + p[i] * camera.fx, camera.cy + p[i + 1] * camera.fx
        elif name == "k1":
            ch["k1"] = camera.k1 + p[i] / rmax**2
        elif name == "k2":
            ch["k2"] = camera.k2 + p[i] / rmax**4
        elif name == "tangential":
            ch["p1"], ch["p2"] = camera.p1 + p[i] / rmax, camera.p2 + p[i + 1] / rmax
        i += calibrate.PARAMETERS[name]
    return R, ch


def _residuals_batch(camera, params, ps: np.ndarray, rays0: np.ndarray,
                     xy: np.ndarray):
    """Residuals (K, 2N) for K parameter vectors ``ps`` (K, P), projected in one batch (numpy:
    the reference of :func:`_residuals_kernel`, which the fits use)."""
    rots, cams = [], []
    for p in ps:
        R, ch = _unpack(camera, params, p)
        rots.append(R)
        cams.append([ch.get(k, getattr(camera, k)) for k in lens.CAMERA_NUMBERS])
    fx, fy, cx, cy, skew, k1, k2, k3, p1, p2, *_ = (c[:, None] for c in np.array(cams).T)
    rays = np.einsum("kij,nj->kni", np.array(rots), rays0)
    xn = rays[..., 0] / rays[..., 2]
    yn = rays[..., 1] / rays[..., 2]
    r2 = xn * xn + yn * yn
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
    yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
    u = fx * xd + skew * yd + cx - xy[:, 0]
    v = fy * yd + cy - xy[:, 1]
    return np.stack([u, v], axis=-1).reshape(len(ps), -1)


def _jacobian_at_start(camera, params, rays0: np.ndarray):
    """Analytic Jacobian (2N, P) of the residuals at ``p = 0`` (the starting camera and
    attitude), for the parameter scaling of :func:`_unpack`: no projection per parameter."""
    X, Y, Z = rays0[:, 0], rays0[:, 1], rays0[:, 2]
    xn, yn = X / Z, Y / Z
    r2 = xn * xn + yn * yn
    k1, k2, k3, p1, p2 = camera.k1, camera.k2, camera.k3, camera.p1, camera.p2
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
    xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
    yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
    # d(xd, yd)/d(xn, yn)
    dxx = radial + 2.0 * xn * xn * drad + 2.0 * p1 * yn + 6.0 * p2 * xn
    dxy = 2.0 * xn * yn * drad + 2.0 * p1 * xn + 2.0 * p2 * yn
    dyx = 2.0 * xn * yn * drad + 2.0 * p1 * xn + 2.0 * p2 * yn
    dyy = radial + 2.0 * yn * yn * drad + 6.0 * p1 * yn + 2.0 * p2 * xn
    fx, fy, s = camera.fx, camera.fy, camera.skew

    def pixel(dxd: np.ndarray, dyd: np.ndarray):
        return np.stack([fx * dxd + s * dyd, fy * dyd], axis=1).ravel()

    def through_lens(dxn: np.ndarray, dyn: np.ndarray):
        return pixel(dxx * dxn + dxy * dyn, dyx * dxn + dyy * dyn)

    cols = []
    # Small rotation ω of the camera frame: δray = ω × ray.
    for w in np.eye(3):
        dX = w[1] * Z - w[2] * Y
        dY = w[2] * X - w[0] * Z
        dZ = w[0] * Y - w[1] * X
        cols.append(through_lens((dX - xn * dZ) / Z, (dY - yn * dZ) / Z))
    rmax = math.hypot(camera.width, camera.height) / 2.0 / camera.fx
    zero = np.zeros_like(xn)
    for name in params:
        if name == "f":
            cols.append(np.stack([fx * xd + s * yd, fy * yd], axis=1).ravel())
        elif name == "aspect":
            cols.append(np.stack([zero, fy * yd], axis=1).ravel())
        elif name == "principal_point":
            cols.append(np.stack([zero + fx, zero], axis=1).ravel())
            cols.append(np.stack([zero, zero + fx], axis=1).ravel())
        elif name == "k1":
            cols.append(pixel(xn * r2, yn * r2) / rmax**2)
        elif name == "k2":
            cols.append(pixel(xn * r2 * r2, yn * r2 * r2) / rmax**4)
        elif name == "tangential":
            cols.append(pixel(2.0 * xn * yn, r2 + 2.0 * yn * yn) / rmax)
            cols.append(pixel(r2 + 2.0 * xn * xn, 2.0 * xn * yn) / rmax)
    return np.stack(cols, axis=1)


def _field(camera, rng, n=60):
    """Pixels, their catalogue vectors and an attitude with ~0.5 px of noise."""
    A = Rotation.random(random_state=rng).as_matrix()
    xy = rng.uniform([0, 0], [camera.width - 1, camera.height - 1], (n, 2))
    r = camera.pixel_to_ray(xy) @ A  # b = A r
    return xy + rng.normal(0, 0.5, xy.shape), r, A


@pytest.mark.parametrize("camera", CAMERAS)
def test_lens_equals_numpy(camera):
    rng = np.random.default_rng(2)
    xy = rng.uniform([0, 0], [camera.width - 1, camera.height - 1], (200, 2))
    ref = _np_pixel_to_ray(camera, xy)
    assert np.abs(camera.pixel_to_ray(xy) - ref).max() < 1e-15
    assert np.abs(camera.ray_to_pixel(ref)[0] - _np_ray_to_pixel(camera, ref)).max() < 1e-9
    assert np.abs(camera.ray_to_pixel(ref)[0] - xy).max() < 1e-4  # the inversion's 1e-5 px, summed
    xn, yn = xy[:, 0] / 3e3, xy[:, 1] / 3e3
    np.testing.assert_array_equal(np.array(camera.distort(xn, yn)), np.array(_np_distort(camera, xn, yn)))
    uv, front = camera.ray_to_pixel(np.array([[0.0, 0.0, -1.0], [0.1, 0.0, 1.0]]))
    assert front.tolist() == [False, True]


@pytest.mark.parametrize("camera", CAMERAS)
def test_rays_equal_camera_pixel_to_ray(camera):
    rng = np.random.default_rng(3)
    xy, r, A = _field(camera, rng)
    b, keep, n_kept = final_fit._rays_and_inliers(xy, r, A, lens.camera_numbers(camera))
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
    J = _jacobian_at_start(camera, union, rays0)
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
    inv, ok = rotation.spd_inverse(M)
    assert ok and np.abs(inv @ M - np.eye(7)).max() < 1e-9
    assert not rotation.spd_inverse(np.diag([1.0, -1.0, 1.0]))[1]


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


def test_pointing_equals_numpy():
    for A in _attitudes(np.random.default_rng(7)):
        out = rotation.pointing(np.ascontiguousarray(A))
        ref = _np_pointing(A)
        np.testing.assert_allclose(out[:3], ref[:3], rtol=0, atol=1e-14)
        np.testing.assert_allclose(out[3:], ref[3:], rtol=0, atol=1e-15)


def test_solution_numbers_equal_numpy():
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
    pointing, table, rmse = pipeline.solution_numbers(A, xy, idx, v, mag, resid)
    ref = rotation.pointing(A)
    np.testing.assert_array_equal(pointing, np.r_[np.degrees(ref[:3]), ref[3:]])
    ra_ref = np.arctan2(v[:, 1], v[:, 0]) % (2 * np.pi)
    dec_ref = np.arcsin(v[:, 2])
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
    ref = _residuals_batch(camera, params, ps, rays0, xy)
    got = calibrate._residuals_fast(camera, params, ps, rays0, xy)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-11)
    assert np.abs(ref[2:]).max() > 1.0  # the steps do move the stars
