"""The camera fit's model and its derivatives, for :mod:`skyfix._kernels.camera_fit` (the model
scoring and the Gauss–Newton under a prior), :mod:`skyfix.calibrate` and
:mod:`skyfix.calibration.joint`: a parameter step applied to the camera numbers, the residuals after
steps, and the projection's Jacobian for the rotations and the camera parameters. The projection
itself is :mod:`skyfix._kernels.lens`'s; rotations are :mod:`skyfix._kernels.rotation`'s.

Camera parameters are chosen by name in :data:`skyfix.calibrate.CAMERA_PARAMETERS`; inside the
kernels each has the code below. A parameter step ``p`` is (three rotations of the camera frame,
then each chosen parameter's numbers) in scaled units, so that a unit step moves the frame's
corner by about a focal length: ``f`` relative (``fx, fy ← f·(1 + p)``), ``aspect`` relative on
``fy``, the principal point in focal lengths, ``k_j`` in ``1/rmax^(2j)`` (``k1`` in ``1/rmax²`` …
``k4`` in ``1/rmax⁸``), ``p1, p2`` in ``1/rmax`` (``rmax`` the half-diagonal over ``fx``: for a
Kannala–Brandt camera the corner's ``θ_d``, about its angle off axis).

The radial coefficients' derivatives are the camera's projection's: Brown–Conrady's
``∂(x_d, y_d)/∂k_j = (x, y)·r^(2j)`` for a pinhole (``k4`` is not its), Kannala–Brandt's
``θ³·(e_x, e_y)·(θ²)^(j−1)`` (:func:`skyfix._kernels.lens.kb_coefficient_terms`, the formula
``lens.kb_pixel_jacobian`` also uses) for a fisheye; the pinhole's arithmetic is that of before
the fisheye was added, operation for operation, so its fits are bit-identical.
"""

from __future__ import annotations

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.lens import (
    CX,
    CY,
    FX,
    FY,
    K1,
    K2,
    K3,
    K4,
    KANNALA_BRANDT,
    P1,
    P2,
    PROJECTION,
    SKEW,
    distort,
    distort_jacobian,
    kb_coefficient_terms,
)
from skyfix._kernels.rotation import rodrigues

__all__ = ["ASPECT", "F", "K1_TERM", "K2_TERM", "K3_TERM", "K4_TERM", "PRINCIPAL_POINT", "TANGENTIAL",
           "apply_step", "code_size", "jacobian_rows", "normal_equations_at_start", "residuals_for_steps"]

# Kernel codes of the camera parameters (skyfix.calibrate.CAMERA_PARAMETERS names them).
# The radial terms are consecutive: k_j's code is K1_TERM + j − 1.
F, ASPECT, PRINCIPAL_POINT, K1_TERM, K2_TERM, K3_TERM, K4_TERM, TANGENTIAL = range(8)


@njit(cache=True)
def code_size(c):
    """How many numbers (step columns) the parameter of code ``c`` is."""
    return 2 if (c == PRINCIPAL_POINT or c == TANGENTIAL) else 1


@njit(cache=True)
def apply_step(cam, rmax, codes, p):
    """The camera numbers (:data:`skyfix._kernels.lens.CAMERA_NUMBERS`) after the parameter
    step ``p`` (rotations first, then ``codes``, in the scaled units of the module text)."""
    out = cam.copy()
    j = 3
    for c in codes:
        if c == F:
            out[FX], out[FY] = cam[FX] * (1.0 + p[j]), cam[FY] * (1.0 + p[j])
        elif c == ASPECT:
            out[FY] = out[FY] * (1.0 + p[j])
        elif c == PRINCIPAL_POINT:
            out[CX], out[CY] = cam[CX] + p[j] * cam[FX], cam[CY] + p[j + 1] * cam[FX]
            j += 1
        elif c == K1_TERM:
            out[K1] = cam[K1] + p[j] / rmax**2
        elif c == K2_TERM:
            out[K2] = cam[K2] + p[j] / rmax**4
        elif c == K3_TERM:
            out[K3] = cam[K3] + p[j] / rmax**6
        elif c == K4_TERM:
            out[K4] = cam[K4] + p[j] / rmax**8
        else:  # TANGENTIAL
            out[P1], out[P2] = cam[P1] + p[j] / rmax, cam[P2] + p[j + 1] / rmax
            j += 1
        j += 1
    return out


@njit(cache=True)
def residuals_for_steps(cam, rmax, codes, ps, rays0, xy):
    """Residuals (K, 2N), (u, v) of each star in turn, of the stars ``xy`` against the rays
    ``rays0`` rotated and projected through the camera ``cam`` after each parameter step of
    ``ps`` (K, P) (parameters ``codes``)."""
    n = xy.shape[0]
    out = np.empty((ps.shape[0], 2 * n))
    for k in range(ps.shape[0]):
        p = ps[k]
        R = rodrigues(p)
        c = apply_step(cam, rmax, codes, p)
        for i in range(n):
            X = R[0, 0] * rays0[i, 0] + R[0, 1] * rays0[i, 1] + R[0, 2] * rays0[i, 2]
            Y = R[1, 0] * rays0[i, 0] + R[1, 1] * rays0[i, 1] + R[1, 2] * rays0[i, 2]
            Z = R[2, 0] * rays0[i, 0] + R[2, 1] * rays0[i, 1] + R[2, 2] * rays0[i, 2]
            xd, yd = distort(X / Z, Y / Z, c)
            out[k, 2 * i] = c[FX] * xd + c[SKEW] * yd + c[CX] - xy[i, 0]
            out[k, 2 * i + 1] = c[FY] * yd + c[CY] - xy[i, 1]
    return out


@njit(cache=True)
def jacobian_rows(xy, rays0, cam, rmax, codes):
    """The Jacobian ``J`` (N, 2, P) and residuals (N, 2) at ``p = 0`` (the camera ``cam`` and the
    rays ``rays0``) for the parameters ``codes``, in the scaled units of the module text
    (``tests/_kernels/test_final_fit_kernels.py`` holds it to finite differences of
    :func:`residuals_for_steps`)."""
    fx, fy, cx, cy, s = cam[FX], cam[FY], cam[CX], cam[CY], cam[SKEW]
    P = 3
    for c in codes:
        P += code_size(c)
    c1, c2, c4 = 1.0 / rmax, 1.0 / rmax**2, 1.0 / rmax**4
    c6 = 1.0 / rmax**6
    fisheye = cam[PROJECTION] == KANNALA_BRANDT
    tx = ty = t2 = 0.0
    J = np.empty((xy.shape[0], 2, P))
    res = np.empty((xy.shape[0], 2))
    for i in range(xy.shape[0]):
        X, Y, Z = rays0[i, 0], rays0[i, 1], rays0[i, 2]
        iz = 1.0 / Z
        xn = X * iz
        yn = Y * iz
        # (xd, yd) and d(xd, yd) / d(xn, yn)
        xd, yd, dxx, dxy, dyx, dyy, r2 = distort_jacobian(xn, yn, cam)
        res[i, 0] = fx * xd + s * yd + cx - xy[i, 0]
        res[i, 1] = fy * yd + cy - xy[i, 1]
        if fisheye:  # ∂(x_d, y_d)/∂k1 = θ³·(e_x, e_y); each next k_j another θ²
            tx, ty, t2 = kb_coefficient_terms(xn, yn)
        ju = J[i, 0]
        jv = J[i, 1]
        # Rotations ω = e_x, e_y, e_z of the camera frame (δray = ω × ray): d(xn, yn).
        for k in range(3):
            if k == 0:
                dxn, dyn = -xn * yn, -1.0 - yn * yn
            elif k == 1:
                dxn, dyn = 1.0 + xn * xn, yn * xn
            else:
                dxn, dyn = -yn, xn
            dxd = dxx * dxn + dxy * dyn
            dyd = dyx * dxn + dyy * dyn
            ju[k] = fx * dxd + s * dyd
            jv[k] = fy * dyd
        j = 3
        for c in codes:
            if c == F:
                ju[j], jv[j] = fx * xd + s * yd, fy * yd
            elif c == ASPECT:
                ju[j], jv[j] = 0.0, fy * yd
            elif c == PRINCIPAL_POINT:
                ju[j], jv[j] = fx, 0.0
                j += 1
                ju[j], jv[j] = 0.0, fx
            elif fisheye and K1_TERM <= c <= K4_TERM:  # θ³·(e_x, e_y)·(θ²)^(j−1) / rmax^(2j)
                ax, ay, scale = tx, ty, c2
                for _ in range(c - K1_TERM):
                    ax *= t2
                    ay *= t2
                    scale *= c2
                ju[j], jv[j] = (fx * ax + s * ay) * scale, fy * ay * scale
            elif c == K1_TERM:
                ju[j], jv[j] = (fx * xn + s * yn) * r2 * c2, fy * yn * r2 * c2
            elif c == K2_TERM:
                ju[j], jv[j] = (fx * xn + s * yn) * r2 * r2 * c4, fy * yn * r2 * r2 * c4
            elif c == K3_TERM:  # a pinhole's r⁶ term (K4_TERM is not a pinhole's)
                ju[j], jv[j] = (fx * xn + s * yn) * r2 * r2 * r2 * c6, fy * yn * r2 * r2 * r2 * c6
            else:  # TANGENTIAL
                ta, tb = 2.0 * xn * yn, r2 + 2.0 * yn * yn
                ju[j], jv[j] = (fx * ta + s * tb) * c1, fy * tb * c1
                j += 1
                ta, tb = r2 + 2.0 * xn * xn, 2.0 * xn * yn
                ju[j], jv[j] = (fx * ta + s * tb) * c1, fy * tb * c1
            j += 1
    return J, res


@njit(cache=True)
def normal_equations_at_start(xy, rays0, cam, rmax, codes):
    """``JᵀJ`` (P, P), ``Jᵀr`` (P,) and ``rᵀr`` at ``p = 0`` for the parameters ``codes``
    from :func:`jacobian_rows`."""
    J, res = jacobian_rows(xy, rays0, cam, rmax, codes)
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
