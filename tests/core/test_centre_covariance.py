"""Two error bars for two points (issue 26 part 1): ``covariance_arcsec2`` is the attitude's — the
camera axes through the principal point, its own uncertainty included when it is fitted — and
``center_covariance_arcsec2`` the image centre's frame (its direction and the roll of image-up
there: ``center_ra_deg``, ``center_dec_deg``, ``center_roll_deg``), from the same fit's posterior
(:func:`skyfix.final_fit.covariance_at_pixel`). With the principal point at the centre the two
are one. Each is checked against the truth: the error over its σ."""

import json
import math
import sys

import numpy as np
import pytest

from skyfix._kernels.rotation import rotation_vector
from skyfix.analysis.truth import judge
from skyfix.attitude import attitude_error
from skyfix.calibrate import CameraPrior, fit_camera_with_prior, frame_at_pixel, frame_covariance_at_pixel
from skyfix.camera import Camera
from skyfix.catalog import load_hipparcos
from skyfix.geometry import attitude_from_radec_roll
from skyfix.pipeline import solve_centroids
from tests.conftest import ROOT

ARCSEC = math.radians(1 / 3600)


@pytest.fixture(scope="module")
def stars():
    return load_hipparcos(epoch=2025.0, mag_limit=7.5)


def _field(camera, A, catalog, sigma_px, rng):
    uv, front = camera.ray_to_pixel(catalog.vectors @ A.T)
    ok = front & camera.in_frame(uv)
    return uv[ok] + rng.normal(0, sigma_px, (ok.sum(), 2)), catalog.vectors[ok]


def _centre_error(sol, A_true, camera_true) -> np.ndarray:
    """The image centre's frame (``along="row"``: what ``center_*`` report), estimated against
    true, about its axes (rad)."""
    c = tuple(sol.center_px)
    return rotation_vector(frame_at_pixel(sol.A_icrs_to_cam, sol.camera, c, "row")
                           @ frame_at_pixel(A_true, camera_true, c, "row").T)


def _normalised(error_rad, covariance_arcsec2) -> np.ndarray:
    return error_rad / (np.sqrt(np.diag(np.asarray(covariance_arcsec2))) * ARCSEC)


def test_the_centre_frames_covariance_is_its_jacobians_of_the_posterior(stars):
    """The frame at a pixel's covariance (rotations exact, camera numbers by central differences)
    against the spread of that frame over 3000 draws of the fit's posterior, each draw's camera
    made by the fit's own step (:func:`skyfix._kernels.camera_jacobian.apply_step`): within 5 %
    at the image centre, 64 px from the fitted principal point; and at the principal point it is
    the covariance the fit's kernel makes with its own linear map
    (:func:`skyfix._kernels.camera_fit.frame_covariance`)."""
    from skyfix._kernels import lens
    from skyfix._kernels.camera_fit import apply_step
    from skyfix._kernels.rotation import rodrigues
    from skyfix.calibrate import CAMERA_PARAMETERS

    rng = np.random.default_rng(3)
    truth = Camera(1280, 960, 2700.0, 2700.0, 690.0, 440.0, k1=-0.2)
    A = attitude_from_radec_roll(1.0, 0.4, 2.0)
    xy, r = _field(truth, A, stars, 0.3, rng)
    fit = fit_camera_with_prior(xy[:80], r[:80], Camera.from_fov(1280, 960, truth.fov_deg), A,
                                CameraPrior.uncalibrated(1280, 960), principal_point="fit")
    at_pp = frame_covariance_at_pixel(fit, (fit.camera.cx, fit.camera.cy), "column")
    np.testing.assert_allclose(at_pp, fit.covariance_rad2, rtol=2e-3, atol=1e-6 * np.abs(at_pp).max())

    centre = (639.5, 479.5)
    C = fit.parameter_covariance
    cam = fit.camera
    codes = np.array([CAMERA_PARAMETERS[name].code for name in fit.parameters], dtype=np.int64)
    rmax = math.hypot(cam.width, cam.height) / 2.0 / cam.fx
    F0 = frame_at_pixel(np.eye(3), cam, centre, "row")
    draws = rng.multivariate_normal(np.zeros(len(C)), C, 3000)
    spread = []
    for p in draws:
        numbers = apply_step.py_func(cam.numbers(), rmax, codes, p)
        drawn = cam.replace(**dict(zip(lens.CAMERA_NUMBERS, numbers.tolist(), strict=True)))
        F = frame_at_pixel(rodrigues(np.ascontiguousarray(p[:3])), drawn, centre, "row")
        spread.append(rotation_vector(np.ascontiguousarray(F @ F0.T)))
    sigma_drawn = np.std(spread, axis=0)
    sigma = np.sqrt(np.diag(frame_covariance_at_pixel(fit, centre)))
    np.testing.assert_allclose(sigma, sigma_drawn, rtol=0.05)
    assert not np.allclose(sigma, np.sqrt(np.diag(C[:3, :3])), rtol=0.2)  # not the axes'


def test_a_fitted_principal_point_splits_the_error_bars_and_both_hold(stars, database):
    """Synthetic fields through cameras whose principal point is 30–60 px off the centre (25°,
    k1 −0.25…−0.1), solved with no camera: where the stars pin the principal point (all but a few),
    the axes' error against ``covariance_arcsec2`` and the centre's against
    ``center_covariance_arcsec2`` have normalised RMS near 1 (a /tmp run of 40 fields: see
    docs/solving-without-a-camera.md), none wrong."""
    rng = np.random.default_rng(26)
    z_axes, z_centre, n_fitted = [], [], 0
    for _ in range(24):
        angle = rng.uniform(0, 2 * math.pi)
        off = rng.uniform(30, 60) * np.array([math.cos(angle), math.sin(angle)])
        truth = Camera.from_fov(1280, 960, 25.0).replace(cx=639.5 + off[0], cy=479.5 + off[1],
                                                       k1=float(rng.uniform(-0.25, -0.1)))
        A = attitude_from_radec_roll(*rng.uniform([0, -1.2, 0], [2 * math.pi, 1.2, 2 * math.pi]))
        xy, _ = _field(truth, A, stars, 0.3, rng)
        sol = solve_centroids(xy, 1280, 960, database=database, epoch=2025.0)
        if not sol.solved:
            continue
        assert not judge(sol.A_icrs_to_cam, sol.camera, A, truth).wrong
        z_centre.append(_normalised(_centre_error(sol, A, truth), sol.center_covariance_arcsec2))
        if sol.boresight_off_centre:
            n_fitted += 1
            z_axes.append(_normalised(attitude_error(A, sol.A_icrs_to_cam), sol.covariance_arcsec2))
    assert len(z_centre) >= 20 and n_fitted >= 16, (len(z_centre), n_fitted)
    rms_axes = np.sqrt(np.mean(np.square(z_axes), axis=0))
    rms_centre = np.sqrt(np.mean(np.square(z_centre), axis=0))
    assert np.all((rms_axes[:2] > 0.7) & (rms_axes[:2] < 1.4)), rms_axes
    assert np.all((rms_centre > 0.7) & (rms_centre < 1.4)), rms_centre
    assert rms_axes[2] < 1.4


def test_a_principal_point_at_the_centre_has_one_error_bar(stars, database):
    """The principal point held at the image centre (a centred lens, no distortion to pin it
    elsewhere): the centre is the boresight and its covariance is the attitude's, number for
    number, in the JSON beside the centre's coordinates."""
    rng = np.random.default_rng(5)
    truth = Camera.from_fov(1280, 960, 15.0)
    A = attitude_from_radec_roll(2.0, -0.3, 1.0)
    xy, _ = _field(truth, A, stars, 0.3, rng)
    sol = solve_centroids(xy, 1280, 960, database=database, epoch=2025.0)
    assert sol.solved and not sol.boresight_off_centre
    assert sol.center_covariance_arcsec2 == sol.covariance_arcsec2
    d = json.loads(sol.to_json())
    keys = list(d)
    assert keys[keys.index("center_px") + 1] == "center_covariance_arcsec2"
    assert d["center_covariance_arcsec2"] == d["covariance_arcsec2"]
    assert sol.center_sigma_arcsec == pytest.approx(np.sqrt(np.diag(sol.covariance_arcsec2)).tolist())


def test_a_given_camera_turns_the_attitudes_covariance_into_the_centres_frame(stars, database):
    """A camera file whose principal point is 100 px off: no camera number is uncertain, so the
    centre's covariance is the attitude's in the centre frame's axes, ``M P Mᵀ`` — the same σ of
    direction (to the perspective's few percent) and the same total."""
    rng = np.random.default_rng(7)
    camera = Camera.from_fov(1280, 960, 20.0).replace(cx=739.5, cy=420.5)
    A = attitude_from_radec_roll(4.0, 0.9, 0.5)
    xy, _ = _field(camera, A, stars, 0.3, rng)
    sol = solve_centroids(xy, 1280, 960, camera=camera, database=database, epoch=2025.0)
    assert sol.solved
    P, C = np.asarray(sol.covariance_arcsec2), np.asarray(sol.center_covariance_arcsec2)
    M = frame_at_pixel(np.eye(3), sol.camera, (639.5, 479.5), "row")
    np.testing.assert_allclose(C, M @ P @ M.T, rtol=1e-12, atol=1e-12 * np.abs(P).max())
    assert np.trace(C) == pytest.approx(np.trace(P), rel=1e-9)
    assert not np.allclose(C, P, rtol=1e-3)  # turned: the centre's axes are not the camera's



def _frames_judged(draw, seeds, **options) -> list[dict]:
    """``benchmarks/centre_covariance.py``'s frames (``draw(seed)``) solved with no camera file and
    judged (its ``judged``: wrong, both normalised errors, both σ); asserts each solved."""
    import skyfix

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from centre_covariance import judged

    rows = []
    for seed in seeds:
        frame, camera, A = draw(seed)
        sol = skyfix.solve(frame.image, **options)
        assert sol.solved, (seed, sol.reason)
        rows.append(judged(sol, camera, A))
    return rows


@pytest.mark.slow
def test_rendered_pinhole_frames_carry_both_error_bars():
    """20 rendered 1280 × 960 frames, 18–30°, principal point 25–60 px off the centre, k1
    −0.25…−0.05 (``benchmarks/centre_covariance.py``'s ``pinhole_frame``, seeds 0–19) solved with
    no camera file: all solved with the principal point fitted, none wrong; the axes' error
    against ``covariance_arcsec2`` and the centre's against ``center_covariance_arcsec2`` both RMS
    0.7–1.4 in x and y (a run: 1.00, 0.92 and 1.14, 0.92; roll 0.51 and 0.59 — the roll's σ, the
    same in both, is conservative here), and the axes' σ about a hundred times the centre's (the
    principal point's ~2 px at 60–90″ a pixel; before issue 26 part 1 ``covariance_arcsec2`` was
    the centre-sized one)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from centre_covariance import pinhole_frame

    rows = _frames_judged(pinhole_frame, range(20), epoch=2026.9)
    assert all(r["fitted"] and not r["wrong"] for r in rows)
    for name in ("z_axes", "z_centre"):
        rms = np.sqrt(np.mean(np.square([r[name] for r in rows]), axis=0))
        assert np.all((rms[:2] > 0.7) & (rms[:2] < 1.4)) and 0.3 < rms[2] < 1.4, (name, rms)
    assert np.median([r["s_axes"][0] / r["s_centre"][0] for r in rows]) > 30.0


@pytest.mark.slow
def test_allsky_frames_centre_error_bar():
    """The all-sky campaign's frames 0–11 (``allsky_frame(seed)``): the centre's error against
    ``center_covariance_arcsec2`` RMS 0.7–1.4 on every axis (a run: 1.14, 0.84, 1.13; against the
    axes' covariance it was 0.22, 0.21: docs/all-sky.md), none wrong, the axes' σ 2.5× the
    centre's or more (median; a run: 3.9–4.4)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from centre_covariance import allsky

    rows = _frames_judged(allsky, range(12))
    assert not any(r["wrong"] for r in rows)
    rms = np.sqrt(np.mean(np.square([r["z_centre"] for r in rows]), axis=0))
    assert np.all((rms > 0.7) & (rms < 1.4)), rms
    assert np.median([r["s_axes"][1] / r["s_centre"][1] for r in rows]) > 2.5
