"""The blind and field campaigns on the campaign engine (issue 27): their rows are those of the
serial loops they replaced (kept here verbatim as the reference, as they were at e64cdec), in
this process and on Dask's workers, whichever batch a trial falls in.

Measured before the port (e64cdec's sources) and after, ``uncalibrated_centroid_trials(40,
seed=3)``, ``preset_image_trials`` (generic 3 false + 20 hot ×6, mt9v022 ×4, seed 2) and
``field_trials`` (cases 2°, 15°, 90° fisheye, 12 frames, seed 7): all 86 trials bit-identical;
``benchmarks/same-results`` (``--quick``, its blind section 50 uncalibrated trials with each
full solution): every record identical.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

pytest.importorskip("dask.distributed")
pytest.importorskip("pyarrow")

from skyfix.analysis import blind_campaign as bc  # noqa: E402
from skyfix.analysis import field_campaign as fc  # noqa: E402
from skyfix.montecarlo.engine import run_rows  # noqa: E402

EPOCH = 2025.0


def _old_uncalibrated(n: int, seed: int) -> list[bc.Trial]:
    """``uncalibrated_centroid_trials`` and ``uncalibrated_fields`` of e64cdec."""
    from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
    from skyfix.catalog import load_hipparcos
    from skyfix.pipeline import solve_centroids

    def fields():
        catalog = load_hipparcos(epoch=EPOCH)
        rng = np.random.default_rng(seed)
        while True:
            camera = bc.random_uncalibrated_camera(rng)
            A = random_attitudes(1, rng)[0]
            field = synthetic_centroids(camera, A, catalog, mag_limit=rng.uniform(5.0, 8.0),
                                        sigma_px=rng.uniform(0.1, 1.0), n_false=int(rng.integers(0, 6)),
                                        dropout=0.05, rng=rng)
            n_real = int((field.star_id > 0).sum())
            if 8 <= n_real <= 40:
                yield camera, A, field, n_real

    return [bc.trial_result(solve_centroids(f.xy, cam.width, cam.height, epoch=EPOCH), A, cam, k)
            for cam, A, f, k in itertools.islice(fields(), n)]


def _old_field(case: fc.FieldCase, n: int, seed: int) -> list[bc.Trial]:
    """``field_trials`` of e64cdec (its trials, the times left out)."""
    from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
    from skyfix.catalog import load_gaia
    from skyfix.pipeline import solve_centroids

    catalog, camera = load_gaia(epoch=EPOCH), fc.case_camera(case)
    rng = np.random.default_rng(seed)
    out = []
    for A in random_attitudes(n, rng):
        field = synthetic_centroids(camera, A, catalog, mag_limit=case.mag_limit, sigma_px=case.sigma_px,
                                    n_false=int(rng.integers(0, case.max_false + 1)), dropout=case.dropout,
                                    mag_sigma=case.mag_sigma, rng=rng)
        sol = solve_centroids(field.xy[:200], case.width, case.height, epoch=EPOCH)
        out.append(bc.trial_result(sol, A, camera, int((field.star_id != 0).sum())))
    return out


def _old_preset(preset: str, n: int, seed: int, false_stars: int, hot_pixels: int) -> list[bc.Trial]:
    """``preset_image_trials`` of e64cdec."""
    from skyfix.analysis.synthetic_centroids import random_attitudes
    from skyfix.camera import camera_from_preset
    from skyfix.pipeline import solve
    from skyfix.simulate import render

    camera = camera_from_preset(preset)
    out = []
    for k, A in enumerate(random_attitudes(n, np.random.default_rng(seed))):
        frame = render(A, preset, epoch=EPOCH, seed=seed * 100003 + k, false_stars=false_stars,
                       hot_pixels=hot_pixels)
        n_stars = sum(1 for s in frame.truth["stars"]
                      if -0.5 <= s["x"] <= camera.width - 0.5 and -0.5 <= s["y"] <= camera.height - 0.5)
        out.append(bc.trial_result(solve(frame.image, epoch=EPOCH), A, camera, n_stars))
    return out


def _same(a: list[bc.Trial], b: list[bc.Trial]) -> None:
    assert len(a) == len(b)
    for k, (x, y) in enumerate(zip(a, b, strict=True)):
        assert x.solved == y.solved and x.reason == y.reason and x.n_stars == y.n_stars, k
        assert x.fov_deg == y.fov_deg and x.plate_scale_arcsec == y.plate_scale_arcsec, k
        assert np.array_equal(x.error_rad, y.error_rad, equal_nan=True), k  # bit for bit
        assert np.array_equal(x.sigma_rad, y.sigma_rad, equal_nan=True), k


def _untimed(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in ("time_ms", "cpu_ms")} for r in rows]


def _forget_sequences() -> None:
    """A new process's memos: every batch steps its sequence from the start."""
    bc._SEQUENCE_STATES.clear()
    fc._ATTITUDES.clear()


def test_uncalibrated_rows_are_the_serial_loops(tmp_path):
    _forget_sequences()
    trials = bc.uncalibrated_centroid_trials(5, seed=3, epoch=EPOCH, batch_size=2,
                                             output=tmp_path / "u.parquet")
    _same(trials, _old_uncalibrated(5, 3))
    # e64cdec's numbers for these fields: solved, stars in view
    assert [(t.solved, t.n_stars) for t in trials] == [(True, 35), (True, 30), (True, 32), (True, 29),
                                                       (False, 9)]
    assert trials[0].fov_deg == 14.393883678094694
    import pyarrow.parquet as pq

    rows = pq.read_table(tmp_path / "u.parquet").to_pylist()
    study = bc.UncalibratedStudy(5, 2, {"seed": 3, "epoch": EPOCH})
    assert list(rows[0]) == list(study.columns)
    _forget_sequences()
    assert _untimed([study.run_trial(3)]) == _untimed(rows[3:4])  # alone, from the start of the sequence
    assert rows[4]["status"] == "failed" and math.isnan(rows[4]["boresight_error_arcsec"])
    assert rows[0]["status"] == "solved" and not rows[0]["wrong"]
    assert rows[0]["boresight_error_arcsec"] == pytest.approx(
        math.hypot(rows[0]["error_x_rad"], rows[0]["error_y_rad"]) * 180 / math.pi * 3600)


def test_field_rows_in_process_and_on_dask_threads_are_the_serial_loop(tmp_path):
    from dask.distributed import Client, LocalCluster

    cases, n = [fc.CASES[2], fc.CASES[5]], 12
    study = fc.field_study(cases, n, seed=7, epoch=EPOCH, batch_size=5)  # batches across both cases
    _forget_sequences()
    here = run_rows(study, tmp_path / "here.parquet", workers=0).to_pylist()
    _forget_sequences()
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster, Client(cluster, set_as_default=False) as client:
        from skyfix.montecarlo.engine import run_campaign

        there = run_campaign(study, tmp_path / "dask.parquet", client=client).table.to_pylist()
    assert _untimed(here) == _untimed(there)
    assert [r["trial"] for r in here] == list(range(2 * n))
    assert [r["case"] for r in here] == ["2°"] * n + ["15°"] * n
    for k, case in enumerate(cases):
        _same([bc.trial_of_row(r) for r in here[k * n:(k + 1) * n]], _old_field(case, n, 7))
    # e64cdec's stars in view, frame by frame
    assert [r["n_stars"] for r in here[:n]] == [76, 23, 39, 17, 18, 14, 23, 36, 17, 58, 21, 25]
    assert [r["n_stars"] for r in here[n:]] == [138, 64, 53, 62, 106, 62, 72, 92, 50, 134, 68, 75]
    assert all(r["cpu_ms"] > 0 and r["time_ms"] > 0 for r in here)
    one = fc.field_trials(cases[1], n, 7, epoch=EPOCH)
    _same([t.trial for t in one], [bc.trial_of_row(r) for r in here[n:]])  # the one case alone


def test_preset_rows_are_the_serial_loop():
    trials = bc.preset_image_trials("generic", 2, seed=2, false_stars=3, hot_pixels=20, epoch=EPOCH)
    _same(trials, _old_preset("generic", 2, 2, 3, 20))
    assert [t.n_stars for t in trials] == [547, 948]  # e64cdec's


def test_field_main_writes_the_rows_and_refuses_an_unreachable_scheduler(tmp_path, monkeypatch, capsys):
    import pyarrow.parquet as pq

    import skyfix.montecarlo.engine as engine

    monkeypatch.setattr(fc, "CASES", fc.CASES[2:4])
    assert fc.main(["--n", "2", "--seed", "5", "--out", str(tmp_path)]) == 0
    table = pq.read_table(tmp_path / "fields.parquet")
    assert table.column("trial").to_pylist() == [0, 1, 2, 3]
    assert table.column("case").to_pylist() == ["2°", "2°", "4°", "4°"]
    written = {p.name for p in tmp_path.iterdir()}
    assert written == {"fields.parquet", "fields.json", "fields.md", "fields.png"}
    capsys.readouterr()
    monkeypatch.setattr(engine, "CONNECT_TIMEOUT_S", 0.5)
    assert fc.main(["--n", "2", "--out", str(tmp_path / "x"), "--scheduler", "tcp://127.0.0.1:9"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot reach the Dask scheduler at tcp://127.0.0.1:9" in err[0]
