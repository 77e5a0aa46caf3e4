"""The star gather, projection and grid matcher that refine and verification share, against
brute-force references; and refine frees k1 for a distorted camera only."""

import numpy as np
import pytest

from skyfix.camera import Camera
from skyfix.identify.catalogue.kernel_data import StarIndex, ViewBuffers
from skyfix.identify.common.verify import gather_stars, grid_index, match_greedy, match_grid, project_stars


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
    return StarIndex(v, c, start, order.astype(np.int32), radius), rng


@pytest.mark.parametrize("cone", [0.05, 0.2, 0.6])
def test_gather_stars_is_a_cone_search(sky, cone):
    stars, rng = sky
    v = stars.vectors
    found = 0
    for _ in range(20):
        z = rng.normal(size=3)
        z /= np.linalg.norm(z)
        limit = int(rng.integers(100, len(v) + 1))
        want = np.flatnonzero((v[:limit] @ z) >= np.cos(cone))
        got = gather_stars(z, cone, limit, stars)
        assert np.array_equal(got, want)
        found += len(want)
    assert found > 20


def test_project_and_match_against_brute_force(sky):
    stars, rng = sky
    v = stars.vectors
    frame = np.array([-640.0, 639.0, -480.0, 479.0])
    f, k1 = 1500.0, 1e-3
    for _ in range(20):
        A = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        near = gather_stars(A[2], 0.6, len(v), stars)
        view = ViewBuffers(np.empty(16384, np.int64), np.empty(16384), np.empty(16384), np.zeros(0, np.bool_),
                           np.empty(0, np.int64))
        n = project_stars(near, A, f, k1, frame, 60, stars, view)
        idx, x, y = view.index, view.x_px, view.y_px
        # Reference: pinhole + k1 projection in numpy, brightest first, the first 60 in frame.
        b = v[near] @ A.T
        front = b[:, 2] > 1e-6
        xn, yn = b[:, 0] / np.where(front, b[:, 2], 1), b[:, 1] / np.where(front, b[:, 2], 1)
        rad = f * (1 + k1 * (xn**2 + yn**2))
        px, py = xn * rad, yn * rad
        inside = front & (px >= frame[0]) & (px <= frame[1]) & (py >= frame[2]) & (py <= frame[3])
        keep = np.flatnonzero(inside)[:60]
        assert n == len(keep) > 10
        assert np.array_equal(idx[:n], near[keep])
        np.testing.assert_allclose(x[:n], px[keep], rtol=1e-12)
        np.testing.assert_allclose(y[:n], py[keep], rtol=1e-12)
        x, y = x[:n].copy(), y[:n].copy()
        # Centroids: the projections jittered, plus false ones, in a random order (sorted by index
        # = brightness, as the grid assumes).
        p = np.column_stack([x, y]) + rng.normal(0.0, 1.5, (n, 2))
        p = np.vstack([p, rng.uniform(frame[[0, 2]], frame[[1, 3]], (15, 2))])[rng.permutation(n + 15)]
        r = 4.0
        grid = grid_index(p, len(p), frame, 2 * r)
        for n_use in (len(p) // 2, len(p)):
            m_want, m_got = np.empty(n, np.int64), np.empty(n, np.int64)
            used = np.zeros(len(p), np.bool_)
            k_want = match_greedy(ViewBuffers(view.index, x, y, used, m_want), n, p, n_use, r)
            k_got = match_grid(ViewBuffers(view.index, x, y, used, m_got), n, p, n_use, grid, r)
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
