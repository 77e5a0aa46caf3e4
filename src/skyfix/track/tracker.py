"""The Tracker: follow the sky from frame to frame (docs/tracking.md).

``Tracker(camera).update(image, t_s)`` takes one frame at a time with its mid-exposure time and
returns a :class:`~skyfix.solution.Solution` whose ``mode`` says which of three states made it
(thesis 002 §2.6's state machine 1 → 10 → 2, with its reset-on-error rules, made better):

``"lost"`` (thesis state 1)
    A full lost-in-space solve (:func:`skyfix.pipeline.solve` with the tracker's camera,
    database and epoch). Solved: the predictor starts from its attitude and covariance and the
    next frame is *acquiring* — or *tracking* straight away when gyro rates give the rate.
``"acquiring"`` (state 10)
    An attitude but no rate yet (σ ``max_rate_dps / 3`` per axis): the frame is tracked as below
    when the windows can hold the unknown smear (short exposures), else solved lost in space;
    either attitude, if it agrees with the prediction, and the first one give the rate (the
    filter's update). Failed: lost again.
``"tracking"`` (state 2)
    One update, in :meth:`Tracker.update`'s order: the predictor propagates the attitude to the
    frame time; the catalogue stars in the frame are projected (the database's star index, the
    camera model, the epoch — so stars entering the field are picked up and those leaving
    dropped each frame); 10–20 isolated stars spread over the frame get windows sized from the
    predicted covariance; each window is centroided and matched to its own star (gate,
    magnitude, pairwise distances: :mod:`skyfix.track.windows`); the attitude is refitted with
    its covariance (``track.fit.fit_attitude``, :mod:`skyfix.attitude`'s formulas), outliers
    dropped; the fit is verified (at least ``min_stars`` stars, residuals consistent with the
    centroids, at least half of the windows that found a star in it:
    :func:`~skyfix.track.step.window_fit_agrees`, the filter's NIS) and updates the
    predictor — or, when at least 6 stars agree with each other but not with the prediction (a
    manoeuvre), restarts it from the fit. The
    Solution reports the filter's attitude, covariance and rate.

A frame the windows cannot track (blank, clouded, a jump, too few stars) is solved lost in
space at once — when the estimated rate draws streaks, first in the frame averaged along them
(``solve(smear_px=…)``, :mod:`skyfix.detect.smear`), where the plain extraction breaks streaks
up: an attitude that agrees with the prediction updates the filter; one that does not (a jump)
restarts it, acquiring next, or tracking next with the rate kept (σ 10 % of it) when the
streaks bore it out. When no attitude comes, the tracker *coasts* on a frame that shows no
stars (blank, covered, blinded: fewer than ``min_stars`` detected): it reports the prediction
(status ``solved``, no stars, ``reason`` says why) for up to ``max_coast_frames`` frames while
the prediction stays precise enough for windows (``k_sigma`` σ of the boresight within
``max_window_px``). A frame with stars that neither the prediction nor lost in space explains
is never coasted on — the prediction may be what is wrong — and, like the end of coasting,
leaves the tracker lost (status ``failed``).

With an observation time (``time=``, or the first frame's own) the stars it projects and fits are
moved to where the camera sees them (aberration; refraction at a site), kept current frame by
frame (:mod:`skyfix.track.sky`): the attitude tracked is the camera's physical one, and each
Solution carries the frame's time and what :func:`skyfix.solve` reports with it.

With no camera (``Tracker()``), the first frames are ``"calibrating"``: solved lost in space
with no camera until three are, then one camera fitted to them jointly and refined on keyframes
across the sequence, its uncertainty carried by the MEKF as consider states (each tracked frame
updated step by step, :meth:`Tracker._steps`, with its fit's sensitivity to the camera) and so in
every reported covariance (:mod:`skyfix.track.self_calibration`; ``calibration_options`` are its
keywords).

Bad input raises a one-line :mod:`skyfix.errors` exception and leaves the state unchanged:
a time that is not after the last frame's (out of order, repeated), not finite, or missing;
a frame whose size is not the camera's; gyro rates that are not three finite numbers.
"""

from __future__ import annotations

import math
import os
import time
from typing import NamedTuple

import numpy as np

from skyfix.attitude import CENTROID_NOISE_FLOOR_PX
from skyfix.camera import Camera
from skyfix.corrections.observation import observe
from skyfix.detect import CENTROIDERS
from skyfix.detect.centroid import centroider
from skyfix.detect.streak import streak_model_sigma, streak_motion
from skyfix.errors import CameraError, InputError
from skyfix.identify import PatternDatabase
from skyfix.identify.catalogue.bands import database_for_fov
from skyfix.identify.catalogue.database import readonly_view
from skyfix.identify.catalogue.kernel_data import StarIndex
from skyfix.io import read_image_with_header
from skyfix.obstime import julian_year
from skyfix.solution import MatchTable, Solution
from skyfix.track import inputs
from skyfix.track import windows as win
from skyfix.track.frame_steps import STREAK_PX, FrameSteps, WindowFit
from skyfix.track.measure import CentroidSettings
from skyfix.track.sky import TrackedSky
from skyfix.validate import check_count, check_epoch, check_positive

__all__ = ["DEFAULT_ACCEL_PSD", "MODES", "TrackSettings", "Tracker"]

#: The tracker's states, the ``mode`` of its Solutions.
MODES = ("calibrating", "lost", "acquiring", "tracking")

_ARCSEC = math.pi / (180 * 3600)
_DEG = math.pi / 180
#: The MEKF's white angular-acceleration density the Tracker gives it, rad²/s³: its rate wanders
#: 0.06 °/s in 1 s (q ≳ α² Δt: accelerations to ~0.2 °/s² at 10 Hz), so at a steady rate the
#: filter averages many frames. A harder manoeuvre (a slew's ramp) is caught by the NIS: the
#: stars outvote the prediction and the filter restarts from their fit with the rate's σ the
#: miss implies (:meth:`Tracker._track`). ``predictor_options={"accel_psd": …}`` overrides it.
DEFAULT_ACCEL_PSD = 1e-6
_VIEW_CAP = 4096  # catalogue stars projected per frame at most (the selection needs the brightest)
_GATE_FLOOR_PX = 0.3  # the gate's allowance for what the motion model leaves out (an acceleration)
_STRONG_FIT = 6  # stars in a fit that outvote the prediction (a manoeuvre, not a wrong match)


class TrackSettings(NamedTuple):
    """The Tracker's settings (the keywords of :class:`Tracker`, documented there)."""

    n_windows: int
    streak_windows: int
    centroid: str
    gain: float | None
    psf_sigma_px: float | None
    k_sigma: float
    min_stars: int
    max_coast_frames: int
    max_rate_dps: float
    exposure_s: float | None
    line_time_s: float
    star_radius_px: float
    max_window_px: float
    min_snr: float
    floor_px: float
    mag_tolerance: float
    nis_gate: float


class Tracker(FrameSteps):
    """Track a camera's attitude over a sequence of frames (module docstring).

    Parameters
    ----------
    camera : Camera, optional
        The camera model (frames must be its size). None: calibrated from the frames themselves
        (:attr:`calibration`, a :class:`~skyfix.track.self_calibration.SelfCalibration`).
    database : PatternDatabase, optional
        Catalogue and star index for lost-in-space and the windows (default: the default FOV
        band's that serves the camera, :func:`skyfix.identify.catalogue.bands.database_for_fov`).
    predictor : str
        A name of :data:`skyfix.track.predictors.PREDICTORS` (``"mekf"``: the Kalman filter).
    epoch : float, optional
        Julian year for proper motion (default: the database's epoch, as :func:`skyfix.solve`).
    n_windows : int
        Windows per frame (10–20: enough stars for the fit, a fraction of a millisecond).
    streak_windows : int
        Windows per frame, at most ``n_windows``, while the stars streak (with the ``"streak"``
        centroider, a predicted streak of at least 2 px at the boresight over the exposure): a
        streak's fit costs ~7 µs, a round star's centre of mass ~0.5 (default: ``n_windows``). At
        1 °/s 12 windows instead of 16 take an update from 0.37–0.45 to 0.31–0.35 ms for 2 % of
        the boresight's RMS (0.85 → 0.87″), but the rate right after a 90° jump at 2 °/s is
        twice as far off (0.10 °/s about the boresight against < 0.05): docs/tracking.md.
    centroid : str
        Centroider in the windows: ``"streak"`` (the default: the streak-matched weighted centre
        of :func:`skyfix.detect.streak.centroid_streaks`, a star's PSF swept along its predicted
        motion; thresholded centre of mass where the prediction is too uncertain to centre the
        weight on), or one of :data:`skyfix.detect.CENTROIDERS`.
    gain : float, optional
        Electrons per ADU, for the centroids' shot noise.
    psf_sigma_px : float, optional
        The PSF's σ for the streak weight, pixels (default 1).
    k_sigma : float
        Windows reach, and gates accept, this many predicted σ.
    min_stars : int
        Fewest stars in a fit (3 pin all three axes).
    max_coast_frames : int
        Frames reported from the prediction alone before the tracker is lost.
    max_rate_dps : float
        The fastest body rate expected, °/s: 3 σ of the unknown rate while acquiring.
    exposure_s : float, optional
        Exposure time, for the smear (default: the time since the last frame, an upper bound).
    line_time_s : float
        Rolling shutter: the time between the readout of two rows (0: a global shutter).
    star_radius_px : float
        How far a star's light reaches from its centre, pixels.
    max_window_px : float
        Largest search half-size; beyond it the frame is solved lost in space.
    min_snr, floor_px, mag_tolerance : float
        A window's centroid counts above this SNR; a σ floor (px) added to every centroid's;
        the largest brightness mismatch against the catalogue, magnitudes.
    nis_gate : float
        A fit whose normalised innovation squared exceeds this disagrees with the prediction.
    predictor_options : dict, optional
        Keywords for the predictor (e.g. ``accel_psd`` of the MEKF).
    solve_options : dict, optional
        Keywords for the lost-in-space :func:`skyfix.solve`.
    time : ObservationTime, str or datetime, optional
        The time of ``t_s = 0`` (default: the first frame file's own, else none; :mod:`.sky`).
    observer, site, weather, refraction, apparent, mounting, exclusion
        As :func:`skyfix.solve`'s; ``observer`` may change frame by frame (:meth:`update`).
    calibration_options : dict, optional
        With no camera, keywords for :class:`~skyfix.track.self_calibration.SelfCalibration`.
    """

    def __init__(self, camera: Camera | None = None, *, database=None, predictor: str = "mekf",
                 epoch: float | None = None, n_windows: int = 16, streak_windows: int | None = None,
                 centroid: str = "streak", gain: float | None = None,
                 psf_sigma_px: float | None = None, k_sigma: float = 4.0,
                 min_stars: int = 3, max_coast_frames: int = 5, max_rate_dps: float = 3.0,
                 exposure_s: float | None = None, line_time_s: float = 0.0, star_radius_px: float = 3.0,
                 max_window_px: float = 60.0, min_snr: float = 5.0, floor_px: float = CENTROID_NOISE_FLOOR_PX,
                 mag_tolerance: float = 1.5, nis_gate: float = 25.0, predictor_options: dict | None = None,
                 solve_options: dict | None = None, calibration_options: dict | None = None, time=None,
                 observer=None, site=None, weather=None, refraction: str = "erfa", apparent: bool = False,
                 mounting=None, exclusion=None) -> None:
        from skyfix.track.predictors import make_predictor

        if camera is not None and not isinstance(camera, Camera):
            raise InputError(f"camera must be a Camera (Camera.load(path)), got {type(camera).__name__}")
        if database is not None and not isinstance(database, PatternDatabase):
            raise InputError(f"database must be a PatternDatabase, got {type(database).__name__}")
        if centroid != "streak" and centroid not in CENTROIDERS:
            raise InputError(f"unknown centroider {centroid!r}; known: streak, {', '.join(CENTROIDERS)}")
        if not (isinstance(line_time_s, (int, float)) and math.isfinite(line_time_s) and line_time_s >= 0):
            raise InputError(f"line_time_s must be a number >= 0 (seconds per row), got {line_time_s!r}")
        n_windows = check_count(n_windows, "n_windows")
        streaking = n_windows if streak_windows is None else check_count(streak_windows, "streak_windows")
        self.settings = TrackSettings(
            n_windows=n_windows, streak_windows=min(streaking, n_windows), centroid=centroid,
            gain=None if gain is None else check_positive(gain, "gain"),
            psf_sigma_px=None if psf_sigma_px is None else check_positive(psf_sigma_px, "psf_sigma_px"),
            k_sigma=check_positive(k_sigma, "k_sigma"),
            min_stars=check_count(min_stars, "min_stars", minimum=3),
            max_coast_frames=check_count(max_coast_frames, "max_coast_frames", minimum=0),
            max_rate_dps=check_positive(max_rate_dps, "max_rate_dps"),
            exposure_s=None if exposure_s is None else check_positive(exposure_s, "exposure_s"),
            line_time_s=float(line_time_s), star_radius_px=check_positive(star_radius_px, "star_radius_px"),
            max_window_px=check_positive(max_window_px, "max_window_px"),
            min_snr=check_positive(min_snr, "min_snr"), floor_px=check_positive(floor_px, "floor_px"),
            mag_tolerance=check_positive(mag_tolerance, "mag_tolerance"),
            nis_gate=check_positive(nis_gate, "nis_gate"))
        self.camera: Camera | None = None
        self.database = database
        self.epoch = check_epoch(epoch)
        obs = observe(time, observer=observer, site=site, weather=weather, refraction=refraction,
                      apparent=apparent, epoch=epoch, mounting=mounting, exclusion=exclusion)  # checked now
        self.sky = TrackedSky(obs, time_from_frames=time is None)
        if self.epoch is None and self.sky.observation.time.known:
            self.epoch = julian_year(self.sky.observation.time)
        self.calibration = None
        if camera is None:
            from skyfix.track.self_calibration import SelfCalibration

            self.calibration = SelfCalibration(database=database, epoch=self.epoch,
                                               **(calibration_options or {}))
        from skyfix import warmup

        warmup.ensure("track")  # the tracker's kernels (and a solve's), compiled up front on first use
        self.predictor_name = predictor
        self._predictor_options = dict(predictor_options or {})
        self._predictor_options.setdefault("rate_sigma_rad_s", self.settings.max_rate_dps * _DEG / 3.0)
        if predictor == "mekf":
            self._predictor_options.setdefault("accel_psd", DEFAULT_ACCEL_PSD)
        self._make_predictor = make_predictor
        # a bad name or option: InputError now, not at the first solved frame
        make_predictor(predictor, np.eye(3), 0.0, np.eye(3) * 1e-10, **self._predictor_options)
        self._solve_options = dict(solve_options or {})
        r_star = self.settings.star_radius_px
        self._window_settings = win.WindowSettings(
            self.settings.n_windows, self.settings.k_sigma, r_star, min_half_px=r_star + 1.0,
            max_half_px=self.settings.max_window_px, max_spread_px=4.0 * r_star, neighbour_dmag=3.0,
            per_box=0)
        self._match_settings = win.MatchSettings(self.settings.min_snr, self.settings.k_sigma ** 2,
                                                 self.settings.floor_px, _GATE_FLOOR_PX,
                                                 self.settings.mag_tolerance, pair_k=5.0)
        self._window_settings_t = tuple(self._window_settings)
        self._streak_window_settings_t = tuple(
            self._window_settings._replace(n_max=self.settings.streak_windows))
        self._match_settings_t = tuple(self._match_settings)
        self._view_t = tuple(win.View.empty(_VIEW_CAP))
        self._max_tile = int(math.ceil(self.settings.max_window_px + 3 * self.settings.star_radius_px))
        self._tiles = np.zeros(self.settings.n_windows * (2 * self._max_tile) ** 2, np.float32)
        # the round-star centroider: the CoM where "streak" cannot centre its weight
        how = centroider("com" if centroid == "streak" else centroid, 3.0, self.settings.psf_sigma_px,
                         self.settings.gain)
        self._centroid_t = tuple(CentroidSettings(
            centroid == "streak", STREAK_PX, int(math.ceil(r_star)) + 1,  # the star and a pixel
            streak_model_sigma(self.settings.psf_sigma_px), tuple(how)))
        self._no_xy, self._no_b, self._no_index = np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0, np.int64)
        self._n_frames = 0
        self.reset()
        if camera is not None:
            self._use_camera(camera)

    def _use_camera(self, camera: Camera) -> None:
        """Track through ``camera`` from now on: its numbers, plate scale, the catalogue cone that
        holds its frame, and (none given) the database that serves its field."""
        if self.database is None:
            self.database = database_for_fov(camera.fov_deg)
        self.camera = camera
        self._cam = camera.numbers()
        self._plate = camera.plate_scale_rad
        self._fov_deg = camera.fov_deg
        self._setup_catalog()
        self._local = None

    def _setup_catalog(self) -> None:
        """The star index (vectors moved to the epoch when it is not the database's), magnitudes
        and HIP numbers; the cone around the boresight that holds the frame and its margin."""
        db = self.database
        ids, mags, _ = db.star_arrays()
        index = db.star_index()
        if self.epoch is not None and abs(self.epoch - db.epoch) > 1e-3:
            # read-only like the database's own (one kernel signature for either epoch)
            moved = readonly_view(np.ascontiguousarray(db.vectors_at(np.arange(len(ids)), self.epoch)))
            shift = float(np.max(np.linalg.norm(moved - index.vectors, axis=1)))  # stars leave their cells
            index = StarIndex(moved, *index[1:4], index.cell_radius_rad + shift)
        self._stars = index
        self._star_ids = ids
        self.sky.new_catalogue()
        self._mags = np.ascontiguousarray(mags, dtype=np.float64)
        cam = self.camera
        corners = cam.pixel_to_ray(np.array([[-0.5, -0.5], [cam.width - 0.5, -0.5], [-0.5, cam.height - 0.5],
                                             [cam.width - 0.5, cam.height - 0.5]]))
        margin = (self.settings.max_window_px + 3 * self.settings.star_radius_px) * cam.plate_scale_rad
        self._cone = float(np.arccos(np.clip(corners[:, 2], -1, 1)).max()) + margin

    def reset(self) -> None:
        """Forget everything: the next frame is solved lost in space."""
        self.mode = "lost"
        self._predictor = None
        self._t_last: float | None = None
        self._coast = 0
        self._zero_point = math.nan
        self._select_mag = 7.0
        self._faintest = math.inf
        self._local: win.Local | None = None
        self._local_z = (0.0, 0.0, 0.0)

    # --- input checks (skyfix.track.inputs) ---------------------------------------------
    def _check_image(self, image, t: float) -> np.ndarray:
        if not isinstance(image, np.ndarray) and isinstance(image, (str, os.PathLike)):
            got = read_image_with_header(image)
            if self.sky.time_from_frames and self._t_last is None and self.sky.first_frame(got, image, t):
                self.epoch = julian_year(self.sky.observation.time)  # the catalogue at the frames' epoch
                if self.camera is not None:
                    self._setup_catalog()
                self._local = None
            image = got.data
        image = inputs.frame_array(image)
        h, w = image.shape
        if self.calibration is not None:
            self.calibration.check_size(w, h)
        elif (w, h) != (self.camera.width, self.camera.height):
            raise CameraError(f"frame is {w}×{h} but the camera is {self.camera.width}×{self.camera.height}")
        return image

    # --- one frame -------------------------------------------------------------------------
    def update(self, image, t_s: float, *, gyro_rate_rad_s=None, observer=None) -> Solution:
        """Process one frame taken at ``t_s`` (seconds, mid-exposure; each frame later than
        the last) and return its Solution with ``mode``, ``frame_time_s``, and in tracking
        ``rate_dps`` and ``rate_covariance_dps2``.

        Parameters
        ----------
        image : (H, W) array or path
            The frame, the camera's size (any real dtype; never copied whole while tracking).
        t_s : float
            Its time, seconds (any origin; only differences matter).
        gyro_rate_rad_s : (3,) array, optional
            The gyro's body rate over the interval since the last frame, camera frame.
        observer : Observer or (3,) numbers, optional
            The camera's velocity at this frame (km/s, GCRS axes), kept for the frames after it.

        Raises
        ------
        skyfix.errors.InputError
            A missing, non-finite, repeated or out-of-order time; bad gyro rates; not a 2-D frame.
        skyfix.errors.CameraError
            A frame of another size than the camera's.
        """
        t0 = time.perf_counter()
        t = inputs.frame_time(t_s, self._t_last)
        name = "<array>" if isinstance(image, np.ndarray) else str(image)
        img = self._check_image(image, t)
        gyro = inputs.gyro_rate(gyro_rate_rad_s)
        self.sky.observe(t, observer)
        if self.camera is None:
            sol = self._calibrating(img, t, gyro, name)
        elif self._predictor is None:
            sol = self._lost(img, t, gyro)
        else:
            sol = self._track(img, t, gyro, t0)
        if self.calibration is not None and self.camera is not None:
            self._refine(img, t, gyro, sol)
        self._n_frames += 1
        self._t_last = t
        sol.image = name
        sol.frame_time_s = t
        sol.time_ms["total"] = 1e3 * (time.perf_counter() - t0)
        return sol

    def predict(self, t_s: float, *, gyro_rate_rad_s=None):
        """The attitude and body rate the tracker expects at ``t_s`` (not before the last frame),
        with their covariances — e.g. for a controller between frames; the state is unchanged.

        Returns
        -------
        skyfix.track.predictors.Prediction
            ``A_icrs_to_cam`` (3, 3), ``attitude_cov_rad2`` (3, 3, of δθ in the camera frame),
            ``rate_rad_s`` (3,, camera frame) and ``rate_cov_rad2_s2`` (3, 3).

        Raises
        ------
        skyfix.errors.InputError
            The tracker has no attitude (lost), or ``t_s`` is not a finite time at or after the
            last frame's.
        """
        if self._predictor is None:
            raise InputError("the tracker is lost: no attitude to predict until a frame is solved")
        t = inputs.finite_time(t_s, "predict")
        if t < self._t_last:
            raise InputError(f"predict({t:.6g} s) is before the last frame ({self._t_last:.6g} s)")
        return self._predictor.predict(t, gyro_rate_rad_s=inputs.gyro_rate(gyro_rate_rad_s))

    # --- no camera: the self-calibration ------------------------------------------------
    def _calibrating(self, img: np.ndarray, t: float, gyro, name: str) -> Solution:
        """A frame solved blind for the self-calibration; the one that completes it is solved
        again, lost in space, through the camera it made."""
        sol = self.calibration.calibrating_frame(img, self._n_frames, name)
        if self.calibration.camera is None:
            return sol
        self._use_camera(self.calibration.camera)
        return self._lost(img, t, gyro)

    def _refine(self, img: np.ndarray, t: float, gyro, sol: Solution) -> None:
        """A keyframe when one is due (tracking, with the MEKF): the camera refitted, taken from
        the next frame on, the filter restarted at the frame's refitted attitude with its rate;
        then the camera's uncertainty added to the frame's covariance."""
        cal = self.calibration
        if self.mode == "tracking" and self.predictor_name == "mekf":
            rate = None if sol.rate_dps is None else np.radians(sol.rate_dps)
            A = cal.keyframe(img, self._n_frames, sol, rate, self._exposure(t), self.settings.line_time_s)
            if A is not None:
                pred = self._predictor.predict(t, gyro_rate_rad_s=gyro)
                self._use_camera(cal.camera)
                rate_sigma = math.sqrt(float(np.max(np.diagonal(pred.rate_cov_rad2_s2))))
                P, cross = cal.keyframe_start()
                self._restart(A, t, P, gyro, pred.rate_rad_s, rate_sigma, camera_cross=cross)
        if sol.method != "track" or not self._considering:  # else the filter's covariance holds it
            cal.account(sol)

    @property
    def _considering(self) -> bool:
        """Whether the filter carries the camera's numbers as consider states: a camera of the
        tracker's own making, and the MEKF."""
        return self.calibration is not None and self.predictor_name == "mekf"

    # --- lost in space ---------------------------------------------------------------------
    def _solve_lost(self, img: np.ndarray, rate=None, t: float | None = None) -> tuple[Solution, bool]:
        """Lost in space; with a body rate ``rate`` (rad/s, camera frame) whose streaks are at
        least :data:`STREAK_PX` long, first in the frame averaged along them (``solve``'s
        ``smear_px``: the streaks' matched filter), then as it is. The Solution, and whether
        the smeared frame solved it (the streaks bore the rate out)."""
        from skyfix.pipeline import solve

        options = dict(camera=self.camera, database=self.database, epoch=self.epoch,
                       **self.sky.solve_options(), **self._solve_options)
        if rate is not None:
            smear = self._smear_px(np.asarray(rate, dtype=np.float64), t)
            if math.hypot(smear[0], smear[1]) >= STREAK_PX:
                sol = solve(img, smear_px=smear, **options)
                if sol.solved:
                    return sol, True
        return solve(img, **options), False

    def _smear_px(self, rate: np.ndarray, t: float | None) -> np.ndarray:
        """A star's streak at the frame's centre under the body rate ``rate`` over the exposure."""
        cam = self.camera
        return streak_motion(cam, np.array([[cam.cx, cam.cy]]), rate, self._exposure(t))[0]

    def _exposure(self, t: float | None) -> float:
        """The exposure: the setting, else the time since the last frame (at most 1 s)."""
        if self.settings.exposure_s is not None:
            return self.settings.exposure_s
        if t is None or self._t_last is None:
            return 0.0
        return min(t - self._t_last, 1.0)

    def _lost(self, img: np.ndarray, t: float, gyro) -> Solution:
        sol, _ = self._solve_lost(img, gyro, t)
        sol.mode = "lost"
        if sol.solved:
            self._start(sol, t, gyro)
        return sol

    def _start(self, sol: Solution, t: float, gyro, rate=None, rate_sigma=None) -> None:
        """(Re)start the predictor from a lost-in-space Solution at ``t``: acquiring next, or
        tracking when the rate is known (gyro rates, or a ``rate`` with its σ ``rate_sigma``
        kept for the Kalman filter)."""
        P = np.asarray(sol.frame_covariance_arcsec2) * _ARCSEC ** 2
        cross = None
        if self._considering:
            from skyfix.track.self_calibration import solution_stars

            _, r = solution_stars(sol)
            P, cross = self.calibration.start(sol.A_icrs_to_cam, r @ np.asarray(sol.A_icrs_to_cam).T, P)
        stars = None
        if self.predictor_name == "small-angle":  # it measures the rate from the stars' motion
            stars = (np.array([(m.x, m.y) for m in sol.matches]).reshape(-1, 2),
                     np.array([m.id for m in sol.matches], np.int64))
        keep = rate is not None and self.predictor_name == "mekf"
        if not keep:
            rate = rate_sigma = None
        self._restart(sol.A_icrs_to_cam, t, P, gyro, rate, rate_sigma, stars, cross)
        mags = [m.mag for m in sol.matches]
        if mags:
            self._select_mag = max(float(np.max(mags)), 4.0)
            self._local = None  # made again at this depth
        self.mode = "tracking" if gyro is not None or keep else "acquiring"

    def _restart(self, A: np.ndarray, t: float, P: np.ndarray, gyro, rate, rate_sigma, stars=None,
                 camera_cross: np.ndarray | None = None) -> None:
        """A new predictor from the attitude ``A`` (covariance ``P``) at ``t``; the MEKF also
        takes a rate and its σ (default: unknown, σ ``max_rate_dps``/3), and with a camera of
        its own the cross-covariance ``camera_cross`` (3, n) of ``A`` with the camera's numbers
        (:meth:`~skyfix.track.self_calibration.SelfCalibration.start`)."""
        opts = dict(self._predictor_options, gyro=gyro is not None)
        if camera_cross is not None and camera_cross.shape[1]:  # (a camera with no free number: none)
            opts["camera_covariance"] = self.calibration.camera_covariance
            opts["camera_cross_rad"] = camera_cross
        if rate_sigma is not None:
            opts["rate_sigma_rad_s"] = rate_sigma
        if rate is not None and gyro is None and self.predictor_name == "mekf":
            opts["rate_rad_s"] = rate
        if stars is not None:
            opts["xy"], opts["ids"] = stars
        self._predictor = self._make_predictor(self.predictor_name, A, t, P, **opts)
        self._coast = 0

    # --- tracking --------------------------------------------------------------------------
    def _track(self, img: np.ndarray, t: float, gyro, t0: float) -> Solution:
        """One tracked frame: with the MEKF in one compiled call (:meth:`_step`), else step by
        step (:meth:`_steps`): another predictor, or the MEKF carrying the camera's numbers as
        consider states (each fit's sensitivity to them computed between the steps)."""
        if self.predictor_name == "mekf" and self.calibration is None:
            return self._step(img, t, gyro, t0)
        return self._steps(img, t, gyro, t0)

    def _steps(self, img: np.ndarray, t: float, gyro, t0: float) -> Solution:
        """One tracked frame step by step, for any predictor: its prediction, the windows' fit
        (one compiled call, :meth:`_measure`) and its gated update."""
        pred = self._predictor.predict(t, gyro_rate_rad_s=gyro)
        t_pred = time.perf_counter()
        fit, why = self._measure(img, t, pred)
        t_fit = time.perf_counter()
        if fit is not None:
            # the fit's NIS against the prediction, and the predictor's update when it agrees
            kw = {}
            if self._considering:
                kw["camera_sensitivity"] = self.calibration.sensitivity(fit.A_icrs_to_cam, fit.b)
            post, inn = self._predictor.update_gated(t, fit.A_icrs_to_cam, fit.covariance_rad2,
                                                     self.settings.nis_gate, xy=fit.xy,
                                                     ids=fit.ids, camera=self.camera,
                                                     gyro_rate_rad_s=gyro, **kw)
            times = {"predict": 1e3 * (t_pred - t0), "measure": 1e3 * (t_fit - t_pred),
                     "filter": 1e3 * (time.perf_counter() - t_fit)}
            if post is not None:
                return self._tracked(post, fit, times)
            return self._disagrees(img, t, gyro, pred, fit, inn, times, t0)
        return self._recover(img, t, gyro, pred, why, t0)

    def _disagrees(self, img: np.ndarray, t: float, gyro, pred, fit: WindowFit, inn, times: dict,
                   t0: float) -> Solution:
        """A fit the predictor's gate refused (its Innovation ``inn``): a manoeuvre when at
        least :data:`_STRONG_FIT` stars agree among themselves, else a failed frame."""
        if len(fit.index) >= _STRONG_FIT:
            # The stars agree among themselves, not with the prediction: a manoeuvre the
            # motion model did not expect. Restart the predictor from the fit, keeping the
            # predicted rate with the uncertainty the miss implies (2|z|/Δt, a constant
            # acceleration's over the interval).
            dt = t - self._t_last
            rate_sigma = max(2.0 * float(np.linalg.norm(inn.residual_rad)) / dt,
                             math.sqrt(float(np.max(np.diagonal(pred.rate_cov_rad2_s2)))))
            P, cross = fit.covariance_rad2, None
            if self._considering:
                P, cross = self.calibration.start(fit.A_icrs_to_cam, fit.b, P)
            self._restart(fit.A_icrs_to_cam, t, P, gyro, pred.rate_rad_s, rate_sigma, camera_cross=cross)
            post = self._predictor.predict(t, gyro_rate_rad_s=gyro)
            return self._tracked(post, fit, times)
        why = f"the star fit disagrees with the prediction (NIS {inn.nis:.3g})"
        return self._recover(img, t, gyro, pred, why, t0)

    def _tracked(self, post, fit: WindowFit, times: dict, numbers: tuple | None = None) -> Solution:
        """The Solution of a frame tracked in windows (``post``: the predictor's estimate after
        it, or with the Solution's ``numbers`` already made its attitude alone), its ``time_ms``
        ``times``."""
        mode = self.mode
        self.mode = "tracking"
        self._coast = 0
        if numbers is None:
            sol = self._solution(post, mode, fit)
        else:
            sol = self._solution_of(post, numbers, mode, fit)
        sol.time_ms = times
        return sol

    # --- the Solution ----------------------------------------------------------------------
    def _solution(self, est, mode: str, fit: WindowFit | None) -> Solution:
        """A Solution for the estimate ``est`` (a Prediction: attitude, covariances, rate) and
        the fit that made it (None: coasting on the prediction)."""
        A = np.ascontiguousarray(est.A_icrs_to_cam)
        if fit is None:
            xy, b, index = self._no_xy, self._no_b, self._no_index
        else:
            xy, b, index = fit.xy, fit.b, fit.index
        vectors = (self._stars.vectors if self._local is None
                   else self.sky.vectors(self._local, self._stars, self._star_ids))
        numbers = win.solution_numbers(A, est.attitude_cov_rad2, est.rate_rad_s, est.rate_cov_rad2_s2, xy, b,
                                       index, vectors, self._stars.vectors, self._mags)
        return self._solution_of(A, numbers, mode, fit)

    def _solution_of(self, A: np.ndarray, numbers: tuple, mode: str, fit: WindowFit | None) -> Solution:
        """The Solution of the attitude ``A`` from its numbers (``head``, ``table``, RMS:
        :func:`skyfix.track.windows.solution_numbers`'s) and the fit (None: coasting)."""
        head, table, rmse = numbers
        A_reported = self.sky.numbers(A, head)  # the attitude in the frame asked for
        h = head.tolist()
        cam = self.camera
        sol = Solution(image="<array>", status="solved", ra_deg=h[0], dec_deg=h[1], roll_deg=h[2],
                       boresight_px=[cam.cx, cam.cy], fov_deg=self._fov_deg, quaternion_xyzw=h[3:7],
                       covariance_arcsec2=[h[7:10], h[10:13], h[13:16]], method="track", mode=mode,
                       rate_dps=h[16:19], rate_covariance_dps2=[h[19:22], h[22:25], h[25:28]])
        sol.A_icrs_to_cam = A
        sol.camera = cam
        self.sky.report(sol, A, A_reported)
        if fit is None:
            return sol
        sol.n_detected = fit.n_found
        sol.n_matched = len(fit.index)
        sol.prob_false = fit.prob_false
        sol.rmse_arcsec = float(rmse)
        sol.matches = MatchTable(table, fit.ids)  # made into Match tuples when read
        return sol
