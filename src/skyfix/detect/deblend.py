"""Deblending: touching stars split at the saddle between prominent maxima.

Step 4 of the default extractor (:mod:`skyfix.detect.components`). In each candidate, the local
maxima of the smoothed frame (hot pixels left out, :func:`~skyfix.detect.measure.sharpness`)
are taken brightest first; a maximum becomes its own star when it is at least ``min_sep``
pixels from every kept one and rises above the saddle toward them (the lowest smoothed value
on the straight segment) by ``contrast`` of its height above the sky and by 3σ. Every pixel
goes to the kept maximum its steepest ascent reaches (else the nearest). A component with more
than ``max_parts`` such maxima is texture (foliage, a nebula) and stays whole.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix.detect._grid import grid_at
from skyfix.detect.labelling import CANDIDATE
from skyfix.detect.measure import residual, sharpness

__all__ = ["DeblendRule", "deblend"]


class DeblendRule(NamedTuple):
    """When a second maximum in a component is a star of its own (module docstring)."""

    contrast: float  #: rise above the saddle, as a fraction of the maximum's height above the sky
    min_sep: float  #: pixels from every brighter kept maximum
    max_parts: int  #: more prominent maxima than this: texture, the component stays whole
    min_sharpness: float  #: maxima less sharp than this are hot pixels, not stars


@njit(cache=True)
def deblend(img, frames, cand, sky, next_label, rule):
    """Split candidates with several prominent maxima; returns the new candidates.

    ``cand`` and the result are :data:`~skyfix.detect.labelling.CANDIDATE` arrays.
    ``frames`` as the labelling left them (``frames.labels`` is relabelled in place); ``rule``
    the :class:`DeblendRule`. New labels are allocated from ``next_label`` upward; the
    component keeps its label for the part around its highest maximum. Scratch arrays are
    allocated once, not per component.
    """
    sm, labels = frames.smooth, frames.labels
    contrast, min_sep, max_parts, min_sharpness = rule
    h, w = sm.shape
    n_in = cand.size
    cap = 1
    for c in range(n_in):
        cap = max(cap, (cand[c].y1 - cand[c].y0 + 1) * (cand[c].x1 - cand[c].x0 + 1))
    my = np.empty(cap, np.int64)
    mx = np.empty(cap, np.int64)
    mv = np.empty(cap, sm.dtype)
    ky = np.empty(cap, np.int64)
    kx = np.empty(cap, np.int64)
    kept = np.empty(cap, np.int64)
    step = np.empty(cap, np.int64)
    root = np.empty(cap, np.int64)
    n_max_out = n_in * max(max_parts, 1)
    out = np.empty(n_max_out, CANDIDATE)
    n = 0
    nxt = next_label
    for c in range(n_in):
        lab = cand[c].id
        y0, y1, x0, x1 = cand[c].y0, cand[c].y1, cand[c].x0, cand[c].x1
        nm = 0
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                if labels[y, x] != lab:
                    continue
                v = sm[y, x]
                is_max = True
                for qy in range(max(y - 1, 0), min(y + 2, h)):
                    for qx in range(max(x - 1, 0), min(x + 2, w)):
                        if (qy != y or qx != x) and labels[qy, qx] == lab:
                            u = sm[qy, qx]
                            # ties: the first in scan order wins
                            if u > v or (u == v and (qy < y or (qy == y and qx < x))):
                                is_max = False
                                break
                    if not is_max:
                        break
                if is_max:
                    # a hot pixel is no star to split off: the measurement leaves it out later
                    if sharpness(img, sky, y, x, residual(img, sky, y, x)) < min_sharpness:
                        continue
                    my[nm] = y
                    mx[nm] = x
                    mv[nm] = v
                    nm += 1
        nk = 1
        kept[0] = 0
        if nm > 1:
            order = np.argsort(-mv[:nm])
            ky[0] = my[order[0]]
            kx[0] = mx[order[0]]
            kept[0] = order[0]
            for r in range(1, order.size):
                i = order[r]
                yy, xx = my[i], mx[i]
                near = False
                col = -np.inf
                for j in range(nk):
                    if (ky[j] - yy) ** 2 + (kx[j] - xx) ** 2 < min_sep**2:
                        near = True
                    col = max(col, _saddle(sm, yy, xx, ky[j], kx[j]))
                if near:
                    continue
                height = mv[i] - grid_at(sky.level_smooth, sky.weights, yy, xx)
                prom = mv[i] - col
                if prom >= contrast * height and prom >= 3.0 * grid_at(sky.noise_smooth, sky.weights, yy, xx):
                    ky[nk] = yy
                    kx[nk] = xx
                    kept[nk] = i
                    nk += 1
        # no maximum, one, or more than a few prominent ones (texture: foliage, nebula, left for
        # the diffuseness test): the component stays whole
        if nm == 0 or nk < 2 or nk > max_parts:
            out[n].id = lab
            out[n].y0, out[n].y1, out[n].x0, out[n].x1 = y0, y1, x0, x1
            out[n].is_part = False
            n += 1
            continue
        first_new = nxt
        part_label = np.empty(nk, np.int32)
        part_label[0] = lab
        for k in range(1, nk):
            part_label[k] = nxt
            nxt += 1
        # assign every pixel to the kept maximum its ascent reaches (else the nearest one); the
        # ascent graph is fixed while labels change (the eligible pixels stay eligible), so each
        # pixel's step is found once and the paths are shared
        bw = x1 - x0 + 1
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                li = (y - y0) * bw + (x - x0)
                lv = labels[y, x]
                root[li] = -2  # not in the component
                if lv != lab and lv < first_new:
                    continue
                root[li] = -1
                by, bx = _ascent_step(sm, labels, lab, first_new, y, x)
                step[li] = (by - y0) * bw + (bx - x0)
        for li in range(bw * (y1 - y0 + 1)):
            if root[li] != -1:
                continue
            j = li
            while root[j] == -1 and step[j] != j:
                j = step[j]
            end = root[j] if root[j] >= 0 else j
            j = li
            while root[j] == -1:
                root[j] = end
                j = step[j]
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                li = (y - y0) * bw + (x - x0)
                if root[li] < 0:
                    continue
                ty, tx = y0 + root[li] // bw, x0 + root[li] % bw
                best = -1
                bd = np.inf
                for k in range(nk):
                    d = (ky[k] - ty) ** 2 + (kx[k] - tx) ** 2
                    if d < bd:
                        bd, best = d, k
                labels[y, x] = part_label[best]
        for k in range(nk):
            by0, by1, bx0, bx1 = h, -1, w, -1
            for y in range(y0, y1 + 1):
                for x in range(x0, x1 + 1):
                    if labels[y, x] == part_label[k]:
                        by0, by1 = min(by0, y), max(by1, y)
                        bx0, bx1 = min(bx0, x), max(bx1, x)
            if by1 >= 0:
                out[n].id = part_label[k]
                out[n].y0, out[n].y1, out[n].x0, out[n].x1 = by0, by1, bx0, bx1
                out[n].is_part = True
                n += 1
    return out[:n].copy()


@njit(cache=True)
def _ascent_step(sm, labels, lab, first_new, y, x):
    """One step of steepest ascent on ``sm`` inside one component (original or split labels).

    The highest neighbour (the first in scan order among equals), or (y, x) at a maximum.
    """
    h, w = sm.shape
    by, bx = y, x
    for qy in range(max(y - 1, 0), min(y + 2, h)):
        for qx in range(max(x - 1, 0), min(x + 2, w)):
            lv = labels[qy, qx]
            if (lv == lab or lv >= first_new) and sm[qy, qx] > sm[by, bx]:
                by, bx = qy, qx
    return by, bx


@njit(cache=True)
def _saddle(sm, y0, x0, y1, x1):
    """Lowest value of ``sm`` on the straight segment between two pixels."""
    n = max(abs(y1 - y0), abs(x1 - x0))
    lo = min(sm[y0, x0], sm[y1, x1])
    for k in range(1, n):
        t = k / n
        lo = min(lo, sm[int(round(y0 + t * (y1 - y0))), int(round(x0 + t * (x1 - x0)))])
    return lo
