"""Wahba's problem, the sums once: the attitude profile matrix that every solver of
:mod:`skyfix.attitude` (and the tracker's compiled fit) starts from, and the information
matrix behind the QUEST measurement-model covariance."""

from __future__ import annotations

import numpy as np

from skyfix._jit import njit

__all__ = ["information_matrix", "profile_matrix"]


@njit(cache=True)
def profile_matrix(b, r, w):
    """Attitude profile matrix ``B = Σ w_i b_i r_iᵀ`` (3, 3) of observed ``b`` (N, 3) and
    catalogue ``r`` (N, 3) with weights ``w`` (N,) (a zero weight drops a pair)."""
    B = np.zeros((3, 3))
    for i in range(b.shape[0]):
        for j in range(3):
            bw = b[i, j] * w[i]
            for k in range(3):
                B[j, k] += bw * r[i, k]
    return B


@njit(cache=True)
def information_matrix(b, info_w):
    """``F = Σ w_i (I − b̂_i b̂_iᵀ)`` (3, 3) with ``b̂ = b / |b|``, in one pass: the inverse of the
    QUEST measurement-model covariance when ``w_i = σ_i⁻²`` (a zero weight drops a star)."""
    F = np.zeros((3, 3))
    total = 0.0
    for i in range(b.shape[0]):
        nb = np.sqrt(b[i, 0] * b[i, 0] + b[i, 1] * b[i, 1] + b[i, 2] * b[i, 2])
        u0, u1, u2 = b[i, 0] / nb, b[i, 1] / nb, b[i, 2] / nb
        total += info_w[i]
        F[0, 0] -= info_w[i] * u0 * u0
        F[0, 1] -= info_w[i] * u0 * u1
        F[0, 2] -= info_w[i] * u0 * u2
        F[1, 1] -= info_w[i] * u1 * u1
        F[1, 2] -= info_w[i] * u1 * u2
        F[2, 2] -= info_w[i] * u2 * u2
    F[1, 0], F[2, 0], F[2, 1] = F[0, 1], F[0, 2], F[1, 2]
    for k in range(3):
        F[k, k] += total
    return F
