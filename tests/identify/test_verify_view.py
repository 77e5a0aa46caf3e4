"""identify.common.verify.stars_in_view reads only the sky cells that can hold a star in the frame (the
frame's cone and edge planes, with identification's k1 = 0): it must still return exactly the stars
a brute-force projection of the whole catalogue puts in the frame."""

from __future__ import annotations

import numpy as np
import pytest

from skyfix.analysis.synthetic_centroids import random_attitudes
from skyfix.identify.catalogue.kernel_data import ViewBuffers
from skyfix.identify.common.verify import star_limit, stars_in_view

# (horizontal FOV deg, width, height, frame offset px): 2-90 deg, the principal point off centre
FRAMES = [(2.0, 1280, 960, 0.0), (4.0, 640, 480, 100.0), (15.0, 1280, 960, -200.0), (30.0, 1024, 1024, 0.0),
          (60.0, 1280, 960, 50.0), (90.0, 1920, 1080, 0.0)]


def _brute_force(vectors: np.ndarray, A: np.ndarray, f: float, frame: np.ndarray) -> np.ndarray:
    """Indices of the stars ``vectors`` projects into ``frame`` (pinhole offsets x = f x_n)."""
    b = vectors @ A.T
    front = b[:, 2] > 1e-6
    z = np.where(front, b[:, 2], 1.0)
    x, y = f * b[:, 0] / z, f * b[:, 1] / z
    inside = front & (x >= frame[0]) & (x <= frame[1]) & (y >= frame[2]) & (y <= frame[3])
    return np.flatnonzero(inside)


@pytest.mark.parametrize("fov, width, height, offset", FRAMES)
def test_stars_in_view_matches_brute_force(database, fov, width, height, offset):
    stars = database.star_index()
    vectors = np.asarray(stars.vectors, dtype=np.float64)
    f = (width / 2.0) / np.tan(np.radians(fov) / 2.0)
    dy = -offset / 2
    frame = np.array([-width / 2 + offset, width / 2 + offset, -height / 2 + dy, height / 2 + dy])
    view = ViewBuffers(np.empty(8192, dtype=np.int64), np.empty(8192), np.empty(8192),
                       np.zeros(60, dtype=np.bool_), np.empty(8192, dtype=np.int64))
    n_checked = n_stars = 0
    for n_cat in (15, 60):  # the verification's quick and full depths
        limit = star_limit(len(vectors), n_cat, frame, f, 2.0)
        for A in random_attitudes(40, np.random.default_rng(int(fov) + n_cat)):
            n = stars_in_view(A, f, 0.0, frame, limit, stars, view)
            want = _brute_force(vectors[:limit], A, f, frame)
            np.testing.assert_array_equal(view.index[:n], want)  # the same stars, brightest first
            assert np.all(view.x_px[:n] >= frame[0]) and np.all(view.x_px[:n] <= frame[1])
            n_checked += 1
            n_stars += n
    assert n_checked == 80
    assert n_stars > 80 * 4  # the frames hold stars: the comparison is not of empty sets
