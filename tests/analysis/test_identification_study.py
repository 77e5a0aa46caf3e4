"""The identification study (skyfix.analysis.identification_study): quick mode's numbers, the
confidence bound, the registry walked generically, the seed cases."""

from __future__ import annotations

import json
import math

import pytest
from typer.testing import CliRunner

from skyfix.analysis import identification_jobs as jobs
from skyfix.analysis import identification_study as st
from skyfix.analysis.identification_cases import quest_catalogue
from skyfix.errors import InputError


def test_upper_bound_is_clopper_pearson():
    # none wrong in n: 1 - 0.05**(1/n), close to the rule of three
    assert jobs.upper_bound_95(0, 1000) == pytest.approx(1 - 0.05 ** (1 / 1000), rel=1e-9)
    assert jobs.upper_bound_95(0, 1000) == pytest.approx(3 / 1000, rel=0.01)
    # one in 100: scipy's beta quantile, checked against the binomial tail it inverts
    p = jobs.upper_bound_95(1, 100)
    assert (1 - p) ** 100 + 100 * p * (1 - p) ** 99 == pytest.approx(0.05, abs=1e-9)
    assert jobs.upper_bound_95(5, 5) == 1.0


def test_methods_walked_from_the_registry():
    from skyfix.identify import METHODS

    names = jobs.method_names()
    assert names[0] == "quad-hash" and "hash" not in names  # an alias runs once
    assert set(names) <= set(METHODS)
    assert len(names) == len({id(f) for f in METHODS.values()})
    with pytest.raises(InputError, match="unknown"):
        jobs.method_names(["no-such-method"])


def test_quick_study_quad_hash():
    settings = st.QUICK._replace(methods=("quad-hash",))
    study = st.run_study(settings)
    summary = st.summarize(study)["quad-hash"]
    clean = summary["cells"]["15° noise-free"]
    noisy = summary["cells"]["15° all: σ 1 px, 5 false, 10 % dropped, 0.3 mag"]
    assert clean["n"] == 20 and noisy["n"] == 20
    assert clean["solved"] >= 19  # ≥ 95 % of the noise-free 15° fields
    assert clean["wrong"] == 0 and noisy["wrong"] == 0
    assert noisy["solved"] >= 17
    assert clean["median_boresight_arcsec"] < 2.0  # noise-free: refit to the catalogue
    assert summary["all"]["wrong_upper95_pct"] == pytest.approx(100 * (1 - 0.05 ** (1 / 40)), rel=1e-6)
    # every record carries its field's truth count; the same fields for every method
    assert all(r.n_stars >= 1 for r in study["records"])


def test_same_fields_for_every_method():
    recs = st.run_block(15.0, jobs.CONDITIONS[5], range(3), ["quad-hash", "triangle"], seed=7)
    assert [r.method for r in recs] == ["quad-hash", "triangle"] * 3
    for a, b in zip(recs[::2], recs[1::2], strict=True):
        assert a.trial == b.trial and a.n_stars == b.n_stars
        assert not a.wrong and not b.wrong


def test_quest_on_catalogue_clusters():
    # thesis 000: 96.7 % of its clusters; with correct pairing QUEST returns the identity always
    res = quest_catalogue(n_stars=170, max_angle_deg=31.8)
    assert res["clusters"] > 4000
    assert res["identity"] == res["clusters"]
    assert res["worst_arcsec"] < 1e-3


def test_cli_case_and_bad_names(tmp_path):
    from skyfix.cli import app

    res = CliRunner().invoke(app, ["analyze", "identification", "--case", "nope", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "--case: unknown case 'nope'" in res.output
    res = CliRunner().invoke(app, ["analyze", "identification", "--methods", "bogus", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "bogus" in res.output and "Traceback" not in res.output
    res = CliRunner().invoke(app, ["analyze", "identification", "--quick", "--methods", "quad-hash",
                                   "--trials", "5", "--safety-trials", "4", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    # off a terminal, a line as each stage starts and as each of its engine batches ends: the grid's
    # 10 fields in batches of 2, the safety case's 4 frames in batches of 2
    steps = [line.split(" (")[0] for line in res.output.splitlines() if line.startswith("skyfix: ")]
    assert steps == [f"skyfix: identification grid {k}/5" for k in range(6)] + [
        f"skyfix: safety frames {k}/2" for k in range(3)], steps
    data = json.loads((tmp_path / "identification_study.json").read_text())
    assert len(data["records"]) == 10
    # the trial rows beside the JSON, as Parquet: the same records
    import pyarrow.parquet as pq

    rows = pq.read_table(tmp_path / "identification_study.parquet").to_pylist()
    assert [r["trial"] for r in rows] == list(range(10)) and [r["field"] for r in rows] == [*range(5)] * 2
    assert [r["boresight_arcsec"] for r in rows] == [r["boresight_arcsec"] for r in data["records"]]
    assert pq.read_table(tmp_path / "identification_safety.parquet").num_rows == 4
    safety = data["safety"]
    assert safety["summary"]["quad-hash"]["n"] == 4 and safety["records"]["trial"] == [0, 1, 2, 3]
    assert safety["summary"]["quad-hash"]["wrong"] == 0
    assert "## Safety: 4 frames per method" in (tmp_path / "identification_study.md").read_text()
    assert data["summary"]["quad-hash"]["all"]["wrong"] == 0
    assert math.isfinite(data["summary"]["quad-hash"]["all"]["median_ms"])
    assert (tmp_path / "solved.png").stat().st_size > 1000
