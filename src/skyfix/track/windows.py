"""Catalogue-predicted windows: where to look for which star in a tracked frame, and what was
found there (docs/tracking.md#one-tracking-update).

One tracking update runs these steps, each a compiled kernel over preallocated buffers (the
frame is never copied or converted whole: a 1-megapixel frame costs what its windows cost):

1. :func:`project_view` — the catalogue stars in the frame at the predicted attitude: the
   database's sky cells near the boresight (:func:`skyfix.identify.common.verify.gather_stars`, the
   same star index as verification) projected through the full camera model
   (:mod:`skyfix._kernels.lens`), brightest first.
2. :func:`select_windows` — up to ``n_max`` of them, brightest first but at most
   ``ceil(n_max / 9)`` per ninth of the frame on a first pass (thesis 004 §4.4's nine boxes),
   isolated (no catalogue star less than ``neighbour_dmag`` fainter within reach of the window)
   and wholly inside the frame. Each gets its predicted position covariance ``C = J P Jᵀ`` from
   the attitude covariance ``P`` through the pixel Jacobian ``J`` (:func:`pixel_jacobian`), its
   smear ``J ω τ`` over the exposure ``τ``, and a search half-size
   ``r = r_star + k·√max(Cxx, Cyy) + |smear|/2`` — thesis 004 §4.7's
   ``r_search = r_star + r_uncert + r_rotation`` with the uncertainty taken from the filter.
3. :func:`cut_tiles` — a square tile for each window copied into one small float32 mosaic that
   :func:`skyfix.detect.centroid_windows` then centroids: centred on the prediction when that
   is precise (the tile is the search window), else on the brightest 3 × 3 sum in the search
   window (thesis 002 §7.2: centre on the peak, not on the first pixel over threshold) with
   room for the whole streak around it.
4. :func:`match_windows` — each window's centroid against its own catalogue star: found
   (SNR), inside the gate ``dᵀ (C + R)⁻¹ d ≤ k²`` (``R`` the centroid's own covariance plus a
   floor), the right brightness (thesis 004 §4.4's magnitude filter, against a zero point),
   then thesis 004's distance check generalised from one triple to every pair: the angle
   between two stars' rays must equal their catalogue angle, and the star in the most
   disagreeing pairs is dropped until all agree.

Pixel Jacobian. With the attitude error ``δθ`` of docs/design.md (``A_est = R(δθ) A_true``) a
star predicted along ``b`` is truly along ``b + b × δθ``; a body rate ``ω`` moves it as
``ḃ = b × ω``. Both are ``S(b) = [b×]`` times a rotation vector, so one Jacobian
``J = K · D · N(b) · S(b)`` (``N`` the pinhole's ``∂(x_n, y_n)/∂b``, ``D`` the distortion's
Jacobian, ``K`` the focal lengths and skew) gives the position covariance ``J P Jᵀ``, the
image motion ``J ω`` and the rolling-shutter shift ``J ω Δt``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.lens import CX, CY, FX, FY, SKEW, distort, distort_jacobian, pixel_rays
from skyfix._kernels.probability import log_binom_sf
from skyfix._kernels.rotation import angles, pointing, vector_radec
from skyfix.detect._stats import robust_level_noise
from skyfix.identify.common.verify import gather_stars
from skyfix.track.fit import fit_attitude

__all__ = ["Local", "MatchSettings", "Plan", "Selection", "View", "WindowFit", "WindowSettings", "crowding",
           "cut_tiles", "fit_windows", "local_catalog", "match_windows", "new_selection", "no_fit",
           "pixel_jacobian", "plan_windows", "project_view", "select_windows", "solution_numbers",
           "tile_layout"]


class WindowSettings(NamedTuple):
    """How the windows of one frame are chosen and sized.

    n_max : int — windows at most (10–20 keeps an update well under a millisecond).
    k_sigma : float — the search reaches ``k_sigma`` predicted σ from the prediction.
    star_radius_px : float — ``r_star``: a star's light reaches this far from its centre.
    min_half_px, max_half_px : float — bounds of the search half-size.
    max_spread_px : float — largest unknown part of a streak (``k·σ_ω·τ`` in pixels): beyond
        it a window cannot tell where the streak's middle is (the rate is not known yet).
    neighbour_dmag : float — a catalogue star less than this much fainter within reach of a
        window (its search and its tile) makes it ambiguous: the star is not chosen.
    per_box : int — stars per ninth of the frame on the first pass (0: ``ceil(n_max / 9)``).
    """

    n_max: int
    k_sigma: float
    star_radius_px: float
    min_half_px: float
    max_half_px: float
    max_spread_px: float
    neighbour_dmag: float
    per_box: int


class Selection(NamedTuple):
    """The windows of one frame (preallocated for ``n_max``; the first ``n`` rows hold them).

    index : (n_max,) int64 — the catalogue star (index into the star index).
    mag : (n_max,) float64 — its magnitude.
    x, y : (n_max,) float64 — its predicted position at the frame time, pixels.
    cov : (n_max, 3) float64 — predicted position covariance ``Cxx, Cxy, Cyy``, px².
    jac : (n_max, 2, 3) float64 — the pixel Jacobian :func:`pixel_jacobian`.
    smear : (n_max, 2) float64 — the star's motion over the exposure, pixels.
    half : (n_max,) float64 — search half-size, pixels.
    tile : (n_max,) float64 — half-size of a tile centred anywhere on the star that holds all
        its light: ``r_star`` + the streak's length and its unknown part, pixels.
    """

    index: np.ndarray
    mag: np.ndarray
    x: np.ndarray
    y: np.ndarray
    cov: np.ndarray
    jac: np.ndarray
    smear: np.ndarray
    half: np.ndarray
    tile: np.ndarray

    @classmethod
    def empty(cls, n_max: int) -> Selection:
        return new_selection(n_max)


class MatchSettings(NamedTuple):
    """How a window's centroid is accepted as its catalogue star.

    min_snr : float — weaker centroids are noise.
    gate_chi2 : float — the position gate, ``dᵀ (C + R)⁻¹ d`` at most this (2 degrees of freedom).
    floor_px : float — centroid σ floor added in quadrature (model and PSF errors).
    gate_floor_px : float — a σ added to the gate alone: what the motion model leaves out (an
        unexpected acceleration moves every star alike; the fit then tells, by its NIS).
    mag_tolerance : float — largest ``|m_inst − m_cat − zero point|``, magnitudes (inf: off).
    pair_k : float — pair check: angles may differ by this many σ of their difference.
    """

    min_snr: float
    gate_chi2: float
    floor_px: float
    gate_floor_px: float
    mag_tolerance: float
    pair_k: float


class Local(NamedTuple):
    """The catalogue near the boresight, copied once for many frames (:func:`local_catalog`):
    ``index`` (m,) int64 catalogue indices, ``vectors`` (m, 3) their unit vectors, ``mags``
    (m,) their magnitudes, brightest first. Reading these few thousand contiguous stars each
    frame costs a tenth of reading them from the whole catalogue, where they lie scattered.
    ``crowd`` (m,) is each star's chord to its nearest neighbour less than ``neighbour_dmag``
    fainter (how isolated it is; NaN until a selection first asks, then kept: the sky does not
    change between frames)."""

    index: np.ndarray
    vectors: np.ndarray
    mags: np.ndarray
    crowd: np.ndarray


class View(NamedTuple):
    """Buffers for the catalogue stars projected into one frame (:func:`project_view`).

    index : (L,) int64 — catalogue index; xy : (L, 2) — pixels; b : (L, 3) — camera-frame rays;
    mag : (L,) — magnitude; local : (L,) int64 — row in the :class:`Local` catalogue.
    """

    index: np.ndarray
    xy: np.ndarray
    b: np.ndarray
    mag: np.ndarray
    local: np.ndarray

    @classmethod
    def empty(cls, size: int) -> View:
        return cls(np.zeros(size, np.int64), np.zeros((size, 2)), np.zeros((size, 3)), np.zeros(size),
                   np.zeros(size, np.int64))


class Plan(NamedTuple):
    """What :func:`plan_windows` chose: ``n`` windows (in the :class:`Selection`), ``too_wide``
    stars that needed a window too large, ``n_view`` catalogue stars bright enough to choose in
    the frame, and the magnitude of the faintest star chosen."""

    n: int
    too_wide: int
    n_view: int
    faintest_mag: float


class WindowFit(NamedTuple):
    """What :func:`fit_windows` made of one frame's windows.

    success : bool — a fit of at least ``min_stars`` stars.
    n_found, n_gated : int — windows with a centroid above the SNR; of those, inside the gate
        and of the right brightness.
    A_icrs_to_cam, covariance_rad2 : (3, 3) — the fit and its covariance.
    zero_point : float — the frame's median ``m_inst − m_cat`` (NaN: no star gated).
    log_chance : float — log P(so many windows hold a star inside their gates by chance).
    n_fit : int — the windows in the fit; the m ≥ ``n_fit`` rows below, the first ``n_fit`` of
        them those stars (the rest: gated but dropped by the pair check or as outliers):
    index : (m,) — their catalogue indices (rows of the star index);
    xy : (m, 2) — their centroids, frame pixels; b : (m, 3) — their rays at the frame time;
    sigma_rad : (m,) — the rays' σ per axis.
    """

    success: bool
    n_found: int
    n_gated: int
    A_icrs_to_cam: np.ndarray
    covariance_rad2: np.ndarray
    zero_point: float
    log_chance: float
    n_fit: int
    index: np.ndarray
    xy: np.ndarray
    b: np.ndarray
    sigma_rad: np.ndarray


@njit(cache=True)
def new_selection(n_max):
    """An empty :class:`Selection` for ``n_max`` windows (``Selection.empty``, also in kernels)."""
    return Selection(np.zeros(n_max, np.int64), np.zeros(n_max), np.zeros(n_max), np.zeros(n_max),
                     np.zeros((n_max, 3)), np.zeros((n_max, 2, 3)), np.zeros((n_max, 2)), np.zeros(n_max),
                     np.zeros(n_max))


@njit(cache=True, inline="always")
def no_fit(n_found, n_gated, zero_point):
    """The :class:`WindowFit` of a frame with too few stars for a fit."""
    return WindowFit(False, n_found, n_gated, np.eye(3), np.zeros((3, 3)), zero_point, 0.0, 0,
                     np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0))


@njit(cache=True, inline="always")
def pixel_jacobian(b0, b1, b2, cam, J):
    """``J = ∂(u, v)/∂δθ`` (2, 3) into ``J`` for a camera-frame ray ``b`` (module docstring):
    the pixel shift of a star for a small rotation vector about camera x, y, z."""
    iz = 1.0 / b2
    xn, yn = b0 * iz, b1 * iz
    _, _, dxx, dxy, dyx, dyy, _ = distort_jacobian(xn, yn, cam)
    # M = K·D (2×2), then M·N(b) (2×3), then ·S(b)
    m00 = cam[FX] * dxx + cam[SKEW] * dyx
    m01 = cam[FX] * dxy + cam[SKEW] * dyy
    m10 = cam[FY] * dyx
    m11 = cam[FY] * dyy
    # rows of M·N(b), N(b) = [[1/z, 0, −x/z²], [0, 1/z, −y/z²]] ...
    a0, a1, a2 = m00 * iz, m01 * iz, -(m00 * xn + m01 * yn) * iz
    c0, c1, c2 = m10 * iz, m11 * iz, -(m10 * xn + m11 * yn) * iz
    # ... times S(b) = [[0, −b2, b1], [b2, 0, −b0], [−b1, b0, 0]]
    J[0, 0] = a1 * b2 - a2 * b1
    J[0, 1] = a2 * b0 - a0 * b2
    J[0, 2] = a0 * b1 - a1 * b0
    J[1, 0] = c1 * b2 - c2 * b1
    J[1, 1] = c2 * b0 - c0 * b2
    J[1, 2] = c0 * b1 - c1 * b0


@njit(cache=True, inline="always")
def _propagate(J, P):
    """``J P Jᵀ`` (2 × 2) of a (2, 3) ``J`` and a (3, 3) ``P``, as ``(xx, xy, yy)``."""
    cxx = cxy = cyy = 0.0
    for a in range(3):
        ja0 = J[0, 0] * P[0, a] + J[0, 1] * P[1, a] + J[0, 2] * P[2, a]
        ja1 = J[1, 0] * P[0, a] + J[1, 1] * P[1, a] + J[1, 2] * P[2, a]
        cxx += ja0 * J[0, a]
        cxy += ja0 * J[1, a]
        cyy += ja1 * J[1, a]
    return cxx, cxy, cyy


@njit(cache=True)
def local_catalog(z, cone, limit, stars, mags):
    """The stars ``< limit`` (a brightness rank) of the
    :class:`~skyfix.identify.catalogue.kernel_data.StarIndex` ``stars`` within ``cone`` radians of
    ``z`` (:func:`~skyfix.identify.common.verify.gather_stars`, verification's own search), copied
    into a :class:`Local`."""
    near = gather_stars(z, cone, limit, stars)
    m = near.size
    vectors = np.empty((m, 3))
    local_mags = np.empty(m)
    for j in range(m):
        vectors[j] = stars.vectors[near[j]]
        local_mags[j] = mags[near[j]]
    return Local(near, vectors, local_mags, np.full(m, np.nan))


@njit(cache=True)
def crowding(local, j, dmag):
    """The chord from star ``j`` of the :class:`Local` catalogue to its nearest neighbour less
    than ``dmag`` fainter (``local.crowd[j]``, computed on first use)."""
    if local.crowd[j] == local.crowd[j]:
        return local.crowd[j]
    v = local.vectors[j]
    lim = local.mags[j] + dmag
    best = 4.0  # squared chord; 2 is antipodal
    for k in range(local.index.size):
        if local.mags[k] > lim:
            break  # brightest first
        if k == j:
            continue
        u = local.vectors[k]
        d = (u[0] - v[0]) ** 2 + (u[1] - v[1]) ** 2 + (u[2] - v[2]) ** 2
        best = min(best, d)
    local.crowd[j] = math.sqrt(best)
    return local.crowd[j]


@njit(cache=True)
def project_view(A, cam, width, height, margin_px, max_mag, local, view):
    """Project the stars of the :class:`Local` catalogue down to ``max_mag`` at attitude ``A``;
    keep, brightest first, those within ``margin_px`` of the frame (a negative margin reaches
    outside it) in the :class:`View` ``view``. Returns how many (at most its length)."""
    n = 0
    cap = view.index.shape[0]
    lo_x, hi_x = -0.5 + margin_px, width - 0.5 - margin_px
    lo_y, hi_y = -0.5 + margin_px, height - 0.5 - margin_px
    for j in range(local.index.size):
        if local.mags[j] > max_mag:
            break  # brightest first
        v = local.vectors[j]
        bz = A[2, 0] * v[0] + A[2, 1] * v[1] + A[2, 2] * v[2]
        if bz <= 1e-6:
            continue
        bx = A[0, 0] * v[0] + A[0, 1] * v[1] + A[0, 2] * v[2]
        by = A[1, 0] * v[0] + A[1, 1] * v[1] + A[1, 2] * v[2]
        xd, yd = distort(bx / bz, by / bz, cam)
        u = cam[FX] * xd + cam[SKEW] * yd + cam[CX]
        w = cam[FY] * yd + cam[CY]
        if u < lo_x or u > hi_x or w < lo_y or w > hi_y:
            continue
        view.index[n] = local.index[j]
        view.mag[n] = local.mags[j]
        view.local[n] = j
        view.xy[n, 0] = u
        view.xy[n, 1] = w
        view.b[n, 0] = bx
        view.b[n, 1] = by
        view.b[n, 2] = bz
        n += 1
        if n >= cap:
            break
    return n


@njit(cache=True)
def select_windows(view, n_view, local, select_mag, P, rate, P_rate, exposure_s, width, height, cam, settings,
                   sel):
    """Choose and size the windows (module docstring, step 2) among the ``n_view`` projected
    stars of the :class:`View` (brightest first; ``select_mag`` the faintest chosen; their
    crowding from the :class:`Local` catalogue, :func:`crowding`)
    for the attitude covariance ``P`` (3, 3, rad²), body rate ``rate`` (rad/s) and its
    covariance ``P_rate`` into ``sel`` (:class:`Selection`). Returns ``(n, wanted)``:
    the windows chosen, and how many stars bright enough to choose lay in the frame but needed
    a half-size beyond ``settings.max_half_px`` or left more than ``settings.max_spread_px`` of
    their streak unknown (the attitude or rate is too uncertain for windows)."""
    n_max = min(settings.n_max, sel.index.shape[0])
    r_star = settings.star_radius_px
    per_box = settings.per_box if settings.per_box > 0 else (n_max + 8) // 9
    boxes = np.zeros(9, np.int64)
    taken = np.zeros(n_view, np.bool_)
    view_xy, view_b, view_mag = view.xy, view.b, view.mag
    px_per_rad = math.sqrt(cam[FX] * cam[FY])
    J = np.empty((2, 3))
    n = 0
    too_wide = 0
    for cap in (per_box, n_max):
        for j in range(n_view):
            if n >= n_max:
                break
            m = view_mag[j]
            if m > select_mag:
                break  # brightest first
            if taken[j]:
                continue
            x, y = view_xy[j, 0], view_xy[j, 1]
            row, col = int(3.0 * (y + 0.5) / height), int(3.0 * (x + 0.5) / width)
            box = min(2, max(0, row)) * 3 + min(2, max(0, col))
            if boxes[box] >= cap:
                continue
            pixel_jacobian(view_b[j, 0], view_b[j, 1], view_b[j, 2], cam, J)
            cxx, cxy, cyy = _propagate(J, P)
            rxx, _, ryy = _propagate(J, P_rate)  # of the image motion, px²/s²
            mx = (J[0, 0] * rate[0] + J[0, 1] * rate[1] + J[0, 2] * rate[2]) * exposure_s
            my = (J[1, 0] * rate[0] + J[1, 1] * rate[1] + J[1, 2] * rate[2]) * exposure_s
            spread = settings.k_sigma * math.sqrt(max(rxx, ryy, 0.0)) * exposure_s
            streak = math.sqrt(mx * mx + my * my)
            half = r_star + settings.k_sigma * math.sqrt(max(cxx, cyy, 0.0)) + 0.5 * (streak + spread)
            half = max(half, settings.min_half_px)
            tile = r_star + streak + spread
            if not (half <= settings.max_half_px and spread <= settings.max_spread_px):
                if cap == per_box:
                    too_wide += 1
                continue
            reach = max(half, tile) + r_star + 1.0
            if x - reach < -0.5 or x + reach > width - 0.5 or y - reach < -0.5 or y + reach > height - 0.5:
                continue
            # a neighbour (less than neighbour_dmag fainter) whose light reaches the window or its
            # tile (chord × focal length: its distance in pixels)
            crowd_px = crowding(local, view.local[j], settings.neighbour_dmag) * px_per_rad
            if crowd_px < max(half, tile) + 2.0 * r_star:
                continue
            taken[j] = True
            boxes[box] += 1
            sel.index[n] = view.index[j]
            sel.mag[n] = m
            sel.x[n] = x
            sel.y[n] = y
            sel.cov[n, 0] = cxx
            sel.cov[n, 1] = cxy
            sel.cov[n, 2] = cyy
            sel.jac[n, :, :] = J
            sel.smear[n, 0] = mx
            sel.smear[n, 1] = my
            sel.half[n] = half
            sel.tile[n] = tile
            n += 1
    return n, too_wide


@njit(cache=True)
def tile_layout(sel, n, max_half):
    """The tiles of :func:`cut_tiles` for the first ``n`` windows of the :class:`Selection`
    ``sel``: ``(tile_half, recentred, longest streak component in pixels)``."""
    half = 0.0
    tile = 0.0
    streak = 0.0
    for i in range(n):
        half = max(half, sel.half[i])
        tile = max(tile, sel.tile[i])
        streak = max(streak, abs(sel.smear[i, 0]), abs(sel.smear[i, 1]))
    # search a peak only when the prediction is off by more than a pixel or so (k σ)
    recentre = tile < half and half - tile > 1.0
    return min(int(math.ceil(tile if recentre else half)) + 1, max_half), recentre, streak


@njit(cache=True)
def cut_tiles(img, sel, n, max_half, tiles, origin, local, sky, noise, border_stats):
    """Step 3 of the module docstring for the first ``n`` windows of the :class:`Selection`
    ``sel``: one tile size for all, ``2·tile_half`` pixels square — centred on the prediction
    when that reaches every search window (``half``) or the search is less than a pixel wider
    than the star, else on the brightest 3 × 3 sum in the search window with room for the whole
    streak around it (``tile``); at most ``max_half`` (:func:`tile_layout`).
    Tile ``i`` is copied (float32; non-finite pixels as 0) into rows ``i·2·tile_half …`` of the
    mosaic, the first ``n·(2·tile_half)²`` values of the flat buffer ``tiles``; its top-left
    pixel goes to ``origin[i]``, the prediction's place in the mosaic to ``local[i]`` (the
    tile's centre when recentred); with ``border_stats``, the sky level and noise σ of its
    border pixels to ``sky[i]`` and ``noise[i]`` (the robust estimate
    :func:`skyfix.detect.centroid_windows` makes; the streak fit takes its own), else NaN.
    ``img`` is the whole frame, of any real dtype, never copied. Returns ``(tile_half,
    recentred, longest streak component in pixels)``."""
    h, w = img.shape
    tile_half, recentre, streak = tile_layout(sel, n, max_half)
    size = 2 * tile_half
    mosaic = tiles[:n * size * size].reshape(n * size, size)
    border = np.empty(4 * size - 4)
    for i in range(n):
        cx = int(round(sel.x[i]))
        cy = int(round(sel.y[i]))
        if recentre:
            r = int(math.ceil(sel.half[i]))
            best = -np.inf
            bx, by = cx, cy
            for y in range(max(cy - r, 1), min(cy + r, h - 2) + 1):
                for x in range(max(cx - r, 1), min(cx + r, w - 2) + 1):
                    s = 0.0
                    for yy in range(y - 1, y + 2):
                        for xx in range(x - 1, x + 2):
                            s += img[yy, xx]
                    if s > best:
                        best = s
                        bx, by = x, y
            cx, cy = bx, by
        x0 = min(max(cx - tile_half, 0), w - size)
        y0 = min(max(cy - tile_half, 0), h - size)
        origin[i, 0] = x0
        origin[i, 1] = y0
        row = i * size
        if recentre:
            local[i, 0] = cx - x0
            local[i, 1] = row + cy - y0
        else:
            local[i, 0] = sel.x[i] - x0
            local[i, 1] = row + sel.y[i] - y0
        m = 0
        for yy in range(size):
            edge = yy == 0 or yy == size - 1
            for xx in range(size):
                v = np.float32(img[y0 + yy, x0 + xx])
                if not np.isfinite(v):
                    v = np.float32(0.0)
                mosaic[row + yy, xx] = v
                if edge or xx == 0 or xx == size - 1:
                    border[m] = v
                    m += 1
        if border_stats:
            sky[i], noise[i] = robust_level_noise(border[:m].copy(), 0.0, False)
        else:
            sky[i] = noise[i] = np.nan
    return tile_half, recentre, streak


@njit(cache=True)
def match_windows(n, cx, cy, csx, csy, cflux, csnr, sel, zero_point, settings, keep, chi2, m_inst):
    """Step 4 of the module docstring up to the pair check: ``keep[i]`` for window ``i < n``
    whose centroid ``(cx, cy)`` (σ ``csx``, ``csy``, flux, SNR) is found, inside the gate
    (``chi2[i]``) and, with a finite ``zero_point``, of the right brightness
    (``m_inst[i] = −2.5 log10 flux`` against the catalogue's ``sel.mag[i]``).
    Returns how many are kept, the median ``m_inst − m_cat`` of the gated stars (the frame's
    zero point, NaN when none) and the mean area of the gates, px² (``π·gate_chi2·√det(C + R)``)."""
    diffs = np.empty(n)
    nd = 0
    floor2 = settings.floor_px * settings.floor_px + settings.gate_floor_px * settings.gate_floor_px
    area = 0.0
    for i in range(n):
        keep[i] = False
        chi2[i] = np.inf
        m_inst[i] = np.nan
        sx = csx[i] if np.isfinite(csx[i]) else 0.0
        sy = csy[i] if np.isfinite(csy[i]) else 0.0
        a = sel.cov[i, 0] + sx * sx + floor2
        b = sel.cov[i, 1]
        c = sel.cov[i, 2] + sy * sy + floor2
        det = a * c - b * b
        area += np.pi * settings.gate_chi2 * math.sqrt(max(det, 0.0)) / n
        if not (np.isfinite(cx[i]) and np.isfinite(cy[i]) and csnr[i] >= settings.min_snr and cflux[i] > 0):
            continue
        dx, dy = cx[i] - sel.x[i], cy[i] - sel.y[i]
        d2 = (c * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / det if det > 0 else np.inf
        chi2[i] = d2
        if not d2 <= settings.gate_chi2:
            continue
        m_inst[i] = -2.5 * math.log10(cflux[i])
        diffs[nd] = m_inst[i] - sel.mag[i]
        nd += 1
        keep[i] = True
    frame_zp = np.median(diffs[:nd]) if nd else np.nan
    zp = zero_point if np.isfinite(zero_point) else frame_zp
    count = 0
    for i in range(n):
        if keep[i] and np.isfinite(zp) and abs(m_inst[i] - sel.mag[i] - zp) > settings.mag_tolerance:
            keep[i] = False
        if keep[i]:
            count += 1
    return count, frame_zp, area


@njit(cache=True)
def plan_windows(A, P, rate, P_rate, exposure_s, local, select_mag, cam, width, height, settings, view, sel):
    """Steps 1–2 of the module docstring in one call: the stars of the :class:`Local` catalogue
    down to ``select_mag`` projected into the frame (:func:`project_view` into the :class:`View`
    ``view``), and the windows chosen among them (:func:`select_windows` into ``sel``).
    Returns a :class:`Plan`."""
    n_view = project_view(A, cam, width, height, 0.0, select_mag, local, view)
    n, too_wide = select_windows(view, n_view, local, select_mag, P, rate, P_rate, exposure_s, width, height,
                                 cam, settings, sel)
    faintest = -np.inf
    for i in range(n):
        faintest = max(faintest, sel.mag[i])
    return Plan(n, too_wide, n_view, faintest)


@njit(cache=True)
def fit_windows(n, x, y, sx, sy, flux, snr, origin, size, sel, vectors, zero_point, settings, cam, rate, dt,
                n_view, frame_area, min_stars, outlier_k):
    """Steps 4–6 of the module docstring in one call, from the centroids of the ``n`` tiles
    (``x, y`` in the mosaic of :func:`cut_tiles`: tile ``i`` is rows ``i·size …`` with its
    top-left pixel at ``origin[i]``; σ, flux, SNR): the gate and magnitude match
    (:func:`match_windows`), the rays (turned back from each star's time ``t + dt[i]`` to the
    frame time at ``rate``: ``b + (ω Δt) × b``), and the pair check and fit
    (:func:`fit_attitude`). The chance of so many matches: each window's gate holds, by
    accident, one of the frame's ``n_view`` catalogue stars with probability
    ``n_view · gate area / frame_area`` (a binomial tail; ``n_view``: the frame's catalogue stars
    as bright as those chosen, :class:`Plan`). Returns a :class:`WindowFit`."""
    cx = np.empty(n)
    cy = np.empty(n)
    n_found = 0
    for i in range(n):
        cx[i] = x[i] + origin[i, 0]
        cy[i] = y[i] - i * size + origin[i, 1]
        if snr[i] >= settings.min_snr and np.isfinite(cx[i]) and np.isfinite(cy[i]):
            n_found += 1
    keep = np.empty(n, np.bool_)
    chi2 = np.empty(n)
    m_inst = np.empty(n)
    n_gated, zp, gate_area = match_windows(n, cx, cy, sx, sy, flux, snr, sel, zero_point, settings, keep,
                                           chi2, m_inst)
    if n_gated < min_stars:
        return no_fit(n_found, n_gated, zp)
    idx = np.flatnonzero(keep)
    m = idx.size
    xy = np.empty((m, 2))
    sigma = np.empty(m)
    r = np.empty((m, 3))
    index = np.empty(m, np.int64)
    floor2 = settings.floor_px * settings.floor_px
    plate = 1.0 / math.sqrt(cam[FX] * cam[FY])
    for j in range(m):
        i = idx[j]
        xy[j, 0], xy[j, 1] = cx[i], cy[i]
        sigma[j] = math.sqrt(0.5 * (sx[i] * sx[i] + sy[i] * sy[i]) + floor2) * plate
        index[j] = sel.index[i]
        r[j] = vectors[index[j]]
    b = pixel_rays(xy, cam)
    for j in range(m):
        d = dt[idx[j]]
        if d != 0.0:
            w0, w1, w2 = rate[0] * d, rate[1] * d, rate[2] * d
            b0, b1, b2 = b[j, 0], b[j, 1], b[j, 2]
            b0, b1, b2 = b0 + (w1 * b2 - w2 * b1), b1 + (w2 * b0 - w0 * b2), b2 + (w0 * b1 - w1 * b0)
            norm = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
            b[j, 0], b[j, 1], b[j, 2] = b0 / norm, b1 / norm, b2 / norm
    fitted = np.ones(m, np.bool_)
    ok, A, P, _ = fit_attitude(b, r, sigma, fitted, settings.pair_k, outlier_k, min_stars)
    order = np.argsort(~fitted, kind="mergesort")  # the fitted stars first, in window order
    n_fit = int(fitted.sum())
    p_chance = min(1.0, n_view * gate_area / frame_area)
    log_chance = log_binom_sf(n_fit, n, p_chance) if ok else 0.0
    return WindowFit(ok, n_found, n_gated, A, P, zp, log_chance, n_fit, index[order], xy[order], b[order],
                     sigma[order])


_ARCSEC = np.pi / (180.0 * 3600.0)
_ARCSEC2_PER_RAD2 = 1.0 / _ARCSEC ** 2
_DEG_PER_RAD = 1.0 / (np.pi / 180.0)
_DEG2_PER_RAD2 = _DEG_PER_RAD ** 2


@njit(cache=True)
def solution_numbers(A, P, rate, P_rate, xy, b, index, vectors, places, mags):
    """A tracked frame's Solution numbers in one call, for the estimate ``A`` (covariance
    ``P``, rad²; body rate ``rate``, rad/s, covariance ``P_rate``) and its stars (centroids
    ``xy``, rays ``b``, catalogue rows ``index`` of ``vectors`` — the directions fitted —,
    ``places`` — their catalogue places, ``vectors`` itself when no correction moved the stars
    (:mod:`skyfix.track.sky`) — and ``mags``): ``head`` (28,) — RA, Dec, roll (degrees) and the
    quaternion ``[x, y, z, w]`` of ``A`` (:func:`skyfix._kernels.rotation.pointing`), ``P`` in
    arcsec² (9, by rows), the rate in °/s (3) and its covariance in (°/s)² (9); the matches'
    table (6, n) of x, y, the catalogue place's RA and Dec (degrees), magnitude and residual
    (arcsec, the angle between ray ``b`` and ``A r``, ``r`` from ``vectors``); the residuals'
    RMS (arcsec)."""
    head = np.empty(28)
    head[:7] = pointing(A)
    for k in range(3):
        head[k] = np.degrees(head[k])
        head[16 + k] = rate[k] * _DEG_PER_RAD
        for j in range(3):
            head[7 + 3 * k + j] = P[k, j] * _ARCSEC2_PER_RAD2
            head[19 + 3 * k + j] = P_rate[k, j] * _DEG2_PER_RAD2
    n = b.shape[0]
    r = np.empty((n, 3))
    for i in range(n):
        r[i] = vectors[index[i]]
    table = np.empty((6, n))
    resid = angles(b, r, A)
    ss = 0.0
    for i in range(n):
        q = places[index[i]]
        ra, dec = vector_radec(q[0], q[1], q[2])
        table[0, i] = xy[i, 0]
        table[1, i] = xy[i, 1]
        table[2, i] = np.degrees(ra)
        table[3, i] = np.degrees(dec)
        table[4, i] = mags[index[i]]
        table[5, i] = resid[i] / _ARCSEC
        ss += table[5, i] * table[5, i]
    return head, table, np.sqrt(ss / n) if n else np.nan
