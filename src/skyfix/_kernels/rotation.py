"""Rotations, RA/Dec, roll and quaternions, once: the arithmetic behind :mod:`skyfix.geometry`
and every kernel that needs it (the conventions of ``docs/design.md#conventions``).

- ``A`` (``A_icrs_to_cam``) takes ICRS unit vectors into the camera frame, ``b = A @ r``.
- Roll: position angle of image-up (camera ``−y``) from celestial north through east.
- Quaternions are scalar-last ``[x, y, z, w]`` with ``w ≥ 0`` (Shepperd's method).
"""

from __future__ import annotations

import math

import numpy as np

from skyfix._jit import njit

__all__ = ["angles", "cholesky", "chord_angle", "det3", "matmul3", "pointing", "proper_rotation",
           "radec_of_vectors", "rodrigues", "rotation_vector", "spd_inverse", "symmetric_eigen3", "triad",
           "vector_radec"]


@njit(cache=True, inline="always")
def vector_radec(x, y, z):
    """RA in [0, 2π) and Dec (radians) of the vector ``(x, y, z)`` (any length)."""
    norm = np.sqrt(x * x + y * y + z * z)
    ra = np.arctan2(y / norm, x / norm)
    if ra < 0.0:
        ra += 2.0 * np.pi
    ra += 0.0  # −0.0 → 0.0
    dec = np.arcsin(min(max(z / norm, -1.0), 1.0))
    return ra, dec


@njit(cache=True)
def radec_of_vectors(v):
    """RA and Dec (two (N,) arrays, radians) of vectors ``v`` (N, 3): :func:`vector_radec`."""
    n = v.shape[0]
    ra = np.empty(n)
    dec = np.empty(n)
    for i in range(n):
        ra[i], dec[i] = vector_radec(v[i, 0], v[i, 1], v[i, 2])
    return ra, dec


@njit(cache=True)
def pointing(A):
    """RA, Dec, roll (radians, RA and roll in [0, 2π)) and the quaternion ``[x, y, z, w]``
    (``w ≥ 0``) of an attitude matrix, as a (7,) array."""
    out = np.empty(7)
    ra, dec = vector_radec(A[2, 0], A[2, 1], A[2, 2])
    east = (-np.sin(ra), np.cos(ra), 0.0)
    north = (-np.sin(dec) * np.cos(ra), -np.sin(dec) * np.sin(ra), np.cos(dec))
    if abs(np.cos(dec)) < 1e-12:
        # At a pole east/north are undefined; use the RA-independent limit of the frame.
        north = (-np.sign(dec) * np.cos(ra), -np.sign(dec) * np.sin(ra), 0.0)
    up = (-A[1, 0], -A[1, 1], -A[1, 2])
    roll = np.arctan2(up[0] * east[0] + up[1] * east[1] + up[2] * east[2],
                      up[0] * north[0] + up[1] * north[1] + up[2] * north[2])
    if roll < 0.0:
        roll += 2.0 * np.pi
    roll += 0.0
    out[0], out[1], out[2] = ra, dec, roll
    # Shepperd's method: the largest of the four squared components first.
    t = A[0, 0] + A[1, 1] + A[2, 2]
    k = 0
    if A[1, 1] > A[k, k]:
        k = 1
    if A[2, 2] > A[k, k]:
        k = 2
    if t > A[k, k]:
        k = 3
    if k == 3:
        q = (A[2, 1] - A[1, 2], A[0, 2] - A[2, 0], A[1, 0] - A[0, 1], 1.0 + t)
    elif k == 0:
        q = (1.0 + 2.0 * A[0, 0] - t, A[0, 1] + A[1, 0], A[0, 2] + A[2, 0], A[2, 1] - A[1, 2])
    elif k == 1:
        q = (A[0, 1] + A[1, 0], 1.0 + 2.0 * A[1, 1] - t, A[1, 2] + A[2, 1], A[0, 2] - A[2, 0])
    else:
        q = (A[0, 2] + A[2, 0], A[1, 2] + A[2, 1], 1.0 + 2.0 * A[2, 2] - t, A[1, 0] - A[0, 1])
    qn = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    sign = 1.0 if q[3] / qn >= 0 else -1.0
    for i in range(4):
        out[3 + i] = sign * (q[i] / qn)
    return out


@njit(cache=True, inline="always")
def chord_angle(chord):
    """Angle (radians) between unit vectors a chord ``|a − b|`` apart: ``2·asin(chord / 2)``,
    accurate at small angles where ``acos(a·b)`` is not. Scalars or arrays."""
    return 2.0 * np.arcsin(np.minimum(chord / 2.0, 1.0))


@njit(cache=True)
def angles(b, r, A):
    """Angles (rad) between rays ``b`` (N, 3) and catalogue vectors ``r`` (N, 3) rotated by
    ``A``: ``2·asin(|b − A r| / 2)``, accurate at small angles."""
    out = np.empty(b.shape[0])
    for i in range(b.shape[0]):
        chord2 = 0.0
        for j in range(3):
            d = b[i, j] - (r[i, 0] * A[j, 0] + r[i, 1] * A[j, 1] + r[i, 2] * A[j, 2])
            chord2 += d * d
        out[i] = chord_angle(np.sqrt(chord2))
    return out


@njit(cache=True)
def rodrigues(p):
    """Rotation matrix of the rotation vector ``p[:3]``: ``I + a K + b K²`` with ``K = [p×]``,
    ``a = sin θ/θ``, ``b = (1 − cos θ)/θ²`` (their limits 1 and ½ below θ = 1e-12), written out."""
    th2 = p[0] * p[0] + p[1] * p[1] + p[2] * p[2]
    if th2 < 1e-24:
        a, b = 1.0, 0.5
    else:
        th = np.sqrt(th2)
        a, b = np.sin(th) / th, (1.0 - np.cos(th)) / th2
    x, y, z = p[0], p[1], p[2]
    R = np.empty((3, 3))
    R[0, 0] = 1.0 - b * (y * y + z * z)
    R[1, 1] = 1.0 - b * (x * x + z * z)
    R[2, 2] = 1.0 - b * (x * x + y * y)
    R[0, 1], R[1, 0] = -a * z + b * x * y, a * z + b * x * y
    R[0, 2], R[2, 0] = a * y + b * x * z, -a * y + b * x * z
    R[1, 2], R[2, 1] = -a * x + b * y * z, a * x + b * y * z
    return R


@njit(cache=True)
def rotation_vector(A):
    """Rotation vector ``v`` (3,), ``|v| ≤ π``, of a rotation matrix: the inverse of
    :func:`rodrigues`, ``R(v) = A``. From :func:`pointing`'s quaternion ``[q, w]`` (``w ≥ 0``):
    ``v = 2·atan2(|q|, w) · q / |q|``, accurate at small angles and near 180°."""
    quat = pointing(A)
    s = np.sqrt(quat[3] * quat[3] + quat[4] * quat[4] + quat[5] * quat[5])
    k = 2.0 / quat[6] if s == 0.0 else 2.0 * np.arctan2(s, quat[6]) / s
    out = np.empty(3)
    for i in range(3):
        out[i] = k * quat[3 + i]
    return out


@njit(cache=True)
def cholesky(M):
    """The lower triangular ``L`` with ``L Lᵀ = M`` of a small symmetric positive definite
    matrix, and whether it was (a pivot ≤ 0 returns False)."""
    k = M.shape[0]
    L = np.zeros((k, k))
    for j in range(k):
        d = M[j, j]
        for p in range(j):
            d -= L[j, p] * L[j, p]
        if not d > 0.0:
            return L, False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, k):
            t = M[i, j]
            for p in range(j):
                t -= L[i, p] * L[j, p]
            L[i, j] = t / L[j, j]
    return L, True


@njit(cache=True)
def spd_inverse(M):
    """Inverse of a small symmetric positive definite matrix by Cholesky (:func:`cholesky`), and
    whether it was (a pivot ≤ 0 returns False); a tenth of a LAPACK call's overhead at these sizes."""
    L, ok = cholesky(M)
    if not ok:
        return L, False
    k = M.shape[0]
    Li = np.zeros((k, k))  # L⁻¹, lower triangular
    for j in range(k):
        Li[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, k):
            t = 0.0
            for p in range(j, i):
                t -= L[i, p] * Li[p, j]
            Li[i, j] = t / L[i, i]
    inv = np.empty((k, k))  # M⁻¹ = L⁻ᵀ L⁻¹
    for a in range(k):
        for b in range(a, k):
            t = 0.0
            for p in range(b, k):
                t += Li[p, a] * Li[p, b]
            inv[a, b] = t
            inv[b, a] = t
    return inv, True


@njit(cache=True, inline="always")
def det3(M):
    """Determinant of a 3 × 3 matrix, written out."""
    return (M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1])
            - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
            + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]))


@njit(cache=True, inline="always")
def matmul3(X, Y):
    """``X @ Y`` of two 3 × 3 matrices, written out (numba's ``@`` calls BLAS, whose library a
    plain solve then loads for a 3 × 3 product: :mod:`skyfix._numba_lapack`)."""
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = X[i, 0] * Y[0, j] + X[i, 1] * Y[1, j] + X[i, 2] * Y[2, j]
    return out


_JACOBI_SWEEPS = 30  # a 3 × 3 Jacobi converges in 4–6 sweeps; the bound only guards the loop
_EPS = 2.220446049250313e-16  # float64's machine epsilon


@njit(cache=True, inline="always")
def _jacobi_angle(a, b, g):
    """Cosine and sine of the Jacobi rotation that zeroes the off-diagonal ``g`` of the symmetric
    2 × 2 ``[[a, g], [g, b]]`` (the smaller of the two angles that do)."""
    zeta = (b - a) / (2.0 * g)
    t = math.copysign(1.0, zeta) / (abs(zeta) + math.sqrt(1.0 + zeta * zeta))
    c = 1.0 / math.sqrt(1.0 + t * t)
    return c, c * t


@njit(cache=True, inline="always")
def _rotate_columns(X, p, q, c, s):
    """Columns ``p`` and ``q`` of ``X`` (3 rows) turned by the plane rotation ``(c, s)``, in place:
    ``X ← X J`` (the step both Jacobi kernels take; ``X.T`` turns rows)."""
    for k in range(3):
        xp, xq = X[k, p], X[k, q]
        X[k, p], X[k, q] = c * xp - s * xq, s * xp + c * xq


@njit(cache=True)
def symmetric_eigen3(S):
    """Eigenvalues (3,), ascending, and eigenvectors (3, 3), as columns, of a symmetric 3 × 3
    matrix: ``np.linalg.eigh``'s answer by cyclic Jacobi rotations, without LAPACK (an element
    is rotated away while it exceeds ε·√|M_pp M_qq|, which keeps small eigenvalues' relative
    accuracy)."""
    M = S.copy()
    V = np.eye(3)
    for _ in range(_JACOBI_SWEEPS):
        rotated = False
        for p in range(2):
            for q in range(p + 1, 3):
                g = M[p, q]
                if not abs(g) > _EPS * math.sqrt(abs(M[p, p] * M[q, q])):  # also a NaN
                    continue
                rotated = True
                c, s = _jacobi_angle(M[p, p], M[q, q], g)
                _rotate_columns(M, p, q, c, s)  # M ← Jᵀ M J, J the rotation in the (p, q) plane
                _rotate_columns(M.T, p, q, c, s)
                M[p, q] = M[q, p] = 0.0
                _rotate_columns(V, p, q, c, s)
        if not rotated:
            break
    order = np.argsort(np.array([M[0, 0], M[1, 1], M[2, 2]]))
    vals = np.empty(3)
    vecs = np.empty((3, 3))
    for j in range(3):
        vals[j] = M[order[j], order[j]]
        for k in range(3):
            vecs[k, j] = V[k, order[j]]
    return vals, vecs


@njit(cache=True)
def proper_rotation(B):
    """The proper rotation nearest the attitude profile matrix ``B = Σ w b rᵀ`` (Markley's SVD
    solution of Wahba's problem): ``U diag(1, 1, det U · det V) Vᵀ``, so det = +1 even for a
    mirror image. That is ``u₁v₁ᵀ + u₂v₂ᵀ + (u₁ × u₂)(v₁ × v₂)ᵀ`` for the two largest singular
    values' vectors, which one-sided Jacobi rotations of ``B``'s columns find without LAPACK
    (Hestenes: ``B V`` has orthogonal columns ``s_k u_k``); a ``B`` of rank one or less, or not
    finite, goes to LAPACK's SVD as before."""
    W = B.copy()
    V = np.eye(3)
    for _ in range(_JACOBI_SWEEPS):
        rotated = False
        for p in range(2):
            for q in range(p + 1, 3):
                a = W[0, p] * W[0, p] + W[1, p] * W[1, p] + W[2, p] * W[2, p]
                b = W[0, q] * W[0, q] + W[1, q] * W[1, q] + W[2, q] * W[2, q]
                g = W[0, p] * W[0, q] + W[1, p] * W[1, q] + W[2, p] * W[2, q]
                if not abs(g) > _EPS * math.sqrt(a * b):  # orthogonal to working precision (or a NaN)
                    continue
                rotated = True
                c, s = _jacobi_angle(a, b, g)
                _rotate_columns(W, p, q, c, s)
                _rotate_columns(V, p, q, c, s)
        if not rotated:
            break
    norms = np.empty(3)
    for k in range(3):
        norms[k] = math.sqrt(W[0, k] * W[0, k] + W[1, k] * W[1, k] + W[2, k] * W[2, k])
    order = np.argsort(-norms)
    i1, i2 = order[0], order[1]
    if norms[i2] > 1e-12 * norms[i1] and np.isfinite(norms[i1]):
        u1, u2 = W[:, i1] / norms[i1], W[:, i2] / norms[i2]
        v1, v2 = V[:, i1], V[:, i2]
        u3, v3 = np.cross(u1, u2), np.cross(v1, v2)
        A = np.empty((3, 3))
        for i in range(3):
            for j in range(3):
                A[i, j] = u1[i] * v1[j] + u2[i] * v2[j] + u3[i] * v3[j]
        return A
    U, _, Vt = np.linalg.svd(B)
    d = 1.0 if det3(U) * det3(Vt) >= 0.0 else -1.0
    A = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            A[i, j] = U[i, 0] * Vt[0, j] + U[i, 1] * Vt[1, j] + d * U[i, 2] * Vt[2, j]
    return A


@njit(cache=True)
def triad(b1, b2, r1, r2, min_sin):
    """TRIAD (Black 1963; thesis 004 §4.5): the attitude ``A`` with ``b1 = A r1`` exactly and
    ``b2`` in the plane of ``A r1``, ``A r2``, from the triads ``(v1, v1×v2/|v1×v2|, v1×t2)``
    of both pairs: ``A = Σ t_b t_rᵀ``. Returns ``(A, ok)``; ``ok`` is False when either pair is
    collinear (``|v1 × v2| < min_sin``)."""
    cb = np.cross(b1, b2)
    cr = np.cross(r1, r2)
    nb = np.sqrt(cb[0] * cb[0] + cb[1] * cb[1] + cb[2] * cb[2])
    nr = np.sqrt(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2])
    A = np.zeros((3, 3))
    if nb < min_sin or nr < min_sin:
        return A, False
    cb /= nb
    cr /= nr
    tb = np.cross(b1, cb)
    tr = np.cross(r1, cr)
    for i in range(3):
        for j in range(3):
            A[i, j] = b1[i] * r1[j] + cb[i] * cr[j] + tb[i] * tr[j]
    return A, True
