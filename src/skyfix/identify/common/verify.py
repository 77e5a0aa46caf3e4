"""Compiled verification: which catalogue stars a candidate attitude puts in the frame, how
many of them land on centroids, and how likely that is by chance.

A candidate from a 4-star pattern is checked by projecting the brightest catalogue stars in
the field into the frame and matching them to the brightest centroids within a radius. A
*wrong* attitude matches each catalogue star by chance with probability ``p`` = (area of the
match circles) / (frame area), so the number of chance matches is binomial; the pattern's own
four stars, matched by construction, are left out of both counts.

All positions are in the undistorted pixel-offset space ``p = x_n · f`` of the search (see
:mod:`skyfix.identify.common.search`), so a calibrated camera's distortion never enters the kernels.
The data the kernels share are named in :mod:`skyfix.identify.catalogue.kernel_data`: the catalogue's
:class:`~skyfix.identify.catalogue.kernel_data.StarIndex`, the
:class:`~skyfix.identify.catalogue.kernel_data.ViewBuffers` the projections and matches fill, and
the :class:`~skyfix.identify.catalogue.kernel_data.CentroidGrid`.
Whether the match counted here is beyond chance is decided in :mod:`skyfix.identify.accept`.
"""

from __future__ import annotations

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.lens import k1_offset
from skyfix._kernels.probability import log_binom_sf
from skyfix.identify.catalogue.kernel_data import CentroidGrid

_N_RADII = 5  # verification radii R, R/2, ..., R/16
_PLANES_MAX_CELLS = 4.0  # stars_in_view tests edge planes when the frame's cone is < this many cell radii

__all__ = ["cell_band", "star_limit", "stars_in_view", "gather_stars", "project_stars",
           "match_greedy", "grid_index", "match_grid", "verify_attitude"]


@njit(cache=True)
def star_limit(n_stars, n_img, frame, f, depth):
    """Catalogue depth (a brightness rank) with ~``depth``·``n_img`` stars in the frame on average."""
    frame_sr = (frame[1] - frame[0]) * (frame[3] - frame[2]) / (f * f)
    return min(n_stars, int(depth * n_img * 4.0 * np.pi / frame_sr) + 1)


@njit(cache=True)
def cell_band(cell_centres, u, cone):
    """Index range ``lo:hi`` of the cells whose centres can lie within ``cone`` radians of ``u``.

    The cell centres are ordered by decreasing z (a Fibonacci lattice; checked on load), so the
    cells within the cone lie in the z band of the polar angles ``θ_u ± cone``: the scans test
    only those (a fifth of the sky or less instead of all of it).
    """
    theta = np.arccos(min(1.0, max(-1.0, u[2])))
    z_hi = np.cos(max(0.0, theta - cone)) + 1e-9
    z_lo = np.cos(min(np.pi, theta + cone)) - 1e-9
    n = len(cell_centres)
    a, b = 0, n  # first index with z <= z_hi
    while a < b:
        m = (a + b) // 2
        if cell_centres[m, 2] > z_hi:
            a = m + 1
        else:
            b = m
    lo = a
    a, b = lo, n  # first index with z < z_lo
    while a < b:
        m = (a + b) // 2
        if cell_centres[m, 2] >= z_lo:
            a = m + 1
        else:
            b = m
    return lo, a


@njit(cache=True, inline="always")
def _edge_plane(A, f_signed, axis, offset):
    """The camera-frame vector ``(f_signed, 0, offset)`` (``axis`` 0) or ``(0, f_signed, offset)``
    (``axis`` 1), normalised and rotated to ICRS by ``Aᵀ``: the inner normal of a frame edge's plane
    through the camera (:func:`stars_in_view`)."""
    ex = f_signed if axis == 0 else 0.0
    ey = f_signed if axis == 1 else 0.0
    norm = np.sqrt(f_signed * f_signed + offset * offset)
    return ((ex * A[0, 0] + ey * A[1, 0] + offset * A[2, 0]) / norm,
            (ex * A[0, 1] + ey * A[1, 1] + offset * A[2, 1]) / norm,
            (ex * A[0, 2] + ey * A[1, 2] + offset * A[2, 2]) / norm)


@njit(cache=True)
def stars_in_view(A, f, k1, frame, limit, stars, view):
    """Catalogue stars (index < ``limit``) of the :class:`StarIndex` ``stars`` that project into
    the frame, brightest first.

    Projection in the undistorted offset space of ``p``: ``x = f·x_n·(1 + k1·r²)``.
    Returns the count written to ``view.index``, ``view.x_px``, ``view.y_px``.

    Only the cells that can hold a star in the frame are read (the reads of star vectors are
    cache misses, most of a verification's time): with ``k1 = 0`` a star in the frame lies
    within ``atan(ext / f)`` of the boresight (``ext`` the frame's farthest corner) and on the
    inner side of the frame's four edge planes, so a cell is read only if its cap (the cell
    radius about its centre) reaches that cone and, in fields narrower than
    :data:`_PLANES_MAX_CELLS` cell radii, every edge plane's inner side; with ``k1`` the cone
    is widened (``1 + 2|k1|`` and 0.01 rad) and the planes are not used.
    """
    star_vectors, cell_centres, cell_start, cell_stars = (stars.vectors, stars.cell_centres, stars.cell_start,
                                                          stars.cell_stars)
    cell_radius = stars.cell_radius_rad
    out_idx, out_x, out_y = view.index, view.x_px, view.y_px
    x_lo, x_hi, y_lo, y_hi = frame[0], frame[1], frame[2], frame[3]
    ext = np.sqrt(max(x_lo * x_lo, x_hi * x_hi) + max(y_lo * y_lo, y_hi * y_hi))
    if k1 == 0.0:
        half_diag = np.arctan(ext / f) + 1e-9
    else:
        half_diag = np.arctan(ext / f) * (1.0 + 2.0 * abs(k1)) + 0.01
    cos_cell = np.cos(min(half_diag + cell_radius, np.pi))
    # The edge planes' inner normals (n·b >= 0 inside) in ICRS, and how far outside a plane a
    # cell centre may lie with its cap still reaching inside: sin(cell radius) (reach).
    # The cells tested against the planes: those whose cap is not within the frame's inscribed
    # cone (inside every plane), and only where the cells are coarse beside the frame (cone
    # under 4 cell radii: the 2-15 deg fields; in wider ones the tests cost more than the reads
    # they save, measured).
    cos_inside = -2.0  # no cell tested
    lx = ly = lz = rx = ry = rz = tx = ty = tz = bx = by = bz_ = 0.0
    reach = -np.sin(min(cell_radius, 0.5 * np.pi)) - 1e-9
    if k1 == 0.0 and half_diag <= _PLANES_MAX_CELLS * cell_radius:
        lx, ly, lz = _edge_plane(A, f, 0, -x_lo)
        rx, ry, rz = _edge_plane(A, -f, 0, x_hi)
        tx, ty, tz = _edge_plane(A, f, 1, -y_lo)
        bx, by, bz_ = _edge_plane(A, -f, 1, y_hi)
        inscribed = np.arctan(min(-x_lo, x_hi, -y_lo, y_hi) / f) - cell_radius - 1e-9
        cos_inside = np.cos(inscribed) if inscribed > 0.0 else 2.0
    n = 0
    band_lo, band_hi = cell_band(cell_centres, A[2], half_diag + cell_radius)
    for cell in range(band_lo, band_hi):
        cx, cy, cz = cell_centres[cell, 0], cell_centres[cell, 1], cell_centres[cell, 2]
        d = cx * A[2, 0] + cy * A[2, 1] + cz * A[2, 2]
        if d < cos_cell:
            continue
        if d < cos_inside and (cx * lx + cy * ly + cz * lz < reach or cx * rx + cy * ry + cz * rz < reach
                               or cx * tx + cy * ty + cz * tz < reach
                               or cx * bx + cy * by + cz * bz_ < reach):
            continue
        for t in range(cell_start[cell], cell_start[cell + 1]):
            s = cell_stars[t]
            if s >= limit:
                break  # cells list their stars brightest first
            v = star_vectors[s]
            bz = A[2, 0] * v[0] + A[2, 1] * v[1] + A[2, 2] * v[2]
            if bz <= 1e-6:
                continue
            xn = (A[0, 0] * v[0] + A[0, 1] * v[1] + A[0, 2] * v[2]) / bz
            yn = (A[1, 0] * v[0] + A[1, 1] * v[1] + A[1, 2] * v[2]) / bz
            x, y = k1_offset(xn, yn, f, k1)
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


@njit(cache=True)
def sorted_indices(a, top):
    """Non-negative integers ``a`` (all ``<= top``) sorted ascending: LSD radix in two passes of
    half the bits of ``top`` each (small count tables for the thousand-odd stars of a field)."""
    n = len(a)
    bits = 1
    while top >> bits > 0:
        bits += 1
    d_bits = (bits + 1) // 2
    mask = (1 << d_bits) - 1
    src = a
    dst = np.empty(n, dtype=a.dtype)
    out = np.empty(n, dtype=a.dtype)
    count = np.empty(mask + 2, dtype=np.int64)
    for shift in (0, d_bits):
        count[:] = 0
        for i in range(n):
            count[((src[i] >> shift) & mask) + 1] += 1
        for d in range(mask + 1):
            count[d + 1] += count[d]
        for i in range(n):
            d = (src[i] >> shift) & mask
            dst[count[d]] = src[i]
            count[d] += 1
        src, dst = dst, out
    return src


@njit(cache=True)
def gather_stars(z, cone, limit, stars):
    """Indices (sorted: brightest first) of the stars ``< limit`` of the :class:`StarIndex`
    ``stars`` within ``cone`` radians of ``z``. No star vector is read in cells that lie wholly
    inside the cone (a third of them; the reads are cache misses)."""
    star_vectors, cell_centres, cell_start, cell_stars = (stars.vectors, stars.cell_centres, stars.cell_start,
                                                          stars.cell_stars)
    cell_radius = stars.cell_radius_rad
    cos_cell = np.cos(min(cone + cell_radius, np.pi))
    cos_cone = np.cos(min(cone, np.pi))
    # Cells whose every star is inside the cone (margin far beyond rounding).
    cos_inner = np.cos(cone - cell_radius - 1e-6) if cone > cell_radius + 1e-6 else 2.0
    near_cells = np.empty(len(cell_centres), dtype=np.int64)
    inner = np.empty(len(cell_centres), dtype=np.bool_)
    n_cells = 0
    n_max = 0
    band_lo, band_hi = cell_band(cell_centres, z, cone + cell_radius)
    for cell in range(band_lo, band_hi):
        cc = cell_centres[cell]
        dot = cc[0] * z[0] + cc[1] * z[1] + cc[2] * z[2]
        if dot < cos_cell:
            continue
        near_cells[n_cells] = cell
        inner[n_cells] = dot >= cos_inner
        n_cells += 1
        n_max += cell_start[cell + 1] - cell_start[cell]
    out = np.empty(min(n_max, limit), dtype=np.int64)
    n = 0
    top = 0
    for c in range(n_cells):
        cell = near_cells[c]
        for t in range(cell_start[cell], cell_start[cell + 1]):
            s = cell_stars[t]
            if s >= limit:
                break  # cells list their stars brightest first
            # Branch-free keep, so that the (cold) vector reads of the next stars need not wait.
            keep = inner[c]
            if not keep:
                v = star_vectors[s]
                keep = v[0] * z[0] + v[1] * z[1] + v[2] * z[2] >= cos_cone
            out[n] = s
            n += keep
            top = max(top, s)
    return sorted_indices(out[:n], top)


@njit(cache=True, error_model="numpy")
def project_stars(near, A, f, k1, frame, n_max, stars, view):
    """Project stars ``near`` (brightest first) of the :class:`StarIndex` ``stars``; keep the
    first ``n_max`` in the frame in ``view.index``, ``view.x_px``, ``view.y_px`` and return how
    many. Written branch-free, so that the cold vector reads of successive stars overlap; the
    buffers need one slot of room beyond what is returned."""
    star_vectors = stars.vectors
    out_idx, out_x, out_y = view.index, view.x_px, view.y_px
    n = 0
    n_room = min(n_max, len(out_idx) - 1)
    for s in near:
        v = star_vectors[s]
        bz = A[2, 0] * v[0] + A[2, 1] * v[1] + A[2, 2] * v[2]
        front = bz > 1e-6
        bz = bz if front else 1.0  # a select, not a branch; the star is dropped anyway
        xn = (A[0, 0] * v[0] + A[0, 1] * v[1] + A[0, 2] * v[2]) / bz
        yn = (A[1, 0] * v[0] + A[1, 1] * v[1] + A[1, 2] * v[2]) / bz
        x, y = k1_offset(xn, yn, f, k1)
        inside = front & (x >= frame[0]) & (x <= frame[1]) & (y >= frame[2]) & (y <= frame[3])
        out_idx[n] = s
        out_x[n] = x
        out_y[n] = y
        n += inside
        if n >= n_room:
            break
    return n


@njit(cache=True)
def match_greedy(view, n_cat, p, n_img, radius_px):
    """Greedy one-to-one matching of the first ``n_cat`` stars of ``view`` (:class:`ViewBuffers`)
    to the first ``n_img`` centroids ``p``, brightest catalogue star first, nearest free centroid
    within the radius. ``view.match[j]`` = centroid of catalogue star ``j`` or -1; returns the
    count."""
    view_x, view_y, used, match_img = view.x_px, view.y_px, view.used, view.match
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


@njit(cache=True)
def grid_index(p, n_img, frame, cell):
    """Bucket the first ``n_img`` points of ``p`` into square cells of side ``cell`` over the
    frame: the :class:`CentroidGrid` that :func:`match_grid` searches."""
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
    return CentroidGrid(frame[0], frame[2], cell, nx, ny, start, items)


@njit(cache=True)
def match_grid(view, n_cat, p, n_use, grid, radius_px):
    """:func:`match_greedy` against centroids ``< n_use`` bucketed in ``grid`` (:func:`grid_index`).
    Needs ``radius_px <= grid.cell_px / 2``: a match circle then reaches only the 2×2 cells on
    the side of its cell that its centre lies in."""
    view_x, view_y, used, match_img = view.x_px, view.y_px, view.used, view.match
    gx0, gy0, cell, nx, ny, start, items = grid
    used[:] = False
    r2 = radius_px * radius_px
    n_match = 0
    for j in range(n_cat):
        ux = (view_x[j] - gx0) / cell
        uy = (view_y[j] - gy0) / cell
        gx = int(ux)
        gy = int(uy)
        x0 = gx - 1 if ux - gx < 0.5 else gx
        y0 = gy - 1 if uy - gy < 0.5 else gy
        best_d = r2
        best_i = -1
        for yy in range(max(0, y0), min(ny, y0 + 2)):
            for xx in range(max(0, x0), min(nx, x0 + 2)):
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


@njit(cache=True)
def verify_attitude(A, f, image, n_cat_max, n_img, radius_px, pattern, combo, stars, view):
    """log P(a wrong attitude matches as well) and the counts, for the ``n_cat_max`` brightest
    catalogue stars in view (of the :class:`StarIndex` ``stars``) matched to the ``n_img``
    brightest centroids of ``image`` (:class:`ImageStars`); ``view`` (:class:`ViewBuffers`) is
    work space.

    The pattern's own stars are not counted. Each catalogue star lands by chance within ``r`` of
    some centroid with ``p = n_img·π·r² / frame area``; the matches are counted within the full
    radius and within 1/2, 1/4, 1/8 and 1/16 of it (a clean frame earns the tighter, more telling
    test; a distorted one still passes with the full radius), and the best of the five binomial
    tails, times 5 for the choice, is returned with (matches within the radius, catalogue stars).
    """
    p, frame = image.offsets_px, image.frame_px
    view_idx, view_x, view_y, match_img = view.index, view.x_px, view.y_px, view.match
    limit = star_limit(len(stars.vectors), n_cat_max, frame, f, 2.0)
    n_view = stars_in_view(A, f, 0.0, frame, limit, stars, view)
    n_cat = min(n_view, n_cat_max)
    match_greedy(view, n_cat, p, n_img, radius_px)
    k = np.zeros(_N_RADII, dtype=np.int64)  # matches within radius_px / 2**m
    n = 0
    r2 = radius_px * radius_px
    for j in range(n_cat):
        own = False
        for a in range(pattern.shape[0]):
            if view_idx[j] == pattern[a]:
                own = True
        if own:
            continue
        n += 1
        i = match_img[j]
        for a in range(combo.shape[0]):
            if i == combo[a]:
                i = -1  # one of the pattern's own centroids: not evidence
        if i >= 0:
            d2 = (p[i, 0] - view_x[j]) ** 2 + (p[i, 1] - view_y[j]) ** 2
            lim = r2
            for m in range(_N_RADII):
                if d2 <= lim:
                    k[m] += 1
                lim /= 4.0
    p_full = min(1.0, n_img * np.pi * r2 / ((frame[1] - frame[0]) * (frame[3] - frame[2])))
    logp = 0.0
    for m in range(_N_RADII):
        logp = min(logp, log_binom_sf(k[m], n, p_full / 4.0**m))
    logp += np.log(float(_N_RADII))
    k_full = k[0]
    return logp, k_full, n
