"""Monte Carlo campaigns (issue 27): the campaign file's checks, trials as pure functions of
(campaign, trial), results identical whatever the worker count and across an interrupted and
resumed run, bad input as one line, and the predicted error against the thesis's numbers."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("dask.distributed")
pytest.importorskip("pyarrow")

from skyfix.errors import CampaignError, InputError, UnknownNameError  # noqa: E402
from skyfix.montecarlo.campaign import campaign_from_dict, load_campaign  # noqa: E402
from tests.conftest import ROOT

CAMPAIGNS = ROOT / "campaigns"
TIMES = ("simulate_ms", "time_ms")

#: 24 trials in 4 batches of 6 over a 2 × 2 grid, one axis drawn: small enough for a test.
SMALL = {
    "campaign": {"name": "small", "level": "centroid", "trials": 24, "seed": 5, "batch_size": 6},
    "camera": {"preset": "generic"},
    "parameters": {"mag_limit": 6.0},
    "sweep": {"sigma_px": [0.2, 0.5], "false_stars": [0, 2], "mag_sigma": {"min": 0.0, "max": 0.3}},
}


def _campaign(**changes):
    data = {k: dict(v) for k, v in SMALL.items()}
    for table, values in changes.items():
        data.setdefault(table, {}).update(values)
    return campaign_from_dict(data)


def _rows(table) -> list[dict]:
    """The rows without their times (which differ run to run)."""
    return table.drop_columns(list(TIMES)).to_pylist()


# --- the campaign file -------------------------------------------------------------------------
def test_quick_campaign_reads():
    c = load_campaign(CAMPAIGNS / "quick.toml")
    assert (c.level, c.trials, c.batch_size, c.n_batches, c.grid_size) == ("centroid", 1000, 50, 20, 6)
    assert c.fixed["dropout"] == 0.05 and c.fixed["given"] == "camera"
    # round robin over the grid: trials 0..5 cover it once, trial 6 starts again
    points = [tuple(c.grid_point(i).values()) for i in range(7)]
    assert points == [(0.1, 0), (0.1, 3), (0.3, 0), (0.3, 3), (1.0, 0), (1.0, 3), (0.1, 0)]


@pytest.mark.parametrize(("changes", "error", "text"), [
    ({"campaign": {"trails": 3}}, UnknownNameError,
     "unknown key of [campaign] 'trails'; choose one of name, "),
    ({"camera": {"preset": "hasselblad"}}, UnknownNameError,
     "unknown camera preset 'hasselblad'; choose one of "),
    ({"parameters": {"sigma": 1.0}}, UnknownNameError, "unknown key of [parameters] 'sigma'; choose one of "),
    ({"sweep": {"fov_deg": []}}, InputError, "[sweep] fov_deg: an empty list of values"),
    ({"sweep": {"fov_deg": {"start": 10, "stop": 20, "num": 0}}}, InputError,
     "[sweep] fov_deg: an empty range (0 values from 10 to 20)"),
    ({"sweep": {"dropout": {"min": 0.3, "max": 0.1}}}, InputError,
     "[sweep] dropout: an empty range (min 0.3 is not below max 0.1)"),
    ({"parameters": {"sigma_px": 0.1}}, InputError,
     "parameter 'sigma_px' is both fixed ([parameters]) and swept"),
    ({"parameters": {"exposure_s": 0.1}}, InputError,
     "parameter 'exposure_s' acts at the image level, not the centroid level"),
    ({"parameters": {"identify_method": "hashes"}}, UnknownNameError,
     "unknown identification method 'hashes'"),
    ({"campaign": {"level": "pixel"}}, UnknownNameError,
     "unknown campaign level 'pixel'; choose one of centroid"),
    ({"campaign": {"trials": 0}}, InputError, "[campaign] trials must be an integer ≥ 1, got 0"),
    ({"attitude": {"distribution": "spiral"}}, UnknownNameError, "unknown attitude distribution 'spiral'"),
    ({"attitude": {"distribution": "profile", "profile": "slew"}}, InputError, "[attitude] profile 'slew': "),
])
def test_bad_campaigns_are_one_line(changes, error, text):
    with pytest.raises(error) as info:
        _campaign(**changes)
    assert str(info.value).startswith(text)
    assert "\n" not in str(info.value)


def test_bad_file_names_the_file(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text("[campaign]\ntrials = 10\n[sweep]\nfov_deg = []\n")
    with pytest.raises(InputError, match=r"^.*bad\.toml: \[sweep\] fov_deg: an empty list of values$"):
        load_campaign(path)


def test_the_fingerprint_follows_what_decides_results():
    a, b = _campaign(), _campaign()
    assert a.fingerprint == b.fingerprint
    assert _campaign(campaign={"seed": 6}).fingerprint != a.fingerprint
    assert _campaign(campaign={"batch_size": 8}).fingerprint != a.fingerprint


# --- trials ------------------------------------------------------------------------------------
def test_trial_seeds_and_values_are_fixed_numbers():
    from skyfix.montecarlo.trials import _streams, trial_seed, trial_values

    c = _campaign()
    assert trial_seed(5, 0) == trial_seed(5, 0) != trial_seed(5, 1)
    assert trial_seed(27, 0) == 3990527057650685062  # the first row of campaigns/quick.toml's results
    v = trial_values(c, 3, _streams(trial_seed(5, 3))["parameters"])
    assert (v["sigma_px"], v["false_stars"], v["mag_limit"]) == (0.5, 2, 6.0)
    assert 0.0 <= v["mag_sigma"] < 0.3
    assert v == trial_values(c, 3, _streams(trial_seed(5, 3))["parameters"])


def test_scan_and_profile_attitudes():
    from skyfix.geometry import radec_roll_from_attitude, rotation_angle_between
    from skyfix.montecarlo.trials import true_attitude

    scan = _campaign(attitude={"distribution": "scan", "pole_deg": [0.0, 90.0], "roll_deg": 30.0})
    ra_dec_roll = [np.degrees(radec_roll_from_attitude(true_attitude(scan, i, None)[0])) for i in (0, 6)]
    np.testing.assert_allclose(ra_dec_roll, [[90.0, 0.0, 30.0], [180.0, 0.0, 30.0]], atol=1e-9)
    turn = _campaign(attitude={"distribution": "profile", "profile": "constant",
                               "start_deg": [10.0, 20.0, 0.0], "frame_period_s": 1.0,
                               "options": {"rate_rad_s": [0.0, math.radians(1.0), 0.0]}})
    A0, _ = true_attitude(turn, 0, None)
    A10, rate = true_attitude(turn, 10, None)
    assert math.degrees(rotation_angle_between(A0, A10)) == pytest.approx(10.0, abs=1e-9)
    np.testing.assert_allclose(rate, [0.0, math.radians(1.0), 0.0], atol=1e-12)


# --- the engine --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def full_run(tmp_path_factory):
    """The small campaign run whole by one thread worker: the reference."""
    from skyfix.montecarlo.engine import run_campaign

    out = tmp_path_factory.mktemp("mc") / "one.parquet"
    result = run_campaign(_campaign(), out, workers=1, processes=False)
    assert result.complete and result.batches_run == 4
    return result


def test_one_row_per_trial_with_the_named_columns(full_run):
    t = full_run.table
    assert t.column("trial").to_pylist() == list(range(24))
    must = {"trial", "seed", "status", "boresight_error_arcsec", "roll_error_arcsec", "time_ms"}
    assert must <= set(t.schema.names)
    assert t.column("status").to_pylist().count("solved") == 24
    assert not any(t.column("wrong").to_pylist())
    assert t.schema.metadata[b"skyfix.fingerprint"].decode() == _campaign().fingerprint


def test_two_workers_give_the_same_rows_and_summary(full_run, tmp_path):
    from skyfix.montecarlo.engine import run_campaign
    from skyfix.montecarlo.results import summarize

    two = run_campaign(_campaign(), tmp_path / "two.parquet", workers=2, processes=False)
    assert two.workers == 2
    assert _rows(two.table) == _rows(full_run.table)
    assert summarize(two.table, _campaign()) == summarize(full_run.table, _campaign())


def test_in_process_run_gives_the_same_rows(full_run, tmp_path):
    from skyfix.montecarlo.engine import run_campaign

    here = run_campaign(_campaign(), tmp_path / "here.parquet", workers=0)
    assert (here.workers, here.batches_run) == (0, 4)
    assert _rows(here.table) == _rows(full_run.table)


def _squares_study(trials: int = 10, batch_size: int = 3, power: int = 2):
    from dataclasses import dataclass

    from skyfix.montecarlo.study import BatchedStudy

    @dataclass(frozen=True)
    class Squares(BatchedStudy):
        kind = "squares"
        columns = {"trial": "int64", "value": "float64", "values": "list<int64>"}

        def run_trial(self, trial: int) -> dict:
            p = self.settings["power"]
            return {"trial": trial, "value": float(trial) ** p, "values": list(range(trial % 3))}

    return Squares(trials, batch_size, {"power": power})


def test_any_study_runs_resumes_and_is_refused_when_changed(tmp_path):
    from skyfix.montecarlo.engine import run_campaign

    study, out = _squares_study(), tmp_path / "sq.parquet"
    first = run_campaign(study, out, workers=0, max_batches=2)
    assert (first.complete, first.batches_run, first.n_batches) == (False, 2, 4)
    done = run_campaign(study, out, workers=1, processes=False)
    assert (done.batches_before, done.batches_run) == (2, 2)
    assert done.table.column("value").to_pylist() == [float(i * i) for i in range(10)]
    assert done.table.column("values").to_pylist()[:4] == [[], [0], [0, 1], []]
    assert done.table.schema.metadata[b"skyfix.fingerprint"].decode() == study.fingerprint
    cubes = _squares_study(power=3)
    assert cubes.fingerprint != study.fingerprint
    run_campaign(cubes, tmp_path / "cubes.parquet", workers=0, max_batches=1)
    (tmp_path / "cubes.parquet.parts").rename(tmp_path / "sq2.parquet.parts")
    with pytest.raises(CampaignError, match="another campaign"):
        run_campaign(study, tmp_path / "sq2.parquet", workers=0)


def test_interrupted_run_resumes_with_every_trial_once(full_run, tmp_path):
    from dask.distributed import Client, LocalCluster

    from skyfix.montecarlo.engine import parts_folder, run_campaign
    from skyfix.montecarlo.results import summarize

    c, out = _campaign(), tmp_path / "resumed.parquet"
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster, Client(cluster, set_as_default=False) as client:
        first = run_campaign(c, out, client=client, max_batches=2)
        assert (first.complete, first.batches_run) == (False, 2)
        kept = sorted(p.name for p in parts_folder(out).glob("batch-*.parquet"))
        assert len(kept) == 2 and not out.exists()
        # a torn part is run again, not kept
        (parts_folder(out) / "batch-000003.parquet").write_bytes(b"PAR1 torn")
        second = run_campaign(c, out, client=client)
    assert (second.complete, second.batches_before, second.batches_run) == (True, 2, 2)
    assert second.table.column("trial").to_pylist() == list(range(24))
    assert _rows(second.table) == _rows(full_run.table)
    assert summarize(second.table, c) == summarize(full_run.table, c)
    assert not parts_folder(out).exists()
    again = run_campaign(c, out, workers=1, processes=False)  # finished: nothing to run
    assert (again.batches_run, again.table.num_rows) == (0, 24)


def test_another_campaigns_parts_are_refused(tmp_path):
    from skyfix.montecarlo.engine import parts_folder, run_campaign

    out = tmp_path / "r.parquet"
    parts_folder(out).mkdir()
    (parts_folder(out) / "campaign.json").write_text('{"fingerprint": "0123"}')
    with pytest.raises(CampaignError, match="holds the finished batches of another campaign"):
        run_campaign(_campaign(), out, workers=1, processes=False)


def test_unreachable_scheduler_is_one_line(tmp_path, monkeypatch):
    from skyfix.montecarlo import engine

    monkeypatch.setattr(engine, "CONNECT_TIMEOUT_S", 1.0)
    with pytest.raises(CampaignError, match=r"^cannot reach the Dask scheduler at tcp://127\.0\.0\.1:9: "):
        engine.run_campaign(_campaign(), tmp_path / "r.parquet", scheduler="tcp://127.0.0.1:9")


def test_summary_numbers(full_run):
    from skyfix.montecarlo.results import summarize

    s = summarize(full_run.table, _campaign())
    assert (s["trials"], s["solved"], s["wrong"], s["availability"]) == (24, 24, 0, 1.0)
    assert s["wrong_rate_upper_95"] == pytest.approx(1 - 0.05 ** (1 / 24))  # rule of three's exact form
    assert [g["value"] for g in s["by_parameter"]["sigma_px"]] == [0.2, 0.5]
    assert [g["trials"] for g in s["by_parameter"]["sigma_px"]] == [12, 12]
    assert sum(g["trials"] for g in s["by_parameter"]["mag_sigma"]) == 24
    assert s["prob_false"]["observed_wrong"] == 0 and s["prob_false"]["calibrated"]
    # the errors scale with the centroid noise: 0.5 px vs 0.2 px
    by = s["by_parameter"]["sigma_px"]
    assert 1.5 < by[1]["rms_arcsec"]["x"] / by[0]["rms_arcsec"]["x"] < 4.0


def test_command_runs_and_bad_input_is_one_line(tmp_path):
    from typer.testing import CliRunner

    from skyfix.cli import app

    bad = tmp_path / "bad.toml"
    bad.write_text('[camera]\npreset = "nope"\n[campaign]\ntrials = 5\n')
    res = CliRunner().invoke(app, ["montecarlo", str(bad), "-o", str(tmp_path / "r.parquet")])
    assert res.exit_code == 2
    assert res.output.strip().splitlines() == [
        f"skyfix: error: {bad}: unknown camera preset 'nope'; choose one of "
        + res.output.split("choose one of ")[1].strip()]
    res = CliRunner().invoke(app, ["montecarlo", str(bad), "--workers", "2", "--scheduler", "tcp://x:1",
                                   "-o", str(tmp_path / "r.parquet")])
    assert res.exit_code == 2 and "give --workers or --scheduler, not both" in res.output


# --- the prediction ----------------------------------------------------------------------------
def test_liebe_reproduces_thesis_000():
    """Thesis 000 §2.9: FOV 30.8°, 0.1 px, 560 px, 3 stars → 0.00318° boresight; roll ≈ 56″."""
    from skyfix.montecarlo.budget import liebe_sigma_rad

    bore, roll = liebe_sigma_rad(30.8, 560, 0.1, 3)
    assert math.degrees(bore) == pytest.approx(0.00318, abs=5e-6)
    assert math.degrees(roll) * 3600 == pytest.approx(55.7, abs=0.5)


def test_fisher_prediction_is_the_quest_model_near_the_axis():
    """Stars near the boresight of a long lens: the pixel-space Cramér–Rao covariance equals the
    QUEST measurement model with σ = σ_px · plate scale; off axis it is smaller (cos θ)."""
    from skyfix.attitude import attitude_covariance
    from skyfix.camera import Camera
    from skyfix.montecarlo.budget import predicted_covariance_rad2

    cam = Camera.from_fov(1024, 1024, 2.0)
    rng = np.random.default_rng(1)
    b = cam.pixel_to_ray(rng.uniform(0, 1023, size=(20, 2)))
    P = predicted_covariance_rad2(cam, b, 0.3)
    Q = attitude_covariance(np.eye(3), b, 0.3 * cam.plate_scale_rad)
    np.testing.assert_allclose(P, Q, rtol=2e-3, atol=1e-6 * np.abs(Q).max())
    wide = Camera.from_fov(1024, 1024, 60.0)
    bw = wide.pixel_to_ray(rng.uniform(0, 1023, size=(20, 2)))
    ratio = np.diag(predicted_covariance_rad2(wide, bw, 0.3)) / np.diag(
        attitude_covariance(np.eye(3), bw, 0.3 * wide.plate_scale_rad))
    assert np.all(ratio < 0.97)
    assert np.isnan(predicted_covariance_rad2(cam, b[:1], 0.3)).all()


@pytest.mark.slow
def test_a_worker_killed_mid_run_loses_no_trial(full_run, tmp_path):
    """Two worker processes; one is killed (SIGKILL) once the first batch is in. Its batches run
    again on a restarted worker: every trial once, the rows of the one-worker run."""
    import os
    import signal

    from dask.distributed import Client, LocalCluster

    from skyfix.montecarlo.engine import _worker_env, run_campaign

    killed = []
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                      env=_worker_env()) as cluster, Client(cluster, set_as_default=False) as client:

        def kill_one(done: int, total: int) -> None:
            if done >= 1 and not killed:
                pid = sorted(client.run(os.getpid).values())[0]
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)

        result = run_campaign(_campaign(), tmp_path / "killed.parquet", client=client, progress=kill_one)
    assert killed and result.complete
    assert result.table.column("trial").to_pylist() == list(range(24))
    assert _rows(result.table) == _rows(full_run.table)


@pytest.mark.slow
def test_the_command_interrupted_and_run_again(tmp_path):
    """``skyfix montecarlo`` given SIGINT once two batches are kept: exit 130 with the one-line
    notice; the same command again finishes, with the rows and summary of an uninterrupted run."""
    import json
    import os
    import signal
    import subprocess
    import sys
    import time

    import pyarrow.parquet as pq

    from skyfix.montecarlo.engine import parts_folder

    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    smoke = str(CAMPAIGNS / "smoke.toml")

    def command(out: Path) -> list[str]:
        return [sys.executable, "-m", "skyfix.cli", "montecarlo", smoke, "--workers", "1", "-o", str(out)]

    out = tmp_path / "cut.parquet"
    proc = subprocess.Popen(command(out), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 600
    while len(list(parts_folder(out).glob("batch-*.parquet"))) < 2 and time.monotonic() < deadline:
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-2000:]
    assert "interrupted: the finished batches are kept in" in err
    kept = len(list(parts_folder(out).glob("batch-*.parquet")))
    assert 2 <= kept < 10
    again = subprocess.run(command(out), env=env, capture_output=True, text=True, timeout=900)
    assert again.returncode == 0, again.stderr[-2000:]
    assert f"{kept} of 10 batches were done already" in again.stderr
    whole = tmp_path / "whole.parquet"
    assert subprocess.run(command(whole), env=env, capture_output=True, timeout=900).returncode == 0
    assert pq.read_table(out).column("trial").to_pylist() == list(range(200))
    assert _rows(pq.read_table(out)) == _rows(pq.read_table(whole))
    summaries = [json.loads(p.with_suffix(".summary.json").read_text()) for p in (out, whole)]
    for s in summaries:
        s.pop("timing")
    assert summaries[0] == summaries[1]


def _trim_threshold():
    import os

    return os.environ.get("MALLOC_TRIM_THRESHOLD_")


def test_local_workers_keep_glibcs_adaptive_mmap_threshold():
    """Dask's nanny would start them with MALLOC_TRIM_THRESHOLD_=65536 (half the speed on frames)."""
    from skyfix.montecarlo.engine import connect

    client, cluster = connect(1, None)
    try:
        assert list(client.run(_trim_threshold).values()) == [None]
    finally:
        client.close()
        cluster.close()
