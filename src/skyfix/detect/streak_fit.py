"""The streak fit's kernels (:func:`skyfix.detect.streak.centroid_streaks` ``method="streak"``,
and the tracker's windows): the streak model — a Gaussian PSF of σ ``s`` swept along the predicted
motion, ``A·[erf((a + L/2)/√2s) − erf((a − L/2)/√2s)]·exp(−b²/2s²)`` — walked over a window by
recurrences, the weighted centre that starts the fit, and the Gauss–Newton fit of the amplitude and
the centre with its covariance (the method is :mod:`skyfix.detect.streak`'s module docstring).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix.detect._stats import robust_level_noise, window_border
from skyfix.detect.centroid import Window

__all__ = ["START_SIGMA_PX", "StreakFit", "fit_streaks"]

# The rows of the streak kernel's (11, N) table, in the order of StreakFit's first fields.
(_X, _Y, _FLUX, _AREA, _PEAK, _SIGMA_X, _SIGMA_Y, _COV_XY, _ELONGATION, _NOISE, _SKY) = range(11)
_NCOL = 11
# The streak model is taken as zero beyond this many σ of its segment (3e-4 of its peak).
_REACH = 4.0
# The column walk seeds a Gaussian afresh below this (its products keep every digit above it).
_TINY = 1e-280
# Gauss–Newton stops when the step or the distance left (extrapolated) is under 0.1 σ (χ² 0.01).
_TOL_CHI2 = 0.01
# The passes over the pixels may fuse a multiply and an add (one rounding, not two), and take a
# pass's sums in any order (split four ways: its loop vectorises); the centres move by 1e-14 px.
_CONTRACT = {"contract"}
_VECTOR = {"contract", "reassoc"}
#: A prediction whose σ per axis is at most this (pixels) starts the Gauss–Newton fit itself,
#: without the weighted centre's passes: from predictions 0.1–0.5 px σ off (up to ~2 px) the fit
#: converges on every one of 600 synthetic streaks (``tests/detect/test_detect_streak.py``'s) to the
#: centre it reaches from the weighted one, within its tolerance (≤ 0.006 px); from 0.7 px σ a
#: few are lost.
START_SIGMA_PX = 0.3


class StreakFit(NamedTuple):
    """What :func:`fit_streaks` measured of N streaks: (N,) columns, NaN centre, σ and elongation
    and zero flux, area and covariance where no centroid was found."""

    x: np.ndarray  #: the streak's centre (its mid-exposure position), pixels
    y: np.ndarray
    flux: np.ndarray  #: the model's integral, ADU
    area: np.ndarray  #: pixels of the footprint (above the sky, at least 1 % of the profile's peak)
    peak: np.ndarray  #: highest pixel above the sky in the window, ADU
    sigma_x: np.ndarray  #: the centre's 1-σ error and x–y covariance, pixels, px²
    sigma_y: np.ndarray
    cov_xy: np.ndarray
    elongation: np.ndarray  #: long over short axis of the footprint's second moments
    noise: np.ndarray  #: each window's noise σ and sky level (its border), ADU
    sky: np.ndarray
    half: np.ndarray  #: (N, 2) int64: each window's half sizes along x and y, pixels
    noise_level: float  #: the median noise and sky level
    background_level: float


class _Shape(NamedTuple):
    """A predicted streak: the motion's unit vector, half its length, 1/length, the PSF σ; for
    the row walk (:func:`_row_start`) ``q = 1/(√2 s)`` and the ratios ``exp(−2(ux·q)²)``,
    ``exp(−2(uy·q)²)`` by which its Gaussians' pixel-to-pixel factors change along a row (and,
    the other way round, from row to row), and ``exp(−2·ux·uy·q²)``, by which the along
    Gaussians' pixel-to-pixel factors change from row to row (the across one's: its inverse)."""

    ux: float
    uy: float
    half_len: float
    inv_len: float
    s: float
    q: float
    ca: float
    cb: float
    cab: float
    inv_cab: float


@njit(cache=True, inline="always")
def _shape(ux, uy, half_len, s):
    """The :class:`_Shape` of a streak along ``(ux, uy)``, ``2·half_len`` long, of PSF σ ``s``."""
    q = 1.0 / (math.sqrt(2.0) * s)
    return _Shape(ux, uy, half_len, 0.5 / half_len, s, q, math.exp(-2.0 * (ux * q) ** 2),
                  math.exp(-2.0 * (uy * q) ** 2), math.exp(-2.0 * ux * uy * q * q),
                  math.exp(2.0 * ux * uy * q * q))


# --- the profile, pixel by pixel along a row --------------------------------------------------------
# Along a row ``a`` and ``b`` are linear in x, so each Gaussian ``exp(−z²)`` of the profile (z =
# (a ± L/2)·q, b·q, with steps dz = ux·q, −uy·q) follows from the last pixel's by the recurrence
# ``g ← g·r, r ← r·exp(−2dz²)`` (``r = exp(−2z·dz − dz²)``): two exps a row, not three a pixel.
# Down a column ``a`` and ``b`` are linear in y too: each row's walk starts in the window's first
# column from the row above's start by the same recurrence (steps dz = uy·q, ux·q), with its
# pixel-to-pixel factors r carried along (``r ← r·exp(−2·dzx·dzy)``), and walks on to the first
# pixel within the streak's reach: nine exps a window, not six a row (an exp is most of a short
# row's walk). A start that underflows (below _TINY) is seeded afresh. Over a 40 px row the
# recurrence drifts under 1e-12 (relative, where the Gaussian is above 1e-30; 3e-13 absolute),
# as much again over 40 rows. The two erfs take the along Gaussians: erfc(|z|) =
# exp(−z²)·P(1/(1 + p|z|)) (Abramowitz & Stegun 7.1.26, within 1.5e-7 of erf; the centres move
# 2e-6 px), a fifth of ``math.erf``'s cost.


@njit(cache=True, inline="always")
def _seed(z, dz):
    """``exp(−z²)`` and its ratio to the next pixel's, ``exp(−(z + dz)²)``; ``(0, 1)`` where it
    underflows (``z² > 700``)."""
    if z * z > 700.0:
        return 0.0, 1.0
    return math.exp(-z * z), math.exp(-dz * (2.0 * z + dz))


@njit(cache=True, inline="always")
def _next(g, r, c, z, dz):
    """The Gaussian ``exp(−z²)`` at the next pixel (``z`` its offset there) and its ratio, from
    this pixel's ``g`` and ``r``; a zero (underflowed, or beyond the seed's reach) seeds afresh."""
    if g == 0.0:
        return _seed(z, dz)
    return g * r, r * c


@njit(cache=True, inline="always")
def _row_start(dx, dy, shape):
    """The row walk at the offset ``(dx, dy)`` from the streak's centre: ``a`` along and ``b``
    across the motion, and each Gaussian with its ratio (``(a + L/2)q``, ``(a − L/2)q``, ``bq``)."""
    ux, uy, h, q = shape.ux, shape.uy, shape.half_len, shape.q
    a, b = dx * ux + dy * uy, dy * ux - dx * uy
    return (a, b) + _seed((a + h) * q, ux * q) + _seed((a - h) * q, ux * q) + _seed(b * q, -uy * q)


@njit(cache=True, inline="always")
def _row_next(walk, shape):
    """The row walk one pixel on (``x + 1``)."""
    a, b, gp, rp, gm, rm, gb, rb = walk
    ux, uy, h, q = shape.ux, shape.uy, shape.half_len, shape.q
    a, b = a + ux, b - uy
    return ((a, b) + _next(gp, rp, shape.ca, (a + h) * q, ux * q)
            + _next(gm, rm, shape.ca, (a - h) * q, ux * q) + _next(gb, rb, shape.cb, b * q, -uy * q))


@njit(cache=True, inline="always")
def _row_step(walk, shape):
    """:func:`_row_next` without its re-seeding, for where no Gaussian can underflow
    (:func:`_no_underflow`): the recurrence alone, no exp in the loop that walks it."""
    a, b, gp, rp, gm, rm, gb, rb = walk
    return (a + shape.ux, b - shape.uy, gp * rp, rp * shape.ca, gm * rm, rm * shape.ca, gb * rb,
            rb * shape.cb)


@njit(cache=True, inline="always")
def _no_underflow(shape):
    """Whether every Gaussian of the profile stays above ``exp(−700)`` within the streak's reach
    (``|a ± L/2| ≤ L + 4s``, ``|b| ≤ 4s``): streaks shorter than ~33 σ."""
    z = (2.0 * shape.half_len + _REACH * shape.s) * shape.q
    return z * z <= 700.0


@njit(cache=True, inline="always")
def _put(buf, m, walk, v):
    """A pixel of the walk into ``buf``'s column ``m``: ``a``, ``b``, the three Gaussians and
    its value ``v`` above the sky."""
    a, b, gp, _, gm, _, gb, _ = walk
    buf[0, m] = a
    buf[1, m] = b
    buf[2, m] = gp
    buf[3, m] = gm
    buf[4, m] = gb
    buf[5, m] = v


@njit(cache=True, inline="always")
def _seed3(z, dzx, dzy):
    """``exp(−z²)`` and its ratios to the next pixel's along a row (``exp(−(z + dzx)²)``) and
    down a column (``exp(−(z + dzy)²)``); ``(0, 1, 1)`` where it underflows (``z² > 700``)."""
    if z * z > 700.0:
        return 0.0, 1.0, 1.0
    return math.exp(-z * z), math.exp(-dzx * (2.0 * z + dzx)), math.exp(-dzy * (2.0 * z + dzy))


@njit(cache=True, inline="always")
def _down(g, rx, ry, cx, cy, z, dzx, dzy):
    """A Gaussian of the column walk one row down (``z`` its offset there), with its ratios
    along the row and down the column, from this row's ``g``, ``rx``, ``ry`` and the ratios'
    factors ``cx``, ``cy``; seeded afresh below :data:`_TINY` (where the products lose digits)."""
    if g < _TINY:
        return _seed3(z, dzx, dzy)
    return g * ry, rx * cx, ry * cy


@njit(cache=True, inline="always")
def _column_start(dx, dy, shape):
    """The column walk at the offset ``(dx, dy)`` from the streak's centre (a window's first
    column and row): ``a``, ``b`` and each Gaussian with its ratios along and down (the
    ``(a + L/2)q``, ``(a − L/2)q`` and ``bq`` of :func:`_row_start`)."""
    ux, uy, h, q = shape.ux, shape.uy, shape.half_len, shape.q
    a, b = dx * ux + dy * uy, dy * ux - dx * uy
    return ((a, b) + _seed3((a + h) * q, ux * q, uy * q) + _seed3((a - h) * q, ux * q, uy * q)
            + _seed3(b * q, -uy * q, ux * q))


@njit(cache=True, inline="always")
def _column_next(col, shape):
    """The column walk one row down (``y + 1``)."""
    a, b, gp, xp, yp, gm, xm, ym, gb, xb, yb = col
    ux, uy, h, q = shape.ux, shape.uy, shape.half_len, shape.q
    a, b = a + uy, b + ux
    return ((a, b) + _down(gp, xp, yp, shape.cab, shape.cb, (a + h) * q, ux * q, uy * q)
            + _down(gm, xm, ym, shape.cab, shape.cb, (a - h) * q, ux * q, uy * q)
            + _down(gb, xb, yb, shape.inv_cab, shape.ca, b * q, -uy * q, ux * q))


@njit(cache=True, inline="always")
def _row_from(col, steps, shape):
    """The row walk ``steps`` pixels on from the column walk's pixel."""
    a, b, gp, xp, _, gm, xm, _, gb, xb, _ = col
    walk = (a, b, gp, xp, gm, xm, gb, xb)
    for _ in range(steps):
        walk = _row_next(walk, shape)
    return walk


@njit(cache=True, inline="always")
def _erf(z, g):
    """``erf(z)`` from ``g = exp(−z²)``: Abramowitz & Stegun 7.1.26, within 1.5e-7."""
    t = 1.0 / (1.0 + 0.3275911 * abs(z))
    poly = 0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429)))
    y = 1.0 - t * poly * g
    return y if z >= 0.0 else -y


@njit(cache=True, inline="always")
def _weight(a, b, gp, gm, gb, shape):
    """The streak profile (a Gaussian of σ ``s`` swept over ``±half_len`` along ``u``, divided by
    the length; it integrates to ``2√(2π)·s``) at the pixel ``a`` along and ``b`` across the
    motion (its Gaussians ``gp``, ``gm``, ``gb`` from the row walk: the erf difference along, the
    Gaussian across), and its gradient by the offset ``(dx, dy)``; zero beyond the streak's light
    — by a product with 0 or 1, not a branch, so that the loop of :func:`_sums` vectorises."""
    h, s, q = shape.half_len, shape.s, shape.q
    g = gb if (abs(b) <= _REACH * s) & (abs(a) <= h + _REACH * s) else 0.0
    e = (_erf((a + h) * q, gp) - _erf((a - h) * q, gm)) * shape.inv_len
    de = (2.0 / math.sqrt(math.pi)) * q * (gp - gm) * shape.inv_len
    da, db = de * g, -e * g * b * (2.0 * q * q)  # 1/s² = 2q²
    return e * g, da * shape.ux - db * shape.uy, da * shape.uy + db * shape.ux


@njit(cache=True, inline="always")
def _profile(walk, shape):
    """The streak profile of :func:`_weight` at the row walk's pixel."""
    a, b, gp, _, gm, _, gb, _ = walk
    return _weight(a, b, gp, gm, gb, shape)[0]


@njit(cache=True, inline="always")
def _limits(c1, c0, width, lo, hi):
    """``[lo, hi]`` cut to the offsets ``t`` with ``|c1·t + c0| <= width`` (empty: ``lo > hi``)."""
    if abs(c1) < 1e-12:
        return (lo, hi) if abs(c0) <= width else (1.0, 0.0)
    t0, t1 = (-width - c0) / c1, (width - c0) / c1
    return max(lo, min(t0, t1)), min(hi, max(t0, t1))


@njit(cache=True, inline="always")
def _span(y, box, shape, xc, yc):
    """The columns ``x0..x1`` of row ``y`` within the reach of the streak centred at ``(xc, yc)``
    (where :func:`_weight` is not zero): the others add nothing to a sum weighted by it, so the
    loops skip them (about half of a 2 °/s window's pixels)."""
    ux, uy, half_len, s = shape.ux, shape.uy, shape.half_len, shape.s
    dy = y - yc
    lo, hi = _limits(ux, dy * uy, half_len + _REACH * s, -1e300, 1e300)  # along
    lo, hi = _limits(-uy, dy * ux, _REACH * s, lo, hi)  # across
    if lo > hi:
        return box.x0, box.x0 - 1
    return max(box.x0, int(math.ceil(xc + lo))), min(box.x1, int(math.floor(xc + hi)))


@njit(cache=True, fastmath=_CONTRACT)
def _weighted_centre(img, box, shape, xc, yc, reach_x, reach_y):
    """A few steps of the streak-weighted centre of gravity from ``(xc, yc)``, with a weight twice
    as wide as the streak (the prediction may be a pixel or two off): the fit's start. ``ok``
    False if it has no light or leaves ``±reach`` of the start."""
    x_start, y_start = xc, yc
    wide = _shape(shape.ux, shape.uy, shape.half_len, 2.0 * shape.s)
    for _ in range(2):
        sw = swx = swy = 0.0
        col = _column_start(box.x0 - xc, box.y0 - yc, wide)
        for y in range(box.y0, box.y1 + 1):
            lo, hi = _span(y, box, wide, xc, yc)
            walk = _row_from(col, lo - box.x0, wide)
            col = _column_next(col, wide)
            for x in range(lo, hi + 1):
                v = (img[y, x] - box.sky) * _profile(walk, wide)
                walk = _row_next(walk, wide)
                sw += v
                swx += v * x
                swy += v * y
        if not sw > 0.0:
            return xc, yc, False
        nx_, ny_ = swx / sw, swy / sw
        if abs(nx_ - x_start) > reach_x or abs(ny_ - y_start) > reach_y:
            return xc, yc, False
        done = abs(nx_ - xc) < 0.25 and abs(ny_ - yc) < 0.25
        xc, yc = nx_, ny_
        if done:
            break
    return xc, yc, True


@njit(cache=True, fastmath=_CONTRACT)
def _gather(img, box, shape, xc, yc, buf):
    """The pixels within the reach of the streak centred at ``(xc, yc)`` (:func:`_span`) into
    the columns of ``buf`` (9 rows, ≥ their count): ``a`` and ``b`` (along and across the motion),
    the row walk's three Gaussians and the value above the sky. Returns their count."""
    m = 0
    safe = _no_underflow(shape)
    col = _column_start(box.x0 - xc, box.y0 - yc, shape)
    for y in range(box.y0, box.y1 + 1):
        lo, hi = _span(y, box, shape, xc, yc)
        walk = _row_from(col, lo - box.x0, shape)
        col = _column_next(col, shape)
        if safe:  # two loops: one with no exp (nor its spills) in it
            for x in range(lo, hi + 1):
                _put(buf, m, walk, img[y, x] - box.sky)
                m += 1
                walk = _row_step(walk, shape)
        else:
            for x in range(lo, hi + 1):
                _put(buf, m, walk, img[y, x] - box.sky)
                m += 1
                walk = _row_next(walk, shape)
    return m


@njit(cache=True, fastmath=_VECTOR, error_model="numpy")
def _sums(img, box, shape, xc, yc, amp, ig, buf):
    """One pass over the streak's reach at the centre ``(xc, yc)``: the sums of the weighted
    normal equations with the amplitude left out (the model is linear in it, :func:`_scaled`):
    ``Σ wᵢ·jᵢ·jₖ`` (6: ``j = (profile, ∂x, ∂y)``, the gradient of the profile without the
    amplitude's −A) and ``Σ wᵢ·jᵢ·vᵢ`` (3), and the count of the pixels, whose ``j`` it leaves in
    ``buf``'s rows 6–8 for :func:`_meat_footprint`. The weights ``wᵢ`` are the pixels' inverse
    variances: the sky's, ``1/noise²``, and with the gain's inverse ``ig`` their shot noise at
    ``amp`` (taken as a factor ``1/(1 + μᵢ·ig/noise²)`` of the sky's, which multiplies the sums
    after the loop).

    The row walk is a recurrence from pixel to pixel: :func:`_gather` runs it into ``buf``; the
    sums are one loop without a branch, which the compiler vectorises (four pixels at a time):
    numba's check of each division for a zero (``error_model="numpy"`` leaves it out; nothing
    here divides by zero) or the sums' fixed order (``_VECTOR``) would each keep it scalar. Without
    the gain (a tracker's fit) the weights are all the sky's: the loop divides by nothing but
    its erfs' own."""
    v0 = box.noise * box.noise if box.noise > 0 else 1.0
    m = _gather(img, box, shape, xc, yc, buf)
    shot = max(amp, 0.0) * ig / v0  # the shot noise at the peak, in sky variances
    s00 = s01 = s02 = s11 = s12 = s22 = t0 = t1 = t2 = 0.0
    for k in range(m):
        w, gx, gy = _weight(buf[0, k], buf[1, k], buf[2, k], buf[3, k], buf[4, k], shape)
        buf[6, k] = w
        buf[7, k] = gx
        buf[8, k] = gy
        v = buf[5, k]
        iv = 1.0 if shot == 0.0 else 1.0 / (1.0 + max(w, 0.0) * shot)
        iw, igx, igy = iv * w, iv * gx, iv * gy
        s00 += iw * w
        s01 += iw * gx
        s02 += iw * gy
        s11 += igx * gx
        s12 += igx * gy
        s22 += igy * gy
        t0 += iw * v
        t1 += igx * v
        t2 += igy * v
    i0 = 1.0 / v0
    return ((i0 * s00, i0 * s01, i0 * s02, i0 * s11, i0 * s12, i0 * s22), (i0 * t0, i0 * t1, i0 * t2), m)


@njit(cache=True, fastmath=_VECTOR, error_model="numpy")
def _meat_footprint(box, shape, amp, ig, wmin, buf, m):
    """At the last pass of :func:`_sums` (its ``m`` pixels and their ``j`` in ``buf``, the
    amplitude ``amp``): the sandwich's meat ``Σ (wᵢ·dᵢ)²·jᵢ·jₖ`` (6) with the residual ``d`` at
    ``amp``, only without the gain (zeros otherwise), and the streak's footprint (the pixels
    above the sky where the profile is at least ``wmin``): its count and ``Σ v``, ``Σ v·dx``,
    ``Σ v·dy``, ``Σ v·dx²``, ``Σ v·dy²``, ``Σ v·dx·dy`` about the pass's centre."""
    v0 = box.noise * box.noise if box.noise > 0 else 1.0
    meat = 1.0 if ig == 0.0 else 0.0
    ux, uy = shape.ux, shape.uy
    m00 = m01 = m02 = m11 = m12 = m22 = 0.0
    n = sv = svx = svy = svxx = svyy = svxy = 0.0
    for k in range(m):
        a, b, v = buf[0, k], buf[1, k], buf[5, k]
        w, gx, gy = buf[6, k], buf[7, k], buf[8, k]
        r = v - amp * w
        r = r * r * meat
        m00 += r * w * w
        m01 += r * w * gx
        m02 += r * w * gy
        m11 += r * gx * gx
        m12 += r * gx * gy
        m22 += r * gy * gy
        f = 1.0 if (v > 0.0) & (w >= wmin) else 0.0
        fv = f * v
        dx, dy = a * ux - b * uy, a * uy + b * ux
        n += f
        sv += fv
        svx += fv * dx
        svy += fv * dy
        svxx += fv * dx * dx
        svyy += fv * dy * dy
        svxy += fv * dx * dy
    i2 = 1.0 / (v0 * v0)
    return ((i2 * m00, i2 * m01, i2 * m02, i2 * m11, i2 * m12, i2 * m22),
            (n, sv, svx, svy, svxx, svyy, svxy))


@njit(cache=True, inline="always")
def _scaled(six, amp, m):
    """The symmetric 3×3 ``Σ w·Jᵢ·Jₖ`` of the Jacobian ``J = (j₀, −A·j₁, −A·j₂)`` from the six
    amplitude-free sums of :func:`_sums`, into ``m`` (returned)."""
    c = (1.0, -amp, -amp)
    k = 0
    for i in range(3):
        for j in range(i, 3):
            m[i, j] = m[j, i] = c[i] * c[j] * six[k]
            k += 1
    return m


@njit(cache=True, inline="always")
def _inverse3(m, adj):
    """The inverse of a 3×3 matrix by its adjugate (a tenth of ``pinv``'s 3 µs), into ``adj``
    (returned); pinv if near singular."""
    for i in range(3):
        for j in range(3):
            r0, r1 = (j + 1) % 3, (j + 2) % 3
            c0, c1 = (i + 1) % 3, (i + 2) % 3
            adj[i, j] = m[r0, c0] * m[r1, c1] - m[r0, c1] * m[r1, c0]
    det = m[0, 0] * adj[0, 0] + m[0, 1] * adj[1, 0] + m[0, 2] * adj[2, 0]
    scale = abs(m[0, 0] * m[1, 1] * m[2, 2])
    if not abs(det) > 1e-12 * scale:
        adj[:, :] = np.linalg.pinv(m)
    else:
        adj /= det
    return adj


@njit(cache=True, inline="always")
def _sandwich3(a, b):
    """``a·b·a`` of two 3×3 matrices (the fit's sandwich covariance from its meat), by loops:
    BLAS's calls cost more than the 54 multiplications."""
    ab = np.zeros((3, 3))
    out = np.zeros((3, 3))
    for i in range(3):
        for k in range(3):
            for j in range(3):
                ab[i, j] += a[i, k] * b[k, j]
    for i in range(3):
        for k in range(3):
            for j in range(3):
                out[i, j] += ab[i, k] * a[k, j]
    return out


@njit(cache=True)
def _fit(img, box, shape, xc, yc, ig, buf):
    """Gauss–Newton fit of the streak model from the weighted centre: (amplitude, x, y), its
    covariance ((JᵀWJ)⁻¹ with a gain, else the sandwich), whether it converged near the start,
    and the footprint of :func:`_meat_footprint` at the last pass, its moments moved to the fit's
    centre (the count, ``Σ v``, ``Σ v·dx²``, ``Σ v·dy²``, ``Σ v·dx·dy``).
    The first pass has no amplitude yet: it takes the linear least-squares one at the start (the
    model is linear in it) and weighs the pixels by the sky's noise alone; the covariance is
    from a later pass, at the amplitude and centre of the last step's start."""
    p = np.array([0.0, xc, yc])
    cov = np.zeros((3, 3))
    jtj, inv, jtr, step = np.empty((3, 3)), np.empty((3, 3)), np.empty(3), np.empty(3)
    prev_x = prev_y = 0.0  # the last step
    wmin = 0.01 * _profile(_row_start(0.0, 0.0, shape), shape)  # the footprint: 1 % of the peak
    nothing = (0.0, 0.0, 0.0, 0.0, 0.0)
    for it in range(15):
        at_x, at_y = p[1], p[2]
        six, tv, m = _sums(img, box, shape, at_x, at_y, p[0], ig, buf)
        if it == 0:
            p[0] = tv[0] / six[0] if six[0] > 0 else 0.0
            if not p[0] > 0:
                return p, cov, False, nothing
        amp = p[0]
        _scaled(six, amp, jtj)
        jtr[0] = tv[0] - amp * six[0]
        jtr[1] = -amp * (tv[1] - amp * six[1])
        jtr[2] = -amp * (tv[2] - amp * six[2])
        _inverse3(jtj, inv)
        for i in range(3):
            step[i] = inv[i, 0] * jtr[0] + inv[i, 1] * jtr[1] + inv[i, 2] * jtr[2]
        # the χ² the step gains (its length², in σ of the fit's metric), and the distance left,
        # extrapolated from the signed ratio ρ of the last two steps (Gauss–Newton converges
        # linearly; the steps alternate, ρ < 0, when the model is wider than the stars):
        # ρ/(1 − ρ) steps
        gain = step[0] * jtr[0] + step[1] * jtr[1] + step[2] * jtr[2]
        d = prev_x * prev_x + prev_y * prev_y
        rho = (step[1] * prev_x + step[2] * prev_y) / d if d > 0.0 else 1.0
        small = gain < _TOL_CHI2 or (abs(rho) < 1.0 and gain * (rho / (1.0 - rho)) ** 2 < _TOL_CHI2)
        prev_x, prev_y = step[1], step[2]
        big = max(abs(step[1]), abs(step[2]))
        if big > 0.5:  # at most half a pixel a step
            step *= 0.5 / big
        p += step
        if not p[0] > 0 or abs(p[1] - xc) > 2.0 or abs(p[2] - yc) > 2.0:
            return p, cov, False, nothing  # lost the star
        if (small or big < 1e-3) and it > 0:
            break
    meat6, foot = _meat_footprint(box, shape, amp, ig, wmin, buf, m)  # the last pass's
    if ig > 0:  # at the last step's start, under 0.1 σ away
        cov = inv
    else:
        cov = _sandwich3(inv, _scaled(meat6, amp, jtj))
    n, sv, svx, svy, svxx, svyy, svxy = foot
    ex, ey = p[1] - at_x, p[2] - at_y  # Σ v·(dx − ex)² …
    return p, cov, True, (n, sv, svxx - 2.0 * ex * svx + ex * ex * sv, svyy - 2.0 * ey * svy + ey * ey * sv,
                          svxy - ex * svy - ey * svx + ex * ey * sv)


@njit(cache=True)
def fit_streaks(img, xy, motion, half_size, s, ig, sigma_pred):
    """:func:`centroid_streaks` ``method="streak"`` without its argument handling, for other
    kernels (the tracker's windows): the streaks predicted at ``xy`` (N, 2) to within
    ``sigma_pred`` (N,) pixels (NaN: unknown) moving by ``motion`` (N, 2) in the float32 image
    ``img``, a margin of ``half_size`` (int64) pixels, the model's σ ``s``
    (:func:`streak_model_sigma`) and the gain's inverse ``ig`` (0: unknown). Returns a
    :class:`StreakFit`."""
    h, w = img.shape
    n = len(xy)
    out = np.zeros((_NCOL, n))
    for row in (_X, _Y, _SIGMA_X, _SIGMA_Y, _ELONGATION):
        out[row, :] = np.nan
    half = np.empty((n, 2), np.int64)
    pixels = np.empty((9, 0))  # _sums' pixels, grown to the largest window
    for i in range(n):
        dx, dy = motion[i, 0], motion[i, 1]
        length = math.hypot(dx, dy)
        hx, hy = half_size + int(math.ceil(abs(dx) / 2)), half_size + int(math.ceil(abs(dy) / 2))
        half[i, 0], half[i, 1] = hx, hy
        xs, ys = xy[i, 0], xy[i, 1]
        if not (np.isfinite(xs) and np.isfinite(ys)):
            continue
        cx, cy = int(round(xs)), int(round(ys))
        y0, y1 = max(cy - hy, 0), min(cy + hy, h - 1)
        x0, x1 = max(cx - hx, 0), min(cx + hx, w - 1)
        if y1 - y0 < 2 or x1 - x0 < 2:
            continue
        buf = np.empty(2 * (x1 - x0 + 1) + 2 * (y1 - y0 - 1))  # the sky from the window's border
        window_border(img, y0, y1, x0, x1, buf)  # fills buf: it is as long as the border
        sky, noise = robust_level_noise(buf, 0.0, False)
        out[_SKY, i] = sky
        out[_NOISE, i] = noise
        box = Window(y0, y1, x0, x1, sky, noise)
        half_len = max(0.5 * length, 5e-4)  # a still star: the limit, a Gaussian along too
        ux, uy = (dx / length, dy / length) if length > 0 else (1.0, 0.0)
        shape = _shape(ux, uy, half_len, s)
        if sigma_pred[i] <= START_SIGMA_PX:
            xc, yc = xs, ys
        else:
            xc, yc, ok = _weighted_centre(img, box, shape, xs, ys, hx, hy)
            if not ok:
                continue
        area = (y1 - y0 + 1) * (x1 - x0 + 1)
        pixels = pixels if pixels.shape[1] >= area else np.empty((9, area))
        p, cov, ok, (npix, sv, sxx, syy, sxy) = _fit(img, box, shape, xc, yc, ig, pixels)
        if not ok:
            continue
        peak = -np.inf
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                peak = max(peak, img[y, x] - sky)
        out[_X, i] = p[1]
        out[_Y, i] = p[2]
        out[_FLUX, i] = p[0] * 2.0 * math.sqrt(2.0 * math.pi) * s  # the model's integral
        out[_PEAK, i] = peak
        out[_SIGMA_X, i] = math.sqrt(max(cov[1, 1], 0.0))
        out[_SIGMA_Y, i] = math.sqrt(max(cov[2, 2], 0.0))
        out[_COV_XY, i] = cov[1, 2]
        out[_AREA, i] = npix
        out[_ELONGATION, i] = 0.0
        if sv > 0.0:  # long over short axis of the second moments
            mxx, myy, mxy = sxx / sv, syy / sv, sxy / sv
            root = math.sqrt(max(0.25 * (mxx - myy) ** 2 + mxy * mxy, 0.0))
            big, small = 0.5 * (mxx + myy) + root, 0.5 * (mxx + myy) - root
            out[_ELONGATION, i] = math.sqrt(big / max(small, 1e-12))
    noise_level = np.median(out[_NOISE]) if n else 0.0
    sky_level = np.median(out[_SKY]) if n else 0.0
    return StreakFit(out[_X], out[_Y], out[_FLUX], out[_AREA], out[_PEAK], out[_SIGMA_X], out[_SIGMA_Y],
                     out[_COV_XY], out[_ELONGATION], out[_NOISE], out[_SKY], half, noise_level, sky_level)
