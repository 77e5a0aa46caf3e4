"""The final fit after identification: outliers out, camera model chosen, stars re-matched,
attitude and its covariance.

Identification proves *which* stars are in the image; this stage makes the attitude as good
and its error bar as honest as the stars allow. With a camera given by the user the camera is
taken as exact and Wahba's problem is solved with the chosen method (QUEST covariance). With
no camera, the camera model the stars support is chosen by BIC (focal length, aspect ratio,
radial distortion: :func:`skyfix.calibrate.select_camera_model`), the catalogue is re-matched
through that model, and the covariance comes from the joint fit, so the attitude's error bar
includes what the unknown camera leaves uncertain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from scipy.spatial import cKDTree

from skyfix.attitude import attitude_covariance, solve_attitude
from skyfix.calibrate import _model_scores, fit_camera
from skyfix.camera import Camera

__all__ = ["FinalFit", "final_fit"]


@dataclass(frozen=True)
class FinalFit:
    """Attitude, camera and the stars that support them.

    Attributes
    ----------
    A_icrs_to_cam : (3, 3)
    camera : Camera — the camera model used (fitted when none was given).
    star_index : (M,) int — indices into the centroids.
    catalog_ids : (M,) int
    catalog_vectors : (M, 3)
    catalog_mag : (M,)
    residuals_rad : (M,) — angle between each star's ray and its catalogue direction.
    covariance_rad2 : (3, 3) — attitude error about the camera axes (x, y, roll).
    camera_params : tuple of str — camera parameters fitted ("" when the camera was given).
    """

    A_icrs_to_cam: np.ndarray
    camera: Camera
    star_index: np.ndarray
    catalog_ids: np.ndarray
    catalog_vectors: np.ndarray
    catalog_mag: np.ndarray
    residuals_rad: np.ndarray
    covariance_rad2: np.ndarray
    camera_params: tuple[str, ...]


def angles(b: np.ndarray, r: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Angles (rad) between observed rays ``b`` and catalogue vectors ``r`` rotated by ``A``."""
    return _angles(np.ascontiguousarray(b, dtype=np.float64), np.ascontiguousarray(r, dtype=np.float64),
                   np.ascontiguousarray(A, dtype=np.float64))


@numba.njit(cache=True)
def _angles(b, r, A):
    """:func:`angles` in one pass (the kernels of this module call only each other: numba's
    cache checks a kernel's own file only)."""
    out = np.empty(b.shape[0])
    for i in range(b.shape[0]):
        chord2 = 0.0
        for j in range(3):
            d = b[i, j] - (r[i, 0] * A[j, 0] + r[i, 1] * A[j, 1] + r[i, 2] * A[j, 2])
            chord2 += d * d
        out[i] = 2.0 * np.arcsin(min(np.sqrt(chord2) / 2.0, 1.0))
    return out


def inliers(resid: np.ndarray, floor: float) -> np.ndarray:
    """Stars to fit: residual lengths of 2-D Gaussian errors are Rayleigh distributed (median
    1.177 σ); those beyond 4 σ (P = 3e-4 by chance; σ floored at ``floor``) are blends or
    mismatched faint stars. At least half of the stars, and three, are always kept."""
    return _inliers(np.ascontiguousarray(resid, dtype=np.float64), float(floor))


@numba.njit(cache=True)
def _sorted(a):
    """A sorted copy of a short 1-D array (Shell sort: compiles in a fraction of np.sort's time)."""
    out = a.copy()
    n = out.shape[0]
    for gap in (701, 301, 132, 57, 23, 10, 4, 1):  # Ciura's gaps
        for i in range(gap, n):
            v = out[i]
            j = i
            while j >= gap and out[j - gap] > v:
                out[j] = out[j - gap]
                j -= gap
            out[j] = v
    return out


@numba.njit(cache=True)
def _inliers(resid, floor):
    """:func:`inliers` in one pass."""
    n = resid.shape[0]
    if n == 0:
        return np.zeros(0, dtype=np.bool_)
    ordered = _sorted(resid)
    median = ordered[n // 2] if n % 2 else (ordered[n // 2 - 1] + ordered[n // 2]) / 2.0
    sigma = max(median / 1.177, floor)
    keep = resid <= 4.0 * sigma
    n_min = min(n, max(3, n // 2))
    if keep.sum() < n_min:
        keep = resid <= ordered[n_min - 1]
    return keep


def final_fit(xy: np.ndarray, ident, *, camera_given: bool, database=None, epoch: float | None = None,
              method: str = "svd") -> FinalFit:
    """Refine a successful identification into the final attitude (see the module text).

    Parameters
    ----------
    xy : (N, 2) centroids, px.
    ident : skyfix.identify.Identification (successful).
    camera_given : bool — the user gave the camera: take it as exact.
    database : PatternDatabase, optional — its star table serves the re-matching.
    epoch : float, optional — Julian year of the catalogue positions.
    method : str — Wahba solver for the attitude.
    """
    camera: Camera = ident.camera
    idx = np.asarray(ident.star_index)
    ids = np.asarray(ident.catalog_ids)
    r = np.ascontiguousarray(ident.catalog_vectors, dtype=np.float64)
    mag = np.asarray(ident.catalog_mag, dtype=np.float64)
    A = np.ascontiguousarray(ident.A_icrs_to_cam, dtype=np.float64)
    xy_idx = np.ascontiguousarray(xy[idx], dtype=np.float64)
    b, keep, n_kept = _rays_and_inliers(xy_idx, r, A, _camera_array(camera))
    if n_kept < len(keep):
        idx, ids, r, mag, b, xy_idx = idx[keep], ids[keep], r[keep], mag[keep], b[keep], xy_idx[keep]
    params: tuple[str, ...] = ()
    cov = None
    if not camera_given and len(idx) >= 4:
        scored, bic, _, covs = _model_scores(xy_idx, r, camera, A)
        best = int(np.argmin(bic))  # the first of equal scores, as min()
        params, cov = scored[best], covs[best]
        if set(params) - {"f", "k1"}:
            # The model grew beyond identification's (focal length, k1, already fitted): the
            # matches made through the simpler model may miss stars or hold wrong ones, so
            # fit the model and match again.
            fit = fit_camera(xy[idx], r, camera, A, params)
            if _largest_shift_px(camera, A, fit.camera, fit.A_icrs_to_cam) > 0.5:
                fit, idx, ids, r, mag = _rematch(xy, fit, database, epoch, (idx, ids, r, mag))
            camera, A, cov = fit.camera, fit.A_icrs_to_cam, fit.attitude_covariance_rad2
            b = camera.pixel_to_ray(xy[idx])
    A = solve_attitude(b, r, method=method)
    resid = _angles(b, r, np.ascontiguousarray(A))
    if cov is None:
        # Per-axis σ from the fit's own residuals (3 attitude dof used), floored at 0.05 px
        # so a lucky tiny residual does not claim an impossible precision.
        dof = max(2 * len(idx) - 3, 1)
        sigma = max(math.sqrt(float(np.sum(resid**2)) / dof), 0.05 * camera.plate_scale_rad)
        cov = attitude_covariance(A, b, sigma)
    return FinalFit(A, camera, idx, ids, r, mag, resid, cov, params)


def _camera_array(camera: Camera) -> np.ndarray:
    """The camera's numbers for the kernels: (fx, fy, cx, cy, skew, k1, k2, k3, p1, p2)."""
    return np.array([camera.fx, camera.fy, camera.cx, camera.cy, camera.skew, camera.k1, camera.k2, camera.k3,
                     camera.p1, camera.p2], dtype=np.float64)


@numba.njit(cache=True)
def _rays_and_inliers(xy, r, A, cam):
    """``camera.pixel_to_ray(xy)`` for the camera ``cam`` (:func:`_pixel_rays`), and the
    :func:`inliers` of their :func:`angles` to ``r`` rotated by ``A`` (σ floored at a tenth of
    the plate scale), and how many those are."""
    b = _pixel_rays(xy, cam)
    keep = _inliers(_angles(b, r, A), 0.1 * (1.0 / np.sqrt(cam[0] * cam[1])))
    n_kept = 0
    for k in keep:
        n_kept += k
    return b, keep, n_kept


@numba.njit(cache=True)
def _pixel_rays(xy, cam):
    """``camera.pixel_to_ray(xy)`` for the camera ``cam`` (:func:`_camera_array`), with the same
    arithmetic: Brown–Conrady inverted by the same fixed-point iteration, stopped when no
    pixel moves by 1e-5 px."""
    fx, fy, cx, cy, skew, k1, k2, k3, p1, p2 = (cam[0], cam[1], cam[2], cam[3], cam[4], cam[5], cam[6],
                                                cam[7], cam[8], cam[9])
    distorted = k1 != 0.0 or k2 != 0.0 or k3 != 0.0 or p1 != 0.0 or p2 != 0.0
    tol = 1e-5 / max(fx, fy)
    n = xy.shape[0]
    xd = np.empty(n)
    yd = np.empty(n)
    for i in range(n):
        yd[i] = (xy[i, 1] - cy) / fy
        xd[i] = (xy[i, 0] - cx - skew * yd[i]) / fx
    xn = xd.copy()
    yn = yd.copy()
    if distorted:
        xs = np.empty(n)
        ys = np.empty(n)
        for _ in range(50):
            step = 0.0
            for i in range(n):
                x, y = xn[i], yn[i]
                r2 = x * x + y * y
                radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
                dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
                dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
                xs[i] = (xd[i] - dx) / radial
                ys[i] = (yd[i] - dy) / radial
                step = max(step, abs(xs[i] - x) + abs(ys[i] - y))
            xn, xs = xs, xn
            yn, ys = ys, yn
            if step < tol:
                break
    b = np.empty((n, 3))
    for i in range(n):
        norm = np.sqrt(xn[i] * xn[i] + yn[i] * yn[i] + 1.0)
        b[i, 0] = xn[i] / norm
        b[i, 1] = yn[i] / norm
        b[i, 2] = 1.0 / norm
    return b


def _largest_shift_px(cam0: Camera, A0: np.ndarray, cam1: Camera, A1: np.ndarray) -> float:
    """How far (px) the new model moves a star anywhere on a 5×5 grid over the frame; below
    about half a pixel the old matches stand, as the match radius is larger."""
    gx, gy = np.meshgrid(np.linspace(0, cam0.width - 1, 5), np.linspace(0, cam0.height - 1, 5))
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    sky = _pixel_rays(grid, _camera_array(cam0)) @ A0  # rows: ICRS directions of the grid pixels
    moved, _ = cam1.ray_to_pixel(sky @ A1.T)
    return float(np.max(np.hypot(*(moved - grid).T)))


def _star_tree(database) -> cKDTree:
    tree = database.__dict__.get("_star_tree")
    if tree is None:
        tree = cKDTree(np.asarray(database.star_vectors, dtype=np.float64))
        database.__dict__["_star_tree"] = tree
    return tree


def _rematch(xy: np.ndarray, fit, database, epoch: float | None, current: tuple):
    """Match the database's stars to the centroids through the fitted model, refit, twice."""
    if database is None:
        from skyfix.identify import default_database

        database = default_database()
    tree = _star_tree(database)
    img_tree = cKDTree(xy)
    for _ in range(2):
        cam, A = fit.camera, fit.A_icrs_to_cam
        half_diag = math.radians(cam.fov_diagonal_deg) / 2.0 * 1.05
        near = np.asarray(tree.query_ball_point(A[2], 2.0 * math.sin(half_diag / 2.0)), dtype=np.int64)
        if len(near) == 0:
            break
        v = database.vectors_at(near, epoch)
        uv, front = cam.ray_to_pixel(v @ A.T)
        seen = front & cam.in_frame(uv)
        near, v, uv = near[seen], v[seen], uv[seen]
        radius = max(4.0 * fit.sigma_px, 1.0)
        dist, j = img_tree.query(uv, distance_upper_bound=radius)
        hit = np.isfinite(dist)
        star, cen = np.flatnonzero(hit), j[hit]
        # Unambiguous pairs only: a centroid with two catalogue stars (a blend) or a star
        # claimed by two centroids says nothing reliable about the camera.
        n_stars_near = cKDTree(uv).query_ball_point(xy[cen], radius, return_length=True)
        n_claims = np.bincount(cen, minlength=len(xy))[cen]
        ok = (n_stars_near == 1) & (n_claims == 1)
        star, cen = star[ok], cen[ok]
        if len(cen) < max(4, len(current[0]) // 2):
            break  # re-matching lost stars: keep what identification verified
        r = v[star]
        new = fit_camera(xy[cen], r, cam, A, fit.params)
        keep = inliers(np.hypot(*new.residuals_px.T), 0.1)
        if keep.sum() < 4:
            break
        fit = fit_camera(xy[cen][keep], r[keep], cam, A, fit.params)
        current = (cen[keep], np.asarray(database.star_ids)[near[star]][keep], r[keep],
                   np.asarray(database.star_mag, dtype=np.float64)[near[star]][keep])
    return (fit, *current)
