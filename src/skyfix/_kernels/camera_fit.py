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
from skyfix._kernels.rotation import rodrigues, spd_inverse

__all__ = ["ASPECT", "F", "K1_TERM", "K2_TERM", "K3_TERM", "K4_TERM", "KB_PRIOR_CODES", "PRINCIPAL_POINT",
           "PRIOR_CODES", "PRIOR_NUMBERS", "TANGENTIAL", "TANGENTIAL_PRIOR_CODES", "GaussNewtonResult",
           "ModelScores", "apply_step",
           "jacobian_rows", "normal_equations_at_start", "prior_codes", "prior_gauss_newton",
           "residuals_for_steps", "score_blocks", "score_models"]

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
STEP_F, STEP_ASPECT, STEP_CX, STEP_CY, STEP_K1, STEP_K2, STEP_K3, STEP_K4 = 3, 4, 5, 6, 7, 8, 9, 10
STEP_P1, STEP_P2 = 9, 10



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


class GaussNewtonResult(NamedTuple):
    """:func:`prior_gauss_newton`'s result: the attitude (3, 3), the camera numbers (12,), σ²
    (px²), the posterior covariance (P, P) of the step at the result, the effective number of
    fitted numbers, the residuals (N, 2) px, each star's studentised χ² (N,), the Gauss–Newton
    step (P,) under ``prior_out`` from the result, and the largest distance (px) the fit moved
    a star's predicted position."""

    A: np.ndarray
    cam: np.ndarray
    sigma2: float
    covariance: np.ndarray
    n_effective: float
    residuals: np.ndarray
    chi2: np.ndarray
    step: np.ndarray
    moved: float


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
    (``tests/test_final_fit_kernels.py`` holds it to finite differences of
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
def prior_gauss_newton(xy, r, A, cam, half_diag_px, prior, robust, iterations, sigma_floor, prior_out):
    """The iterations of :func:`skyfix.calibrate.fit_camera_with_prior` for the camera's
    :func:`prior_codes` (a pinhole's :data:`PRIOR_CODES`, with p1, p2 when ``prior``'s tangential
    σ is positive, a Kannala–Brandt camera's :data:`KB_PRIOR_CODES`); ``prior``
    (:data:`PRIOR_NUMBERS`) for the steps, ``prior_out`` for the
    posterior returned. Returns the attitude, camera numbers, σ², the posterior covariance at
    the result, n_eff, the residuals (N, 2), the studentised χ² (N,) and the Gauss–Newton step
    (P,) under ``prior_out`` from the result (what freeing ``prior_out``'s parameters would do),
    and the largest distance (px) by which the fit moved a star's predicted position.

    (Ten arguments: the stars, the start, the two priors and the fit's four settings.) Returns a
    :class:`GaussNewtonResult`."""
    fisheye = cam[PROJECTION] == KANNALA_BRANDT
    tangential = not fisheye and prior[SIGMA_TANGENTIAL] > 0.0
    codes = prior_codes(cam, tangential)
    n = xy.shape[0]
    n_obs = 2 * n
    P = 11 if (fisheye or tangential) else 9
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
        rmax = half_diag_px / cam[FX]
        J, res = jacobian_rows(xy, rays0, cam, rmax, codes)
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
        lam[STEP_ASPECT] = 1.0 / pr[SIGMA_ASPECT] ** 2
        lam[STEP_CX] = lam[STEP_CY] = (cam[FX] / pr[SIGMA_PP]) ** 2
        lam[STEP_K1] = 1.0 / (pr[SIGMA_K1] * rmax**2) ** 2
        lam[STEP_K2] = 1.0 / (pr[SIGMA_K2] * rmax**4) ** 2
        dev[STEP_ASPECT] = cam[FY] / cam[FX] - pr[PRIOR_ASPECT]
        dev[STEP_CX] = (cam[CX] - prior[PRIOR_CX]) / cam[FX]
        dev[STEP_CY] = (cam[CY] - prior[PRIOR_CY]) / cam[FX]
        dev[STEP_K1] = (cam[K1] - pr[PRIOR_K1]) * rmax**2
        dev[STEP_K2] = (cam[K2] - pr[PRIOR_K2]) * rmax**4
        if fisheye:
            lam[STEP_K3] = 1.0 / (pr[SIGMA_K3] * rmax**6) ** 2
            lam[STEP_K4] = 1.0 / (pr[SIGMA_K4] * rmax**8) ** 2
            dev[STEP_K3] = (cam[K3] - pr[PRIOR_K3]) * rmax**6
            dev[STEP_K4] = (cam[K4] - pr[PRIOR_K4]) * rmax**8
        elif tangential:  # p's step is p·rmax (apply_step)
            lam[STEP_P1] = lam[STEP_P2] = 1.0 / (pr[SIGMA_TANGENTIAL] * rmax) ** 2
            dev[STEP_P1] = (cam[P1] - pr[PRIOR_P1]) * rmax
            dev[STEP_P2] = (cam[P2] - pr[PRIOR_P2]) * rmax
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
        if it == iterations:
            break
        A = rodrigues(step) @ A
        cam = apply_step(cam, rmax, codes, step)
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
    return GaussNewtonResult(A, cam, sigma2, inv, n_eff, res, chi2, step, moved)
