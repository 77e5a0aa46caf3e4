"""``skyfix cache info|clear`` and ``skyfix database info FILE`` (issue 28, part 4): where the
user cache and the compiled kernels live and their sizes, clearing them with a line that says
what went, and what a pattern database covers. The user cache is a test folder
(``$SKYFIX_CACHE``); the kernels are only ever listed (``--dry-run``), never removed."""

from __future__ import annotations

import json
import re

import pytest
from typer.testing import CliRunner

from skyfix.cli import app


@pytest.fixture
def user_cache(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    folder.mkdir()
    (folder / "patterns_v3_1-2deg.npz").write_bytes(b"x" * 2_000_000)
    (folder / "hip2_v2.npz.lock").write_bytes(b"")
    monkeypatch.setenv("SKYFIX_CACHE", str(folder))
    return folder


def test_cache_info_names_the_folders_and_sizes(user_cache):
    result = CliRunner().invoke(app, ["cache", "info"])
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert lines[0] == f"data: star catalogues and pattern databases: 2 files, 2.0 MB in {user_cache}"
    assert lines[1] == "  patterns_v3_1-2deg.npz  2.0 MB"
    assert re.fullmatch(r"kernels: compiled kernels \(numba's cache and skyfix warmup's modules\): "
                        r"\d+ files, [\d.]+ MB in .*skyfix.*", lines[2])


def test_cache_clear_removes_with_a_line_saying_what(user_cache):
    result = CliRunner().invoke(app, ["cache", "clear", "--only", "data"])
    assert result.exit_code == 0, result.output
    assert result.stdout == (f"data: removed 2 files, 2.0 MB (star catalogues and pattern databases) "
                             f"from {user_cache}\n")
    assert list(user_cache.iterdir()) == []


def test_cache_clear_dry_run_removes_nothing(user_cache):
    from skyfix.cli.cache import cache_areas

    kernels = [a for a in cache_areas() if a.name == "kernels"][0]
    result = CliRunner().invoke(app, ["cache", "clear", "--dry-run"])
    assert result.exit_code == 0, result.output
    assert f"kernels: would remove {len(kernels.files)} files" in result.stdout
    assert len(list(user_cache.iterdir())) == 2 and all(f.exists() for f in kernels.files)


def test_database_info_says_what_it_covers(database):
    from skyfix.identify.catalogue.bands import STANDARD

    result = CliRunner().invoke(app, ["database", "info", str(STANDARD.path), "--json"])
    assert result.exit_code == 0, result.output
    info = json.loads(result.stdout)
    assert (info["fov_min_deg"], info["fov_max_deg"]) == (10.0, 30.0)
    assert info["served_fov_deg"] == pytest.approx([10 / 1.35, 30 * 1.35])
    assert info["pattern_mag_limit"] == 8.5 and info["catalog"] == "Hipparcos 2"
    assert info["size_bytes"] == STANDARD.path.stat().st_size
    text = CliRunner().invoke(app, ["database", "info", str(STANDARD.path)]).stdout
    assert f"{info['n_patterns']} patterns of {info['n_stars']} stars" in text
    assert "serves fields of 7.41–40.5°" in text


def test_database_info_of_no_database_is_one_line(tmp_path):
    bad = tmp_path / "x.npz"
    bad.write_text("nope")
    result = CliRunner().invoke(app, ["database", "info", str(bad)])
    assert result.exit_code == 2 and len(result.stderr.splitlines()) == 1
    assert result.stderr.startswith(f"skyfix: error: pattern database {bad} is unusable")
