"""The Tracker on simulated sequences (docs/tracking.md): 1280×960, 15°, 10 Hz, the generic
sensor's noise, at rest and at 1 °/s.

Each sequence is rendered once per module and tracked frame by frame; every frame after the
acquiring one must be tracked, with a boresight error within a few arcseconds of the truth and
no worse than lost-in-space on the same frames, error bars that fit the errors, and the rate
found. Forced losses (a blank frame, a 90° jump) recover within two frames; bad input (times
out of order or repeated, a frame of another size) is a one-line skyfix error.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import skyfix
from skyfix.attitude import attitude_error
from skyfix.camera import Camera
from skyfix.errors import CameraError, InputError
from skyfix.geometry import attitude_from_quaternion, attitude_from_radec_roll
from skyfix.simulate import render_sequence
from skyfix.track import Tracker
from skyfix.track.frame_steps import window_fit_agrees
from skyfix.track.windows import pixel_jacobian

CAMERA = Camera.from_fov(1280, 960, 15.0)
EPOCH = 2025.5
FPS = 10.0
N_FRAMES = 20
A0 = attitude_from_radec_roll(math.radians(84.0), math.radians(-2.0), math.radians(20.0))
ARCSEC = math.pi / (180 * 3600)
RATES_DPS = {"rest": None, "1 deg/s": np.array([0.6, -0.75, 0.28])}  # |ω| = 1 °/s


def _rate(name):
    v = RATES_DPS[name]
    return None if v is None else np.radians(v / np.linalg.norm(v))


def _frames(A, rate, n, seed):
    return list(render_sequence(A, CAMERA, n_frames=n, fps=FPS, rate_rad_s=rate, epoch=EPOCH, seed=seed))


def _truth(frame) -> np.ndarray:
    return attitude_from_quaternion(frame.truth["quaternion_xyzw"])


def _error_arcsec(frame, sol) -> np.ndarray:
    """(x, y, roll) error of a solution against the frame's truth, arcsec."""
    return attitude_error(_truth(frame), sol.A_icrs_to_cam) / ARCSEC


@pytest.fixture(scope="module", params=list(RATES_DPS))
def tracked(request):
    """(rate name, frames, tracker solutions, lost-in-space solutions of the same frames)."""
    rate = _rate(request.param)
    frames = _frames(A0, rate, N_FRAMES, seed=3)
    tracker = Tracker(CAMERA, epoch=EPOCH)
    sols = [tracker.update(f.image, f.truth["t_s"]) for f in frames]
    lis = [skyfix.solve(f.image, camera=CAMERA, epoch=EPOCH) for f in frames]
    return request.param, frames, sols, lis


def test_every_frame_after_acquisition_is_tracked(tracked):
    name, frames, sols, _ = tracked
    modes = [s.mode for s in sols]
    assert modes[:2] == ["lost", "acquiring"], modes
    assert modes[2:] == ["tracking"] * (len(frames) - 2), modes
    assert all(s.solved for s in sols)
    for s in sols[2:]:
        assert s.n_matched >= 10 and s.method == "track" and not s.reason
        assert s.prob_false < 1e-9
        assert len(s.matches) == s.n_matched


def test_tracking_is_as_accurate_as_lost_in_space(tracked):
    name, frames, sols, lis = tracked
    track_err = np.array([_error_arcsec(f, s) for f, s in zip(frames[2:], sols[2:], strict=True)])
    lis_err = np.array([_error_arcsec(f, s) for f, s in zip(frames[2:], lis[2:], strict=True)])
    track_bore = np.hypot(track_err[:, 0], track_err[:, 1])
    lis_bore = np.hypot(lis_err[:, 0], lis_err[:, 1])
    print(f"\n{name}: boresight median tracking {np.median(track_bore):.2f}″ lost-in-space "
          f"{np.median(lis_bore):.2f}″; roll median |err| tracking {np.median(abs(track_err[:, 2])):.1f}″ "
          f"lost-in-space {np.median(abs(lis_err[:, 2])):.1f}″")
    assert track_bore.max() < 5.0
    assert np.median(track_bore) <= np.median(lis_bore)
    assert np.median(abs(track_err[:, 2])) < 60.0


def test_error_bars_fit_the_errors(tracked):
    """error / reported σ per axis over the tracked frames: an RMS near 1 (a loose band for ~20
    correlated frames; the ≥ 1000-frame study is docs/tracking.md's)."""
    name, frames, sols, _ = tracked
    z = []
    for f, s in zip(frames[2:], sols[2:], strict=True):
        sigma = np.sqrt(np.diag(np.asarray(s.covariance_arcsec2)))
        z.append(_error_arcsec(f, s) / sigma)
    rms = np.sqrt(np.mean(np.square(z), axis=0))
    print(f"\n{name}: normalised error RMS per axis {np.round(rms, 2)}")
    assert np.all((0.25 < rms) & (rms < 2.5)), rms


def test_rate_is_found(tracked):
    name, frames, sols, _ = tracked
    for f, s in zip(frames[4:], sols[4:], strict=True):
        rate = f.truth["rate_rad_s"]
        truth = np.degrees(np.zeros(3) if rate is None else np.asarray(rate))
        err = np.asarray(s.rate_dps) - truth
        sigma = np.sqrt(np.diag(np.asarray(s.rate_covariance_dps2)))
        assert np.all(abs(err) < 5 * sigma + 1e-4), (err, sigma)
        assert np.all(abs(err[:2]) < 0.01)  # °/s about the cross-boresight axes


def test_solution_json_has_the_tracking_fields(tracked):
    _, frames, sols, lis = tracked
    d = sols[-1].to_dict()
    assert d["mode"] == "tracking" and len(d["rate_dps"]) == 3
    assert d["frame_time_s"] == frames[-1].truth["t_s"]
    assert np.shape(d["rate_covariance_dps2"]) == (3, 3)
    for key in ("mode", "frame_time_s", "rate_dps", "rate_covariance_dps2"):
        assert key not in lis[-1].to_dict()  # lost-in-space output is unchanged


@pytest.fixture(scope="module")
def frames_at_rest():
    return _frames(A0, None, 8, seed=5)


def test_blank_frame_then_recovery(frames_at_rest):
    frames = frames_at_rest
    tracker = Tracker(CAMERA, epoch=EPOCH)
    sols = []
    for k, f in enumerate(frames):
        image = np.full_like(f.image, 64) if k == 4 else f.image
        sols.append(tracker.update(image, f.truth["t_s"]))
    blank = sols[4]
    assert blank.solved and blank.mode == "tracking" and blank.n_matched == 0
    assert "coasting" in blank.reason and "blank frame" in blank.reason
    assert np.hypot(*_error_arcsec(frames[4], blank)[:2]) < 5.0  # the prediction holds
    for k in (5, 6, 7):
        assert sols[k].mode == "tracking" and sols[k].n_matched >= 10 and not sols[k].reason


def test_jump_of_90_degrees_then_recovery(frames_at_rest):
    """Tracking, then the camera is suddenly 90° away (about its x axis): that frame is solved
    lost in space and restarts the filter, the next acquires the rate, the one after tracks."""
    before = frames_at_rest[:5]
    jumped = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]) @ A0  # 90° about camera x
    after = _frames(jumped, None, 4, seed=8)
    tracker = Tracker(CAMERA, epoch=EPOCH)
    sols = [tracker.update(f.image, f.truth["t_s"]) for f in before]
    t_last = before[-1].truth["t_s"]
    for f in after:
        sols.append(tracker.update(f.image, t_last + 0.1 + f.truth["t_s"]))
    modes = [s.mode for s in sols]
    assert modes == ["lost", "acquiring", "tracking", "tracking", "tracking", "lost", "acquiring", "tracking",
                     "tracking"], modes
    assert all(s.solved for s in sols)
    for f, s in zip(after, sols[5:], strict=True):
        assert np.hypot(*_error_arcsec(f, s)[:2]) < 5.0


def test_jump_while_turning_at_2_deg_s_recovers_at_once():
    """At 2 °/s (17 px streaks) the plain lost-in-space solve often fails; after a 90° jump the
    tracker solves the frame along its predicted streaks, keeps the rate and tracks the next."""
    rate = np.radians(2.0 * RATES_DPS["1 deg/s"] / np.linalg.norm(RATES_DPS["1 deg/s"]))
    before = _frames(A0, rate, 6, seed=11)
    jumped = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]) @ A0
    after = _frames(jumped, rate, 3, seed=12)
    tracker = Tracker(CAMERA, epoch=EPOCH, exposure_s=0.1)
    frames = before + after
    t_last = before[-1].truth["t_s"]
    times = [f.truth["t_s"] for f in before] + [t_last + 0.1 + f.truth["t_s"] for f in after]
    sols = [tracker.update(f.image, t) for f, t in zip(frames, times, strict=True)]
    jump, nxt = sols[6], sols[7]
    assert jump.solved and jump.mode == "lost" and jump.method == "quad-hash", jump.reason
    assert nxt.mode == "tracking" and nxt.method == "track" and nxt.n_matched >= 8, nxt.reason
    assert sols[8].mode == "tracking" and sols[8].method == "track"
    # the rate from one tracked frame after the jump: the cross axes to 0.05 °/s (σ 0.02), the roll
    # rate within 3 of its own σ (0.13 °/s: measured 0.17 °/s off with the detector's noise draws of
    # issue 27 part 5, 0.0 before — one realisation either way)
    err, sigma = nxt.rate_dps - np.degrees(rate), np.sqrt(np.diag(nxt.rate_covariance_dps2))
    assert np.all(np.abs(err[:2]) < 0.05) and abs(err[2]) < 3 * sigma[2], (err, sigma)
    for f, s in zip(frames, sols, strict=True):
        if s.solved:  # never a wrong attitude: the jump frame is not coasted on the old pointing
            assert np.hypot(*_error_arcsec(f, s)[:2]) < 60.0, (s.mode, s.method, s.reason)


def test_stars_the_prediction_cannot_explain_are_not_coasted(frames_at_rest):
    """A frame full of stars none of which is where the prediction puts one (here the frame
    mirrored: no sky looks like it, so lost in space fails too) is not coasted on: failed, lost."""
    frames = frames_at_rest
    tracker = Tracker(CAMERA, epoch=EPOCH)
    sols = []
    for k, f in enumerate(frames[:6]):
        image = np.ascontiguousarray(f.image[:, ::-1]) if k == 4 else f.image
        sols.append(tracker.update(image, f.truth["t_s"]))
    bad = sols[4]
    assert bad.status == "failed" and bad.mode == "tracking" and "not coasting" in bad.reason, bad.reason
    assert sols[5].mode == "lost" and sols[5].solved


def test_predict_between_frames():
    """``Tracker.predict(t)`` at 1 °/s: the attitude of a frame not yet given, within its error
    bars, and the rate; the state is unchanged (the frame then tracks as usual)."""
    rate = _rate("1 deg/s")
    frames = _frames(A0, rate, 8, seed=13)
    tracker = Tracker(CAMERA, epoch=EPOCH)
    with pytest.raises(InputError, match="lost"):
        tracker.predict(0.0)
    for f in frames[:6]:
        tracker.update(f.image, f.truth["t_s"])
    with pytest.raises(InputError, match="before the last frame"):
        tracker.predict(frames[4].truth["t_s"])
    with pytest.raises(InputError, match="finite"):
        tracker.predict(float("inf"))
    nxt = frames[7]  # two frame periods ahead
    p = tracker.predict(nxt.truth["t_s"])
    e = attitude_error(_truth(nxt), p.A_icrs_to_cam)
    sigma = np.sqrt(np.diag(p.attitude_cov_rad2))
    assert np.hypot(e[0], e[1]) / ARCSEC < 10.0, e / ARCSEC
    assert np.all(np.abs(e) < 4 * sigma), (e / ARCSEC, sigma / ARCSEC)
    np.testing.assert_allclose(p.rate_rad_s, rate, atol=np.radians(0.02))
    sol = tracker.update(frames[6].image, frames[6].truth["t_s"])
    assert sol.mode == "tracking" and sol.method == "track" and sol.n_matched >= 10


def test_gyro_rates_track_from_the_second_frame():
    """With a gyro (biased by 0.02 °/s, noisy) the rate is known at once: lost, then tracking —
    the second frame solved whole (the gyro's bias is unknown, σ 0.57 °/s: too wide a smear for
    windows), windows from the third; every frame within a few arcseconds, the reported rate
    the body's (the filter takes the bias out)."""
    rate = _rate("1 deg/s")
    frames = _frames(A0, rate, 12, seed=17)
    rng = np.random.default_rng(4)
    bias = np.radians([0.02, -0.02, 0.01])
    tracker = Tracker(CAMERA, epoch=EPOCH)
    sols = [tracker.update(f.image, f.truth["t_s"], gyro_rate_rad_s=rate + bias + rng.normal(0, 1e-5, 3))
            for f in frames]
    assert [s.mode for s in sols] == ["lost"] + ["tracking"] * 11
    assert [s.method for s in sols[:3]] == ["quad-hash", "quad-hash", "track"]
    for f, s in zip(frames, sols, strict=True):
        assert s.solved and s.n_matched >= 10 and np.hypot(*_error_arcsec(f, s)[:2]) < 5.0
    assert np.all(np.abs(np.asarray(sols[-1].rate_dps) - np.degrees(rate)) < 0.01), sols[-1].rate_dps


def test_a_fit_of_a_minority_of_the_windows_is_not_trusted():
    assert window_fit_agrees(16, 16) and window_fit_agrees(8, 16) and window_fit_agrees(3, 5)
    assert not window_fit_agrees(7, 16) and not window_fit_agrees(3, 7)


def test_times_out_of_order_or_repeated_are_errors(frames_at_rest):
    frames = frames_at_rest
    tracker = Tracker(CAMERA, epoch=EPOCH)
    tracker.update(frames[0].image, 0.0)
    tracker.update(frames[1].image, 0.1)
    with pytest.raises(InputError, match="out of order"):
        tracker.update(frames[2].image, 0.05)
    with pytest.raises(InputError, match="repeated"):
        tracker.update(frames[2].image, 0.1)
    for bad in (None, float("nan"), "0.2"):
        with pytest.raises(InputError):
            tracker.update(frames[2].image, bad)
    sol = tracker.update(frames[2].image, 0.2)  # the state survived the bad calls
    assert sol.mode == "tracking" and sol.solved


def test_frame_of_another_size_is_an_error(frames_at_rest):
    tracker = Tracker(CAMERA, epoch=EPOCH)
    with pytest.raises(CameraError, match="frame is 640×480 but the camera is 1280×960"):
        tracker.update(np.zeros((480, 640), np.uint16), 0.0)
    with pytest.raises(InputError, match="gyro"):
        tracker.update(frames_at_rest[0].image, 0.0, gyro_rate_rad_s=[0.0, 1.0])


def test_streak_windows_are_at_most_the_windows():
    """Fewer windows while the stars streak, never more than ``n_windows``; a count that is not
    a positive integer is a one-line error."""
    assert Tracker(CAMERA, epoch=EPOCH).settings.streak_windows == 16  # default: n_windows
    assert Tracker(CAMERA, epoch=EPOCH, n_windows=10, streak_windows=14).settings.streak_windows == 10
    assert Tracker(CAMERA, epoch=EPOCH, streak_windows=12).settings.streak_windows == 12
    for bad in (0, -3, 2.5):
        with pytest.raises(InputError, match="streak_windows"):
            Tracker(CAMERA, epoch=EPOCH, streak_windows=bad)


def test_pixel_jacobian_is_the_derivative_of_the_projection():
    """J δθ is where a star moves for a small attitude error (with distortion and skew)."""
    cam = Camera.from_fov(1280, 960, 15.0).replace(k1=-0.08, p1=1e-3, skew=2.0)
    rng = np.random.default_rng(1)
    xy = rng.uniform([50, 50], [1230, 910], (20, 2))
    b = cam.pixel_to_ray(xy)
    J = np.empty((2, 3))
    for ray, p in zip(b, xy, strict=True):
        pixel_jacobian(ray[0], ray[1], ray[2], cam.numbers(), J)
        for axis in range(3):
            d = np.zeros(3)
            d[axis] = 1e-6
            # A_est = R(d) A_true: the true ray is R(−d) b
            moved = cam.ray_to_pixel((ray + np.cross(ray, d))[None])[0][0]
            assert np.allclose(moved - p, J[:, axis] * 1e-6, atol=1e-7)


def test_compiled_fit_is_the_attitude_modules():
    """track.fit.fit_attitude (compiled for the tracking loop) gives svd_attitude's attitude and
    attitude_covariance's covariance (σ scaled up by √(χ²/dof) when the residuals exceed σ)."""
    from skyfix.attitude import attitude_covariance, svd_attitude
    from skyfix.geometry import radec_to_vector
    from skyfix.track.fit import fit_attitude

    rng = np.random.default_rng(4)
    r = radec_to_vector(rng.uniform(1.4, 1.6, 12), rng.uniform(-0.1, 0.1, 12))
    sigma = rng.uniform(1, 3, 12) * ARCSEC
    b = r @ A0.T + rng.normal(size=(12, 3)) * sigma[:, None]
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    keep = np.ones(12, bool)
    ok, A, P, scale = fit_attitude(b, r, sigma, keep, 5.0, 5.0, 3)
    assert ok and keep.all()
    assert np.allclose(A, svd_attitude(b, r, 1 / sigma**2), atol=1e-12)
    assert np.allclose(P, attitude_covariance(A, b, sigma * scale), rtol=1e-9)
    b[3] = r[3] @ attitude_from_radec_roll(1.5, 0.0, 0.0).T  # a wrong star: the pair check drops it
    keep[:] = True
    ok, A, P, _ = fit_attitude(b, r, sigma, keep, 5.0, 5.0, 3)
    assert ok and not keep[3] and keep.sum() == 11
    assert np.degrees(np.linalg.norm(attitude_error(A0, A))) * 3600 < 3.0


def test_track_command(frames_at_rest, tmp_path):
    """``skyfix track``: one JSON Solution per frame with mode, rate and the read time apart; a
    gyro file with a gap is used where it has samples; an unreadable frame is one error line."""
    import json

    from PIL import Image
    from typer.testing import CliRunner

    from skyfix.cli import app

    paths = []
    for k, f in enumerate(frames_at_rest[:5]):
        paths.append(tmp_path / f"f{k}.png")
        Image.fromarray(f.image.astype(np.uint16)).save(paths[-1])
    camera = tmp_path / "camera.toml"
    CAMERA.save(camera)
    gyro = tmp_path / "gyro.csv"
    gyro.write_text("t_s,x,y,z\n0.0,0,0,0\n0.05,0,0,0\n0.1,0,0,0\n0.35,0,0,0\n0.4,0,0,0\n")  # a gap: 0.1–0.35
    args = ["track", *map(str, paths), "--camera", str(camera), "--fps", "10", "--epoch", str(EPOCH),
            "--json"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    sols = [json.loads(line) for line in result.stdout.splitlines()]
    assert [s["mode"] for s in sols] == ["lost", "acquiring", "tracking", "tracking", "tracking"]
    assert [s["frame_time_s"] for s in sols] == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4])
    assert all({"read", "total"} <= s["time_ms"].keys() and len(s["rate_dps"]) == 3 for s in sols[1:])
    result = CliRunner().invoke(app, [*args, "--gyro", str(gyro)])
    assert result.exit_code == 0, result.output
    assert [json.loads(line)["mode"] for line in result.stdout.splitlines()][-1] == "tracking"
    (tmp_path / "f2.png").write_bytes(b"not an image")
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2
    assert sum("skyfix: error:" in line and "f2.png" in line for line in result.stderr.splitlines()) == 1
    assert json.loads(result.stdout.splitlines()[-1])["mode"] == "tracking"


def test_rolling_shutter_is_corrected():
    """A rolling shutter reading 960 rows in 19 ms at 1 °/s skews the frame by ±0.4 px; with the
    sensor's line time the tracker times each star by its row and the error stays an arcsecond."""
    from skyfix.simulate import Sensor

    line_time = 2e-5
    sensor = Sensor.from_preset("generic").replace(line_time_s=line_time)
    frames = list(render_sequence(A0, CAMERA, n_frames=10, fps=FPS, rate_rad_s=_rate("1 deg/s"), epoch=EPOCH,
                                  seed=9, sensor=sensor, exposure_s=0.02))
    errors = {}
    for lt in (0.0, line_time):
        tracker = Tracker(CAMERA, epoch=EPOCH, exposure_s=0.02, line_time_s=lt)
        sols = [tracker.update(f.image, f.truth["t_s"]) for f in frames]
        assert [s.mode for s in sols[2:]] == ["tracking"] * 8
        errors[lt] = np.array([np.hypot(*_error_arcsec(f, s)[:2]) for f, s in zip(frames[2:], sols[2:],
                                                                                 strict=True)])
    print(f"\nrolling shutter: boresight median {np.median(errors[0.0]):.2f}″ uncorrected, "
          f"{np.median(errors[line_time]):.2f}″ corrected")
    assert np.median(errors[line_time]) < 1.5 and errors[line_time].max() < 3.0
    assert np.median(errors[line_time]) < np.median(errors[0.0])
