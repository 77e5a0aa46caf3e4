"""The final fit's catalogue cone (:class:`skyfix._rematch.CatalogueCone`): found from the sky
cells for a narrow cone and by a scan of every star for a wide one, each exactly the stars a
star tree query finds, and a limited cone the first stars of the whole one."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyfix._rematch import CatalogueCone, star_tree
from skyfix.identify.catalogue.bands import NARROW, STANDARD, band_database


@pytest.mark.parametrize("band", [NARROW, STANDARD], ids=lambda b: b.name)
def test_cone_from_the_cells_is_the_tree_query(band):
    db = band_database(band)
    tree = star_tree(db)
    rng = np.random.default_rng(3)
    sizes = []
    for k in range(40):
        axis = rng.normal(size=3)
        if k < 4:  # the poles and the equator, where the cells' z bands end or are widest
            axis = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 0.6, 0.8]][k])
        axis /= np.linalg.norm(axis)
        half = math.radians(rng.uniform(0.5, 6.0))
        index, _ = CatalogueCone(db, None).cone(axis, half)
        direct = np.sort(tree.query_ball_point(axis, 2 * math.sin(half / 2)))
        assert np.array_equal(index, direct)
        sizes.append(len(index))
    assert min(sizes) >= 1 and max(sizes) > 250  # cones of a handful to hundreds of stars


def test_a_limited_cone_is_the_first_stars_of_the_whole_one():
    db = band_database(STANDARD)
    rng = np.random.default_rng(4)
    for _ in range(10):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        index, rows = CatalogueCone(db, 2025.0).cone(axis, math.radians(12.0))
        for limit in (1, 50, len(index), len(index) + 10):
            first, first_rows = CatalogueCone(db, 2025.0).cone(axis, math.radians(12.0), limit)
            assert np.array_equal(first, index[:limit]) and np.array_equal(first_rows, rows[:limit])
