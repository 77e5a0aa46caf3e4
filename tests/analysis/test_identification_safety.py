"""The identification study's safety case (skyfix.analysis.identification_study.run_safety):
its frames drawn and replayed, its judge counting a wrong attitude as wrong, its bookkeeping."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skyfix.analysis import identification_study as st
from skyfix.solution import Solution

_ARCSEC = math.pi / (180 * 3600)


@pytest.fixture(scope="module")
def catalog():
    from skyfix.catalog import load_hipparcos

    return load_hipparcos(epoch=st.EPOCH, mag_limit=st.MAG_LIMIT + 1.0)


def test_draws_cover_the_axes_and_replay():
    draws = [st.safety_draw(t, seed=3) for t in range(3000)]
    assert st.safety_draw(17, seed=3) == draws[17]  # a function of (seed, trial) alone
    assert st.safety_draw(17, seed=4) != draws[17]
    kinds = np.array([d.bright_stars for d in draws])
    assert abs(np.mean(kinds == 3) - 0.2) < 0.03 and abs(np.mean((kinds == 4) | (kinds == 5)) - 0.2) < 0.03
    assert {d.fov_deg for d in draws} == {8.0, 15.0, 30.0}
    assert {d.n_false for d in draws} == set(range(11))
    assert max(d.sigma_px for d in draws) > 1.95 and min(d.sigma_px for d in draws) < 0.05
    assert max(d.dropout for d in draws) <= 0.2 and max(d.mag_sigma for d in draws) <= 0.5
    assert 0.45 < np.mean([d.camera_given for d in draws]) < 0.55


def test_sparse_frame_holds_its_brightest_stars(catalog):
    draw = st.SafetyDraw(5, 30.0, 0.0, 2, 0.0, 0.0, True, 3)
    camera, field = st.safety_field(draw, catalog)
    assert np.sum(field.star_id > 0) == 3 and np.sum(field.star_id == 0) == 2
    again = st.safety_field(draw, catalog)[1]
    assert np.array_equal(field.xy, again.xy)  # the same frame, to the bit


def _fake_solve(rotvec_arcsec):
    """A solve that reports the truth turned by ``rotvec_arcsec`` (camera axes), σ 10″ a side."""

    def solve(xy, width, height, **kw):
        field = solve.field
        R = Rotation.from_rotvec(np.asarray(rotvec_arcsec) * _ARCSEC).as_matrix()
        return Solution(status="solved", A_icrs_to_cam=R @ field.A_icrs_to_cam, camera=field.camera,
                        covariance_arcsec2=np.diag([100.0, 100.0, 100.0]).tolist(), n_matched=4,
                        prob_false=1e-12)

    return solve


@pytest.mark.parametrize("rotvec, wrong", [((30.0, 20.0, 0.0), False), ((50.0, 40.0, 0.0), True),
                                           ((0.0, 0.0, 0.6 * 3600), True), ((0.0, 0.0, 0.4 * 3600), False)])
def test_judge_counts_a_wrong_attitude(monkeypatch, catalog, rotvec, wrong):
    draw = st.safety_draw(11)
    camera, field = st.safety_field(draw, catalog)
    fake = _fake_solve(rotvec)
    fake.field = field
    monkeypatch.setattr("skyfix.pipeline.solve_centroids", fake)
    r = st.safety_trial("quad-hash", draw, camera, field)
    assert r.solved and r.wrong is wrong
    assert r.boresight_arcsec == pytest.approx(math.hypot(rotvec[0], rotvec[1]), abs=0.05)
    assert r.roll_deg == pytest.approx(rotvec[2] / 3600, abs=1e-4)
    assert r.normalised == pytest.approx(math.hypot(*rotvec) / 10.0, rel=1e-3)
    summary = st.safety_summary([r, r._replace(trial=12, solved=False, wrong=False)])["quad-hash"]
    assert summary["n"] == 2 and summary["solved"] == 1 and summary["wrong"] == int(wrong)
    assert [w["trial"] for w in summary["wrong_trials"]] == ([11] if wrong else [])
    assert summary["wrong_upper95_pct"] == pytest.approx(100 * st.upper_bound_95(int(wrong), 2))


def test_small_run_bookkeeping_and_replay(tmp_path):
    mix = st.SAFETY_MIX._replace(fovs_deg=(15.0, 30.0))  # the 8° frames' refusals take the time
    settings = st.SafetySettings(trials=6, methods=("quad-hash", "grid"), block=4, mix=mix)
    safety = st.run_safety(settings, checkpoint=tmp_path / "part.jsonl")
    recs = safety["records"]
    back = st.read_checkpoint(tmp_path / "part.jsonl")  # the blocks as they came, read back in order
    assert len(back) == len(recs)
    for a, b in zip(back, recs, strict=True):
        same = [x == y or (isinstance(x, float) and math.isnan(x) and math.isnan(y))
                for x, y in zip(a, b, strict=True)]
        assert all(same), (a, b)
    assert [(r.trial, r.method) for r in recs] == [(t, m) for t in range(6) for m in ("quad-hash", "grid")]
    for r in recs:
        assert r.n_centroids >= r.n_stars and r.time_ms > 0
        assert r.solved == math.isfinite(r.boresight_arcsec)
        assert not r.wrong and (not r.solved or r.boresight_arcsec < 60.0)  # no method may be wrong here
        assert r.solved or r.reason
    again = st.replay_safety(4, "grid", mix=mix)
    assert again._replace(time_ms=0.0) == recs[9]._replace(time_ms=0.0)
    paths = st.write_safety(safety, tmp_path, command="test")
    data = json.loads(paths[0].read_text())
    assert data["summary"]["grid"]["n"] == 6 and len(data["records"]["trial"]) == 12
    assert "## Safety: 6 frames per method" in paths[1].read_text()
