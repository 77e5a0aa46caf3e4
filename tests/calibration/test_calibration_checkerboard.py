"""``skyfix calibrate checkerboard`` (issue 25 part 2): OpenCV's corners and fits, mapped to the Camera.

Boards are rendered by :func:`skyfix.calibration.checkerboard.render_board` (each pixel its area's
mean; pixel ``(col, row)`` covers ``[col − ½, col + ½]``) at random poses with the whole board in
frame, 2 DN of noise on a 30–220 DN board; the truth of every corner is ``cv2.projectPoints`` (or
``cv2.fisheye.projectPoints``) of the board at that pose.
"""

from __future__ import annotations

import numpy as np
import pytest

from skyfix.calibration import checkerboard as cb
from skyfix.camera import Camera
from skyfix.errors import CalibrationError, InputError, UnknownNameError

cv2 = pytest.importorskip("cv2")

PATTERN = (9, 6)
SQUARE_MM = 25.0
# Thesis 000 §5.2's camera: 752×480, 6 µm, fx 8.63 mm, fy 8.56 mm, its distortion; the principal
# point off the centre by (+12, −7) px.
THESIS_000_CAMERA = Camera(width=752, height=480, fx=8630.0 / 6.0, fy=8560.0 / 6.0, cx=387.5, cy=232.5,
                           k1=-0.3686, k2=0.3148, p1=-0.0023, p2=0.0003)
FISHEYE = Camera.from_fov(752, 480, 110.0, projection="kannala-brandt", k1=-0.02, k2=0.004).replace(
    cx=380.0, cy=236.0)
NOISE_DN = 2.0


def _poses(camera: Camera, n: int, rng: np.random.Generator, distance_mm: tuple[float, float],
           tilt: float = 0.6) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` board poses (rvec, tvec): the board's centre on a random pixel's ray at a random
    distance, tilted up to ``tilt`` rad about x and y and turned at random, its margin in frame."""
    cols, rows = PATTERN
    outline = np.array([[-2, -2, 0], [cols, -2, 0], [cols, rows, 0], [-2, rows, 0]], float) * SQUARE_MM
    edge = np.concatenate([outline[i] + np.linspace(0, 1, 20)[:, None] * (outline[(i + 1) % 4] - outline[i])
                           for i in range(4)])
    centre = np.array([(cols - 1) / 2, (rows - 1) / 2, 0.0]) * SQUARE_MM
    out = []
    while len(out) < n:
        rvec = np.array([rng.uniform(-tilt, tilt), rng.uniform(-tilt, tilt), rng.uniform(-np.pi, np.pi)])
        R = cv2.Rodrigues(rvec)[0]
        aim = [[rng.uniform(0, camera.width - 1), rng.uniform(0, camera.height - 1)]]
        ray = camera.pixel_to_ray(np.array(aim))
        tvec = ray[0] / ray[0, 2] * rng.uniform(*distance_mm) - R @ centre
        uv, front = camera.ray_to_pixel(edge @ R.T + tvec)
        if front.all() and camera.in_frame(uv, margin=3).all():
            out.append((rvec, tvec))
    return out


def _render(camera: Camera, poses, rng: np.random.Generator) -> list[np.ndarray]:
    return [cb.render_board(camera, r, t, PATTERN, square=SQUARE_MM) + rng.normal(0, NOISE_DN, (camera.height,
                                                                                                camera.width))
            for r, t in poses]


def _truth(camera: Camera, rvec, tvec) -> np.ndarray:
    K, D = cb.opencv_matrices(camera)
    obj = cb.board_points(PATTERN, SQUARE_MM)
    if camera.projection == "pinhole":
        return cv2.projectPoints(obj, rvec, tvec, K, D)[0].reshape(-1, 2)
    return cv2.fisheye.projectPoints(obj.reshape(1, -1, 3), rvec, tvec, K, D)[0].reshape(-1, 2)


def _grid_error_px(fitted: Camera, truth: Camera, grid: np.ndarray | None = None) -> float:
    """The largest distance, over a 20-px grid of the frame (or the pixels ``grid``), between where
    the true and the fitted camera put the same ray."""
    if grid is None:
        ys, xs = np.mgrid[0:truth.height:20, 0:truth.width:20]
        grid = np.c_[xs.ravel(), ys.ravel()].astype(float)
    uv, _ = fitted.ray_to_pixel(truth.pixel_to_ray(grid))
    return float(np.nanmax(np.hypot(*(uv - grid).T)))


@pytest.fixture(scope="module")
def boards():
    """12 rendered boards of thesis 000's camera, 400–800 mm away (the poses and images)."""
    rng = np.random.default_rng(2)
    poses = _poses(THESIS_000_CAMERA, 12, rng, (400.0, 800.0))
    return poses, _render(THESIS_000_CAMERA, poses, rng)


@pytest.mark.parametrize("camera", [THESIS_000_CAMERA, FISHEYE],
                         ids=["brown-conrady", "fisheye"])
def test_the_camera_projects_as_opencv_and_maps_both_ways(camera):
    """Camera.ray_to_pixel equals cv2.projectPoints / cv2.fisheye.projectPoints with
    :func:`opencv_matrices`' K and D (both projectPoints ignore K's skew, which both fits hold
    at 0), and :func:`camera_from_opencv` is its inverse."""
    rvec, tvec = np.array([0.3, -0.2, 1.0]), np.array([-40.0, 30.0, 300.0])
    R = cv2.Rodrigues(rvec)[0]
    uv, front = camera.ray_to_pixel(cb.board_points(PATTERN, SQUARE_MM) @ R.T + tvec)
    assert front.all()
    assert np.max(np.abs(uv - _truth(camera, rvec, tvec))) < 1e-9
    K, D = cb.opencv_matrices(camera)
    assert cb.camera_from_opencv(K, D, camera.width, camera.height, camera.projection) == camera


def test_opencv_corners_sit_at_skyfix_pixel_centres():
    """The pixel conventions agree: a fronto-parallel board whose vertical edges fall a quarter
    pixel into a pixel renders that pixel a quarter one colour (pixel c covers [c − ½, c + ½]; the
    8 × 8 samples sit at (k + ½)/8, so a quarter is exact), and OpenCV's corners
    land on the projected truth with no half-pixel shift (measured: mean offset (0.0037, −0.0014)
    px, RMS 0.038 px, on this undistorted board turned 0.1 rad)."""
    camera = Camera(width=400, height=300, fx=800.0, fy=800.0, cx=199.5, cy=149.5)
    tvec = np.array([-100.0 + 0.25 * 500 / 800, -60.0, 500.0])  # corner (0, 0) at x = 199.5 − 160 + 0.25
    img = cb.render_board(camera, np.zeros(3), tvec, PATTERN, square=SQUARE_MM, black=0.0, white=100.0)
    x_edge = 199.5 + 800 * tvec[0] / 500  # the board's first inner corner column: 39.75
    assert x_edge == pytest.approx(39.75)
    row = int(round(149.5 + 800 * (tvec[1] + 0.5 * SQUARE_MM) / 500))  # halfway down the first row of squares
    # pixel 40 covers [39.5, 40.5]: a quarter of it left of the edge at 39.75
    left, right = img[row, 39], img[row, 41]
    assert {left, right} == {0.0, 100.0}
    assert img[row, 40] == pytest.approx(left + (right - left) * 0.75, abs=1e-4)
    # corners at one sub-pixel phase share one cornerSubPix bias (−0.074 px in x here); turned by
    # 0.1 rad the 54 corners sample every phase, and the mean offset is what is left of a convention
    rvec = np.array([0.0, 0.0, 0.1])
    img = cb.render_board(camera, rvec, tvec, PATTERN, square=SQUARE_MM)
    found = cb.find_corners(img, PATTERN)
    truth = _truth(camera, rvec, tvec)
    offset = found - truth
    assert np.abs(offset.mean(axis=0)).max() < 0.01
    assert np.sqrt(np.mean(np.sum(offset**2, axis=1))) < 0.06


def test_rendered_boards_recover_thesis_000s_camera(boards):
    """12 boards of thesis 000's camera (k1 −0.3686, k2 0.3148, p −0.0023, 0.0003; pp +12, −7 px):
    measured (seed 2) fx 1438.42 ± 0.54 (truth 1438.33), fy 1426.76 ± 0.53 (1426.67), cx 386.43 ±
    0.98 (387.5), cy 232.95 ± 0.66 (232.5), k1 −0.3685 ± 0.0026, k2 0.278 ± 0.043 (0.3148), p1
    −0.00225 ± 8e-5, p2 0.00025 ± 6e-5 (1σ, OpenCV's), k3 fixed at 0 (−1.3 ± 2.1); per-image RMS
    0.039–0.073 px, std (0.035, 0.044) px; the fitted camera within 1.29 px of the truth over the
    frame (its corners, which no board reaches, the worst)."""
    poses, images = boards
    cal = cb.calibrate_checkerboard(images, pattern="9x6", square_mm=SQUARE_MM)
    cam, truth = cal.camera, THESIS_000_CAMERA
    assert cal.skipped == {} and cal.rejected == {}
    assert list(cal.fixed) == ["k3"] and cam.k3 == 0.0
    assert np.all(cal.rms_px() < 0.1)
    assert max(cal.pixel_error_px) < 0.05
    assert abs(cam.fx - truth.fx) < 1.5 and abs(cam.fy - truth.fy) < 1.5
    assert abs(cam.cx - truth.cx) < 1.5 and abs(cam.cy - truth.cy) < 1.5
    assert abs(cam.k1 - truth.k1) < 0.01 and abs(cam.k2 - truth.k2) < 0.15
    assert abs(cam.p1 - truth.p1) < 3e-4 and abs(cam.p2 - truth.p2) < 3e-4
    for k in ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"):  # within 3σ of the truth
        assert abs(getattr(cam, k) - getattr(truth, k)) < 3 * cal.sigma[k], k
    assert _grid_error_px(cam, truth) < 2.0
    assert np.all((cal.distance_mm > 350) & (cal.distance_mm < 850))
    assert Camera.from_toml(cal.to_toml()) == cam


def test_an_outlier_image_is_rejected_and_the_rest_refitted(boards):
    """Thesis 003's loop: a board seen through another lens (k1 = 0: its corners up to several px
    off this camera's) is dropped by name, and the camera is the one the good boards give."""
    poses, images = boards
    views = [cb.BoardView(f"board {i}", cb.find_corners(im, PATTERN)) for i, im in enumerate(images[:8])]
    bad = _truth(THESIS_000_CAMERA.replace(k1=0.0, k2=0.0), *poses[8])
    size = (THESIS_000_CAMERA.width, THESIS_000_CAMERA.height)
    clean = cb.calibrate_views(views, size, PATTERN, square_mm=SQUARE_MM)
    cal = cb.calibrate_views([*views, cb.BoardView("other lens", bad)], size, PATTERN, square_mm=SQUARE_MM)
    assert list(cal.rejected) == ["other lens"]
    assert "the others' median" in cal.rejected["other lens"]
    assert cal.names == clean.names
    for k in ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "p1", "p2"):
        assert getattr(cal.camera, k) == pytest.approx(getattr(clean.camera, k), rel=1e-6, abs=1e-9)
    # with too few boards to spare, nothing is dropped
    few = cb.calibrate_views([*views[:2], cb.BoardView("other lens", bad)], size, PATTERN)
    assert few.rejected == {} and len(few.names) == 3


def test_fisheye_corners_recover_the_fisheye():
    """The fisheye fit and its mapping, on corners projected by cv2.fisheye.projectPoints with
    0.05 px noise (no rendering): 10 boards 150–300 mm from a 110° Kannala–Brandt camera."""
    rng = np.random.default_rng(5)
    size = (FISHEYE.width, FISHEYE.height)
    views = [cb.BoardView(f"b{i}", _truth(FISHEYE, r, t) + rng.normal(0, 0.05, (54, 2)))
             for i, (r, t) in enumerate(_poses(FISHEYE, 10, rng, (150.0, 300.0)))]
    cal = cb.calibrate_views(views, size, PATTERN, square_mm=SQUARE_MM, model="fisheye")
    cam = cal.camera
    assert cam.projection == "kannala-brandt"
    assert np.all(cal.rms_px() < 0.1)
    assert abs(cam.fx - FISHEYE.fx) < 0.5
    assert abs(cam.cx - FISHEYE.cx) < 0.5 and abs(cam.cy - FISHEYE.cy) < 0.5
    # where the boards were (measured 0.16 px: fx 397.58 for 397.67); the frame's corners, which
    # no board reached, are k3 and k4's guess (k4 0.037 for 0)
    assert _grid_error_px(cam, FISHEYE, np.concatenate([v.corners for v in views])) < 0.25
    assert Camera.from_toml(cal.to_toml()) == cam


@pytest.mark.slow
def test_rendered_fisheye_boards_recover_the_fisheye():
    """10 rendered boards of the 110° fisheye, 150–300 mm away: measured (seed 3; 9 boards fitted)
    fx 397.82, fy 397.85 (truth 397.67), cx 379.96 (380), cy 235.93 (236), k1 −0.0195 (−0.02);
    per-image RMS 0.031–0.062 px; within 0.16 px of the truth where the boards were (1.05 px at
    the frame's corners, which no board reached: k2 … k4 trade there)."""
    rng = np.random.default_rng(3)
    images = _render(FISHEYE, _poses(FISHEYE, 10, rng, (150.0, 300.0)), rng)
    cal = cb.calibrate_checkerboard(images, square_mm=SQUARE_MM, model="fisheye")
    cam = cal.camera
    assert np.all(cal.rms_px() < 0.1)
    assert abs(cam.fx - FISHEYE.fx) < 0.3 and abs(cam.fy - FISHEYE.fy) < 0.3
    assert abs(cam.cx - FISHEYE.cx) < 0.5 and abs(cam.cy - FISHEYE.cy) < 0.5
    assert abs(cam.k1 - FISHEYE.k1) < 0.002
    assert _grid_error_px(cam, FISHEYE, np.concatenate(cal.corners)) < 0.5


def test_bad_pattern_and_model():
    for text in ("9", "9x1", "ax6", "9x6x2", ""):
        with pytest.raises(InputError, match="--pattern"):
            cb.parse_pattern(text)
    assert cb.parse_pattern("9x6") == (9, 6) and cb.parse_pattern("7×5") == (7, 5)
    with pytest.raises(UnknownNameError, match="unknown checkerboard model 'zoom'; choose one of "
                       "brown-conrady, fisheye"):
        cb.checkerboard_model("zoom")
    with pytest.raises(CalibrationError, match="at least 3 boards, found 2 \\(1 without a board: blank\\)"):
        cb.calibrate_views([cb.BoardView("a", np.zeros((54, 2)))] * 2, (752, 480), PATTERN,
                           skipped={"blank": "x"})


def test_command_writes_the_camera_and_refuses_bad_input(boards, tmp_path):
    """``skyfix calibrate checkerboard``: a blank image is named and skipped while enough boards
    remain; the file round-trips; too few boards, mixed sizes, a bad pattern and an unknown
    model are one ``skyfix: error:`` line each, exit status 2, no file."""
    from typer.testing import CliRunner

    from skyfix.cli import app

    _, images = boards
    paths = []
    for i, im in enumerate(images[:4]):
        paths.append(tmp_path / f"board{i}.png")
        cv2.imwrite(str(paths[-1]), np.clip(np.rint(im), 0, 255).astype(np.uint8))
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((480, 752), 128, np.uint8))
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.full((240, 376), 128, np.uint8))
    out = tmp_path / "camera.toml"
    base = ["calibrate", "checkerboard", "-o", str(out), "--square-mm", "25"]
    result = CliRunner().invoke(app, [*base, *map(str, paths), str(blank), "--pixel-pitch-um", "6",
                                      "--plot", str(tmp_path / "rep.png")])
    assert result.exit_code == 0, result.output
    assert f"skipped {blank}: no 9×6 checkerboard found" in result.output
    assert "thesis 000 §5.2" in result.output and "fx 8.63 mm" in result.output
    cam = Camera.load(out)
    assert cam.pixel_pitch_um == 6.0 and abs(cam.fx - THESIS_000_CAMERA.fx) < 5
    assert 'method = "checkerboard"' in out.read_text() and (tmp_path / "rep.png").stat().st_size > 0
    out.unlink()
    cases = {("--pattern", "9by6"): "--pattern '9by6': give the inner corners as COLSxROWS, each at least 2 "
                                    "(9x6 for a board of 10 × 7 squares)",
             ("--model", "zoom"): "--model: unknown checkerboard model 'zoom'; choose one of brown-conrady, "
                                  "fisheye"}
    for (option, value), message in cases.items():
        result = CliRunner().invoke(app, [*base, *map(str, paths), option, value])
        assert result.exit_code == 2 and result.stderr.strip().splitlines() == [f"skyfix: error: {message}"]
    result = CliRunner().invoke(app, [*base, str(paths[0]), str(paths[1]), str(blank)])
    assert result.exit_code == 2
    assert result.stderr.strip().splitlines() == [f"skyfix: error: a checkerboard calibration needs at least "
                                                  f"3 boards, found 2 (1 without a board: {blank})"]
    result = CliRunner().invoke(app, [*base, *map(str, paths), str(small)])
    assert result.exit_code == 2
    assert result.stderr.strip().splitlines() == [f"skyfix: error: {small}: 376×240, but {paths[0]} is "
                                                  "752×480: one camera, one frame size"]
    assert not out.exists()
