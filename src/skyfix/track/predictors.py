"""Attitude predictors chosen by name: where the sky will be at the next frame, and how sure.

A tracker feeds each predictor the star fit of every frame (``update``) and asks it for the
attitude at the next frame's time (``predict``) to place its windows. One registry,
:data:`PREDICTORS`, maps names to classes (like :data:`skyfix.attitude.METHODS`):

- ``"mekf"`` (default): the multiplicative EKF of :mod:`skyfix.track.filter` — attitude + rate,
  or attitude + gyro bias once gyro rates are given — with exact covariance propagation.
- ``"small-angle"``: thesis 002 §2.4 — the body rate from the motion of the stars matched by ID
  between the last two frames (:func:`skyfix.track.rate.small_angle_rate`), held constant.
- ``"three-point"``: the quadratic through the last three attitudes (weights 1, −3, 3).
- ``"three-point-thesis"``: thesis 004 §4.9's ``x + v T + ½ a T²`` (weights 0.5, −2, 2.5),
  biased by ``−½ α T²`` under a constant angular acceleration α (kept to show the bias).

**Three-point on attitudes.** Thesis 004 extrapolates the three Euler angles independently,
which needs unwrapping near ±180° and is singular at pitch ±90°. Here the older attitudes are
first expressed as rotation vectors relative to the latest, ``dᵢ = log(Aᵢ A₁ᵀ)`` (so ``d₁ = 0``;
camera frame, the convention of ``δθ``), the weights of
:func:`skyfix.track.rate.extrapolation_weights` combine them, ``p = Σ wᵢ dᵢ``, and
``A_pred = R(p) A₁``. The vectors are small (a few frames of motion), nothing wraps, and a
rotation about a fixed axis — a constant rate or a constant angular acceleration — is
extrapolated exactly (the ``"exact"`` weights) because its ``dᵢ`` are collinear.

Every predictor reports a covariance with its prediction. For the three-point predictors it is
the measurement covariances carried through the weights, ``Σ wᵢ² Cᵢ`` (19 C for the exact
weights at one period ahead, 10.5 C for the thesis's: the exact predictor trades the bias for
noise), and the rate's ``Σ ẇᵢ² Cᵢ``; before three fits exist they fall back to two (linear) or
one (hold, with the initial rate σ).

Interface of every predictor class, started from a first star fit::

    Predictor(A_icrs_to_cam, t_s, attitude_cov_rad2, *, gyro=False, rate_sigma_rad_s=..., ...)
    update(t_s, A_meas, cov_meas_rad2, *, xy=None, ids=None, camera=None, gyro_rate_rad_s=None)
        -> Prediction       # the estimate at t_s after this fit (t_s > the last fit's time)
    predict(t_s, gyro_rate_rad_s=None) -> Prediction      # at t_s ≥ the last fit's time
    innovation_nis(t_s, A_meas, cov_meas_rad2) -> float   # χ²(3) when consistent
    update_gated(t_s, A_meas, cov_meas_rad2, nis_gate, *, xy=None, ids=None, camera=None,
                 gyro_rate_rad_s=None) -> (Prediction or None, Innovation)
        # update only when the NIS is at most nis_gate (None: not committed)

Only the MEKF uses gyro rates (``gyro=True``: attitude + gyro bias); the thesis predictors had
no gyro and ignore them. Only the MEKF carries a self-calibrated camera's uncertainty
(``camera_covariance=``, ``camera_cross_rad=``: consider states, :mod:`skyfix.track.filter`);
its ``update``, ``update_gated`` and ``innovation_nis`` then take each fit's
``camera_sensitivity=G`` (3, n).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._kernels.rotation import rodrigues, rotation_vector
from skyfix.errors import InputError, unknown_name
from skyfix.track.filter import (
    DEFAULT_ACCEL_PSD,
    DEFAULT_BIAS_SIGMA_RAD_S,
    DEFAULT_BIAS_WALK,
    DEFAULT_GYRO_NOISE,
    DEFAULT_RATE_SIGMA_RAD_S,
    AttitudeFilter,
    FilterState,
    Innovation,
    as_covariance,
    as_rotation,
    as_time,
    innovation,
)
from skyfix.track.rate import extrapolation_weights, small_angle_rate

__all__ = [
    "DEFAULT_PREDICTOR",
    "PREDICTORS",
    "MekfPredictor",
    "Prediction",
    "SmallAnglePredictor",
    "ThreePointPredictor",
    "ThreePointThesisPredictor",
    "make_predictor",
]

DEFAULT_PREDICTOR = "mekf"


class Prediction(NamedTuple):
    """An attitude and body rate at one time, with their covariances."""

    A_icrs_to_cam: np.ndarray       # (3, 3)
    attitude_cov_rad2: np.ndarray   # (3, 3) of δθ, camera frame
    rate_rad_s: np.ndarray          # (3,) body rate, camera frame
    rate_cov_rad2_s2: np.ndarray    # (3, 3)


class _Predictor:
    """What the predictors share: the NIS of a measurement against :meth:`predict`."""

    def predict(self, t_s: float, gyro_rate_rad_s: np.ndarray | None = None) -> Prediction:
        raise NotImplementedError

    def innovation_nis(self, t_s: float, A_meas: np.ndarray, cov_meas_rad2: np.ndarray) -> float:
        """Normalised innovation squared of a star fit at ``t_s`` against the prediction:
        χ²(3) when consistent (:data:`skyfix.track.filter.NIS_GATE` at 0.999)."""
        p = self.predict(t_s)
        return innovation(p.A_icrs_to_cam, p.attitude_cov_rad2, A_meas, cov_meas_rad2).nis

    def update(self, t_s: float, A_meas: np.ndarray, cov_meas_rad2: np.ndarray, *, xy=None, ids=None,
               camera=None, gyro_rate_rad_s: np.ndarray | None = None) -> Prediction:
        raise NotImplementedError

    def update_gated(self, t_s: float, A_meas: np.ndarray, cov_meas_rad2: np.ndarray, nis_gate: float, *,
                     xy=None, ids=None, camera=None, gyro_rate_rad_s: np.ndarray | None = None
                     ) -> tuple[Prediction | None, Innovation]:
        """The star fit's innovation against :meth:`predict` at ``t_s`` and, when its NIS is at
        most ``nis_gate``, :meth:`update` with it (else None: nothing committed)."""
        p = self.predict(t_s, gyro_rate_rad_s)
        inn = innovation(p.A_icrs_to_cam, p.attitude_cov_rad2, A_meas, cov_meas_rad2)
        if not inn.nis <= nis_gate:
            return None, inn
        return self.update(t_s, A_meas, cov_meas_rad2, xy=xy, ids=ids, camera=camera,
                           gyro_rate_rad_s=gyro_rate_rad_s), inn


def _prediction(state: FilterState) -> Prediction:
    P = state.covariance
    return Prediction(state.A_icrs_to_cam, P[:3, :3].copy(), state.rate_rad_s, P[3:, 3:].copy())


class MekfPredictor(_Predictor):
    """The multiplicative EKF (:class:`skyfix.track.filter.AttitudeFilter`) started from a first
    fit; ``gyro=True`` runs it on gyro rates (attitude + gyro bias). Options: the filter's."""

    def __init__(self, A_icrs_to_cam: np.ndarray, t_s: float, attitude_cov_rad2: np.ndarray, *,
                 gyro: bool = False, rate_rad_s: np.ndarray | None = None,
                 rate_sigma_rad_s: float = DEFAULT_RATE_SIGMA_RAD_S,
                 accel_psd: float = DEFAULT_ACCEL_PSD, gyro_noise: float = DEFAULT_GYRO_NOISE,
                 bias_walk: float = DEFAULT_BIAS_WALK,
                 bias_sigma_rad_s: float = DEFAULT_BIAS_SIGMA_RAD_S,
                 camera_covariance: np.ndarray | None = None,
                 camera_cross_rad: np.ndarray | None = None) -> None:
        self.filter = AttitudeFilter(A_icrs_to_cam, t_s, attitude_cov_rad2, rate_rad_s=rate_rad_s,
                                     rate_sigma_rad_s=rate_sigma_rad_s, accel_psd=accel_psd, gyro=gyro,
                                     gyro_noise=gyro_noise, bias_walk=bias_walk,
                                     bias_sigma_rad_s=bias_sigma_rad_s, camera_covariance=camera_covariance,
                                     camera_cross_rad=camera_cross_rad)

    def update(self, t_s: float, A_meas: np.ndarray, cov_meas_rad2: np.ndarray, *, xy=None, ids=None,
               camera=None, gyro_rate_rad_s: np.ndarray | None = None,
               camera_sensitivity: np.ndarray | None = None) -> Prediction:
        state = self.filter.update(t_s, A_meas, cov_meas_rad2, gyro_rate_rad_s, camera_sensitivity)
        return _prediction(state)

    def update_gated(self, t_s: float, A_meas: np.ndarray, cov_meas_rad2: np.ndarray, nis_gate: float, *,
                     xy=None, ids=None, camera=None, gyro_rate_rad_s: np.ndarray | None = None,
                     camera_sensitivity: np.ndarray | None = None) -> tuple[Prediction | None, Innovation]:
        done, inn = self.filter.update_gated(t_s, A_meas, cov_meas_rad2, nis_gate, gyro_rate_rad_s,
                                             camera_sensitivity)
        return (Prediction(*self.filter.prediction(t_s)) if done else None), inn

    def predict(self, t_s: float, gyro_rate_rad_s: np.ndarray | None = None) -> Prediction:
        return Prediction(*self.filter.prediction(t_s, gyro_rate_rad_s))

    def innovation_nis(self, t_s: float, A_meas: np.ndarray, cov_meas_rad2: np.ndarray, *,
                       camera_sensitivity: np.ndarray | None = None) -> float:
        return self.filter.innovation_nis(t_s, A_meas, cov_meas_rad2, camera_sensitivity=camera_sensitivity)


class _Fit(NamedTuple):
    t_s: float
    A: np.ndarray
    cov: np.ndarray


class _HistoryPredictor(_Predictor):
    """Keeps the last few fits (``history_length``); checks times and inputs."""

    history_length = 2

    def __init__(self, A_icrs_to_cam: np.ndarray, t_s: float, attitude_cov_rad2: np.ndarray, *,
                 gyro: bool = False, rate_sigma_rad_s: float = DEFAULT_RATE_SIGMA_RAD_S) -> None:
        self.rate_sigma_rad_s = float(rate_sigma_rad_s)
        if not (math.isfinite(self.rate_sigma_rad_s) and self.rate_sigma_rad_s > 0):
            raise InputError(f"rate_sigma_rad_s must be a positive number, got {rate_sigma_rad_s!r}")
        self.fits: list[_Fit] = []
        self._add(t_s, A_icrs_to_cam, attitude_cov_rad2)

    def _add(self, t_s: float, A_meas: np.ndarray, cov_meas_rad2: np.ndarray) -> _Fit:
        t = as_time(t_s, "predictor time")
        if self.fits and not t > self.fits[-1].t_s:
            raise InputError(f"predictor time must increase: t={t!r} s after {self.fits[-1].t_s!r} s")
        fit = _Fit(t, as_rotation(A_meas, "measured attitude"),
                   as_covariance(cov_meas_rad2, "measurement covariance"))
        self.fits = (self.fits + [fit])[-self.history_length:]
        return fit

    def _check_time(self, t_s: float) -> float:
        t = as_time(t_s, "predictor time")
        if t < self.fits[-1].t_s:
            raise InputError(f"cannot predict back in time: t={t!r} s is before the last fit's "
                             f"{self.fits[-1].t_s!r} s")
        return t


class SmallAnglePredictor(_HistoryPredictor):
    """Thesis 002 §2.4: a constant body rate measured from the stars' motion between the last
    two frames (matched by ``ids``), applied to the last fit: ``A(t) = R(−ω (t − t₁)) A₁``.

    ``update`` needs ``xy`` (N, 2), ``ids`` (N,) and ``camera`` to measure the rate (the first
    frame's ``xy`` and ``ids`` may be given to the constructor); with fewer than 2 stars in
    common (or no centroids) the rate comes from the last two fits instead,
    ``ω = −log(A₁ A₂ᵀ)/(t₁ − t₂)``, and with one fit it is 0 ± ``rate_sigma_rad_s``.
    ``sigma_px``: centroid σ for the rate's covariance (default: from the fit's residuals).
    """

    def __init__(self, A_icrs_to_cam: np.ndarray, t_s: float, attitude_cov_rad2: np.ndarray, *,
                 gyro: bool = False, rate_sigma_rad_s: float = DEFAULT_RATE_SIGMA_RAD_S,
                 sigma_px: float | None = None, xy: np.ndarray | None = None,
                 ids: np.ndarray | None = None) -> None:
        super().__init__(A_icrs_to_cam, t_s, attitude_cov_rad2, rate_sigma_rad_s=rate_sigma_rad_s)
        self.sigma_px = sigma_px
        self._stars = self._star_table(xy, ids)
        self.rate = np.zeros(3)
        self.rate_cov = self.rate_sigma_rad_s**2 * np.eye(3)

    @staticmethod
    def _star_table(xy, ids) -> tuple | None:
        """(xy (N, 2), ids (N,)) of a frame's stars, or None without ``xy``."""
        if xy is None:
            return None
        if ids is None:
            raise InputError("the small-angle predictor needs the stars' ids with xy")
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        ids = np.asarray(ids).reshape(-1)
        if len(ids) != len(xy):
            raise InputError(f"one id per star needed, got {len(ids)} for {len(xy)}")
        return xy, ids

    def update(self, t_s: float, A_meas: np.ndarray, cov_meas_rad2: np.ndarray, *, xy=None, ids=None,
               camera=None, gyro_rate_rad_s: np.ndarray | None = None) -> Prediction:
        stars = self._star_table(xy, ids)
        if stars is not None and camera is None:
            raise InputError("the small-angle predictor needs the camera with xy")
        fit = self._add(t_s, A_meas, cov_meas_rad2)
        old = self.fits[0]
        measured = False
        if stars is not None and self._stars is not None:
            common, i_prev, i_cur = np.intersect1d(self._stars[1], stars[1], return_indices=True)
            if len(common) >= 2:
                est = small_angle_rate(self._stars[0][i_prev], stars[0][i_cur], camera,
                                       fit.t_s - old.t_s, sigma_px=self.sigma_px)
                self.rate, self.rate_cov = est.rate_rad_s, est.covariance
                measured = True
        if not measured:
            dt = fit.t_s - old.t_s
            self.rate = -rotation_vector(np.ascontiguousarray(fit.A @ old.A.T)) / dt
            self.rate_cov = (fit.cov + old.cov) / dt**2
        self._stars = stars
        return Prediction(fit.A.copy(), fit.cov.copy(), self.rate.copy(), self.rate_cov.copy())

    def predict(self, t_s: float, gyro_rate_rad_s: np.ndarray | None = None) -> Prediction:
        t = self._check_time(t_s)
        last = self.fits[-1]
        dt = t - last.t_s
        R = rodrigues(-self.rate * dt)
        cov = R @ last.cov @ R.T + dt * dt * self.rate_cov
        return Prediction(R @ last.A, cov, self.rate.copy(), self.rate_cov.copy())


class ThreePointPredictor(_HistoryPredictor):
    """The last three fits extrapolated as rotation vectors relative to the latest (module
    docstring) with the ``"exact"`` quadratic weights (1, −3, 3 at equal spacing)."""

    history_length = 3
    kind = "exact"

    def update(self, t_s: float, A_meas: np.ndarray, cov_meas_rad2: np.ndarray, *, xy=None, ids=None,
               camera=None, gyro_rate_rad_s: np.ndarray | None = None) -> Prediction:
        fit = self._add(t_s, A_meas, cov_meas_rad2)
        p = self._extrapolate(fit.t_s)
        return Prediction(fit.A.copy(), fit.cov.copy(), p.rate_rad_s, p.rate_cov_rad2_s2)

    def predict(self, t_s: float, gyro_rate_rad_s: np.ndarray | None = None) -> Prediction:
        return self._extrapolate(self._check_time(t_s))

    def _extrapolate(self, t: float) -> Prediction:
        fits = self.fits
        latest = fits[-1]
        w, dw = extrapolation_weights(np.array([f.t_s for f in fits]), t, self.kind)
        d = np.zeros((len(fits), 3))  # rotation vectors of each fit relative to the latest
        for i, f in enumerate(fits[:-1]):
            d[i] = rotation_vector(np.ascontiguousarray(f.A @ latest.A.T))
        A = rodrigues(w @ d) @ latest.A
        cov = sum(wi * wi * f.cov for wi, f in zip(w.tolist(), fits, strict=True))
        if len(fits) == 1:  # a hold: the rate is unknown
            rate_cov = self.rate_sigma_rad_s**2 * np.eye(3)
            return Prediction(A, cov + (t - latest.t_s) ** 2 * rate_cov, np.zeros(3), rate_cov)
        # d(t) = −ω (t − t₁) near the latest fit, so ω = −ḋ.
        rate_cov = sum(wi * wi * f.cov for wi, f in zip(dw.tolist(), fits, strict=True))
        return Prediction(A, cov, -(dw @ d), rate_cov)


class ThreePointThesisPredictor(ThreePointPredictor):
    """:class:`ThreePointPredictor` with thesis 004's weights (0.5, −2, 2.5): biased by
    ``−½ α T²`` under a constant angular acceleration α (:func:`skyfix.track.rate.three_point_error`)."""

    kind = "thesis"


PREDICTORS: dict[str, type] = {
    "mekf": MekfPredictor,
    "small-angle": SmallAnglePredictor,
    "three-point": ThreePointPredictor,
    "three-point-thesis": ThreePointThesisPredictor,
}


def make_predictor(name: str, A_icrs_to_cam: np.ndarray, t_s: float, attitude_cov_rad2: np.ndarray,
                   **options) -> _Predictor:
    """A predictor of :data:`PREDICTORS` by name, started from a first fit, with its keyword
    options; an unknown name or option is an InputError."""
    try:
        cls = PREDICTORS[name.lower()]
    except (KeyError, AttributeError):
        raise unknown_name("predictor", name, PREDICTORS) from None
    try:
        return cls(A_icrs_to_cam, t_s, attitude_cov_rad2, **options)
    except TypeError as exc:
        raise InputError(f"bad option for predictor {name!r}: {exc}") from None
