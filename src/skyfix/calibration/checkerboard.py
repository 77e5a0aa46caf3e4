"""Checkerboard calibration with OpenCV: ``skyfix calibrate checkerboard``.

The bench method of thesis 000 §5.2 and thesis 003 (Zhang's closed-form start, then least
squares on every corner; Bouguet's toolbox there, OpenCV here — the same model):

1. **Each image's board is found** (:func:`find_corners`: ``cv2.findChessboardCorners``, then
   ``cv2.cornerSubPix`` with a window under half the corners' spacing). An image whose board is
   not found is named in :attr:`BoardCalibration.skipped` and left out; fewer than
   :data:`MIN_IMAGES` boards left is an error. Images of different sizes are an error.
2. **One camera is fitted to every corner** (``cv2.calibrateCameraExtended`` for
   ``brown-conrady``; ``cv2.fisheye.calibrate`` for ``fisheye``: :data:`CHECKERBOARD_MODELS`),
   each image's board pose its own.
3. **Outlier images are rejected** (thesis 003: "drop images whose errors lie outside the main
   cluster and re-run"): while the worst image's reprojection RMS exceeds
   :data:`OUTLIER_FACTOR` times the median of the others' and :data:`OUTLIER_FLOOR_PX`, it is
   dropped (named in :attr:`BoardCalibration.rejected`) and the camera refitted, keeping at
   least :data:`MIN_IMAGES`.
4. **Insignificant distortion is fixed at 0** (``brown-conrady``; thesis 003's rule: a
   coefficient whose 3σ — :data:`SIGNIFICANCE` σ — exceeds its value is fixed to 0 and the camera
   refitted), one at a time, highest order first: ``k3``, then ``p1, p2`` together (as OpenCV
   fixes them), then ``k2``, then ``k1``. The fisheye fit gives no σ: its ``k1 … k4``
   are all kept.

The pixel convention is OpenCV's and skyfix's alike (docs/design.md#pixel-coordinates): an
integer coordinate is a pixel's centre, so ``K``'s ``cx, cy`` are the Camera's as they are
(``tests/calibration/test_calibration_checkerboard.py`` renders boards whose pixel ``(col, row)`` covers
``[col − ½, col + ½]`` and finds OpenCV's corners there with no half-pixel shift). OpenCV's
``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` and distortion ``(k1, k2, p1, p2, k3)`` (Brown–Conrady)
or ``(k1, k2, k3, k4)`` (``cv::fisheye``, whose ``alpha`` is ``s / fx``) map to the Camera's fields
one for one (:func:`camera_from_opencv`, :func:`opencv_matrices`).

``cv2`` is imported by the functions that use it, never by ``import skyfix``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from skyfix.calibration.camera_file import camera_file
from skyfix.camera import Camera
from skyfix.errors import CalibrationError, InputError, unknown_name

__all__ = ["CHECKERBOARD_MODELS", "MIN_IMAGES", "OUTLIER_FACTOR", "OUTLIER_FLOOR_PX", "SIGNIFICANCE",
           "THESIS_000", "BoardCalibration", "BoardView", "CheckerboardModel", "board_points",
           "calibrate_checkerboard", "calibrate_views", "camera_from_opencv", "checkerboard_model",
           "detect_boards", "find_corners", "opencv_matrices", "parse_pattern", "render_board"]

MIN_IMAGES = 3
"""Fewest boards a calibration takes (Zhang: each view gives two constraints on the five
intrinsics of the pinhole, so three views fix them; the distortion rides on every corner)."""
OUTLIER_FACTOR = 3.0
OUTLIER_FLOOR_PX = 0.1
"""An image is an outlier when its reprojection RMS exceeds ``OUTLIER_FACTOR`` × the median of
the other images' and ``OUTLIER_FLOOR_PX`` (below which no image is bad: rendered boards
reproject to 0.01–0.03 px)."""
SIGNIFICANCE = 3.0
"""Thesis 003's rule: a distortion coefficient whose ``SIGNIFICANCE``·σ exceeds its value is fixed at 0."""
_SUBPIX_MAX_HALF_WINDOW = 11
_SUBPIX_CRITERIA = (100, 1e-4)  # iterations, px
_CALIBRATE_CRITERIA = (200, 1e-12)


class ThesisResult(NamedTuple):
    """A published checkerboard calibration, to print beside a new one."""

    source: str
    fx_mm: float
    fy_mm: float
    k: tuple[float, float, float]
    p: tuple[float, float]
    pixel_error_px: tuple[float, float]
    images: int


THESIS_000 = ThesisResult("thesis 000 §5.2 (MT9V022, 8.5 mm, 6 µm pixels; Bouguet's toolbox)", 8.63, 8.56,
                          (-0.3686, 0.3148, 0.0), (-0.0023, 0.0003), (0.569, 0.557), 30)
"""Thesis 000's checkerboard result (§5.2): focal lengths ± 0.05 mm, the reprojection error's
standard deviation in x and y."""


class CheckerboardModel(NamedTuple):
    """A camera model a checkerboard calibration fits: the Camera's projection, its distortion
    coefficients in OpenCV's order, and the fit."""

    projection: str
    coefficients: tuple[str, ...]
    fit: Callable[..., _Fit]
    doc: str


class BoardView(NamedTuple):
    """One image's board: its name and its inner corners (N, 2) px, row by row as OpenCV orders them."""

    name: str
    corners: np.ndarray


class _Fit(NamedTuple):
    camera: Camera
    residuals: list[np.ndarray]  # per view (N, 2), measured − model, px
    sigma: dict[str, float]  # 1σ of each fitted number (empty for the fisheye)
    rvecs: list[np.ndarray]
    tvecs: list[np.ndarray]


@dataclass(frozen=True)
class BoardCalibration:
    """The result of :func:`calibrate_views`.

    Attributes
    ----------
    camera : Camera — the calibrated camera.
    model : str — the :data:`CHECKERBOARD_MODELS` name.
    names : list of str — the images fitted (after rejection).
    residuals_px : list of (N, 2) — each fitted image's corners, measured − model, px.
    corners : list of (N, 2) — each fitted image's measured corners.
    sigma : dict — 1σ of each fitted camera number (OpenCV's, from its Jacobian; empty for the fisheye).
    fixed : dict — coefficient → why it was fixed at 0.
    rejected : dict — image → its RMS and why it was dropped (the outlier loop).
    skipped : dict — image → why it gave no board.
    distance_mm : (M,) — each board's distance from the camera, in the units of ``square_mm``.
    """

    camera: Camera
    model: str
    names: list[str]
    residuals_px: list[np.ndarray] = field(repr=False)
    corners: list[np.ndarray] = field(repr=False)
    sigma: dict[str, float]
    fixed: dict[str, str]
    rejected: dict[str, str]
    skipped: dict[str, str]
    distance_mm: np.ndarray = field(repr=False)

    def rms_px(self) -> np.ndarray:
        """Each image's reprojection RMS, px (the length of the residual, OpenCV's per-view error)."""
        return np.array([math.sqrt(float(np.mean(np.sum(r**2, axis=1)))) for r in self.residuals_px])

    @property
    def pixel_error_px(self) -> tuple[float, float]:
        """The reprojection error's standard deviation in x and y over every corner (Bouguet's
        "pixel error", thesis 000's 0.569, 0.557 px)."""
        r = np.concatenate(self.residuals_px)
        return float(np.std(r[:, 0])), float(np.std(r[:, 1]))

    def to_toml(self) -> str:
        """The camera file (:func:`skyfix.calibration.camera_file.camera_file`)."""
        sx, sy = self.pixel_error_px
        table: dict[str, object] = {
            "method": "checkerboard", "model": self.model, "images": len(self.names),
            "corners": sum(len(c) for c in self.corners), "pixel_error_px": [sx, sy],
            "rms_px": float(np.sqrt(np.mean(self.rms_px() ** 2)))}
        if self.fixed:
            table["fixed"] = list(self.fixed)
        if self.rejected:
            table["rejected"] = list(self.rejected)
        if self.skipped:
            table["skipped"] = list(self.skipped)
        return camera_file(self.camera, table, self.sigma)


# --- the pattern and the mapping between OpenCV's matrices and the Camera -------------------------
def parse_pattern(text: str) -> tuple[int, int]:
    """``"9x6"`` → (9, 6): inner corners per row and per column (OpenCV's ``patternSize``)."""
    m = re.fullmatch(r"\s*(\d+)\s*[x×]\s*(\d+)\s*", str(text))
    if not m or min(int(m[1]), int(m[2])) < 2:
        raise InputError(f"--pattern {text!r}: give the inner corners as COLSxROWS, each at least 2 "
                         "(9x6 for a board of 10 × 7 squares)")
    return int(m[1]), int(m[2])


def board_points(pattern: tuple[int, int], square_mm: float = 1.0) -> np.ndarray:
    """The inner corners (N, 3) on the board's plane (z = 0), row by row as OpenCV finds them:
    ``(i·square, j·square, 0)`` for row ``j``, column ``i``."""
    cols, rows = pattern
    j, i = np.mgrid[0:rows, 0:cols]
    return np.c_[i.ravel(), j.ravel(), np.zeros(cols * rows)] * float(square_mm)


def opencv_matrices(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's ``K`` (3, 3) and distortion vector of ``camera``: ``(k1, k2, p1, p2, k3)`` for a
    pinhole, ``(k1, k2, k3, k4)`` for Kannala–Brandt (``cv2.fisheye``). ``K[0, 1]`` is the skew:
    ``cv2.fisheye`` reads it (``alpha = skew / fx``); ``cv2.projectPoints`` ignores it, and
    ``calibrateCamera`` holds it at 0."""
    K = np.array([[camera.fx, camera.skew, camera.cx], [0.0, camera.fy, camera.cy], [0.0, 0.0, 1.0]])
    model = _MODEL_OF_PROJECTION[camera.projection]
    return K, np.array([getattr(camera, k) for k in CHECKERBOARD_MODELS[model].coefficients])


def camera_from_opencv(K: np.ndarray, dist: np.ndarray, width: int, height: int, projection: str = "pinhole"
                       ) -> Camera:
    """The Camera of OpenCV's ``K`` and distortion vector (the order of :func:`opencv_matrices`;
    higher Brown–Conrady terms than ``k3`` must be 0)."""
    K = np.asarray(K, dtype=np.float64)
    dist = np.asarray(dist, dtype=np.float64).ravel()
    names = CHECKERBOARD_MODELS[_MODEL_OF_PROJECTION[projection]].coefficients
    if np.any(dist[len(names):] != 0.0):
        raise CalibrationError("OpenCV distortion terms beyond k3 have no Camera field")
    coefficients = {k: float(v) for k, v in zip(names, dist, strict=False)}
    return Camera(width=int(width), height=int(height), fx=float(K[0, 0]), fy=float(K[1, 1]),
                  cx=float(K[0, 2]), cy=float(K[1, 2]), skew=float(K[0, 1]), projection=projection,
                  **coefficients)


# --- finding the board -------------------------------------------------------------------------
def _as_uint8(image: np.ndarray) -> np.ndarray:
    """A frame scaled to 0–255 between its 0.1 and 99.9 percentiles (what the corner finder reads)."""
    lo, hi = np.percentile(image, [0.1, 99.9])
    scaled = (np.asarray(image, dtype=np.float64) - lo) * (255.0 / max(hi - lo, 1e-12))
    return np.clip(np.rint(scaled), 0, 255).astype(np.uint8)


def find_corners(image: np.ndarray, pattern: tuple[int, int]) -> np.ndarray | None:
    """The board's inner corners (N, 2) px in ``image`` (2-D), or None when it is not found.

    ``cv2.findChessboardCorners`` (adaptive threshold, normalised image), then ``cv2.cornerSubPix``
    with a half-window of 0.4 × the smallest spacing between neighbouring corners (at most
    11 px): the window must not reach the next corner."""
    import cv2

    gray = _as_uint8(image)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(gray, tuple(pattern), flags=flags)
    if not found:
        return None
    grid = corners.reshape(pattern[1], pattern[0], 2)
    spacing = min(np.min(np.hypot(*np.diff(grid, axis=1).reshape(-1, 2).T)),
                  np.min(np.hypot(*np.diff(grid, axis=0).reshape(-1, 2).T)))
    half = int(max(2, min(_SUBPIX_MAX_HALF_WINDOW, 0.4 * spacing)))
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, *_SUBPIX_CRITERIA)
    corners = cv2.cornerSubPix(gray, corners, (half, half), (-1, -1), criteria)
    return corners.reshape(-1, 2).astype(np.float64)


def _read(image: str | Path | np.ndarray, index: int) -> tuple[str, np.ndarray]:
    from skyfix.io import read_image

    if isinstance(image, np.ndarray):
        return f"image {index + 1}", read_image(image)
    return str(image), read_image(image)


def detect_boards(images: Sequence[str | Path | np.ndarray], pattern: tuple[int, int]
                  ) -> tuple[list[BoardView], dict[str, str], tuple[int, int]]:
    """Each image's board (:func:`find_corners`): the views found, the images skipped (name →
    why), and the frame size (width, height). Images of different sizes are a
    :class:`~skyfix.errors.CalibrationError` naming the image."""
    views: list[BoardView] = []
    skipped: dict[str, str] = {}
    size: tuple[int, int] | None = None
    first = ""
    for i, image in enumerate(images):
        name, data = _read(image, i)
        h, w = data.shape
        if size is None:
            size, first = (w, h), name
        elif (w, h) != size:
            raise CalibrationError(f"{name}: {w}×{h}, but {first} is {size[0]}×{size[1]}: one camera, one "
                                   "frame size")
        corners = find_corners(data, pattern)
        if corners is None:
            skipped[name] = f"no {pattern[0]}×{pattern[1]} checkerboard found"
        else:
            views.append(BoardView(name, corners))
    assert size is not None
    return views, skipped, size


# --- the fits ------------------------------------------------------------------------------------
_STD_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")  # stdDeviationsIntrinsics' first


def _fit_brown_conrady(obj: list[np.ndarray], img: list[np.ndarray], size: tuple[int, int],
                       fixed: Sequence[str]) -> _Fit:
    """``cv2.calibrateCameraExtended``: fx, fy, cx, cy, k1, k2, p1, p2, k3 less ``fixed`` (held at 0)."""
    import cv2

    flags = 0
    for name, flag in (("k1", cv2.CALIB_FIX_K1), ("k2", cv2.CALIB_FIX_K2), ("k3", cv2.CALIB_FIX_K3),
                       ("p1", cv2.CALIB_ZERO_TANGENT_DIST)):
        if name in fixed:
            flags |= flag
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, *_CALIBRATE_CRITERIA)
    obj32 = [o.astype(np.float32) for o in obj]
    img32 = [p.astype(np.float32).reshape(-1, 1, 2) for p in img]
    _, K, D, rvecs, tvecs, std, _, _ = cv2.calibrateCameraExtended(obj32, img32, size, None, None,
                                                                   flags=flags, criteria=criteria)
    camera = camera_from_opencv(K, D.ravel()[:5], *size)
    residuals = [p - cv2.projectPoints(o, r, t, K, D)[0].reshape(-1, 2)
                 for o, p, r, t in zip(obj, img, rvecs, tvecs, strict=True)]
    held = set(fixed) | ({"p2"} if "p1" in fixed else set())
    sigma = {k: float(s) for k, s in zip(_STD_NAMES, std.ravel(), strict=False) if k not in held}
    return _Fit(camera, residuals, sigma, list(rvecs), list(tvecs))


def _fit_fisheye(obj: list[np.ndarray], img: list[np.ndarray], size: tuple[int, int],
                 fixed: Sequence[str]) -> _Fit:
    """``cv2.fisheye.calibrate``: fx, fy, cx, cy, k1 … k4 (skew held at 0)."""
    import cv2

    names = cv2.fisheye if hasattr(cv2.fisheye, "CALIB_FIX_SKEW") else cv2  # OpenCV 4 | 5
    flags = names.CALIB_RECOMPUTE_EXTRINSIC | names.CALIB_FIX_SKEW
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, *_CALIBRATE_CRITERIA)
    obj3 = [o.reshape(1, -1, 3).astype(np.float64) for o in obj]
    img2 = [p.reshape(1, -1, 2).astype(np.float64) for p in img]
    _, K, D, rvecs, tvecs = cv2.fisheye.calibrate(obj3, img2, size, np.eye(3), np.zeros(4), flags=flags,
                                                  criteria=criteria)
    camera = camera_from_opencv(K, D.ravel(), *size, projection="kannala-brandt")
    residuals = [p - cv2.fisheye.projectPoints(o, r, t, K, D)[0].reshape(-1, 2)
                 for o, p, r, t in zip(obj3, img, rvecs, tvecs, strict=True)]
    return _Fit(camera, residuals, {}, list(rvecs), list(tvecs))


# The registry of checkerboard models, chosen by name (``--model``).
CHECKERBOARD_MODELS: dict[str, CheckerboardModel] = {
    "brown-conrady": CheckerboardModel("pinhole", ("k1", "k2", "p1", "p2", "k3"), _fit_brown_conrady,
                                       "OpenCV calibrateCamera: fx, fy, cx, cy, k1, k2, p1, p2, k3"),
    "fisheye": CheckerboardModel("kannala-brandt", ("k1", "k2", "k3", "k4"), _fit_fisheye,
                                 "OpenCV fisheye.calibrate (Kannala–Brandt): fx, fy, cx, cy, k1 … k4"),
}
_MODEL_OF_PROJECTION = {m.projection: name for name, m in CHECKERBOARD_MODELS.items()}


def checkerboard_model(name: str) -> CheckerboardModel:
    if name not in CHECKERBOARD_MODELS:
        raise unknown_name("checkerboard model", name, CHECKERBOARD_MODELS)
    return CHECKERBOARD_MODELS[name]


def _rms(residuals: np.ndarray) -> float:
    return math.sqrt(float(np.mean(np.sum(residuals**2, axis=1))))


# Thesis 003's rule tests the coefficients highest order first — k3, then p1 and p2 together (as
# OpenCV fixes them), then k2, then k1 — and fixes the first found insignificant: k2 and k3
# correlate strongly, and a free k3 can make a real k2 look insignificant.
_FIXING_ORDER = (("k3",), ("p1", "p2"), ("k2",), ("k1",))


def _first_insignificant(fit: _Fit, fixed: Sequence[str]) -> dict[str, str]:
    """Thesis 003's rule on a Brown–Conrady fit: the first coefficient (group) of
    :data:`_FIXING_ORDER` whose SIGNIFICANCE·σ exceeds its value (every one of a group's), with why."""
    cam, s = fit.camera, fit.sigma
    for group in _FIXING_ORDER:
        if group[0] in fixed or any(SIGNIFICANCE * s[k] <= abs(getattr(cam, k)) for k in group):
            continue
        values = ", ".join(f"{getattr(cam, k):.2g}" for k in group)
        sigmas = ", ".join(f"{s[k]:.2g}" for k in group)
        why = f"{SIGNIFICANCE:g}σ exceeds the value ({values} ± {sigmas}, 1σ); fixed at 0"
        return dict.fromkeys(group, why)
    return {}


def calibrate_views(views: Sequence[BoardView], size: tuple[int, int], pattern: tuple[int, int], *,
                    square_mm: float = 1.0, model: str = "brown-conrady",
                    skipped: dict[str, str] | None = None) -> BoardCalibration:
    """Fit one camera to found boards: steps 2–4 of the module text."""
    family = checkerboard_model(model)
    if len(views) < MIN_IMAGES:
        lost = f" ({len(skipped)} without a board: {', '.join(skipped)})" if skipped else ""
        raise CalibrationError(f"a checkerboard calibration needs at least {MIN_IMAGES} boards, found "
                               f"{len(views)}{lost}")
    obj = board_points(pattern, square_mm)
    kept = list(views)
    rejected: dict[str, str] = {}
    fixed: dict[str, str] = {}
    while True:
        fit = family.fit([obj] * len(kept), [v.corners for v in kept], size, tuple(fixed))
        rms = np.array([_rms(r) for r in fit.residuals])
        worst = int(np.argmax(rms))
        others = float(np.median(np.delete(rms, worst)))
        limit = max(OUTLIER_FACTOR * others, OUTLIER_FLOOR_PX)
        if len(kept) > MIN_IMAGES and rms[worst] > limit:
            rejected[kept[worst].name] = (f"RMS {rms[worst]:.3g} px > {OUTLIER_FACTOR:g} × the others' "
                                          f"median {others:.3g} px")
            del kept[worst]
            continue
        drop = _first_insignificant(fit, tuple(fixed)) if fit.sigma else {}
        if not drop:
            break
        fixed.update(drop)
    distance = np.array([float(np.linalg.norm(t)) for t in fit.tvecs])
    return BoardCalibration(camera=fit.camera, model=model, names=[v.name for v in kept],
                            residuals_px=fit.residuals, corners=[v.corners for v in kept], sigma=fit.sigma,
                            fixed=fixed, rejected=rejected, skipped=dict(skipped or {}), distance_mm=distance)


def calibrate_checkerboard(images: Sequence[str | Path | np.ndarray], *,
                           pattern: str | tuple[int, int] = "9x6", square_mm: float = 25.0,
                           model: str = "brown-conrady") -> BoardCalibration:
    """Calibrate one camera from checkerboard images: :func:`detect_boards`, then :func:`calibrate_views`."""
    checkerboard_model(model)
    pattern = parse_pattern(pattern) if isinstance(pattern, str) else tuple(pattern)
    if not (isinstance(square_mm, (int, float)) and math.isfinite(square_mm) and square_mm > 0):
        raise InputError(f"--square-mm {square_mm}: the side of a square must be a positive number")
    views, skipped, size = detect_boards(images, pattern)
    return calibrate_views(views, size, pattern, square_mm=square_mm, model=model, skipped=skipped)


# --- synthetic boards ----------------------------------------------------------------------------
def render_board(camera: Camera, rvec: Sequence[float], tvec: Sequence[float], pattern: tuple[int, int], *,
                 square: float = 1.0, black: float = 30.0, white: float = 220.0, background: float = 110.0,
                 supersample: int = 8) -> np.ndarray:
    """A checkerboard seen by ``camera`` at pose ``(rvec, tvec)`` (OpenCV's: board → camera), each
    pixel the mean of ``supersample``² samples over its area (pixel ``(col, row)`` covers
    ``[col − ½, col + ½] × [row − ½, row + ½]``, docs/design.md#pixel-coordinates).

    The board is ``pattern + 1`` squares each way (the square at its first corner black), in a
    white margin a square wide, on a ``background`` plane; its inner corners are
    :func:`board_points`' ``(i·square, j·square, 0)``. Each pixel corner's board coordinates come
    from the camera's exact inverse (:meth:`Camera.pixel_to_ray` and the plane); a pixel whose four
    corners lie in one square takes its colour, and the others are sampled with the board
    coordinates interpolated bilinearly across the pixel (the mapping is smooth at that scale)."""
    import cv2

    w, h = camera.width, camera.height
    R = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))[0]
    t = np.asarray(tvec, dtype=np.float64).ravel()
    ys, xs = np.mgrid[-0.5:h, -0.5:w]  # the (h+1) × (w+1) pixel corners
    rays = camera.pixel_to_ray(np.c_[xs.ravel(), ys.ravel()])
    n = R[:, 2]
    s = (n @ t) / (rays @ n)
    on = np.isfinite(s) & (s > 0)
    board = ((s[:, None] * rays - t) @ R)[:, :2] / square  # board coordinates, in squares
    board[~on] = np.nan
    bx, by = board[:, 0].reshape(h + 1, w + 1), board[:, 1].reshape(h + 1, w + 1)
    cols, rows = pattern

    def shade(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        fx, fy = np.floor(x), np.floor(y)
        inside = (fx >= -1) & (fx <= cols - 1) & (fy >= -1) & (fy <= rows - 1)
        margin = (fx >= -2) & (fx <= cols) & (fy >= -2) & (fy <= rows)
        out = np.where(margin, white, background)
        out = np.where(inside & ((fx + fy) % 2 == 0), black, out)
        return np.where(np.isfinite(x), out, background)

    # a pixel's cell: its square (clipped beyond the margin, where the plane is all background)
    square_x, square_y = np.floor(np.clip(bx, -3, cols + 1)), np.floor(np.clip(by, -3, rows + 1))
    cell = np.where(np.isfinite(bx), square_x * 4096 + square_y, np.inf)
    corners4 = np.stack([cell[:-1, :-1], cell[:-1, 1:], cell[1:, :-1], cell[1:, 1:]])
    mixed = ~np.all(corners4 == corners4[0], axis=0)
    cx, cy = 0.5 * (bx[:-1, :-1] + bx[1:, 1:]), 0.5 * (by[:-1, :-1] + by[1:, 1:])
    image = shade(cx, cy)
    r, c = np.nonzero(mixed)
    u = (np.arange(supersample) + 0.5) / supersample
    a, b = np.meshgrid(u, u)  # a across (x), b down (y)
    a, b = a.ravel()[None, :], b.ravel()[None, :]

    def lerp(q: np.ndarray) -> np.ndarray:
        q00, q01, q10, q11 = (q[r, c][:, None], q[r, c + 1][:, None], q[r + 1, c][:, None],
                              q[r + 1, c + 1][:, None])
        return (1 - b) * ((1 - a) * q00 + a * q01) + b * ((1 - a) * q10 + a * q11)

    image[r, c] = shade(lerp(bx), lerp(by)).mean(axis=1)
    return image.astype(np.float32)
