"""Threshold and label: the smoothed frame above the sky by k·σ, as 8-connected components.

Steps 2–3 of the default extractor (:mod:`skyfix.detect.components`):

1. :func:`smooth_threshold` — one pass over the frame smooths it (3×3 binomial, a cheap matched
   filter for a PSF of σ ≈ 1 px), sets the pixels whose smoothed value exceeds the smoothed
   sky by ``sigma``·σ (more on the frame border, where smoothing averages fewer pixels), flags
   the 64-pixel blocks that hold any, and returns the frame's sum (non-finite pixels) and
   maximum (saturation).
2. :func:`label_components` — runs of set pixels along rows joined by union-find into
   8-connected components, skipping empty blocks; records each component's size, box and
   summed excess (:data:`COMPONENT`).
3. :func:`select_candidates` — components too small, too large or too extended (Moon, roof
   edges) are dropped, and lone hot pixels (nearly all the light in one pixel), before the cap
   on measured candidates (:data:`CANDIDATE`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix.detect._grid import SkyGrid, grid_at, grid_rows
from skyfix.detect._smooth import column_sum, smooth_row
from skyfix.detect._stats import argsort_descending
from skyfix.detect._threads import run_chunks, split

__all__ = ["Frames", "COMPONENT", "CANDIDATE", "MAX_COMPONENTS", "Runs", "Thresholded", "smooth_threshold",
           "label_components", "select_candidates", "clear_boxes"]

#: Components beyond this many (in raster order) stay unlabelled.
MAX_COMPONENTS = 1 << 16
# Fraction of a component's positive raw light in its brightest pixel beyond which it is a hot
# pixel (a star centred on a pixel with PSF σ = 0.35 px puts 80% there).
_HOT_CONCENTRATION = 0.9
# Noise σ of the 3×3 binomial mean with replicated edges, relative to the interior:
# [3 1]/4 along a border axis has Σw² = 10/16 against 6/16.
_EDGE_NOISE = math.sqrt(10.0 / 6.0)


class Frames(NamedTuple):
    """The full-frame buffers of one extraction, H×W (reused between calls of one frame size)."""

    smooth: np.ndarray  #: (H, W) float32 — the 3×3-smoothed frame
    mask: np.ndarray  #: (H, W rounded up to 64) uint8 — smoothed frame above threshold (padding 0)
    blocks: np.ndarray  #: (H, ⌈W/64⌉) uint8 — whether each 64-pixel block of a mask row has a pixel set
    labels: np.ndarray  #: (H, W) int32 — component labels, 1-based (0: none)


# The per-object tables are structured arrays (one array between numba and Python, not one per
# column: each array returned to Python costs about a microsecond).

#: A connected component (:func:`label_components`), in label order (label = index + 1): pixels
#: above threshold; bounding box rows ``y0..y1`` and columns ``x0..x1`` (inclusive); summed
#: excess of the smoothed frame over its sky; highest raw pixel above the sky; sum of the raw
#: pixels above the sky (the positive ones only).
COMPONENT = np.dtype([("area", np.int64), ("y0", np.int64), ("y1", np.int64), ("x0", np.int64),
                      ("x1", np.int64), ("excess", np.float64), ("peak", np.float64),
                      ("positive", np.float64)])
#: A candidate for measurement (:func:`select_candidates`, :func:`~skyfix.detect.deblend.deblend`):
#: its label in ``Frames.labels``, bounding box, and whether deblending split it off a component.
CANDIDATE = np.dtype([("id", np.int32), ("y0", np.int64), ("y1", np.int64), ("x0", np.int64),
                      ("x1", np.int64), ("is_part", np.bool_)])


def smooth_threshold(img: np.ndarray, thr_grid: np.ndarray, sky: SkyGrid, frames: Frames) -> Thresholded:
    """One pass over the frame smooths it into ``frames.smooth``, sets ``frames.mask`` where it
    is above threshold and finds the runs of set pixels along its rows (:func:`label_components`
    joins them) — in bands of rows, shared with the helper thread (:mod:`skyfix.detect._threads`).

    The smoothing is :func:`~skyfix.detect.background.smooth3`'s; ``frames.blocks`` flags the
    64-pixel blocks of each mask row that hold a set pixel (the labelling skips the others).
    ``img`` is float32 (:func:`~skyfix.detect.background.frame_f32`); ``thr_grid`` the threshold
    on the tile grid of ``sky`` (a :class:`~skyfix.detect._grid.SkyGrid`), interpolated
    bilinearly (raised on the border, :func:`_threshold_at`). Nothing depends on the bands but
    the rounding of the sum (only its finiteness is used).
    """
    edges = split(img.shape[0], -(-300_000 // img.shape[1]))  # 300 kilopixels or more a band
    bits = img.view(np.int32)
    parts = run_chunks(lambda i: _smooth_threshold_rows(img, bits, thr_grid, sky, frames, edges[i],
                                                        edges[i + 1]), len(edges) - 1)
    top = max(p[1] for p in parts)
    top ^= (top >> 31) & 0x7FFFFFFF  # back from the monotonic int32 to the float's bits
    maximum = float(np.array([top], np.int32).view(np.float32)[0])
    runs, starts = _joined([p[2] for p in parts])
    return Thresholded(float(sum(p[0] for p in parts)), maximum, runs, starts)


def _joined(parts: list[Runs]) -> tuple[Runs, np.ndarray]:
    """The bands' runs as one table (parents renumbered), and where each band's start."""
    starts = np.zeros(len(parts) + 1, np.int64)
    for i, r in enumerate(parts):
        starts[i + 1] = starts[i] + r.y.size
    if len(parts) == 1:
        return parts[0], starts
    runs = Runs(*(np.concatenate(columns) for columns in zip(*parts, strict=True)))
    for i in range(1, len(parts)):
        runs.parent[starts[i]:starts[i + 1]] += starts[i]
    return runs, starts


class Thresholded(NamedTuple):
    """What :func:`smooth_threshold` found besides the frames it filled."""

    total: float  #: the raw frame's sum (non-finite if any pixel is)
    maximum: float  #: the raw frame's maximum
    runs: Runs  #: the runs of set pixels, each band's joined within it (:func:`label_components`)
    starts: np.ndarray  #: (B + 1,) int64 — where each band's runs start in ``runs``


@njit(cache=True, fastmath={"reassoc", "contract"}, nogil=True)
def _smooth_threshold_rows(img, bits, thr_grid, sky, frames, y0, y1):
    """:func:`smooth_threshold` on rows ``y0..y1 − 1``. ``bits`` is ``img`` viewed as int32 (for
    the maximum). Returns the rows' sum (non-finite if any pixel is), their maximum as a
    monotonic int32 (a float's bits, negatives flipped) and the runs of set pixels in their mask.
    Reassociation lets the row loops vectorise; NaN and Inf still propagate (no "nnan"/"ninf").
    The arithmetic is float32 (exact on 8- to 16-bit data).
    """
    h, w = img.shape
    sm, mask, blocks = frames.smooth, frames.mask, frames.blocks
    iy, fy = sky.weights.iy, sky.weights.fy
    # the threshold grid interpolated along x at the tile-centre rows: any pixel row is then
    # r0 + f·dr, one fused multiply-add per pixel
    t0, dt = grid_rows(thr_grid, sky.weights)
    tmp = np.empty(w, np.float32)
    total = 0.0
    top = np.int32(-(2**31))
    for y in range(y0, y1):
        ya, yb = max(y - 1, 0), min(y + 1, h - 1)
        acc = np.float32(0.0)
        for x in range(w):
            tmp[x] = column_sum(img, ya, y, yb, x)
            acc += img[y, x]
            # the maximum on the float's bits made monotonic as int32: a float max reduction
            # does not vectorise without "nnan", an integer one does
            b = bits[y, x]
            top = max(top, b ^ ((b >> 31) & np.int32(0x7FFFFFFF)))
        total += acc
        out = sm[y]
        smooth_row(tmp, out, w)
        i = iy[y]
        f = np.float32(fy[y])
        m = mask[y]
        for x in range(w):
            m[x] = out[x] > t0[i, x] + f * dt[i, x]
        # border pixels: the replicated edge makes their smoothed noise larger
        if y == 0 or y == h - 1:
            for x in range(w):
                m[x] = out[x] > _threshold_at(thr_grid, sky, y, x, h, w)
        else:
            m[0] = out[0] > _threshold_at(thr_grid, sky, y, np.int64(0), h, w)  # typed (skyfix.detect._stats)
            m[w - 1] = out[w - 1] > _threshold_at(thr_grid, sky, y, w - 1, h, w)
        words = m.view(np.uint64)
        for c in range(blocks.shape[1]):
            any_set = np.uint64(0)
            for wi in range(8 * c, 8 * c + 8):
                any_set |= words[wi]
            blocks[y, c] = any_set != 0
    return total, top, _band_runs(img, frames, sky, y0, y1)


@njit(cache=True, fastmath={"reassoc", "contract"})
def _threshold_at(thr_grid, sky, y, x, h, w):
    """Detection threshold at (y, x), raised on the frame border where smoothing averages less.

    The flags are :func:`smooth_threshold`'s, which numba gave it from the start by inheritance.
    """
    t = grid_at(thr_grid, sky.weights, y, x)
    fac = 1.0
    if y == 0 or y == h - 1:
        fac *= _EDGE_NOISE
    if x == 0 or x == w - 1:
        fac *= _EDGE_NOISE
    if fac == 1.0:
        return t
    b = grid_at(sky.level_smooth, sky.weights, y, x)
    return b + (t - b) * fac


class Runs(NamedTuple):
    """Runs of set mask pixels along rows, in raster order (:func:`label_components`): row,
    first and last column, union-find parent, summed excess of the smoothed frame over its sky,
    highest raw pixel above the sky, sum of the positive raw pixels above the sky."""

    y: np.ndarray
    x0: np.ndarray
    x1: np.ndarray
    parent: np.ndarray
    excess: np.ndarray
    peak: np.ndarray
    positive: np.ndarray


def label_components(img: np.ndarray, frames: Frames, sky: SkyGrid, max_components: int,
                     found: Thresholded | None = None) -> np.ndarray:
    """8-connected components of the pixels set in ``frames.mask``, into ``frames.labels`` (1-based).

    ``frames`` as :func:`smooth_threshold` left them, ``found`` what it returned (without it the
    runs are found here, the frame one band); ``labels`` must be 0 wherever the mask is set.
    Components are numbered in the raster order of their first pixel (as a flood fill from a
    raster scan numbers them); those beyond ``max_components`` stay unlabelled. Works on runs
    of set pixels along rows, joined to the touching runs of the row above by union-find: the
    frame is read row by row (a flood fill's scattered reads wait on memory). Runs joined within
    each band of rows are joined here across the bands' edges and numbered in one pass, so the
    components are the same whatever the bands.
    Returns the components, a :data:`COMPONENT` array.
    """
    if found is None:
        runs = _band_runs(img, frames, sky, 0, frames.mask.shape[0])
        runs, starts = _joined([runs])
    else:
        runs, starts = found.runs, found.starts
    return _number_components(frames.labels, runs, starts, max_components)


@njit(cache=True)
def _band_runs(img, frames, sky, y0, y1):
    """The :class:`Runs` of rows ``y0..y1 − 1``, joined within them (parents count from 0)."""
    cap = _count_runs(frames.mask[y0:y1], frames.blocks[y0:y1])  # exactly (a bound of 32 a block was 5 MB)
    runs = Runs(np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(cap, np.int64),
                np.empty(cap, np.int64), np.empty(cap), np.empty(cap), np.empty(cap))
    _find_runs(img, frames, sky, y0, y1, runs, 0)
    return runs


@njit(cache=True)
def _find_runs(img, frames, sky, y0, y1, runs, r0):
    """The runs of rows ``y0..y1 − 1`` into ``runs`` from index ``r0``, joined within the rows."""
    sm, mask, blocks, labels = frames
    iy, fy = sky.weights.iy, sky.weights.fy
    w = sm.shape[1]
    b0, db = grid_rows(sky.level_smooth, sky.weights)
    q0, dq = grid_rows(sky.level, sky.weights)
    run_y, run_x0, run_x1, parent, run_excess, run_peak, run_sum = runs
    nr = r0
    prev_start = prev_end = r0
    for y in range(y0, y1):
        words = mask[y].view(np.uint64)
        cur_start = nr
        i = iy[y]
        f = fy[y]
        for c in range(blocks.shape[1]):
            if blocks[y, c] == 0:
                continue
            for wi in range(8 * c, 8 * c + 8):
                if words[wi] == 0:
                    continue
                for x in range(8 * wi, min(8 * wi + 8, w)):
                    if mask[y, x] == 0:
                        continue
                    if nr == cur_start or run_x1[nr - 1] != x - 1:
                        run_y[nr] = y
                        run_x0[nr] = x
                        parent[nr] = nr
                        run_excess[nr] = 0.0
                        run_peak[nr] = -np.inf
                        run_sum[nr] = 0.0
                        nr += 1
                    run_x1[nr - 1] = x
                    run_excess[nr - 1] += sm[y, x] - (b0[i, x] + f * db[i, x])
                    r = img[y, x] - (q0[i, x] + f * dq[i, x])
                    run_peak[nr - 1] = max(run_peak[nr - 1], r)
                    run_sum[nr - 1] += max(r, 0.0)
        _join_rows(runs, prev_start, prev_end, cur_start, nr)
        prev_start, prev_end = cur_start, nr
    return nr


@njit(cache=True, inline="always")
def _join_rows(runs, prev_start, prev_end, cur_start, cur_end):
    """Join each run ``cur_start..cur_end − 1`` of a row to the runs ``prev_start..prev_end − 1``
    of the row above that touch it (8-connected); both in x order."""
    run_x0, run_x1, parent = runs.x0, runs.x1, runs.parent
    k0 = prev_start
    for j in range(cur_start, cur_end):
        while k0 < prev_end and run_x1[k0] < run_x0[j] - 1:
            k0 += 1
        k = k0
        while k < prev_end and run_x0[k] <= run_x1[j] + 1:
            # union, the earlier run (in raster order) becoming the root
            a = k
            while parent[a] != a:
                parent[a] = parent[parent[a]]
                a = parent[a]
            bb = j
            while parent[bb] != bb:
                parent[bb] = parent[parent[bb]]
                bb = parent[bb]
            if a < bb:
                parent[bb] = a
            elif bb < a:
                parent[a] = bb
            k += 1


@njit(cache=True)
def _number_components(labels, runs, starts, max_components):
    """The bands' runs (band ``b`` from ``starts[b]``) joined across the bands' edges, numbered
    as components in raster order and written into ``labels``: a :data:`COMPONENT` array."""
    run_y, parent = runs.y, runs.parent
    nr = starts[-1]
    for b in range(1, starts.size - 1):
        # the last row of the band above (if it has runs there) and the first row of this band
        s = starts[b]
        e = starts[b + 1]
        if s == starts[b - 1] or s == e:
            continue
        first = run_y[s]
        prev_end = s
        prev_start = s
        while prev_start > starts[b - 1] and run_y[prev_start - 1] == first - 1:
            prev_start -= 1
        cur_end = s
        while cur_end < e and run_y[cur_end] == first:
            cur_end += 1
        if prev_start < prev_end:
            _join_rows(runs, prev_start, prev_end, s, cur_end)
    h, w = labels.shape
    # component numbers: roots in raster order (each root is its component's first run)
    rank = np.empty(nr, np.int64)
    k = 0
    for r in range(nr):
        a = r
        while parent[a] != a:
            a = parent[a]
        parent[r] = a
        if a == r:
            rank[r] = k
            k += 1
    n_comp = min(k, max_components)
    comps = np.zeros(n_comp, COMPONENT)
    for c in range(n_comp):
        comps[c].y0 = h
        comps[c].y1 = -1
        comps[c].x0 = w
        comps[c].x1 = -1
        comps[c].peak = -np.inf
    for r in range(nr):
        c = rank[parent[r]]
        if c >= n_comp:
            continue
        y, x0, x1 = run_y[r], runs.x0[r], runs.x1[r]
        comps[c].area += x1 - x0 + 1
        comps[c].y0 = min(comps[c].y0, y)
        comps[c].y1 = max(comps[c].y1, y)
        comps[c].x0 = min(comps[c].x0, x0)
        comps[c].x1 = max(comps[c].x1, x1)
        comps[c].excess += runs.excess[r]
        comps[c].peak = max(comps[c].peak, runs.peak[r])
        comps[c].positive += runs.positive[r]
        for x in range(x0, x1 + 1):
            labels[y, x] = c + 1
    return comps


@njit(cache=True)
def _count_runs(mask, blocks):
    """How many runs of set pixels the rows of ``mask`` hold (in the blocks ``blocks`` flags).

    A mask word holds 8 pixels, a byte each (0 or 1): a run starts at a set byte whose left
    neighbour (the byte below it, or the previous word's top byte) is clear, and the starts of
    a word are counted by summing its bytes (a multiply by 0x0101…01, the sum in the top byte).
    Freeing tables sized by a bound of 32 runs a block (5 MB on a dense 1280 × 960 frame) let
    the allocator hand the heap back and fault it in again on every call.
    """
    n = np.int64(0)  # typed (skyfix.detect._stats)
    ones = np.uint64(0x0101010101010101)
    words = mask.view(np.uint64)
    for y in range(mask.shape[0]):
        prev = np.uint64(0)  # the word left of the block (0 if its block is empty)
        for c in range(blocks.shape[1]):
            if blocks[y, c] == 0:
                prev = np.uint64(0)
                continue
            for wi in range(8 * c, 8 * c + 8):
                cur = words[y, wi]
                starts = cur & ~((cur << np.uint64(8)) | (prev >> np.uint64(56)))
                n += np.int64((starts * ones) >> np.uint64(56))
                prev = cur
    return n


@njit(cache=True)
def select_candidates(comps, min_area, max_area, max_extent, drop_hot, cap):
    """The components worth measuring, by decreasing summed excess: a :data:`CANDIDATE` array.

    ``comps`` a :data:`COMPONENT` array. Size and extent limits; with ``drop_hot``, lone hot
    pixels (nearly all of the component's light in one pixel); at most ``cap``, the brightest
    (ties keep label order).
    """
    n = comps.size
    keep = np.empty(n, np.int64)
    k = 0
    for c in range(n):
        area = comps[c].area
        extent = max(comps[c].y1 - comps[c].y0, comps[c].x1 - comps[c].x0) + 1
        ok = area >= min_area and area <= max_area and extent <= max_extent
        if drop_hot and not comps[c].peak < _HOT_CONCENTRATION * max(comps[c].positive, 1e-30):
            ok = False
        if ok:
            keep[k] = c
            k += 1
    idx = keep[:k]
    order = argsort_descending(comps.excess[idx])  # stable
    idx = idx[order[:cap]]
    cand = np.empty(idx.size, CANDIDATE)
    for i in range(idx.size):
        c = idx[i]
        cand[i].id = c + 1
        cand[i].y0 = comps[c].y0
        cand[i].y1 = comps[c].y1
        cand[i].x0 = comps[c].x0
        cand[i].x1 = comps[c].x1
        cand[i].is_part = False
    return cand


@njit(cache=True)
def clear_boxes(labels, boxes):
    """Zero ``labels`` inside each box (records with ``y0, y1, x0, x1``: what the last call labelled)."""
    for k in range(boxes.size):
        for y in range(boxes[k].y0, boxes[k].y1 + 1):
            for x in range(boxes[k].x0, boxes[k].x1 + 1):
                labels[y, x] = 0
