"""Attitude profiles (skyfix.simulate.profiles), sequences rendered with them, and
``skyfix simulate --frames N --fps F --profile NAME OUT_DIR``."""

import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from skyfix.camera import Camera
from skyfix.catalog import Catalog
from skyfix.cli import app
from skyfix.detect.streak import centroid_streaks, star_times, streak_motion
from skyfix.errors import SimulationError, UnknownNameError
from skyfix.geometry import attitude_from_quaternion, attitude_from_radec_roll
from skyfix.simulate import PROFILES, Sensor, make_profile, render, render_sequence
from skyfix.simulate.profiles import Slew

EPOCH = 2025.0
A0 = attitude_from_radec_roll(math.radians(80.0), math.radians(-10.0), math.radians(25.0))
CAM = Camera.from_fov(1280, 960, 15.0)
SENSOR = Sensor(qe=0.5, full_well_e=1e9, gain_e_per_adu=1.0, bit_depth=16, bias_adu=0.0)
CLEAN = dict(sensor=SENSOR, sky_mag_arcsec2=None, noise=False, epoch=EPOCH)
D = math.radians

# Each profile with parameters that exercise it: the pendulum swings 20° about three axes out of
# phase, so its rate is far from φ̇ (the Jacobian's terms are 10 % of it).
CASES = {
    "constant": dict(rate_rad_s=[D(0.3), D(-2.0), D(1.0)]),
    "inertial-axis": dict(axis_icrs=[0.2, -0.5, 0.8], rate_rad_s=D(3.0)),
    "slew": dict(rotation_rad=[D(10.0), D(-25.0), D(5.0)], max_rate_rad_s=D(4.0), accel_rad_s2=D(2.0),
                 start_s=0.5),
    "slew-smooth": dict(rotation_rad=[0.0, D(3.0), D(-1.0)], max_rate_rad_s=D(4.0), accel_rad_s2=D(2.0),
                        shape="smooth"),
    "pendulum": dict(amplitude_rad=[D(20.0), D(25.0), D(15.0)], period_s=3.0, damping_ratio=0.1,
                     phase_rad=[0.3, 1.2, 2.5]),
}


def profile(case: str):
    return make_profile(case.removesuffix("-smooth"), A0, **CASES[case])


def numerical_rate(p, t, h=1e-5):
    """ω from the central difference of the attitude: A(t + h) A(t − h)ᵀ = R(−2h ω) + O(h³)."""
    dA = p.attitude(t + h) @ p.attitude(t - h).T
    return -Rotation.from_matrix(dA).as_rotvec() / (2 * h)


@pytest.mark.parametrize("case", CASES)
def test_rate_is_the_derivative_of_the_attitude(case):
    p = profile(case)
    kinks = []
    if isinstance(p, Slew):
        T, C, s = p.ramp_s, p.coast_s, p.start_s
        kinks = [s, s + T, s + T + C, s + 2 * T + C]
    times = [t for t in np.linspace(0.0, 12.0, 241) if min((abs(t - k) for k in kinks), default=1.0) > 1e-3]
    scale = max(float(np.linalg.norm(p.rate(t))) for t in times)
    assert scale > D(1.0)
    worst = max(float(np.linalg.norm(numerical_rate(p, t) - p.rate(t))) for t in times)
    assert worst <= 1e-6 * scale, (case, worst / scale)
    # arrays of times give the same as one time at a time
    ts = np.array(times[:7])
    assert np.allclose(p.attitude(ts), np.stack([p.attitude(t) for t in ts]), atol=1e-15)
    assert np.allclose(p.rate(ts), np.stack([p.rate(t) for t in ts]), atol=1e-15)
    assert p.attitude(ts.reshape(7, 1)).shape == (7, 1, 3, 3) and p.rate(ts.reshape(7, 1)).shape == (7, 1, 3)


def test_the_pendulum_rate_needs_the_jacobian():
    p = profile("pendulum")
    t = np.linspace(0.0, 6.0, 61)
    phi, dphi = p.turn(t)
    gap = np.linalg.norm(p.rate(t) - dphi, axis=1) / np.linalg.norm(dphi, axis=1)
    assert gap.max() > 0.05  # φ̇ alone would be 5 % off; the rate test above holds to 1e-6


def test_constant_rate_convention():
    # ω about camera +y: ḃ = −ω × b, A(t) = R(−ωt) A0 (skyfix.simulate.motion)
    w = np.array([0.0, D(2.0), 0.0])
    p = make_profile("constant", A0, rate_rad_s=w)
    r = A0[2]  # the ICRS direction on the boresight at t = 0
    b = p.attitude(0.5) @ r
    assert b == pytest.approx(-np.cross(w, [0, 0, 1.0]) * 0.5 + [0, 0, 1.0], abs=1e-3)
    assert b[0] < 0  # the star moves toward −x


def test_inertial_axis_is_a_constant_rate_about_a_fixed_axis():
    p = profile("inertial-axis")
    n = np.array(CASES["inertial-axis"]["axis_icrs"]) / np.linalg.norm(CASES["inertial-axis"]["axis_icrs"])
    for t in (0.0, 1.0, 7.5):
        A = p.attitude(t)
        assert A.T @ p.rate(t) == pytest.approx(D(3.0) * n, abs=1e-14)  # the rate, seen in ICRS
        assert A @ n == pytest.approx(A0 @ n, abs=1e-14)  # the axis stays put in the image
    # a quarter turn about the ICRS z axis moves the boresight's RA by 90°
    q = make_profile("inertial-axis", attitude_from_radec_roll(0.3, 0.0, 0.0), axis_icrs=[0, 0, 1],
                     rate_rad_s=D(10.0))
    assert q.attitude(9.0)[2] == pytest.approx([-math.sin(0.3), math.cos(0.3), 0.0], abs=1e-12)


@pytest.mark.parametrize("shape", ["trapezoid", "smooth"])
def test_slew_accelerates_coasts_and_stops_on_target(shape):
    rot = np.array([0.0, D(30.0), D(-10.0)])
    p = make_profile("slew", A0, rotation_rad=rot, max_rate_rad_s=D(3.0), accel_rad_s2=D(1.5), start_s=1.0,
                     shape=shape)
    k = 1.0 if shape == "trapezoid" else math.pi / 2
    assert p.ramp_s == pytest.approx(k * 2.0)  # 3 °/s at 1.5 °/s²
    assert p.coast_rate_rad_s == pytest.approx(D(3.0))
    end = p.start_s + p.duration_s
    assert np.linalg.norm(p.rate([0.0, 0.99, end + 0.01, end + 5])) == 0.0
    assert p.attitude(end + 1.0) == pytest.approx(Rotation.from_rotvec(-rot).as_matrix() @ A0, abs=1e-14)
    assert p.attitude(0.5) == pytest.approx(A0, abs=1e-15)
    t = np.linspace(0, end + 1, 4001)
    speed = np.linalg.norm(p.rate(t), axis=1)
    assert speed.max() == pytest.approx(D(3.0), rel=1e-12)
    accel = np.abs(np.diff(speed) / np.diff(t))
    assert accel.max() == pytest.approx(D(1.5), rel=1e-3)
    # the angle turned is the integral of the rate
    assert np.trapezoid(speed, t) == pytest.approx(np.linalg.norm(rot), rel=1e-6)
    # too short to reach the coasting rate: the ramps meet
    short = make_profile("slew", A0, rotation_rad=[0, D(1.0), 0], max_rate_rad_s=D(3.0), accel_rad_s2=D(1.5),
                         shape=shape)
    assert short.coast_s == 0.0 and short.coast_rate_rad_s == pytest.approx(math.sqrt(D(1.5) * D(1.0) / k))
    target = Rotation.from_rotvec([0, -D(1.0), 0]).as_matrix() @ A0
    assert short.attitude(short.duration_s) == pytest.approx(target, abs=1e-14)


def test_slew_between_two_attitudes():
    A1 = attitude_from_radec_roll(math.radians(84.0), math.radians(-5.0), math.radians(40.0))
    p = Slew.between(A0, A1, D(2.0), D(1.0))
    assert p.attitude(p.duration_s + 0.1) == pytest.approx(A1, abs=1e-12)
    assert p.attitude(0.0) == pytest.approx(A0, abs=1e-15)


def test_pendulum_swings_through_equilibrium_and_decays():
    p = make_profile("pendulum", A0, amplitude_rad=[0.0, D(2.0), 0.0], period_s=4.0, damping_ratio=0.05)
    assert p.attitude(0.0) == pytest.approx(A0, abs=1e-15)  # the push: at equilibrium, at full speed
    w0 = p.rate(0.0)[1]
    assert w0 == pytest.approx(D(2.0) * 2 * math.pi / 4.0, rel=1e-12)
    sigma = 0.05 * (2 * math.pi / 4.0) / math.sqrt(1 - 0.05**2)
    for n in (1, 3):
        assert p.rate(4.0 * n)[1] == pytest.approx(w0 * math.exp(-sigma * 4.0 * n), rel=1e-12)
        assert p.attitude(4.0 * n) == pytest.approx(A0, abs=1e-15)


SLEW = dict(rotation_rad=[0, 0.1, 0], max_rate_rad_s=1.0, accel_rad_s2=1.0)


@pytest.mark.parametrize("name, params, match", [
    ("spin", {}, "unknown motion profile 'spin'"),
    ("slew", {**SLEW, "rotation_rad": [0, 0, 0]}, "nonzero"),
    ("slew", {**SLEW, "accel_rad_s2": -1.0}, "accel_rad_s2 must be a positive"),
    ("slew", {**SLEW, "max_rate_rad_s": 0.0}, "max_rate_rad_s must be a pos"),
    ("slew", {**SLEW, "shape": "s"}, "slew shape 's'"),
    ("slew", {**SLEW, "rotation_rad": [0, 4.0, 0]}, "at most 180"),
    ("pendulum", dict(amplitude_rad=[0, 0.1, 0], period_s=3.0, damping_ratio=1.0), "damping_ratio must be"),
    ("pendulum", dict(amplitude_rad=[0, 0.1, 0], period_s=-3.0, damping_ratio=0.1), "period_s must be a pos"),
    ("pendulum", dict(amplitude_rad=[0, 0.1], period_s=3.0, damping_ratio=0.1), "amplitude_rad must be 3"),
    ("constant", dict(rate_rad_s=[0, math.nan, 0]), "finite"),
    ("constant", dict(rate=[0, 1, 0]), "unexpected keyword argument 'rate'"),
    ("inertial-axis", dict(axis_icrs=[0, 0, 0], rate_rad_s=0.1), "nonzero"),
])
def test_bad_profiles_are_one_line_errors(name, params, match):
    with pytest.raises((SimulationError, UnknownNameError), match=match) as err:  # a bad value, a bad name
        make_profile(name, A0, **params)
    assert "\n" not in str(err.value)


def test_registry():
    assert list(PROFILES) == ["constant", "inertial-axis", "slew", "pendulum"]
    p = profile("slew")
    assert json.loads(json.dumps(p.to_dict()))["name"] == "slew"


# --- sequences ---------------------------------------------------------------------------------
def field_catalog(n=40, seed=1, mag=5.0):
    """Stars scattered over (and a little beyond) the field of A0."""
    rng = np.random.default_rng(seed)
    xy = np.column_stack([rng.uniform(-100, CAM.width + 100, n), rng.uniform(-100, CAM.height + 100, n)])
    vec = CAM.pixel_to_ray(xy) @ A0
    return Catalog(np.arange(1, n + 1), vec, np.full(n, mag, np.float32), np.zeros(n), np.zeros(n), EPOCH)


def test_slew_sequence_truth_is_the_projection_at_the_truth_attitude():
    cat = field_catalog()
    rot = np.array([0.0, D(3.0), D(1.0)])
    params = dict(rotation_rad=rot, max_rate_rad_s=D(2.0), accel_rad_s2=D(4.0))
    frames = list(render_sequence(A0, CAM, n_frames=6, fps=10.0, profile="slew", profile_params=params,
                                  exposure_s=0.05, catalog=cat, **CLEAN))
    slew = make_profile("slew", A0, **params)
    for k, f in enumerate(frames):
        t = k / 10.0
        truth = f.truth
        assert truth["t_s"] == t and truth["profile"]["name"] == "slew"
        A = attitude_from_quaternion(truth["quaternion_xyzw"])
        # the truth attitude is the slew's closed form (about the fixed axis, angle θ(t))
        assert A == pytest.approx(slew.attitude(t), abs=1e-12)
        assert truth["rate_rad_s"] == pytest.approx(slew.rate(t), abs=1e-15)
        ids = np.array([s["id"] for s in truth["stars"]])
        xy = np.array([[s["x"], s["y"]] for s in truth["stars"]])
        proj, front = CAM.ray_to_pixel(cat.vectors[ids - 1] @ A.T)
        assert front.all() and np.abs(proj - xy).max() < 1e-6
        # the image (noise off): the intensity centroid of each streak is the star's mean
        # position over the exposure on the profile (the smear follows the slew, also at t = 0
        # where it starts mid-exposure) ...
        inner = (xy[:, 0] > 15) & (xy[:, 0] < CAM.width - 15) & (xy[:, 1] > 15) & (xy[:, 1] < CAM.height - 15)
        motion = streak_motion(CAM, xy, truth["rate_rad_s"], 0.05)
        com = centroid_streaks(f.image, xy + 0.7, motion, method="com")
        steps = t + (np.arange(500) + 0.5) / 500 * 0.05 - 0.025
        b = np.einsum("kij,nj->kni", slew.attitude(steps), cat.vectors[ids[inner] - 1])
        mean_xy = CAM.ray_to_pixel(b.reshape(-1, 3))[0].reshape(500, -1, 2).mean(axis=0)
        assert np.abs(com.xy[inner] - mean_xy).max() < 0.002
        # ... which the acceleration α moves from the mid-exposure (truth) position by α·τ²/24
        # (0.035 px here); the streak-weighted centroid lands closer to mid-exposure
        c = centroid_streaks(f.image, xy + 0.7, motion)
        assert np.abs(mean_xy - xy[inner]).max() < 0.036 and np.abs(c.xy[inner] - xy[inner]).max() < 0.035
    speeds = [np.linalg.norm(f.truth["rate_rad_s"]) for f in frames]
    assert speeds[0] == 0.0 and speeds[1] == pytest.approx(D(0.4)) and speeds[-1] == pytest.approx(D(2.0))


def test_accelerating_profile_with_rolling_shutter_follows_the_profile_exactly():
    """Each star's truth is the projection at its own row's time on the profile (not at the
    frame's rate): a fast pendulum, where the constant-rate approximation is 0.3 px off."""
    cat = field_catalog(seed=2)
    line = 30e-6
    p = make_profile("pendulum", A0, amplitude_rad=[D(1.0), D(4.0), D(0.5)], period_s=2.0, damping_ratio=0.1,
                     phase_rad=[0.0, 1.3, 0.4])
    frames = list(render_sequence(A0, CAM, n_frames=3, fps=20.0, profile=p, exposure_s=0.02, catalog=cat,
                                  **{**CLEAN, "sensor": SENSOR.replace(line_time_s=line)}))
    worst_constant = 0.0
    for f in frames:
        t_k = f.truth["t_s"]
        ids = np.array([s["id"] for s in f.truth["stars"]])
        xy = np.array([[s["x"], s["y"]] for s in f.truth["stars"]])
        t = star_times(xy, t_k, line, CAM.height)
        b = np.einsum("nij,nj->ni", p.attitude(t), cat.vectors[ids - 1])
        assert np.abs(CAM.ray_to_pixel(b)[0] - xy).max() < 1e-6
        A_const = Rotation.from_rotvec(-np.outer(t - t_k, p.rate(t_k))).as_matrix() @ p.attitude(t_k)
        b_const = np.einsum("nij,nj->ni", A_const, cat.vectors[ids - 1])
        worst_constant = max(worst_constant, np.abs(CAM.ray_to_pixel(b_const)[0] - xy).max())
    assert worst_constant > 0.1


def test_constant_rate_sequence_is_unchanged():
    """The old keyword still means a constant rate: frame 0 equals render() bit for bit, and the
    profile keyword gives the same frames."""
    cat = field_catalog(n=10)
    w = [0.0, D(1.0), D(0.5)]
    kw = dict(exposure_s=0.05, catalog=cat, seed=3, epoch=EPOCH)
    old = list(render_sequence(A0, CAM, n_frames=2, fps=10.0, rate_rad_s=w, **kw))
    new = list(render_sequence(A0, CAM, n_frames=2, fps=10.0, profile="constant",
                               profile_params={"rate_rad_s": w}, **kw))
    single = render(A0, CAM, rate_rad_s=w, **kw)
    assert np.array_equal(old[0].image, single.image) and np.array_equal(new[1].image, old[1].image)
    assert old[1].truth["profile"] == {"name": "constant", "rate_rad_s": w}


def test_bad_sequences():
    with pytest.raises(UnknownNameError, match="unknown motion profile"):
        next(render_sequence(A0, CAM, n_frames=2, fps=10.0, profile="wobble"))
    with pytest.raises(SimulationError, match="fps must be a positive"):
        next(render_sequence(A0, CAM, n_frames=2, fps=-10.0, profile="constant",
                             profile_params={"rate_rad_s": [0, 0, 0]}))
    with pytest.raises(SimulationError, match="not both"):
        next(render_sequence(A0, CAM, n_frames=2, fps=10.0, rate_rad_s=[0, 0, 0], profile="constant"))
    with pytest.raises(SimulationError, match="differs from the profile"):
        next(render_sequence(np.eye(3), CAM, n_frames=2, fps=10.0, profile=profile("pendulum")))


# --- the command line -----------------------------------------------------------------------------
runner = CliRunner()


def test_cli_writes_a_slew_sequence(tmp_path):
    out = tmp_path / "run"
    result = runner.invoke(app, ["simulate", "--ra", "80", "--dec", "-10", "--frames", "4", "--fps", "10",
                                 "--exposure", "0.02", "--profile", "slew", "--rotation-deg", "0,1,0",
                                 "--max-rate-dps", "2", "--accel-dps2", "5", "--camera", "has2", str(out)])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in out.iterdir()) == [f"frame-{k:04d}.{e}" for k in range(4)
                                                     for e in ("fits", "truth.json")]
    truths = [json.loads((out / f"frame-{k:04d}.truth.json").read_text()) for k in range(4)]
    assert [t["t_s"] for t in truths] == [0.0, 0.1, 0.2, 0.3]
    assert truths[2]["profile"]["shape"] == "trapezoid"
    assert math.degrees(np.linalg.norm(truths[3]["rate_rad_s"])) == pytest.approx(1.5)  # 5 °/s² × 0.3 s
    assert truths[3]["dec_deg"] != truths[0]["dec_deg"]


@pytest.mark.parametrize("args, message", [
    (["--profile", "spin"], "--profile 'spin' is not a motion profile"),
    (["--fps", "-5"], "--fps -5 must be a positive number"),
    (["--profile", "pendulum", "--damping", "1.5"], "--damping 1.5 must be a damping ratio"),
    (["--profile", "pendulum", "--amplitude-deg", "0,100,0"], "amplitude must be at most 90 degrees"),
    (["--profile", "slew", "--accel-dps2", "0"], "--accel-dps2 0 must be a positive number"),
    (["--profile", "slew", "--rotation-deg", "0,1"], "--rotation-deg takes 3 numbers"),
    (["--profile", "slew", "--period", "3"], "--period is not an option of --profile slew"),
    (["--profile", "inertial-axis", "--rate-dps", "1"], "--profile inertial-axis needs --axis"),
    (["--rate-dps", "1,2"], "--rate-dps takes 3 numbers"),
    (["-o", "x.fits"], "not both"),
])
def test_cli_bad_motion_is_one_line_exit_2(tmp_path, args, message):
    result = runner.invoke(app, ["simulate", "--ra", "80", "--dec", "-10", "--frames", "3", *args,
                                 str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    assert message in result.output and result.output.count("\n") == 1
    assert not (tmp_path / "out").exists()
