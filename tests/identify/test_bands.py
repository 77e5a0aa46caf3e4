"""The default FOV bands: fields from 1° to 90° solve with no hint (issues 10 and 26), each band's
database built on first need, a stale or corrupt one rebuilt."""

import math

import numpy as np
import pytest

import skyfix.identify.catalogue.bands as bands_module
from skyfix.analysis.field_campaign import CASES, case_camera, field_trials, summarize_case
from skyfix.analysis.truth import attitude_error_rad, judge_error
from skyfix.errors import DatabaseError
from skyfix.identify import PatternDatabase
from skyfix.identify.catalogue.bands import BANDS, Band, band_database, bands_for, database_for_fov
from skyfix.pipeline import solve_centroids

ARCSEC = math.pi / (180 * 3600)


def _case(name):
    return next(c for c in CASES if c.name == name)


def test_bands_cover_1_to_90_degrees_and_are_tried_in_order():
    assert [b.name for b in bands_for()] == ["standard", "narrow", "wide", "fine"]
    served = sorted(b.served_fov_deg for b in BANDS)
    assert served[0][0] < 1.0 and served[-1][1] > 90.0
    for below, above in zip(served, served[1:], strict=False):
        assert above[0] < below[1], "a gap between bands"
    assert [b.name for b in bands_for(14, 16)] == ["standard"]
    assert [b.name for b in bands_for(3, 4)] == ["narrow"]
    assert [b.name for b in bands_for(36, 50)] == ["wide", "standard"]  # the most overlap first
    assert [b.name for b in bands_for(0.8, 1.2)] == ["fine"]
    assert [b.name for b in bands_for(1.6, 2.5)] == ["narrow", "fine"]
    assert bands_for(0.5, 0.7) == []


def test_a_fov_hint_outside_every_band_fails_in_one_line_naming_a_deeper_catalogue():
    xy = np.random.default_rng(0).uniform(0, 1000, (20, 2))
    sol = solve_centroids(xy, 1280, 960, fov_deg=0.6)
    assert not sol.solved
    assert "outside every default FOV band (they serve 0.741–122°)" in sol.reason and "\n" not in sol.reason
    # 11.7 stars deg⁻² × 0.6° × 0.45° (0.66° wide at the hint's 10 % tolerance)
    assert "holds about 3 stars of the bundled catalogue" in sol.reason
    assert "`skyfix database build --fov-min 0.54 --fov-max 0.66 --catalog DEEP.csv" in sol.reason
    with pytest.raises(DatabaseError, match="outside every default FOV band"):
        database_for_fov(150.0)


def test_a_band_built_with_other_settings_or_corrupt_is_rebuilt(tmp_path, monkeypatch):
    monkeypatch.setenv("SKYFIX_CACHE", str(tmp_path))
    monkeypatch.setattr(bands_module, "_LOADED", {})
    band = Band("test", 60.0, 60.0)
    db = band_database(band, progress=False)
    assert band.path.exists() and db.meta["stars_per_field"] == 8
    # the same file name, other settings: not used, rebuilt with the band's
    monkeypatch.setattr(bands_module, "_LOADED", {})
    other = band._replace(stars_per_field=6)
    assert other.path == band.path
    rebuilt = band_database(other, progress=False)
    assert rebuilt.meta["stars_per_field"] == 6
    assert PatternDatabase.load(band.path).meta["stars_per_field"] == 6
    # a truncated file: rebuilt, never used
    monkeypatch.setattr(bands_module, "_LOADED", {})
    data = band.path.read_bytes()
    band.path.write_bytes(data[: len(data) // 2])
    again = band_database(other, progress=False)
    assert len(again) == len(rebuilt)
    assert PatternDatabase.load(band.path).meta["stars_per_field"] == 6


def test_narrow_fields_solve_from_gaia_with_no_hint():
    """3° fields (Gaia to G 10): the narrow band's database is built on first need."""
    case = _case("4°")._replace(name="3°", fov_deg=3.0)
    trials = field_trials(case, 8, seed=5)
    s = summarize_case(case, trials)
    assert s["frames_min_stars"] == 8
    assert s["solved_min_stars"] >= 7 and s["wrong"] == 0, s
    assert s["median_boresight_arcsec"] < 3.0  # 8.4″ pixels
    assert all(0.4 < v < 2.0 for v in s["normalised_rms"])


def test_1_degree_fields_solve_from_gaia_with_no_hint():
    """1° fields (Gaia to G 10, ~9 stars in view on average): the fine band, with no hint, and a
    failure where too few stars are in view."""
    case = _case("4°")._replace(name="1°", fov_deg=1.0)
    trials = field_trials(case, 12, seed=3)
    s = summarize_case(case, trials)
    countable = [t.trial for t in trials if t.trial.n_stars >= 8]
    assert len(countable) >= 6, s
    assert sum(t.solved for t in countable) >= len(countable) - 1 and s["wrong"] == 0, s
    assert s["median_boresight_arcsec"] < 1.5  # 2.8″ pixels


def test_a_60_degree_barrel_lens_solves_with_no_camera_file():
    """k1 = −0.3 squeezes the corners of a 60° frame by 22 %: found among the distortion hypotheses."""
    case = _case("60°, k1 −0.3")
    camera = case_camera(case)
    trials = field_trials(case, 6, seed=11)
    solved = [t.trial for t in trials if t.trial.solved]
    assert len(solved) >= 5
    for t in solved:
        assert not judge_error(t.error_rad, t.plate_scale_arcsec).wrong
        assert math.hypot(*t.error_rad[:2]) / ARCSEC < 40.0  # 200″ pixels
    assert camera.k1 == -0.3


def test_the_standard_band_is_the_default_database_and_the_solution_names_its_catalogue(database):
    assert database.meta.get("catalog_source", "hipparcos") == "hipparcos"
    cam = case_camera(_case("15°"))
    from skyfix.analysis.synthetic_centroids import synthetic_centroids
    from skyfix.catalog import load_hipparcos

    A = np.eye(3)
    f = synthetic_centroids(cam, A, load_hipparcos(epoch=2025.0), mag_limit=7.0, sigma_px=0.3, rng=1)
    sol = solve_centroids(f.xy, cam.width, cam.height, epoch=2025.0)
    assert sol.solved and sol.catalog == "Hipparcos 2" and sol.catalog_epoch == 2025.0
    err = attitude_error_rad(sol.A_icrs_to_cam, sol.camera, A, cam)
    assert math.hypot(err[0], err[1]) / ARCSEC < 5.0


def test_cli_builds_every_default_band_and_says_what_it_serves():
    from typer.testing import CliRunner

    from skyfix.cli import app

    result = CliRunner().invoke(app, ["database", "build", "--default-bands"])
    assert result.exit_code == 0, result.output
    lines = result.output.strip().splitlines()
    assert [line.split(":")[0] for line in lines] == ["standard", "narrow", "wide", "fine"]
    assert "serves 1.48–8.1°" in lines[1] and "482176 stars" in lines[1]
    assert "serves 0.741–1.96°" in lines[3] and "482176 stars" in lines[3]


def test_a_fisheye_camera_given_selects_the_band_of_its_true_field():
    """A 90° equidistant camera (fx says 76° to a pinhole): solved in the wide band, its corners
    (112° off axis) kept out of the search's frame."""
    from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
    from skyfix.catalog import load_gaia

    cam = case_camera(_case("90° fisheye"))
    rng = np.random.default_rng(4)
    for A in random_attitudes(3, rng):
        f = synthetic_centroids(cam, A, load_gaia(epoch=2025.0), mag_limit=5.0, sigma_px=0.5, n_false=2,
                                dropout=0.05, rng=rng)
        sol = solve_centroids(f.xy[:200], cam.width, cam.height, epoch=2025.0, camera=cam)
        assert sol.solved, sol.reason
        err = attitude_error_rad(sol.A_icrs_to_cam, sol.camera, A, cam)
        assert math.hypot(err[0], err[1]) / ARCSEC < 60.0 and abs(err[2]) / ARCSEC < 120.0
