"""Wide searches with no camera (:mod:`skyfix.identify.methods.quad`): the equidistant hypothesis and the
central stars' patterns first. Frames of the field campaign that the searches found only after
1400–3400 image patterns, or not in 4000 (the 90° fisheye's under the cubic distortion
hypotheses; 45° and 60° frames of k1 −0.3 in brightness order), are found within 300, with the
right attitude."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from skyfix.analysis.field_campaign import CASES, case_camera
from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
from skyfix.analysis.truth import attitude_error_rad
from skyfix.catalog import load_gaia
from skyfix.identify import identify
from skyfix.identify.catalogue.bands import WIDE, band_database
from skyfix.identify.common.search import breadth_first_combinations, centre_first_combinations

# (case name, frame) of the field campaign (seed 1, 100 attitudes a case) -> the image patterns a
# search had looked up when it found the frame before (None: not found in 4000).
LATE = {("90° fisheye", 54): None, ("90° fisheye", 72): 3388, ("90° fisheye", 44): 3183,
        ("90° fisheye", 49): 2467, ("45°, k1 −0.3", 9): 1435, ("60°, k1 −0.3", 40): 1440}


@pytest.fixture(scope="module")
def frames():
    """The LATE frames: (camera, centroids, true attitude), drawn as field_trials(case, 100, seed=1)."""
    catalog = load_gaia(epoch=2025.0)
    out = {}
    for case in CASES:
        wanted = {k for name, k in LATE if name == case.name}
        if not wanted:
            continue
        camera = case_camera(case)
        rng = np.random.default_rng(1)
        for k, A in enumerate(random_attitudes(100, rng)):
            n_false = int(rng.integers(0, case.max_false + 1))
            field = synthetic_centroids(camera, A, catalog, mag_limit=case.mag_limit, sigma_px=case.sigma_px,
                                        n_false=n_false, dropout=case.dropout, mag_sigma=case.mag_sigma,
                                        rng=rng)
            if k in wanted:
                out[case.name, k] = (camera, field.xy[:200], A)
            if k >= max(wanted):
                break
    return out


@pytest.mark.parametrize("frame", sorted(LATE), ids=lambda f: f"{f[0]}-{f[1]}")
def test_late_wide_frames_are_found_early(frames, frame):
    camera, xy, A_true = frames[frame]
    ident = identify(xy, camera.width, camera.height, database=band_database(WIDE), max_patterns=300,
                     time_limit_s=30.0, epoch=2025.0)
    assert ident.success, ident.reason
    # identification's camera is a Brown–Conrady approximation (of a fisheye, too): judged at the
    # principal point, its boresight within a pixel and its roll within a tenth of a degree
    err = attitude_error_rad(ident.A_icrs_to_cam, ident.camera, A_true, camera)
    assert math.hypot(err[0], err[1]) < camera.plate_scale_rad
    assert abs(err[2]) < math.radians(0.1)


@pytest.mark.parametrize("n", [4, 5, 11, 24])
def test_centre_first_order_interleaves_the_two_orders(n):
    rng = np.random.default_rng(n)
    base = breadth_first_combinations(n)
    for _ in range(5):
        central = rng.random(n) < 0.4
        out = centre_first_combinations(central)
        rows = {tuple(c): i for i, c in enumerate(base)}
        place = np.array([rows[tuple(c)] for c in out])
        assert sorted(place) == list(range(len(base)))  # every subset once
        # the central-first order: breadth-first over the stars renumbered central ones first
        order = np.argsort(~central, kind="stable")
        other = np.array([rows[tuple(sorted(order[c]))] for c in base])
        where_other = np.empty(len(base), int)
        where_other[other] = np.arange(len(base))
        # each subset comes at the earlier of its two places, interleaved: by 2 min(i, j) + 1
        assert np.all(np.arange(len(base)) <= 2 * np.minimum(place, where_other[place]) + 1)
        n_central = int(central.sum())
        if n_central >= 4:  # the four brightest central stars' pattern is among the first two
            first = tuple(sorted(np.flatnonzero(central)[:4]))
            assert rows[first] in place[:2]


@pytest.mark.parametrize("n", [0, 3, 4, 5, 13, 30])
def test_breadth_first_order_is_by_largest_star_then_lexicographic(n):
    expected = sorted(itertools.combinations(range(n), 4), key=lambda c: (c[3], c))
    got = breadth_first_combinations(n)
    assert got.shape == (len(expected), 4) and got.dtype == np.int64
    assert [tuple(int(v) for v in row) for row in got] == expected
