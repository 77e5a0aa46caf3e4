"""The camera model's arithmetic, once: pinhole + Brown–Conrady (:class:`skyfix.camera.Camera`).

Every numba kernel that projects or back-projects calls these helpers, and so do the readable
methods (``Camera.distort``, ``undistort``, ``pixel_to_ray``, ``ray_to_pixel``): one copy of
each formula. A kernel takes a camera as its ten numbers (:func:`camera_numbers`), indexed by
the names below.

Model (normalised coordinates ``x = X/Z``, ``y = Y/Z``, ``r² = x² + y²``)::

    radial = 1 + k1 r² + k2 r⁴ + k3 r⁶
    x_d = x·radial + 2 p1 x y + p2 (r² + 2x²)
    y_d = y·radial + p1 (r² + 2y²) + 2 p2 x y
    u = fx·x_d + skew·y_d + cx,   v = fy·y_d + cy
"""

from __future__ import annotations

import operator

import numba
import numpy as np

__all__ = ["CAMERA_NUMBERS", "CX", "CY", "FX", "FY", "K1", "K2", "K3", "P1", "P2", "SKEW", "camera_numbers",
           "distort", "distort_jacobian", "distort_points", "k1_offset", "offset_ray", "pixel_rays",
           "pixels_to_normalized", "project_rays", "undistort"]

# The camera's numbers as kernels take them, in this order (Camera's field names).
CAMERA_NUMBERS = ("fx", "fy", "cx", "cy", "skew", "k1", "k2", "k3", "p1", "p2")
FX, FY, CX, CY, SKEW, K1, K2, K3, P1, P2 = range(10)

# Undistortion: fixed-point iteration stopped when no point moves by this many pixels.
UNDISTORT_TOLERANCE_PX = 1e-5
UNDISTORT_ITERATIONS = 50


_numbers_of = operator.attrgetter(*CAMERA_NUMBERS)


@numba.njit(cache=True, inline="always")
def offset_ray(x, y, f):
    """Unit camera ray of the pixel offset ``(x, y)`` from the principal point at focal length
    ``f`` (identification's square-pixel pinhole): ``(x/f, y/f, 1) / |(x/f, y/f, 1)|``."""
    xn = x / f
    yn = y / f
    n = np.sqrt(xn * xn + yn * yn + 1.0)
    return xn / n, yn / n, 1.0 / n


@numba.njit(cache=True, inline="always")
def k1_offset(xn, yn, f, k1):
    """Pixel offset from the principal point of normalised ``(xn, yn)`` under identification's
    reduced model — one focal length, radial ``k1`` only: ``(x, y) = f·(xn, yn)·(1 + k1 r²)``."""
    radial = f * (1.0 + k1 * (xn * xn + yn * yn))
    return xn * radial, yn * radial


def camera_numbers(camera) -> np.ndarray:
    """A :class:`~skyfix.camera.Camera`'s numbers (10,) float64 in :data:`CAMERA_NUMBERS` order."""
    return np.array(_numbers_of(camera), dtype=np.float64)


@numba.njit(cache=True, inline="always")
def distort(x, y, cam):
    """Brown–Conrady: distorted normalised coordinates of undistorted ``(x, y)``."""
    r2 = x * x + y * y
    radial = 1.0 + r2 * (cam[K1] + r2 * (cam[K2] + r2 * cam[K3]))
    xd = x * radial + 2.0 * cam[P1] * x * y + cam[P2] * (r2 + 2.0 * x * x)
    yd = y * radial + cam[P1] * (r2 + 2.0 * y * y) + 2.0 * cam[P2] * x * y
    return xd, yd


@numba.njit(cache=True, inline="always")
def distort_jacobian(x, y, cam):
    """:func:`distort` and its derivatives: ``(xd, yd, ∂xd/∂x, ∂xd/∂y, ∂yd/∂x, ∂yd/∂y, r²)``."""
    k1, k2, k3, p1, p2 = cam[K1], cam[K2], cam[K3], cam[P1], cam[P2]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r²
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    dxx = radial + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x
    dxy = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
    dyy = radial + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x
    return xd, yd, dxx, dxy, dxy, dyy, r2


@numba.njit(cache=True)
def distort_points(x, y, cam):
    """:func:`distort` for arrays ``x``, ``y`` (N,): new arrays ``(xd, yd)``."""
    n = x.shape[0]
    xd = np.empty(n)
    yd = np.empty(n)
    for i in range(n):
        xd[i], yd[i] = distort(x[i], y[i], cam)
    return xd, yd


@numba.njit(cache=True)
def undistort(xd, yd, cam):
    """Invert :func:`distort` for arrays ``xd``, ``yd`` (N,) by fixed-point iteration, stopped
    when no point moves by :data:`UNDISTORT_TOLERANCE_PX` (at most
    :data:`UNDISTORT_ITERATIONS` steps). Returns new arrays ``(x, y)``."""
    n = xd.shape[0]
    xn = xd.copy()
    yn = yd.copy()
    if cam[K1] == 0.0 and cam[K2] == 0.0 and cam[K3] == 0.0 and cam[P1] == 0.0 and cam[P2] == 0.0:
        return xn, yn
    tol = UNDISTORT_TOLERANCE_PX / max(cam[FX], cam[FY])
    xs = np.empty(n)
    ys = np.empty(n)
    for _ in range(UNDISTORT_ITERATIONS):
        step = 0.0
        for i in range(n):
            x, y = xn[i], yn[i]
            r2 = x * x + y * y
            radial = 1.0 + r2 * (cam[K1] + r2 * (cam[K2] + r2 * cam[K3]))
            dx = 2.0 * cam[P1] * x * y + cam[P2] * (r2 + 2.0 * x * x)
            dy = cam[P1] * (r2 + 2.0 * y * y) + 2.0 * cam[P2] * x * y
            xs[i] = (xd[i] - dx) / radial
            ys[i] = (yd[i] - dy) / radial
            step = max(step, abs(xs[i] - x) + abs(ys[i] - y))
        xn, xs = xs, xn
        yn, ys = ys, yn
        if step < tol:
            break
    return xn, yn


@numba.njit(cache=True)
def pixels_to_normalized(xy, cam):
    """Undistorted normalised coordinates ``(x, y)`` (two (N,) arrays) of pixels ``xy`` (N, 2)."""
    n = xy.shape[0]
    xd = np.empty(n)
    yd = np.empty(n)
    for i in range(n):
        yd[i] = (xy[i, 1] - cam[CY]) / cam[FY]
        xd[i] = (xy[i, 0] - cam[CX] - cam[SKEW] * yd[i]) / cam[FX]
    return undistort(xd, yd, cam)


@numba.njit(cache=True)
def pixel_rays(xy, cam):
    """Unit camera-frame rays (N, 3) of pixels ``xy`` (N, 2)."""
    xn, yn = pixels_to_normalized(xy, cam)
    n = xy.shape[0]
    b = np.empty((n, 3))
    for i in range(n):
        norm = np.sqrt(xn[i] * xn[i] + yn[i] * yn[i] + 1.0)
        b[i, 0] = xn[i] / norm
        b[i, 1] = yn[i] / norm
        b[i, 2] = 1.0 / norm
    return b


@numba.njit(cache=True)
def project_rays(rays, cam):
    """Pixels (N, 2) of camera-frame rays (N, 3) and whether each is in front (``Z > 1e-9``);
    a ray behind the camera is projected as if its ``Z`` were 1."""
    n = rays.shape[0]
    uv = np.empty((n, 2))
    front = np.empty(n, dtype=np.bool_)
    for i in range(n):
        z = rays[i, 2]
        front[i] = z > 1e-9
        zs = z if front[i] else 1.0
        xd, yd = distort(rays[i, 0] / zs, rays[i, 1] / zs, cam)
        uv[i, 0] = cam[FX] * xd + cam[SKEW] * yd + cam[CX]
        uv[i, 1] = cam[FY] * yd + cam[CY]
    return uv, front
