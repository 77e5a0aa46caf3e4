"""The camera fit's kernels, for :mod:`skyfix.calibrate`: least-squares scoring of camera models,
and the Gauss–Newton of the fit under a prior. The model, its parameter codes, steps (in the
scaled units described there) and Jacobian are :mod:`skyfix._kernels.camera_jacobian`'s (re-exported
here); the projection itself is :mod:`skyfix._kernels.lens`'s; rotations and small inverses are
:mod:`skyfix._kernels.rotation`'s.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.camera_jacobian import (
    ASPECT,
    K1_TERM,
    K2_TERM,
    K3_TERM,
    K4_TERM,
    PRINCIPAL_POINT,
    TANGENTIAL,
    F,
    apply_step,
    code_size,
    jacobian_rows,
    normal_equations_at_start,
    residuals_for_steps,
)
from skyfix._kernels.camera_models import (
    ModelScores,
    choose_model,
    free_columns,
    log_evidence,
    model_step,
    score_blocks,
    score_models,
)
from skyfix._kernels.lens import CX, CY, FX, FY, K1, K2, K3, K4, KANNALA_BRANDT, P1, P2, PROJECTION
from skyfix._kernels.rotation import matmul3, rodrigues, spd_inverse, symmetric_eigen3

__all__ = ["ASPECT", "F", "HELD_SHIFT_CHI2", "K1_TERM", "K2_TERM", "K3_TERM", "K4_TERM", "KB_PRIOR_CODES",
           "MODEL_CHANGES", "OUTLIER_CHI2", "PP_AUTO", "PP_CHI2", "PP_FIT", "PP_HOLD", "PRINCIPAL_POINT",
           "PRIOR_CODES", "PRIOR_NUMBERS", "STEP_CX", "STEP_CY", "TANGENTIAL", "TANGENTIAL_PRIOR_CODES",
           "GaussNewtonResult", "ModelScores", "PriorFitOptions", "apply_step", "choose_model", "code_size",
           "frame_covariance", "frame_step", "free_columns", "held_shift_chi2", "hold_at_prior",
           "jacobian_rows", "log_evidence", "normal_equations_at_start", "outlier_limit", "prior_codes",
           "prior_gauss_newton", "prior_terms", "residuals_for_steps", "score_blocks", "score_models"]


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


@njit(cache=True)
def prior_codes(cam, tangential):
    """The parameter codes of the fit under a prior for the camera ``cam``'s projection
    (:data:`PRIOR_CODES`, with ``tangential`` :data:`TANGENTIAL_PRIOR_CODES`, or a Kannala–Brandt
    camera's :data:`KB_PRIOR_CODES`)."""
    if cam[PROJECTION] == KANNALA_BRANDT:
        return np.array(KB_PRIOR_CODES, dtype=np.int64)
    if tangential:
        return np.array(TANGENTIAL_PRIOR_CODES, dtype=np.int64)
    return np.array(PRIOR_CODES, dtype=np.int64)


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
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
                for b in range(a, P):  # the upper triangle; the lower one is its mirror
                    out[b] += wa * row[b]
    for a in range(P):
        for b in range(a):
            JtJ[a, b] = JtJ[b, a]
    return JtJ, g


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
def outlier_limit(dof):
    """The externally studentised χ² a good star exceeds with probability 3.4e-4 (the tail of
    :data:`OUTLIER_CHI2`): twice the F(2, m) quantile, m = dof − 2, in closed form
    (``P(F > x) = (1 + 2x/m)^(−m/2)``); it tends to :data:`OUTLIER_CHI2` for many stars."""
    m = max(dof - 2.0, 1.0)
    return m * (math.exp(OUTLIER_CHI2 / m) - 1.0)


@njit(cache=True)
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


@njit(cache=True)
def _rotated(r, A):
    """The vectors ``r`` (N, 3) rotated by ``A``."""
    out = np.empty((r.shape[0], 3))
    for i in range(r.shape[0]):
        for k in range(3):
            out[i, k] = A[k, 0] * r[i, 0] + A[k, 1] * r[i, 1] + A[k, 2] * r[i, 2]
    return out


@njit(cache=True)
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
                step, n_eff = model_step(JtJ, g, sigma2, lam, dev, free_columns(codes, free))
                for k in range(n_codes):
                    if not free[k]:
                        hold_at_prior(cam, prior, codes[k])
                A = matmul3(rodrigues(step), A)
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
                    A = matmul3(rodrigues(step), A)
                    cam = apply_step(cam, rmax, codes_f, step)
                    keep = np.ones(xs.shape[0], dtype=np.bool_)
                    keep[worst] = False
                    xs, rs, index, res0, vw = xs[keep], rs[keep], index[keep], res0[keep], vw[keep]
                    w = np.repeat(vw, 2)
                    drops += 1
                    it = 0
                    continue
            A = matmul3(rodrigues(step), A)
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


@njit(cache=True)
def frame_step(step, fx_over_fy):
    """The rotation (3,) of the frame at the principal point's pixel that a prior fit's ``step``
    (P,) makes (:func:`frame_covariance`'s ``T step``)."""
    out = np.empty(3)
    out[0] = step[0] - fx_over_fy * step[STEP_CY]
    out[1] = step[1] + step[STEP_CX]
    out[2] = step[2]
    return out


@njit(cache=True)
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
    P = inv.shape[0]
    Tinv = np.zeros((3, P))  # T inv Tᵀ, written out: numba's @ calls BLAS (skyfix._numba_lapack)
    for i in range(3):
        for b in range(P):
            for a in range(P):
                Tinv[i, b] += T[i, a] * inv[a, b]
    out = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            for b in range(P):
                out[i, j] += Tinv[i, b] * T[j, b]
    return out


@njit(cache=True)
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
    vals, vecs = symmetric_eigen3(0.5 * (D + D.T))
    delta = frame_step(step, fx_over_fy)
    chi2 = 0.0
    for k in range(3):
        if vals[k] > 1e-9 * vals[2]:
            t = vecs[0, k] * delta[0] + vecs[1, k] * delta[1] + vecs[2, k] * delta[2]
            chi2 += t * t / vals[k]
    return chi2
