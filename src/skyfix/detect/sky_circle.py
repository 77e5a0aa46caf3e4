"""An all-sky lens's image circle, and the sky inside it: what an all-sky frame's solve may use.

A fisheye that sees the whole sky draws it as a disc; outside the disc (the frame's corners, or
its sides too when the disc is narrower than a wide sensor) the lens passes no light. Inside
lie the sky and, around its edge, the horizon: hills, trees and buildings, dark, or lit and
brighter than the sky, and a town's light dome.

:func:`find_image_circle` answers, cheaply on an ordinary frame, whether a frame is an all-sky
one and where its circle is:

1. *The rim first* (tens of µs): the four corners and the middles of the short sides must all
   be dark — alike, and far below the frame's centre (:func:`_corner_test`). A frame of stars
   on a sky has its sky there too, and is answered None here.
2. *The lit disc*: the frame is shrunk by block means (at most :data:`_GRID_CELLS` blocks on a
   side); blocks above the midpoint between the corners' level and the centre's are lit; the
   largest connected lit region is the sky (with anything lit on the horizon).
3. *The circle*: the lit region's convex hull has its vertices on the circle (dark trees only
   cut chords into the disc; lit ones lie inside it), except where the disc is clipped by the
   frame's edges — those vertices are left out. A circle is fitted to the vertices by least
   squares (Kåsa's), and vertices more than two blocks inside it are dropped and the circle
   fitted again.
4. It is an all-sky frame when the circle is at least :data:`MIN_FILL` of the short side across
   and its centre inside the frame.

:func:`sky_mask` is the sky to find stars in: inside the circle less a margin, less the blocks
that are dark (an obstruction's silhouette) or textured (a lit obstruction: its block-to-block
scatter, median-filtered so that a lone bright star's block does not count, far above the sky's)
and their neighbours. ``--mask FILE`` replaces it (an explicit mask always wins).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

__all__ = ["ImageCircle", "MIN_FILL", "find_image_circle", "sky_mask"]

MIN_FILL = 0.7
"""An image circle at least this share of the frame's short side across makes an all-sky frame."""

_GRID_CELLS = 400  # the shrunk frame's longer side, blocks
_RIM_ALIKE = 6.0  # the rim's patches' means lie within this many σ of a mean
_CORNER_SIGMA = 10.0  # the centre must be this many σ of a mean above the rim
_DARK_SHARE = 0.5  # a block below this share of the way from the corners' level to the sky's is dark
_TEXTURE_RATIO = 3.0  # a block whose (median-filtered) scatter is this many times the sky's is textured


class ImageCircle(NamedTuple):
    """An all-sky lens's image circle: its centre ``(cx, cy)`` and radius, pixels
    (docs/design.md#conventions), and the frame's dark level (the corners' median, ADU) and the
    sky's (the circle's central region's median)."""

    cx: float
    cy: float
    radius: float
    dark_level: float
    sky_level: float

    def mirrored(self, width: int) -> ImageCircle:
        """The circle in the frame mirrored left to right (``x → width − 1 − x``)."""
        return self._replace(cx=width - 1 - self.cx)


def _corner_test(data: np.ndarray) -> tuple[float, float] | None:
    """The dark level and the centre's when the frame's rim is dark (step 1); None otherwise.

    Six 8 × 8 px patches — the four corners and the middles of the two short sides, which lie
    outside a circle that fits the short side — must be alike (their means within
    :data:`_RIM_ALIKE` σ of a patch's mean, σ their pooled pixel scatter) and their mean far below
    the centre's median (:data:`_CORNER_SIGMA` σ of the six patches' mean): a vignetted frame's
    side middles are brighter than its corners, a frame of stars on a sky has the sky in them."""
    h, w = data.shape
    if min(h, w) < 64:
        return None
    m = 8
    r, c = h // 2 - m // 2, w // 2 - m // 2
    sides = ((r, 0), (r, w - m)) if w >= h else ((0, c), (h - m, c))
    corners = ((0, 0), (0, w - m), (h - m, 0), (h - m, w - m))
    rim = np.empty((6, m, m))
    for i, (y, x) in enumerate(corners + sides):
        rim[i] = data[y:y + m, x:x + m]
    means = rim.mean(axis=(1, 2))
    centre = _median(data[h // 2 - 2 * m:h // 2 + 2 * m, w // 2 - 2 * m:w // 2 + 2 * m])
    sigma = math.sqrt(float(rim.var()) + 1.0 / 12.0)  # a pixel's, with the ADU's rounding
    if (means.max() - means.min() > _RIM_ALIKE * sigma / m
            or centre - means.mean() < _CORNER_SIGMA * sigma / (m * math.sqrt(6.0))):
        return None
    return float(np.median(means)), centre


def _median(block: np.ndarray) -> float:
    """``np.median`` of a small block, without importing ``numpy.ma`` (which ``np.median``
    does on its first call: 15–30 ms of a process's first solve, this check being its only
    median)."""
    flat = np.asarray(block).ravel()
    k = flat.size // 2
    part = np.partition(flat, [k - 1, k])
    return float(np.mean(part[k:k + 1] if flat.size % 2 else part[k - 1:k + 1]))


def _blocks(data: np.ndarray, b: int) -> np.ndarray:
    """Block means of ``data`` (b × b blocks; the ragged right and bottom edges left out)."""
    h, w = (data.shape[0] // b) * b, (data.shape[1] // b) * b
    return data[:h, :w].reshape(h // b, b, w // b, b).mean(axis=(1, 3), dtype=np.float64)


def _fit_circle(points: np.ndarray) -> tuple[float, float, float]:
    """Kåsa's least-squares circle through ``points`` (N, 2): centre and radius."""
    x, y = points[:, 0], points[:, 1]
    M = np.stack([x, y, np.ones_like(x)], axis=1)
    sol, *_ = np.linalg.lstsq(M, x * x + y * y, rcond=None)
    cx, cy = sol[0] / 2.0, sol[1] / 2.0
    return cx, cy, math.sqrt(max(sol[2] + cx * cx + cy * cy, 0.0))


def _outline(region: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rows and columns of a region's extreme blocks: the first and last of each row and of
    each column (its convex hull's vertices are among them)."""
    rows, cols = [], []
    for axis in (0, 1):
        any_ = region.any(axis=axis)
        idx = np.flatnonzero(any_)
        first = np.argmax(region, axis=axis)[idx]
        last = region.shape[axis] - 1 - np.argmax(np.flip(region, axis=axis), axis=axis)[idx]
        for edge in (first, last):
            if axis == 0:  # along columns: edge is a row
                rows.append(edge)
                cols.append(idx)
            else:
                rows.append(idx)
                cols.append(edge)
    return np.concatenate(rows), np.concatenate(cols)


def find_image_circle(data: np.ndarray) -> ImageCircle | None:
    """The image circle of an all-sky frame (the module text's steps), or None when ``data``
    (H, W) is not one."""
    data = np.asarray(data)
    if data.ndim != 2:
        return None
    levels = _corner_test(data)
    if levels is None:
        return None
    from scipy.ndimage import label
    from scipy.spatial import ConvexHull, QhullError

    dark, centre = levels
    h, w = data.shape
    b = max(1, math.ceil(max(h, w) / _GRID_CELLS))
    grid = _blocks(data, b)
    lit = grid > dark + 0.5 * (centre - dark)
    regions, n = label(lit)
    if n == 0:
        return None
    sizes = np.bincount(regions.ravel())[1:]
    region = regions == 1 + int(np.argmax(sizes))
    rows, cols = _outline(region)
    # the outline blocks' corners, in pixels
    pts = np.concatenate([np.stack([cols * b + dx, rows * b + dy], 1) for dx in (-0.5, b - 0.5)
                          for dy in (-0.5, b - 0.5)]).astype(np.float64)
    try:
        hull = pts[ConvexHull(pts).vertices]
    except QhullError:
        return None
    gh, gw = grid.shape
    inner = ((hull[:, 0] > b) & (hull[:, 0] < gw * b - 1.5 * b)
             & (hull[:, 1] > b) & (hull[:, 1] < gh * b - 1.5 * b))
    hull = hull[inner]
    if len(hull) < 8:
        return None
    cx, cy, radius = _fit_circle(hull)
    for _ in range(3):
        keep = np.hypot(hull[:, 0] - cx, hull[:, 1] - cy) > radius - 2.0 * b
        if keep.sum() < 8 or keep.all():
            break
        hull = hull[keep]
        cx, cy, radius = _fit_circle(hull)
    if not (2.0 * radius >= MIN_FILL * min(h, w) and 0 <= cx < w and 0 <= cy < h):
        return None
    return ImageCircle(float(cx), float(cy), float(radius), dark, centre)


def sky_mask(data: np.ndarray, circle: ImageCircle, margin_share: float = 0.01) -> np.ndarray:
    """The pixels (H, W) bool of ``data`` to find stars in: inside ``circle`` less
    ``margin_share`` of its radius, and not in or next to a dark or textured block (the module
    text)."""
    from scipy.ndimage import binary_dilation, median_filter

    data = np.asarray(data)
    h, w = data.shape
    b = max(2, math.ceil(max(h, w) / _GRID_CELLS) * 2)  # blocks of ≥ 2 px, for their scatter
    mean = _blocks(data, b)
    scatter = np.sqrt(np.maximum(_blocks(np.asarray(data, dtype=np.float64) ** 2, b) - mean**2, 0.0))
    gh, gw = mean.shape
    yc = (np.arange(gh) + 0.5) * b - 0.5
    xc = (np.arange(gw) + 0.5) * b - 0.5
    r = np.hypot(xc[None, :] - circle.cx, yc[:, None] - circle.cy)
    inside = r < circle.radius
    central = r < 0.5 * circle.radius
    sky_scatter = float(np.median(scatter[central])) if central.any() else float(np.median(scatter[inside]))
    dark = mean < circle.dark_level + _DARK_SHARE * (circle.sky_level - circle.dark_level)
    textured = median_filter(scatter, size=3) > _TEXTURE_RATIO * max(sky_scatter, 1e-9)
    bad = binary_dilation((dark | textured) & inside, np.ones((3, 3), bool))
    good = np.repeat(np.repeat(~bad, b, axis=0), b, axis=1)
    full = np.zeros((h, w), dtype=bool)
    full[:good.shape[0], :good.shape[1]] = good
    yy, xx = np.ogrid[0:h, 0:w]
    full &= (xx - circle.cx) ** 2 + (yy - circle.cy) ** 2 < (circle.radius * (1.0 - margin_share)) ** 2
    return full
