"""The camera model's arithmetic, once: pinhole + Brown–Conrady, or Kannala–Brandt (the
equidistant fisheye) — :class:`skyfix.camera.Camera`.

Every numba kernel that projects or back-projects calls these helpers, and so do the readable
methods (``Camera.distort``, ``undistort``, ``pixel_to_ray``, ``ray_to_pixel``): one copy of
each formula. A kernel takes a camera as its twelve numbers (:func:`camera_numbers`), indexed by
the names below; the last, ``PROJECTION``, says which projection (:data:`PINHOLE` or
:data:`KANNALA_BRANDT`), and each helper branches on it once.

Model. A camera-frame ray ``(X, Y, Z)`` has normalised coordinates ``x = X/Z``, ``y = Y/Z``,
``r² = x² + y²``; the projection maps them to distorted normalised coordinates ``(x_d, y_d)``
(:func:`distort`, the one step that differs), and then to the pixel::

    u = fx·x_d + skew·y_d + cx,   v = fy·y_d + cy

- ``pinhole`` (code 0): Brown–Conrady, OpenCV's ``cv::projectPoints``::

      radial = 1 + k1 r² + k2 r⁴ + k3 r⁶
      x_d = x·radial + 2 p1 x y + p2 (r² + 2x²)
      y_d = y·radial + p1 (r² + 2y²) + 2 p2 x y

- ``kannala-brandt`` (code 1): OpenCV's ``cv::fisheye``, ``θ = atan r`` the ray's angle from
  the boresight::

      θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)                        (kb_theta_d)
      (x_d, y_d) = (θ_d / r)·(x, y)          ((x, y) itself at r = 0)

  so ``|(x_d, y_d)| = θ_d``: with square pixels a star lies ``f·θ_d`` pixels from the principal
  point. All ``k = 0`` is the equidistant projection, ``f·θ``. ``p1, p2`` are unused (0).

Inverse (pixel → ray). The pixel gives ``(x_d, y_d)`` by inverting ``K`` (:func:`pixel_to_distorted`).
Brown–Conrady is inverted by fixed-point iteration on ``(x, y)`` (:func:`undistort`).
Kannala–Brandt is radial: ``r_d = |(x_d, y_d)| = θ_d``, and :func:`kb_theta` solves
``θ_d(θ) = r_d`` for ``θ`` by Newton's method, safeguarded by bisection in a bracket found on a
coarse grid of ``[0, π]`` (on the branch rising from 0 when the polynomial folds back); then the ray
is ``(sin θ·x_d/r_d, sin θ·y_d/r_d, cos θ)`` and ``(x, y) = tan θ·(x_d, y_d)/r_d``.

Angles near and beyond 90°. ``x = X/Z`` cannot express a ray at ``θ ≥ 90°``. :func:`project_rays`
treats every projection alike: a ray with ``Z ≤ 1e-9`` is not in front (``front`` False) and
its pixel is not meaningful. :func:`pixel_rays` gives a Kannala–Brandt pixel its true ray at any
``θ < π`` (a fisheye frame's corners may lie past 90°), while :func:`pixels_to_normalized` and
:func:`undistort` give NaN there. A pixel whose ``r_d`` the polynomial never reaches has a NaN
ray. ``Camera`` keeps the horizontal field under 170° (``θ < 85°`` at the frame's side edges).

Derivatives for least squares. With ``(e_x, e_y) = (x, y)/r``:

- ``∂(u, v)/∂fx = (x_d, 0)``, ``∂fy: (0, y_d)``, ``∂cx: (1, 0)``, ``∂cy: (0, 1)``,
  ``∂skew: (y_d, 0)`` — either projection;
- ``∂(x_d, y_d)/∂(x, y)``: :func:`distort_jacobian`, either projection (chain it with
  ``∂(x, y)/∂ray`` for the attitude). For Kannala–Brandt, with ``s = θ_d/r`` and
  ``θ_d' = dθ_d/dθ = 1 + 3k1 θ² + 5k2 θ⁴ + 7k3 θ⁶ + 9k4 θ⁸``: ``∂x_d/∂x = s + x² g``,
  ``∂x_d/∂y = ∂y_d/∂x = x y g``, ``∂y_d/∂y = s + y² g``, ``g = (θ_d'/(1 + r²) − s)/r²``
  (→ ``2(k1 − 1/3)`` as ``r → 0``);
- Kannala–Brandt's coefficients: ``∂(x_d, y_d)/∂k_j = θ^(2j+1)·(e_x, e_y)``, so
  ``∂u/∂k_j = (fx e_x + skew e_y) θ^(2j+1)``, ``∂v/∂k_j = fy e_y θ^(2j+1)``
  (:func:`kb_coefficient_terms` inside a kernel, :func:`kb_pixel_jacobian` for arrays).
"""

from __future__ import annotations

import math
import operator

import numpy as np

from skyfix._jit import njit

__all__ = ["CAMERA_NUMBERS", "CX", "CY", "FX", "FY", "K1", "K2", "K3", "K4", "KANNALA_BRANDT", "P1", "P2",
           "PINHOLE", "PROJECTION", "SKEW", "brown_conrady", "camera_numbers", "distort",
           "distort_jacobian", "distort_points", "k1_offset", "kannala_brandt", "kannala_brandt_jacobian",
           "kb_coefficient_terms", "kb_pixel_jacobian", "kb_theta", "kb_theta_d", "offset_ray",
           "pixel_rays", "pixel_to_distorted", "pixels_to_normalized", "project_rays", "undistort"]

# The camera's numbers as kernels take them, in this order (Camera's attribute names).
CAMERA_NUMBERS = ("fx", "fy", "cx", "cy", "skew", "k1", "k2", "k3", "p1", "p2", "k4", "projection_code")
FX, FY, CX, CY, SKEW, K1, K2, K3, P1, P2, K4, PROJECTION = range(12)

# The projection codes at PROJECTION, floats as the numbers are (Camera names them:
# skyfix.camera.PROJECTIONS).
PINHOLE = 0.0
KANNALA_BRANDT = 1.0

# Undistortion: fixed-point iteration stopped when no point moves by this many pixels.
UNDISTORT_TOLERANCE_PX = 1e-5
UNDISTORT_ITERATIONS = 50
# Kannala–Brandt's θ: the bracket's coarse grid over [0, π], and Newton/bisection stopped at a
# step under this many radians (1e-10 px at f = 10⁴ px). Kannala–Brandt's helpers that a
# kernel's loop calls (kannala_brandt, kannala_brandt_jacobian, kb_theta) are compiled once,
# not inlined: every kernel that projects also compiles the branch it does not take, and inlined
# they added 2-4 s CPU to a fresh cache's compile of lens and camera_fit, against 1-2 s.
KB_GRID = 16
KB_THETA_TOLERANCE = 1e-14
KB_ITERATIONS = 100


_numbers_of = operator.attrgetter(*CAMERA_NUMBERS)


@njit(cache=True, inline="always")
def offset_ray(x, y, f):
    """Unit camera ray of the pixel offset ``(x, y)`` from the principal point at focal length
    ``f`` (identification's square-pixel pinhole): ``(x/f, y/f, 1) / |(x/f, y/f, 1)|``."""
    xn = x / f
    yn = y / f
    n = np.sqrt(xn * xn + yn * yn + 1.0)
    return xn / n, yn / n, 1.0 / n


@njit(cache=True, inline="always")
def k1_offset(xn, yn, f, k1):
    """Pixel offset from the principal point of normalised ``(xn, yn)`` under identification's
    reduced model — one focal length, radial ``k1`` only: ``(x, y) = f·(xn, yn)·(1 + k1 r²)``."""
    radial = f * (1.0 + k1 * (xn * xn + yn * yn))
    return xn * radial, yn * radial


def camera_numbers(camera) -> np.ndarray:
    """A :class:`~skyfix.camera.Camera`'s numbers (12,) float64 in :data:`CAMERA_NUMBERS` order."""
    return np.array(_numbers_of(camera), dtype=np.float64)


@njit(cache=True, inline="always")
def kb_theta_d(theta, cam):
    """Kannala–Brandt's ``θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)`` and ``dθ_d/dθ``."""
    t2 = theta * theta
    poly = 1.0 + t2 * (cam[K1] + t2 * (cam[K2] + t2 * (cam[K3] + t2 * cam[K4])))
    slope = 1.0 + t2 * (3.0 * cam[K1] + t2 * (5.0 * cam[K2] + t2 * (7.0 * cam[K3] + t2 * 9.0 * cam[K4])))
    return theta * poly, slope


@njit(cache=True)
def kb_theta(rd, cam):
    """The angle ``θ`` from the boresight whose ``θ_d`` is ``rd`` (≥ 0): the root in ``[0, π]``
    in the first step of a grid of :data:`KB_GRID` where ``θ_d`` reaches ``rd``, by Newton's
    method safeguarded by bisection to :data:`KB_THETA_TOLERANCE`; NaN when ``θ_d`` never
    reaches ``rd`` in ``[0, π]``."""
    if rd == 0.0:
        return 0.0
    lo = 0.0
    hi = math.nan
    for j in range(1, KB_GRID + 1):
        t = math.pi * j / KB_GRID
        if kb_theta_d(t, cam)[0] >= rd:
            hi = t
            break
        lo = t
    if not hi == hi:  # NaN: no root (or rd is NaN)
        return math.nan
    theta = min(max(rd, lo), hi)  # θ_d ≈ θ: a good first guess
    for _ in range(KB_ITERATIONS):
        td, slope = kb_theta_d(theta, cam)
        f = td - rd
        if f == 0.0:
            return theta
        if f < 0.0:
            lo = theta
        else:
            hi = theta
        new = 0.5 * (lo + hi)  # bisection, unless Newton's step stays in the bracket
        if slope > 0.0 and lo <= theta - f / slope <= hi:
            new = theta - f / slope
        if abs(new - theta) <= KB_THETA_TOLERANCE:
            return new
        theta = new
    return theta


@njit(cache=True, inline="always")
def kb_coefficient_terms(x, y):
    """Kannala–Brandt: ``θ³·(e_x, e_y)`` and ``θ²`` at normalised ``(x, y)``, so that
    ``∂(x_d, y_d)/∂k_j = θ³·(e_x, e_y)·(θ²)^(j−1)`` (``(e_x, e_y) = (x, y)/r``; 0 at ``r = 0``)."""
    r2 = x * x + y * y
    if r2 == 0.0:
        return 0.0, 0.0, 0.0
    r = np.sqrt(r2)
    theta = math.atan(r)
    t3 = theta * theta * theta / r
    return x * t3, y * t3, theta * theta


@njit(cache=True, inline="always")
def pixel_to_distorted(u, v, cam):
    """Distorted normalised ``(x_d, y_d)`` of the pixel ``(u, v)`` (``K`` inverted)."""
    yd = (v - cam[CY]) / cam[FY]
    return (u - cam[CX] - cam[SKEW] * yd) / cam[FX], yd


@njit(cache=True, inline="always")
def brown_conrady(x, y, cam):
    """The pinhole's distorted normalised coordinates of undistorted ``(x, y)``."""
    r2 = x * x + y * y
    radial = 1.0 + r2 * (cam[K1] + r2 * (cam[K2] + r2 * cam[K3]))
    xd = x * radial + 2.0 * cam[P1] * x * y + cam[P2] * (r2 + 2.0 * x * x)
    yd = y * radial + cam[P1] * (r2 + 2.0 * y * y) + 2.0 * cam[P2] * x * y
    return xd, yd


@njit(cache=True)
def kannala_brandt(x, y, cam):
    """Kannala–Brandt's distorted normalised coordinates ``(θ_d/r)·(x, y)`` of ``(x, y)``."""
    r2 = x * x + y * y
    if r2 == 0.0:
        return x, y
    r = np.sqrt(r2)
    s = kb_theta_d(math.atan(r), cam)[0] / r
    return x * s, y * s


@njit(cache=True, inline="always")
def distort(x, y, cam):
    """Distorted normalised coordinates of undistorted ``(x, y)``: the camera's projection's
    (:func:`brown_conrady` or :func:`kannala_brandt`)."""
    if cam[PROJECTION] == KANNALA_BRANDT:
        return kannala_brandt(x, y, cam)
    return brown_conrady(x, y, cam)


@njit(cache=True)
def kannala_brandt_jacobian(x, y, cam):
    """:func:`kannala_brandt` and its derivatives, as :func:`distort_jacobian` gives them."""
    r2 = x * x + y * y
    if r2 == 0.0:
        return x, y, 1.0, 0.0, 0.0, 1.0, r2
    r = np.sqrt(r2)
    td, slope = kb_theta_d(math.atan(r), cam)
    s = td / r
    g = (slope / (1.0 + r2) - s) / r2
    return x * s, y * s, s + x * x * g, x * y * g, x * y * g, s + y * y * g, r2


@njit(cache=True, inline="always")
def distort_jacobian(x, y, cam):
    """:func:`distort` and its derivatives: ``(xd, yd, ∂xd/∂x, ∂xd/∂y, ∂yd/∂x, ∂yd/∂y, r²)``."""
    if cam[PROJECTION] == KANNALA_BRANDT:
        return kannala_brandt_jacobian(x, y, cam)
    r2 = x * x + y * y
    k1, k2, k3, p1, p2 = cam[K1], cam[K2], cam[K3], cam[P1], cam[P2]
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r²
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    dxx = radial + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x
    dxy = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
    dyy = radial + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x
    return xd, yd, dxx, dxy, dxy, dyy, r2


@njit(cache=True)
def distort_points(x, y, cam):
    """:func:`distort` for arrays ``x``, ``y`` (N,): new arrays ``(xd, yd)`` (the projection
    chosen once, so that the pinhole's loop vectorises)."""
    n = x.shape[0]
    xd = np.empty(n)
    yd = np.empty(n)
    if cam[PROJECTION] == KANNALA_BRANDT:
        for i in range(n):
            xd[i], yd[i] = kannala_brandt(x[i], y[i], cam)
        return xd, yd
    for i in range(n):
        xd[i], yd[i] = brown_conrady(x[i], y[i], cam)
    return xd, yd


@njit(cache=True)
def _kb_undistort(xd, yd, cam):
    """Kannala–Brandt's :func:`undistort`: ``(x, y) = tan θ·(x_d, y_d)/r_d``, NaN at ``θ ≥ 90°``."""
    n = xd.shape[0]
    x = np.empty(n)
    y = np.empty(n)
    for i in range(n):
        rd = np.sqrt(xd[i] * xd[i] + yd[i] * yd[i])
        theta = kb_theta(rd, cam)
        if rd == 0.0:
            s = 1.0
        elif theta < 0.5 * math.pi:
            s = math.tan(theta) / rd
        else:
            s = math.nan
        x[i] = xd[i] * s
        y[i] = yd[i] * s
    return x, y


@njit(cache=True)
def undistort(xd, yd, cam):
    """Invert :func:`distort` for arrays ``xd``, ``yd`` (N,); returns new arrays ``(x, y)``.
    Brown–Conrady by fixed-point iteration, stopped when no point moves by
    :data:`UNDISTORT_TOLERANCE_PX` (at most :data:`UNDISTORT_ITERATIONS` steps);
    Kannala–Brandt through :func:`kb_theta`, NaN where ``θ ≥ 90°``."""
    if cam[PROJECTION] == KANNALA_BRANDT:
        return _kb_undistort(xd, yd, cam)
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


@njit(cache=True)
def pixels_to_normalized(xy, cam):
    """Undistorted normalised coordinates ``(x, y)`` (two (N,) arrays) of pixels ``xy`` (N, 2)."""
    n = xy.shape[0]
    xd = np.empty(n)
    yd = np.empty(n)
    for i in range(n):
        xd[i], yd[i] = pixel_to_distorted(xy[i, 0], xy[i, 1], cam)
    return undistort(xd, yd, cam)


@njit(cache=True)
def pixel_rays(xy, cam):
    """Unit camera-frame rays (N, 3) of pixels ``xy`` (N, 2); Kannala–Brandt's at any ``θ < π``
    (NaN where the polynomial does not reach the pixel)."""
    n = xy.shape[0]
    b = np.empty((n, 3))
    if cam[PROJECTION] == KANNALA_BRANDT:
        for i in range(n):
            xd, yd = pixel_to_distorted(xy[i, 0], xy[i, 1], cam)
            rd = np.sqrt(xd * xd + yd * yd)
            theta = kb_theta(rd, cam)
            s = math.sin(theta) / rd if rd > 0.0 else 0.0
            b[i, 0] = xd * s
            b[i, 1] = yd * s
            b[i, 2] = math.cos(theta)
        return b
    xn, yn = pixels_to_normalized(xy, cam)
    for i in range(n):
        norm = np.sqrt(xn[i] * xn[i] + yn[i] * yn[i] + 1.0)
        b[i, 0] = xn[i] / norm
        b[i, 1] = yn[i] / norm
        b[i, 2] = 1.0 / norm
    return b


@njit(cache=True)
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


@njit(cache=True)
def kb_pixel_jacobian(rays, cam):
    """Kannala–Brandt: ``∂(u, v)/∂(k1, k2, k3, k4)`` (N, 2, 4) of camera-frame rays (N, 3) in
    front: ``∂u/∂k_j = (fx e_x + skew e_y) θ^(2j+1)``, ``∂v/∂k_j = fy e_y θ^(2j+1)``."""
    n = rays.shape[0]
    J = np.empty((n, 2, 4))
    for i in range(n):
        tx, ty, t2 = kb_coefficient_terms(rays[i, 0] / rays[i, 2], rays[i, 1] / rays[i, 2])
        for j in range(4):
            J[i, 0, j] = cam[FX] * tx + cam[SKEW] * ty
            J[i, 1, j] = cam[FY] * ty
            tx *= t2
            ty *= t2
    return J
