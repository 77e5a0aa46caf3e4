"""Wahba's problem: the attitude that best rotates catalogue vectors onto observed ones.

Every solver takes matched unit vectors ``b_cam`` (camera frame) and ``r_icrs`` (catalogue)
and returns ``A_icrs_to_cam`` (docs/design.md#attitude-matrix: ``b = A r``), minimising the loss

    J(A) = ½ Σ w_i |b_i − A r_i|².

The solvers are chosen by name in :func:`solve_attitude`:

- ``"svd"``      Markley's SVD of the attitude profile matrix ``B = Σ w b rᵀ`` (robust reference).
- ``"q-method"`` Davenport: eigenvector of ``K`` for its largest eigenvalue (thesis 003).
- ``"quest"``    Shuster's QUEST: ``λ_max`` by Newton–Raphson on ``det(λI − K)``, then the
  quaternion in closed form (thesis 000 §2.8, with the printed typos corrected); the 180°
  singularity is avoided by Shuster's sequential rotations of the reference frame.
- ``"esoq2"``    Mortari's ESOQ2: the rotation axis as the null vector of a 3×3 matrix, with
  the same λ_max; its zero-rotation singularity is avoided by the same frame rotations.
- ``"triad"``    TRIAD on the first two vectors (thesis 004), anchored on the first.

Quaternions here are Shuster's (scalar last, ``A(q) = (q4² − |v|²) I + 2 v vᵀ − 2 q4 [v×]``);
they stay internal — the public quaternion (docs/design.md#quaternion) is scipy's, from the returned matrix.

The covariance is the QUEST measurement model (Shuster & Oh 1981) in the camera frame:
``P = (Σ σ_i⁻² (I − b_i b_iᵀ))⁻¹`` for the small rotation ``δθ`` with ``A_est = R(δθ) A_true``
(axes: x, y cross-boresight, z roll about the boresight).
"""

from __future__ import annotations

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.rotation import proper_rotation, rotation_vector, triad
from skyfix._kernels.wahba import information_matrix, profile_matrix
from skyfix.errors import unknown_name
from skyfix.geometry import angle_between, normalize

__all__ = [
    "METHODS",
    "solve_attitude",
    "svd_attitude",
    "qmethod_attitude",
    "quest_attitude",
    "esoq2_attitude",
    "triad_attitude",
    "attitude_covariance",
    "covariance_to_arcsec2",
    "attitude_error",
    "residuals_arcsec",
    "rmse_arcsec",
]

RAD_TO_ARCSEC = 180.0 / np.pi * 3600.0

# Below this sine of the largest angle between vectors, the set is treated as collinear.
_COLLINEAR_SIN = 1e-10

# The three 180° frame rotations of Shuster's sequential-rotation method (diagonal matrices);
# index 0 is the identity.
_FRAME_FLIPS = np.array([[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0]])


# --- input checks ----------------------------------------------------------------------------
def _prepare(b_cam: np.ndarray, r_icrs: np.ndarray, weights: np.ndarray | None,
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validated unit vectors (N, 3), (N, 3) and weights (N,) summing to 1; ValueError otherwise."""
    code, n_kept, b, r, w = _checked_unit_vectors(*_checked_arrays(b_cam, r_icrs, weights))
    if code:
        raise ValueError(_PREPARE_ERRORS[code].format(n_kept))
    return b, r, w


def _checked_arrays(b_cam: np.ndarray, r_icrs: np.ndarray, weights: np.ndarray | None,
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Contiguous float arrays (N, 3), (N, 3), (N,) of matching shapes; ValueError otherwise."""
    b = np.ascontiguousarray(b_cam, dtype=np.float64)
    r = np.ascontiguousarray(r_icrs, dtype=np.float64)
    if b.ndim != 2 or b.shape[1] != 3 or r.shape != b.shape:
        raise ValueError(f"attitude needs matching (N, 3) vector arrays, got {b.shape} and {r.shape}")
    w = np.ones(len(b)) if weights is None else np.ascontiguousarray(weights, dtype=np.float64).reshape(-1)
    if w.shape != (len(b),):
        raise ValueError(f"attitude needs one weight per vector, got {w.shape[0]} for {len(b)}")
    return b, r, w


_PREPARE_ERRORS = {
    1: "attitude vectors and weights must be finite",
    2: "attitude weights must be non-negative",
    3: "attitude needs at least 2 weighted vectors, got {}",
    4: "attitude vectors must be non-zero",
    5: "attitude is undetermined: all observed vectors are collinear",
    6: "attitude is undetermined: all catalogue vectors are collinear",
}


@njit(cache=True)
def _checked_unit_vectors(b, r, w):
    """The checks of :func:`_prepare` in one pass: (error code of ``_PREPARE_ERRORS`` or 0,
    vectors kept, unit ``b``, unit ``r``, weights of the kept vectors normalised to sum 1)."""
    n = b.shape[0]
    for i in range(n):
        if not np.isfinite(w[i]):
            return 1, 0, b, r, w
        for k in range(3):
            if not (np.isfinite(b[i, k]) and np.isfinite(r[i, k])):
                return 1, 0, b, r, w
    n_kept = 0
    for i in range(n):
        if w[i] < 0:
            return 2, 0, b, r, w
        if w[i] > 0:
            n_kept += 1
    if n_kept < 2:
        return 3, n_kept, b, r, w
    bu = np.empty((n_kept, 3))
    ru = np.empty((n_kept, 3))
    wu = np.empty(n_kept)
    j = 0
    total = 0.0
    for i in range(n):
        if w[i] > 0:
            nb = np.sqrt(b[i, 0] * b[i, 0] + b[i, 1] * b[i, 1] + b[i, 2] * b[i, 2])
            nr = np.sqrt(r[i, 0] * r[i, 0] + r[i, 1] * r[i, 1] + r[i, 2] * r[i, 2])
            if nb == 0 or nr == 0:
                return 4, n_kept, b, r, w
            for k in range(3):
                bu[j, k] = b[i, k] / nb
                ru[j, k] = r[i, k] / nr
            wu[j] = w[i]
            total += w[i]
            j += 1
    for code, v in ((5, bu), (6, ru)):
        # Largest sine of the angle to the first vector: below _COLLINEAR_SIN all are collinear.
        largest = 0.0
        for i in range(n_kept):
            c0 = v[i, 1] * v[0, 2] - v[i, 2] * v[0, 1]
            c1 = v[i, 2] * v[0, 0] - v[i, 0] * v[0, 2]
            c2 = v[i, 0] * v[0, 1] - v[i, 1] * v[0, 0]
            largest = max(largest, np.sqrt(c0 * c0 + c1 * c1 + c2 * c2))
        if largest < _COLLINEAR_SIN:
            return code, n_kept, b, r, w
    for j in range(n_kept):
        wu[j] = wu[j] / total
    return 0, n_kept, bu, ru, wu


def _profile(b: np.ndarray, r: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Attitude profile matrix ``B = Σ w b rᵀ``."""
    return (b * w[:, None]).T @ r


# --- quaternion helpers (Shuster's convention) -------------------------------------------------
def _matrix_from_shuster(q: np.ndarray) -> np.ndarray:
    """``A(q) = (q4² − |v|²) I + 2 v vᵀ − 2 q4 [v×]`` for a unit quaternion ``q = [v, q4]``."""
    v, s = q[:3], q[3]
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return (s * s - v @ v) * np.eye(3) + 2.0 * np.outer(v, v) - 2.0 * s * vx


def _k_parts(B: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """``S = B + Bᵀ``, ``σ = tr B`` and ``z = Σ w b × r`` of Davenport's K matrix."""
    S = B + B.T
    z = np.array([B[1, 2] - B[2, 1], B[2, 0] - B[0, 2], B[0, 1] - B[1, 0]])
    return S, float(np.trace(B)), z


def _davenport_k(B: np.ndarray) -> np.ndarray:
    """The 4×4 matrix K with ``tr(A Bᵀ) = qᵀ K q`` (Shuster quaternion, scalar last)."""
    S, sigma, z = _k_parts(B)
    K = np.empty((4, 4))
    K[:3, :3] = S - sigma * np.eye(3)
    K[:3, 3] = z
    K[3, :3] = z
    K[3, 3] = sigma
    return K


def _adj_trace(S: np.ndarray) -> float:
    """Trace of the adjugate of a symmetric 3×3 matrix (sum of its principal 2×2 minors)."""
    return float(S[1, 1] * S[2, 2] - S[1, 2] * S[2, 1] + S[0, 0] * S[2, 2] - S[0, 2] * S[2, 0]
                 + S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0])


def _lambda_max(B: np.ndarray, lam0: float = 1.0, max_iter: int = 100) -> float:
    """Largest eigenvalue of K by Newton–Raphson on the characteristic polynomial from ``λ0 = Σw``.

    ``ψ(λ) = λ⁴ − (a + b) λ² − c λ + (a b + c σ − d)`` with ``a = σ² − tr adj S``,
    ``b = σ² + zᵀz``, ``c = det S + zᵀ S z``, ``d = zᵀ S² z`` (thesis 000 §2.8). All roots are
    real and ``λ0 ≥ λ_max``, so Newton descends monotonically onto the largest root.
    """
    S, sigma, z = _k_parts(B)
    Sz = S @ z
    a = sigma * sigma - _adj_trace(S)
    b = sigma * sigma + z @ z
    c = float(np.linalg.det(S)) + z @ Sz
    d = Sz @ Sz
    c0 = a * b + c * sigma - d
    lam = lam0
    for _ in range(max_iter):
        lam2 = lam * lam
        psi = lam2 * lam2 - (a + b) * lam2 - c * lam + c0
        dpsi = 4.0 * lam2 * lam - 2.0 * (a + b) * lam - c
        if dpsi <= 0.0:  # only at a multiple root (fully degenerate input)
            break
        step = psi / dpsi
        lam -= step
        if abs(step) <= 1e-15 * max(1.0, abs(lam)):
            break
    return lam


# --- solvers -----------------------------------------------------------------------------------
def svd_attitude(b_cam: np.ndarray, r_icrs: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Markley's SVD solution: ``A_icrs_to_cam`` minimising Σ w |b − A r|².

    Parameters
    ----------
    b_cam : (N, 3) unit vectors observed in the camera frame.
    r_icrs : (N, 3) matching catalogue unit vectors (ICRS).
    weights : (N,) optional non-negative weights (default 1).

    Returns
    -------
    A : (3, 3) rotation matrix, ``b ≈ A r``.
    """
    b, r, w = _checked_arrays(b_cam, r_icrs, weights)
    code, n_kept, B, A = _checked_profile_polar(b, r, w)
    if code:
        raise ValueError(_PREPARE_ERRORS[code].format(n_kept))
    if A.shape[0] != 3:  # two stars, or a degenerate field: from the SVD
        A = proper_rotation(B)
    return A


@njit(cache=True)
def _checked_profile_polar(b, r, w):
    """The checks of :func:`_prepare`, the profile matrix ``B = Σ w b rᵀ`` of the unit vectors
    and its orthogonal polar factor (:func:`_polar_newton`), in one call: (error code, vectors
    kept, B, factor or an empty (0, 3) array)."""
    code, n_kept, bu, ru, wu = _checked_unit_vectors(b, r, w)
    if code:
        return code, n_kept, np.zeros((3, 3)), np.empty((0, 3))
    B = profile_matrix(bu, ru, wu)
    return code, n_kept, B, _polar_newton(B)


@njit(cache=True)
def _polar_newton(B):
    """Orthogonal polar factor of a 3×3 ``B`` with ``det B > 0``, or an empty (0, 3) array when
    ``B`` is ill-conditioned, improper or the iteration does not converge.

    For ``det B > 0`` it is the SVD's proper factor ``U diag(1, 1, det U det V) Vᵀ``; the scaled
    Newton iteration ``X ← (γ X + X⁻ᵀ / γ) / 2`` (Higham 1986) reaches it to rounding in about
    eight 3×3 steps, free of a LAPACK call (any field of three or more stars)."""
    fail = np.empty((0, 3))
    fro = 0.0
    for i in range(3):
        for j in range(3):
            fro += B[i, j] * B[i, j]
    fro = np.sqrt(fro)
    if not fro > 0.0:
        return fail
    X = B / fro
    C = np.empty((3, 3))
    scaled = True
    for _ in range(40):
        # X⁻ᵀ = cof(X) / det X
        C[0, 0] = X[1, 1] * X[2, 2] - X[1, 2] * X[2, 1]
        C[0, 1] = X[1, 2] * X[2, 0] - X[1, 0] * X[2, 2]
        C[0, 2] = X[1, 0] * X[2, 1] - X[1, 1] * X[2, 0]
        C[1, 0] = X[0, 2] * X[2, 1] - X[0, 1] * X[2, 2]
        C[1, 1] = X[0, 0] * X[2, 2] - X[0, 2] * X[2, 0]
        C[1, 2] = X[0, 1] * X[2, 0] - X[0, 0] * X[2, 1]
        C[2, 0] = X[0, 1] * X[1, 2] - X[0, 2] * X[1, 1]
        C[2, 1] = X[0, 2] * X[1, 0] - X[0, 0] * X[1, 2]
        C[2, 2] = X[0, 0] * X[1, 1] - X[0, 1] * X[1, 0]
        det = X[0, 0] * C[0, 0] + X[0, 1] * C[0, 1] + X[0, 2] * C[0, 2]
        if not det > 1e-12:  # improper, singular or too ill-conditioned for this iteration
            return fail
        g = 1.0
        if scaled:
            nx = 0.0
            nc = 0.0
            for i in range(3):
                for j in range(3):
                    nx += X[i, j] * X[i, j]
                    nc += C[i, j] * C[i, j]
            g = np.sqrt(np.sqrt(nc) / det / np.sqrt(nx))
        change = 0.0
        for i in range(3):
            for j in range(3):
                y = 0.5 * (g * X[i, j] + C[i, j] / det / g)
                change += (y - X[i, j]) ** 2
                X[i, j] = y
        change = np.sqrt(change)
        if change < 1e-3:
            scaled = False  # near convergence the unscaled step converges quadratically
        if change < 1e-15:
            return X
    return fail


def qmethod_attitude(b_cam: np.ndarray, r_icrs: np.ndarray,
                     weights: np.ndarray | None = None) -> np.ndarray:
    """Davenport's q-method: the eigenvector of K with the largest eigenvalue (thesis 003).

    Parameters and return value as :func:`svd_attitude`.
    """
    b, r, w = _prepare(b_cam, r_icrs, weights)
    _, vecs = np.linalg.eigh(_davenport_k(_profile(b, r, w)))
    return _matrix_from_shuster(vecs[:, -1])


def quest_attitude(b_cam: np.ndarray, r_icrs: np.ndarray,
                   weights: np.ndarray | None = None) -> np.ndarray:
    """Shuster's QUEST with sequential rotations (thesis 000 §2.8, corrected).

    ``λ_max`` comes from Newton–Raphson on the characteristic polynomial of K (start
    ``λ0 = Σ w = 1``); then ``α = λ² − σ² + tr adj S``, ``β = λ − σ``,
    ``γ = α (λ + σ) − det S``, ``x = (α I + β S + S²) z`` and ``q = [x, γ] / |[x, γ]|``.
    Since ``[x, γ] = c q4 q`` with ``c`` the product of K's eigen-gaps, QUEST loses precision
    as the rotation angle nears 180° (``q4 → 0``). Rotating the reference frame by 180° about
    axis ``i`` turns ``q4`` into ``±q_i``, and ``γ_i = c q_i²``: we evaluate ``γ`` in the frame
    and in the three flipped frames and solve in the one with the largest ``γ``, so the
    rotation solved for is never more than 120° (``|q4| ≥ ½``).

    Parameters and return value as :func:`svd_attitude`.
    """
    b, r, w = _prepare(b_cam, r_icrs, weights)
    B0 = _profile(b, r, w)
    lam = _lambda_max(B0)
    best_gamma, flip = -np.inf, _FRAME_FLIPS[0]
    for f in _FRAME_FLIPS:
        B = B0 * f[None, :]  # B R_i: reference vectors rotated by 180° about an axis
        S, sigma, _ = _k_parts(B)
        gamma = (lam * lam - sigma * sigma + _adj_trace(S)) * (lam + sigma) - float(np.linalg.det(S))
        if gamma > best_gamma:
            best_gamma, flip = gamma, f
    B = B0 * flip[None, :]
    q = _quest_quaternion(B, lam)
    # One Rayleigh-quotient update of λ: Newton's λ carries the polynomial's rounding error,
    # which the closed form divides by K's smallest eigen-gap (the roll information, tiny for
    # narrow fields); qᵀKq is accurate to second order in the error of q.
    q = _quest_quaternion(B, float(q @ _davenport_k(B) @ q))
    return _matrix_from_shuster(q) * flip[None, :]


def _quest_quaternion(B: np.ndarray, lam: float) -> np.ndarray:
    """QUEST's closed-form unit quaternion for a profile matrix and ``λ_max``."""
    S, sigma, z = _k_parts(B)
    alpha = lam * lam - sigma * sigma + _adj_trace(S)
    gamma = alpha * (lam + sigma) - float(np.linalg.det(S))
    x = (alpha * np.eye(3) + (lam - sigma) * S + S @ S) @ z
    q = np.append(x, gamma)
    return q / np.linalg.norm(q)


def esoq2_attitude(b_cam: np.ndarray, r_icrs: np.ndarray,
                   weights: np.ndarray | None = None) -> np.ndarray:
    """Mortari's ESOQ2: the rotation axis ``e`` as the null vector of a 3×3 matrix.

    Eliminating ``q4`` from ``K q = λ q`` gives ``M e = 0`` with
    ``M = (λ − σ)((λ + σ) I − S) − z zᵀ``; ``e`` is the largest cross product of two rows of
    ``M``, and ``q ∝ [(λ − σ) e, z · e]``. ``M`` vanishes as the rotation angle nears zero
    (``λ − σ → 0``, ``z → 0``), so the reference frame is first flipped by 180° about the axis
    that makes ``λ − σ`` largest (``σ_i = 2 B_ii − tr B``).

    Parameters and return value as :func:`svd_attitude`.
    """
    b, r, w = _prepare(b_cam, r_icrs, weights)
    B0 = _profile(b, r, w)
    lam = _lambda_max(B0)
    trace = np.trace(B0)
    sigmas = np.append(trace, 2.0 * np.diag(B0) - trace)
    flip = _FRAME_FLIPS[int(np.argmin(sigmas))]
    B = B0 * flip[None, :]
    q = _esoq2_quaternion(B, lam)
    q = _esoq2_quaternion(B, float(q @ _davenport_k(B) @ q))  # Rayleigh update of λ, as QUEST
    return _matrix_from_shuster(q) * flip[None, :]


def _esoq2_quaternion(B: np.ndarray, lam: float) -> np.ndarray:
    """ESOQ2's unit quaternion for a profile matrix and ``λ_max``."""
    S, sigma, z = _k_parts(B)
    M = (lam - sigma) * ((lam + sigma) * np.eye(3) - S) - np.outer(z, z)
    crosses = np.cross(M[[0, 1, 2]], M[[1, 2, 0]])
    e = crosses[int(np.argmax(np.einsum("ij,ij->i", crosses, crosses)))]
    e = e / np.linalg.norm(e)
    q = np.append((lam - sigma) * e, z @ e)
    return q / np.linalg.norm(q)


def triad_attitude(b_cam: np.ndarray, r_icrs: np.ndarray,
                   weights: np.ndarray | None = None) -> np.ndarray:
    """TRIAD (Black 1963; thesis 004 §4.5) on two vectors, exact along the first.

    With weights, the two most heavily weighted vectors are used (the heaviest as the anchor);
    without, the first two. Triads ``t1 = v1``, ``t2 = v1 × v2 / |v1 × v2|``, ``t3 = t1 × t2``
    from both sets, and ``A = [t1b t2b t3b] [t1r t2r t3r]ᵀ``.

    Parameters and return value as :func:`svd_attitude`.
    """
    b, r, w = _prepare(b_cam, r_icrs, weights)
    order = np.argsort(-w, kind="stable")[:2]
    b, r = np.ascontiguousarray(b[order]), np.ascontiguousarray(r[order])
    A, ok = triad(b[0], b[1], r[0], r[1], _COLLINEAR_SIN)
    if not ok:
        raise ValueError("TRIAD is undetermined: its two vectors are collinear")
    return A


METHODS = {
    "svd": svd_attitude,
    "quest": quest_attitude,
    "esoq2": esoq2_attitude,
    "q-method": qmethod_attitude,
    "triad": triad_attitude,
}


def solve_attitude(b_cam: np.ndarray, r_icrs: np.ndarray, weights: np.ndarray | None = None,
                   method: str = "svd") -> np.ndarray:
    """Solve Wahba's problem with the solver named ``method`` (see :data:`METHODS`).

    Parameters
    ----------
    b_cam : (N, 3) unit vectors observed in the camera frame.
    r_icrs : (N, 3) matching catalogue unit vectors (ICRS).
    weights : (N,) optional non-negative weights, e.g. ``1/σ_i²`` (default 1).
    method : ``"svd"``, ``"quest"``, ``"esoq2"``, ``"q-method"`` or ``"triad"``.

    Returns
    -------
    A_icrs_to_cam : (3, 3) rotation matrix, ``b ≈ A r``.

    Raises
    ------
    ValueError
        Unknown method, fewer than 2 weighted vectors, collinear vectors, bad shapes.
    """
    try:
        solver = METHODS[method.lower()]
    except (KeyError, AttributeError):
        raise unknown_name("attitude method", method, METHODS) from None
    if solver is not svd_attitude:  # the other solvers' kernels, compiled up front on first use
        from skyfix import warmup

        warmup.ensure("attitude")
    return solver(b_cam, r_icrs, weights)


# --- error model -------------------------------------------------------------------------------
# The smallest per-axis centroid noise a covariance is built on, px: what a centroid of a bright,
# well-sampled star reaches (skyfix's own at rest: 0.015-0.05 px, thesis 002's HAS2 0.031-0.034 px,
# tests/simulate/test_simulate_slew.py), so that residuals smaller than that (a lucky few, or centroids
# simulated without noise) do not claim a precision no detector delivers. The final fit of a
# calibrated camera floors its residual sigma here; the tracker's measurement noise too.
CENTROID_NOISE_FLOOR_PX = 0.02


def attitude_covariance(A_icrs_to_cam: np.ndarray, b_cam: np.ndarray, sigma_rad: float | np.ndarray,
                        weights: np.ndarray | None = None, frame: str = "camera") -> np.ndarray:
    """QUEST measurement-model covariance of the attitude error, rad².

    ``P = (Σ w_i σ_i⁻² (I − b_i b_iᵀ))⁻¹``: each observed direction is off by an isotropic
    tangential error of ``σ_i`` per axis. ``P`` is the covariance of the small rotation
    ``δθ`` with ``A_est = R(δθ) A_true``.

    Parameters
    ----------
    A_icrs_to_cam : (3, 3) the estimated attitude (used only for ``frame="icrs"``).
    b_cam : (N, 3) the observed unit vectors in the camera frame.
    sigma_rad : scalar or (N,) angular error per axis of each observation, radians
        (centroid σ in pixels × plate scale).
    weights : (N,) optional relative inverse-variance factors (``σ_i² → σ_i² / w_i``); 0 drops
        a star.
    frame : ``"camera"`` (axes x, y cross-boresight, z roll) or ``"icrs"`` (``Aᵀ P A``).

    Returns
    -------
    P : (3, 3) covariance, rad².

    Raises
    ------
    ValueError
        Fewer than two distinct directions (the roll is then unobservable).
    """
    b = np.asarray(b_cam, dtype=np.float64)
    if b.ndim != 2 or b.shape[1] != 3:
        raise ValueError(f"attitude covariance needs (N, 3) vectors, got {b.shape}")
    sig = np.broadcast_to(np.asarray(sigma_rad, dtype=np.float64), (len(b),))
    if not (np.all(np.isfinite(sig)) and np.all(sig > 0)):
        raise ValueError("attitude covariance needs positive finite sigma_rad")
    info_w = 1.0 / sig**2
    if weights is not None:
        info_w = info_w * np.asarray(weights, dtype=np.float64)
    F = information_matrix(np.ascontiguousarray(b), np.ascontiguousarray(info_w, dtype=np.float64))
    if not (np.all(np.isfinite(F)) and np.linalg.cond(F) <= 1e14):
        raise ValueError("attitude covariance is unbounded: fewer than two distinct directions")
    P = np.linalg.inv(F)
    P = 0.5 * (P + P.T)
    if frame == "camera":
        return P
    if frame == "icrs":
        A = np.asarray(A_icrs_to_cam, dtype=np.float64)
        return A.T @ P @ A
    raise ValueError(f"unknown covariance frame {frame!r}; use 'camera' or 'icrs'")


def attitude_error(A_true: np.ndarray, A_est: np.ndarray) -> np.ndarray:
    """Error rotation vector ``δθ`` (3,) in the camera frame, radians: ``A_est = R(δθ) A_true``.

    ``δθ[:2]`` is the cross-boresight (pointing) error and ``δθ[2]`` the roll error, the axes of
    :func:`attitude_covariance`. In quaternions (scipy's composition) this is
    ``q_err = q_est ⊗ q_true⁻¹`` — the inverse that thesis 003's Eq. 7.15 omits.
    """
    dA = np.asarray(A_est, dtype=np.float64) @ np.asarray(A_true, dtype=np.float64).T
    return rotation_vector(np.ascontiguousarray(dA))


def covariance_to_arcsec2(P_rad2: np.ndarray) -> np.ndarray:
    """Convert a covariance from rad² to arcsec²."""
    return np.asarray(P_rad2, dtype=np.float64) * RAD_TO_ARCSEC**2


def residuals_arcsec(A_icrs_to_cam: np.ndarray, b_cam: np.ndarray, r_icrs: np.ndarray) -> np.ndarray:
    """Angle between each observed vector and its catalogue vector rotated by ``A``, arcsec (N,)."""
    b = np.asarray(b_cam, dtype=np.float64)
    pred = np.asarray(r_icrs, dtype=np.float64) @ np.asarray(A_icrs_to_cam, dtype=np.float64).T
    return angle_between(normalize(b), normalize(pred)) * RAD_TO_ARCSEC


def rmse_arcsec(A_icrs_to_cam: np.ndarray, b_cam: np.ndarray, r_icrs: np.ndarray) -> float:
    """Root-mean-square of :func:`residuals_arcsec`, arcsec."""
    res = residuals_arcsec(A_icrs_to_cam, b_cam, r_icrs)
    return float(np.sqrt(np.mean(res**2))) if res.size else float("nan")
