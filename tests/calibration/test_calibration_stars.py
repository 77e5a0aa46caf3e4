"""Star-field calibration over many images (skyfix.calibration): one camera and one attitude per
image fitted jointly, the model chosen by BIC, what the stars cannot constrain refused, the
camera file read back bit for bit, and bad input refused in one line before any file is written.

The camera of issue 25: thesis 000 §5.2's distortion (k1 −0.3686, k2 0.3148, p1 −0.0023,
p2 0.0003) on a 24° 1280×960 frame, its principal point 21 px and −13 px off centre."""

import math

import numpy as np
import pytest

from skyfix.calibration.joint import MatchedImage, fit_joint
from skyfix.calibration.stars import (
    CALIBRATION_MODELS,
    PRINCIPAL_POINT_SIGMA_PX,
    calibrate_stars,
    calibration_model,
    check_not_one_field,
    choose_model,
    parameter_table,
)
from skyfix.camera import Camera
from skyfix.catalog import load_hipparcos
from skyfix.errors import CalibrationError, UnknownNameError
from skyfix.geometry import attitude_from_radec_roll

BASE = Camera.from_fov(1280, 960, 24.0)
TRUTH = BASE.replace(cx=639.5 + 21, cy=479.5 - 13, k1=-0.3686, k2=0.3148, p1=-0.0023, p2=0.0003)
FULL = ("f", "aspect", "principal_point", "k1", "k2", "tangential")


def _attitudes(n: int, seed: int, roll: float | None = None) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [attitude_from_radec_roll(rng.uniform(0, 2 * math.pi), math.asin(rng.uniform(-1, 1)),
                                     rng.uniform(0, 2 * math.pi) if roll is None else roll) for _ in range(n)]


@pytest.fixture(scope="module")
def stars():
    return load_hipparcos(epoch=2025.0, mag_limit=7.0)


def _matched(stars, camera: Camera, attitudes, sigma_px: float, seed: int, n_max: int | None = None):
    """Each attitude's catalogue stars in ``camera``'s frame (within its field: a Brown–Conrady
    k1 < 0 folds stars from 50° off axis back into the frame), their pixels with Gaussian noise."""
    rng = np.random.default_rng(seed)
    out = []
    near = math.cos(math.radians(camera.fov_diagonal_deg) / 2 * 1.2)
    for i, A in enumerate(attitudes):
        rays = stars.vectors @ A.T
        uv, front = camera.ray_to_pixel(rays)
        seen = np.flatnonzero(front & (rays[:, 2] > near) & camera.in_frame(uv))[:n_max]
        out.append(MatchedImage(f"frame {i}", uv[seen] + rng.normal(0.0, sigma_px, (len(seen), 2)),
                                stars.vectors[seen], A))
    return out


def _grid_error_px(camera: Camera, A: np.ndarray, truth: Camera, A_true: np.ndarray) -> float:
    """Largest distance, over a 17×13 grid spanning the frame, between a pixel and where the
    fitted camera and attitude put its true sky direction."""
    g = np.stack(np.meshgrid(np.linspace(0, truth.width - 1, 17), np.linspace(0, truth.height - 1, 13)),
                 -1).reshape(-1, 2)
    uv, front = camera.ray_to_pixel(truth.pixel_to_ray(g) @ A_true @ A.T)
    assert front.all()
    return float(np.hypot(*(uv - g).T).max())


def test_joint_fit_recovers_the_camera_and_its_sigma(stars):
    """12 fields of exact stars with 0.15 px noise, 8 noise draws: the reported 1σ matches the
    scatter (normalised RMS over the draws and the 8 numbers 0.7–1.5), the focal length within
    0.05 %, the principal point within 3σ (σ ≈ 0.75 px with these ~160 stars a field: the
    rendered frames' 400 give 0.3–0.4 px), the distortion within 0.2 px over the frame."""
    attitudes = _attitudes(12, seed=5)
    z = []
    for draw in range(8):
        fit = fit_joint(_matched(stars, TRUTH, attitudes, 0.15, seed=draw), BASE, FULL)
        cam = fit.camera
        assert abs(cam.fx / TRUTH.fx - 1) < 5e-4 and abs(cam.fy / TRUTH.fy - 1) < 5e-4
        assert abs(cam.cx - TRUTH.cx) < 3 * fit.sigma["cx"] and abs(cam.cy - TRUTH.cy) < 3 * fit.sigma["cy"]
        assert _grid_error_px(cam, fit.attitudes[0], TRUTH, attitudes[0]) < 0.2
        assert 0.14 < fit.sigma_px < 0.16
        z.append([(getattr(cam, k) - getattr(TRUTH, k)) / s for k, s in fit.sigma.items()])
    z = np.array(z)
    assert z.shape == (8, 8)  # fx, fy, cx, cy, k1, k2, p1, p2
    nrms = math.sqrt(float(np.mean(z**2)))
    assert 0.7 < nrms < 1.5, nrms


def test_bic_and_refusals_keep_a_sparse_narrow_field_simple(stars):
    """A 10° field of 20 stars an image: k3 is not fitted (the BIC or the significance refuses
    it), nor is the principal point, which four such fields cannot place to 2 px."""
    narrow = Camera.from_fov(1280, 960, 10.0).replace(k1=-0.2)
    attitudes = _attitudes(4, seed=2)
    matched = _matched(stars, narrow, attitudes, 0.2, seed=1, n_max=20)
    family = calibration_model("brown-conrady")
    full = fit_joint(matched, Camera.from_fov(1280, 960, 10.0), family.ladder[-1])
    assert full.sigma["k3"] > 100 * abs(narrow.k3 + 1e-9) or abs(full.camera.k3) < 2 * full.sigma["k3"]
    assert max(full.sigma["cx"], full.sigma["cy"]) > PRINCIPAL_POINT_SIGMA_PX
    # the choice alone, without images to re-identify
    best, scores, refused = choose_model(matched, Camera.from_fov(1280, 960, 10.0), family, skew=False)
    assert "k3" not in best.params and "principal_point" not in best.params
    assert "principal_point" in refused
    assert len(scores) == len(family.ladder)


def test_skew_is_fitted_when_asked_and_recovered(stars):
    """The skew is off by default (``--skew`` frees it). Issue 25's camera with a skew of 2 px
    (Bouguet's alpha_c 6.6e-4; 0.4 px at the frame's top and bottom), 12 fields of exact stars with
    0.15 px of noise: by default no skew is fitted and the residuals grow; with ``skew=True`` it
    is chosen and recovered within 3σ (measured 1.993 ± 0.051 px; residual σ 0.151 px, 0.181
    without it); on the same fields of an unskewed camera it is refused as not significant."""
    skewed = TRUTH.replace(skew=2.0)
    attitudes = _attitudes(12, seed=7)
    matched = _matched(stars, skewed, attitudes, 0.15, seed=3)
    family = calibration_model("brown-conrady")
    plain, _, _ = choose_model(matched, BASE, family, skew=False)
    assert "skew" not in plain.params and plain.camera.skew == 0.0
    fit, _, refused = choose_model(matched, BASE, family, skew=True)
    assert "skew" in fit.params and "skew" not in refused
    sigma = fit.sigma["skew"]
    print(f"\nskew {fit.camera.skew:.3f} ± {sigma:.3f} px (truth 2); σ {fit.sigma_px:.4f} px with it, "
          f"{plain.sigma_px:.4f} without")
    assert abs(fit.camera.skew - 2.0) < 3 * sigma and sigma < 0.2
    assert fit.sigma_px < plain.sigma_px
    straight = _matched(stars, TRUTH, attitudes, 0.15, seed=3)
    unskewed, _, refused = choose_model(straight, BASE, family, skew=True)
    assert "skew" in refused and "skew" not in unskewed.params and unskewed.camera.skew == 0.0


def test_same_roll_images_constrain_the_principal_point_as_well(stars):
    """Stars are at infinity and every image's attitude is its own: a set of images all at one
    roll pins the principal point as well as one at random rolls (measured, not assumed)."""
    sig = []
    for roll in (None, 0.3):
        fit = fit_joint(_matched(stars, TRUTH, _attitudes(12, seed=3, roll=roll), 0.1, seed=4), BASE, FULL)
        sig.append(max(fit.sigma["cx"], fit.sigma["cy"]))
    assert sig[1] < 1.2 * sig[0] and sig[1] < 0.7


def test_one_field_is_a_degenerate_set(stars):
    A = _attitudes(1, seed=1)[0]
    matched = _matched(stars, TRUTH, [A, A, A], 0.1, seed=0)
    with pytest.raises(CalibrationError, match="degenerate set: all 3 images are of one field"):
        check_not_one_field(matched)


def test_unknown_model_and_too_few_images():
    with pytest.raises(UnknownNameError, match="unknown calibration model 'zoom'; choose one of pinhole, "
                       "brown-conrady, fisheye"):
        calibrate_stars([np.zeros((10, 10))] * 3, model="zoom")
    with pytest.raises(CalibrationError, match="at least 3 images, got 2"):
        calibrate_stars([np.zeros((10, 10))] * 2)
    assert set(CALIBRATION_MODELS) == {"pinhole", "brown-conrady", "fisheye"}


@pytest.fixture(scope="module")
def rendered():
    """12 frames of TRUTH at random pointings, rendered by skyfix.simulate (0.3 s, generic sensor)."""
    from skyfix.simulate import render

    attitudes = _attitudes(12, seed=1)
    frames = [render(A, TRUTH, sensor="generic", optics="generic", exposure_s=0.3, epoch=2025.0,
                     seed=100 + i).image for i, A in enumerate(attitudes)]
    return frames, attitudes


@pytest.fixture(scope="module")
def calibrated(rendered):
    return calibrate_stars(rendered[0], max_stars=600)


def test_rendered_frames_calibrate_with_no_prior_knowledge(rendered, calibrated):
    """The must-show of issue 25 part 1, one noise draw: focal length within 0.05 %, principal
    point within 0.5 px (about 1σ), distortion within 0.2 px everywhere; after < before."""
    frames, attitudes = rendered
    cal = calibrated
    cam = cal.camera
    assert cal.fit.params == FULL and not cal.refused
    assert abs(cam.fx / TRUTH.fx - 1) < 5e-4 and abs(cam.fy / TRUTH.fy - 1) < 5e-4
    assert abs(cam.cx - TRUTH.cx) < 0.5 and abs(cam.cy - TRUTH.cy) < 0.5
    assert _grid_error_px(cam, cal.fit.attitudes[0], TRUTH, attitudes[0]) < 0.2
    assert cal.fit.n_stars > 4000
    assert np.all(cal.fit.rms_arcsec() < 0.1 * cal.before.rms_arcsec())
    rows = {n: (v, s) for n, v, s in parameter_table(cal)}
    assert set(rows) == {"fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"}
    # The camera file: [camera] read back bit for bit, [calibration] beside it.
    text = cal.to_toml()
    assert Camera.from_toml(text) == cam
    import tomllib

    table = tomllib.loads(text)["calibration"]
    assert table["sigma"]["cx"] == rows["cx"][1] and table["images"] == 12


def test_thesis_004_statistics_of_the_calibration(calibrated):
    """Thesis 004 §6.3's statistics on skyfix's calibration of the rendered frames (docs/calibration.md):
    every pair of the inliers of each image, measured distance less catalogue distance. Measured:
    1.45 million pairs of 5806 stars, σ_dist 59.7 µrad = 0.180 px, σ_pos 42.2 µrad = 8.7″ =
    0.127 px — the joint fit's own per-axis σ (0.128 px) from another road — and no bias of scale
    (mean 0.1 µrad); σ_mag 0.169 on 5799 stars, 7 beyond a magnitude left out (thesis: 78.2 µrad =
    0.34 px, 55.3 µrad = 11.4″ = 0.24 px, 0.2 Mv)."""
    from skyfix.calibration.bench import calibration_statistics

    fit = calibrated.fit
    stats = calibration_statistics(fit)
    d, m = stats.distances, stats.magnitudes
    plate = fit.camera.plate_scale_rad
    assert d.stars == fit.n_stars and d.images == 12 and d.pairs > 1_000_000
    assert d.sigma_pos_rad / plate == pytest.approx(fit.sigma_px, rel=0.05)
    assert abs(d.mean_rad) < 0.02 * d.sigma_dist_rad
    assert 0.1 < m.sigma_mag < 0.25 and m.left_out < 0.005 * m.stars


def test_too_few_stars_and_sizes_name_the_image(rendered):
    frames, _ = rendered
    blank = np.full_like(frames[0], 100)
    with pytest.raises(CalibrationError, match=r"^image 2: not solved"):
        calibrate_stars([frames[0], blank, frames[1]])
    with pytest.raises(CalibrationError, match=r"^image 3: 640×480, but image 1 is 1280×960"):
        calibrate_stars([frames[0], frames[1], frames[2][:480, :640]])


@pytest.mark.slow
def test_rendered_sigma_matches_the_scatter_over_noise_draws():
    """Six noise draws of the same 12 pointings: the reported 1σ against the actual errors,
    normalised RMS 0.7–1.5 over every camera number."""
    from skyfix.simulate import render

    attitudes = _attitudes(12, seed=1)
    z = []
    for draw in range(6):
        frames = [render(A, TRUTH, sensor="generic", optics="generic", exposure_s=0.3, epoch=2025.0,
                         seed=1000 * draw + i).image for i, A in enumerate(attitudes)]
        cal = calibrate_stars(frames, max_stars=600)
        z += [(getattr(cal.camera, k) - getattr(TRUTH, k)) / s for k, s in cal.fit.sigma.items()]
    nrms = math.sqrt(float(np.mean(np.square(z))))
    assert 0.7 < nrms < 1.5, nrms


@pytest.mark.slow
def test_esa_frames_calibrated_over_all_eight(real_dir):
    """The 8 ESA frames: each image's residual RMS falls below the uncalibrated pinhole's."""
    paths = sorted((real_dir / "esa-tetra3").glob("*.tiff"))
    cal = calibrate_stars(paths)
    assert cal.fit.params[:3] == ("f", "aspect", "principal_point")
    assert np.all(cal.fit.rms_arcsec() < cal.before.rms_arcsec())
    assert abs(cal.camera.fx - 5115) < 5
    # thesis 004 §6.3's statistics on them (measured: σ_dist 43.9 µrad = 0.225 px, σ_pos 31.0 µrad =
    # 6.4″ = 0.159 px over 72,977 pairs of 1025 stars; σ_mag 0.283 against Hipparcos Hp)
    from skyfix.calibration.bench import calibration_statistics

    stats = calibration_statistics(cal.fit)
    sigma_pos_px = stats.distances.sigma_pos_rad / cal.camera.plate_scale_rad
    assert sigma_pos_px == pytest.approx(cal.fit.sigma_px, rel=0.05)
    assert stats.magnitudes.sigma_mag < 0.35


def test_command_refuses_bad_input_in_one_line_and_writes_nothing(tmp_path):
    """``skyfix calibrate stars``: an unknown model and too few images are one ``skyfix: error:``
    line each, exit status 2, no camera file (both checked before an image is read)."""
    from typer.testing import CliRunner

    from skyfix.cli import app

    paths = [tmp_path / f"f{i}.fits" for i in range(3)]
    for p in paths:
        p.write_bytes(b"")
    out = tmp_path / "camera.toml"
    cases = {("--model", "zoom"): "--model: unknown calibration model 'zoom'; choose one of pinhole, "
                                  "brown-conrady, fisheye",
             ("--max-stars", "300"): "a star calibration needs at least 3 images, got 2"}
    for (option, value), message in cases.items():
        images = paths if option == "--model" else paths[:2]
        args = ["calibrate", "stars", *map(str, images), "-o", str(out), option, value]
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 2, result.output
        assert result.stderr.strip().splitlines() == [f"skyfix: error: {message}"]
        assert not out.exists()
