"""Windowed against full-frame centroiding time on a large frame (thesis 002 Table 5-1, its
experiment E5), for :mod:`skyfix.analysis.tracking_study` (docs/tracking-study.md).

A 2560 × 1920 frame with N stars: :func:`skyfix.detect.extract_centroids` over the whole frame
against N windows of side ROI cut from it into one small mosaic (what the tracker does) and
centroided by :func:`skyfix.detect.centroid_windows` (centre of mass over sky + 5σ). The time is
the fastest of repeated calls: what the work costs, since other processes on the machine only add
to it. No kernel here runs on more than one thread. Every timed window is checked against the
truth, and the same windows are centroided over sky + 3σ too (thesis 002's noise threshold just
above the floor): in a large window the noise pixels above it pull the centre.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np

__all__ = ["THESIS_TABLE_5_1", "TimingRow", "timing_frame", "run_timing"]

#: Thesis 002 Table 5-1 (DM355, 2560 × 1920, 5 stars): ROI px → (full frame ms, windowed ms).
THESIS_TABLE_5_1 = {40: (169.0, 3.0), 50: (103.0, 5.0), 80: (171.0, 12.0), 100: (111.0, 18.0),
                    150: (188.0, 40.0), 200: (211.0, 70.0)}


class TimingRow(NamedTuple):
    roi_px: int
    n_stars: int
    windowed_ms: float
    full_ms: float
    ratio: float                 # full / windowed
    found_windowed: int          # windows whose centroid is within 0.5 px of the truth
    found_full: int              # truth stars the full-frame extraction found within 1 px
    rms_windowed_px: float       # RMS error of the timed windows (CoM over sky + 5σ)
    rms_windowed_3sigma_px: float  # the same windows with the CoM over sky + 3σ (not timed)


def timing_frame(n_stars: int, rng: np.random.Generator, width: int = 2560, height: int = 1920,
                 margin: int = 110) -> tuple[np.ndarray, np.ndarray]:
    """A uint16 frame (sky 100 ADU, noise 5 ADU) with ``n_stars`` Gaussian stars (σ 1 px, 2 000 –
    20 000 ADU), at least ``margin`` px from the edges and 2·margin apart (a ValueError when
    they do not fit); returns the frame and the true positions (N, 2)."""
    from skyfix.analysis.centroid_study import expected_stamps

    xy: list = []
    for _ in range(100 * n_stars):
        p = rng.uniform([margin, margin], [width - margin, height - margin])
        if all(np.hypot(*(p - q)) > 2 * margin for q in xy):
            xy.append(p)
        if len(xy) == n_stars:
            break
    else:
        raise ValueError(f"{n_stars} stars {2 * margin} px apart do not fit a {width}×{height} frame")
    xy = np.array(xy)
    img = rng.normal(100.0, 5.0, (height, width))
    size, half = 16, 8
    for (x, y), flux in zip(xy, rng.uniform(2000, 20000, n_stars), strict=True):
        ix, iy = int(round(x)) - half, int(round(y)) - half
        stamp = expected_stamps(np.array([x - ix]), np.array([y - iy]), flux, 1.0, size)[0]
        img[iy:iy + size, ix:ix + size] += stamp
    return np.clip(np.round(img), 0, 65535).astype(np.uint16), xy


def _windowed(image: np.ndarray, xy_pred: np.ndarray, half: int, mosaic: np.ndarray, k_sigma: float = 5.0):
    """Cut a ``2·half`` tile around each prediction into ``mosaic`` and centroid them all at once
    (centre of mass over the pixels above sky + ``k_sigma``·σ); (x, y) in frame pixels."""
    from skyfix.detect import centroid_windows

    size = 2 * half
    h, w = image.shape
    origin = np.empty((len(xy_pred), 2), np.int64)
    for i, (x, y) in enumerate(xy_pred):
        x0 = min(max(int(round(x)) - half, 0), w - size)
        y0 = min(max(int(round(y)) - half, 0), h - size)
        mosaic[i * size:(i + 1) * size] = image[y0:y0 + size, x0:x0 + size]
        origin[i] = x0, y0
    local = xy_pred - origin + np.column_stack([np.zeros(len(xy_pred)), size * np.arange(len(xy_pred))])
    c = centroid_windows(mosaic[:len(xy_pred) * size], local, half_size=half, method="com", sigma=k_sigma)
    return c.x + origin[:, 0], c.y - size * np.arange(len(xy_pred)) + origin[:, 1]


def _fastest_ms(fn: Callable[[], object], repeats: int) -> float:
    fn()  # warm (compiled kernels, caches)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.min(times))


def run_timing(rois: Sequence[int], star_counts: Sequence[int], repeats: int = 21, seed: int = 0,
               progress: Callable[[str], None] | None = None) -> list[TimingRow]:
    """Table 5-1 (module docstring): for each star count one frame, the full-frame extraction
    timed once per frame, the windows at predictions 1 px off the truth timed per ROI."""
    from skyfix.detect import extract_centroids

    rng = np.random.default_rng(seed)
    rows = []
    for n in star_counts:
        image, xy = timing_frame(n, rng)
        full_ms = _fastest_ms(functools.partial(extract_centroids, image), max(3, repeats // 2))
        c = extract_centroids(image)
        d = np.hypot(c.x[None, :] - xy[:, :1], c.y[None, :] - xy[:, 1:])
        found_full = int(np.count_nonzero(d.min(axis=1) < 1.0)) if len(c.x) else 0
        pred = xy + rng.uniform(-1, 1, xy.shape)
        for roi in rois:
            half = roi // 2
            mosaic = np.empty((n * roi, roi), np.float32)
            ms = _fastest_ms(functools.partial(_windowed, image, pred, half, mosaic), repeats)
            x, y = _windowed(image, pred, half, mosaic)
            err = np.hypot(x - xy[:, 0], y - xy[:, 1])
            x3, y3 = _windowed(image, pred, half, mosaic, k_sigma=3.0)
            err3 = np.hypot(x3 - xy[:, 0], y3 - xy[:, 1])
            rows.append(TimingRow(int(roi), int(n), ms, full_ms, full_ms / ms, int(np.sum(err < 0.5)),
                                  found_full, float(np.sqrt(np.nanmean(err ** 2))),
                                  float(np.sqrt(np.nanmean(err3 ** 2)))))
            if progress is not None:
                progress(f"timing N={n} ROI={roi}")
    return rows
