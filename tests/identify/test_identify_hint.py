"""Identification from a known attitude (skyfix.identify.hint, solve(attitude_hint=...),
``skyfix solve --attitude-hint``): near a good hint the same attitude as lost in space, a far
wrong hint falls back to lost in space, a wrong hint never makes a wrong attitude "solved", bad
hints are one-line errors."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
from skyfix.attitude import attitude_error
from skyfix.camera import Camera
from skyfix.catalog import load_hipparcos
from skyfix.errors import InputError
from skyfix.identify.accept import WRONG_BORESIGHT_ARCSEC, WRONG_ROLL_DEG
from skyfix.identify.hint import METHOD, AttitudeHint, check_attitude_hint, identify_near
from skyfix.pipeline import solve, solve_centroids
from tests.conftest import EXAMPLES

W, H = 1280, 960
CAMERA = Camera.from_fov(W, H, 15.0)
ARCSEC = math.pi / (180 * 3600)


@pytest.fixture(scope="module")
def catalog(database):
    return load_hipparcos(epoch=database.epoch, mag_limit=8.0)


def _field(catalog, seed, **kw):
    A = random_attitudes(1, rng=seed)[0]
    return synthetic_centroids(CAMERA, A, catalog, sigma_px=0.5, rng=seed, **kw)


def _off(A, angle_deg, seed):
    """``A`` turned by ``angle_deg`` about a random axis."""
    axis = np.random.default_rng(seed).normal(size=3)
    axis /= np.linalg.norm(axis)
    return Rotation.from_rotvec(math.radians(angle_deg) * axis).as_matrix() @ A


def _errors_arcsec(A_true, A_est):
    """Boresight and roll error, arcsec."""
    e = attitude_error(A_true, A_est) / ARCSEC
    return math.hypot(e[0], e[1]), abs(e[2])


# --- good hints ----------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [11, 12])
@pytest.mark.parametrize(("offset_deg", "uncertainty_deg"), [(0.1, 0.2), (1.0, 1.5), (3.0, 4.0)])
def test_good_hint_solves_as_lost_in_space(catalog, database, seed, offset_deg, uncertainty_deg):
    f = _field(catalog, seed)
    hint = AttitudeHint(_off(f.A_icrs_to_cam, offset_deg, seed), math.radians(uncertainty_deg))
    near = solve_centroids(f.xy, W, H, camera=CAMERA, database=database, attitude_hint=hint)
    lost = solve_centroids(f.xy, W, H, camera=CAMERA, database=database)
    assert near.solved and near.method == METHOD, near.reason
    assert lost.solved and lost.method == "quad-hash"
    bore, roll = _errors_arcsec(f.A_icrs_to_cam, near.A_icrs_to_cam)
    assert bore < 3.0 and roll < 30.0
    # the same stars, the same attitude as lost in space
    assert {m.id for m in near.matches} == {m.id for m in lost.matches}
    assert max(_errors_arcsec(lost.A_icrs_to_cam, near.A_icrs_to_cam)) < 0.01
    assert near.prob_false < 1e-9


def test_identify_near_matches_the_true_stars(catalog, database):
    f = _field(catalog, 21, n_false=5)
    A_hint = _off(f.A_icrs_to_cam, 0.5, 21)
    res = identify_near(f.xy, CAMERA, A_hint, math.radians(1.0), database=database)
    assert res.success, res.reason
    _assert_true_stars(res, f, catalog)
    assert len(res.star_index) >= 0.9 * np.count_nonzero(~f.is_false)
    assert np.all(np.diff(res.star_index) > 0)
    assert max(_errors_arcsec(f.A_icrs_to_cam, res.A_icrs_to_cam)) < 30.0
    assert res.prob_false < 1e-9 and res.n_trials >= res.n_candidates >= 1
    ident = res.identification()
    assert ident.success and ident.method == METHOD and np.array_equal(ident.star_index, res.star_index)
    # a magnitude limit predicts only the brighter stars; NaN rows keep the caller's indices
    bright = identify_near(f.xy, CAMERA, A_hint, math.radians(1.0), database=database, mag_limit=6.5)
    assert bright.success and bright.catalog_mag.max() <= 6.5 and len(bright.star_index) < len(res.star_index)
    xy = np.insert(f.xy, 3, np.nan, axis=0)
    shifted = identify_near(xy, CAMERA, A_hint, math.radians(1.0), database=database)
    assert shifted.success
    assert np.array_equal(shifted.star_index - (shifted.star_index > 3), res.star_index)


def test_hint_with_a_field_of_view_fits_the_camera(catalog, database):
    f = _field(catalog, 31)
    hint = AttitudeHint(_off(f.A_icrs_to_cam, 1.0, 31), math.radians(1.5))
    sol = solve_centroids(f.xy, W, H, fov_deg=14.0, database=database, attitude_hint=hint)
    assert sol.solved and sol.method == METHOD, sol.reason
    assert sol.fov_deg == pytest.approx(15.0, abs=0.01)
    # no camera: the principal point is fitted too, so compare the image centre's attitude (the true
    # principal point's), and lost in space's, which is the same
    centre = sol.attitude_at_pixel((W - 1) / 2, (H - 1) / 2)
    assert _errors_arcsec(f.A_icrs_to_cam, centre)[0] < 20.0  # 9″: the fitted principal point's
    lost = solve_centroids(f.xy, W, H, fov_deg=14.0, database=database)
    assert max(_errors_arcsec(lost.A_icrs_to_cam, sol.A_icrs_to_cam)) < 0.01


def test_hint_without_a_scale_solves_lost_in_space(catalog, database):
    f = _field(catalog, 41)
    sol = solve_centroids(f.xy, W, H, database=database, attitude_hint=AttitudeHint(f.A_icrs_to_cam, 0.01))
    assert sol.solved and sol.method == "quad-hash"


# --- wrong hints -----------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [51, 52])
def test_far_wrong_hint_falls_back_to_lost_in_space(catalog, database, seed):
    f = _field(catalog, seed)
    hint = AttitudeHint(_off(f.A_icrs_to_cam, 30.0, seed), math.radians(1.0))
    res = identify_near(f.xy, CAMERA, hint.A_icrs_to_cam, hint.uncertainty_rad, database=database)
    assert not res.success and res.A_icrs_to_cam is None and res.reason
    sol = solve_centroids(f.xy, W, H, camera=CAMERA, database=database, attitude_hint=hint)
    assert sol.solved and sol.method == "quad-hash"
    assert _errors_arcsec(f.A_icrs_to_cam, sol.A_icrs_to_cam)[0] < 5.0


def test_wrong_hint_with_too_few_stars_fails_with_a_reason(catalog, database):
    f = _field(catalog, 61)
    for A in (f.A_icrs_to_cam, _off(f.A_icrs_to_cam, 5.0, 61)):
        sol = solve_centroids(f.xy[:3], W, H, camera=CAMERA, database=database,
                              attitude_hint=AttitudeHint(A, math.radians(10.0)))
        assert sol.status == "failed" and sol.A_icrs_to_cam is None
        assert "attitude hint: too few stars (3 detected, need 4)" in sol.reason


def _assert_true_stars(res, f, catalog):
    """Every matched centroid of a real star got that star or, in a close pair, its neighbour
    within 20″ (a blend the synthetic field keeps apart); at most one false star matched (to a
    catalogue star fainter than the field's, by chance)."""
    ids = f.star_id[res.star_index]
    real = ids != 0
    row = {int(h): i for i, h in enumerate(catalog.ids)}
    true_v = catalog.vectors[[row[int(h)] for h in ids[real]]]
    sep = np.degrees(np.arccos(np.clip(np.sum(true_v * res.catalog_vectors[real], axis=1), -1, 1))) * 3600
    assert np.all(sep < 20.0)
    assert np.count_nonzero(~real) <= 1


def test_wrong_hints_never_give_a_wrong_attitude(catalog, database):
    """Sparse and dense fields (5 to 40 stars, some false), hints with the truth inside their
    uncertainty (1–10°) and outside it (off by 1–15° more), and random points: whatever
    identify_near accepts is the true attitude."""
    rng = np.random.default_rng(71)
    n_ok = n_inside = 0
    for trial in range(40):
        f = _field(catalog, 100 + trial, n_false=int(rng.integers(0, 4)))
        xy = f.xy[: int(rng.integers(5, 40))]
        unc = float(rng.uniform(1.0, 10.0))
        kind = trial % 4  # 0, 1: truth inside the uncertainty; 2: outside; 3: no sky at all
        off = unc * float(rng.uniform(0.2, 0.9)) if kind < 2 else unc + float(rng.uniform(1.0, 15.0))
        if kind == 3:
            xy = rng.uniform([0, 0], [W, H], (len(xy), 2))
        n_inside += kind < 2
        A_hint = _off(f.A_icrs_to_cam, off, trial)
        res = identify_near(xy, CAMERA, A_hint, math.radians(unc), database=database)
        if res.success:
            n_ok += 1
            assert kind != 3
            bore, roll = _errors_arcsec(f.A_icrs_to_cam, res.A_icrs_to_cam)  # not wrong (accept.py's bars)
            assert bore < WRONG_BORESIGHT_ARCSEC and roll < 3600 * WRONG_ROLL_DEG
            _assert_true_stars(res, f, catalog)
    assert n_ok >= n_inside // 2  # the truth inside the uncertainty is found often enough to mean something


# --- bad hints -------------------------------------------------------------------------------------
@pytest.mark.parametrize(("text", "message"), [
    ("abc", "attitude_hint 'abc' must be RA,DEC,ROLL[,UNCERTAINTY_DEG] in degrees"),
    ("10,20", "attitude_hint '10,20' must be RA,DEC,ROLL[,UNCERTAINTY_DEG] in degrees"),
    ("10,20,30,1,5", "must be RA,DEC,ROLL"),
    ("10,nan,30", "must be RA,DEC,ROLL"),
    ("10,95,0", "attitude_hint: Dec 95 is outside -90..90 degrees"),
    ("10,20,30,-1", "attitude_hint: uncertainty -1° must be a positive number of degrees up to 30"),
    ("10,20,30,0", "uncertainty 0° must be a positive number"),
    ("10,20,30,45", "uncertainty 45° must be a positive number"),
])
def test_bad_hint_is_one_line(text, message):
    with pytest.raises(InputError) as err:
        check_attitude_hint(text)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_hint_forms_and_bad_matrices():
    a = check_attitude_hint("84,-2,20")
    b = check_attitude_hint((84, -2, 20, 1.0))
    assert np.allclose(a.A_icrs_to_cam, b.A_icrs_to_cam)
    assert a.uncertainty_rad == pytest.approx(math.radians(1))
    assert np.array_equal(check_attitude_hint(a.A_icrs_to_cam).A_icrs_to_cam, a.A_icrs_to_cam)
    with pytest.raises(InputError, match="is not a rotation matrix"):
        check_attitude_hint(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(InputError, match="is not a rotation matrix"):
        check_attitude_hint(2 * np.eye(3))
    xy = np.zeros((10, 2))
    with pytest.raises(InputError, match="Dec 95 is outside"):
        solve_centroids(xy, W, H, camera=CAMERA, attitude_hint="10,95,0")
    with pytest.raises(InputError, match="uncertainty_rad: uncertainty -1°"):
        identify_near(xy, CAMERA, np.eye(3), math.radians(-1.0))


def _cli(*args):
    from skyfix.cli import app

    result = CliRunner().invoke(app, [str(a) for a in args])
    assert "Traceback" not in result.output
    return result


@pytest.mark.parametrize(("hint", "message"), [
    ("x,y,z", "--attitude-hint 'x,y,z' must be RA,DEC,ROLL[,UNCERTAINTY_DEG] in degrees"),
    ("84,-95,20", "--attitude-hint: Dec -95 is outside -90..90 degrees"),
    ("84,-2,20,-1", "--attitude-hint: uncertainty -1° must be a positive number of degrees up to 30"),
])
def test_cli_bad_hint_exit_2(hint, message):
    result = _cli("solve", EXAMPLES / "sky.png", "--attitude-hint", hint)
    assert result.exit_code == 2 and result.stdout == ""
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"skyfix: error: {message}"), result.stderr


def test_cli_solves_near_the_hint():
    import json

    camera = EXAMPLES / "sky.camera.toml"
    result = _cli("solve", EXAMPLES / "sky.png", "--camera", camera, "--attitude-hint", "84.4,-2.2,20.3,1.5",
                  "--json")
    assert result.exit_code == 0, result.output
    sol = json.loads(result.stdout)
    assert sol["method"] == METHOD and sol["status"] == "solved"
    assert sol["ra_deg"] == pytest.approx(84.0, abs=0.001)
    assert sol["dec_deg"] == pytest.approx(-2.0, abs=0.001)
    text = _cli("solve", EXAMPLES / "sky.png", "--camera", camera, "--attitude-hint=-275.6,-2.2,20.3")
    assert text.exit_code == 0 and text.stdout.rstrip().endswith("| near the attitude hint"), text.output


# --- a real image -----------------------------------------------------------------------------------
def test_real_image_solves_near_its_perturbed_solution(real_dir, database):
    path = real_dir / "esa-tetra3/2019-07-29T204726_Alt40_Azi-135_Try1.tiff"
    lost = solve(path, database=database)
    assert lost.solved, lost.reason
    hint = AttitudeHint(_off(lost.A_icrs_to_cam, 1.0, 81), math.radians(1.5))
    near = solve(path, database=database, fov_deg=lost.fov_deg, attitude_hint=hint)
    assert near.solved and near.method == METHOD, near.reason
    assert near.n_matched >= 0.9 * lost.n_matched
    bore, roll = _errors_arcsec(lost.A_icrs_to_cam, near.A_icrs_to_cam)
    assert bore < 5.0 and roll < 60.0
