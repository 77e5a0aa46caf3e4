"""The preset and all-sky campaigns on the campaign engine (issue 27 part 2): their trials are pure
functions of (settings, trial index), so the rows run in this process, on a Dask cluster and by a
direct call of the trial function are the same; and they reproduce the numbers the campaigns gave
before they moved to the engine (their own loops at e64cdec: the same settings, bit-identical
records and tables, times aside)."""

from __future__ import annotations

import math

import pytest

from skyfix.analysis import allsky_campaign as ac
from skyfix.analysis import preset_campaign as pc
from skyfix.montecarlo.engine import run_rows
from skyfix.montecarlo.study import table_of


def _same(a, b) -> bool:
    """Rows equal, NaN equal to NaN, the solve times aside."""
    if a.keys() != b.keys():
        return False
    for k in a:
        if k.endswith("time_s"):
            continue
        x, y = a[k], b[k]
        if isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y):
            continue
        if x != y:
            return False
    return True


def _cluster_rows(study, out):
    from dask.distributed import Client, LocalCluster

    from skyfix.montecarlo.engine import run_campaign

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster, Client(cluster, set_as_default=False) as client:
        return run_campaign(study, out, client=client).table.to_pylist()


# Before the engine (its own loop at e64cdec: `run_campaign(3, seed=1, rows=(CampaignRow("generic"),
# …))`; the first two of 3 attitudes are those of 2), frame by frame: detectable stars, boresight
# error ″ with no hint, with the camera given.
PRESET_BEFORE = (64, 0.9152645896902315, 0.8026843969114863, 57, 0.48661237870449775, 0.9572835935520219)


def test_preset_rows_are_the_trial_function_in_process_and_on_dask(tmp_path):
    study = pc.campaign_study(2, seed=1, rows=(pc.CampaignRow("generic"),), batch_size=1)
    here = run_rows(study, tmp_path / "here.parquet", workers=0).to_pylist()
    assert [r["trial"] for r in here] == [0, 1] and all(r["blind_solved"] for r in here)
    (direct,) = table_of(study, [study.run_trial(1)]).to_pylist()  # the row a direct call gives
    assert _same(here[1], direct)
    on_dask = _cluster_rows(study, tmp_path / "dask.parquet")
    assert all(_same(a, b) for a, b in zip(here, on_dask, strict=True))
    campaign = pc.campaign_of(study, run_rows(study, tmp_path / "here.parquet"))  # finished: read back
    (row, dbs, frames), = campaign.rows
    assert row == pc.CampaignRow("generic") and dbs == {"bands": None}
    got = [v for f in frames for v in (f.n_detectable, f.solves["bands/blind"].boresight_arcsec,
                                       f.solves["bands/camera"].boresight_arcsec)]
    # the default database's stars are moved to the day it was built: pinned to 1 mas, not the bit
    assert got == pytest.approx(PRESET_BEFORE, rel=1e-6, abs=1e-3)


@pytest.mark.slow  # two 2 MP fisheye frames rendered and solved: 17 s at load 6
def test_allsky_rows_are_the_trial_function_and_reproduce():
    """Seed 1 before the engine (e64cdec, `allsky_campaign(range(3))[1]`): a 1600 × 1200
    equidistant 190° frame, solved, 7.507766015055369″ off, 163 stars matched, the axes' errors
    over σ 0.8720772417727075, −0.33392869501003936, −0.15115986782532692."""
    (r,) = ac.allsky_campaign([1])
    study = ac.AllSkyStudy(1, 1, {"seeds": [1], "solve_options": {}})
    assert ac.result_of(study.run_trial(0))[:8] == r[:8]
    assert (r.seed, r.size, r.lens, r.solved, r.wrong, r.n_matched) == (1, (1600, 1200), "equidistant 190°",
                                                                           True, False, 163)
    assert r.boresight_arcsec == pytest.approx(7.507766015055369, rel=1e-12, abs=0)
    z = (0.8720772417727075, -0.33392869501003936, -0.15115986782532692)
    assert r.axis_error_sigmas == pytest.approx(z, rel=1e-12, abs=0)
