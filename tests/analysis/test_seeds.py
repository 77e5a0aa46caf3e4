"""skyfix analyze seeds: the seed theses' numbers reproduced (issue 27 part 7). Each quick
reproduction that runs in under a minute is pinned here; the registry's commands and
docs/seeds.md are checked against each other."""

import json

import pytest
from typer.testing import CliRunner

from skyfix.analysis.seeds import REPRODUCTIONS, reproduction_keys, run_reproductions
from skyfix.cli import app
from tests.conftest import ROOT


def _one(key: str, quick: bool = True):
    (rep, got), = run_reproductions([key], quick=quick)
    assert rep.key == key and got is not None
    return got


def test_registry_keys_commands_and_docs_agree():
    keys = reproduction_keys()
    assert len(keys) == len(set(keys)) >= 10
    assert {r.thesis for r in REPRODUCTIONS} == {"000", "002", "003", "004"}
    seeds_md = (ROOT / "docs" / "seeds.md").read_text()
    for rep in REPRODUCTIONS:
        assert f"`{rep.key}`" in seeds_md, f"docs/seeds.md does not list {rep.key}"
        words = rep.command.split()
        if words[0] == "skyfix":  # the command exists
            assert CliRunner().invoke(app, [*words[1:3], "-h"] if words[1] in ("analyze", "calibrate")
                                      else [words[1], "-h"]).exit_code == 0, rep.command
        else:
            assert (ROOT / words[words.index("pytest") + 1]).exists(), rep.command
    for path in ("campaigns/thesis003-aptina.toml", "campaigns/thesis003-droid.toml"):
        assert (ROOT / path).exists()


def test_bennett_refraction_matches_thesis_003():
    got = _one("003-bennett")
    assert got.verdict == "matches"
    assert got.numbers["alt_5_arcmin"] == pytest.approx(9.883, abs=5e-4)
    assert got.numbers["alt_40_arcmin"] == pytest.approx(1.1848, abs=5e-5)


def test_table_9_5_holds_for_the_aptina_not_the_droid():
    got = _one("003-table-9-5")
    assert got.verdict == "differs"
    assert got.numbers["Aptina"]["sum_within_2_sigma"] and not got.numbers["Droid X2"]["sum_within_2_sigma"]
    assert got.numbers["Aptina"]["sum"] == pytest.approx(0.526, abs=1e-3)
    assert got.numbers["Droid X2"]["rss"] == pytest.approx(0.617, abs=1e-3)


def test_star_statistics_of_thesis_004():
    got = _one("004-table-5-1")
    assert got.verdict == "matches"
    assert 0.0045 < got.numbers["p_lt3"] < 0.0075  # thesis 0.0056; 10⁶ pointings give 0.00536
    assert 45 <= got.numbers["max"] <= 55  # thesis 49


def test_quest_on_catalogue_triangles_is_never_wrong():
    got = _one("000-quest-catalogue")
    assert got.verdict == "better" and got.numbers["success_pct"] == 100.0
    assert got.numbers["worst_arcsec"] < 1e-3


def test_one_star_moved_is_never_a_wrong_identification():
    got = _one("000-table-6")
    assert got.numbers["wrong"] == 0 and got.numbers["frames"] >= 100  # shifts 0–2 px
    assert got.numbers["right"] == got.numbers["frames"]


def test_cli_prints_each_row_and_writes_json(tmp_path):
    out = tmp_path / "seeds.json"
    r = CliRunner().invoke(app, ["analyze", "seeds", "--only", "003-bennett,002-slope", "--quick",
                                 "--json", str(out)])
    assert r.exit_code == 0, r.output
    assert "9.883′ at 5°" in r.stdout and "[matches]" in r.stdout and "[run the command]" in r.stdout
    rows = json.loads(out.read_text())["rows"]
    assert [row["key"] for row in rows] == ["003-bennett", "002-slope"]
    assert rows[1]["skyfix"] is None and rows[1]["command"] == "skyfix analyze tracking"


def test_unknown_key_is_one_line():
    r = CliRunner().invoke(app, ["analyze", "seeds", "--only", "003-bennett,nosuch"])
    assert r.exit_code == 2 and len(r.stderr.splitlines()) == 1 and "nosuch" in r.stderr
