"""Text burned into a frame — a photograph's caption, a camera's time stamp, a watermark — found
among the detections so that its letters do not take the brightest stars' places.

A line of text is a chain of detections side by side — each letter within a few letter sizes
of the next along the row and at nearly the same height — that are alike and not star-like:
their peaks within a factor of 3 of each other (one ink, one font), and most of them elongated
(median axis ratio ≥ 1.4: most letters are strokes) or clipped at the frame's white. A compact
cluster can line up stars as closely (the Pleiades on a 512-pixel wide-field frame put six in a
chain), but their brightness spans magnitudes and they are round.
"""

from __future__ import annotations

import numpy as np

from skyfix.detect.centroids import Centroids

__all__ = ["MIN_LETTERS", "text_like"]

MIN_LETTERS = 6
"""Detections in a chain before it is taken for text."""
_ALONG = 3.0  # letters' centres within this many footprint sizes of each other along the row
_ACROSS = 0.6  # and within this many across it (descenders, capitals)
_FLAT = 3.0  # a line is at least this many times longer than it is tall
_PEAK_SPREAD = 3.0  # its letters' peaks: 90th percentile / 10th at most this
_ELONGATED = 1.4  # median axis ratio of a line of letters at least this (or most clipped)


def text_like(centroids: Centroids) -> np.ndarray:
    """Which detections belong to a horizontal line of text (boolean, one per detection).

    Detections ``i`` and ``j`` are linked when ``|x_i − x_j| ≤ 3 s + 2`` and ``|y_i − y_j| ≤ 0.6 s
    + 1`` px, ``s`` the larger of their footprints' sizes (√area); a linked group of at least
    :data:`MIN_LETTERS` whose width is at least 3 times its height, its height no more than 2
    footprint sizes (median), is a line of text when its members are alike and not star-like
    (the module text: peaks within a factor of :data:`_PEAK_SPREAD`, median elongation at least
    :data:`_ELONGATED` or most of them saturated).
    """
    n = len(centroids)
    out = np.zeros(n, bool)
    if n < MIN_LETTERS:
        return out
    xy = centroids.xy
    size = np.sqrt(np.maximum(centroids.area, 1.0))
    i, j = _row_neighbours(xy[:, 1], _ACROSS * float(size.max()) + 1.0)
    if len(i) < MIN_LETTERS - 1:
        return out
    s = np.maximum(size[i], size[j])
    d = np.abs(xy[i] - xy[j])
    linked = (d[:, 0] <= _ALONG * s + 2.0) & (d[:, 1] <= _ACROSS * s + 1.0)
    if np.count_nonzero(linked) < MIN_LETTERS - 1:
        return out
    label = _components(n, i[linked], j[linked])
    counts = np.bincount(label)
    for group in np.flatnonzero(counts >= MIN_LETTERS):
        members = label == group
        width = np.ptp(xy[members, 0])
        height = np.ptp(xy[members, 1])
        line = width >= _FLAT * max(height, 1.0) and height <= 2.0 * float(np.median(size[members])) + 2.0
        p10, p90 = np.percentile(centroids.peak[members], [10.0, 90.0])
        alike = p90 <= _PEAK_SPREAD * max(p10, 1e-12)
        letters = (np.median(centroids.elongation[members]) >= _ELONGATED
                   or np.mean(centroids.saturated[members]) >= 0.5)
        if line and alike and letters:
            out |= members
    return out


def _row_neighbours(y: np.ndarray, dy: float) -> tuple[np.ndarray, np.ndarray]:
    """Every pair ``(i, j)``, ``i ≠ j`` once, with ``|y_i − y_j| ≤ dy`` (a sweep over the rows)."""
    order = np.argsort(y, kind="stable")
    ys = y[order]
    first = np.arange(len(ys))
    count = np.searchsorted(ys, ys + dy, side="right") - first - 1
    total = int(count.sum())
    a = np.repeat(first, count)
    b = a + 1 + (np.arange(total) - np.repeat(np.cumsum(count) - count, count))
    return order[a], order[b]


def _components(n: int, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Connected components of ``n`` nodes linked by the pairs ``(i, j)``: each node's label is the
    smallest node number in its component (labels spread along the links until none changes;
    a few rounds for the short chains here)."""
    label = np.arange(n)
    while True:
        low = np.minimum(label[i], label[j])
        before = label.copy()
        np.minimum.at(label, i, low)
        np.minimum.at(label, j, low)
        label = label[label]  # jump to the label's own label
        if np.array_equal(label, before):
            return label
