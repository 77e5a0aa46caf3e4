"""The tracker with no camera file (issue 25; skyfix.track.self_calibration): it calibrates its
camera from its first frames, refines it on keyframes across the sequence, and adds the camera's
uncertainty to every error bar.

The camera is issue 25's: thesis 000 §5.2's distortion (k1 −0.3686, k2 0.3148, p1 −0.0023,
p2 0.0003) on a 24° 1280×960 frame, its principal point 21 px and −13 px off centre; the
sequences turn at 1 °/s, 10 frames a second (the generic sensor's noise). Errors are judged as
every study judges them (:func:`skyfix.analysis.truth.judge`: at the solution's principal point),
and each run is compared with the same frames tracked through the true camera.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyfix.analysis.truth import judge
from skyfix.camera import Camera
from skyfix.errors import CameraError
from skyfix.geometry import attitude_from_quaternion, attitude_from_radec_roll
from skyfix.simulate import render_sequence
from skyfix.track import Tracker

TRUTH = Camera.from_fov(1280, 960, 24.0).replace(cx=639.5 + 21, cy=479.5 - 13, k1=-0.3686, k2=0.3148,
                                                  p1=-0.0023, p2=0.0003)
EPOCH = 2025.5
A0 = attitude_from_radec_roll(math.radians(84.0), math.radians(-2.0), math.radians(20.0))
RATE = np.radians(np.array([0.6, -0.75, 0.28]) / np.linalg.norm([0.6, -0.75, 0.28]))  # 1 °/s
ARCSEC = math.pi / (180 * 3600)


def _frames(n: int, seed: int):
    return list(render_sequence(A0, TRUTH, n_frames=n, fps=10.0, rate_rad_s=RATE, epoch=EPOCH, seed=seed))


def _run(tracker: Tracker, frames, nis: list | None = None) -> tuple[list, np.ndarray, np.ndarray]:
    """Solutions, boresight errors (″, NaN unsolved) and errors / σ per axis (solved frames);
    each tracked frame's NIS (the MEKF's, against its own prediction) into ``nis`` when given."""
    sols, bore, z = [], [], []
    for f in frames:
        s = tracker.update(f.image, f.truth["t_s"])
        sols.append(s)
        if nis is not None and s.solved and s.method == "track" and s.mode == "tracking":
            nis.append(tracker._predictor.filter.last_nis)
        if not s.solved:
            bore.append(math.nan)
            continue
        j = judge(s.A_icrs_to_cam, s.camera, attitude_from_quaternion(f.truth["quaternion_xyzw"]), TRUTH)
        assert not j.wrong, (s.mode, j)
        bore.append(j.boresight_arcsec)
        z.append(j.error_rad / ARCSEC / np.sqrt(np.diag(s.covariance_arcsec2)))
    return sols, np.array(bore), np.array(z)


@pytest.fixture(scope="module")
def short_run():
    """12 frames: tracked with no camera (a keyframe every 4 frames, so that the camera is
    refitted twice) and through the true camera."""
    frames = _frames(12, seed=4)
    tracker = Tracker(epoch=EPOCH, calibration_options={"keyframe_every": 4})
    nis: list = []
    own = _run(tracker, frames, nis)
    given = _run(Tracker(TRUTH, epoch=EPOCH), frames)
    return frames, tracker, own, given, nis


def test_no_camera_calibrates_then_tracks(short_run):
    frames, tracker, (sols, bore, z), (_, bore_true, _), _ = short_run
    modes = [s.mode for s in sols]
    assert modes[:4] == ["calibrating", "calibrating", "lost", "acquiring"], modes
    assert modes[4:] == ["tracking"] * (len(frames) - 4), modes
    assert all(s.solved for s in sols)
    cal = tracker.calibration
    assert cal.calibrated_at == 2 and cal.refits == 2 and len(cal.matched) == 5
    # the camera it made: the principal point free (never held at the centre), the distortion found
    cam = tracker.camera
    assert {"cx", "cy", "k1", "p1", "p2"} <= set(cal.fit.sigma)
    assert abs(cam.cx - TRUTH.cx) < 3 * cal.fit.sigma["cx"]
    assert abs(cam.cy - TRUTH.cy) < 3 * cal.fit.sigma["cy"]
    assert abs(cam.k1 - TRUTH.k1) < 0.02 and abs(cam.fx / TRUTH.fx - 1) < 2e-4
    assert sols[-1].camera is cam and sols[5].camera is not cam  # refitted at frames 7 and 11
    line = cal.describe()
    assert line.startswith("camera: calibrated in flight at frame 3, refitted 2 times over 5 keyframes")
    assert "cx 6" in line
    # The first frames' camera is three frames of one field's (the principal point to ~2 px): over
    # the 10 frames after it the median is 0.99–3.4 × the true camera's (seeds 1–6, measured; 1.63″
    # against 0.91″ here), within the error bars; the 100-frame run holds 1.5 × (the slow test).
    print(f"\nboresight median from the 3rd frame: {np.median(bore[2:]):.2f}″ with no camera, "
          f"{np.median(bore_true[2:]):.2f}″ with the true camera")
    assert np.median(bore[2:]) < 2.5 and np.max(bore[2:]) < 5.0


def test_error_bars_hold_the_cameras_uncertainty(short_run):
    """The error bars grow by what the camera leaves unknown, and still fit the errors — before
    the first keyframe refit (frames 3–6) and after it (7–12)."""
    _, _, (sols, _, z), (sols_true, _, _), nis = short_run
    own = np.array([np.sqrt(np.diag(s.covariance_arcsec2)) for s in sols[4:]])
    true = np.array([np.sqrt(np.diag(s.covariance_arcsec2)) for s in sols_true[4:]])
    assert np.all(np.median(own[:, :2], axis=0) > 1.05 * np.median(true[:, :2], axis=0))
    # z[k] is frame k's. Measured (seed 4): before 1.14, 0.81, 0.56; after 0.72, 1.02, 0.59; the
    # true camera's own run over frames 3–12 0.45, 0.75, 0.52 — the tracker's error bars are
    # cautious by themselves (the windows' measurement noise and the process noise, shared with
    # a camera file's run: docs/tracking.md#without-a-camera-file)
    for part in (z[2:6], z[6:]):
        rms = np.sqrt(np.mean(part ** 2, axis=0))
        assert np.all((0.4 < rms) & (rms < 1.5)), rms
    # the NIS of the tracked frames (χ²₃ when consistent; a keyframe's frame restarts the filter,
    # whose last NIS is then NaN): measured mean 0.66 over 6 frames; the 6-frame mean's 99.9 %
    # upper bound is χ²₁₈(0.999)/6 = 7.1
    nis = [x for x in nis if math.isfinite(x)]
    assert len(nis) == 6 and np.mean(nis) < 7.1, nis


def test_the_filter_carries_the_camera(short_run):
    """The MEKF holds the camera's free numbers as consider states with the joint fit's
    covariance, and a tracked frame's reported covariance is the filter's own (no add-on)."""
    frames, tracker, (sols, _, _), _, _ = short_run
    filt = tracker._predictor.filter
    C = tracker.calibration.camera_covariance  # the joint fit's, symmetrised in the filter
    np.testing.assert_allclose(filt.camera_covariance, 0.5 * (C + C.T), rtol=1e-15, atol=0)
    assert filt.camera_covariance.shape == (len(tracker.calibration.fit.sigma),) * 2
    assert sols[-1].method == "track"
    P = filt.state.covariance[:3, :3] / ARCSEC**2
    np.testing.assert_allclose(sols[-1].covariance_arcsec2, P, rtol=1e-12)
    # the camera's part: the attitude's error correlates with the camera's numbers
    X = filt.camera_cross(filt.state.t_s)
    assert X.shape == (6, filt.camera_covariance.shape[0]) and np.max(np.abs(X[:3])) > 0


def test_a_frame_of_another_size_is_an_error_while_calibrating(short_run):
    frames = short_run[0]
    tracker = Tracker(epoch=EPOCH)
    tracker.update(frames[0].image, 0.0)
    with pytest.raises(CameraError, match="frame is 640×480 but the sequence's first frame was 1280×960"):
        tracker.update(frames[1].image[:480, :640], 0.1)
    assert tracker.camera is None


def test_camera_covariance_matches_a_monte_carlo():
    """camera_attitude_covariance against 500 cameras drawn from the covariance, each frame's
    attitude refitted (Wahba) to the same 16 stars through its camera and judged at its principal
    point: each axis's σ within 12 % (measured 3–7 %)."""
    from skyfix.attitude import solve_attitude
    from skyfix.calibrate import frame_rotation_at_pixel
    from skyfix.catalog import load_hipparcos
    from skyfix.track.self_calibration import camera_attitude_covariance

    stars = load_hipparcos(epoch=2025.0, mag_limit=6.5)
    A = attitude_from_radec_roll(1.2, 0.3, 0.7)
    rays = stars.vectors @ A.T
    uv, front = TRUTH.ray_to_pixel(rays)
    seen = np.flatnonzero(front & (rays[:, 2] > 0.9) & TRUTH.in_frame(uv))[:16]
    xy, r = uv[seen], stars.vectors[seen]
    sigma = {"fx": 0.2, "fy": 0.2, "cx": 1.5, "cy": 1.0, "k1": 0.003, "k2": 0.04, "p1": 5e-5, "p2": 4e-5}
    rng = np.random.default_rng(0)
    L = rng.normal(size=(8, 8)) * 0.3 + np.eye(8)
    corr = L @ L.T
    corr /= np.sqrt(np.outer(np.diag(corr), np.diag(corr)))
    S = corr * np.outer(list(sigma.values()), list(sigma.values()))
    numbers = ["fx", "fy", "cx", "cy", "skew", "k1", "k2", "k3", "p1", "p2", "k4", "projection_code"]
    cov = np.zeros((12, 12))
    index = [numbers.index(k) for k in sigma]
    cov[np.ix_(index, index)] = S
    P = camera_attitude_covariance(TRUTH, cov, A, xy, r)
    errors = []
    for dc in rng.multivariate_normal(np.zeros(8), S, size=500):
        cam = TRUTH.replace(**{k: getattr(TRUTH, k) + v for k, v in zip(sigma, dc, strict=True)})
        A_fit = solve_attitude(cam.pixel_to_ray(xy), r)
        errors.append(frame_rotation_at_pixel(A_fit, cam, A, TRUTH, (cam.cx, cam.cy)))
    ratio = np.std(errors, axis=0) / np.sqrt(np.diag(P))
    assert np.all(abs(ratio - 1) < 0.12), ratio
    assert np.sqrt(P[0, 0]) / ARCSEC > 0.3  # the principal point's 1.5 px is felt: not a rounding error


@pytest.mark.slow
def test_100_frames_with_no_camera_file():
    """Issue 25's acceptance: 100 frames, no camera file — every frame from the 3rd solved, none
    wrong, the boresight's median error within 1.5 × the run given the true camera (measured,
    seed 7: 0.86″ against 0.84″; seeds 1–4 1.13–1.39 ×, docs/tracking.md)."""
    frames = _frames(100, seed=7)
    tracker = Tracker(epoch=EPOCH)
    nis: list = []
    sols, bore, z = _run(tracker, frames, nis)
    _, bore_true, _ = _run(Tracker(TRUTH, epoch=EPOCH), frames)
    assert all(s.solved for s in sols[2:])
    ratio = np.median(bore[2:]) / np.median(bore_true[2:])
    print(f"\nboresight median {np.median(bore[2:]):.2f}″ (true camera {np.median(bore_true[2:]):.2f}″), "
          f"ratio {ratio:.2f}; {tracker.calibration.describe()}")
    assert ratio <= 1.5
    assert tracker.calibration.refits >= 8
    cam = tracker.camera
    assert abs(cam.cx - TRUTH.cx) < 3 * tracker.calibration.fit.sigma["cx"]
    assert abs(cam.k1 - TRUTH.k1) < 3 * tracker.calibration.fit.sigma["k1"]
    rms = np.sqrt(np.mean(z[2:] ** 2, axis=0))
    assert np.all((0.25 < rms) & (rms < 2.0)), rms
    # measured: 0.57, 0.68, 0.59 (the true camera's run 0.58, 0.67, 0.58); mean NIS 0.45 over 77
    # tracked frames (the true camera's 0.49): cautious, never over-confident (χ²₂₃₁(0.999)/77 = 3.9)
    assert np.nanmean(nis) < 3.9, np.nanmean(nis)


def test_track_command_with_no_camera(short_run, tmp_path):
    """``skyfix track`` without ``--camera``: the first frames calibrating, then tracking, and
    on stderr the camera it used."""
    import json

    from PIL import Image
    from typer.testing import CliRunner

    from skyfix.cli import app

    paths = []
    for k, f in enumerate(short_run[0][:6]):
        paths.append(tmp_path / f"f{k}.png")
        Image.fromarray(f.image.astype(np.uint16)).save(paths[-1])
    args = ["track", *map(str, paths), "--fps", "10", "--epoch", str(EPOCH), "--json"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    modes = [json.loads(line)["mode"] for line in result.stdout.splitlines()]
    assert modes == ["calibrating", "calibrating", "lost", "acquiring", "tracking", "tracking"]
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("skyfix: camera: calibrated in flight at frame 3")
