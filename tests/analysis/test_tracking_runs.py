"""The tracking study on the campaign engine (skyfix.analysis.tracking_runs, issue 27).

Two short sequences — 8 frames turning at 1 °/s with a blank frame and a 90° jump (so thesis
002's predictor told wrong times is there), and 6 frames of the pendulum at 4 Hz without one —
as the trials of a :class:`TrackingSequences` study: the rows hold what ``run_sequence`` gave at
e64cdec (the study's own pool, before the engine; fixed numbers below), a row and a record
convert both ways exactly, and the rows are the same in this process and on a Dask cluster.
"""

from __future__ import annotations

import json
import math
from dataclasses import fields

import numpy as np
import pytest

pytest.importorskip("dask.distributed")
pytest.importorskip("pyarrow")

from skyfix.analysis import tracking_runs as tr  # noqa: E402
from skyfix.analysis import tracking_study as ts  # noqa: E402

DEG = math.pi / 180
SPECS = [
    ts.SequenceSpec("1 °/s", "constant", {"rate_rad_s": (1.0 * DEG * ts.RATE_AXIS).tolist()},
                    n_frames=8, blank_frame=6, jump_frame=7, radec_roll_deg=(84.0, -2.0, 20.0), seed=5,
                    time_error_s=0.02),
    ts.SequenceSpec("pendulum", "pendulum", {"amplitude_rad": [0.25 * DEG, 1.0 * DEG, 0.1 * DEG],
                                             "period_s": 12.0, "damping_ratio": 0.05,
                                             "phase_rad": [0.0, 0.0, math.pi / 2]},
                    n_frames=6, fps=4.0, exposure_s=0.0625, radec_roll_deg=(200.0, 30.0, 100.0), seed=6),
]
TIMES = ("time_track_ms", "time_lis_ms", "wall_s")


def _same(rows: list[dict]) -> list[str]:
    """Rows without their times, as exact text (floats by repr, NaN as NaN)."""
    return [json.dumps({k: v for k, v in r.items() if k not in TIMES}, sort_keys=True) for r in rows]


@pytest.fixture(scope="module")
def here(tmp_path_factory):
    from skyfix.montecarlo.engine import run_campaign

    out = tmp_path_factory.mktemp("tracking") / "rows.parquet"
    result = run_campaign(tr.TrackingSequences.of(SPECS), out, workers=0)
    assert result.complete and (result.batches_run, result.trials_run) == (2, 2)
    return result.table.to_pylist()


def test_the_columns_hold_every_field_of_a_record():
    names = [f.name for f in fields(ts.SequenceResult) if f.name not in ("spec", "predictions")]
    names += [n for n in ts.SequenceSpec._fields if n != "radec_roll_deg"]
    missing = [n for n in names if n not in tr.COLUMNS and f"{n}_x" not in tr.COLUMNS]
    assert missing == [] and list(tr.COLUMNS)[0] == "trial"


def test_rows_hold_the_numbers_of_the_study_before_the_engine(here):
    """Fixed numbers of e64cdec's ``run_sequence`` on the same two specs (its pool ran the same
    function); floats to 1e-9 relative (they were equal to the last bit on the machine that pinned
    them)."""
    turn, pend = here
    assert [r["trial"] for r in here] == [0, 1]
    assert turn["event"] == PINNED["event"] and turn["mode"] == PINNED["mode"]
    assert turn["n_matched"] == PINNED["n_matched"] and turn["n_lis"] == PINNED["n_lis"]
    assert turn["tracked"] == PINNED["tracked"] and turn["n_visible"] == PINNED["n_visible"]
    assert turn["late_predictor"] == "small-angle, times ±20 ms" and pend["late_predictor"] is None
    assert pend["pred_late_meas_px"] is None and pend["n_matched"] == PINNED["pend_n_matched"]
    pinned = [(turn, c, want) for c, want in PINNED["floats"].items()]
    pinned.append((pend, "pred_small_angle_meas_px", PINNED["pend_pred_small_angle_meas_px"]))
    for row, column, want in pinned:
        got = np.asarray(row[column], np.float64)
        # to 1 mas (or 1e-6): the default database's stars are moved to the day it is built
        np.testing.assert_allclose(got, np.asarray(want, np.float64), rtol=1e-6, atol=1e-3, equal_nan=True,
                                   err_msg=column)


def test_a_row_and_its_record_convert_exactly(here):
    for row in here:
        seq = tr.sequence_of(row)
        assert seq.spec == ts.SequenceSpec(*SPECS[row["trial"]])
        assert seq.err_track.shape == (seq.spec.n_frames, 3) and seq.tracked.dtype == bool
        assert _same([tr.sequence_row(row["trial"], seq, row["wall_s"])]) == _same([row])
    late = "small-angle, times ±20 ms"
    assert sorted(tr.sequence_of(here[0]).predictions) == sorted([*ts.PREDICTOR_NAMES, late])


def test_dask_gives_the_rows_of_this_process(here, tmp_path):
    from dask.distributed import Client, LocalCluster

    from skyfix.montecarlo.engine import run_campaign

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster, Client(cluster, set_as_default=False) as client:
        result = run_campaign(tr.TrackingSequences.of(SPECS), tmp_path / "dask.parquet", client=client)
    assert _same(result.table.to_pylist()) == _same(here)


def test_an_unreachable_scheduler_is_one_line(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from skyfix.cli import app
    from skyfix.montecarlo import engine

    monkeypatch.setattr(engine, "CONNECT_TIMEOUT_S", 1.0)
    res = CliRunner().invoke(app, ["analyze", "tracking", "--quick", "--scheduler", "tcp://127.0.0.1:9",
                                   "--out", str(tmp_path / "out")])
    assert res.exit_code == 2 and res.stdout == ""
    assert res.stderr.startswith("skyfix: error: cannot reach the Dask scheduler at tcp://127.0.0.1:9: ")
    assert len(res.stderr.splitlines()) == 1
    res = CliRunner().invoke(app, ["analyze", "tracking", "--workers", "-1", "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and res.stderr == "skyfix: error: --workers must be ≥ 0, got -1\n"


#: e64cdec's run_sequence on SPECS (tracking_study's own pool ran it; its JSON, floats by repr).
PINNED: dict = {'event': ['', '', '', '', '', '', 'blank', 'jump'],
 'floats': {'err_lis_x': [0.41230140676658017, -0.0683372535846377, -0.15374250682638335, 1.194892089879628,
                          -0.43742785093902486, 0.5202768876589906, math.nan, -2.638777373106708],
            'err_lis_y': [1.1614020130981089, -1.884977315790738, 0.5441467413285781, -2.64477443829666,
                          -0.40556480586435445, -2.0044347139551473, math.nan, 4.311150044984777],
            'err_lis_z': [-0.27705917246994305, -15.688715777760677, -20.915314710023708,
                          -24.972453881304233, 10.619378101199244, 6.144831668012533, math.nan,
                          -5.88820308922955],
            'err_track_x': [0.41230140676658017, -0.0683372535846377, -0.312838035452694,
                            0.1990713354653352, 0.6336743316440695, -0.6197492431521096,
                            -2.0913971718477957, -0.12346325172989285],
            'err_track_y': [1.1614020130981089, -1.884977315790738, -0.396773328283837, 0.22004532254068207,
                            -0.018868900782897838, 0.35020811477171504, 0.7731904365824518,
                            1.5325142807602254],
            'err_track_z': [-0.27705917246994305, -15.688715777760677, -7.147971315647513,
                            -8.093690622358032, -12.797112035193573, -8.072838184941705, -7.585247890838442,
                            1.7164203248869314],
            'nees_track': [0.7672949088247777, 2.6148621947749233, 0.4916265222143529, 0.41026946686807636,
                           1.2501801523459286, 0.6107242760666485, 0.2533628632138345, 0.639996658291128],
            'pred_late_att_x': [math.nan, math.nan, math.nan, -8.475438138603126, -96.48328054333443,
                                5.855166461063057, math.nan, math.nan],
            'pred_mekf_meas_px': [math.nan, math.nan, math.nan, 0.20157787840879685,
                                  0.19223836204360958, 0.23113234853737613, math.nan, math.nan],
            'pred_three_point_true_px': [math.nan, math.nan, math.nan, 0.1280794264423851,
                                         0.10484074540014655, 0.16099644284002473, math.nan, math.nan]},
 'mode': ['lost', 'acquiring', 'tracking', 'tracking', 'tracking', 'tracking', 'tracking', 'lost'],
 'n_lis': [61, 66, 66, 64, 61, 61, 0, 26],
 'n_matched': [61, 66, 16, 16, 16, 16, 0, 58],
 'n_visible': [84, 82, 82, 82, 82, 82, 0, 26],
 'pend_n_matched': [20, 22, 16, 16, 16, 16],
 'pend_pred_small_angle_meas_px': [math.nan, math.nan, math.nan, 0.6065272380467284, 0.574318801745936,
                                   0.9119437897882088],
 'tracked': [False, False, True, True, True, True, False, False]}
