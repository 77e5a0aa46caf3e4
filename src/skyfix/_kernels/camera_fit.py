"""The camera fit's kernels, for :mod:`skyfix.calibrate`: the projection's Jacobian for the
camera parameters, least-squares scoring of camera models, and the Gauss–Newton of the fit
under a prior. The projection itself is :mod:`skyfix._kernels.lens`'s; rotations and small
inverses are :mod:`skyfix._kernels.rotation`'s.

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

import math
from typing import NamedTuple

import numba
import numpy as np

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
from skyfix._kernels.rotation import cholesky, rodrigues, spd_inverse

__all__ = ["ASPECT", "F", "HELD_SHIFT_CHI2", "K1_TERM", "K2_TERM", "K3_TERM", "K4_TERM", "KB_PRIOR_CODES",
           "MODEL_CHANGES", "OUTLIER_CHI2", "PP_AUTO", "PP_CHI2", "PP_FIT", "PP_HOLD", "PRINCIPAL_POINT",
           "PRIOR_CODES", "PRIOR_NUMBERS", "STEP_CX", "STEP_CY", "TANGENTIAL", "TANGENTIAL_PRIOR_CODES",
           "GaussNewtonResult", "ModelScores", "PriorFitOptions", "apply_step", "choose_model", "code_size",
           "frame_covariance", "frame_step", "free_columns", "held_shift_chi2", "hold_at_prior",
           "jacobian_rows", "log_evidence", "normal_equations_at_start", "outlier_limit", "prior_codes",
           "prior_gauss_newton", "prior_terms", "residuals_for_steps", "score_blocks", "score_models"]

# Kernel codes of the camera parameters (skyfix.calibrate.CAMERA_PARAMETERS names them).
# The radial terms are consecutive: k_j's code is K1_TERM + j − 1.
F, ASPECT, PRINCIPAL_POINT, K1_TERM, K2_TERM, K3_TERM, K4_TERM, TANGENTIAL = range(8)

# The prior's numbers as prior_gauss_newton takes them (skyfix.calibrate.CameraPrior's fields),
# and their indices.
PRIOR_NUMBERS = ("cx", "cy", "sigma_principal_point_px", "sigma_aspect", "sigma_k1", "sigma_k2", "aspect",
                 "k1", "k2", "sigma_k3", "sigma_k4", "k3", "k4", "sigma_tangential", "p1", "p2")
(PRIOR_CX, PRIOR_CY, SIGMA_PP, SIGMA_ASPECT, SIGMA_K1, SIGMA_K2, PRIOR_ASPECT, PRIOR_K1, PRIOR_K2, SIGMA_K3,
 SIGMA_K4, PRIOR_K3, PRIOR_K4, SIGMA_TANGENTIAL, PRIOR_P1, PRIOR_P2) = range(16)
# The parameters of the fit under a prior (skyfix.calibrate.PRIOR_PARAMETERS), a pinhole's and a
# Kannala–Brandt camera's (k3, k4 too: a fisheye's θ polynomial reaches far past θ = 1), and
# where each sits in its step vector (after the three rotations). A pinhole prior with a
# tangential σ (> 0) fits p1, p2 too (TANGENTIAL_PRIOR_CODES; steps 9, 10 like a fisheye's k3, k4).
PRIOR_CODES = (F, ASPECT, PRINCIPAL_POINT, K1_TERM, K2_TERM)
TANGENTIAL_PRIOR_CODES = (F, ASPECT, PRINCIPAL_POINT, K1_TERM, K2_TERM, TANGENTIAL)
KB_PRIOR_CODES = (F, ASPECT, PRINCIPAL_POINT, K1_TERM, K2_TERM, K3_TERM, K4_TERM)
# The principal point's place in the step of the prior fit (every prior's third parameter).
STEP_CX, STEP_CY = 5, 6

# The fit under a prior (prior_gauss_newton) holds or frees the principal point: PP_HOLD keeps it at
# the prior's, PP_FIT frees it, PP_AUTO frees it only where the stars pin it down: its posterior σ a
# third of the prior's or less and its move beyond PP_CHI2 (χ², 2 dof) of its posterior covariance,
# 1e-3 by chance. (At 30, 3e-7, 5 of 10 000 blind uncalibrated fields were wrong; at 13.8, 2, with the
# same solves: benchmarks/suite_blind.py.)
PP_HOLD, PP_AUTO, PP_FIT = 0, 1, 2
PP_CHI2 = 13.8
# A star whose externally studentised residual (χ², 2 dof) exceeds this, for many stars, is an
# outlier: P = 3.4e-4 for a star that fits, the tail of a 4σ cut (outlier_limit for few stars).
OUTLIER_CHI2 = 16.0
# The model choice by evidence may change the camera numbers fitted this many times in one fit
# (each change refits from the last; a fourth choice would be a cycle).
MODEL_CHANGES = 3
# Numbers held at the prior's values that move the attitude beyond this χ² of their noise
# (held_shift_chi2; 3 dof: 1e-3 by chance) are all freed.
HELD_SHIFT_CHI2 = 16.3



class ModelScores(NamedTuple):
    """:func:`score_models`'s result: which models were scored (K,) bool, their BIC (K,), RSS
    (K,) px² and attitude covariances (K, 3, 3) rad², whether every block inverted by Cholesky
    (else the caller redoes them with numpy), and the union's ``JᵀJ``, ``Jᵀr``, ``rᵀr``."""

    chosen: np.ndarray
    bic: np.ndarray
    rss: np.ndarray
    covariance: np.ndarray
    ok: bool
    JtJ: np.ndarray
    Jtr: np.ndarray
    rr: float


class PriorFitOptions(NamedTuple):
    """How :func:`prior_gauss_newton` fits: Cauchy weights and a median σ (``robust``), the most
    Gauss–Newton steps per round, the smallest σ believed (px), the principal point
    (:data:`PP_HOLD`, :data:`PP_AUTO` or :data:`PP_FIT`), whether the camera numbers fitted are
    chosen by evidence (``select``; never with ``robust``) or all freed, and whether outliers are
    dropped as the fit goes (``drop_outliers``)."""

    robust: bool
    iterations: int
    sigma_floor: float
    principal_point: int
    select: bool
    drop_outliers: bool


class GaussNewtonResult(NamedTuple):
    """:func:`prior_gauss_newton`'s result: the attitude (3, 3), the camera numbers (12,), σ²
    (px²), the posterior covariance (P, P) of the step at the result with every prior parameter
    free and that of the attitude at the principal point's pixel (3, 3, :func:`frame_covariance`),
    its effective number of fitted numbers, the kept stars' residuals (M, 2) px and
    studentised χ² (M,) under the model fitted, the Gauss–Newton step (P,) with every prior
    parameter free from the result, the largest distance (px) the fit moved a kept star's
    predicted position from where the start put it, which stars were kept (N,) and which of
    :func:`prior_codes` were fitted (the others held at the prior's values)."""

    A: np.ndarray
    cam: np.ndarray
    sigma2: float
    covariance: np.ndarray
    attitude_covariance: np.ndarray
    n_effective: float
    residuals: np.ndarray
    chi2: np.ndarray
    step: np.ndarray
    moved: float
    kept: np.ndarray
    fitted: np.ndarray


@numba.njit(cache=True)
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


@numba.njit(cache=True)
def prior_codes(cam, tangential):
    """The parameter codes of the fit under a prior for the camera ``cam``'s projection
    (:data:`PRIOR_CODES`, with ``tangential`` :data:`TANGENTIAL_PRIOR_CODES`, or a Kannala–Brandt
    camera's :data:`KB_PRIOR_CODES`)."""
    if cam[PROJECTION] == KANNALA_BRANDT:
        return np.array(KB_PRIOR_CODES, dtype=np.int64)
    if tangential:
        return np.array(TANGENTIAL_PRIOR_CODES, dtype=np.int64)
    return np.array(PRIOR_CODES, dtype=np.int64)


@numba.njit(cache=True)
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


@numba.njit(cache=True)
def jacobian_rows(xy, rays0, cam, rmax, codes):
    """The Jacobian ``J`` (N, 2, P) and residuals (N, 2) at ``p = 0`` (the camera ``cam`` and the
    rays ``rays0``) for the parameters ``codes``, in the scaled units of the module text
    (``tests/_kernels/test_final_fit_kernels.py`` holds it to finite differences of
    :func:`residuals_for_steps`)."""
    fx, fy, cx, cy, s = cam[FX], cam[FY], cam[CX], cam[CY], cam[SKEW]
    P = 3
    for c in codes:
        P += 2 if (c == PRINCIPAL_POINT or c == TANGENTIAL) else 1
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


@numba.njit(cache=True)
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


@numba.njit(cache=True)
def score_models(xy, r, A, cam, rmax, codes, cols, n_cols, min_stars_per_number):
    """Which models the stars support (see :func:`skyfix.calibrate.score_camera_models`; the
    first scorable always), and their BIC, RSS and covariance (filled for those only): a
    :class:`ModelScores`."""
    n_stars = xy.shape[0]
    rays0 = np.empty((n_stars, 3))
    for i in range(n_stars):
        for j in range(3):
            rays0[i, j] = r[i, 0] * A[j, 0] + r[i, 1] * A[j, 1] + r[i, 2] * A[j, 2]
    JtJ, Jtr, rr = normal_equations_at_start(xy, rays0, cam, rmax, codes)
    chosen = np.zeros(n_cols.shape[0], dtype=np.bool_)
    any_chosen = False
    for m in range(n_cols.shape[0]):
        k = n_cols[m]
        if 2 * n_stars <= k or (n_stars < min_stars_per_number * k and any_chosen):
            continue
        chosen[m] = True
        any_chosen = True
    bic, rss, cov, ok = score_blocks(JtJ, Jtr, rr, 2 * n_stars, cols, n_cols, chosen)
    return ModelScores(chosen, bic, rss, cov, ok, JtJ, Jtr, rr)


@numba.njit(cache=True)
def score_blocks(JtJ, Jtr, rr, n, cols, n_cols, chosen):
    """BIC, RSS and attitude covariance of each chosen model's linear step (see
    :func:`skyfix.calibrate.score_camera_models`); model ``m`` uses the columns ``cols[m, :n_cols[m]]``."""
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
        inv, ok = spd_inverse(sub)
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


@numba.njit(cache=True)
def code_size(c):
    """How many numbers (step columns) the parameter of code ``c`` is."""
    return 2 if (c == PRINCIPAL_POINT or c == TANGENTIAL) else 1


@numba.njit(cache=True)
def prior_terms(cam, rmax, prior, codes):
    """The prior's precision ``λ`` (P,) and the camera's deviation from the prior's value (P,),
    for each step column of the parameters ``codes`` (rotations and ``f`` flat: 0), in the
    scaled units of the module text."""
    P = 3
    for c in codes:
        P += code_size(c)
    lam = np.zeros(P)
    dev = np.zeros(P)
    j = 3
    for c in codes:
        if c == ASPECT:
            lam[j] = 1.0 / prior[SIGMA_ASPECT] ** 2
            dev[j] = cam[FY] / cam[FX] - prior[PRIOR_ASPECT]
        elif c == PRINCIPAL_POINT:
            lam[j] = lam[j + 1] = (cam[FX] / prior[SIGMA_PP]) ** 2
            dev[j] = (cam[CX] - prior[PRIOR_CX]) / cam[FX]
            dev[j + 1] = (cam[CY] - prior[PRIOR_CY]) / cam[FX]
        elif c == K1_TERM:
            lam[j] = 1.0 / (prior[SIGMA_K1] * rmax**2) ** 2
            dev[j] = (cam[K1] - prior[PRIOR_K1]) * rmax**2
        elif c == K2_TERM:
            lam[j] = 1.0 / (prior[SIGMA_K2] * rmax**4) ** 2
            dev[j] = (cam[K2] - prior[PRIOR_K2]) * rmax**4
        elif c == K3_TERM:
            lam[j] = 1.0 / (prior[SIGMA_K3] * rmax**6) ** 2
            dev[j] = (cam[K3] - prior[PRIOR_K3]) * rmax**6
        elif c == K4_TERM:
            lam[j] = 1.0 / (prior[SIGMA_K4] * rmax**8) ** 2
            dev[j] = (cam[K4] - prior[PRIOR_K4]) * rmax**8
        elif c == TANGENTIAL:  # p's step is p·rmax (apply_step)
            lam[j] = lam[j + 1] = 1.0 / (prior[SIGMA_TANGENTIAL] * rmax) ** 2
            dev[j] = (cam[P1] - prior[PRIOR_P1]) * rmax
            dev[j + 1] = (cam[P2] - prior[PRIOR_P2]) * rmax
        j += code_size(c)
    return lam, dev


@numba.njit(cache=True)
def hold_at_prior(cam, prior, c):
    """Set the camera numbers ``cam`` of the parameter of code ``c`` to the prior's values, in
    place (the pixel aspect ``fy/fx`` by ``fy``)."""
    if c == ASPECT:
        cam[FY] = cam[FX] * prior[PRIOR_ASPECT]
    elif c == PRINCIPAL_POINT:
        cam[CX], cam[CY] = prior[PRIOR_CX], prior[PRIOR_CY]
    elif c == K1_TERM:
        cam[K1] = prior[PRIOR_K1]
    elif c == K2_TERM:
        cam[K2] = prior[PRIOR_K2]
    elif c == K3_TERM:
        cam[K3] = prior[PRIOR_K3]
    elif c == K4_TERM:
        cam[K4] = prior[PRIOR_K4]
    elif c == TANGENTIAL:
        cam[P1], cam[P2] = prior[PRIOR_P1], prior[PRIOR_P2]


@numba.njit(cache=True)
def free_columns(codes, free):
    """The step columns, in the layout of all ``codes``, of the rotations and of each code that
    ``free`` (bool, one per code) frees."""
    n = 3
    for k in range(codes.shape[0]):
        if free[k]:
            n += code_size(codes[k])
    cols = np.empty(n, dtype=np.int64)
    cols[0], cols[1], cols[2] = 0, 1, 2
    i, j = 3, 3
    for k in range(codes.shape[0]):
        for _ in range(code_size(codes[k])):
            if free[k]:
                cols[i] = j
                i += 1
            j += 1
    return cols


@numba.njit(cache=True)
def _noise(res, n_eff, robust, sigma_floor, w, vw):
    """σ² (px², of a star of weight 1) from the residuals (N, 2) and the stars' inverse variances
    ``vw`` (N,): their weighted sum of squares over ``2N − n_eff``, or with ``robust`` from their
    lengths' median (a 2-D Gaussian's has median 1.1774 σ), the Cauchy weights
    ``1 / (1 + (d / 3σ)²)`` then written into ``w`` (2N,) (times ``vw``); floored at
    ``sigma_floor``."""
    n = res.shape[0]
    d = np.empty(n)
    ss = 0.0
    for i in range(n):
        d[i] = np.sqrt(res[i, 0] ** 2 + res[i, 1] ** 2)
        ss += vw[i] * d[i] * d[i]
    if robust:
        sigma2 = max((np.median(d) / 1.1774) ** 2, sigma_floor**2)
        for i in range(n):
            w[2 * i] = w[2 * i + 1] = vw[i] / (1.0 + d[i] * d[i] / (9.0 * sigma2))
        return sigma2
    return max(ss / max(2 * n - n_eff, 1.0), sigma_floor**2)


@numba.njit(cache=True)
def _normal_equations(J, res, w):
    """``JᵀWJ`` (P, P) and ``JᵀWr`` (P,) of the Jacobian (N, 2, P), residuals (N, 2) and
    weights (2N,)."""
    n, _, P = J.shape
    JtJ = np.zeros((P, P))
    g = np.zeros(P)
    for i in range(n):
        for c in range(2):
            row = J[i, c]
            wi = w[2 * i + c]
            rc = res[i, c]
            for a in range(P):
                wa = wi * row[a]
                g[a] += wa * rc
                out = JtJ[a]
                for b in range(P):  # the whole row vectorises; the lower triangle is overwritten
                    out[b] += wa * row[b]
    for a in range(P):
        for b in range(a):
            JtJ[a, b] = JtJ[b, a]
    return JtJ, g


@numba.njit(cache=True)
def _posterior(JtJ, g, sigma2, lam, dev):
    """The posterior covariance ``(JᵀWJ/σ² + Λ)⁻¹`` of the step, its effective number of fitted
    numbers (the hat matrix's trace) and the Gauss–Newton step from here."""
    P = lam.shape[0]
    N = JtJ / sigma2
    for a in range(P):
        N[a, a] += lam[a]
    inv, ok = spd_inverse(N)
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
    return inv, n_eff, step


@numba.njit(cache=True)
def _studentised(J, res, inv, cols, w, vw, sigma2, n_eff, robust, sigma_floor):
    """Each star's residual against what the others predict for it (N,): ``v rᵀ (σ² (I − H))⁻¹ r``
    with ``H`` its 2×2 block of the hat matrix ``J (JᵀWJ/σ² + Λ)⁻¹ JᵀW / σ²`` of the model
    whose columns of ``J`` are ``cols`` and posterior ``inv``, ``v`` the star's inverse variance
    (``vw``); without ``robust`` externally studentised: σ re-estimated without the star (a wrong
    star inflates σ and so hides itself from the internal statistic)."""
    n = res.shape[0]
    P = cols.shape[0]
    n_obs = 2 * n
    chi2 = np.empty(n)
    rss = 0.0
    for i in range(n):
        rss += vw[i] * (res[i, 0] ** 2 + res[i, 1] ** 2)
    H = np.empty((2, 2))
    t = np.empty((2, P))
    Ji = np.empty((2, P))
    for i in range(n):
        for e in range(2):
            for a in range(P):
                Ji[e, a] = J[i, e, cols[a]]
        for e in range(2):
            for a in range(P):
                acc = 0.0
                for b in range(P):
                    acc += inv[a, b] * Ji[e, b]
                t[e, a] = acc
        for c in range(2):
            for e in range(2):
                acc = 0.0
                for a in range(P):
                    acc += Ji[c, a] * t[e, a]
                H[c, e] = acc * w[2 * i + c] / sigma2
        m00, m01 = sigma2 * (1.0 - H[0, 0]), -sigma2 * H[0, 1]
        m10, m11 = -sigma2 * H[1, 0], sigma2 * (1.0 - H[1, 1])
        det = max(m00 * m11 - m01 * m10, 1e-12 * sigma2 * sigma2)  # a star the fit rests on alone
        q = vw[i] * (m11 * res[i, 0] ** 2 - (m01 + m10) * res[i, 0] * res[i, 1] + m00 * res[i, 1] ** 2) / det
        if not robust:
            rss_without = max(rss - q * sigma2, 1e-12 * sigma2)
            q = q * sigma2 / max(rss_without / max(n_obs - n_eff - 2.0, 1.0), sigma_floor**2)
        chi2[i] = q
    return chi2


@numba.njit(cache=True)
def outlier_limit(dof):
    """The externally studentised χ² a good star exceeds with probability 3.4e-4 (the tail of
    :data:`OUTLIER_CHI2`): twice the F(2, m) quantile, m = dof − 2, in closed form
    (``P(F > x) = (1 + 2x/m)^(−m/2)``); it tends to :data:`OUTLIER_CHI2` for many stars."""
    m = max(dof - 2.0, 1.0)
    return m * (math.exp(OUTLIER_CHI2 / m) - 1.0)


@numba.njit(cache=True)
def _model_normal_equations(JtJ, g, rr, sigma2, lam, dev, cols):
    """The normal equations of the linearised fit (``JᵀJ``, ``Jᵀr``, ``rᵀr`` at the current
    point, σ² known) with the step columns ``cols`` free — each under its Gaussian prior
    (precision ``λ``, the current value ``dev`` from the prior's; flat where ``λ`` = 0) — and
    every other column held at the prior's value (its step ``−dev``): ``N = JᵀJ/σ² + Λ`` (k, k),
    ``c = Jᵀr'/σ² + Λ·dev`` (k,) (``r'`` the residuals with the held columns moved; the step is
    ``−N⁻¹c``), ``r'ᵀr'/σ² + devᵀΛ dev`` and ``Σ log λ`` over the free columns with a prior."""
    P = lam.shape[0]
    k = cols.shape[0]
    held = np.ones(P, dtype=np.bool_)
    for a in cols:
        held[a] = False
    const = rr
    for h in range(P):
        if held[h] and dev[h] != 0.0:
            const -= 2.0 * g[h] * dev[h]
            for h2 in range(P):
                if held[h2]:
                    const += dev[h] * JtJ[h, h2] * dev[h2]
    const /= sigma2
    N = np.empty((k, k))
    c = np.empty(k)
    log_lam = 0.0
    for ia in range(k):
        a = cols[ia]
        acc = g[a]
        for h in range(P):
            if held[h]:
                acc -= JtJ[a, h] * dev[h]
        c[ia] = acc / sigma2 + lam[a] * dev[a]
        const += lam[a] * dev[a] * dev[a]
        if lam[a] > 0.0:
            log_lam += math.log(lam[a])
        for ib in range(k):
            N[ia, ib] = JtJ[a, cols[ib]] / sigma2
        N[ia, ia] += lam[a]
    return N, c, const, log_lam


@numba.njit(cache=True)
def log_evidence(JtJ, g, rr, sigma2, lam, dev, cols):
    """The log marginal likelihood, up to a constant common to every model, of the linearised fit
    with the step columns ``cols`` free and the others held at the prior's values
    (:func:`_model_normal_equations`)::

        log Z = −½ (r'ᵀr'/σ² + devᵀΛ dev − cᵀN⁻¹c) − ½ log det N + ½ Σ log λ

    the evidence of a linear model under a Gaussian prior: the fit's χ² against the Occam
    factor of each number freed (the prior's width over the posterior's). −inf when ``N`` is
    not positive definite."""
    N, c, const, log_lam = _model_normal_equations(JtJ, g, rr, sigma2, lam, dev, cols)
    L, ok = cholesky(N)
    if not ok:
        return -math.inf
    log_det = 0.0
    quad = 0.0
    z = np.empty(cols.shape[0])
    for i in range(cols.shape[0]):  # z = L⁻¹c, cᵀN⁻¹c = zᵀz
        log_det += 2.0 * math.log(L[i, i])
        t = c[i]
        for p in range(i):
            t -= L[i, p] * z[p]
        z[i] = t / L[i, i]
        quad += z[i] * z[i]
    return -0.5 * (const - quad) - 0.5 * log_det + 0.5 * log_lam


@numba.njit(cache=True)
def _model_step(JtJ, g, sigma2, lam, dev, cols):
    """The Gauss–Newton step (k,) of the model with the step columns ``cols`` free, from the
    linearisation whose held columns are moved to the prior's values
    (:func:`_model_normal_equations`), and that model's effective number of fitted numbers."""
    N, c, _, _ = _model_normal_equations(JtJ, g, 0.0, sigma2, lam, dev, cols)
    k = cols.shape[0]
    inv, ok = spd_inverse(N)
    if not ok:
        inv = np.linalg.pinv(N)
    step = np.zeros(k)
    n_eff = 0.0
    for a in range(k):
        for b in range(k):
            step[a] -= inv[a, b] * c[b]
            n_eff += inv[a, b] * JtJ[cols[b], cols[a]]
    return step, n_eff / sigma2


@numba.njit(cache=True)
def choose_model(JtJ, g, rr, sigma2, lam, dev, codes, free):
    """Which of the parameters ``codes`` to fit (bool, one per code): of every model that frees
    ``f``, the principal point as ``free`` has it, and any subset of the others, the one of
    largest :func:`log_evidence` (the simpler on a tie: subsets in order of their bit mask). With
    the principal point free, decentring (p1, p2) is fitted with it: the two trade, and a lens's
    decentring held at 0 goes into the principal point and the boresight (thesis 003's MT9P031
    lens: cy 974.0–974.5 against 975.7, the boresight 2–3σ off)."""
    optional = np.empty(codes.shape[0], dtype=np.int64)
    n_opt = 0
    pp_free = False
    for k in range(codes.shape[0]):
        if codes[k] == PRINCIPAL_POINT:
            pp_free = free[k]
        elif codes[k] != F:
            optional[n_opt] = k
            n_opt += 1
    best = free.copy()
    best_z = -math.inf
    trial = free.copy()
    for mask in range(1 << n_opt):
        decentring = True
        for o in range(n_opt):
            trial[optional[o]] = (mask >> o) & 1 == 1
            if codes[optional[o]] == TANGENTIAL:
                decentring = trial[optional[o]]
        if pp_free and not decentring:
            continue
        z = log_evidence(JtJ, g, rr, sigma2, lam, dev, free_columns(codes, trial))
        if z > best_z:
            best_z = z
            best[:] = trial
    return best


@numba.njit(cache=True)
def _chosen(JtJ, g, res, step, n_eff, lam, dev, codes, free, sigma_floor):
    """:func:`choose_model` at a linearisation (``JᵀJ``, ``Jᵀr``, the residuals (N, 2)) with σ² from
    the residuals of its step with every number free (``step``, ``n_eff``), floored at
    ``sigma_floor``."""
    rr = 0.0
    for i in range(res.shape[0]):
        rr += res[i, 0] ** 2 + res[i, 1] ** 2
    rss = rr
    for a in range(step.shape[0]):
        rss += 2.0 * step[a] * g[a]
        for b in range(step.shape[0]):
            rss += step[a] * JtJ[a, b] * step[b]
    sigma2 = max(rss / max(2.0 * res.shape[0] - n_eff, 1.0), sigma_floor**2)
    return choose_model(JtJ, g, rr, sigma2, lam, dev, codes, free)


@numba.njit(cache=True)
def _rotated(r, A):
    """The vectors ``r`` (N, 3) rotated by ``A``."""
    out = np.empty((r.shape[0], 3))
    for i in range(r.shape[0]):
        for k in range(3):
            out[i, k] = A[k, 0] * r[i, 0] + A[k, 1] * r[i, 1] + A[k, 2] * r[i, 2]
    return out


@numba.njit(cache=True)
def prior_gauss_newton(xy, r, A, cam, half_diag_px, prior, options, weights):
    """The fit of :func:`skyfix.calibrate.fit_camera_with_prior`: attitude and the camera's
    :func:`prior_codes` (a pinhole's :data:`PRIOR_CODES`, with p1, p2 when ``prior``'s tangential
    σ is positive, a Kannala–Brandt camera's :data:`KB_PRIOR_CODES`) under ``prior``
    (:data:`PRIOR_NUMBERS`), as :class:`PriorFitOptions` say, each star weighted by its inverse
    variance ``weights`` (N,; relative, σ² is the weight-1 star's). Returns a
    :class:`GaussNewtonResult`.

    Rounds of Gauss–Newton, each on the parameters fitted so far (the others held at the prior's
    values), until a step moves the stars by ~2e-3 px. With ``options.drop_outliers``, at each
    converged step the star whose studentised residual is the worst beyond :func:`outlier_limit`
    is dropped and the round goes on (at most half the stars; three always kept). At the end of
    a round, the posterior with every prior parameter free is taken at the fit; from it:

    - with ``PP_AUTO``, a held principal point is freed where the stars pin it down
      (:data:`PP_CHI2`), and another round fits it;
    - with ``options.select``, the parameters fitted are those of the model of largest evidence
      (:func:`choose_model`: a number is freed only where the stars pay for it), and if they
      changed another round fits them (at most :data:`MODEL_CHANGES` times).

    The covariance, effective number of parameters and step returned are that posterior's, every
    prior parameter free (what the stars leave of the parameters held is in the attitude's error
    bar); σ² and the studentised residuals are the model fitted's."""
    fisheye = cam[PROJECTION] == KANNALA_BRANDT
    tangential = not fisheye and prior[SIGMA_TANGENTIAL] > 0.0
    codes = prior_codes(cam, tangential)
    n_codes = codes.shape[0]
    select = options.select and not options.robust
    free = np.zeros(n_codes, dtype=np.bool_)
    pp = -1
    pp_col = 0
    j = 3
    for k in range(n_codes):
        if codes[k] == F:
            free[k] = True
        elif codes[k] == PRINCIPAL_POINT:
            free[k] = options.principal_point == PP_FIT
            pp, pp_col = k, j
        else:
            free[k] = not select
        j += code_size(codes[k])
    n = xy.shape[0]
    xs = xy.copy()
    rs = r.copy()
    index = np.arange(n)
    # where the starting camera and attitude put the stars
    _, res0 = jacobian_rows(xs, _rotated(rs, A), cam, half_diag_px / cam[FX], codes[:0])
    cam = cam.copy()
    for k in range(n_codes):
        if not free[k]:
            hold_at_prior(cam, prior, codes[k])
    n_eff = 4.0
    vw = weights.copy()
    w = np.empty(2 * n)
    for i in range(n):
        w[2 * i] = w[2 * i + 1] = vw[i]
    changes = 0
    drops = 0
    max_drops = max(n // 2, 1)
    start = select  # the first step also chooses the model, at the start
    while True:
        codes_f = codes[free]
        it = 0
        checked = False
        while it < options.iterations:
            it += 1
            rmax = half_diag_px / cam[FX]
            if start:
                # The model of largest evidence at the start (from far off, a model too simple to
                # follow the stars may fit them by a focal length near 0), and its step.
                start = False
                J, res = jacobian_rows(xs, _rotated(rs, A), cam, rmax, codes)
                sigma2 = _noise(res, n_eff, options.robust, options.sigma_floor, w, vw)
                JtJ, g = _normal_equations(J, res, w)
                lam, dev = prior_terms(cam, rmax, prior, codes)
                _, n_eff_all, step = _posterior(JtJ, g, sigma2, lam, dev)
                free = _chosen(JtJ, g, res, step, n_eff_all, lam, dev, codes, free, options.sigma_floor)
                codes_f = codes[free]
                step, n_eff = _model_step(JtJ, g, sigma2, lam, dev, free_columns(codes, free))
                for k in range(n_codes):
                    if not free[k]:
                        hold_at_prior(cam, prior, codes[k])
                A = rodrigues(step) @ A
                cam = apply_step(cam, rmax, codes_f, step)
                continue
            J, res = jacobian_rows(xs, _rotated(rs, A), cam, rmax, codes_f)
            sigma2 = _noise(res, n_eff, options.robust, options.sigma_floor, w, vw)
            JtJ, g = _normal_equations(J, res, w)
            lam, dev = prior_terms(cam, rmax, prior, codes_f)
            inv, n_eff, step = _posterior(JtJ, g, sigma2, lam, dev)
            moved = 0.0
            for a in range(step.shape[0]):
                for b in range(step.shape[0]):
                    moved += step[a] * JtJ[a, b] * step[b]
            converged = moved < 4e-6 * (2 * xs.shape[0])  # stars moved by ~2e-3 px
            checked = converged and options.drop_outliers
            if checked:
                # the worst star against the others, at this linearisation (the step is tiny)
                chi2 = _studentised(J, res, inv, np.arange(step.shape[0]), w, vw, sigma2, n_eff,
                                    options.robust, options.sigma_floor)
                worst = int(np.argmax(chi2))
                if (drops < max_drops and xs.shape[0] > 3
                        and chi2[worst] > outlier_limit(2.0 * xs.shape[0] - n_eff)):
                    # Drop it, and step from here without it (its rows taken out of the normal
                    # equations): the next linearisation confirms the fit.
                    for c in range(2):
                        row = J[worst, c]
                        wr = w[2 * worst + c]
                        for a in range(row.shape[0]):
                            g[a] -= wr * row[a] * res[worst, c]
                            for b in range(row.shape[0]):
                                JtJ[a, b] -= wr * row[a] * row[b]
                    _, _, step = _posterior(JtJ, g, sigma2, lam, dev)
                    A = rodrigues(step) @ A
                    cam = apply_step(cam, rmax, codes_f, step)
                    keep = np.ones(xs.shape[0], dtype=np.bool_)
                    keep[worst] = False
                    xs, rs, index, res0, vw = xs[keep], rs[keep], index[keep], res0[keep], vw[keep]
                    w = np.repeat(vw, 2)
                    drops += 1
                    it = 0
                    continue
            A = rodrigues(step) @ A
            cam = apply_step(cam, rmax, codes_f, step)
            if converged:
                break
        # The posterior with every prior parameter free, at the fit.
        rmax = half_diag_px / cam[FX]
        J, res = jacobian_rows(xs, _rotated(rs, A), cam, rmax, codes)
        sigma2 = _noise(res, n_eff, options.robust, options.sigma_floor, w, vw)
        JtJ, g = _normal_equations(J, res, w)
        lam, dev = prior_terms(cam, rmax, prior, codes)
        inv, n_eff_all, step = _posterior(JtJ, g, sigma2, lam, dev)
        cols = free_columns(codes, free)
        if cols.shape[0] == lam.shape[0]:
            inv_f, n_eff = inv, n_eff_all
        else:  # the model fitted's own posterior, for its hat matrix and the error bar's bias term
            k = cols.shape[0]
            sub = np.empty((k, k))
            sub_lam = np.empty(k)
            for a in range(k):
                sub_lam[a] = lam[cols[a]]
                for b in range(k):
                    sub[a, b] = JtJ[cols[a], cols[b]]
            inv_f, n_eff, _ = _posterior(sub, np.zeros(k), sigma2, sub_lam, np.zeros(k))
        if not checked:  # (else the converged step's are the model's: it moved no star by 2e-3 px)
            chi2 = _studentised(J, res, inv_f, cols, w, vw, sigma2, n_eff, options.robust,
                                options.sigma_floor)
            if options.drop_outliers and drops < max_drops and xs.shape[0] > 3:
                worst = int(np.argmax(chi2))
                if chi2[worst] > outlier_limit(2.0 * xs.shape[0] - n_eff):
                    keep = np.ones(xs.shape[0], dtype=np.bool_)
                    keep[worst] = False
                    xs, rs, index, res0, vw = xs[keep], rs[keep], index[keep], res0[keep], vw[keep]
                    w = np.repeat(vw, 2)
                    drops += 1
                    continue
        if pp >= 0 and options.principal_point == PP_AUTO and not free[pp]:
            x, y = pp_col, pp_col + 1
            mx, my = step[x], step[y]
            c00, c01, c11 = inv[x, x], inv[x, y], inv[y, y]
            det = c00 * c11 - c01 * c01
            chi2_move = (c11 * mx * mx - 2.0 * c01 * mx * my + c00 * my * my) / det if det > 0 else 0.0
            pinned = 3.0 * math.sqrt(max(c00, c11)) * cam[FX] < prior[SIGMA_PP]
            if pinned and chi2_move > PP_CHI2:
                free[pp] = True
                for k in range(n_codes):  # decentring with it (choose_model)
                    free[k] = free[k] or codes[k] == TANGENTIAL
                continue
        if select and changes < MODEL_CHANGES:
            best = _chosen(JtJ, g, res, step, n_eff_all, lam, dev, codes, free, options.sigma_floor)
            if not np.array_equal(best, free):
                for k in range(n_codes):
                    if free[k] and not best[k]:
                        hold_at_prior(cam, prior, codes[k])
                free = best
                changes += 1
                continue
        if select and cols.shape[0] < lam.shape[0]:
            # The attitude is what the fit is for: where the numbers held at the prior's values move
            # it beyond their noise (HELD_SHIFT_CHI2), the stars see them (as the principal point
            # would take a lens's decentring): every one is freed (the principal point as it is).
            if held_shift_chi2(inv, inv_f, cols, step, cam[FX] / cam[FY]) > HELD_SHIFT_CHI2:
                for k in range(n_codes):
                    free[k] = free[k] or codes[k] != PRINCIPAL_POINT
                select = False
                continue
        break
    moved_px = 0.0
    for i in range(res.shape[0]):
        moved_px = max(moved_px, np.sqrt((res[i, 0] - res0[i, 0]) ** 2 + (res[i, 1] - res0[i, 1]) ** 2))
    kept = np.zeros(n, dtype=np.bool_)
    kept[index] = True
    return GaussNewtonResult(A, cam, sigma2, inv, frame_covariance(inv, cam[FX] / cam[FY]), n_eff_all, res,
                             chi2, step, moved_px, kept, free)


@numba.njit(cache=True)
def frame_step(step, fx_over_fy):
    """The rotation (3,) of the frame at the principal point's pixel that a prior fit's ``step``
    (P,) makes (:func:`frame_covariance`'s ``T step``)."""
    out = np.empty(3)
    out[0] = step[0] - fx_over_fy * step[STEP_CY]
    out[1] = step[1] + step[STEP_CX]
    out[2] = step[2]
    return out


@numba.njit(cache=True)
def frame_covariance(inv, fx_over_fy):
    """The attitude covariance (3, 3) of the frame at the principal point's pixel from the
    posterior ``inv`` (P, P) of a prior fit's step: a shift (δcx, δcy) of the principal point
    (scaled by fx, :data:`STEP_CX`, :data:`STEP_CY`) with no change of that pixel's sky direction
    is the rotation (−δcy·fx/fy, δcx, 0), so the frame's error is the rotation plus that share of
    the shift: ``T inv Tᵀ``."""
    T = np.zeros((3, inv.shape[0]))
    for k in range(3):
        T[k, k] = 1.0
    T[1, STEP_CX] = 1.0
    T[0, STEP_CY] = -fx_over_fy
    return T @ np.ascontiguousarray(inv) @ T.T


@numba.njit(cache=True)
def held_shift_chi2(inv, inv_f, cols, step, fx_over_fy):
    """How far, in its own noise, holding camera numbers at the prior's values moves the attitude
    at the principal point's pixel: ``δᵀ D⁺ δ``, δ the frame's rotation to the mean of the
    posterior ``inv`` with every number free (:func:`frame_step`), ``D = C_all − C_fitted`` the
    covariance that rotation has where the held numbers are the truth (C the attitude covariances
    of ``inv`` and of the fitted model's posterior ``inv_f`` on the step columns ``cols``): a χ²
    with as many degrees of freedom as ``D``'s rank where the held numbers are the truth, large
    where the stars see them away from the prior's and the attitude follows."""
    fitted_inv = np.zeros_like(inv)
    for a in range(cols.shape[0]):
        for b in range(cols.shape[0]):
            fitted_inv[cols[a], cols[b]] = inv_f[a, b]
    D = frame_covariance(inv, fx_over_fy) - frame_covariance(fitted_inv, fx_over_fy)
    vals, vecs = np.linalg.eigh(0.5 * (D + D.T))
    delta = frame_step(step, fx_over_fy)
    chi2 = 0.0
    for k in range(3):
        if vals[k] > 1e-9 * vals[2]:
            t = vecs[0, k] * delta[0] + vecs[1, k] * delta[1] + vecs[2, k] * delta[2]
            chi2 += t * t / vals[k]
    return chi2
