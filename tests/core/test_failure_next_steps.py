"""Failures that say what to try (issue 28, part 2): a FOV hint that matches nothing is not
trusted — the frame is solved without it and the Solution says the hint was not used (or, failing
too, what both searches said and what to try); an attitude hint that fails says so beside the
lost-in-space solution, whose ``method`` says which path solved; a tiny frame says it is too small
for any star field (tests/core/test_bad_input_api.py)."""

from __future__ import annotations

import numpy as np

from skyfix import solve, solve_centroids
from tests.conftest import EXAMPLES

SKY = EXAMPLES / "sky.png"  # 17.06° wide; RA 84, Dec −2, roll 20


def _sep_arcsec(a, b) -> float:
    d = a.A_icrs_to_cam @ b.A_icrs_to_cam.T
    return float(np.degrees(np.arccos(np.clip((np.trace(d) - 1) / 2, -1, 1))) * 3600)


def test_a_wrong_fov_hint_is_not_used_and_says_so(database):
    """30° in the standard database; 100° in the default bands (the wide one serves it), as the
    CLI solves without --database. (A database given that does not serve the hint refuses it and
    says how to build one that does: tests/core/test_bad_input_api.py.)"""
    plain = solve(SKY, database=database)
    for wrong, db in ((30.0, database), (100.0, None)):
        sol = solve(SKY, fov_deg=wrong, database=db)
        assert sol.solved and sol.method == "quad-hash", sol.reason
        assert abs(sol.fov_deg - plain.fov_deg) < 1e-6 and _sep_arcsec(sol, plain) < 0.01
        assert len(sol.warnings) == 1
        assert sol.warnings[0].startswith(f"the FOV hint {wrong:g}° was not used: nothing matched at it (")
        assert sol.warnings[0].endswith(f"solved without it, the stars give {plain.fov_deg:.3f}°")


def test_a_right_fov_hint_says_nothing(database):
    sol = solve(SKY, fov_deg=17.0, database=database)
    assert sol.solved and sol.warnings == []


def test_a_wrong_attitude_hint_says_it_was_not_used(database):
    sol = solve(SKY, fov_deg=17.0, attitude_hint="10,10,0", database=database)
    assert sol.solved and sol.method == "quad-hash"
    assert len(sol.warnings) == 1 and sol.warnings[0].startswith("the attitude hint was not used (")
    assert sol.warnings[0].endswith("): solved lost in space")
    near = solve(SKY, fov_deg=17.0, attitude_hint="84,-2,20", database=database)
    assert near.solved and near.method == "attitude-hint" and near.warnings == []


def test_a_fov_hinted_frame_that_fails_both_ways_says_both(database):
    xy = np.random.default_rng(5).uniform([0, 0], [1024, 768], (12, 2))  # no sky at all
    sol = solve_centroids(xy, 1024, 768, fov_deg=20.0, database=database)
    assert not sol.solved
    assert "; with the FOV hint 20° too (" in sol.reason
    assert sol.reason.endswith("if the field of view is known, check it; else solve without it")
