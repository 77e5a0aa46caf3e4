"""Hipparcos catalogue: contents, proper motion, cone search, thinning."""

import numpy as np
import pytest

from skyfix.catalog import load_hipparcos
from skyfix.geometry import angle_between, radec_to_vector

ARCSEC = np.radians(1 / 3600)


@pytest.fixture(scope="module")
def hip():
    return load_hipparcos(epoch=1991.25)


def test_catalogue_size_and_order(hip):
    assert len(hip) == 117955
    assert np.all(np.diff(hip.mag) >= 0)
    assert hip.ids[0] == 32349  # Sirius is the brightest


def test_bright_star_counts(hip):
    # Thesis 000 quotes BSC counts 170 < 3.0 and 513 < 4.0 (V); Hp is a little fainter than V
    # for red stars, so the Hipparcos Hp counts are of the same size but not equal.
    assert 140 < np.sum(hip.mag < 3.0) < 200
    assert 440 < np.sum(hip.mag < 4.0) < 560


def test_proper_motion_barnards_star():
    # Barnard's star (HIP 87937) moves 10.3″/yr; 35 years move it about 6′.
    a = load_hipparcos(epoch=1991.25, mag_limit=10)
    b = load_hipparcos(epoch=2026.25, mag_limit=10)
    i = np.flatnonzero(a.ids == 87937)[0]
    moved = angle_between(a.vectors[i], b.vectors[i]) / ARCSEC
    assert moved == pytest.approx(10.36 * 35, rel=0.01)


def test_cone_search_matches_brute_force(hip):
    c = radec_to_vector(np.radians(83.8), np.radians(-5.4))
    idx = hip.cone(c, np.radians(5))
    brute = np.flatnonzero(angle_between(hip.vectors, c) <= np.radians(5))
    np.testing.assert_array_equal(idx, brute)


def test_thinning_evens_density(hip):
    thin = hip.brighter_than(8).thinned(3000, 4)
    assert len(thin) <= 3000 * 4
    assert len(thin) > 0.9 * 3000 * 4  # nearly every cell has 4 stars to mag 8
    assert np.all(np.diff(thin.mag) >= 0)
