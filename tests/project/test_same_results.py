"""benchmarks/same_results.py: two records of the same code compare equal; a perturbed one does not."""

import sys

import numpy as np
import pytest

from tests.conftest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))

import same_results  # noqa: E402

TINY = same_results.Plan(real=2, synthetic_per_config=1, sim_frames=0, bench_frames_per_fov=0, blind=0,
                         database_fov=None)


@pytest.fixture(scope="module")
def two_records(real_dir, tmp_path_factory):
    folder = tmp_path_factory.mktemp("same_results")
    paths = []
    for k in range(2):
        records, meta = same_results.record(TINY, progress=False)
        paths.append(folder / f"r{k}.npz")
        same_results.save_record(paths[-1], records, meta)
    return paths


def test_two_records_of_the_same_code_are_the_same(two_records, capsys):
    records, _ = same_results.load_record(two_records[0])
    assert len(records["real"]) == 2 and len(records["synthetic"]) == 5
    assert same_results.main(["compare", *map(str, two_records)]) == 0
    out = capsys.readouterr().out
    assert "SAME" in out and "DIFFERENT" not in out


def test_a_perturbed_quaternion_is_a_difference(two_records, tmp_path, capsys):
    records, meta = same_results.load_record(two_records[1])
    name = next(iter(records["synthetic"]))
    fields = records["synthetic"][name]
    assert str(fields["fov.status"]) == "solved"
    fields["fov.q"] = fields["fov.q"] + np.array([1e-9, 0.0, 0.0, 0.0])
    bad = tmp_path / "perturbed.npz"
    same_results.save_record(bad, records, meta)
    assert same_results.main(["compare", str(two_records[0]), str(bad)]) == 1
    out = capsys.readouterr().out
    assert "DIFFERENT" in out and name in out and "fov.q" in out
    result = same_results.compare_records(same_results.load_record(two_records[0])[0], records)
    assert result["synthetic"].identical == 4 and len(result["synthetic"].differences) == 1
    assert 0 < result["synthetic"].max_attitude_arcsec < 1e-3  # 2e-9 rad ≈ 4e-4″
    assert result["real"].identical == 2


def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys):
    junk = tmp_path / "junk.npz"
    junk.write_text("not a zip")
    for argv in (["compare", str(tmp_path / "missing.npz"), str(junk)], ["compare", str(junk), str(junk)],
                 ["against", "no-such-ref-xyz"], ["frobnicate"], ["record", str(tmp_path / "x.txt")]):
        assert same_results.main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("same_results.py: error:")


def test_nan_fields_of_a_failed_solve_compare_equal():
    failed = {"sol.A": np.full((3, 3), np.nan), "sol.prob_false": np.array(np.nan),
              "sol.status": np.array("failed"), "c.x": np.array([1.0, np.inf])}
    same = {k: v.copy() for k, v in failed.items()}
    assert same_results.compare_fields(failed, same) == ([], 0.0, 0.0, True)
    other = dict(failed, **{"sol.prob_false": np.array(1e-12)})
    notes, _, _, exact = same_results.compare_fields(failed, other)
    assert not exact and len(notes) == 1 and notes[0].startswith("sol.prob_false")
