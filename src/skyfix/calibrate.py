"""Camera calibration from star fields: fit intrinsics and distortion to matched stars.

A solved image gives pixel positions ``xy`` of stars and their catalogue directions ``r``;
the camera model and the attitude are fitted together by least squares on the reprojection
error in pixels. Which parameters are free is a choice of model; :func:`select_camera_model`
picks the one the data support (Bayesian information criterion), so a field of 20 stars does
not fit a 10-parameter lens and a strongly distorted lens is not forced into a pinhole.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np

from skyfix.camera import Camera

__all__ = ["CameraFit", "CameraPrior", "ModelScore", "PriorFit", "fit_camera", "fit_camera_with_prior",
           "frame_at_pixel", "frame_rotation_at_pixel",
           "score_camera_models", "select_camera_model", "PRIOR_PARAMETERS",
           "PARAMETERS", "MODEL_LADDER"]

# Free parameters a fit may take, and how many numbers each is.
PARAMETERS = {"f": 1, "aspect": 1, "principal_point": 2, "k1": 1, "k2": 1, "tangential": 2}

# Models tried by select_camera_model, simplest first. The principal point and tangential
# terms are left out: from one field they trade off against the pointing itself, so they
# belong to a calibration over many fields, not to a per-image fit.
MODEL_LADDER: tuple[tuple[str, ...], ...] = (
    ("f",),
    ("f", "k1"),
    ("f", "aspect"),
    ("f", "aspect", "k1"),
    ("f", "k1", "k2"),
    ("f", "aspect", "k1", "k2"),
)


@dataclass(frozen=True)
class CameraFit:
    """A fitted camera and attitude, with the fit's quality.

    Attributes
    ----------
    camera : Camera — the fitted model.
    A_icrs_to_cam : (3, 3) — the fitted attitude.
    params : tuple of str — the free parameters.
    rss_px2 : float — sum of squared reprojection residuals, px².
    n_stars : int
    residuals_px : (N, 2) — reprojection residuals, px.
    attitude_covariance_rad2 : (3, 3) — covariance of the attitude error about the camera
        axes (x, y cross-boresight, z roll), rad², with the camera parameters marginalised
        and σ taken from the residuals.
    """

    camera: Camera
    A_icrs_to_cam: np.ndarray
    params: tuple[str, ...]
    rss_px2: float
    n_stars: int
    residuals_px: np.ndarray
    attitude_covariance_rad2: np.ndarray

    @property
    def n_free(self) -> int:
        """Free numbers: 3 attitude angles plus the camera's."""
        return 3 + sum(PARAMETERS[p] for p in self.params)

    @property
    def sigma_px(self) -> float:
        """Per-axis residual σ, px, with the fitted degrees of freedom removed."""
        return math.sqrt(self.rss_px2 / max(2 * self.n_stars - self.n_free, 1))

    @property
    def bic(self) -> float:
        """Bayesian information criterion of the fit (Gaussian residuals)."""
        n = 2 * self.n_stars
        return n * math.log(max(self.rss_px2, 1e-300) / n) + self.n_free * math.log(n)


def _rotvec_matrix(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (Rodrigues); scipy's Rotation costs 50 µs a call."""
    theta = math.sqrt(float(w @ w))
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if theta < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + (math.sin(theta) / theta) * K + ((1.0 - math.cos(theta)) / theta**2) * (K @ K)


def _unpack(camera: Camera, params: tuple[str, ...], p: np.ndarray) -> tuple[np.ndarray, dict]:
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
        i += PARAMETERS[name]
    return R, ch


_CAMERA_KEYS = ("fx", "fy", "cx", "cy", "skew", "k1", "k2", "k3", "p1", "p2")


def _residuals_batch(camera: Camera, params: tuple[str, ...], ps: np.ndarray, rays0: np.ndarray,
                     xy: np.ndarray) -> np.ndarray:
    """Residuals (K, 2N) for K parameter vectors ``ps`` (K, P), projected in one batch (numpy:
    the reference of :func:`_residuals_kernel`, which the fits use)."""
    rots, cams = [], []
    for p in ps:
        R, ch = _unpack(camera, params, p)
        rots.append(R)
        cams.append([ch.get(k, getattr(camera, k)) for k in _CAMERA_KEYS])
    fx, fy, cx, cy, skew, k1, k2, k3, p1, p2 = (c[:, None] for c in np.array(cams).T)
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


def _residuals(camera: Camera, params: tuple[str, ...], p: np.ndarray, rays0: np.ndarray,
               xy: np.ndarray) -> np.ndarray:
    return _residuals_fast(camera, params, p[None, :], rays0, xy)[0]


def _residuals_fast(camera: Camera, params: tuple[str, ...], ps: np.ndarray, rays0: np.ndarray,
                    xy: np.ndarray) -> np.ndarray:
    """:func:`_residuals_batch` (its reference) by :func:`_residuals_kernel`."""
    cam = np.array([camera.fx, camera.fy, camera.cx, camera.cy, camera.skew, camera.k1, camera.k2, camera.k3,
                    camera.p1, camera.p2], dtype=np.float64)
    rmax = math.hypot(camera.width, camera.height) / 2.0 / camera.fx
    codes = np.array([_PARAMETER_CODES[name] for name in params], dtype=np.int64)
    return _residuals_kernel(cam, rmax, codes, np.ascontiguousarray(ps, dtype=np.float64),
                             np.ascontiguousarray(rays0, dtype=np.float64),
                             np.ascontiguousarray(xy, dtype=np.float64))


@numba.njit(cache=True)
def _residuals_kernel(cam, rmax, codes, ps, rays0, xy):
    """Residuals (K, 2N) of :func:`_residuals_batch` for the camera ``cam`` (fx, fy, cx, cy,
    skew, k1, k2, k3, p1, p2), parameters ``codes`` (:data:`_PARAMETER_CODES`) and vectors
    ``ps`` (K, P): :func:`_unpack` and the projection, with the same arithmetic."""
    n = xy.shape[0]
    out = np.empty((ps.shape[0], 2 * n))
    for k in range(ps.shape[0]):
        p = ps[k]
        R = _rodrigues(p)  # as _rotvec_matrix
        c = _apply_step(cam, rmax, codes, p)  # as _unpack
        fx, fy, cx, cy, skew, k1, k2, k3, p1, p2 = c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8], c[9]
        for i in range(n):
            X = R[0, 0] * rays0[i, 0] + R[0, 1] * rays0[i, 1] + R[0, 2] * rays0[i, 2]
            Y = R[1, 0] * rays0[i, 0] + R[1, 1] * rays0[i, 1] + R[1, 2] * rays0[i, 2]
            Z = R[2, 0] * rays0[i, 0] + R[2, 1] * rays0[i, 1] + R[2, 2] * rays0[i, 2]
            xn = X / Z
            yn = Y / Z
            r2 = xn * xn + yn * yn
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
            yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
            out[k, 2 * i] = fx * xd + skew * yd + cx - xy[i, 0]
            out[k, 2 * i + 1] = fy * yd + cy - xy[i, 1]
    return out


def _jacobian(camera: Camera, params: tuple[str, ...], p: np.ndarray, rays0: np.ndarray, xy: np.ndarray,
              r0: np.ndarray) -> np.ndarray:
    """Forward-difference Jacobian (2N, P) of the residuals, all steps in one batch; the model
    is smooth and nearly linear at these scales, so a fixed step of 1e-7 is accurate to ~1e-7."""
    h = 1e-7
    steps = p[None, :] + h * np.eye(p.size)
    return ((_residuals_fast(camera, params, steps, rays0, xy) - r0) / h).T


def _jacobian_at_start(camera: Camera, params: tuple[str, ...], rays0: np.ndarray) -> np.ndarray:
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

    def pixel(dxd: np.ndarray, dyd: np.ndarray) -> np.ndarray:
        return np.stack([fx * dxd + s * dyd, fy * dyd], axis=1).ravel()

    def through_lens(dxn: np.ndarray, dyn: np.ndarray) -> np.ndarray:
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


def fit_camera(xy: np.ndarray, r_icrs: np.ndarray, camera: Camera, A_icrs_to_cam: np.ndarray,
               params: Sequence[str] = ("f",), *, iterations: int = 8) -> CameraFit:
    """Fit the attitude and the named camera parameters to matched stars (Gauss–Newton on the
    reprojection error in pixels).

    Parameters
    ----------
    xy : (N, 2) array
        Pixel positions of the stars (DESIGN.md convention).
    r_icrs : (N, 3) array
        Their catalogue unit vectors.
    camera : Camera
        Starting model; parameters not named stay fixed.
    A_icrs_to_cam : (3, 3) array
        Starting attitude.
    params : sequence of str
        Free parameters, from :data:`PARAMETERS`: ``f`` (common focal scale), ``aspect``
        (``fy/fx``), ``principal_point`` (``cx, cy``), ``k1``, ``k2``, ``tangential``
        (``p1, p2``).
    iterations : int
        Most Gauss–Newton steps (it stops when a step moves no star by 1e-6 px).

    Returns
    -------
    CameraFit
    """
    params = tuple(params)
    unknown = set(params) - set(PARAMETERS)
    if unknown:
        raise ValueError(f"unknown camera parameters: {', '.join(sorted(unknown))}")
    xy = np.asarray(xy, dtype=np.float64)
    r = np.asarray(r_icrs, dtype=np.float64)
    n_free = 3 + sum(PARAMETERS[p] for p in params)
    if 2 * len(xy) <= n_free:
        raise ValueError(f"fitting {n_free} numbers needs more than {n_free // 2} stars, got {len(xy)}")
    return _fit(xy, r, camera, np.asarray(A_icrs_to_cam, dtype=np.float64), params, iterations)


def _fit(xy: np.ndarray, r: np.ndarray, camera: Camera, A0: np.ndarray, params: tuple[str, ...],
         iterations: int, J: np.ndarray | None = None, res: np.ndarray | None = None) -> CameraFit:
    """Gauss–Newton with the Jacobian of the starting point, recomputed only when the steps
    stop shrinking (the model is nearly linear over the few pixels a fit moves stars)."""
    rays0 = r @ A0.T
    n_free = 3 + sum(PARAMETERS[name] for name in params)
    p = np.zeros(n_free)
    if res is None:
        res = _residuals(camera, params, p, rays0, xy)
    if J is None:
        J = _jacobian(camera, params, p, rays0, xy, res)
    last = math.inf
    for _ in range(iterations):
        p = p + np.linalg.lstsq(J, -res, rcond=None)[0]
        new = _residuals(camera, params, p, rays0, xy)
        moved = float(np.max(np.abs(new - res)))
        res = new
        if moved < 1e-6:
            break
        if moved > 0.5 * last:
            J = _jacobian(camera, params, p, rays0, xy, res)
        last = moved
    R, ch = _unpack(camera, params, p)
    sigma2 = float(res @ res) / max(res.size - n_free, 1)
    # Columns 0–2 are rotations of the camera frame, so this block is the attitude error
    # about the camera axes with every camera parameter marginalised.
    cov = sigma2 * _inverse(J.T @ J)[:3, :3]
    return CameraFit(camera=camera.replace(**ch), A_icrs_to_cam=R @ A0, params=params,
                     rss_px2=float(res @ res), n_stars=len(xy), residuals_px=res.reshape(-1, 2),
                     attitude_covariance_rad2=cov)


def _inverse(M: np.ndarray) -> np.ndarray:
    """Inverse of a small normal matrix; the pseudo-inverse only when it is singular."""
    try:
        return np.linalg.inv(M)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(M)


@dataclass(frozen=True)
class ModelScore:
    """A camera model scored from the linearisation about the starting point.

    Attributes
    ----------
    params : tuple of str
    bic : float
    rss_px2 : float — residual sum of squares after the linear step, px².
    attitude_covariance_rad2 : (3, 3) — attitude error about the camera axes, camera
        parameters marginalised, σ from ``rss_px2``.
    """

    params: tuple[str, ...]
    bic: float
    rss_px2: float
    attitude_covariance_rad2: np.ndarray


def score_camera_models(xy: np.ndarray, r_icrs: np.ndarray, camera: Camera, A_icrs_to_cam: np.ndarray,
                        models: Sequence[Sequence[str]] = MODEL_LADDER, *,
                        min_stars_per_number: float = 2.0) -> list[ModelScore]:
    """Score each model the number of stars supports, from one linearisation.

    The models' parameters are subsets of their union, so one analytic Jacobian serves all:
    each score is a small linear least-squares problem on a block of ``JᵀJ``. A model with
    ``k`` free numbers is scored only with at least ``min_stars_per_number · k`` stars (the
    first model is always scored), so sparse fields keep simple models.
    """
    scored, bic, rss, cov = _model_scores(xy, r_icrs, camera, A_icrs_to_cam, models, min_stars_per_number)
    return [ModelScore(tuple(params), float(bic[i]), float(rss[i]), cov[i])
            for i, params in enumerate(scored)]


def _model_scores(xy: np.ndarray, r_icrs: np.ndarray, camera: Camera, A_icrs_to_cam: np.ndarray,
                  models: Sequence[Sequence[str]] = MODEL_LADDER, min_stars_per_number: float = 2.0,
                  ) -> tuple[list, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`score_camera_models` as arrays: the models scored, their BIC (K,), RSS (K,) px²
    and attitude covariances (K, 3, 3) rad² (no ModelScore objects: the final fit's hot path)."""
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    r = np.ascontiguousarray(r_icrs, dtype=np.float64)
    A = np.ascontiguousarray(A_icrs_to_cam, dtype=np.float64)
    models = models if models is MODEL_LADDER else tuple(tuple(m) for m in models)
    codes, cols, n_cols = _model_blocks(models)
    rmax = math.hypot(camera.width, camera.height) / 2.0 / camera.fx
    cam = np.array([camera.fx, camera.fy, camera.cx, camera.cy, camera.skew, camera.k1, camera.k2, camera.k3,
                    camera.p1, camera.p2], dtype=np.float64)
    chosen, bic, rss, cov, ok, JtJ, Jtr, rr = _score_models(xy, r, A, cam, rmax, codes, cols, n_cols,
                                                            float(min_stars_per_number))
    if not chosen.any():
        raise ValueError(f"too few stars ({len(xy)}) to fit a camera model")
    if not ok:  # a block not numerically positive definite: LU inverses (pseudo-inverse if singular)
        n = 2 * len(xy)
        for m in np.flatnonzero(chosen):
            c = cols[m, :n_cols[m]]
            inv = _inverse(JtJ[np.ix_(c, c)])
            rss[m] = max(rr - float(Jtr[c] @ inv @ Jtr[c]), 1e-300)
            bic[m] = n * math.log(rss[m] / n) + len(c) * math.log(n)
            cov[m] = rss[m] / max(n - len(c), 1) * inv[:3, :3]
    if chosen.all():
        return list(models), bic, rss, cov
    k = np.flatnonzero(chosen)
    return [models[i] for i in k], bic[k], rss[k], cov[k]


_BLOCKS_CACHE: dict = {}

# Codes of the parameters in the numba kernels.
_PARAMETER_CODES = {"f": 0, "aspect": 1, "principal_point": 2, "k1": 3, "k2": 4, "tangential": 5}


def _model_blocks(models: tuple[tuple[str, ...], ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Kernel codes (U,) of the union of the models' parameters (in order of first appearance),
    and each model's columns of the union's Jacobian (rotations 0–2 first): ``cols[m, :n_cols[m]]``."""
    hit = _BLOCKS_CACHE.get(models)
    if hit is None:
        union = tuple(dict.fromkeys(p for m in models for p in m))
        unknown = set(union) - set(PARAMETERS)
        if unknown:
            raise ValueError(f"unknown camera parameters: {', '.join(sorted(unknown))}")
        columns, i = {}, 3
        for name in union:
            columns[name] = list(range(i, i + PARAMETERS[name]))
            i += PARAMETERS[name]
        blocks = [[0, 1, 2] + [c for name in m for c in columns[name]] for m in models]
        cols = np.zeros((len(models), i), dtype=np.int64)
        for k, c in enumerate(blocks):
            cols[k, :len(c)] = c
        hit = (np.array([_PARAMETER_CODES[p] for p in union], dtype=np.int64), cols,
               np.array([len(c) for c in blocks], dtype=np.int64))
        if len(_BLOCKS_CACHE) < 64:
            _BLOCKS_CACHE[models] = hit
    return hit


@numba.njit(cache=True)
def _score_models(xy, r, A, cam, rmax, codes, cols, n_cols, min_stars_per_number):
    """Which models the stars support (see :func:`score_camera_models`; the first scorable
    always), and their BIC, RSS and covariance (filled for those only)."""
    n_stars = xy.shape[0]
    rays0 = np.empty((n_stars, 3))
    for i in range(n_stars):
        for j in range(3):
            rays0[i, j] = r[i, 0] * A[j, 0] + r[i, 1] * A[j, 1] + r[i, 2] * A[j, 2]
    JtJ, Jtr, rr = _normal_equations_at_start(xy, rays0, cam, rmax, codes)
    chosen = np.zeros(n_cols.shape[0], dtype=np.bool_)
    any_chosen = False
    for m in range(n_cols.shape[0]):
        k = n_cols[m]
        if 2 * n_stars <= k or (n_stars < min_stars_per_number * k and any_chosen):
            continue
        chosen[m] = True
        any_chosen = True
    bic, rss, cov, ok = _score_blocks(JtJ, Jtr, rr, 2 * n_stars, cols, n_cols, chosen)
    return chosen, bic, rss, cov, ok, JtJ, Jtr, rr


@numba.njit(cache=True)
def _jacobian_rows(xy, rays0, cam, rmax, codes):
    """The Jacobian ``J`` (N, 2, P) and residuals (N, 2) at ``p = 0`` (the camera ``cam`` and the
    rays ``rays0``) for the parameters ``codes`` (:data:`_PARAMETER_CODES`), in the scaled units
    of :func:`_unpack`: the arithmetic of :func:`_residuals_batch` and :func:`_jacobian_at_start`
    (their numpy references)."""
    fx, fy, cx, cy, s, k1, k2, k3, p1, p2 = (cam[0], cam[1], cam[2], cam[3], cam[4], cam[5], cam[6],
                                             cam[7], cam[8], cam[9])
    P = 3
    for c in codes:
        P += 2 if (c == 2 or c == 5) else 1
    c1, c2, c4 = 1.0 / rmax, 1.0 / rmax**2, 1.0 / rmax**4
    J = np.empty((xy.shape[0], 2, P))
    res = np.empty((xy.shape[0], 2))
    for i in range(xy.shape[0]):
        X, Y, Z = rays0[i, 0], rays0[i, 1], rays0[i, 2]
        iz = 1.0 / Z
        xn = X * iz
        yn = Y * iz
        r2 = xn * xn + yn * yn
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
        xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
        yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
        res[i, 0] = fx * xd + s * yd + cx - xy[i, 0]
        res[i, 1] = fy * yd + cy - xy[i, 1]
        ju = J[i, 0]
        jv = J[i, 1]
        # d(xd, yd) / d(xn, yn)
        dxx = radial + 2.0 * xn * xn * drad + 2.0 * p1 * yn + 6.0 * p2 * xn
        dxy = 2.0 * xn * yn * drad + 2.0 * p1 * xn + 2.0 * p2 * yn
        dyy = radial + 2.0 * yn * yn * drad + 6.0 * p1 * yn + 2.0 * p2 * xn
        # Rotations ω = e_x, e_y, e_z of the camera frame (δray = ω × ray): d(xn, yn).
        for k in range(3):
            if k == 0:
                dxn, dyn = -xn * yn, -1.0 - yn * yn
            elif k == 1:
                dxn, dyn = 1.0 + xn * xn, yn * xn
            else:
                dxn, dyn = -yn, xn
            dxd = dxx * dxn + dxy * dyn
            dyd = dxy * dxn + dyy * dyn
            ju[k] = fx * dxd + s * dyd
            jv[k] = fy * dyd
        j = 3
        for c in codes:
            if c == 0:  # f
                ju[j], jv[j] = fx * xd + s * yd, fy * yd
            elif c == 1:  # aspect
                ju[j], jv[j] = 0.0, fy * yd
            elif c == 2:  # principal_point
                ju[j], jv[j] = fx, 0.0
                j += 1
                ju[j], jv[j] = 0.0, fx
            elif c == 3:  # k1
                ju[j], jv[j] = (fx * xn + s * yn) * r2 * c2, fy * yn * r2 * c2
            elif c == 4:  # k2
                ju[j], jv[j] = (fx * xn + s * yn) * r2 * r2 * c4, fy * yn * r2 * r2 * c4
            else:  # tangential
                ta, tb = 2.0 * xn * yn, r2 + 2.0 * yn * yn
                ju[j], jv[j] = (fx * ta + s * tb) * c1, fy * tb * c1
                j += 1
                ta, tb = r2 + 2.0 * xn * xn, 2.0 * xn * yn
                ju[j], jv[j] = (fx * ta + s * tb) * c1, fy * tb * c1
            j += 1
    return J, res


@numba.njit(cache=True)
def _normal_equations_at_start(xy, rays0, cam, rmax, codes):
    """``JᵀJ`` (P, P), ``Jᵀr`` (P,) and ``rᵀr`` at ``p = 0`` for the parameters ``codes``
    (:data:`_PARAMETER_CODES`), from :func:`_jacobian_rows`."""
    J, res = _jacobian_rows(xy, rays0, cam, rmax, codes)
    P = J.shape[2]
    JtJ = np.zeros((P, P))
    Jtr = np.zeros(P)
    rr = 0.0
    for i in range(J.shape[0]):
        u, v = res[i, 0], res[i, 1]
        for a in range(P):
            Jtr[a] += J[i, 0, a] * u + J[i, 1, a] * v
            for b in range(a, P):
                JtJ[a, b] += J[i, 0, a] * J[i, 0, b] + J[i, 1, a] * J[i, 1, b]
        rr += u * u + v * v
    for a in range(P):
        for b in range(a):
            JtJ[a, b] = JtJ[b, a]
    return JtJ, Jtr, rr


@numba.njit(cache=True)
def _spd_inverse(M):
    """Inverse of a small symmetric positive definite matrix by Cholesky, and whether it was
    (a pivot ≤ 0 returns False); a tenth of a LAPACK call's overhead at these sizes."""
    k = M.shape[0]
    L = np.zeros((k, k))
    for j in range(k):
        d = M[j, j]
        for p in range(j):
            d -= L[j, p] * L[j, p]
        if not d > 0.0:
            return L, False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, k):
            t = M[i, j]
            for p in range(j):
                t -= L[i, p] * L[j, p]
            L[i, j] = t / L[j, j]
    Li = np.zeros((k, k))  # L⁻¹, lower triangular
    for j in range(k):
        Li[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, k):
            t = 0.0
            for p in range(j, i):
                t -= L[i, p] * Li[p, j]
            Li[i, j] = t / L[i, i]
    inv = np.empty((k, k))  # M⁻¹ = L⁻ᵀ L⁻¹
    for a in range(k):
        for b in range(a, k):
            t = 0.0
            for p in range(b, k):
                t += Li[p, a] * Li[p, b]
            inv[a, b] = t
            inv[b, a] = t
    return inv, True


@numba.njit(cache=True)
def _score_blocks(JtJ, Jtr, rr, n, cols, n_cols, chosen):
    """BIC, RSS and attitude covariance of each chosen model's linear step (see
    :func:`score_camera_models`); model ``m`` uses the columns ``cols[m, :n_cols[m]]``."""
    K = n_cols.shape[0]
    bic = np.empty(K)
    rss = np.empty(K)
    cov = np.empty((K, 3, 3))
    for m in range(K):
        if not chosen[m]:
            continue
        k = n_cols[m]
        sub = np.empty((k, k))
        g = np.empty(k)
        for a in range(k):
            g[a] = Jtr[cols[m, a]]
            for b in range(k):
                sub[a, b] = JtJ[cols[m, a], cols[m, b]]
        inv, ok = _spd_inverse(sub)
        if not ok:  # not numerically positive definite: the caller redoes it with numpy
            return bic, rss, cov, False
        # Normal equations on the sub-block: step = −(JᵀJ)⁻¹Jᵀr, RSS = rᵀr + stepᵀJᵀr.
        dot = 0.0
        for a in range(k):
            step = 0.0
            for b in range(k):
                step -= inv[a, b] * g[b]
            dot += step * g[a]
        rss[m] = max(rr + dot, 1e-300)
        bic[m] = n * math.log(rss[m] / n) + k * math.log(n)
        scale = rss[m] / max(n - k, 1)
        for a in range(3):
            for b in range(3):
                cov[m, a, b] = scale * inv[a, b]
    return bic, rss, cov, True


def select_camera_model(xy: np.ndarray, r_icrs: np.ndarray, camera: Camera, A_icrs_to_cam: np.ndarray,
                        models: Sequence[Sequence[str]] = MODEL_LADDER, *,
                        min_stars_per_number: float = 2.0) -> CameraFit:
    """Choose the camera model the stars support (lowest BIC, :func:`score_camera_models`)
    and fit it to convergence (:func:`fit_camera`)."""
    scores = score_camera_models(xy, r_icrs, camera, A_icrs_to_cam, models,
                                 min_stars_per_number=min_stars_per_number)
    best = min(scores, key=lambda sc: sc.bic)
    return fit_camera(xy, r_icrs, camera, A_icrs_to_cam, best.params)


# --- an uncalibrated camera: every parameter free, each with a Gaussian prior ------------------

# The parameters of an uncalibrated camera, in the order of :func:`fit_camera_with_prior`'s
# parameter vector (after the three rotations).
PRIOR_PARAMETERS: tuple[str, ...] = ("f", "aspect", "principal_point", "k1", "k2")


# The principal point is moved off the prior's centre when its move is beyond this χ² (2 dof) of
# its posterior: 1e-3 by chance. (At 30, 3e-7, 5 of 10 000 blind uncalibrated fields were wrong;
# at 13.8, 2, with the same solves: benchmarks/suite_blind.py.)
_PP_CHI2 = 13.8


class CameraPrior(NamedTuple):
    """What is known of a camera before its image is solved: a Gaussian prior on each parameter
    but the focal length (free) — the principal point about ``(cx, cy)``, the pixel aspect
    ``fy/fx`` about ``aspect`` (1), radial distortion about ``k1``, ``k2`` (0; OpenCV's normalised
    units).

    The prior keeps a sparse field from fitting an absurd lens (``k2 = 400``) and lets the
    attitude's covariance include what the stars leave unknown; many stars overrule it.
    """

    cx: float
    cy: float
    sigma_principal_point_px: float
    sigma_aspect: float = 0.05
    sigma_k1: float = 0.3
    sigma_k2: float = 0.3
    aspect: float = 1.0
    k1: float = 0.0
    k2: float = 0.0

    @classmethod
    def uncalibrated(cls, width: int, height: int) -> CameraPrior:
        """The prior for an unknown camera of this frame size: principal point at the image
        centre within a quarter of the half-diagonal (lens mounting — or an off-centre crop of a
        larger frame: with 5% the error bars of 60% crops were 6–8× too small), aspect within
        5%, |k1|, |k2| ≲ 0.3 (most lenses narrower than 60°)."""
        return cls(cx=(width - 1) / 2.0, cy=(height - 1) / 2.0,
                   sigma_principal_point_px=0.25 * math.hypot(width, height) / 2.0)


class PriorFit(NamedTuple):
    """The result of :func:`fit_camera_with_prior`.

    Attributes
    ----------
    camera : Camera — the fitted model (maximum a posteriori).
    A_icrs_to_cam : (3, 3) — the fitted attitude.
    residuals_px : (N, 2) — reprojection residuals, px.
    sigma_px : float — centroid noise per axis estimated from the residuals, px.
    covariance_rad2 : (3, 3) — attitude error about the camera axes (x, y, roll), rad², at the
        principal point, with every camera parameter marginalised over its posterior.
    n_effective : float — effective number of fitted numbers (3 rotations + the camera's
        share: ``trace`` of the hat matrix); the camera's part is what the stars paid for it.
    outlier_chi2 : (N,) — each star's residual against what the others predict for it
        (studentised: ``rᵀ (σ² (I − H))⁻¹ r`` with ``H`` its 2×2 block of the hat matrix, and
        σ from the other stars' residuals unless ``robust``): for a star that fits the model,
        twice an F(2, dof − 2) variable, dof = ``2N − n_effective``.
    parameter_covariance : (P, P) — posterior covariance of the parameter step (rotations,
        then :data:`PRIOR_PARAMETERS` in :func:`_unpack`'s scaled units).
    largest_move_px : float — the largest distance by which the fit moved a star's predicted
        position from where the starting camera and attitude put it.
    """

    camera: Camera
    A_icrs_to_cam: np.ndarray
    residuals_px: np.ndarray
    sigma_px: float
    covariance_rad2: np.ndarray
    n_effective: float
    outlier_chi2: np.ndarray
    parameter_covariance: np.ndarray
    largest_move_px: float = 0.0

    def prediction_sigma_px(self, r_icrs: np.ndarray) -> np.ndarray:
        """How uncertain (px, the larger axis's σ) the fitted model's pixel position of each
        catalogue direction ``r_icrs`` (M, 3) is, from :attr:`parameter_covariance`."""
        cam = self.camera
        rays = np.ascontiguousarray(np.asarray(r_icrs, dtype=np.float64) @ self.A_icrs_to_cam.T)
        rmax = math.hypot(cam.width, cam.height) / 2.0 / cam.fx
        Js, _ = _jacobian_rows(np.zeros((len(rays), 2)), rays, _camera_numbers(cam), rmax, _PRIOR_CODES)
        C = (Js @ self.parameter_covariance) @ Js.transpose(0, 2, 1)
        half_tr = (C[:, 0, 0] + C[:, 1, 1]) / 2.0
        return np.sqrt(half_tr + np.sqrt(np.maximum(half_tr**2 - (C[:, 0, 0] * C[:, 1, 1] - C[:, 0, 1] ** 2),
                                                    0.0)))


_PRIOR_CODES = np.array([_PARAMETER_CODES[p] for p in PRIOR_PARAMETERS], dtype=np.int64)


def _camera_numbers(camera: Camera) -> np.ndarray:
    """The camera's numbers for the kernels: (fx, fy, cx, cy, skew, k1, k2, k3, p1, p2)."""
    return np.array([camera.fx, camera.fy, camera.cx, camera.cy, camera.skew, camera.k1, camera.k2,
                     camera.k3, camera.p1, camera.p2], dtype=np.float64)


@numba.njit(cache=True)
def _apply_step(cam, rmax, codes, p):
    """The camera numbers (fx, fy, cx, cy, skew, k1, k2, k3, p1, p2) after the parameter step
    ``p`` (rotations first, then ``codes``, in :func:`_unpack`'s scaled units)."""
    out = cam.copy()
    j = 3
    for c in codes:
        if c == 0:  # f
            out[0], out[1] = cam[0] * (1.0 + p[j]), cam[1] * (1.0 + p[j])
        elif c == 1:  # aspect
            out[1] = out[1] * (1.0 + p[j])
        elif c == 2:  # principal_point
            out[2], out[3] = cam[2] + p[j] * cam[0], cam[3] + p[j + 1] * cam[0]
            j += 1
        elif c == 3:  # k1
            out[5] = cam[5] + p[j] / rmax**2
        elif c == 4:  # k2
            out[6] = cam[6] + p[j] / rmax**4
        else:  # tangential
            out[8], out[9] = cam[8] + p[j] / rmax, cam[9] + p[j + 1] / rmax
            j += 1
        j += 1
    return out


@numba.njit(cache=True)
def _rodrigues(p):
    """Rotation matrix of the rotation vector ``p[:3]``: ``I + sin θ/θ K + (1 − cos θ)/θ² K²``."""
    theta = np.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
    K = np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]])
    a, b = 1.0, 0.0
    if theta >= 1e-12:
        a, b = np.sin(theta) / theta, (1.0 - np.cos(theta)) / theta**2
    R = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            KK = K[i, 0] * K[0, j] + K[i, 1] * K[1, j] + K[i, 2] * K[2, j]
            R[i, j] = (1.0 if i == j else 0.0) + a * K[i, j] + b * KK
    return R


@numba.njit(cache=True)
def _prior_gauss_newton(xy, r, A, cam, half_diag_px, prior, robust, iterations, sigma_floor, prior_out):
    """The iterations of :func:`fit_camera_with_prior` for :data:`PRIOR_PARAMETERS`; ``prior``
    = (cx, cy, σ principal point px, σ aspect, σ k1, σ k2, aspect, k1, k2) for the steps,
    ``prior_out`` for the posterior returned. Returns the attitude, camera numbers, σ², the posterior covariance at
    the result, n_eff, the residuals (N, 2), the studentised χ² (N,) and the Gauss–Newton step
    (P,) under ``prior_out`` from the result (what freeing ``prior_out``'s parameters would do),
    and the largest distance (px) by which the fit moved a star's predicted position."""
    codes = np.array([0, 1, 2, 3, 4], dtype=np.int64)  # PRIOR_PARAMETERS in _PARAMETER_CODES
    n = xy.shape[0]
    n_obs = 2 * n
    P = 9
    n_eff = 4.0
    rays0 = np.empty((n, 3))
    lam = np.zeros(P)
    dev = np.zeros(P)
    w = np.ones(n_obs)
    sigma2 = 1.0
    inv = np.zeros((P, P))
    J = np.empty((n, 2, P))
    res = np.empty((n, 2))
    res0 = np.empty((n, 2))
    for it in range(iterations + 1):
        for i in range(n):
            for k in range(3):
                rays0[i, k] = A[k, 0] * r[i, 0] + A[k, 1] * r[i, 1] + A[k, 2] * r[i, 2]
        rmax = half_diag_px / cam[0]
        J, res = _jacobian_rows(xy, rays0, cam, rmax, codes)
        if it == 0:
            res0 = res.copy()
        d = np.empty(n)
        ss = 0.0
        for i in range(n):
            d[i] = np.sqrt(res[i, 0] ** 2 + res[i, 1] ** 2)
            ss += d[i] * d[i]
        if robust:
            sigma2 = max((np.median(d) / 1.1774) ** 2, sigma_floor**2)
            for i in range(n):
                w[2 * i] = w[2 * i + 1] = 1.0 / (1.0 + d[i] * d[i] / (9.0 * sigma2))
        else:
            sigma2 = max(ss / max(n_obs - n_eff, 1.0), sigma_floor**2)
        JtJ = np.zeros((P, P))
        g = np.zeros(P)
        for i in range(n):
            for c in range(2):
                wi = w[2 * i + c]
                for a in range(P):
                    g[a] += wi * J[i, c, a] * res[i, c]
                    for b in range(a, P):
                        JtJ[a, b] += wi * J[i, c, a] * J[i, c, b]
        for a in range(P):
            for b in range(a):
                JtJ[a, b] = JtJ[b, a]
        pr = prior_out if it == iterations else prior
        lam[4] = 1.0 / pr[3] ** 2
        lam[5] = lam[6] = (cam[0] / pr[2]) ** 2
        lam[7] = 1.0 / (pr[4] * rmax**2) ** 2
        lam[8] = 1.0 / (pr[5] * rmax**4) ** 2
        dev[4] = cam[1] / cam[0] - pr[6]
        dev[5] = (cam[2] - prior[0]) / cam[0]
        dev[6] = (cam[3] - prior[1]) / cam[0]
        dev[7] = (cam[5] - pr[7]) * rmax**2
        dev[8] = (cam[6] - pr[8]) * rmax**4
        N = JtJ / sigma2
        for a in range(P):
            N[a, a] += lam[a]
        inv, ok = _spd_inverse(N)
        if not ok:
            inv = np.linalg.pinv(N)
        n_eff = 0.0
        for a in range(P):
            for b in range(P):
                n_eff += inv[a, b] * JtJ[b, a]
        n_eff /= sigma2
        step = np.zeros(P)
        for a in range(P):
            for b in range(P):
                step[a] -= inv[a, b] * (g[b] / sigma2 + lam[b] * dev[b])
        if it == iterations:
            break
        A = _rodrigues(step) @ A
        cam = _apply_step(cam, rmax, codes, step)
        moved = 0.0
        for a in range(P):
            for b in range(P):
                moved += step[a] * JtJ[a, b] * step[b]
        if moved < 4e-6 * n_obs:  # stars moved by ~2e-3 px: converged
            iterations = it + 1
    # Studentised residuals: each star's 2×2 block of the hat matrix J (JᵀWJ/σ² + Λ)⁻¹ JᵀW / σ²,
    # and rᵀ (σ² (I − H))⁻¹ r; without ``robust`` externally studentised: σ re-estimated without
    # the star (a wrong star inflates σ and so hides itself from the internal statistic).
    chi2 = np.empty(n)
    rss = 0.0
    for i in range(n):
        rss += res[i, 0] ** 2 + res[i, 1] ** 2
    H = np.empty((2, 2))
    t = np.empty((2, P))
    moved = 0.0  # how far the fit moved the stars from where the starting model put them
    for i in range(n):
        moved = max(moved, np.sqrt((res[i, 0] - res0[i, 0]) ** 2 + (res[i, 1] - res0[i, 1]) ** 2))
        for e in range(2):
            for a in range(P):
                acc = 0.0
                for b in range(P):
                    acc += inv[a, b] * J[i, e, b]
                t[e, a] = acc
        for c in range(2):
            for e in range(2):
                acc = 0.0
                for a in range(P):
                    acc += J[i, c, a] * t[e, a]
                H[c, e] = acc * w[2 * i + c] / sigma2
        m00, m01 = sigma2 * (1.0 - H[0, 0]), -sigma2 * H[0, 1]
        m10, m11 = -sigma2 * H[1, 0], sigma2 * (1.0 - H[1, 1])
        det = max(m00 * m11 - m01 * m10, 1e-12 * sigma2 * sigma2)  # a star the fit rests on alone
        q = (m11 * res[i, 0] ** 2 - (m01 + m10) * res[i, 0] * res[i, 1] + m00 * res[i, 1] ** 2) / det
        if not robust:
            rss_without = max(rss - q * sigma2, 1e-12 * sigma2)
            q = q * sigma2 / max(rss_without / max(n_obs - n_eff - 2.0, 1.0), sigma_floor**2)
        chi2[i] = q
    return A, cam, sigma2, inv, n_eff, res, chi2, step, moved


def fit_camera_with_prior(xy: np.ndarray, r_icrs: np.ndarray, camera: Camera, A_icrs_to_cam: np.ndarray,
                          prior: CameraPrior, *, robust: bool = False, iterations: int = 12,
                          sigma_floor_px: float = 0.05, principal_point: str = "auto") -> PriorFit:
    """Fit attitude, focal length, aspect, principal point, k1 and k2 to matched stars, each
    camera parameter but the focal length held by its ``prior`` (maximum a posteriori).

    Gauss–Newton on ``Σ w |residual|²/σ² + Σ ((θ − θ₀)/τ)²`` with the analytic Jacobian of
    :func:`_jacobian_rows`, in one numba kernel (:func:`_prior_gauss_newton`). σ, the centroid
    noise, is re-estimated at every step: from the residuals (``σ² = RSS / (2N − n_eff)``), or
    with ``robust`` from their median (a
    2-D Gaussian's residual length has median 1.1774 σ) and with Cauchy weights
    ``w = 1 / (1 + (|residual| / 3σ)²)``, so that a few wrong stars cannot hold the model away
    from the many right ones; floored at ``sigma_floor_px``. The covariance is the
    posterior's, ``(JᵀWJ/σ² + Λ)⁻¹``. Its attitude block is taken for the frame at the
    principal point *as a pixel*: a principal-point shift moves the optical axis but not the sky
    position of that pixel, so only what the principal point does beyond a shift (the field's
    perspective and the distortion centre) enters the attitude's error bar.

    ``principal_point``: ``"fit"`` moves the principal point from the prior's as the stars
    ask; ``"hold"`` keeps it at the prior's (the image centre), so that the attitude refers to
    that pixel, with its uncertainty (free under its prior at the held solution) in the
    covariance; ``"auto"`` fits it where the stars pin it down (posterior σ below a third of the
    prior's, the move beyond χ² = 13.8 of its posterior: a wide or distorted field, a crop) and
    holds it elsewhere.

    Parameters
    ----------
    xy : (N, 2) — star positions, px.
    r_icrs : (N, 3) — their catalogue unit vectors.
    camera, A_icrs_to_cam : the starting model and attitude.
    prior : CameraPrior
    robust : bool — Cauchy weights and a median σ (for matches that may hold wrong stars).
    iterations : int — most Gauss–Newton steps.
    sigma_floor_px : float — smallest centroid noise believed, px.
    principal_point : str — ``"auto"``, ``"fit"`` or ``"hold"`` (above).
    """
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    r = np.ascontiguousarray(r_icrs, dtype=np.float64)
    A0 = np.ascontiguousarray(A_icrs_to_cam, dtype=np.float64)
    prior_numbers = np.array([prior.cx, prior.cy, prior.sigma_principal_point_px, prior.sigma_aspect,
                              prior.sigma_k1, prior.sigma_k2, prior.aspect, prior.k1, prior.k2], dtype=np.float64)
    half_diag = float(math.hypot(camera.width, camera.height) / 2.0)
    cam0 = _camera_numbers(camera)
    if principal_point not in ("auto", "fit", "hold"):
        raise ValueError(f"principal_point must be 'auto', 'fit' or 'hold', not {principal_point!r}")
    fixed = prior_numbers.copy()
    fixed[2] = 1e-9 * prior.sigma_principal_point_px
    if principal_point == "fit":
        A, cam, sigma2, inv, n_eff, res, chi2, _, moved = _prior_gauss_newton(
            xy, r, A0, cam0, half_diag, prior_numbers, bool(robust), int(iterations), float(sigma_floor_px),
            prior_numbers)
    else:
        # Fit with the principal point held at the prior's; the posterior and one step with it
        # free come from the result: the step tells "auto" whether the stars pin it down
        # elsewhere.
        held = cam0.copy()
        held[2], held[3] = prior.cx, prior.cy
        A, cam, sigma2, inv, n_eff, res, chi2, free_step, moved = _prior_gauss_newton(
            xy, r, A0, held, half_diag, fixed, bool(robust), int(iterations), float(sigma_floor_px),
            prior_numbers)
        if principal_point == "auto":
            # Moved only when the stars say so: the move against its posterior covariance beyond
            # _PP_CHI2 (2 dof: 1e-3 by chance) and the posterior σ a third of the prior's or less.
            (mx, my), (c00, c01, c11) = free_step[5:7], (inv[5, 5], inv[5, 6], inv[6, 6])
            det = c00 * c11 - c01 * c01
            chi2_move = (c11 * mx * mx - 2.0 * c01 * mx * my + c00 * my * my) / det if det > 0 else 0.0
            principal_point = "hold"
            pinned = 3.0 * math.sqrt(max(c00, c11)) * cam[0] < prior.sigma_principal_point_px
            if pinned and chi2_move > _PP_CHI2:
                principal_point = "fit"
                res_held = res
                A1, cam, sigma2, inv, n_eff, res, chi2, _, _ = _prior_gauss_newton(
                    xy, r, A, cam, half_diag, prior_numbers, bool(robust), int(iterations),
                    float(sigma_floor_px), prior_numbers)
                moved += float(np.max(np.hypot(*(res - res_held).T)))
                A = A1
    camera = camera.replace(**dict(zip(_CAMERA_KEYS, cam.tolist(), strict=True)))
    # Attitude of the frame at the principal point's pixel: a shift (δcx, δcy) of the principal
    # point (scaled by fx) with no change of that pixel's sky direction is the rotation
    # (−δcy·fx/fy, δcx, 0) — take the covariance of rotation + that share of the shift.
    T = np.zeros((3, len(inv)))
    T[:, :3] = np.eye(3)
    T[1, 5] = 1.0
    T[0, 6] = -camera.fx / camera.fy
    cov = T @ inv @ T.T
    return PriorFit(camera, A, res, math.sqrt(sigma2), cov, n_eff, chi2, inv, float(moved))


def frame_at_pixel(A_icrs_to_cam: np.ndarray, camera: Camera, pixel: tuple[float, float]) -> np.ndarray:
    """The attitude (3, 3) of the frame that ``camera`` and ``A_icrs_to_cam`` give at ``pixel``:
    z along that pixel's sky direction, x along the direction in which the column grows there
    (made perpendicular to z), y = z × x. At the principal point it is ``A_icrs_to_cam``."""
    p0 = np.array([pixel], dtype=np.float64)
    ray0 = camera.pixel_to_ray(p0)[0]
    ray1 = camera.pixel_to_ray(p0 + [0.5, 0.0])[0]
    z = ray0 / np.linalg.norm(ray0)
    x = ray1 - ray0
    x -= (x @ z) * z
    x /= np.linalg.norm(x)
    return np.vstack([x, np.cross(z, x), z]) @ np.asarray(A_icrs_to_cam, dtype=np.float64)


def frame_rotation_at_pixel(A: np.ndarray, camera: Camera, A_ref: np.ndarray, camera_ref: Camera,
                            pixel: tuple[float, float]) -> np.ndarray:
    """Rotation vector (3,) rad, about ``camera``'s axes, from the frame that (``A_ref``,
    ``camera_ref``) give at ``pixel`` (:func:`frame_at_pixel`) to the camera frame of ``A``.
    For ``pixel`` at ``camera``'s principal point it is the error of ``A`` when the reference is
    the truth."""
    return _rotation_vector(A @ frame_at_pixel(A_ref, camera_ref, pixel).T)


def _rotation_vector(R: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) of a rotation matrix not near 180° (the errors compared here)."""
    angle = math.acos(min(max((float(np.trace(R)) - 1.0) / 2.0, -1.0), 1.0))
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-8:
        return axis / 2.0
    return axis * (angle / (2.0 * math.sin(angle)))
