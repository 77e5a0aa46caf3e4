"""Frame-to-frame star IDs without a catalogue (skyfix.track.relative, thesis 002 §2.5)."""

from __future__ import annotations

import numpy as np
import pytest

from skyfix.errors import InputError
from skyfix.track.relative import first_ids, match_relative

PREV = np.array([[100.0, 50.0], [400.0, 80.0], [250.0, 300.0], [600.0, 310.0], [900.0, 700.0]])
PREV_IDS = np.array([1, 2, 3, 4, 5])


def test_first_ids_in_raster_order():
    xy = np.array([[500.0, 40.0], [10.0, 300.0], [20.0, 40.0], [700.0, 39.5]])
    np.testing.assert_array_equal(first_ids(xy), [3, 4, 2, 1])  # by row, then column
    np.testing.assert_array_equal(first_ids(xy, 10), [12, 13, 11, 10])
    assert first_ids(np.empty((0, 2))).shape == (0,)


def test_star_entering_and_leaving():
    """Every star moves by (+3, −2) px; star 5 leaves, two stars enter (numbered in raster
    order from next_id); the rest keep their IDs in a shuffled current order."""
    rng = np.random.default_rng(0)
    cur = np.vstack([PREV[:4] + [3.0, -2.0] + rng.normal(scale=0.2, size=(4, 2)),
                     [[800.0, 20.0], [30.0, 10.0]]])
    order = np.array([3, 5, 0, 2, 4, 1])
    m = match_relative(PREV, PREV_IDS, cur[order], gate_px=10.0, next_id=6)
    np.testing.assert_array_equal(m.ids, np.array([1, 2, 3, 4, 7, 6])[order])
    np.testing.assert_array_equal(m.new_mask, np.array([0, 0, 0, 0, 1, 1], bool)[order])
    np.testing.assert_array_equal(m.retired_ids, [5])
    assert m.next_id == 8
    assert not m.error and m.reason == ""


def test_clustered_pair_raises_the_error_flag():
    """Two current stars 3.4 px apart both nearest to previous star 3 within the gate: the error
    flag is set; the closer one keeps ID 3, the other gets a new ID."""
    cur = np.vstack([PREV[:4], [[252.0, 303.0]]])  # star 3 and a neighbour 3.6 px away
    cur[2] += [0.5, 0.0]
    m = match_relative(PREV, PREV_IDS, cur, gate_px=10.0, next_id=6)
    assert m.error and "more than one" in m.reason
    np.testing.assert_array_equal(m.ids, [1, 2, 3, 4, 6])
    np.testing.assert_array_equal(m.new_mask, [False, False, False, False, True])
    np.testing.assert_array_equal(m.retired_ids, [5])


def test_fewer_than_two_pairs_is_an_error():
    m = match_relative(PREV, PREV_IDS, PREV[:1] + 1.0, gate_px=5.0, next_id=6)
    assert m.error and "1 matched pair" in m.reason
    m = match_relative(PREV, PREV_IDS, PREV + 50.0, gate_px=5.0, next_id=6)
    assert m.error and m.new_mask.all()
    np.testing.assert_array_equal(np.sort(m.ids), [6, 7, 8, 9, 10])
    np.testing.assert_array_equal(m.retired_ids, PREV_IDS)
    m = match_relative(np.empty((0, 2)), [], PREV, gate_px=5.0, next_id=1)
    np.testing.assert_array_equal(m.ids, first_ids(PREV))  # no previous frame: first-time IDs
    assert m.error


def test_gate_is_inclusive_and_plain_distance():
    cur = PREV + [3.0, 4.0]  # 5 px exactly
    assert not match_relative(PREV, PREV_IDS, cur, gate_px=5.0, next_id=6).new_mask.any()
    assert match_relative(PREV, PREV_IDS, cur, gate_px=4.99, next_id=6).new_mask.all()


def test_tree_and_matrix_agree():
    """Above the matrix size the k-d tree answers; both equal a brute-force nearest neighbour."""
    rng = np.random.default_rng(4)
    prev = rng.uniform(0, 2000, size=(300, 2))
    ids = rng.permutation(10_000)[:300]
    cur = np.vstack([prev[:250] + rng.normal(scale=1.0, size=(250, 2)), rng.uniform(0, 2000, (40, 2))])
    m = match_relative(prev, ids, cur, gate_px=6.0, next_id=10_000)
    d2 = ((cur[:, None] - prev[None]) ** 2).sum(-1)
    nearest = d2.argmin(1)
    inside = d2.min(1) <= 36.0
    claims = np.bincount(nearest[inside], minlength=len(prev))
    assert m.error == bool((claims > 1).any())
    unique = inside & (claims[nearest] == 1)
    np.testing.assert_array_equal(m.ids[unique], ids[nearest[unique]])
    # The same question below the size limit (the matrix path).
    small = match_relative(prev[:60], ids[:60], cur[:60], gate_px=6.0, next_id=10_000)
    np.testing.assert_array_equal(small.ids, ids[:60])


def test_bad_input():
    with pytest.raises(InputError, match="one ID"):
        match_relative(PREV, PREV_IDS[:3], PREV, 5.0, 6)
    with pytest.raises(InputError, match="distinct"):
        match_relative(PREV, [1, 1, 2, 3, 4], PREV, 5.0, 6)
    with pytest.raises(InputError, match="gate"):
        match_relative(PREV, PREV_IDS, PREV, 0.0, 6)
    with pytest.raises(InputError, match="in use"):
        match_relative(PREV, PREV_IDS, PREV, 5.0, 5)
    with pytest.raises(InputError, match="finite"):
        match_relative(PREV, PREV_IDS, PREV * np.nan, 5.0, 6)
    with pytest.raises(InputError, match=r"\(N, 2\)"):
        match_relative(PREV, PREV_IDS, PREV.ravel(), 5.0, 6)
