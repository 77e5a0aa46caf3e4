"""Refine: its own kernels give exactly what the verification kernels they replace give, and k1 is
freed for a distorted camera only."""

import numpy as np
import pytest

from skyfix.camera import Camera
from skyfix.identify.refine import _gather_near, _match_quadrant, _project_near, _sorted_indices
from skyfix.identify.verify import gather_stars, grid_index, match_grid, project_stars


@pytest.fixture(scope="module")
def sky():
    """Random stars (index = brightness rank) in Fibonacci-lattice cells, like the database."""
    rng = np.random.default_rng(3)
    n_stars, n_cells = 20000, 400
    v = rng.normal(size=(n_stars, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    k = np.arange(n_cells) + 0.5
    z = 1.0 - 2.0 * k / n_cells  # decreasing z, as the database orders its cells
    phi = np.pi * (1.0 + 5.0**0.5) * k
    c = np.column_stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z])
    cell_of = np.argmax(v @ c.T, axis=1)
    order = np.lexsort((np.arange(n_stars), cell_of))
    start = np.concatenate([[0], np.cumsum(np.bincount(cell_of, minlength=n_cells))]).astype(np.int64)
    radius = float(np.max(np.arccos(np.clip(np.sum(v * c[cell_of], axis=1), -1, 1))))
    return v, c, start, order.astype(np.int32), radius, rng


def test_sorted_indices_sorts(sky):
    rng = sky[-1]
    for n, top in ((0, 0), (1, 5), (937, 117954), (3000, 2**20 - 1)):
        a = rng.integers(0, top + 1, n).astype(np.int64)
        assert np.array_equal(_sorted_indices(a, max(top, int(a.max(initial=0)))), np.sort(a))


@pytest.mark.parametrize("cone", [0.05, 0.2, 0.6])
def test_gather_near_equals_gather_stars(sky, cone):
    v, c, start, stars, radius, rng = sky
    for _ in range(20):
        z = rng.normal(size=3)
        z /= np.linalg.norm(z)
        limit = int(rng.integers(100, len(v) + 1))
        want = gather_stars(z, cone, limit, v, c, start, stars, radius)
        got = _gather_near(z, cone, limit, v, c, start, stars, radius)
        assert len(want) > 0
        assert np.array_equal(got, want)


def test_project_and_match_equal_verify_kernels(sky):
    v, c, start, stars, radius, rng = sky
    frame = np.array([-640.0, 639.0, -480.0, 479.0])
    f = 1500.0
    for _ in range(20):
        A = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        near = gather_stars(A[2], 0.6, len(v), v, c, start, stars, radius)
        outs = []
        for fn in (project_stars, _project_near):
            idx, x, y = np.empty(16384, np.int64), np.empty(16384), np.empty(16384)
            n = fn(near, A, f, 1e-3, frame, 60, v, idx, x, y)
            outs.append((idx[:n].copy(), x[:n].copy(), y[:n].copy()))
        assert len(outs[0][0]) > 10
        for a, b in zip(*outs, strict=True):
            assert np.array_equal(a, b)
        idx, x, y = outs[0]
        # Centroids: the projections jittered, some dropped, plus false ones, in a random order.
        p = np.column_stack([x, y]) + rng.normal(0.0, 1.5, (len(x), 2))
        p = np.vstack([p, rng.uniform(frame[[0, 2]], frame[[1, 3]], (15, 2))])[rng.permutation(len(x) + 15)]
        r = 4.0
        grid = grid_index(p, len(p), frame, 2 * r)
        for n_use in (len(p) // 2, len(p)):
            m_want, m_got = np.empty(len(x), np.int64), np.empty(len(x), np.int64)
            used = np.zeros(len(p), np.bool_)
            k_want = match_grid(x, y, len(x), p, n_use, frame, 2 * r, *grid, r, used, m_want)
            k_got = _match_quadrant(x, y, len(x), p, n_use, frame, 2 * r, *grid, r, used, m_got)
            assert k_want == k_got > 0
            assert np.array_equal(m_want, m_got)


def test_k1_freed_only_for_a_distorted_camera(database):
    from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
    from skyfix.catalog import load_hipparcos
    from skyfix.identify import identify

    catalog = load_hipparcos(mag_limit=8.0)
    w, h = 1280, 960
    k1s = {}
    for k1 in (0.0, -0.3):
        cam = Camera.from_fov(w, h, 20.0).replace(k1=k1)
        fitted = []
        for i, A in enumerate(random_attitudes(4, rng=7)):
            field = synthetic_centroids(cam, A, catalog, sigma_px=0.5, n_false=3, rng=i)
            res = identify(field.xy, w, h, database=database)
            assert res.success
            fitted.append(res.camera.k1)
        k1s[k1] = np.array(fitted)
    # The step test must not keep k1 from a camera that has it, nor free it for one that has not.
    assert np.all(k1s[0.0] == 0.0)
    assert np.all(np.abs(k1s[-0.3] + 0.3) < 0.06)
