"""The tracker's own camera when it is given none (issue 25; docs/tracking.md#without-a-camera-file).

A :class:`~skyfix.track.Tracker` made without a camera holds a :class:`SelfCalibration`, which
makes the camera from the sequence itself and keeps it honest:

1. **Calibrating** (the first frames; their Solutions' ``mode`` is ``"calibrating"``). Each frame
   is extracted (up to ``max_stars`` centroids) and solved lost in space with no camera
   (:func:`skyfix.solve_centroids`: a camera of its own fitted under a prior, as any blind
   solve). Once ``n_start`` frames are solved, one camera is fitted to all of them jointly:
   :func:`skyfix.calibration.stars.calibrate_frames` — the model chosen by BIC along the
   Brown–Conrady ladder, stars re-identified through it until the matches settle — with two
   differences from ``skyfix calibrate stars``: frames of one field are accepted (a tracker at
   rest has no others), and the principal point is never held at the image centre (held there,
   a lens whose centre is 25 px off biased every attitude by 5″ in the simulated sequence of
   the tests; free, its σ is part of the error bars instead, item 3). The tracker then solves
   that frame lost in space through the camera, and tracks.
2. **Refined across the sequence.** Every ``keyframe_every`` frames, a frame tracked (with the
   MEKF) becomes a keyframe: the whole frame extracted, its streaks refitted and a rolling
   shutter's shear undone (:func:`keyframe_stars`), its stars re-identified through the current
   camera at the frame's attitude (:func:`~skyfix.calibration.stars.rematch_frame`), and the
   camera fitted again over every keyframe (:func:`~skyfix.calibration.stars.choose_model`:
   the model chosen again, so a term the first frames could not support joins when the sky
   the camera has turned across supports it). At most ``max_keyframes`` are kept: when there is
   one too many, the oldest of the two nearest in pointing goes, so that the set spreads over
   the sky the sequence has seen. The tracker takes the new camera at once, its attitude
   restarted at the keyframe's refitted one, the rate kept.
3. **The camera's uncertainty in the filter.** What each free camera number does to a frame's
   attitude is ``G`` (3 × n, :func:`camera_attitude_sensitivity`): the frame's attitude refitted
   to its own stars through the camera moved by that number (linearised), the change judged at
   the principal point's pixel as :mod:`skyfix.analysis.truth` judges an error. The camera's
   error is one bias that every frame shares — not noise new each frame, which a filter would
   average down — so the MEKF carries the camera numbers as consider states
   (:mod:`skyfix.track.filter`: their covariance ``Σ_c`` the joint fit's,
   :attr:`~skyfix.calibration.joint.JointFit.covariance`, the cross-covariance with the attitude
   and rate carried from frame to frame, each fit's ``G`` its sensitivity). A filter (re)started
   from an attitude fitted through the camera with covariance ``R`` starts from
   ``P = R + G Σ_c Gᵀ`` and cross-covariance ``G Σ_c`` (:meth:`SelfCalibration.start`), and from
   a keyframe's refit with ``R`` its stars' own (:meth:`SelfCalibration.keyframe_start`). The
   filter's covariance is then what a tracked frame reports. A frame solved lost in space, whose
   attitude no filter made, reports ``R + G Σ_c Gᵀ`` (:meth:`SelfCalibration.account`,
   :func:`camera_attitude_covariance`), as does every frame of a predictor other than the MEKF.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from skyfix.calibrate import frame_rotation_at_pixel
from skyfix.calibration.joint import JointFit, MatchedImage
from skyfix.calibration.stars import (
    MIN_STARS,
    REMATCH_FLOOR_PX,
    REMATCH_SIGMA,
    StarFrame,
    calibrate_frames,
    calibration_model,
    choose_model,
    frame_catalogues,
    rematch_frame,
)
from skyfix.camera import Camera
from skyfix.errors import CalibrationError, CameraError
from skyfix.geometry import radec_to_vector, rotation_angle_between

__all__ = ["CameraSensitivity", "SelfCalibration", "camera_attitude_covariance",
           "camera_attitude_sensitivity", "free_numbers", "keyframe_stars", "solution_stars"]

_ARCSEC = math.pi / (180 * 3600)
# Steps of the numerical derivatives: a rotation (rad), the pixel-valued camera numbers (px),
# the dimensionless coefficients.
_H_ROTATION = 1e-6
_H_PIXELS = 1e-2
_H_COEFFICIENT = 1e-6
_STREAK_PX = 2.0  # streaks this long are fitted as streaks (the tracker's own threshold)
_PIXEL_NUMBERS = ("fx", "fy", "cx", "cy", "skew")
_NUMBERS = ("fx", "fy", "cx", "cy", "skew", "k1", "k2", "k3", "p1", "p2", "k4")  # lens.CAMERA_NUMBERS[:11]


def _rotation(v: np.ndarray) -> np.ndarray:
    """The rotation matrix of a small rotation vector ``v`` (rad): ``b' = R b``."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(v).as_matrix()


class CameraSensitivity(NamedTuple):
    """What a camera's numbers do to one frame's fitted attitude (:func:`camera_attitude_sensitivity`)."""

    G: np.ndarray         # (3, n) rad per unit of each free number, about the camera's x, y, roll axes
    normal: np.ndarray    # (3, 3) J_θᵀ J_θ, px²/rad²: the stars' information on the rotation per px⁻²


def free_numbers(covariance: np.ndarray) -> list[int]:
    """The camera numbers a covariance (12, 12, ``lens.CAMERA_NUMBERS`` order) leaves free: those
    of positive variance (a held number's row is zero)."""
    return [i for i in range(len(_NUMBERS)) if covariance[i, i] > 0.0]


def camera_attitude_sensitivity(camera: Camera, free: list[int], A_icrs_to_cam: np.ndarray,
                                rays: np.ndarray) -> CameraSensitivity:
    """The sensitivity ``G`` (3, n) of an attitude ``A_icrs_to_cam`` fitted to stars along
    ``rays`` (N ≥ 2, 3, camera frame) to the camera numbers ``free`` (``lens.CAMERA_NUMBERS``
    indices; module text, item 3), and the stars' normal matrix ``J_θᵀ J_θ``.

    For each free number ``c_j``: ``δθ_j = −(J_θᵀJ_θ)⁻¹ J_θᵀ J_c,j`` is the frame's attitude
    refitted to its stars (``J_θ`` the pixels' derivatives by a rotation, ``J_c,j`` by the
    number), and ``G_j`` the change of the frame at the moved camera's principal point
    (:func:`skyfix.calibrate.frame_rotation_at_pixel`)."""
    A = np.asarray(A_icrs_to_cam, dtype=np.float64)
    b = np.asarray(rays, dtype=np.float64)
    uv0, _ = camera.ray_to_pixel(b)
    J_rot = np.empty((2 * len(b), 3))
    for a in range(3):
        step = np.zeros(3)
        step[a] = _H_ROTATION
        uv, _ = camera.ray_to_pixel(b @ _rotation(step).T)
        J_rot[:, a] = ((uv - uv0) / _H_ROTATION).ravel()
    # frame_at_pixel's own finite difference errs by ~4e-7 rad in roll at the principal point
    # (a tangential term's curvature over half a pixel): taken out, as it is the same for both
    base = frame_rotation_at_pixel(A, camera, A, camera, (camera.cx, camera.cy))
    G = np.zeros((3, len(free)))
    for j, i in enumerate(free):
        name = _NUMBERS[i]
        h = _H_PIXELS if name in _PIXEL_NUMBERS else _H_COEFFICIENT
        moved = camera.replace(**{name: getattr(camera, name) + h})
        uv, _ = moved.ray_to_pixel(b)
        J_cam = ((uv - uv0) / h).ravel()
        dtheta = -np.linalg.lstsq(J_rot, J_cam, rcond=None)[0] * h
        A_moved = _rotation(dtheta) @ A
        G[:, j] = (frame_rotation_at_pixel(A_moved, moved, A, camera, (moved.cx, moved.cy)) - base) / h
    return CameraSensitivity(G, J_rot.T @ J_rot)


def camera_attitude_covariance(camera: Camera, covariance: np.ndarray, A_icrs_to_cam: np.ndarray,
                               xy: np.ndarray, r_icrs: np.ndarray) -> np.ndarray:
    """The covariance (3, 3, rad², about the camera's x, y and roll axes) that the camera's own
    uncertainty gives an attitude fitted to the stars ``xy`` (N, 2, px) of catalogue directions
    ``r_icrs`` (N, 3) at ``A_icrs_to_cam``: ``G Σ Gᵀ`` (:func:`camera_attitude_sensitivity`).

    ``covariance`` is that of the camera numbers (12, 12, ``lens.CAMERA_NUMBERS`` order, the
    camera's units; zero rows for numbers held), e.g. a :class:`JointFit`'s."""
    cov = np.asarray(covariance, dtype=np.float64)
    free = free_numbers(cov)
    if not free or len(xy) < 2:
        return np.zeros((3, 3))
    A = np.asarray(A_icrs_to_cam, dtype=np.float64)
    G = camera_attitude_sensitivity(camera, free, A, np.asarray(r_icrs, dtype=np.float64) @ A.T).G
    return G @ cov[np.ix_(free, free)] @ G.T


def keyframe_stars(image: np.ndarray, camera: Camera, max_stars: int, rate_rad_s=None,
                   exposure_s: float = 0.0, line_time_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A keyframe's stars (N, 2) and fluxes (N,): the frame's ``max_stars`` brightest
    (:func:`skyfix.detect.extract_centroids`). When the camera turns (``rate_rad_s``, camera
    frame): streaks of 2 px or more are centroided again by the streak fit the tracker's windows
    use (:func:`skyfix.detect.streak.centroid_streaks`: on the simulated 5 px streaks of 1 °/s
    its centroids scatter 0.195 px about the calibrated camera, the extractor's 0.234), and on a
    rolling shutter each star is moved back along its motion to the frame's time (its row's
    offset, :func:`skyfix.detect.streak.row_time_offset`) — else the shutter's shear would be
    fitted as distortion."""
    from skyfix.detect import extract_centroids
    from skyfix.detect.streak import centroid_streaks, row_time_offset, streak_motion

    stars = extract_centroids(image, max_stars=max_stars)
    xy, flux = stars.xy, np.asarray(stars.flux, dtype=np.float64)
    if rate_rad_s is None or len(xy) == 0:
        return xy, flux
    rate = np.asarray(rate_rad_s, dtype=np.float64)
    if exposure_s > 0:
        motion = streak_motion(camera, xy, rate, exposure_s)
        if float(np.max(np.hypot(motion[:, 0], motion[:, 1]))) >= _STREAK_PX:
            fitted = centroid_streaks(image, xy, motion, method="streak").xy
            ok = np.isfinite(fitted).all(axis=1) & (np.hypot(*(fitted - xy).T) < _STREAK_PX)
            xy, flux = fitted[ok], flux[ok]
    if line_time_s > 0 and len(xy):
        h = 1e-3  # s: the stars' velocity, px/s
        velocity = streak_motion(camera, xy, rate, h) / h
        xy = xy - velocity * row_time_offset.py_func(xy[:, 1], line_time_s, image.shape[0])[:, None]
    return xy, flux


def solution_stars(sol) -> tuple[np.ndarray, np.ndarray]:
    """A Solution's matched stars: pixels (N, 2) and catalogue directions (N, 3, ICRS)."""
    xy = np.array([(m.x, m.y) for m in sol.matches], dtype=np.float64).reshape(-1, 2)
    ra, dec = np.radians([(m.ra_deg, m.dec_deg) for m in sol.matches]).reshape(-1, 2).T
    return xy, radec_to_vector(ra, dec)


class SelfCalibration:
    """The camera of a tracker given none (module text): calibrated from its first ``n_start``
    solved frames, refined on a keyframe every ``keyframe_every`` frames (at most
    ``max_keyframes`` kept), each frame's ``max_stars`` brightest centroids; ``model`` is a
    :data:`skyfix.calibration.stars.CALIBRATION_MODELS` family. ``database`` and ``epoch`` are
    the tracker's, for the blind solves."""

    def __init__(self, *, database=None, epoch: float | None = None, n_start: int = 3,
                 keyframe_every: int = 5, max_keyframes: int = 30, max_stars: int = 300,
                 model: str = "brown-conrady") -> None:
        self.family = calibration_model(model)
        self.model = model
        self.database = database
        self.epoch = epoch
        self.n_start = max(int(n_start), 1)
        self.keyframe_every = max(int(keyframe_every), 1)
        self.max_keyframes = max(int(max_keyframes), self.n_start)
        self.max_stars = int(max_stars)
        self.fit: JointFit | None = None     # the camera and its covariance, once calibrated
        self.refused: dict[str, str] = {}
        self.frames: list[StarFrame] = []    # the frames calibrating, then the keyframes
        self.matched: list[MatchedImage] = []
        self.size: tuple[int, int] | None = None
        self.calibrated_at: int | None = None  # the frame whose arrival made the camera
        self.refits = 0
        self._start: Camera | None = None
        self._catalogue = None
        self._last_keyframe = -math.inf

    @property
    def camera(self) -> Camera | None:
        """The camera now (None until calibrated)."""
        return None if self.fit is None else self.fit.camera

    def check_size(self, width: int, height: int) -> None:
        """Every frame the size of the first (:class:`~skyfix.errors.CameraError` otherwise)."""
        if self.size is None:
            self.size = (width, height)
        elif (width, height) != self.size:
            raise CameraError(f"frame is {width}×{height} but the sequence's first frame was "
                              f"{self.size[0]}×{self.size[1]}")

    # --- 1. calibrating -------------------------------------------------------------------
    def calibrating_frame(self, image: np.ndarray, index: int, name: str):
        """Solve frame number ``index`` blind and keep it when solved; once ``n_start`` are kept,
        calibrate (:attr:`camera` is then set). Returns the frame's blind Solution."""
        from skyfix.detect import extract_centroids
        from skyfix.pipeline import solve_centroids

        h, w = image.shape
        stars = extract_centroids(image, max_stars=self.max_stars)
        sol = solve_centroids(stars.xy, w, h, database=self.database, epoch=self.epoch, name=name)
        sol.mode = "calibrating"
        if not (sol.solved and sol.n_matched >= MIN_STARS):
            return sol
        self.frames.append(StarFrame(name, w, h, stars.xy, stars.flux, sol))
        if len(self.frames) < self.n_start:
            return sol
        try:
            cal = calibrate_frames(self.frames, model=self.model, allow_one_field=True,
                                   principal_point_sigma_px=math.inf)
        except CalibrationError as exc:  # e.g. too few stars re-identified: try with the next frame
            self.frames.pop(0)
            sol.reason = f"camera not calibrated yet: {exc}"
            return sol
        # the refits' start, as calibrate_frames': the blind solves' median focal length, centred
        fx = float(np.median([f.solution.camera.fx for f in self.frames]))
        self._start = Camera(width=w, height=h, fx=fx, fy=fx, cx=(w - 1) / 2.0, cy=(h - 1) / 2.0)
        if self.family.projection != "pinhole":
            self._start = Camera.from_fov(w, h, self._start.fov_deg, projection=self.family.projection)
        self._catalogue = frame_catalogues(self.frames)[0]
        self.fit, self.refused = cal.fit, cal.refused
        radius = self._radius_px()
        self.matched = [rematch_frame(f, self._catalogue, self.camera, A, radius)
                        for f, A in zip(self.frames, cal.fit.attitudes, strict=True)]
        self.calibrated_at = self._last_keyframe = index
        return sol

    def _radius_px(self) -> float:
        return max(REMATCH_SIGMA * self.fit.sigma_px, REMATCH_FLOOR_PX)

    # --- 2. keyframes ----------------------------------------------------------------------
    def keyframe(self, image: np.ndarray, index: int, sol, rate_rad_s=None, exposure_s: float = 0.0,
                 line_time_s: float = 0.0) -> np.ndarray | None:
        """Make frame ``index`` (its Solution ``sol``, solved through :attr:`camera`) a keyframe
        when one is due, and refit the camera. The camera's body rate ``rate_rad_s`` (camera
        frame), the exposure and the rolling shutter's line time place the stars
        (:func:`keyframe_stars`). Returns the frame's attitude through the new camera (3, 3), or
        None when no keyframe was made."""
        if self.fit is None or not sol.solved or index - self._last_keyframe < self.keyframe_every:
            return None
        h, w = image.shape
        xy, flux = keyframe_stars(image, self.camera, self.max_stars, rate_rad_s, exposure_s, line_time_s)
        frame = StarFrame(sol.image, w, h, xy, flux, sol)
        A = np.asarray(sol.A_icrs_to_cam, dtype=np.float64)
        matched = rematch_frame(frame, self._catalogue, self.camera, A, self._radius_px())
        if len(matched.xy) < MIN_STARS:
            return None
        self._last_keyframe = index
        self.frames.append(frame)
        self.matched.append(matched)
        if len(self.matched) > self.max_keyframes:
            self._drop_one()
        fit, _, refused = choose_model(self.matched, self._start, self.family, False,
                                       principal_point_sigma_px=math.inf)
        self.fit, self.refused = fit, refused
        self.matched = [replace(m, A_icrs_to_cam=A) for m, A in zip(self.matched, fit.attitudes, strict=True)]
        self.refits += 1
        return fit.attitudes[-1]

    def _drop_one(self) -> None:
        """Drop the older of the two keyframes nearest in pointing (never the newest)."""
        n = len(self.matched)
        best = (math.inf, 0)
        for i in range(n - 1):
            for j in range(i + 1, n):
                angle = rotation_angle_between(self.matched[i].A_icrs_to_cam, self.matched[j].A_icrs_to_cam)
                if angle < best[0]:
                    best = (angle, i)
        del self.matched[best[1]], self.frames[best[1]]

    # --- 3. the camera's uncertainty -----------------------------------------------------
    @property
    def camera_covariance(self) -> np.ndarray:
        """The covariance (n, n) of the camera's free numbers: the filter's consider states."""
        free = free_numbers(self.fit.covariance)
        return self.fit.covariance[np.ix_(free, free)]

    def sensitivity(self, A_icrs_to_cam: np.ndarray, rays: np.ndarray) -> np.ndarray:
        """``G`` (3, n) of an attitude fitted through the camera to stars along ``rays`` (N, 3,
        camera frame): :func:`camera_attitude_sensitivity` for the free numbers."""
        free = free_numbers(self.fit.covariance)
        return camera_attitude_sensitivity(self.camera, free, A_icrs_to_cam, rays).G

    def start(self, A_icrs_to_cam: np.ndarray, rays: np.ndarray, R: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
        """A filter's start from an attitude fitted through the camera to stars along ``rays``
        with covariance ``R`` (3, 3, rad², the camera taken as exact): its covariance
        ``R + G Σ_c Gᵀ`` and its cross-covariance ``G Σ_c`` (3, n) with the camera's numbers."""
        G = self.sensitivity(A_icrs_to_cam, rays)
        cross = G @ self.camera_covariance
        return np.asarray(R, dtype=np.float64) + cross @ G.T, cross

    def keyframe_start(self) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`start` at the newest keyframe's refitted attitude, its ``R`` its stars' own:
        ``σ² (J_θᵀ J_θ)⁻¹`` with σ the joint fit's pixel σ."""
        m = self.matched[-1]
        A = m.A_icrs_to_cam
        rays = m.r_icrs @ A.T
        normal = camera_attitude_sensitivity(self.camera, [], A, rays).normal
        return self.start(A, rays, self.fit.sigma_px ** 2 * np.linalg.inv(normal))

    def account(self, sol) -> None:
        """Add to a solved Solution's covariance what the camera's uncertainty gives its
        attitude (:func:`camera_attitude_covariance`, on its matched stars): for an attitude no
        filter made (lost in space, or another predictor's)."""
        if self.fit is None or not sol.solved or not sol.matches:
            return
        xy, r = solution_stars(sol)
        P = camera_attitude_covariance(self.camera, self.fit.covariance, sol.A_icrs_to_cam, xy, r)
        frame = np.asarray(sol.frame_covariance_arcsec2)  # the tracker's, relative to the camera
        sol.covariance_arcsec2 = (np.asarray(sol.covariance_arcsec2) + P / _ARCSEC**2).tolist()
        sol.frame_covariance_arcsec2 = (frame + P / _ARCSEC**2).tolist()

    def describe(self) -> str:
        """One line: which camera, from what, each fitted number with its 1σ."""
        if self.fit is None:
            return f"camera: not calibrated yet ({len(self.frames)} of {self.n_start} frames solved)"
        fit = self.fit
        numbers = ", ".join(f"{n} {getattr(fit.camera, n):.6g} ± {s:.2g}" for n, s in fit.sigma.items())
        held = f"; held: {', '.join(self.refused)}" if self.refused else ""
        return (f"camera: calibrated in flight at frame {self.calibrated_at + 1}, refitted {self.refits} "
                f"times over {len(self.matched)} keyframes ({fit.n_stars} stars, σ {fit.sigma_px:.3f} px): "
                f"{numbers}{held}")
