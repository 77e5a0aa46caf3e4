"""Compiled refit of attitude, focal length and radial distortion on all matched stars.

After a pattern is verified, :func:`refine` matches the brightest centroids to the catalogue
stars in view, fits the attitude (and, without a calibrated camera, the focal length and
radial distortion k1) by robust Gauss–Newton on the pixel residuals, and repeats with a
match radius that shrinks to the fit's own scatter. It takes and returns the named data of
:mod:`skyfix.identify.catalogue.kernel_data`
(:class:`~skyfix.identify.catalogue.kernel_data.RefineSettings` in,
:class:`~skyfix.identify.catalogue.kernel_data.Refit` out).
"""

from __future__ import annotations

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.lens import k1_offset
from skyfix._kernels.rotation import matmul3, rodrigues
from skyfix.identify.catalogue.kernel_data import ImageStars, RefineSettings, Refit, StarIndex, ViewBuffers
from skyfix.identify.common.verify import gather_stars, grid_index, match_grid, project_stars, star_limit

__all__ = ["refine", "refine_entry"]

# The rows of the per-star table of :func:`_gauss_newton` (a (13, M) table, one column per star,
# so that the sums over stars read memory in order): the residuals, the weight, and the
# Jacobian rows of u and v with respect to the rotation (3), the focal length and k1.
_RU, _RV, _W = 0, 1, 2
_DU = 3  # _DU + 0..2: ∂u/∂δ; _DU + 3: ∂u/∂f; _DU + 4: ∂u/∂k1
_DV = 8  # the same for v
_J_ROWS = 13


@njit(cache=True)
def _solve_spd(N, g):
    """Solve ``N x = g`` for a small symmetric positive-definite ``N`` (Cholesky, no LAPACK)."""
    n = len(g)
    L = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1):
            acc = N[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            if i == j:
                if acc <= 0.0:
                    return np.zeros(n), False
                L[i, i] = np.sqrt(acc)
            else:
                L[i, j] = acc / L[j, j]
    y = np.empty(n)
    for i in range(n):
        acc = g[i]
        for k in range(i):
            acc -= L[i, k] * y[k]
        y[i] = acc / L[i, i]
    x = np.empty(n)
    for i in range(n - 1, -1, -1):
        acc = y[i]
        for k in range(i + 1, n):
            acc -= L[k, i] * x[k]
        x[i] = acc / L[i, i]
    return x, True


@njit(cache=True)
def _residuals(A, f, k1, v, q, out):
    """Pixel residuals (2M,) of projected catalogue vectors ``v`` against offsets ``q``."""
    for t in range(len(v)):
        bz = A[2, 0] * v[t, 0] + A[2, 1] * v[t, 1] + A[2, 2] * v[t, 2]
        xn = (A[0, 0] * v[t, 0] + A[0, 1] * v[t, 1] + A[0, 2] * v[t, 2]) / bz
        yn = (A[1, 0] * v[t, 0] + A[1, 1] * v[t, 1] + A[1, 2] * v[t, 2]) / bz
        x, y = k1_offset(xn, yn, f, k1)
        out[2 * t] = x - q[t, 0]
        out[2 * t + 1] = y - q[t, 1]


@njit(cache=True, error_model="numpy")
def _gauss_newton(A, f, k1, v, q, n_params, iterations, cauchy_px):
    """Robust least-squares fit of attitude (3), focal length and k1 (``n_params`` = 3, 4 or 5)
    to pixel offsets ``q`` of catalogue vectors ``v``.

    Gauss–Newton on ``u = f·x_n·(1 + k1·r²)`` (and ``v``) with the analytic Jacobian of a small
    rotation ``δ`` (``A ← R(δ) A``, ``∂b/∂δ = −[b×]``), and Cauchy weights
    ``1 / (1 + (d / cauchy_px)²)`` so that a few wrong pairs pull little. Returns (A, f, k1).
    """
    m = len(v)
    N = np.empty((n_params, n_params))
    g = np.empty(n_params)
    c2 = cauchy_px * cauchy_px
    # Per star: residuals (u, v), weight, and the Jacobian rows of u (5) and v (5).
    J = np.empty((_J_ROWS, m))
    for _ in range(iterations):
        # First every star's terms (independent: the divisions overlap), then the sums in order.
        a00, a01, a02 = A[0, 0], A[0, 1], A[0, 2]
        a10, a11, a12 = A[1, 0], A[1, 1], A[1, 2]
        a20, a21, a22 = A[2, 0], A[2, 1], A[2, 2]
        for t in range(m):
            bx = a00 * v[t, 0] + a01 * v[t, 1] + a02 * v[t, 2]
            by = a10 * v[t, 0] + a11 * v[t, 1] + a12 * v[t, 2]
            bz = a20 * v[t, 0] + a21 * v[t, 1] + a22 * v[t, 2]
            xn, yn = bx / bz, by / bz
            r2 = xn * xn + yn * yn
            gr = 1.0 + k1 * r2
            ru = f * xn * gr - q[t, 0]
            rv = f * yn * gr - q[t, 1]
            dudx, dudy = f * (gr + 2.0 * k1 * xn * xn), f * 2.0 * k1 * xn * yn
            dvdx, dvdy = dudy, f * (gr + 2.0 * k1 * yn * yn)
            # d(xn)/dδ and d(yn)/dδ from db/dδ = -[b×].
            dx0, dx1, dx2 = (0.0 - xn * by) / bz, (bz + xn * bx) / bz, (-by) / bz
            dy0, dy1, dy2 = (-bz - yn * by) / bz, (0.0 + yn * bx) / bz, bx / bz
            J[_RU, t], J[_RV, t], J[_W, t] = ru, rv, 1.0 / (1.0 + (ru * ru + rv * rv) / c2)
            J[_DU, t], J[_DU + 1, t] = dudx * dx0 + dudy * dy0, dudx * dx1 + dudy * dy1
            J[_DU + 2, t] = dudx * dx2 + dudy * dy2
            J[_DV, t], J[_DV + 1, t] = dvdx * dx0 + dvdy * dy0, dvdx * dx1 + dvdy * dy1
            J[_DV + 2, t] = dvdx * dx2 + dvdy * dy2
            J[_DU + 3, t], J[_DV + 3, t] = xn * gr, yn * gr
            J[_DU + 4, t], J[_DV + 4, t] = f * xn * r2, f * yn * r2
        # The 15 sums of the 5-parameter normal matrix and 5 of the gradient as scalars; a
        # smaller fit uses the leading block.
        n00 = n01 = n02 = n03 = n04 = n11 = n12 = n13 = n14 = n22 = n23 = n24 = n33 = n34 = n44 = 0.0
        g0 = g1 = g2 = g3 = g4 = 0.0
        for t in range(m):
            ru, rv, w = J[_RU, t], J[_RV, t], J[_W, t]
            u0, u1, u2, u3, u4 = J[_DU, t], J[_DU + 1, t], J[_DU + 2, t], J[_DU + 3, t], J[_DU + 4, t]
            v0, v1, v2, v3, v4 = J[_DV, t], J[_DV + 1, t], J[_DV + 2, t], J[_DV + 3, t], J[_DV + 4, t]
            g0 += w * (u0 * ru + v0 * rv)
            g1 += w * (u1 * ru + v1 * rv)
            g2 += w * (u2 * ru + v2 * rv)
            n00 += w * (u0 * u0 + v0 * v0)
            n01 += w * (u0 * u1 + v0 * v1)
            n02 += w * (u0 * u2 + v0 * v2)
            n11 += w * (u1 * u1 + v1 * v1)
            n12 += w * (u1 * u2 + v1 * v2)
            n22 += w * (u2 * u2 + v2 * v2)
            if n_params > 3:
                g3 += w * (u3 * ru + v3 * rv)
                n03 += w * (u0 * u3 + v0 * v3)
                n13 += w * (u1 * u3 + v1 * v3)
                n23 += w * (u2 * u3 + v2 * v3)
                n33 += w * (u3 * u3 + v3 * v3)
            if n_params > 4:
                g4 += w * (u4 * ru + v4 * rv)
                n04 += w * (u0 * u4 + v0 * v4)
                n14 += w * (u1 * u4 + v1 * v4)
                n24 += w * (u2 * u4 + v2 * v4)
                n34 += w * (u3 * u4 + v3 * v4)
                n44 += w * (u4 * u4 + v4 * v4)
        N[0, 0], N[0, 1], N[0, 2], N[1, 1], N[1, 2], N[2, 2] = n00, n01, n02, n11, n12, n22
        g[0], g[1], g[2] = g0, g1, g2
        if n_params > 3:
            N[0, 3], N[1, 3], N[2, 3], N[3, 3], g[3] = n03, n13, n23, n33, g3
        if n_params > 4:
            N[0, 4], N[1, 4], N[2, 4], N[3, 4], N[4, 4], g[4] = n04, n14, n24, n34, n44, g4
        for i in range(n_params):
            for j in range(i):
                N[i, j] = N[j, i]
        step, ok = _solve_spd(N, -g)
        if not ok:
            break
        A = matmul3(rodrigues(step[:3]), A)
        if n_params > 3:
            f += step[3]
        if n_params > 4:
            k1 += step[4]
        if abs(step[0]) + abs(step[1]) + abs(step[2]) < 1e-7 and (n_params < 4 or abs(step[3]) < 1e-6 * f):
            break
    return A, f, k1


@njit(cache=True)
def refine_entry(image, A, f, settings, stars):
    """:func:`refine` with its NamedTuple arguments as plain tuples (``tuple(nt)``): the entry
    for Python callers (:mod:`skyfix.identify.catalogue.kernel_data` says why)."""
    return refine(ImageStars(*image), A, f, RefineSettings(*settings), StarIndex(*stars))


@njit(cache=True)
def refine(image, A, f, settings, stars):
    """Match all stars with the accepted attitude ``A`` at focal length ``f``, refit, re-match
    (``settings.iterations`` times).

    Each pass matches the ``n_img`` brightest centroids of ``image`` (:class:`ImageStars`; the
    first pass only ``n_first``) to the catalogue stars of ``stars`` (:class:`StarIndex`) in
    view (about twice as deep) and fits, by robust Gauss–Newton on the pixel residuals, the
    attitude and, when ``fit_focal``, the focal length and — from the second pass on, with at
    least ``fit_k1_min`` matches, and only if it reduces χ² significantly — radial distortion
    k1 (``p = f·x_n·(1 + k1·r²)``). The match radius then shrinks to 3.5 robust σ of the
    residuals (not below 1.5σ of the centroid noise). ``settings`` is a :class:`RefineSettings`.

    Returns a :class:`Refit`. When a later pass matches fewer than 3 stars, the pairs of the
    pass before are returned with the attitude and focal length given (k1 = 0): the fits of
    the passes are dropped.
    """
    p, frame = image.offsets_px, image.frame_px
    fit_focal, fit_k1_min, n_first, n_img, radius_px, sigma_px, iterations = settings
    star_vectors = stars.vectors
    out_img = np.empty(16384, dtype=np.int64)
    out_star = np.empty(16384, dtype=np.int64)
    view = ViewBuffers(np.empty(16384, dtype=np.int64), np.empty(16384), np.empty(16384),
                       np.zeros(n_img, dtype=np.bool_), np.empty(16384, dtype=np.int64))
    view_idx, match_img = view.index, view.match
    f_given = f
    k1 = 0.0
    radius = radius_px
    n_pairs = 0
    rms = radius_px
    last_radius = radius_px
    last_n_cat = 0
    A_cur = A.copy()
    use_k1 = -1  # undecided; decided once, on the first pass with all stars
    # Cells of twice the match radius: a quarter of the cells to set up, the same matches.
    cell = 2.0 * radius_px
    grid = grid_index(p, n_img, frame, cell)
    # The catalogue stars that can come into view while the fit moves (once, brightest first).
    ext = np.sqrt(max(frame[0] ** 2, frame[1] ** 2) + max(frame[2] ** 2, frame[3] ** 2))
    limit = star_limit(len(star_vectors), n_img, frame, f, 3.0)
    near = gather_stars(A[2], np.arctan(ext / f) * 1.1 + 0.02, limit, stars)
    for it in range(iterations + 1):
        # The first pass matches only the brightest stars, where chance neighbours are rare.
        n_use = min(n_img, n_first) if it == 0 else n_img
        n_cat = project_stars(near, A_cur, f, k1, frame, 2 * n_use, stars, view)
        n_match = match_grid(view, n_cat, p, n_use, grid, radius)
        if n_match < 3:
            return Refit(n_pairs, out_img[:n_pairs], out_star[:n_pairs], A.copy(), f_given, 0.0, rms,
                         last_radius, last_n_cat)
        n_pairs = 0
        for j in range(n_cat):
            if match_img[j] >= 0:
                out_img[n_pairs] = match_img[j]
                out_star[n_pairs] = view_idx[j]
                n_pairs += 1
        last_radius = radius
        last_n_cat = n_cat
        if it == iterations:
            break
        v = np.empty((n_pairs, 3))
        q = np.empty((n_pairs, 2))
        for t in range(n_pairs):
            s, i = out_star[t], out_img[t]
            v[t, 0], v[t, 1], v[t, 2] = star_vectors[s, 0], star_vectors[s, 1], star_vectors[s, 2]
            q[t, 0], q[t, 1] = p[i, 0], p[i, 1]
        res = np.empty(2 * n_pairs)
        cauchy = radius / 1.5
        if not fit_focal:
            # np.int64(): typed ints, not literals, so that every call shares one compiled
            # _gauss_newton (each literal pair compiled a copy of its own: ~7 s of first-solve time)
            A_cur, f, k1 = _gauss_newton(A_cur, f, k1, v, q, np.int64(3), np.int64(8), cauchy)
        else:
            if use_k1 == 1:
                A_cur, f, k1 = _gauss_newton(A_cur, f, k1, v, q, np.int64(5), np.int64(8), cauchy)
                A4, f4 = A_cur, f
            else:
                A4, f4, _ = _gauss_newton(A_cur, f, 0.0, v, q, np.int64(4), np.int64(8), cauchy)
                A_cur, f, k1 = A4, f4, 0.0
            if use_k1 < 0 and it > 0 and n_pairs >= fit_k1_min:
                use_k1 = 0
                # Free k1 only when it explains the residuals significantly (Δχ² > 25 σ²):
                # with stars in one part of the frame it trades off against pointing and scale.
                dof = max(2 * n_pairs - 5, 1)
                _residuals(A4, f4, 0.0, v, q, res)
                chi4 = np.sum(res**2 / (1.0 + res**2 / cauchy**2))
                # One step with k1 free predicts the full fit's gain (the full gain was at most
                # 1.8 times the one-step gain on 1200 trials, synthetic and real): the full fit
                # only when a gain of 4 times the step's could pass (Δχ² > 25 χ²/(dof + 25)).
                A1, f1, k1_step = _gauss_newton(A4, f4, 0.0, v, q, np.int64(5), np.int64(1), cauchy)
                _residuals(A1, f1, k1_step, v, q, res)
                gain_step = chi4 - np.sum(res**2 / (1.0 + res**2 / cauchy**2))
                if 4.0 * gain_step > 25.0 * chi4 / (dof + 25):
                    A5, f5, k5 = _gauss_newton(A4, f4, 0.0, v, q, np.int64(5), np.int64(8), cauchy)
                    _residuals(A5, f5, k5, v, q, res)
                    chi5 = np.sum(res**2 / (1.0 + res**2 / cauchy**2))
                    if chi4 - chi5 > 25.0 * chi5 / dof:
                        A_cur, f, k1 = A5, f5, k5
                        use_k1 = 1
        _residuals(A_cur, f, k1, v, q, res)
        dist = np.sqrt(res[0::2] ** 2 + res[1::2] ** 2)
        sigma_est = np.median(dist) / 1.1774  # median of a 2-D Gaussian distance is 1.1774 σ
        radius = min(radius_px, max(3.5 * sigma_est, 1.5 * sigma_px))
        rms = np.sqrt(np.mean(dist**2))
    return Refit(n_pairs, out_img[:n_pairs], out_star[:n_pairs], A_cur, f, k1, rms, last_radius, last_n_cat)
