"""Frames around the camera (skyfix.frames): Euler 1-2-3, thesis 004's sensor → body matrix and
orbit frame with their corrections and worked checks, the mounting (quaternion, Euler, string,
TOML), round trips camera ↔ body ↔ orbit ↔ ICRS, and true of date against astropy's TETE/CIRS."""

from __future__ import annotations

import math

import erfa
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skyfix import frames as fr
from skyfix.analysis import coverage as cv
from skyfix.camera import Camera
from skyfix.errors import InputError
from skyfix.geometry import angle_between, attitude_from_radec_roll, quaternion_from_attitude, vector_to_radec

ARCSEC = math.radians(1.0 / 3600.0)
S = math.sqrt(0.5)


def _random_rotations(n: int, seed: int = 0) -> np.ndarray:
    return Rotation.random(n, random_state=seed).as_matrix()


# --- Euler 1-2-3 (thesis 004 (1.10)–(1.13)) --------------------------------------------------------
def test_euler123_is_thesis_004s_product_and_scipys():
    phi, theta, psi = 0.3, -0.7, 2.1
    c, s = np.cos, np.sin
    printed_corrected = np.array([  # 004's (1.13) as its reading corrects it
        [c(psi) * c(theta), c(psi) * s(theta) * s(phi) + s(psi) * c(phi),
         -c(psi) * s(theta) * c(phi) + s(psi) * s(phi)],
        [-s(psi) * c(theta), -s(psi) * s(theta) * s(phi) + c(psi) * c(phi),
         s(psi) * s(theta) * c(phi) + c(psi) * s(phi)],
        [s(theta), -c(theta) * s(phi), c(theta) * c(phi)]])
    A = fr.matrix_from_euler123(phi, theta, psi)
    assert np.allclose(A, printed_corrected, atol=1e-15)
    assert np.allclose(A, Rotation.from_euler("XYZ", [phi, theta, psi]).as_matrix().T, atol=1e-15)
    # 004's elementary DCMs are frame rotations: A_x(φ) [0, 1, 0] = [0, cos φ, −sin φ]
    assert fr.elementary_rotation(0, 0.3) @ [0, 1, 0] == pytest.approx([0, math.cos(0.3), -math.sin(0.3)])


def test_euler123_round_trip_and_gimbal_lock():
    A = _random_rotations(500, seed=1)
    angles = fr.euler123_from_matrix(A)
    assert np.max(np.abs(fr.matrix_from_euler123(*angles.T) - A)) < 1e-12
    assert np.all(np.abs(angles[:, 1]) <= math.pi / 2)
    for theta in (math.pi / 2, -math.pi / 2):
        A = fr.matrix_from_euler123(0.4, theta, -1.1)
        phi, th, psi = fr.euler123_from_matrix(A)
        assert phi == 0.0 and th == pytest.approx(theta)
        assert np.max(np.abs(fr.matrix_from_euler123(phi, th, psi) - A)) < 1e-12


# --- thesis 004's sensor → body matrix, orbit frame, worked checks ----------------------------------------
def test_sunsat_sensor_to_body_corrected_matrix():
    A_ss_b = fr.sunsat_sensor_to_body()
    assert np.allclose(A_ss_b, [[S, S, 0], [S, -S, 0], [0, 0, -1]], atol=1e-15)  # 004 reading §1.3
    assert np.allclose(A_ss_b, fr.matrix_from_euler123(math.pi, 0.0, -math.pi / 4), atol=1e-15)
    boresight_ss = np.array([0.0, 1.0, 0.0])
    assert A_ss_b @ boresight_ss == pytest.approx([S, -S, 0.0])  # between x_b and −y_b, as 004 says
    printed = fr.elementary_rotation(2, -math.pi / 4)  # (1.14) as printed: the 180° about x dropped
    assert printed @ boresight_ss == pytest.approx([-S, S, 0.0])  # between −x_b and +y_b: wrong
    assert np.linalg.det(printed) == pytest.approx(1.0)  # a rotation too, so only the check catches it
    # the Sunsat mounting: the camera's +z (boresight) is y_ss, its +x is x_ss, its +y is −z_ss
    M = fr.sunsat_mounting().A_cam_to_body
    assert M @ [0, 0, 1] == pytest.approx([S, -S, 0.0])
    assert M @ [1, 0, 0] == pytest.approx(A_ss_b @ [1, 0, 0])
    assert M @ [0, 1, 0] == pytest.approx(A_ss_b @ [0, 0, -1])


def test_thesis_004_worked_example():
    # 004 §1.3: yaw −45° points the boresight along −y_o (the orbit normal), yaw 135° along +y_o,
    # which i = 97° puts at declination +7°; roll moves stars in v, yaw in u, pitch turns the image
    mount = fr.sunsat_mounting()
    node, incl, u = math.radians(140.0), math.radians(97.0), math.radians(63.0)
    A_c_o = fr.orbit_frame_from_elements(node, incl, u)
    for yaw_deg, sign in ((-45.0, -1.0), (135.0, 1.0)):
        A_c_b = fr.matrix_from_euler123(0.0, 0.0, math.radians(yaw_deg)) @ A_c_o
        boresight_icrs = mount.camera_attitude(A_c_b)[2]
        assert boresight_icrs == pytest.approx(sign * A_c_o[1], abs=1e-15)
    A_cam = mount.camera_attitude(fr.matrix_from_euler123(0.0, 0.0, math.radians(135.0)) @ A_c_o)
    assert math.degrees(vector_to_radec(A_cam[2])[1]) == pytest.approx(7.0, abs=1e-12)
    assert np.allclose(cv.sunsat_attitude_matrix(0.0, 0.0, math.radians(135.0), u, incl, node)[0], A_cam,
                       atol=1e-15)  # coverage.py uses the same chain

    centre = A_cam[2]  # the star on the boresight
    off = A_cam[2] + 0.05 * A_cam[0] + 0.03 * A_cam[1]  # and one off it
    off /= np.linalg.norm(off)

    def image_shift(star: np.ndarray, roll: float, pitch: float, yaw: float) -> np.ndarray:
        A = mount.camera_attitude(fr.matrix_from_euler123(roll, pitch, math.radians(135.0) + yaw) @ A_c_o)
        b0, b = A_cam @ star, A @ star
        return b[:2] / b[2] - b0[:2] / b0[2]

    d = 1e-4
    roll, yaw = image_shift(centre, d, 0, 0), image_shift(centre, 0, 0, d)
    assert abs(roll[1]) == pytest.approx(d, rel=1e-6) and abs(roll[0]) < 1e-12  # roll: along y, 004's v
    assert abs(yaw[0]) == pytest.approx(d, rel=1e-6) and abs(yaw[1]) < 1e-12  # yaw: along x, 004's u
    # pitch: about the boresight — the centre stays, a star off it turns about the centre by d
    assert np.max(np.abs(image_shift(centre, 0, d, 0))) < 1e-15
    pitch = image_shift(off, 0, d, 0)
    xy = (A_cam @ off)[:2] / (A_cam @ off)[2]
    assert abs(pitch @ xy) < 1e-3 * np.linalg.norm(pitch) * np.linalg.norm(xy)
    assert np.linalg.norm(pitch) == pytest.approx(d * np.linalg.norm(xy), rel=1e-3)


def _kepler_circular(node: float, incl: float, u: float, radius_km: float = 7078.0):
    """Position and velocity on a circular orbit from its elements, written independently of 004."""
    n_node = np.array([math.cos(node), math.sin(node), 0.0])
    normal = np.array([math.sin(incl) * math.sin(node), -math.sin(incl) * math.cos(node), math.cos(incl)])
    in_plane = np.cross(normal, n_node)
    speed = math.sqrt(398600.4418 / radius_km)
    r = radius_km * (math.cos(u) * n_node + math.sin(u) * in_plane)
    v = speed * (-math.sin(u) * n_node + math.cos(u) * in_plane)
    return r, v, normal, n_node


def test_orbit_frame_sign_check():
    rng = np.random.default_rng(2)
    for node, incl, u in rng.uniform([0, 0.05, 0], [2 * math.pi, math.pi - 0.05, 2 * math.pi], (50, 3)):
        r, v, normal, _ = _kepler_circular(node, incl, u)
        A = fr.orbit_frame(r, v)
        assert np.max(np.abs(A - fr.orbit_frame_from_elements(node, incl, u))) < 1e-12
        assert A[2] == pytest.approx(-r / np.linalg.norm(r), abs=1e-15)  # z_o nadir
        assert A[1] == pytest.approx(-normal, abs=1e-15)  # y_o against the orbit normal
        assert A[0] == pytest.approx(v / np.linalg.norm(v), abs=1e-15)  # x_o along the velocity
    # 004's check at the ascending node: z_o = −node direction, x_o = the velocity there
    r, v, normal, n_node = _kepler_circular(0.7, math.radians(97.0), 0.0)
    A = fr.orbit_frame_from_elements(0.7, math.radians(97.0), 0.0)
    assert A[2] == pytest.approx(-n_node) and A[0] == pytest.approx(v / np.linalg.norm(v))
    # the printed (1.18), A_y(+ω′), runs backwards: a quarter orbit on, its nadir is the zenith
    r, v, *_ = _kepler_circular(0.7, math.radians(97.0), math.pi / 2)
    printed = (fr.elementary_rotation(1, math.pi / 2) @ fr.elementary_rotation(0, -math.pi / 2)
               @ fr.elementary_rotation(1, -math.radians(97.0))
               @ fr.elementary_rotation(2, math.pi / 2 + 0.7))
    assert printed[2] == pytest.approx(r / np.linalg.norm(r))
    with pytest.raises(InputError, match="parallel"):
        fr.orbit_frame([7000.0, 0, 0], [7.5, 0, 0])
    with pytest.raises(InputError, match="3 numbers"):
        fr.orbit_frame([7000.0, 0], [0, 7.5, 0])


# --- round trips --------------------------------------------------------------------------------
def test_round_trips_camera_body_orbit_icrs_exact():
    A_cams = _random_rotations(200, seed=3)
    mounts = _random_rotations(200, seed=4)
    rng = np.random.default_rng(5)
    worst = 0.0
    for A_cam, M, (node, incl, u) in zip(A_cams, mounts, rng.uniform(0, 3, (200, 3)), strict=True):
        mounting = fr.Mounting(M)
        r, v, *_ = _kepler_circular(node, incl, u)
        A_orbit = fr.orbit_frame(r, v)
        A_body = mounting.body_attitude(A_cam)  # ICRS → body
        A_o_b = A_body @ A_orbit.T  # orbit → body
        back = mounting.camera_attitude(A_o_b @ A_orbit)  # orbit → ICRS → camera
        worst = max(worst, np.max(np.abs(back - A_cam)))
        # through the output's quaternions and Euler angles
        out = fr.attitude_frames(A_cam, mounting=mounting, A_icrs_to_orbit=A_orbit)
        q_o_b = out.body_in_orbit.quaternion_xyzw
        A_o_b_q = Rotation.from_quat(q_o_b).as_matrix()
        A_o_b_e = fr.matrix_from_euler123(*np.radians(out.body_in_orbit.euler123_deg))
        for A in (A_o_b_q, A_o_b_e):
            worst = max(worst, np.max(np.abs(mounting.camera_attitude(A @ A_orbit) - A_cam)))
        m2 = fr.Mounting.from_quaternion(mounting.quaternion_xyzw)
        m3 = fr.Mounting.from_euler123_deg(mounting.euler123_deg)
        worst = max(worst, np.max(np.abs(m2.A_cam_to_body - M)), np.max(np.abs(m3.A_cam_to_body - M)))
    assert worst < 1e-12


def test_attitude_frames_json_names_every_frame():
    A = attitude_from_radec_roll(math.radians(84.0), math.radians(-2.0), math.radians(20.0))
    r, v, *_ = _kepler_circular(1.0, math.radians(97.0), 0.4)
    out = fr.attitude_frames(A, mounting=fr.sunsat_mounting(), A_icrs_to_orbit=fr.orbit_frame(r, v))
    js = out.to_json()
    assert js["reference_frame"] == "icrs"
    assert (js["camera"]["from"], js["camera"]["to"]) == ("icrs", "camera")
    assert (js["body"]["from"], js["body"]["to"]) == ("icrs", "body")
    assert (js["body_in_orbit"]["from"], js["body_in_orbit"]["to"]) == ("orbit", "body")
    assert js["camera"]["ra_deg"] == pytest.approx(84.0) and js["camera"]["roll_deg"] == pytest.approx(20.0)
    assert js["camera"]["quaternion_xyzw"] == pytest.approx(quaternion_from_attitude(A), abs=1e-10)
    tod = fr.attitude_frames(A, reference="true-of-date", jd_tt=2460390.0).to_json()
    assert tod["reference_frame"] == "true-of-date" and tod["camera"]["from"] == "true-of-date"
    assert "body" not in tod
    with pytest.raises(InputError, match="needs the time"):
        fr.attitude_frames(A, reference="true-of-date")
    with pytest.raises(InputError, match="reference frame 'j2000'"):
        fr.attitude_frames(A, reference="j2000")


# --- true of date -------------------------------------------------------------------------------
def test_true_of_date_agrees_with_astropy_tete_and_cirs():
    import astropy.units as u
    from astropy.coordinates import CIRS, GCRS, TETE, CartesianRepresentation
    from astropy.time import Time
    from astropy.utils import iers

    with iers.conf.set_temp("auto_download", False):
        t = Time("2024-03-20T04:00:00", scale="utc")
        jd_tt = t.tt.jd
        A = _random_rotations(1, seed=6)[0]
        A_tod = fr.true_of_date(A, jd_tt)
        axes = A.T  # columns: camera axes in ICRS (= GCRS axes)
        g = GCRS(CartesianRepresentation(axes * u.one), obstime=t)
        tete = g.transform_to(TETE(obstime=t)).cartesian.xyz.value
        cirs = g.transform_to(CIRS(obstime=t)).cartesian.xyz.value
    # each camera axis in the true-of-date frame is A_todᵀ's column: within 0.1″ (measured µas)
    err = angle_between(A_tod, (tete / np.linalg.norm(tete, axis=0)).T) / ARCSEC
    assert err.max() < 1e-3
    # CIRS differs from TETE by the equation of the origins, a turn about the pole
    eo = erfa.eo06a(2400000.5, jd_tt - 2400000.5)
    A_cirs = A_tod @ fr.elementary_rotation(2, -eo).T
    err_cirs = angle_between(A_cirs, (cirs / np.linalg.norm(cirs, axis=0)).T) / ARCSEC
    assert err_cirs.max() < 1e-3
    # and the attitude of date is the ICRS one turned by 24.2 years of precession (~0.34°)
    assert math.degrees(math.acos((np.trace(A_tod @ A.T) - 1) / 2)) == pytest.approx(0.339, abs=0.005)


# --- the mounting -------------------------------------------------------------------------------
def test_mounting_from_strings_tables_and_files(tmp_path):
    q = Rotation.from_euler("XYZ", [10, -20, 30], degrees=True).inv().as_quat(canonical=True)
    m = fr.Mounting.parse(",".join(f"{x:.15g}" for x in q))
    assert np.allclose(m.A_cam_to_body, fr.Mounting.parse("10,-20,30").A_cam_to_body, atol=1e-15)  # Euler
    assert m.euler123_deg == pytest.approx([10, -20, 30])
    assert fr.Mounting.parse("0.7071,0,0,0.7071").A_cam_to_body @ [0, 1, 0] == pytest.approx(
        [0, 0, 1], abs=1e-4)  # 4 printed digits are accepted (normalised)
    sunsat = fr.Mounting.from_table({"euler123_deg": [180.0, 0.0, -45.0]})
    assert np.allclose(sunsat.A_cam_to_body, fr.sunsat_sensor_to_body(), atol=1e-15)
    path = tmp_path / "cam.toml"
    path.write_text(Camera.from_fov(1280, 960, 17.0).to_toml() + "\n[mounting]\nquaternion_xyzw = "
                    f"[{', '.join(str(x) for x in m.quaternion_xyzw)}]\n")
    assert fr.Mounting.load(path) == fr.Mounting.from_quaternion(m.quaternion_xyzw)
    assert Camera.load(path) == Camera.from_fov(1280, 960, 17.0)  # the camera file still loads
    no_mount = tmp_path / "plain.toml"
    no_mount.write_text(Camera.from_fov(1280, 960, 17.0).to_toml())
    assert fr.Mounting.load(no_mount) is None
    assert np.allclose(fr.Mounting.from_table(m.to_table()).A_cam_to_body, m.A_cam_to_body, atol=1e-15)


@pytest.mark.parametrize("make, match", [
    (lambda: fr.Mounting.parse("1,1,1,1"), r"not a unit quaternion \(norm 2\)"),
    (lambda: fr.Mounting.parse("0,0,0.5,0.5"), "not a unit quaternion"),
    (lambda: fr.Mounting.parse("1,2"), "has 2 numbers: give a quaternion x,y,z,w"),
    (lambda: fr.Mounting.parse("1,2,3,4,5"), "has 5 numbers"),
    (lambda: fr.Mounting.parse("a,b,c"), "not comma-separated numbers"),
    (lambda: fr.Mounting.from_quaternion([0, 0, 1]), "needs 4 numbers"),
    (lambda: fr.Mounting.from_quaternion([0, 0, float("nan"), 1]), "not finite"),
    (lambda: fr.Mounting.from_table({"quaternion_xyzw": [0, 0, 0, 1], "euler123_deg": [0, 0, 0]}),
     "exactly one"),
    (lambda: fr.Mounting.from_table({"euler": [0, 0, 0]}), "unknown \\[mounting\\] keys: euler"),
    (lambda: fr.Mounting.from_toml("[mounting]\neuler123_deg = [1, 2]\n"), "need 3 numbers, not 2"),
    (lambda: fr.Mounting(np.diag([1.0, 1.0, -1.0])), "not a rotation"),
])
def test_malformed_mounting_is_one_line_input_error(make, match):
    with pytest.raises(InputError, match=match) as info:
        make()
    assert "\n" not in str(info.value)
