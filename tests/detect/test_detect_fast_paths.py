"""The extractor's fast paths give the same stars as the plain ones.

Integer frames skip the float32 copy, the background samples the smoothed frame only on its
lattice, the medians use a branch-free quickselect with a guessed first pivot, and non-finite
pixels are found during the fused smoothing pass. Each must give the numbers of the direct
computation.
"""

from __future__ import annotations

import numpy as np
import pytest

from skyfix.detect import extract_centroids
from skyfix.detect._grid import GridWeights, SkyGrid, interp_weights
from skyfix.detect._stats import median_inplace
from skyfix.detect.background import estimate_background, is_integer_valued, median_of, smooth3


def _star_field(seed: int = 3, h: int = 240, w: int = 320, n: int = 25) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian stars (σ = 1.2 px) on a sloped sky with Poisson-like noise, uint16, and their truth."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    img = 300.0 + 80.0 * xx / w + rng.normal(0.0, 6.0, (h, w))
    xy = np.column_stack([rng.uniform(8, w - 8, n), rng.uniform(8, h - 8, n)])
    for (x0, y0), f in zip(xy, 10 ** rng.uniform(3.3, 4.5, n), strict=True):
        img += f / (2 * np.pi * 1.44) * np.exp(-((xx - x0) ** 2 + (yy - y0) ** 2) / (2 * 1.44))
    return np.clip(np.round(img), 0, 4095).astype(np.uint16), xy


def _same(a, b) -> None:
    assert len(a) == len(b) > 0
    np.testing.assert_allclose(a.xy, b.xy, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.flux, b.flux, rtol=1e-9)
    np.testing.assert_array_equal(a.saturated, b.saturated)


@pytest.mark.parametrize("dtype", [np.uint16, np.uint8])
def test_integer_frames_match_float32(dtype):
    img, truth = _star_field()
    if dtype == np.uint8:
        img = np.clip(img // 16, 0, 255).astype(np.uint8)
    a, b = extract_centroids(img), extract_centroids(img.astype(np.float32))
    _same(a, b)
    assert a.meta["saturation"] == b.meta["saturation"]
    # and the stars are the real ones
    d = np.hypot(*(a.xy[:, None, :] - truth[None, :, :]).transpose(2, 0, 1)).min(axis=1)
    assert np.median(d) < 0.1


def test_background_on_lattice_matches_full_smoothing():
    img = _star_field()[0].astype(np.float32)
    lattice = estimate_background(img)
    full = estimate_background(img, smoothed=smooth3(img))
    for name in ("level", "noise", "level_smooth", "noise_smooth"):
        np.testing.assert_allclose(getattr(lattice, name), getattr(full, name), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("where", ["on_lattice", "off_lattice"])
def test_nan_pixel_same_as_replaced(where):
    img = _star_field()[0].astype(np.float32)
    bad = img.copy()
    y, x = (60, 61) if where == "on_lattice" else (5, 3)
    bad[y, x] = np.nan
    fixed = img.copy()
    fixed[y, x] = np.median(img[np.isfinite(bad)])  # what skyfix.io.as_image puts there
    _same(extract_centroids(bad), extract_centroids(fixed))


def test_all_nan_and_inf_frames_are_empty():
    assert len(extract_centroids(np.full((50, 60), np.nan, np.float32))) == 0
    img = _star_field()[0].astype(np.float32)
    img[:200] = np.inf  # more than half non-finite: unusable
    assert len(extract_centroids(img)) == 0


@pytest.mark.parametrize("kind", ["normal", "ties", "constant", "two_values"])
@pytest.mark.parametrize("n", [1, 2, 7, 100, 121])
def test_median_inplace_matches_numpy(kind, n):
    rng = np.random.default_rng(n)
    v = {"normal": rng.normal(size=n), "ties": np.round(rng.normal(size=n) * 2) / 16,
         "constant": np.full(n, 3.25), "two_values": rng.integers(0, 2, n).astype(float)}[kind]
    for guess in (np.nan, 0.0, float(np.median(v)), 1e9, -1e9):
        a = v.copy()
        med = median_inplace(a, n, guess)
        assert med == np.median(v)
        # below index n//2 lie values ≤ the median (the noise estimate relies on it)
        assert np.all(a[: n // 2] <= med)
        assert sorted(a) == sorted(v)


def test_median_terminates_on_nan():
    v = np.array([1.0, np.nan, 3.0, np.nan, 2.0])
    median_inplace(v.copy(), v.size)
    median_inplace(v.copy(), v.size, 2.0)


def test_interp_weights_and_helpers_match_numpy():
    for n, m in [(507, 16), (960, 16), (1280, 21), (5, 1), (100, 3), (7, 7)]:
        edges = np.linspace(0, n, m + 1).round()
        centers = 0.5 * (edges[:-1] + edges[1:]) - 0.5
        pos = np.arange(n, dtype=np.float64)
        if m == 1:
            i0, f0 = np.zeros(n, np.int64), np.zeros(n, np.float32)
        else:
            i0 = np.clip(np.searchsorted(centers, pos, side="right") - 1, 0, m - 2)
            f0 = ((pos - centers[i0]) / (centers[i0 + 1] - centers[i0])).astype(np.float32)
        i1, f1 = interp_weights(centers, n)
        np.testing.assert_array_equal(i0, i1)
        np.testing.assert_array_equal(f0, f1)
    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 336):
        v = rng.normal(size=(n,))
        assert median_of(v) == np.median(v)
    grid = np.arange(12.0).reshape(3, 4)
    assert is_integer_valued(grid) and not is_integer_valued(grid + 0.5)
    assert is_integer_valued(grid.astype(np.uint16))
    grid[0, 0] = np.nan
    assert not is_integer_valued(grid)


@pytest.mark.parametrize("density", [0.05, 0.3, 0.6])
def test_run_labelling_matches_scipy(density):
    """Labels of the run-based labelling equal scipy's 8-connected ones (raster-order numbering)."""
    from scipy import ndimage

    from skyfix.detect.labelling import Frames, label_components

    rng = np.random.default_rng(int(density * 100))
    h, w = 61, 150  # not a multiple of the 64-pixel blocks
    on = rng.random((h, w)) < density
    mask = np.zeros((h, 192), np.uint8)
    mask[:, :w] = on
    blocks = mask.reshape(h, 3, 64).any(axis=2).astype(np.uint8)
    sm = rng.normal(size=(h, w)).astype(np.float32)
    img = rng.normal(size=(h, w)).astype(np.float32)
    grid = np.zeros((2, 3))
    iy, fy = interp_weights(np.array([15.0, 45.0]), h)
    ix, fx = interp_weights(np.array([25.0, 75.0, 125.0]), w)
    ref, n = ndimage.label(on, structure=np.ones((3, 3), int))
    for cap in (1 << 16, max(n // 3, 1)):
        labels = np.zeros((h, w), np.int32)
        sky = SkyGrid(grid, grid, grid, grid, np.array([15.0, 45.0]), np.array([25.0, 75.0, 125.0]),
                      GridWeights(iy, fy, ix, fx))
        comps = label_components(img, Frames(sm, mask, blocks, labels), sky, cap)
        expect = np.where(ref <= cap, ref, 0)
        np.testing.assert_array_equal(labels, expect)
        assert comps.size == min(n, cap)
        for k, comp in enumerate(comps):
            ys, xs = np.nonzero(ref == k + 1)
            assert comp["area"] == ys.size
            box = (ys.min(), ys.max(), xs.min(), xs.max())
            assert (comp["y0"], comp["y1"], comp["x0"], comp["x1"]) == box
            excess = float(sm[ys, xs].astype(np.float64).sum())
            assert comp["excess"] == pytest.approx(excess, rel=1e-9, abs=1e-9)
            assert comp["peak"] == img[ys, xs].max()


def test_converted_frames_go_to_one_reused_buffer():
    """8/16-bit and float64 frames are converted into the thread's one float32 buffer (a fresh
    multi-megabyte array a call faulted its pages in every time), with astype's values, and
    give the stars their float32 copies give."""
    from skyfix.detect.components import float32_frame

    u16, _ = _star_field()
    a = float32_frame(u16)
    b = float32_frame((u16 // 2).astype(np.float64))
    assert a is b and a.dtype == np.float32 and a.flags.c_contiguous
    np.testing.assert_array_equal(b, (u16 // 2).astype(np.float32))
    f32 = u16.astype(np.float32)
    assert float32_frame(f32) is f32  # already float32: as it is
    ref = extract_centroids(f32)
    for frame in (u16, u16.astype(np.float64), np.asfortranarray(u16)):
        c = extract_centroids(frame)
        assert len(c) == len(ref) > 10
        for col in ("x", "y", "flux", "snr"):
            np.testing.assert_array_equal(getattr(c, col), getattr(ref, col))


def test_run_count_is_exact():
    """The labelling sizes its run tables by counting the runs of set pixels (words of 8 mask
    bytes): the count equals the number of 0 → 1 steps along the rows."""
    from skyfix.detect.labelling import _count_runs

    rng = np.random.default_rng(5)
    for _ in range(300):
        h, w = int(rng.integers(1, 12)), int(rng.integers(1, 200))
        mask = np.zeros((h, (w + 63) // 64 * 64), np.uint8)
        mask[:, :w] = rng.random((h, w)) < rng.random()
        blocks = mask.reshape(h, -1, 64).any(axis=2).astype(np.uint8)
        steps = np.diff(mask[:, :w].astype(np.int8), axis=1, prepend=0) == 1
        assert _count_runs(mask, blocks) == int(steps.sum())


@pytest.mark.parametrize("bad", [0.5, np.nan, np.inf, -np.inf])
def test_whole_number_test_on_the_sample_lattice(bad):
    """A frame is integer-valued when every sample of its 7 × 5 lattice is a whole number; one
    fractional, NaN or infinite sample says no, one off the lattice is not seen."""
    frame = np.round(np.random.default_rng(2).normal(500, 30, (50, 61))).astype(np.float32)
    assert is_integer_valued(frame)
    on, off = frame.copy(), frame.copy()
    on[42, 55] = bad  # row 42 = 6·7, column 55 = 11·5
    off[43, 55] = bad
    assert not is_integer_valued(on)
    assert is_integer_valued(off)


def test_kept_grid_weights_give_the_same_stars_as_fresh_ones():
    from skyfix.detect import _grid

    img, _ = _star_field(seed=9)
    _grid._WEIGHTS.clear()
    fresh = extract_centroids(img)
    assert len(_grid._WEIGHTS) == 1  # the background and the extractor's sky share one tiling
    kept = extract_centroids(img)
    np.testing.assert_array_equal(kept.xy, fresh.xy)
    np.testing.assert_array_equal(kept.flux, fresh.flux)
    cy, cx = np.array([10.0, 30.0]), np.array([5.0, 25.0, 45.0])
    w = _grid.grid_weights(cy, cx, (40, 50))
    assert _grid.grid_weights(cy.copy(), cx.copy(), (40, 50)) is w  # same tiling: the kept arrays
    assert _grid.grid_weights(cy, cx, (41, 50)) is not w
    np.testing.assert_array_equal(w.fy, _grid.interp_weights(cy, 40)[1])
