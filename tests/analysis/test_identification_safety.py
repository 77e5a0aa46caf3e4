"""The identification study's safety case (skyfix.analysis.identification_study.run_safety):
its frames drawn and replayed, its judge counting a wrong attitude as wrong, its bookkeeping."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skyfix.analysis import identification_jobs as jobs
from skyfix.analysis import identification_safety as sf
from skyfix.solution import Solution

_ARCSEC = math.pi / (180 * 3600)


@pytest.fixture(scope="module")
def catalog():
    from skyfix.catalog import load_hipparcos

    return load_hipparcos(epoch=jobs.EPOCH, mag_limit=jobs.MAG_LIMIT + 1.0)


def test_draws_cover_the_axes_and_replay():
    draws = [sf.safety_draw(t, seed=3) for t in range(3000)]
    assert sf.safety_draw(17, seed=3) == draws[17]  # a function of (seed, trial) alone
    assert sf.safety_draw(17, seed=4) != draws[17]
    kinds = np.array([d.bright_stars for d in draws])
    assert abs(np.mean(kinds == 3) - 0.2) < 0.03 and abs(np.mean((kinds == 4) | (kinds == 5)) - 0.2) < 0.03
    assert {d.fov_deg for d in draws} == {8.0, 15.0, 30.0}
    assert {d.n_false for d in draws} == set(range(11))
    assert max(d.sigma_px for d in draws) > 1.95 and min(d.sigma_px for d in draws) < 0.05
    assert max(d.dropout for d in draws) <= 0.2 and max(d.mag_sigma for d in draws) <= 0.5
    assert 0.45 < np.mean([d.camera_given for d in draws]) < 0.55


def test_sparse_frame_holds_its_brightest_stars(catalog):
    draw = sf.SafetyDraw(5, 30.0, 0.0, 2, 0.0, 0.0, True, 3)
    camera, field = sf.safety_field(draw, catalog)
    assert np.sum(field.star_id > 0) == 3 and np.sum(field.star_id == 0) == 2
    again = sf.safety_field(draw, catalog)[1]
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


@pytest.mark.parametrize("trial", [6, 11])  # a 15° and a 30° frame: one pixel 42″ and 84″
@pytest.mark.parametrize("bore, roll, wrong", [(0.9, 0.0, False), (1.1, 0.0, True), (0.0, 0.6, True),
                                               (0.0, 0.4, False)])
def test_judge_counts_a_wrong_attitude(monkeypatch, catalog, trial, bore, roll, wrong):
    """The one definition (skyfix.analysis.truth.is_wrong): boresight beyond max(60″, 1 px) — here
    0.9 and 1.1 of that bar, split 3:4 over x and y — or roll beyond 0.5°."""
    draw = sf.safety_draw(trial)
    camera, field = sf.safety_field(draw, catalog)
    bar = max(60.0, math.degrees(camera.plate_scale_rad) * 3600.0)
    assert {6: 15.0, 11: 30.0}[trial] == draw.fov_deg
    rotvec = (0.6 * bore * bar, 0.8 * bore * bar, roll * 3600.0)
    fake = _fake_solve(rotvec)
    fake.field = field
    monkeypatch.setattr("skyfix.pipeline.solve_centroids", fake)
    r = sf.safety_trial("quad-hash", draw, camera, field)
    assert r.solved and r.wrong is wrong
    assert r.boresight_arcsec == pytest.approx(math.hypot(rotvec[0], rotvec[1]), abs=0.05)
    assert r.roll_deg == pytest.approx(rotvec[2] / 3600, abs=1e-4)
    assert r.normalised == pytest.approx(math.hypot(*rotvec) / 10.0, rel=1e-3)
    summary = sf.safety_summary([r, r._replace(trial=12, solved=False, wrong=False)])["quad-hash"]
    assert summary["n"] == 2 and summary["solved"] == 1 and summary["wrong"] == int(wrong)
    assert [w["trial"] for w in summary["wrong_trials"]] == ([trial] if wrong else [])
    assert summary["wrong_upper95_pct"] == pytest.approx(100 * jobs.upper_bound_95(int(wrong), 2))


def test_small_run_bookkeeping_and_replay(tmp_path):
    mix = sf.SAFETY_MIX._replace(fovs_deg=(15.0, 30.0))  # the 8° frames' refusals take the time
    settings = sf.SafetySettings(trials=6, methods=("quad-hash", "grid"), block=4, mix=mix)
    safety = sf.run_safety(settings, out=tmp_path / "safety.parquet")
    recs = safety["records"]
    back = sf.read_safety(tmp_path / "safety.parquet")  # the rows the engine wrote, read back
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
    again = sf.replay_safety(4, "grid", mix=mix)
    assert again._replace(time_ms=0.0) == recs[9]._replace(time_ms=0.0)
    paths = sf.write_safety(safety, tmp_path, command="test")
    data = json.loads(paths[0].read_text())
    assert data["summary"]["grid"]["n"] == 6 and len(data["records"]["trial"]) == 12
    assert "## Safety: 6 frames per method" in paths[1].read_text()


def test_one_definition_of_a_wrong_attitude():
    """skyfix.analysis.truth.is_wrong: beyond max(60″, 1 px) or 0.5° of roll; NaN is wrong."""
    from skyfix.analysis.truth import is_wrong, judge_error

    assert not is_wrong(60.0, 0.5) and is_wrong(60.01, 0.0) and is_wrong(0.0, -0.51)
    assert not is_wrong(80.0, 0.0, plate_scale_arcsec=84.0) and is_wrong(85.0, 0.0, plate_scale_arcsec=84.0)
    assert is_wrong(math.nan, 0.0) and is_wrong(0.0, math.nan)
    verdict = judge_error(np.array([3.0, 4.0, 0.01]) * 20.0 * _ARCSEC)  # 100″ off the boresight
    assert verdict.wrong and verdict.boresight_arcsec == pytest.approx(100.0, rel=1e-12)
    assert verdict.roll_deg == pytest.approx(0.2 / 3600.0, rel=1e-9)


def test_quick_safety_searches_the_standard_database_alone(monkeypatch, catalog):
    """--quick's frames: 15°, the FOV told, the standard band's database given to every solve (no
    other band built); the full study's: every band (no database given)."""
    from skyfix.identify import default_database

    seen = []

    def fake(xy, width, height, **kw):
        seen.append((kw.get("database"), kw.get("camera"), kw.get("fov_deg")))
        raise RuntimeError("not solved here")

    monkeypatch.setattr("skyfix.pipeline.solve_centroids", fake)
    quick = sf.SAFETY_QUICK
    assert quick.trials == 20 and not quick.bands and quick.mix.fovs_deg == (15.0,)
    recs = sf.run_safety_block(range(6), ["quad-hash"], mix=quick.mix, bands=quick.bands)
    assert [r.fov_deg for r in recs] == [15.0] * 6 and not any(r.camera_given for r in recs)
    standard = default_database(progress=False)
    assert all(db is standard and cam is None and fov == 15.0 for db, cam, fov in seen)
    seen.clear()
    sf.run_safety_block(range(2), ["quad-hash"], mix=sf.SAFETY_STUDY.mix, bands=sf.SAFETY_STUDY.bands)
    assert [db for db, _, _ in seen] == [None, None]
