"""The Tracker's steps on a frame apart from its filter loop (:mod:`skyfix.track.tracker`):
the star fit from windows around the predicted stars (:meth:`FrameSteps._measure`, one compiled
call: :func:`skyfix.track.measure.measure_frame`; with the MEKF :meth:`FrameSteps._step`, one
compiled call from the window plan to the filter's update: :func:`skyfix.track.step.track_step`)
and the recovery of a frame the windows could not track (:meth:`FrameSteps._recover`: lost in
space at once, then update, jump, coast or lost).

:class:`FrameSteps` is a base of :class:`~skyfix.track.tracker.Tracker` and works on its state
(the settings, the predictor, the catalogue, the sky); it is not used on its own.
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import numpy as np

from skyfix.solution import Solution
from skyfix.track import windows as win
from skyfix.track.filter import gate_innovation, innovation
from skyfix.track.measure import measure_frame
from skyfix.track.predictors import Prediction
from skyfix.track.step import track_step, window_fit_agrees

__all__ = ["STREAK_PX", "FrameSteps", "WindowFit", "window_fit_agrees"]

_ARCSEC = math.pi / (180 * 3600)
_DEG = math.pi / 180
_LOCAL_MARGIN_RAD = math.radians(2.0)  # the local catalogue reaches this far beyond the frame
_LOCAL_COS = math.cos(0.5 * _LOCAL_MARGIN_RAD)  # ... and is made again when the boresight moves half that
_OUTLIER_SIGMA = 5.0  # a fitted star whose residual exceeds this many σ is dropped
#: A predicted streak at least this long (pixels) is centroided by the streak fit (a round star:
#: the centre of mass).
STREAK_PX = 2.0
#: After a jump solved along the predicted streaks, the rate is kept with at least this
#: fraction of its size as σ: windows then hold a streak 4σ = 40 % longer or shorter than
#: predicted; a rate further off fails the next frame's windows, which is solved again.
_JUMP_RATE_SIGMA = 0.1


class WindowFit(NamedTuple):
    """A frame's star fit: the attitude, its covariance and the stars in it."""

    A_icrs_to_cam: np.ndarray
    covariance_rad2: np.ndarray
    xy: np.ndarray          # (n, 2) centroids
    index: np.ndarray       # (n,) catalogue indices
    ids: np.ndarray         # (n,) their catalogue ids
    b: np.ndarray           # (n, 3) rays at the frame time
    n_found: int            # windows with a centroid
    n_windows: int
    prob_false: float


def _copied(A: np.ndarray, P: np.ndarray, rate: np.ndarray) -> Prediction:
    """The Prediction of the filter's attitude ``A``, covariance ``P`` (6, 6) and rate, copies
    (as the MEKF predictor's ``predict`` gives it)."""
    return Prediction(A.copy(), P[:3, :3].copy(), rate.copy(), P[3:, 3:].copy())


class FrameSteps:
    """The Tracker's measurement and recovery of a frame (module docstring)."""

    def _recover(self, img: np.ndarray, t: float, gyro, pred, why: str, t0: float) -> Solution:
        """A frame the windows could not track: lost in space at once (along the predicted
        streaks first, :meth:`_solve_lost`); an attitude that agrees with the prediction updates
        the predictor (the rate survives), one that does not is a jump: start again from it,
        keeping the rate when the streaks bore it out. No attitude: coast, while allowed, only
        on a frame that shows no stars (blank, covered, blinded) — stars the prediction does not
        explain mean it is wrong — else lost."""
        lis, aided = self._solve_lost(img, pred.rate_rad_s, t)
        if lis.solved:
            P = np.asarray(lis.frame_covariance_arcsec2) * _ARCSEC ** 2
            kw = {}
            if self._considering:  # the camera's numbers are consider states: the fit's sensitivity
                from skyfix.track.self_calibration import solution_stars

                A = np.asarray(lis.A_icrs_to_cam)
                kw["camera_sensitivity"] = self.calibration.sensitivity(A, solution_stars(lis)[1] @ A.T)
                nis = self._predictor.filter.innovation(t, A, P, gyro, kw["camera_sensitivity"]).nis
            else:
                nis = innovation(pred.A_icrs_to_cam, pred.attitude_cov_rad2, lis.A_icrs_to_cam, P).nis
            if nis <= self.settings.nis_gate:
                xy = np.array([(m.x, m.y) for m in lis.matches]).reshape(-1, 2)
                ids = np.array([m.id for m in lis.matches], np.int64)
                post = self._predictor.update(t, lis.A_icrs_to_cam, P, xy=xy, ids=ids, camera=self.camera,
                                              gyro_rate_rad_s=gyro, **kw)
                lis.mode = self.mode
                self.mode = "tracking"
                self._coast = 0
                lis.rate_dps = (np.asarray(post.rate_rad_s) / _DEG).tolist()
                lis.rate_covariance_dps2 = (np.asarray(post.rate_cov_rad2_s2) / _DEG ** 2).tolist()
                return lis
            lis.mode = "lost"  # a jump: start again from here
            if aided:
                rate = np.asarray(pred.rate_rad_s, dtype=np.float64)
                sigma = max(math.sqrt(float(np.max(np.diagonal(pred.rate_cov_rad2_s2)))),
                            _JUMP_RATE_SIGMA * float(np.linalg.norm(rate)))
                self._start(lis, t, gyro, rate, sigma)
            else:
                self._start(lis, t, gyro)
            return lis
        dark = lis.n_detected < self.settings.min_stars  # nothing in the frame contradicts the prediction
        coast = dark and self.mode == "tracking" and self._coast < self.settings.max_coast_frames
        if coast and self._windows_fit(pred):
            self._coast += 1
            sol = self._solution(pred, "tracking", None)
            sol.reason = (f"coasting on the prediction ({self._coast} of {self.settings.max_coast_frames}): "
                          f"{why}; lost in space: {lis.reason}")
            sol.time_ms = dict(lis.time_ms)
            return sol
        lis.mode = self.mode
        self.mode = "lost"
        self._predictor = None
        lis.reason = f"{why}; lost in space: {lis.reason}"
        if not dark:
            lis.reason += f" ({lis.n_detected} stars the prediction does not explain: not coasting)"
        return lis

    def _windows_fit(self, pred) -> bool:
        """Whether windows of ``max_window_px`` still reach ``k_sigma`` predicted σ of the
        boresight's error: the prediction is good enough to coast on and track from."""
        P = pred.attitude_cov_rad2
        sigma_px = math.sqrt(max(P[0, 0] + P[1, 1], 0.0)) / self._plate
        return self.settings.k_sigma * sigma_px + self.settings.star_radius_px <= self.settings.max_window_px

    def _step(self, img: np.ndarray, t: float, gyro, t0: float) -> Solution:
        """A frame tracked with the MEKF: the filter's prediction, then the windows, the fit,
        the filter's gated correction and the Solution's numbers in one compiled call
        (:func:`skyfix.track.step.track_step`); what the step-by-step path decides from them
        (:meth:`_measured`, the gate's Innovation) decided here the same way."""
        filt = self._predictor.filter
        A, P, rate, gyro_rate, bias, gyro_mode = filt.step_inputs(t, gyro)
        t_pred = time.perf_counter()
        n_max, args = self._measure_args(t, A, rate)
        out, gate, (new_rate, new_bias), numbers = track_step(
            img, A, P, rate, gyro_rate, bias, gyro_mode, *args, float(self.settings.nis_gate), self._mags,
            self._stars.vectors)
        t_step = time.perf_counter()
        fit, why = self._measured(out, n_max)
        if fit is None:
            return self._recover(img, t, gyro, _copied(A, P, rate), why, t0)
        rotation_code, covariance_code, ok, z, S, nis, done, A_new, _, P_new = gate
        inn = gate_innovation(rotation_code, covariance_code, ok, z, S, nis)
        times = {"predict": 1e3 * (t_pred - t0), "step": 1e3 * (t_step - t_pred)}
        if not done:
            return self._disagrees(img, t, gyro, _copied(A, P, rate), fit, inn, times, t0)
        filt.take(t, A_new, P_new, new_rate, new_bias, gyro_rate, nis)
        return self._tracked(A_new.copy(), fit, times, numbers)

    def _measure(self, img: np.ndarray, t: float, pred) -> tuple[WindowFit | None, str]:
        """The star fit of one frame from windows around the predicted stars (module
        docstring; :func:`skyfix.track.measure.measure_frame`), or None and why not."""
        A = np.ascontiguousarray(pred.A_icrs_to_cam)
        rate = np.ascontiguousarray(pred.rate_rad_s, dtype=np.float64)
        n_max, args = self._measure_args(t, A, rate)
        out = measure_frame(img, A, np.ascontiguousarray(pred.attitude_cov_rad2), rate,
                            np.ascontiguousarray(pred.rate_cov_rad2_s2), *args)
        return self._measured(out, n_max)

    def _measure_args(self, t: float, A: np.ndarray, rate: np.ndarray) -> tuple[int, tuple]:
        """The windows' most, and :func:`~skyfix.track.measure.measure_frame`'s arguments after
        the prediction (``A``, its covariance, ``rate``, its covariance) for the frame at ``t``:
        the local catalogue (made again when the boresight has moved) and the star vectors as
        seen."""
        s = self.settings
        exposure = self._exposure(t)
        local = self._local_catalog(A[2])
        vectors = self.sky.vectors(local, self._stars, self._star_ids)  # as seen, with a time
        wx, wy, _ = rate.tolist()  # the streak at the boresight, px: fewer windows when it is long
        streaking = s.centroid == "streak" and exposure * math.hypot(wx, wy) >= STREAK_PX * self._plate
        n_max = s.streak_windows if streaking else s.n_windows
        windows = self._streak_window_settings_t if streaking else self._window_settings_t
        return n_max, (exposure, s.line_time_s, self._local_t,
                       min(self._select_mag, self._faintest + 1.0), self._cam, windows, self._view_t,
                       self._tiles, self._max_tile, vectors, self._zero_point, self._match_settings_t,
                       self._centroid_t, s.min_stars, _OUTLIER_SIGMA)

    def _measured(self, out: tuple, n_max: int) -> tuple[WindowFit | None, str]:
        """:func:`~skyfix.track.measure.measure_frame`'s tuple ``out`` as the frame's
        :class:`WindowFit`, or None and why not; the faintest star to choose next frame and the
        magnitudes' zero point kept."""
        s = self.settings
        (n, too_wide, faintest, ok, n_found, n_gated, n_fit, A_fit, P_fit, zero_point, log_chance, index, xy,
         b) = out
        # next frame: stars down to a magnitude fainter than the faintest chosen (all, when short)
        self._faintest = faintest if n == n_max else math.inf
        if n < s.min_stars:
            if too_wide:
                return None, (f"attitude too uncertain for windows ({too_wide} stars need more than "
                              f"{s.max_window_px:g} px)")
            return None, f"{n} catalogue stars to track in the frame (need {s.min_stars})"
        if not ok:
            if n_gated < s.min_stars:
                return None, f"{n_gated} of {n} windows hold their star ({n_found} found a star)"
            return None, (f"{n_fit} of {n_gated} stars agree in the pair check and the fit "
                          f"(need {s.min_stars})")
        if not window_fit_agrees(n_fit, n_found):
            return None, f"only {n_fit} of the {n_found} windows that found a star agree on the attitude"
        if zero_point == zero_point:  # not NaN
            zp = self._zero_point
            self._zero_point = zero_point if zp != zp else 0.8 * zp + 0.2 * zero_point
        index = index[:n_fit]
        return WindowFit(A_fit, P_fit, xy[:n_fit], index, self._star_ids[index], b[:n_fit], n_found, n,
                         math.exp(log_chance)), ""

    def _local_catalog(self, z: np.ndarray) -> win.Local:
        """The catalogue within the frame's cone plus :data:`_LOCAL_MARGIN_RAD` of the boresight
        ``z``, down to what the windows can choose or be crowded by; made again when the
        boresight has moved half that margin."""
        x, y, w = z.tolist()  # Python floats: a 3-vector's dot in numpy costs a microsecond
        lx, ly, lw = self._local_z
        if self._local is None or x * lx + y * ly + w * lw < _LOCAL_COS:
            limit = int(np.searchsorted(self._mags, self._select_mag + self._window_settings.neighbour_dmag,
                                        side="right"))
            self._local = win.local_catalog(z, self._cone + _LOCAL_MARGIN_RAD, limit, self._stars, self._mags)
            self._local_t = tuple(self._local)
            self._local_z = (x, y, w)
        return self._local
