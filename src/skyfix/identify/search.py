"""The compiled inner loop of the 4-star search: image patterns -> candidate catalogue patterns.

For each image 4-star combination (in the breadth-first order the caller gives), the kernel
computes the edge ratios from camera rays at an assumed focal length, probes every key bin
within the tolerance, walks the hash table, keeps catalogue patterns whose ratios agree, then
estimates the focal length from the ratio of largest edges, recomputes the image ratios at that
focal length and keeps the pattern only if they agree tightly and the focal length is allowed.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from skyfix.identify.hashing import lookup_run

__all__ = ["breadth_first_combinations", "search"]

_COMBOS: dict[int, np.ndarray] = {}


def breadth_first_combinations(n: int) -> np.ndarray:
    """All 4-subsets of ``range(n)`` ordered so that those of the brightest stars come first.

    Subsets are sorted by their largest member, then lexicographically: every subset of the
    first ``m`` stars precedes any subset that uses star ``m``.
    """
    if n not in _COMBOS:
        i, j, k, m = np.meshgrid(*[np.arange(n)] * 4, indexing="ij")
        sel = (i < j) & (j < k) & (k < m)
        c = np.stack([i[sel], j[sel], k[sel], m[sel]], axis=1)
        order = np.lexsort((c[:, 2], c[:, 1], c[:, 0], c[:, 3]))
        _COMBOS[n] = np.ascontiguousarray(c[order], dtype=np.int64)
    return _COMBOS[n]


@numba.njit(cache=True, inline="always")
def _pattern_edges(p: np.ndarray, combo: np.ndarray, f: float, out: np.ndarray) -> None:
    """Sorted six edge angles (radians) of image stars ``combo`` at focal length ``f`` (pixels)."""
    rays = np.empty((4, 3))
    for a in range(4):
        x = p[combo[a], 0] / f
        y = p[combo[a], 1] / f
        n = np.sqrt(x * x + y * y + 1.0)
        rays[a, 0] = x / n
        rays[a, 1] = y / n
        rays[a, 2] = 1.0 / n
    e = 0
    for a in range(4):
        for b in range(a + 1, 4):
            dx = rays[a, 0] - rays[b, 0]
            dy = rays[a, 1] - rays[b, 1]
            dz = rays[a, 2] - rays[b, 2]
            out[e] = 2.0 * np.arcsin(min(np.sqrt(dx * dx + dy * dy + dz * dz) / 2.0, 1.0))
            e += 1
    out.sort()


@numba.njit(cache=True)
def _log_binom_sf(k: int, n: int, p: float) -> float:
    """log P(X >= k) for X ~ Binomial(n, p)."""
    if k <= 0:
        return 0.0
    if k > n:
        return -np.inf
    p = min(max(p, 1e-300), 1.0 - 1e-16)
    lp, lq = np.log(p), np.log1p(-p)
    base = math.lgamma(n + 1.0)
    best = -np.inf
    terms = np.empty(n - k + 1)
    for j in range(k, n + 1):
        t = base - math.lgamma(j + 1.0) - math.lgamma(n - j + 1.0) + j * lp + (n - j) * lq
        terms[j - k] = t
        best = max(best, t)
    acc = 0.0
    for t in terms:
        acc += np.exp(t - best)
    return best + np.log(acc)


@numba.njit(cache=True)
def _kabsch(b: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Proper rotation A minimising Σ|b − A r|² (SVD; det A = +1, so mirror images fit badly)."""
    B = b.T @ r
    U, _, Vt = np.linalg.svd(B)
    d = np.linalg.det(U) * np.linalg.det(Vt)
    D = np.eye(3)
    D[2, 2] = d
    return U @ D @ Vt


@numba.njit(cache=True)
def _angle_matrix(v: np.ndarray, out: np.ndarray) -> None:
    for a in range(4):
        out[a, a] = 0.0
        for b in range(a + 1, 4):
            d = np.sqrt(np.sum((v[a] - v[b]) ** 2))
            out[a, b] = out[b, a] = 2.0 * np.arcsin(min(d / 2.0, 1.0))


@numba.njit(cache=True)
def _stars_in_view(A, f, k1, frame, star_limit, star_vectors, cell_centres, cell_start, cell_stars,
                   cell_radius, out_idx, out_x, out_y):
    """Catalogue stars (index < ``star_limit``) that project into the frame, brightest first.

    Projection in the undistorted offset space of ``p``: ``x = f·x_n·(1 + k1·r²)``.
    Returns the count written to ``out_*``.
    """
    x_lo, x_hi, y_lo, y_hi = frame[0], frame[1], frame[2], frame[3]
    ext = np.sqrt(max(x_lo * x_lo, x_hi * x_hi) + max(y_lo * y_lo, y_hi * y_hi))
    half_diag = np.arctan(ext / f) * (1.0 + 2.0 * abs(k1)) + 0.01
    cos_cell = np.cos(min(half_diag + cell_radius, np.pi))
    n = 0
    for cell in range(len(cell_centres)):
        cc = cell_centres[cell]
        if cc[0] * A[2, 0] + cc[1] * A[2, 1] + cc[2] * A[2, 2] < cos_cell:
            continue
        for t in range(cell_start[cell], cell_start[cell + 1]):
            s = cell_stars[t]
            if s >= star_limit:
                break  # cells list their stars brightest first
            v = star_vectors[s]
            bz = A[2, 0] * v[0] + A[2, 1] * v[1] + A[2, 2] * v[2]
            if bz <= 1e-6:
                continue
            xn = (A[0, 0] * v[0] + A[0, 1] * v[1] + A[0, 2] * v[2]) / bz
            yn = (A[1, 0] * v[0] + A[1, 1] * v[1] + A[1, 2] * v[2]) / bz
            radial = f * (1.0 + k1 * (xn * xn + yn * yn))
            x = xn * radial
            y = yn * radial
            if x < x_lo or x > x_hi or y < y_lo or y > y_hi or n >= len(out_idx):
                continue
            out_idx[n] = s
            out_x[n] = x
            out_y[n] = y
            n += 1
    order = np.argsort(out_idx[:n])
    out_idx[:n] = out_idx[:n][order]
    out_x[:n] = out_x[:n][order]
    out_y[:n] = out_y[:n][order]
    return n


@numba.njit(cache=True)
def _match(view_x, view_y, n_cat, p, n_img, radius_px, used, match_img):
    """Greedy one-to-one matching, brightest catalogue star first, nearest free centroid within
    the radius. ``match_img[j]`` = centroid of catalogue star ``j`` or -1; returns the count."""
    used[:n_img] = False
    r2 = radius_px * radius_px
    n_match = 0
    for j in range(n_cat):
        best_d = r2
        best_i = -1
        for i in range(n_img):
            if used[i]:
                continue
            d = (p[i, 0] - view_x[j]) ** 2 + (p[i, 1] - view_y[j]) ** 2
            if d <= best_d:
                best_d = d
                best_i = i
        match_img[j] = best_i
        if best_i >= 0:
            used[best_i] = True
            n_match += 1
    return n_match


@numba.njit(cache=True)
def _grid_index(p, n_img, frame, cell):
    """Bucket the first ``n_img`` points of ``p`` into square cells of side ``cell`` over the
    frame: returns (nx, ny, start (nx·ny + 1,), items) for :func:`_match_grid`."""
    nx = max(1, int((frame[1] - frame[0]) / cell) + 1)
    ny = max(1, int((frame[3] - frame[2]) / cell) + 1)
    ids = np.empty(n_img, dtype=np.int64)
    count = np.zeros(nx * ny + 1, dtype=np.int64)
    for i in range(n_img):
        gx = min(nx - 1, max(0, int((p[i, 0] - frame[0]) / cell)))
        gy = min(ny - 1, max(0, int((p[i, 1] - frame[2]) / cell)))
        ids[i] = gy * nx + gx
        count[ids[i] + 1] += 1
    start = np.cumsum(count)
    fill = start[:-1].copy()
    items = np.empty(n_img, dtype=np.int64)
    for i in range(n_img):  # in index order, so each cell lists the brightest first
        items[fill[ids[i]]] = i
        fill[ids[i]] += 1
    return nx, ny, start, items


@numba.njit(cache=True)
def _match_grid(view_x, view_y, n_cat, p, n_use, frame, cell, nx, ny, start, items, radius_px, used,
                match_img):
    """:func:`_match` against centroids ``< n_use`` bucketed by :func:`_grid_index`
    (``radius_px <= cell``)."""
    used[:] = False
    r2 = radius_px * radius_px
    n_match = 0
    for j in range(n_cat):
        gx = int((view_x[j] - frame[0]) / cell)
        gy = int((view_y[j] - frame[2]) / cell)
        best_d = r2
        best_i = -1
        for yy in range(max(0, gy - 1), min(ny, gy + 2)):
            for xx in range(max(0, gx - 1), min(nx, gx + 2)):
                cid = yy * nx + xx
                for t in range(start[cid], start[cid + 1]):
                    i = items[t]
                    if i >= n_use:
                        break  # cells list their centroids brightest first
                    if used[i]:
                        continue
                    d = (p[i, 0] - view_x[j]) ** 2 + (p[i, 1] - view_y[j]) ** 2
                    if d <= best_d:
                        best_d = d
                        best_i = i
        match_img[j] = best_i
        if best_i >= 0:
            used[best_i] = True
            n_match += 1
    return n_match


def _star_limit(n_stars, n_img, frame, f, depth):
    """Catalogue depth (a brightness rank) with ~``depth``·``n_img`` stars in the frame on average."""
    frame_sr = (frame[1] - frame[0]) * (frame[3] - frame[2]) / (f * f)
    return min(n_stars, int(depth * n_img * 4.0 * np.pi / frame_sr) + 1)


_star_limit_jit = numba.njit(cache=True)(_star_limit)


@numba.njit(cache=True)
def _verify(A, f, frame, n_cat_max, n_img, p, radius_px, pattern, combo, star_vectors, cell_centres,
            cell_start, cell_stars, cell_radius, view_idx, view_x, view_y, used, match_img):
    """log P(a wrong attitude matches as well) and the counts, for the ``n_cat_max`` brightest
    catalogue stars in view matched to the ``n_img`` brightest centroids.

    The pattern's own stars are not counted. Each catalogue star lands by chance within ``r`` of
    some centroid with ``p = n_img·π·r² / frame area``; the matches are counted within the full
    radius and within a half and a quarter of it (a clean frame earns the tighter, more telling
    test; a distorted one still passes with the full radius), and the best of the three binomial
    tails, times 3 for the choice, is returned with (matches within the radius, catalogue stars).
    """
    limit = _star_limit_jit(len(star_vectors), n_cat_max, frame, f, 2.0)
    n_view = _stars_in_view(A, f, 0.0, frame, limit, star_vectors, cell_centres, cell_start,
                            cell_stars, cell_radius, view_idx, view_x, view_y)
    n_cat = min(n_view, n_cat_max)
    _match(view_x, view_y, n_cat, p, n_img, radius_px, used, match_img)
    k_full = k_half = k_quarter = 0
    n = 0
    r2 = radius_px * radius_px
    for j in range(n_cat):
        own = False
        for a in range(4):
            if view_idx[j] == pattern[a]:
                own = True
        if own:
            continue
        n += 1
        i = match_img[j]
        if i >= 0 and i != combo[0] and i != combo[1] and i != combo[2] and i != combo[3]:
            k_full += 1
            d2 = (p[i, 0] - view_x[j]) ** 2 + (p[i, 1] - view_y[j]) ** 2
            if d2 <= r2 / 4.0:
                k_half += 1
            if d2 <= r2 / 16.0:
                k_quarter += 1
    p_full = min(1.0, n_img * np.pi * r2 / ((frame[1] - frame[0]) * (frame[3] - frame[2])))
    logp = min(_log_binom_sf(k_full, n, p_full), _log_binom_sf(k_half, n, p_full / 4.0),
               _log_binom_sf(k_quarter, n, p_full / 16.0)) + np.log(3.0)
    return logp, k_full, n


@numba.njit(cache=True)
def search(p, combos, start, stop, f0, f_lo, f_hi, fix_focal, eps_key, sigma_px, model_err, n_bins,
           table, key_codes, key_start, pattern_ratios, pattern_largest, pattern_stars, star_vectors,
           cell_centres, cell_start, cell_stars, cell_radius, frame, n_verify, radius_px,
           log_threshold, trials_before, cand_before, perms, result_A, result_stats):
    """Search image combinations ``start:stop`` for a verified catalogue pattern.

    Parameters
    ----------
    p : (N, 2) float64 — image stars as undistorted pixel offsets from the principal point
        (``x_n · f0``), brightest first.
    combos : (C, 4) int64 — image-star index quadruples, in search order.
    f0 : float — assumed focal length (pixels); ``f_lo``–``f_hi`` the allowed range;
        ``fix_focal`` — use ``f0`` itself (calibrated camera).
    eps_key : float — ratio tolerance of the key probe (covers the unknown focal length).
    sigma_px, model_err : float — centroid noise (pixels) and the ratio error of the unmodelled
        camera; the tight ratio tolerance is ``4·√2·σ / L_px + model_err``.
    cell_* : the database's sky-cell index of all stars (verification).
    frame : (4,) float — x_lo, x_hi, y_lo, y_hi of the frame in ``p`` coordinates.
    n_verify : int — image stars (and at most as many catalogue stars) used in verification.
    radius_px : float — verification match radius.
    log_threshold : float — log of the largest accepted false-match probability.
    trials_before, cand_before : int — look-elsewhere counts of earlier calls.
    perms : (24, 4) int64 — all vertex permutations.
    result_A : (3, 3) out — accepted attitude; result_stats : (6,) out — f, log P(false),
        combination index, pattern index, n matched, n catalogue.

    Returns
    -------
    (found, n_done, n_candidates) — whether a pattern was accepted, combinations processed,
    candidates verified.
    """
    edges = np.empty(6)
    edges1 = np.empty(6)
    runs = np.empty((1024, 2), dtype=np.int64)
    lo = np.empty(5, dtype=np.int64)
    hi = np.empty(5, dtype=np.int64)
    cur = np.empty(5, dtype=np.int64)
    weights = np.empty(5, dtype=np.int64)
    w = 1
    for i in range(5):
        weights[i] = w
        w *= n_bins
    b = np.empty((4, 3))
    r = np.empty((4, 3))
    rp = np.empty((4, 3))
    ai = np.empty((4, 4))
    ac = np.empty((4, 4))
    view_idx = np.empty(8192, dtype=np.int64)
    view_x = np.empty(8192)
    view_y = np.empty(8192)
    n_img = min(n_verify, len(p))
    used = np.zeros(n_img, dtype=np.bool_)
    match_img = np.empty(8192, dtype=np.int64)
    n_cand = 0
    for c in range(start, stop):
        combo = combos[c]
        _pattern_edges(p, combo, f0, edges)
        largest = edges[5]
        if largest <= 0.0:
            continue
        for i in range(5):
            rr = edges[i] / largest
            lo[i] = max(0, min(n_bins - 1, np.int64((rr - eps_key) * n_bins)))
            hi[i] = max(0, min(n_bins - 1, np.int64((rr + eps_key) * n_bins)))
            cur[i] = lo[i]
        # Every key code in the box lo..hi (an odometer over the five bins); each code's
        # patterns are one contiguous run.
        n_runs = 0
        while True:
            code = np.int64(0)
            ok = True
            for i in range(5):
                if i > 0 and cur[i] < cur[i - 1]:
                    ok = False  # sorted ratios have non-decreasing bins
                code += cur[i] * weights[i]
            if ok:
                r0, r1 = lookup_run(code, table, key_codes, key_start)
                if r1 > r0 and n_runs < len(runs):
                    runs[n_runs, 0] = r0
                    runs[n_runs, 1] = r1
                    n_runs += 1
            i = 0
            while i < 5:
                cur[i] += 1
                if cur[i] <= hi[i]:
                    break
                cur[i] = lo[i]
                i += 1
            if i == 5:
                break
        for k in range(n_runs):
            for q in range(runs[k, 0], runs[k, 1]):
                bad = False
                for i in range(5):
                    if abs(edges[i] / largest - pattern_ratios[q, i]) > eps_key:
                        bad = True
                        break
                if bad:
                    continue
                # Focal length from the largest edges (angles scale ~ 1/f), refined once.
                if fix_focal:
                    f1 = f0
                else:
                    f1 = f0 * largest / pattern_largest[q]
                    _pattern_edges(p, combo, f1, edges1)
                    f1 = f1 * edges1[5] / pattern_largest[q]
                if f1 < f_lo or f1 > f_hi:
                    continue
                _pattern_edges(p, combo, f1, edges1)
                tol = 4.0 * 1.4142 * sigma_px / (edges1[5] * f1) + model_err
                bad = False
                for i in range(5):
                    if abs(edges1[i] / edges1[5] - pattern_ratios[q, i]) > tol:
                        bad = True
                        break
                if bad:
                    continue
                n_cand += 1
                # Vertex correspondence: the permutation whose six edges agree best.
                for a in range(4):
                    x = p[combo[a], 0] / f1
                    y = p[combo[a], 1] / f1
                    nn = np.sqrt(x * x + y * y + 1.0)
                    b[a, 0], b[a, 1], b[a, 2] = x / nn, y / nn, 1.0 / nn
                    r[a] = star_vectors[pattern_stars[q, a]]
                _angle_matrix(b, ai)
                _angle_matrix(r, ac)
                best_err = np.inf
                best = 0
                for m in range(len(perms)):
                    err = 0.0
                    for a in range(4):
                        for a2 in range(a + 1, 4):
                            err = max(err, abs(ai[a, a2] - ac[perms[m, a], perms[m, a2]]))
                    if err < best_err:
                        best_err = err
                        best = m
                for a in range(4):
                    rp[a] = r[perms[best, a]]
                A = _kabsch(b, rp)
                resid = 0.0
                for a in range(4):
                    resid = max(resid, np.sqrt(np.sum((b[a] - A @ rp[a]) ** 2)))
                if resid * f1 > radius_px:
                    continue  # a mirror image or an inconsistent correspondence
                # Verification: the brightest catalogue stars in the frame, matched to centroids.
                # A quick first stage (the 15 brightest against 30 centroids) rejects most false
                # candidates at a third of the cost; the pattern's own stars are not counted.
                n_img1 = min(n_img, 30)
                logp1, _, n1_ = _verify(A, f1, frame, 15, n_img1, p, radius_px, pattern_stars[q], combo,
                                        star_vectors, cell_centres, cell_start, cell_stars, cell_radius,
                                        view_idx, view_x, view_y, used, match_img)
                if n1_ >= 3 and logp1 > -3.0:
                    continue
                logp, n_match, n_cat = _verify(A, f1, frame, n_img, n_img, p, radius_px, pattern_stars[q],
                                               combo, star_vectors, cell_centres, cell_start, cell_stars,
                                               cell_radius, view_idx, view_x, view_y, used, match_img)
                n_trials = cand_before + n_cand  # look-elsewhere: candidates examined so far
                logp += np.log(n_trials)
                if logp <= log_threshold:
                    result_A[:, :] = A
                    result_stats[0] = f1
                    result_stats[1] = logp
                    result_stats[2] = c
                    result_stats[3] = q
                    result_stats[4] = n_match
                    result_stats[5] = n_cat
                    return True, c - start + 1, n_cand
    return False, stop - start, n_cand


@numba.njit(cache=True)
def _rotation(d):
    """Rotation matrix of the rotation vector ``d`` (Rodrigues)."""
    th2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    if th2 < 1e-24:
        a, b = 1.0, 0.5
    else:
        th = np.sqrt(th2)
        a, b = np.sin(th) / th, (1.0 - np.cos(th)) / th2
    x, y, z = d[0], d[1], d[2]
    R = np.empty((3, 3))
    R[0, 0] = 1.0 - b * (y * y + z * z)
    R[1, 1] = 1.0 - b * (x * x + z * z)
    R[2, 2] = 1.0 - b * (x * x + y * y)
    R[0, 1], R[1, 0] = -a * z + b * x * y, a * z + b * x * y
    R[0, 2], R[2, 0] = a * y + b * x * z, -a * y + b * x * z
    R[1, 2], R[2, 1] = -a * x + b * y * z, a * x + b * y * z
    return R


@numba.njit(cache=True)
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


@numba.njit(cache=True)
def _residuals(A, f, k1, v, q, out):
    """Pixel residuals (2M,) of projected catalogue vectors ``v`` against offsets ``q``."""
    for t in range(len(v)):
        bz = A[2, 0] * v[t, 0] + A[2, 1] * v[t, 1] + A[2, 2] * v[t, 2]
        xn = (A[0, 0] * v[t, 0] + A[0, 1] * v[t, 1] + A[0, 2] * v[t, 2]) / bz
        yn = (A[1, 0] * v[t, 0] + A[1, 1] * v[t, 1] + A[1, 2] * v[t, 2]) / bz
        radial = f * (1.0 + k1 * (xn * xn + yn * yn))
        out[2 * t] = xn * radial - q[t, 0]
        out[2 * t + 1] = yn * radial - q[t, 1]


@numba.njit(cache=True)
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
    ju = np.empty(5)
    jv = np.empty(5)
    c2 = cauchy_px * cauchy_px
    for _ in range(iterations):
        N[:, :] = 0.0
        g[:] = 0.0
        for t in range(m):
            bx = A[0, 0] * v[t, 0] + A[0, 1] * v[t, 1] + A[0, 2] * v[t, 2]
            by = A[1, 0] * v[t, 0] + A[1, 1] * v[t, 1] + A[1, 2] * v[t, 2]
            bz = A[2, 0] * v[t, 0] + A[2, 1] * v[t, 1] + A[2, 2] * v[t, 2]
            xn, yn = bx / bz, by / bz
            r2 = xn * xn + yn * yn
            gr = 1.0 + k1 * r2
            ru = f * xn * gr - q[t, 0]
            rv = f * yn * gr - q[t, 1]
            w = 1.0 / (1.0 + (ru * ru + rv * rv) / c2)
            dudx, dudy = f * (gr + 2.0 * k1 * xn * xn), f * 2.0 * k1 * xn * yn
            dvdx, dvdy = dudy, f * (gr + 2.0 * k1 * yn * yn)
            # d(xn)/dδ and d(yn)/dδ from db/dδ = -[b×].
            dx0, dx1, dx2 = (0.0 - xn * by) / bz, (bz + xn * bx) / bz, (-by) / bz
            dy0, dy1, dy2 = (-bz - yn * by) / bz, (0.0 + yn * bx) / bz, bx / bz
            ju[0], ju[1], ju[2] = dudx * dx0 + dudy * dy0, dudx * dx1 + dudy * dy1, dudx * dx2 + dudy * dy2
            jv[0], jv[1], jv[2] = dvdx * dx0 + dvdy * dy0, dvdx * dx1 + dvdy * dy1, dvdx * dx2 + dvdy * dy2
            ju[3], jv[3] = xn * gr, yn * gr
            ju[4], jv[4] = f * xn * r2, f * yn * r2
            for i in range(n_params):
                g[i] += w * (ju[i] * ru + jv[i] * rv)
                for j in range(i, n_params):
                    N[i, j] += w * (ju[i] * ju[j] + jv[i] * jv[j])
        for i in range(n_params):
            for j in range(i):
                N[i, j] = N[j, i]
        step, ok = _solve_spd(N, -g)
        if not ok:
            break
        A = _rotation(step[:3]) @ A
        if n_params > 3:
            f += step[3]
        if n_params > 4:
            k1 += step[4]
        if abs(step[0]) + abs(step[1]) + abs(step[2]) < 1e-7 and (n_params < 4 or abs(step[3]) < 1e-6 * f):
            break
    return A, f, k1


@numba.njit(cache=True)
def _gather(z, cone, limit, star_vectors, cell_centres, cell_start, cell_stars, cell_radius):
    """Indices (sorted: brightest first) of stars ``< limit`` within ``cone`` radians of ``z``."""
    cos_cell = np.cos(min(cone + cell_radius, np.pi))
    cos_cone = np.cos(min(cone, np.pi))
    out = np.empty(min(limit, len(star_vectors)), dtype=np.int64)
    n = 0
    for cell in range(len(cell_centres)):
        cc = cell_centres[cell]
        if cc[0] * z[0] + cc[1] * z[1] + cc[2] * z[2] < cos_cell:
            continue
        for t in range(cell_start[cell], cell_start[cell + 1]):
            s = cell_stars[t]
            if s >= limit:
                break
            v = star_vectors[s]
            if v[0] * z[0] + v[1] * z[1] + v[2] * z[2] >= cos_cone:
                out[n] = s
                n += 1
    return np.sort(out[:n])


@numba.njit(cache=True)
def _project(near, A, f, k1, frame, n_max, star_vectors, out_idx, out_x, out_y):
    """Project stars ``near`` (brightest first); keep the first ``n_max`` in the frame."""
    n = 0
    for s in near:
        v = star_vectors[s]
        bz = A[2, 0] * v[0] + A[2, 1] * v[1] + A[2, 2] * v[2]
        if bz <= 1e-6:
            continue
        xn = (A[0, 0] * v[0] + A[0, 1] * v[1] + A[0, 2] * v[2]) / bz
        yn = (A[1, 0] * v[0] + A[1, 1] * v[1] + A[1, 2] * v[2]) / bz
        radial = f * (1.0 + k1 * (xn * xn + yn * yn))
        x = xn * radial
        y = yn * radial
        if x < frame[0] or x > frame[1] or y < frame[2] or y > frame[3]:
            continue
        out_idx[n] = s
        out_x[n] = x
        out_y[n] = y
        n += 1
        if n >= n_max or n >= len(out_idx):
            break
    return n


@numba.njit(cache=True)
def refine(p, A, f, fit_focal, fit_k1_min, frame, n_first, n_img, radius_px, sigma_px, star_vectors,
           cell_centres, cell_start, cell_stars, cell_radius, iterations, out_img, out_star, out_fk):
    """Match all stars with the accepted attitude, refit, re-match (``iterations`` times).

    Each pass matches the ``n_img`` brightest centroids (the first pass only ``n_first``) to
    the catalogue stars in view (about twice as deep) and fits, by robust Gauss–Newton on the
    pixel residuals, the attitude and, when ``fit_focal``, the focal length and — from the
    second pass on, with at least ``fit_k1_min`` matches, and only if it reduces χ²
    significantly — radial distortion k1 (``p = f·x_n·(1 + k1·r²)``). The match radius then
    shrinks to 3.5 robust σ of the residuals (not below 1.5σ of the centroid noise).

    Returns the number of matched pairs written to ``out_img`` (centroid) and ``out_star``
    (catalogue index); ``A`` is updated in place; ``out_fk`` = (f, k1, rms px).
    """
    view_idx = np.empty(16384, dtype=np.int64)
    view_x = np.empty(16384)
    view_y = np.empty(16384)
    used = np.zeros(n_img, dtype=np.bool_)
    match_img = np.empty(16384, dtype=np.int64)
    k1 = 0.0
    radius = radius_px
    n_pairs = 0
    out_fk[0] = f
    out_fk[1] = k1
    out_fk[2] = radius_px
    A_cur = A.copy()
    use_k1 = -1  # undecided; decided once, on the first pass with all stars
    nx, ny, gstart, gitems = _grid_index(p, n_img, frame, radius_px)
    # The catalogue stars that can come into view while the fit moves (once, brightest first).
    ext = np.sqrt(max(frame[0] ** 2, frame[1] ** 2) + max(frame[2] ** 2, frame[3] ** 2))
    limit = _star_limit_jit(len(star_vectors), n_img, frame, f, 3.0)
    near = _gather(A[2], np.arctan(ext / f) * 1.1 + 0.02, limit, star_vectors, cell_centres,
                   cell_start, cell_stars, cell_radius)
    for it in range(iterations + 1):
        # The first pass matches only the brightest stars, where chance neighbours are rare.
        n_use = min(n_img, n_first) if it == 0 else n_img
        n_cat = _project(near, A_cur, f, k1, frame, 2 * n_use, star_vectors, view_idx, view_x, view_y)
        n_match = _match_grid(view_x, view_y, n_cat, p, n_use, frame, radius_px, nx, ny, gstart,
                              gitems, radius, used, match_img)
        if n_match < 3:
            return n_pairs
        n_pairs = 0
        for j in range(n_cat):
            if match_img[j] >= 0:
                out_img[n_pairs] = match_img[j]
                out_star[n_pairs] = view_idx[j]
                n_pairs += 1
        if it == iterations:
            break
        v = np.empty((n_pairs, 3))
        q = np.empty((n_pairs, 2))
        for t in range(n_pairs):
            v[t] = star_vectors[out_star[t]]
            q[t] = p[out_img[t]]
        res = np.empty(2 * n_pairs)
        cauchy = radius / 1.5
        if not fit_focal:
            A_cur, f, k1 = _gauss_newton(A_cur, f, k1, v, q, 3, 8, cauchy)
        else:
            if use_k1 == 1:
                A_cur, f, k1 = _gauss_newton(A_cur, f, k1, v, q, 5, 8, cauchy)
                A4, f4 = A_cur, f
            else:
                A4, f4, _ = _gauss_newton(A_cur, f, 0.0, v, q, 4, 8, cauchy)
                A_cur, f, k1 = A4, f4, 0.0
            if use_k1 < 0 and it > 0 and n_pairs >= fit_k1_min:
                use_k1 = 0
                # Free k1 only when it explains the residuals significantly (Δχ² > 25 σ²):
                # with stars in one part of the frame it trades off against pointing and scale.
                A5, f5, k5 = _gauss_newton(A4, f4, 0.0, v, q, 5, 8, cauchy)
                _residuals(A4, f4, 0.0, v, q, res)
                chi4 = np.sum(res**2 / (1.0 + res**2 / cauchy**2))
                _residuals(A5, f5, k5, v, q, res)
                chi5 = np.sum(res**2 / (1.0 + res**2 / cauchy**2))
                if chi4 - chi5 > 25.0 * chi5 / max(2 * n_pairs - 5, 1):
                    A_cur, f, k1 = A5, f5, k5
                    use_k1 = 1
        _residuals(A_cur, f, k1, v, q, res)
        dist = np.sqrt(res[0::2] ** 2 + res[1::2] ** 2)
        sigma_est = np.median(dist) / 1.1774  # median of a 2-D Gaussian distance is 1.1774 σ
        radius = min(radius_px, max(3.5 * sigma_est, 1.5 * sigma_px))
        out_fk[2] = np.sqrt(np.mean(dist**2))
    A[:, :] = A_cur
    out_fk[0] = f
    out_fk[1] = k1
    return n_pairs
