"""Sky coverage and the seeds' catalogue tools (skyfix.analysis.coverage) against thesis 004 ch. 5.

The pinned numbers come from 10⁶ pointings (``skyfix analyze coverage --fov 11.17,8.32
--brightest 5026 --n 1000000``: P(<3) = 0.00536 ± 0.00007, mean 11.287, max 53); the tests
draw 10⁵ and allow four of their standard errors.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from typer.testing import CliRunner

from skyfix.analysis import coverage as cv
from skyfix.errors import InputError
from skyfix.geometry import attitude_from_radec_roll, radec_to_vector


@pytest.fixture(scope="module")
def catalog():
    return cv.coverage_catalog(6.5)


@pytest.fixture(scope="module")
def thesis_catalog(catalog):
    return catalog.brighter_than(cv.limit_for_count(catalog, cv.THESIS_004_CATALOG_SIZE))


def test_rectangle_test_exact_on_hand_made_stars():
    # camera at RA 0, Dec 0, roll 0; stars just inside / outside each edge and corner
    A = attitude_from_radec_roll(0.0, 0.0, 0.0)
    w, h = 10.0, 6.0
    tw, th = math.tan(math.radians(w / 2)), math.tan(math.radians(h / 2))
    cam = []
    for sx, sy in [(0.999, 0), (1.001, 0), (0, 0.999), (0, 1.001), (0.999, 0.999), (1.001, 0.5),
                   (-0.999, -0.999), (-0.5, -1.001)]:
        cam.append([sx * tw, sy * th, 1.0])
    cam = np.array(cam) / np.linalg.norm(cam, axis=1, keepdims=True)
    icrs = cam @ A  # b = A r  ->  r = A^T b
    field, star = cv.stars_in_fields(icrs, A[None], w, h)
    assert field.tolist() == [0, 0, 0, 0]
    assert star.tolist() == [0, 2, 4, 6]
    # the same stars behind the camera are never in view
    assert len(cv.stars_in_fields(-icrs, A[None], w, h)[0]) == 0


def test_thesis_004_star_statistics(thesis_catalog):
    n = 100_000
    counts = cv.star_counts(11.17, 8.32, 7.0, n, seed=3, catalog=thesis_catalog)
    assert counts.n_catalog == 5026
    se = counts.standard_error(0.0054)  # 2.3e-4
    assert abs(counts.p_lt3 - 0.00536) < 4 * se
    assert abs(counts.p_lt3 - 0.0056) < 0.0012  # thesis 004 §5.1: 0.0056
    assert abs(counts.p_lt4 - 0.0188) < 4 * counts.standard_error(0.0188)
    assert abs(counts.mean - 11.287) < 0.1
    assert 42 <= counts.max <= 56  # thesis: 49 in 10⁶; skyfix 53 in 10⁶
    assert counts.probability().sum() == pytest.approx(1.0)
    assert int(counts.counts.sum()) == pytest.approx(counts.mean * n)


def test_hp_limit_is_fainter_than_v(catalog):
    # the 5,026 brightest Hipparcos stars end at Hp 6.086; Hp <= 6 holds 4,559 stars
    assert cv.limit_for_count(catalog, 5026) == pytest.approx(6.0856, abs=2e-4)
    assert len(catalog.brighter_than(6.0)) == 4559


def test_distance_table(thesis_catalog):
    table = cv.distance_table(thesis_catalog, 13.9)
    assert table.n_stars == 5026
    assert table.n_pairs == 212_971  # thesis 004: 288,464 (docs/coverage.md: why)
    assert np.all(np.diff(table.angle_rad) >= 0)
    assert table.angle_rad[0] >= math.radians(0.25) and table.angle_rad[-1] <= math.radians(13.9)
    # the angles are the stars' true angles
    v = thesis_catalog.vectors
    k = np.arange(0, table.n_pairs, 997)
    truth = np.arccos(np.clip(np.sum(v[table.first[k]] * v[table.second[k]], axis=1), -1, 1))
    assert np.max(np.abs(truth - table.angle_rad[k])) < 1e-9
    # every pair within the range is in the table: count by brute force on a 300-star subset
    sub = thesis_catalog.subset(np.arange(300))
    d = np.degrees(np.arccos(np.clip(sub.vectors @ sub.vectors.T, -1, 1)))
    iu = np.triu_indices(300, 1)
    assert cv.distance_table(sub, 13.9).n_pairs == int(np.sum((d[iu] >= 0.25) & (d[iu] <= 13.9)))
    with pytest.raises(InputError):
        cv.distance_table(sub, 0.1)


def test_sub_catalogue_cone_any_roll(thesis_catalog):
    # boresight within 10° of (RA 100°, Dec +20°), any roll: the stars are within 10° + the
    # half-diagonal of the axis, and nearly all of them (the lattice leaves ragged edges)
    axis = radec_to_vector(math.radians(100.0), math.radians(20.0))
    A = cv.cone_attitudes(axis, 10.0, step_deg=1.0)
    sub = cv.sub_catalogue(thesis_catalog, A, 11.17, 8.32, 7.0)
    reach = 10.0 + math.degrees(cv.half_diagonal_rad(11.17, 8.32))
    sep = np.degrees(np.arccos(np.clip(sub.vectors @ axis, -1, 1)))
    assert sep.max() <= reach + 1e-6
    in_reach = len(thesis_catalog.cone(axis, math.radians(reach)))
    assert 0.97 * in_reach <= len(sub) <= in_reach
    # inside the cone of boresights plus the inscribed half-height, every star is seen
    inner = thesis_catalog.cone(axis, math.radians(10.0 + 8.32 / 2 - 0.5))
    assert set(thesis_catalog.ids[inner]) <= set(sub.ids)


def test_sunsat_two_week_sub_catalogue(thesis_catalog):
    # thesis 004 Table 5-2 (two weeks): 113 stars; skyfix's 5,026-star equivalent: 132 at the
    # default 2°/5° steps, 129 at ω′ steps of 10° (the steps' ragged edge: a few stars)
    A = cv.sunsat_attitudes(cv.TABLE_5_2, 2.0, 10.0)
    boresight_dec = np.degrees(np.arcsin(A[:, 2, 2]))
    assert abs(np.median(boresight_dec) - 7.0) < 0.5  # i = 97° puts the field at Dec +7°
    sub = cv.sub_catalogue(thesis_catalog, A, 11.17, 8.32, 7.0)
    assert len(sub) == 129


def test_cli_coverage_json():
    import json

    from skyfix.cli import app

    res = CliRunner().invoke(app, ["analyze", "coverage", "--fov", "11.17,8.32", "--brightest", "5026",
                                   "--n", "20000", "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output.strip().splitlines()[-1])
    assert out["n_catalog"] == 5026 and out["n_pointings"] == 20000
    assert abs(out["p_lt3"] - 0.00536) < 4 * out["p_lt3_stderr"] + 1e-4
    bad = CliRunner().invoke(app, ["analyze", "coverage", "--fov", "11,x", "--mag", "6"])
    assert bad.exit_code == 2 and "not W,H" in bad.output


def test_bad_input_one_line(catalog):
    for args, match in [((11.0, 8.0, float("nan"), 10), "not a number"),
                        ((0.0, 8.0, 6.0, 10), "field of view"),
                        ((11.0, 8.0, 6.0, 0), "n_pointings")]:
        with pytest.raises(InputError, match=match):
            cv.star_counts(*args, catalog=catalog)
    with pytest.raises(InputError):
        cv.limit_for_count(catalog, len(catalog) + 1)
    # no star brighter than the limit: every field empty, not an error
    empty = cv.star_counts(11.0, 8.0, -5.0, 100, catalog=catalog)
    assert empty.n_catalog == 0 and empty.max == 0 and empty.p_lt3 == 1.0
