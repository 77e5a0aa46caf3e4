"""The benchmarks' own yardsticks: the independent renderer and the error metrics (no peers needed),
and the plumbing of ``benchmarks/run --against`` (workers, worktree, the comparison's flags)."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))

from common import (  # noqa: E402
    attitude_from_radec_roll_deg,
    boresight_error_arcsec,
    radec_roll_deg,
    roll_error_deg,
)
from render import add_gaussian_stars  # noqa: E402


@pytest.mark.parametrize("x0, y0", [(20.0, 30.0), (20.3, 30.7), (19.5, 31.25)])
def test_rendered_spot_centroid_is_where_it_was_put(x0, y0):
    # (0, 0) is the centre of the top-left pixel: the flux-weighted mean of the pixel-integrated
    # Gaussian must land on the requested position to a few thousandths of a pixel.
    img = np.zeros((64, 64))
    add_gaussian_stars(img, np.array([[x0, y0]]), np.array([1000.0]), sigma=1.2)
    ys, xs = np.mgrid[:64, :64]
    assert img.sum() == pytest.approx(1000.0, rel=1e-4)
    assert (img * xs).sum() / img.sum() == pytest.approx(x0, abs=2e-3)
    assert (img * ys).sum() / img.sum() == pytest.approx(y0, abs=2e-3)


def test_attitude_round_trip_and_errors():
    A = attitude_from_radec_roll_deg(123.4, -56.7, 250.0)
    assert np.allclose(A @ A.T, np.eye(3), atol=1e-12)
    ra, dec, roll = radec_roll_deg(A)
    assert (ra, dec, roll) == pytest.approx((123.4, -56.7, 250.0), abs=1e-9)
    B = attitude_from_radec_roll_deg(123.4, -56.7 + 10 / 3600, 250.3)
    assert boresight_error_arcsec(B, A) == pytest.approx(10.0, rel=1e-3)
    assert roll_error_deg(B, A) == pytest.approx(0.3, abs=1e-3)


def test_north_is_up_at_roll_zero():
    # A star slightly north of the boresight projects toward row 0 (camera -y) at roll 0.
    A = attitude_from_radec_roll_deg(10.0, 20.0, 0.0)
    north = np.radians([10.0, 20.1])
    r = np.array([np.cos(north[1]) * np.cos(north[0]), np.cos(north[1]) * np.sin(north[0]), np.sin(north[1])])
    b = A @ r
    assert b[1] < 0 and abs(b[0]) < 1e-9


# --- benchmarks/run --against: the plumbing (no solving, so no kernel compiles: seconds) -----------

def test_against_measure_flags_only_real_regressions():
    from against import Measure

    assert Measure("b", "median", 1.11, 1.0).flag.startswith("REGRESSION")
    assert Measure("b", "median", 1.09, 1.0).flag == ""
    assert Measure("b", "median", 0.5, 1.0).flag == ""  # faster is no regression
    assert Measure("b", "p99", 2.0, 1.0, "p99").flag == ""  # shown, not flagged
    assert Measure("f", "speed-up", 18.0, 20.0, "median", "higher").flag.startswith("REGRESSION")
    assert Measure("f", "speed-up", 19.0, 20.0, "median", "higher").flag == ""
    assert Measure("b", "wrong", 1, 0, "count").flag == "WORSE"
    assert Measure("b", "solved", 199, 200, "count", "higher").flag == "WORSE"
    assert Measure("b", "solved", 200, 200, "count", "higher").flag == ""
    assert Measure("b", "median", 2.0, 1.0).ratio == pytest.approx(2.0)


@pytest.fixture(scope="module")
def head_sides(tmp_path_factory):
    import against

    where = tmp_path_factory.mktemp("against") / "ref"
    sides = [against.tree_side(), against.ref_side("HEAD", where)]
    yield sides
    against.remove_ref_tree(where)


def test_against_workers_import_their_own_side(head_sides):
    from remote import RemoteError, Worker

    workers = [Worker(s.label, s.src) for s in head_sides]
    try:
        for side, w in zip(head_sides, workers, strict=True):
            assert Path(w.info["skyfix_file"]).resolve().is_relative_to(side.src.resolve())
            assert w.call("common:ratio", 1.0, 4.0) == 0.25
            big = np.arange(200_000, dtype=np.float64)  # sent once, then referred to by key
            assert w.call("numpy:sum", big) == w.call("numpy:sum", big) == big.sum()
            out = w.many("common:ratio", [((1.0, 2.0), {}), ((1.0,), {}), ((3.0, 2.0), {})])
            assert out[0] == 0.5 and out[2] == 1.5 and isinstance(out[1], RemoteError)
        assert workers[0].info["pid"] != workers[1].info["pid"]
    finally:
        for w in workers:
            w.close()


def test_against_run_compares_both_sides(head_sides, tmp_path):
    import run_all
    from common import RESULTS_DIR

    ref = head_sides[1]
    assert run_all.main(["--against", "HEAD", "--ref-tree", str(ref.root), "--suites", "h",
                         "--startup", "cli", "--startup-n", "1"]) == 0
    rows = json.loads((RESULTS_DIR / f"against-{ref.commit[:7]}" / "against.json").read_text())["rows"]
    names = {r["name"]: r for r in rows}
    for what in ("skyfix --version s", "skyfix -h s"):
        r = names[what]
        assert r["tree"] > 0 and r["ref"] > 0 and r["ratio"] == pytest.approx(r["tree"] / r["ref"])
