"""The tracker's attitude fit, compiled: the windows' stars checked pair by pair against the
catalogue (thesis 004's distance check), fitted by Wahba's SVD solution with outliers out, and
the QUEST covariance (docs/tracking.md#one-tracking-update)."""

from __future__ import annotations

import math

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.rotation import angles, proper_rotation, spd_inverse
from skyfix._kernels.wahba import information_matrix, profile_matrix

__all__ = ["fit_attitude", "pair_check"]


@njit(cache=True)
def pair_check(b, r, sigma_rad, keep, k):
    """Thesis 004's distance check over every pair of kept stars: the angle between rays
    ``b[i]``, ``b[j]`` must equal that between catalogue vectors ``r[i]``, ``r[j]`` within
    ``k·√(σ_i² + σ_j²)`` (the rays' σ per axis, radians). The star in the most disagreeing pairs
    is dropped (``keep[i] = False``) until every pair agrees — of stars in equally many, the
    least precise (largest σ): two groups that disagree with each other, one of bright stars and
    one of faint ones biased alike, would otherwise lose the bright ones first, as the windows
    come brightest first. Returns how many were dropped."""
    n = b.shape[0]
    bad = np.zeros(n, np.int64)
    dropped = 0
    while True:
        bad[:] = 0
        worst = -1
        for i in range(n):
            if not keep[i]:
                continue
            for j in range(i + 1, n):
                if not keep[j]:
                    continue
                cb = 0.0
                cr = 0.0
                for a in range(3):
                    cb += (b[i, a] - b[j, a]) ** 2
                    cr += (r[i, a] - r[j, a]) ** 2
                # chords, not angles: d(chord)/d(angle) = cos(θ/2) ≈ 1 within a field
                if abs(math.sqrt(cb) - math.sqrt(cr)) > k * math.sqrt(sigma_rad[i] ** 2 + sigma_rad[j] ** 2):
                    bad[i] += 1
                    bad[j] += 1
        for i in range(n):
            if keep[i] and bad[i] > 0 and (worst < 0 or bad[i] > bad[worst]
                                           or (bad[i] == bad[worst] and sigma_rad[i] > sigma_rad[worst])):
                worst = i
        if worst < 0:
            return dropped
        keep[worst] = False
        dropped += 1


@njit(cache=True)
def fit_attitude(b, r, sigma_rad, keep, pair_k, outlier_k, min_stars):
    """Steps 5–6 of the module docstring in one call, for the tracking loop: the pair check
    (:func:`pair_check`), then the weighted SVD solution of Wahba's problem
    (``A = proper_rotation(Σ σ⁻² b rᵀ)``, :func:`skyfix.attitude.svd_attitude`'s) over the kept
    stars, the star with the largest residual beyond ``outlier_k`` σ dropped and the fit
    repeated (never below ``min_stars``), and the covariance of
    :func:`skyfix.attitude.attitude_covariance`, ``(Σ (I − b bᵀ)/σ²)⁻¹``, with σ scaled up by
    ``√(χ²/dof)`` when the residuals exceed their σ (never down). The sums are theirs
    (:mod:`skyfix._kernels.wahba`); only the loop is here, compiled, because those two public
    functions cost a tenth of a tracking update in their argument checks
    (``tests/track/test_track.py`` checks this kernel against them).

    Returns ``(ok, A, P, scale)``; ``keep`` marks the stars in the fit."""
    pair_check(b, r, sigma_rad, keep, pair_k)
    n = b.shape[0]
    A = np.eye(3)
    P = np.zeros((3, 3))
    while True:
        count = 0
        for i in range(n):
            count += 1 if keep[i] else 0
        if count < min_stars:
            return False, A, P, 0.0
        w = np.zeros(n)
        for i in range(n):
            if keep[i]:
                w[i] = 1.0 / (sigma_rad[i] * sigma_rad[i])
        A = proper_rotation(profile_matrix(b, r, w))
        e = angles(b, r, A)
        chi2 = 0.0
        worst = -1
        for i in range(n):
            if keep[i]:
                e[i] /= sigma_rad[i]
                chi2 += e[i] * e[i]
                if worst < 0 or e[i] > e[worst]:
                    worst = i
        if e[worst] > outlier_k and count > min_stars:
            keep[worst] = False
            continue
        scale2 = max(1.0, chi2 / (2 * count - 3))
        P, ok = spd_inverse(information_matrix(b, w / scale2))
        return ok, A, P, math.sqrt(scale2)
