"""The identification study on the campaign engine (issue 27): the grid's and the safety case's
rows are their trial functions' records (the numbers the study's own process pool gave at
e64cdec, pinned below), the same in this process and on a Dask cluster, a stopped run's batches
are read back and continued, and an unreachable scheduler is one line."""

from __future__ import annotations

import math

import pytest

pytest.importorskip("dask.distributed")
pytest.importorskip("pyarrow")

from skyfix.analysis import identification_safety as sf  # noqa: E402
from skyfix.analysis import identification_study as st  # noqa: E402
from skyfix.montecarlo.engine import parts_folder, run_campaign  # noqa: E402

METHODS = ["quad-hash", "grid"]

# What the study's own pool gave at e64cdec (run_study(QUICK with 6 fields, quad-hash, triangle, grid,
# safety=SAFETY_QUICK with 6 frames)): quad-hash's fields 0–2 of each cell, safety frames 3–5.
PINNED_GRID_STARS = [21, 27, 75, 26, 27, 24]
PINNED_GRID_BORESIGHT = [0.026667333876063685, 0.10356278661426616, 0.018279583038747334, 13.44053010363744,
                         8.103137634189963, 13.288147204556848]
PINNED_SAFETY_BORESIGHT = [5.456495324797723, 5.456495324835009, 10.612072888671813, 10.612072888652266,
                           None, None]  # frame 5: "attitude too uncertain" for both
PINNED_SAFETY_CENTROIDS = [29, 47, 22]


def _untimed(row: dict) -> dict:
    """A row without its time, NaN as None (comparable with ==)."""
    return {k: None if isinstance(v, float) and math.isnan(v) else v
            for k, v in row.items() if k != "time_ms"}


def _plain(records) -> list[dict]:
    return [_untimed(r._asdict()) for r in records]


def _rows(table) -> list[dict]:
    return [_untimed(row) for row in table.to_pylist()]


def _dask(study, output):
    from dask.distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None)
    with cluster, Client(cluster, set_as_default=False) as client:
        return run_campaign(study, output, client=client)


def test_grid_rows_are_its_fields_here_and_on_dask(tmp_path):
    settings = st.QUICK._replace(trials=3)  # 15°: noise-free and every error, 3 fields each
    study = st.grid_study(settings, METHODS)
    assert (study.trials, study.batch_size, study.n_batches) == (12, 4, 3)  # batches of 2 fields
    here = run_campaign(study, tmp_path / "here.parquet", workers=0).table
    there = _dask(study, tmp_path / "dask.parquet").table
    assert _rows(here) == _rows(there)
    records = st.GridStudy.records(here)
    direct = [r for c in settings.conditions for r in st.run_block(15.0, c, range(3), METHODS, seed=0)]
    assert _plain(records) == _plain(direct)
    assert [(r.method, r.condition, r.trial) for r in records[:4]] == [
        ("quad-hash", "noise-free", 0), ("grid", "noise-free", 0), ("quad-hash", "noise-free", 1),
        ("grid", "noise-free", 1)]
    # the numbers of the study's own pool before it ran on the engine (e64cdec): to the bit on the
    # day they were pinned; the default database's stars are moved to the day it is built (proper
    # motion), which moves a solve by ~1e-5″ a day, so to 1 mas here
    assert [r.n_stars for r in records[::2]] == PINNED_GRID_STARS
    assert [r.boresight_arcsec for r in records if r.method == "quad-hash"] == pytest.approx(
        PINNED_GRID_BORESIGHT, rel=1e-6, abs=1e-3)


def test_safety_rows_stop_continue_and_replay(tmp_path):
    settings = sf.SAFETY_QUICK._replace(trials=3, first=3, block=1)
    study = sf.safety_study(settings, METHODS)
    out = tmp_path / "safety.parquet"
    first = run_campaign(study, out, workers=0, max_batches=1)  # stopped after frame 3
    assert not first.complete
    stopped = sf.read_safety(parts_folder(out))
    assert [(r.trial, r.method) for r in stopped] == [(3, "quad-hash"), (3, "grid")]
    done = _dask(study, out)
    assert (done.batches_before, done.batches_run) == (1, 2)
    records = sf.read_safety(out)
    assert _plain(records[:2]) == _plain(stopped)
    direct = sf.run_safety_block(range(3, 6), METHODS, mix=settings.mix, bands=False)
    assert _plain(records) == _plain(direct)
    got = [None if math.isnan(r.boresight_arcsec) else r.boresight_arcsec for r in records]
    assert [g is None for g in got] == [w is None for w in PINNED_SAFETY_BORESIGHT]
    assert [g for g in got if g is not None] == pytest.approx(  # to 1 mas: the database's day
        [w for w in PINNED_SAFETY_BORESIGHT if w is not None], rel=1e-6, abs=1e-3)
    assert [r.n_centroids for r in records[::2]] == PINNED_SAFETY_CENTROIDS


def test_seed_experiments_are_a_study_of_cases(tmp_path, monkeypatch):
    import pyarrow.parquet as pq

    from skyfix.analysis import identification_cases as ic

    monkeypatch.setitem(ic.CASES, "fake-a", lambda: {"case": "fake-a", "worst": math.nan, "n": (1, 2)})
    monkeypatch.setitem(ic.CASES, "fake-b", lambda: {"case": "fake-b", "rate": 0.25})
    out = tmp_path / "identification_cases.parquet"
    results = ic.run_cases(["fake-b", "fake-a"], out=out)
    assert results == {"fake-b": {"case": "fake-b", "rate": 0.25},
                       "fake-a": {"case": "fake-a", "worst": None, "n": [1, 2]}}  # as the JSON writes them
    table = pq.read_table(out)
    assert table.column("case").to_pylist() == ["fake-b", "fake-a"]
    assert table.column("trial").to_pylist() == [0, 1]
    assert all(t >= 0 for t in table.column("seconds").to_pylist())


@pytest.mark.slow  # two whole (tiny) studies: 9 s at load 6
def test_a_stopped_study_continues(tmp_path):
    """A run of the whole study that stopped in its safety case: run again into the same folder, the
    finished grid is kept and the safety case continues from its finished batches."""
    settings = st.QUICK._replace(trials=2, methods=("quad-hash",))
    safety = sf.SAFETY_QUICK._replace(trials=4, methods=("quad-hash",))
    first = st.run_study(settings, safety=safety, out=tmp_path)
    (tmp_path / "identification_safety.parquet").unlink()
    run_campaign(sf.safety_study(safety, ["quad-hash"]), tmp_path / "identification_safety.parquet",
                 workers=0, max_batches=1)  # the stop
    starts = {}

    def progress(stage: str, done: int, total: int) -> None:
        starts.setdefault(stage, (done, total))

    again = st.run_study(settings, progress, safety=safety, out=tmp_path)
    assert starts == {"safety frames": (1, 2)}  # the grid not run (the engine reports nothing)
    assert _plain(again["records"]) == _plain(first["records"])  # the grid's rows, times and all, kept
    assert [r.time_ms for r in again["records"]] == [r.time_ms for r in first["records"]]
    assert _plain(again["safety"]["records"]) == _plain(first["safety"]["records"])
    assert not parts_folder(tmp_path / "identification_safety.parquet").exists()


def test_an_unreachable_scheduler_is_one_line(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from skyfix.cli import app
    from skyfix.montecarlo import engine

    monkeypatch.setattr(engine, "CONNECT_TIMEOUT_S", 1.0)
    result = CliRunner().invoke(app, ["analyze", "identification", "--quick", "--methods", "quad-hash",
                                      "--scheduler", "tcp://127.0.0.1:9", "--out", str(tmp_path)])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "cannot reach the Dask scheduler at tcp://127.0.0.1:9" in lines[0], lines
