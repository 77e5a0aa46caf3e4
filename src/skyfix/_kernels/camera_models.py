"""The camera fit's model choice, for :mod:`skyfix._kernels.camera_fit` and :mod:`skyfix.calibrate`:
which camera numbers the stars support — least-squares scores of models from the Jacobian at the
start (BIC, :func:`score_models`), and the evidence of a linearised fit under a Gaussian prior
with some numbers freed and the others held at the prior's values (:func:`log_evidence`,
:func:`choose_model`), with that model's Gauss–Newton step (:func:`model_step`). The parameter
codes and the Jacobian are :mod:`skyfix._kernels.camera_jacobian`'s.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.camera_jacobian import (
    PRINCIPAL_POINT,
    TANGENTIAL,
    F,
    code_size,
    normal_equations_at_start,
)
from skyfix._kernels.rotation import cholesky, spd_inverse

__all__ = ["ModelScores", "choose_model", "free_columns", "log_evidence", "model_normal_equations",
           "model_step", "score_blocks", "score_models"]


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


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
def model_normal_equations(JtJ, g, rr, sigma2, lam, dev, cols):
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


@njit(cache=True)
def log_evidence(JtJ, g, rr, sigma2, lam, dev, cols):
    """The log marginal likelihood, up to a constant common to every model, of the linearised fit
    with the step columns ``cols`` free and the others held at the prior's values
    (:func:`model_normal_equations`)::

        log Z = −½ (r'ᵀr'/σ² + devᵀΛ dev − cᵀN⁻¹c) − ½ log det N + ½ Σ log λ

    the evidence of a linear model under a Gaussian prior: the fit's χ² against the Occam
    factor of each number freed (the prior's width over the posterior's). −inf when ``N`` is
    not positive definite."""
    N, c, const, log_lam = model_normal_equations(JtJ, g, rr, sigma2, lam, dev, cols)
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


@njit(cache=True)
def model_step(JtJ, g, sigma2, lam, dev, cols):
    """The Gauss–Newton step (k,) of the model with the step columns ``cols`` free, from the
    linearisation whose held columns are moved to the prior's values
    (:func:`model_normal_equations`), and that model's effective number of fitted numbers."""
    N, c, _, _ = model_normal_equations(JtJ, g, 0.0, sigma2, lam, dev, cols)
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


@njit(cache=True)
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
