"""Tracking mode measured: against lost in space, against its own error bars, against thesis 002.

``skyfix analyze tracking`` runs these studies —
:func:`skyfix.analysis.tracking_runs.run_study`: every sequence a trial of the campaign engine,
a Parquet row each — and :func:`skyfix.analysis.tracking_report.write_study` writes their tables
and plots; docs/tracking-study.md holds the numbers of a full run and reads them.

**Sequences** (:func:`run_sequence`). Frames of :data:`CAMERA` (1280 × 960, 15°) at 10 Hz with
the generic sensor's noise (:func:`skyfix.simulate.render_sequence`), the camera turning at a
constant 0, 0.5, 1 or 2 °/s about :data:`RATE_AXIS`, or slewing (accelerate at 1 °/s² to 2 °/s,
coast, decelerate). One frame is blanked (the sky level and its noise, no stars) and later the
camera jumps 90° (the same motion continues about the new pointing). Every frame goes to a
:class:`skyfix.track.Tracker` *and* to :func:`skyfix.pipeline.solve` (lost in space), and both
attitudes are compared with the truth: ``δθ`` of :func:`skyfix.attitude.attitude_error`
(boresight ``|δθx, δθy|``, roll ``δθz``) and, for the tracker, ``δθ / σ`` per axis with σ from
its reported covariance.

**Prediction error** (thesis 002 §5.1, §5.4; its experiments E3, E6, E7). Thesis 002 measures
how far its windows' centres (the predicted star positions) are from the centroids found in
them. Here every predictor of :data:`skyfix.track.PREDICTORS` is run beside the tracker, fed the
same per-frame star fits (the tracker's matched window centroids and their catalogue stars,
fitted by :func:`skyfix.attitude.svd_attitude`), and asked before each fit where frame k's stars
will be. The error is the predicted minus the measured position (thesis's definition) and minus
the true one, pixels, and the predicted attitude's error ``δθ``. Under a constant angular
acceleration ``α`` a predictor that holds the rate of the last interval is off by ``α T²`` (the
rate is that of the interval's middle, half a period old, and the turn over the next period
misses ``½ α T²``); thesis 004's three-point weights by ``½ α T²``; the exact quadratic by 0
(:func:`skyfix.track.rate.three_point_error`): :func:`accel_slopes` measures the ratio of ``δθ``
to ``α T²`` across the boresight. The thesis's own analysis (prediction error against rate on
its air bearing) is rerun on a damped pendulum mostly in pitch at 4 Hz with a 62.5 ms exposure
(seed 002 §4.3), binned by pitch rate after its acceleration filter (:func:`rate_slopes`). A
held-rate predictor's error grows with the rate only when its frame times are wrong, so thesis
002's predictor runs once more, told times off by an independent σ = 20 ms per frame
(:func:`time_error_slope` gives the growth to expect).

**Centroiding time** (Table 5-1, E5): :mod:`skyfix.analysis.window_timing`, run first so that
it times an idle machine.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from skyfix._kernels.rotation import rodrigues
from skyfix.analysis.window_timing import THESIS_TABLE_5_1, TimingRow, run_timing, timing_frame
from skyfix.attitude import attitude_covariance, attitude_error, svd_attitude
from skyfix.camera import Camera
from skyfix.geometry import attitude_from_quaternion, attitude_from_radec_roll, normalize, radec_to_vector
from skyfix.simulate import render_sequence
from skyfix.simulate.profiles import Profile, make_profile

__all__ = [
    "CAMERA", "EPOCH", "RATE_AXIS", "PREDICTOR_NAMES", "ANALYTIC_ACCEL_RATIO", "THESIS_SLOPES",
    "THESIS_INTERCEPT_PX", "THESIS_TABLE_5_1",
    "SequenceSpec", "StudySettings", "FULL", "QUICK", "PredictionErrors", "SequenceResult",
    "SlopeFit", "TimingRow", "TrackingStudy", "sequence_specs", "run_sequence", "accuracy_summary",
    "binned_fits", "error_correlations", "time_error_slope", "normalised_errors", "recovery_frames",
    "accel_terms", "accel_slopes", "rate_slopes",
    "constant_rate_slopes", "timing_frame", "run_timing",
]

CAMERA = Camera.from_fov(1280, 960, 15.0)
EPOCH = 2025.5
#: Direction of the constant rates (camera frame): mostly cross-boresight, some roll.
RATE_AXIS = normalize(np.array([0.6, -0.75, 0.28]))
PREDICTOR_NAMES = ("mekf", "small-angle", "three-point", "three-point-thesis")
#: δθ / (α T²) along α under a constant angular acceleration, by predictor (module docstring).
ANALYTIC_ACCEL_RATIO = {"small-angle": 1.0, "three-point": 0.0, "three-point-thesis": 0.5}
#: Thesis 002 Fig 5-9: prediction error vs pitch rate, px per (arcsec/s), and its ≈0.1 px at rest.
THESIS_SLOPES = {"mean − std": 0.0019, "mean": 0.0028, "mean + std": 0.0038}
THESIS_INTERCEPT_PX = 0.1
_ARCSEC = math.pi / (180 * 3600)
_DEG = math.pi / 180
_VISIBLE_SNR = 10.0


class SequenceSpec(NamedTuple):
    """One simulated sequence: its motion profile (a name of
    :data:`skyfix.simulate.profiles.PROFILES` and parameters, SI units) and forced losses."""

    name: str
    profile: str
    params: dict
    n_frames: int
    fps: float = 10.0
    exposure_s: float | None = None   # None: the generic preset's (0.1 s)
    radec_roll_deg: tuple = (84.0, -2.0, 20.0)
    blank_frame: int | None = None     # this frame holds only the sky and its noise
    jump_frame: int | None = None      # from this frame on, the camera points 90° away
    seed: int = 0
    time_error_s: float = 0.0          # > 0: also thesis 002's predictor told times off by this σ


class StudySettings(NamedTuple):
    """The study's size: frames per sequence, the constant rates, the forced losses' frames, the
    pendulum's frames, the Table 5-1 grid and repeats, the seed, and the campaign engine's local
    worker processes for the sequences (0: in the calling process; they decide no number)."""

    n_frames: int = 210
    rates_dps: tuple = (0.0, 0.5, 1.0, 2.0)
    blank_frame: int = 70
    jump_frame: int = 140
    pendulum_frames: int = 200
    rois: tuple = (40, 50, 80, 100, 150, 200)
    star_counts: tuple = (5, 10, 20)
    timing_repeats: int = 21
    seed: int = 0
    workers: int = 2


FULL = StudySettings()
QUICK = StudySettings(n_frames=16, blank_frame=6, jump_frame=10, pendulum_frames=24, rois=(40, 100, 200),
                      star_counts=(5, 20), timing_repeats=5)


def sequence_specs(s: StudySettings) -> list[SequenceSpec]:
    """The study's sequences: the constant rates, the slew (both with a blank frame and a jump),
    and the thesis's air-bearing pendulum (4 Hz, 62.5 ms, no forced loss)."""
    rng = np.random.default_rng(s.seed)
    specs = []

    def pointing():  # a random sky position per sequence (|Dec| ≤ 64°) and roll
        return (float(rng.uniform(0, 360)), float(np.degrees(np.arcsin(rng.uniform(-0.9, 0.9)))),
                float(rng.uniform(0, 360)))

    common = dict(n_frames=s.n_frames, blank_frame=s.blank_frame, jump_frame=s.jump_frame, time_error_s=0.02)
    for i, r in enumerate(s.rates_dps):
        specs.append(SequenceSpec(f"{r:g} °/s", "constant", {"rate_rad_s": (r * _DEG * RATE_AXIS).tolist()},
                                  radec_roll_deg=pointing(), seed=s.seed * 1000 + i, **common))
    # 1 s at rest, 2 s accelerating, 8 s at 2 °/s, 2 s decelerating, at rest again (the jump)
    slew = {"rotation_rad": (20 * _DEG * normalize(np.array([0.3, 1.0, 0.1]))).tolist(),
            "max_rate_rad_s": 2 * _DEG, "accel_rad_s2": 1 * _DEG, "start_s": 1.0}
    specs.append(SequenceSpec("slew", "slew", slew, radec_roll_deg=pointing(), seed=s.seed * 1000 + 50,
                              **common))
    pendulum = {"amplitude_rad": [0.25 * _DEG, 1.0 * _DEG, 0.1 * _DEG], "period_s": 12.0,
                "damping_ratio": 0.05, "phase_rad": [0.0, 0.0, math.pi / 2]}
    specs.append(SequenceSpec("pendulum", "pendulum", pendulum, n_frames=s.pendulum_frames, fps=4.0,
                              exposure_s=0.0625, radec_roll_deg=pointing(), seed=s.seed * 1000 + 60,
                              time_error_s=0.02))
    return specs


class _Jumped(Profile):
    """A profile seen from ``t0`` on, about a pointing turned by the fixed ICRS rotation ``Q``:
    ``A'(t) = A(t0 + t) Q`` (the same body motion, another part of the sky)."""

    name = "jumped"

    def __init__(self, base: Profile, t0_s: float, Q: np.ndarray) -> None:
        self.base, self.t0_s, self.A0 = base, float(t0_s), base.A0 @ Q

    def turn(self, t_s):
        return self.base.turn(np.asarray(t_s, dtype=np.float64) + self.t0_s)

    def params(self) -> dict:
        return {"base": self.base.to_dict(), "t0_s": self.t0_s}


def _frames(spec: SequenceSpec) -> Iterator[tuple[float, str, object, Profile, float]]:
    """(time, event, frame, profile, profile time) of every frame of a sequence."""
    ra, dec, roll = np.radians(spec.radec_roll_deg)
    base = make_profile(spec.profile, attitude_from_radec_roll(ra, dec, roll), **spec.params)
    n1 = spec.n_frames if spec.jump_frame is None else min(spec.jump_frame, spec.n_frames)
    kw = dict(fps=spec.fps, epoch=EPOCH, exposure_s=spec.exposure_s)
    for k, f in enumerate(render_sequence(None, CAMERA, n_frames=n1, profile=base, seed=spec.seed, **kw)):
        yield k / spec.fps, "blank" if k == spec.blank_frame else "", f, base, k / spec.fps
    if n1 == spec.n_frames:
        return
    t0 = n1 / spec.fps
    bore = base.attitude(t0)[2]  # the boresight in ICRS: turn it by 90° about an axis across it
    across = [0.0, 0.0, 1.0] if abs(bore[2]) < 0.9 else [1.0, 0.0, 0.0]
    axis = normalize(np.cross(bore, across))
    jumped = _Jumped(base, t0, rodrigues(0.5 * math.pi * axis).T)
    frames = render_sequence(None, CAMERA, n_frames=spec.n_frames - n1, profile=jumped, seed=spec.seed + 500,
                             **kw)
    for k, f in enumerate(frames):
        yield t0 + k / spec.fps, "jump" if k == 0 else "", f, jumped, k / spec.fps


def _blank(image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The frame's sky level and pixel noise without its stars (a lens cap, a cloud)."""
    level = float(np.median(image))
    noise = 1.4826 * float(np.median(np.abs(image - level)))
    return np.clip(np.round(rng.normal(level, max(noise, 1.0), image.shape)), 0, None).astype(image.dtype)


def _n_visible(truth: dict) -> int:
    """Stars in the frame whose unsmeared SNR (truth electrons, sky, read noise) is ≥ 10."""
    e = np.array([s["electrons"] for s in truth["stars"]], dtype=np.float64)
    sigma_psf = truth["optics"]["psf_fwhm_px"] / 2.3548
    noise_e = truth["background_e"] + truth["sensor"]["read_noise_e"] ** 2
    snr = e / np.sqrt(e + 4 * math.pi * (sigma_psf ** 2 + 1 / 12) * noise_e)
    return int(np.count_nonzero(snr >= _VISIBLE_SNR))


class _StarFit(NamedTuple):
    A: np.ndarray
    P: np.ndarray
    xy: np.ndarray
    ids: np.ndarray
    r: np.ndarray


def _star_fit(sol) -> _StarFit | None:
    """The attitude of a Solution's matched stars alone (what a predictor is fed): an unweighted
    SVD fit, its covariance with σ from the residuals (at least 0.05 px)."""
    if not sol.solved or len(sol.matches) < 3:
        return None
    m = sol.matches
    xy = np.array([(s.x, s.y) for s in m])
    r = radec_to_vector(np.radians([s.ra_deg for s in m]), np.radians([s.dec_deg for s in m]))
    b = CAMERA.pixel_to_ray(xy)
    A = svd_attitude(b, r)
    cosang = np.clip(np.sum(b * (r @ A.T), axis=1), -1.0, 1.0)
    res2 = float(np.sum(np.arccos(cosang) ** 2))
    sigma = max(math.sqrt(res2 / max(2 * len(m) - 3, 1)), 0.05 * CAMERA.plate_scale_rad)
    return _StarFit(A, attitude_covariance(A, b, sigma), xy, np.array([s.id for s in m], np.int64), r)


class _Shadows:
    """Every predictor fed the same consecutive star fits; a gap or a restart starts them again."""

    def __init__(self, names: Sequence[str]) -> None:
        from skyfix.track import make_predictor

        self.names, self.make = tuple(names), make_predictor
        self.p: dict = {}
        self.n_fits = 0

    def step(self, t: float, fit: _StarFit | None, restart: bool) -> dict:
        """Predictions for ``t`` by predictors with three fits behind them, then the update."""
        if fit is None:
            self.p, self.n_fits = {}, 0
            return {}
        if restart or not self.p:
            self.p = {n: self.make(n, fit.A, t, fit.P, rate_sigma_rad_s=_DEG,
                                   **({"xy": fit.xy, "ids": fit.ids} if n == "small-angle" else {}))
                      for n in self.names}
            self.n_fits = 1
            return {}
        preds = {n: p.predict(t) for n, p in self.p.items()} if self.n_fits >= 3 else {}
        for p in self.p.values():
            p.update(t, fit.A, fit.P, xy=fit.xy, ids=fit.ids, camera=CAMERA)
        self.n_fits += 1
        return preds


@dataclass
class PredictionErrors:
    """One predictor's errors per frame (NaN where it did not predict)."""

    meas_px: np.ndarray       # mean |predicted − measured| over the frame's fitted stars
    true_px: np.ndarray       # mean |predicted − true|
    att_arcsec: np.ndarray    # (n, 3) δθ of the predicted attitude

    @classmethod
    def empty(cls, n: int) -> PredictionErrors:
        return cls(np.full(n, np.nan), np.full(n, np.nan), np.full((n, 3), np.nan))

    def record(self, k: int, A_pred: np.ndarray, fit: _StarFit, truth_xy: dict, A_true: np.ndarray) -> None:
        """Frame ``k``'s errors of the attitude ``A_pred`` predicted for it."""
        xy_pred = CAMERA.ray_to_pixel(fit.r @ A_pred.T)[0]
        self.meas_px[k] = float(np.mean(np.hypot(*(xy_pred - fit.xy).T)))
        have = np.array([i in truth_xy for i in fit.ids.tolist()])
        if have.any():
            xy_true = np.array([truth_xy[i] for i in fit.ids[have].tolist()])
            self.true_px[k] = float(np.mean(np.hypot(*(xy_pred[have] - xy_true).T)))
        self.att_arcsec[k] = attitude_error(A_true, A_pred) / _ARCSEC


@dataclass
class SequenceResult:
    """Per-frame records of one sequence (arcsec, °/s, ms; NaN where not solved)."""

    spec: SequenceSpec
    t_s: np.ndarray
    event: list
    mode: list
    tracked: np.ndarray        # mode "tracking" with stars fitted
    coasting: np.ndarray       # reported from the prediction alone
    n_matched: np.ndarray
    n_visible: np.ndarray
    err_track: np.ndarray      # (n, 3)
    sigma_track: np.ndarray    # (n, 3)
    nees_track: np.ndarray     # δθᵀ P⁻¹ δθ
    err_lis: np.ndarray        # (n, 3)
    n_lis: np.ndarray          # stars in the lost-in-space fit
    time_track_ms: np.ndarray
    time_lis_ms: np.ndarray
    rate_dps: np.ndarray       # (n, 3) truth
    accel_dps2: np.ndarray     # (n, 3) truth
    steady_accel: np.ndarray   # α constant over the three periods before the frame
    predictions: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        out = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in vars(self).items()
               if k not in ("spec", "predictions")}
        out["spec"] = self.spec._asdict()
        out["predictions"] = {n: {k: v.tolist() for k, v in vars(p).items()}
                              for n, p in self.predictions.items()}
        return out


def _accel(profile: Profile, t: np.ndarray, h: float = 1e-4) -> np.ndarray:
    """Angular acceleration (rad/s², camera frame) by a central difference of the profile's
    rate; below 1e-9 rad/s² (the difference's rounding) it is 0."""
    acc = (profile.rate(t + h) - profile.rate(t - h)) / (2 * h)
    return np.where(np.abs(acc) < 1e-9, 0.0, acc)


def run_sequence(spec: SequenceSpec, *, database=None) -> SequenceResult:
    """Track one sequence and solve each frame lost in space (module docstring)."""
    from skyfix.identify import default_database
    from skyfix.pipeline import solve
    from skyfix.track import Tracker

    db = default_database() if database is None else database
    exposure = spec.exposure_s if spec.exposure_s is not None else 1.0 / spec.fps
    tracker = Tracker(CAMERA, database=db, epoch=EPOCH, exposure_s=exposure)
    shadows = _Shadows(PREDICTOR_NAMES)
    rng = np.random.default_rng(spec.seed + 7)
    n = spec.n_frames
    nan3 = np.full((n, 3), np.nan)
    rec = dict(t_s=np.zeros(n), event=[], mode=[], tracked=np.zeros(n, bool), coasting=np.zeros(n, bool),
               n_matched=np.zeros(n, np.int64), n_visible=np.zeros(n, np.int64), err_track=nan3.copy(),
               sigma_track=nan3.copy(), nees_track=np.full(n, np.nan), err_lis=nan3.copy(),
               n_lis=np.zeros(n, np.int64),
               time_track_ms=np.full(n, np.nan), time_lis_ms=np.full(n, np.nan), rate_dps=nan3.copy(),
               accel_dps2=nan3.copy(), steady_accel=np.zeros(n, bool))
    preds = {p: PredictionErrors.empty(n) for p in PREDICTOR_NAMES}
    # thesis 002's predictor told frame times off by σ = time_error_s (module docstring)
    late = _Shadows(("small-angle",)) if spec.time_error_s > 0 else None
    late_name = f"small-angle, times ±{1e3 * spec.time_error_s:g} ms"
    if late is not None:
        preds[late_name] = PredictionErrors.empty(n)
    rng_time = np.random.default_rng(spec.seed + 9)
    T = 1.0 / spec.fps
    for k, (t, event, frame, profile, t_local) in enumerate(_frames(spec)):
        image = _blank(frame.image, rng) if event == "blank" else frame.image
        A_true = attitude_from_quaternion(frame.truth["quaternion_xyzw"])
        sol = tracker.update(image, t)
        t0 = time.perf_counter()
        lis = solve(image, camera=CAMERA, database=db, epoch=EPOCH)
        rec["time_lis_ms"][k] = 1e3 * (time.perf_counter() - t0)
        rec["t_s"][k] = t
        rec["event"].append(event)
        rec["mode"].append(sol.mode)
        rec["n_matched"][k] = sol.n_matched if sol.solved else 0
        rec["coasting"][k] = sol.solved and not sol.matches
        rec["tracked"][k] = sol.mode == "tracking" and sol.solved and bool(sol.matches)
        rec["n_visible"][k] = 0 if event == "blank" else _n_visible(frame.truth)
        rec["time_track_ms"][k] = sol.time_ms.get("total", np.nan)
        if sol.solved:
            e = attitude_error(A_true, sol.A_icrs_to_cam) / _ARCSEC
            P = np.asarray(sol.covariance_arcsec2)
            rec["err_track"][k], rec["sigma_track"][k] = e, np.sqrt(np.diag(P))
            rec["nees_track"][k] = float(e @ np.linalg.solve(P, e))
        if lis.solved:
            rec["err_lis"][k] = attitude_error(A_true, lis.A_icrs_to_cam) / _ARCSEC
            rec["n_lis"][k] = lis.n_matched
        rec["rate_dps"][k] = profile.rate(t_local) / _DEG
        back = t_local - T * np.arange(4)
        acc = _accel(profile, back)
        rec["accel_dps2"][k] = acc[0] / _DEG
        rec["steady_accel"][k] = bool(back[-1] >= 0 and np.ptp(acc, axis=0).max() < 1e-3 * _DEG)
        fit = _star_fit(sol)
        truth_xy = {s["id"]: (s["x"], s["y"]) for s in frame.truth["stars"]}
        for name, p in shadows.step(t, fit, restart=sol.mode == "lost").items():
            preds[name].record(k, p.A_icrs_to_cam, fit, truth_xy, A_true)
        if late is not None:
            label = t + float(np.clip(rng_time.normal(0.0, spec.time_error_s), -0.4 * T, 0.4 * T))
            for p in late.step(label, fit, restart=sol.mode == "lost").values():
                preds[late_name].record(k, p.A_icrs_to_cam, fit, truth_xy, A_true)
    return SequenceResult(spec=spec, predictions=preds, **rec)


# --- analyses of the records ---------------------------------------------------------------------
def _boresight(err: np.ndarray) -> np.ndarray:
    return np.hypot(err[:, 0], err[:, 1])


def recovery_frames(seq: SequenceResult, event: str) -> int | None:
    """Frames from a forced loss to the first frame tracked with stars again (None: no event;
    -1: never recovered)."""
    if event not in seq.event:
        return None
    k = seq.event.index(event)
    later = np.flatnonzero(seq.tracked[k:])
    return int(later[0]) if len(later) else -1


def accuracy_summary(seq: SequenceResult) -> dict:
    """Tracking against lost in space on the same frames (both solved; the tracker in tracking
    mode with stars), and which frames that should be tracked were not.

    A frame should be tracked when it shows ≥ 3 visible stars and is neither the first two of
    the sequence nor the two after the jump (lost in space, then acquiring, by design — but the
    frame after the jump is tracked when the jump frame was solved along the predicted streaks,
    which keeps the rate)."""
    n = len(seq.t_s)
    starting = np.zeros(n, bool)
    starting[:2] = True
    if "jump" in seq.event:
        j = seq.event.index("jump")
        starting[j:j + 2] = True
    eligible = (seq.n_visible >= 3) & ~starting
    both = seq.tracked & np.all(np.isfinite(seq.err_lis), axis=1)
    bt, bl = _boresight(seq.err_track[both]), _boresight(seq.err_lis[both])
    rt, rl = np.abs(seq.err_track[both, 2]), np.abs(seq.err_lis[both, 2])
    missed = np.flatnonzero(eligible & ~seq.tracked)

    def med(a):
        return float(np.median(a)) if len(a) else math.nan

    def p95(a):
        return float(np.percentile(a, 95)) if len(a) else math.nan

    return dict(name=seq.spec.name, frames=n, eligible=int(eligible.sum()),
                tracked_eligible=int((eligible & seq.tracked).sum()),
                missed=[(int(k), seq.mode[k]) for k in missed], coasting=int(seq.coasting.sum()),
                compared=int(both.sum()), lis_solved=int(np.all(np.isfinite(seq.err_lis), axis=1).sum()),
                bore_track=med(bt), bore_lis=med(bl), bore_track_p95=p95(bt), bore_lis_p95=p95(bl),
                roll_track=med(rt), roll_lis=med(rl), roll_track_p95=p95(rt), roll_lis_p95=p95(rl),
                recover_blank=recovery_frames(seq, "blank"), recover_jump=recovery_frames(seq, "jump"),
                ms_track=med(seq.time_track_ms[seq.tracked]), ms_lis=med(seq.time_lis_ms),
                stars_track=med(seq.n_matched[both]), stars_lis=med(seq.n_lis[both]))


def normalised_errors(seqs: Sequence[SequenceResult]) -> dict:
    """``δθ / σ`` per axis over every tracked frame of ``seqs``: RMS per axis (1 when the error
    bars are honest), the mean 3-axis NEES (3), and the share beyond 3σ (0.27 % for a normal)."""
    z = np.concatenate([s.err_track[s.tracked] / s.sigma_track[s.tracked] for s in seqs])
    nees = np.concatenate([s.nees_track[s.tracked] for s in seqs])
    return dict(n_frames=len(z), rms=np.sqrt(np.mean(z ** 2, axis=0)).tolist(),
                mean=np.mean(z, axis=0).tolist(), nees_mean=float(np.mean(nees)),
                beyond_3sigma=float(np.mean(np.abs(z) > 3)), z=z)


class SlopeFit(NamedTuple):
    """A straight line through per-bin statistics: ``slope`` px per (arcsec/s), ``intercept`` px."""

    statistic: str
    slope: float
    intercept: float


def _line(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 2 or np.ptp(x[ok]) == 0:
        return math.nan, math.nan
    slope, intercept = np.polyfit(x[ok], y[ok], 1)
    return float(slope), float(intercept)


def binned_fits(rate: np.ndarray, err: np.ndarray, n_bins: int = 6) -> tuple[list[SlopeFit], np.ndarray]:
    """Thesis Fig 5-8/5-9: bins of rate, mean and std of the error per bin (≥ 3 samples), lines
    through mean − std, mean, mean + std against the bins' mean rates. Few samples get fewer
    bins (at least 4 samples a bin, at least 2 bins)."""
    ok = np.isfinite(rate) & np.isfinite(err)
    rate, err = rate[ok], err[ok]
    n_bins = min(n_bins, len(rate) // 4)
    if n_bins < 2:
        return [SlopeFit(s, math.nan, math.nan) for s in THESIS_SLOPES], np.zeros((0, 4))
    edges = np.linspace(rate.min(), rate.max() + 1e-9, n_bins + 1)
    rows = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        m = (rate >= a) & (rate < b)
        if m.sum() >= 3:
            rows.append((rate[m].mean(), err[m].mean(), err[m].std(), m.sum()))
    bins = np.array(rows).reshape(-1, 4)
    fits = [SlopeFit(name, *_line(bins[:, 0], bins[:, 1] + sign * bins[:, 2]))
            for name, sign in zip(THESIS_SLOPES, (-1, 0, 1), strict=True)]
    return fits, bins


def rate_slopes(seq: SequenceResult, predictor: str, accel_filter: str = "abs", n_bins: int = 6,
                error: str = "meas_px") -> tuple[list[SlopeFit], np.ndarray]:
    """Thesis 002 §5.4.3 on a pendulum: prediction error against |pitch rate| (arcsec/s).

    ``accel_filter``: ``"thesis"`` keeps the samples whose pitch acceleration is ≤ μ − 1.5σ (as
    printed: the most negative ones), ``"abs"`` those with |α| ≤ half the largest (the small
    accelerations the thesis meant to keep), ``"none"`` all. Returns the three lines and the
    bins (mean rate, mean error, std, count)."""
    rate = np.abs(seq.rate_dps[:, 1]) * 3600.0
    acc = seq.accel_dps2[:, 1]
    err = getattr(seq.predictions[predictor], error)
    keep = np.isfinite(err)
    if accel_filter == "thesis":
        keep &= acc <= np.mean(acc[keep]) - 1.5 * np.std(acc[keep])
    elif accel_filter == "abs":
        keep &= np.abs(acc) <= 0.5 * np.max(np.abs(acc[keep]))
    elif accel_filter != "none":
        raise ValueError(f"unknown acceleration filter {accel_filter!r}")
    return binned_fits(rate[keep], err[keep], n_bins)


def error_correlations(seq: SequenceResult, predictor: str, error: str = "meas_px") -> dict:
    """Thesis 002 §5.4 (Figs 5-5, 5-6): the correlation of the prediction error with |α| and with
    |ω| (the pitch axis), and how many frames have an error."""
    err = getattr(seq.predictions[predictor], error)
    ok = np.isfinite(err)
    rate, acc = np.abs(seq.rate_dps[ok, 1]), np.abs(seq.accel_dps2[ok, 1])
    if ok.sum() < 3:
        return dict(accel=math.nan, rate=math.nan, n=int(ok.sum()))
    return dict(accel=float(np.corrcoef(err[ok], acc)[0, 1]), rate=float(np.corrcoef(err[ok], rate)[0, 1]),
                n=int(ok.sum()))


def time_error_slope(sigma_s: float) -> float:
    """Growth of the mean prediction error with the rate, px per arcsec/s, when a held-rate
    predictor is told frame times each off by an independent σ: the turn it predicts is off by
    ``ω (δₖ − 2δₖ₋₁ + δₖ₋₂)`` (the rate from the last interval applied over the next), whose mean
    magnitude is ``√(12/π) σ |ω|``."""
    return math.sqrt(12.0 / math.pi) * sigma_s / (CAMERA.plate_scale_rad / _ARCSEC)


def constant_rate_slopes(seqs: Sequence[SequenceResult], predictor: str, error: str = "meas_px") -> dict:
    """Per constant-rate sequence: mean and std of the prediction error (frames before the jump),
    and the line through the means against the rate (px per arcsec/s)."""
    rows = []
    for s in seqs:
        if s.spec.profile != "constant":
            continue
        stop = s.event.index("jump") if "jump" in s.event else len(s.t_s)
        e = getattr(s.predictions[predictor], error)[:stop]
        e = e[np.isfinite(e)]
        rate = float(np.linalg.norm(s.rate_dps[0])) * 3600.0
        mean, std = (float(np.mean(e)), float(np.std(e))) if len(e) else (math.nan, math.nan)
        rows.append((rate, mean, std, len(e)))
    rows.sort()
    a = np.array(rows, dtype=np.float64).reshape(-1, 4)
    slope, intercept = _line(a[:, 0], a[:, 1])
    return dict(rows=rows, slope=slope, intercept=intercept)


def accel_terms(seqs: Sequence[SequenceResult], predictor: str) -> tuple[np.ndarray, np.ndarray]:
    """``a = α T²`` and the prediction's ``δθ`` (arcsec), cross-boresight (x, y), on the frames
    under a steady acceleration; (n, 2) each."""
    a_all, d_all = [], []
    for s in seqs:
        T = 1.0 / s.spec.fps
        p = s.predictions[predictor]
        m = s.steady_accel & np.all(np.isfinite(p.att_arcsec), axis=1)
        a_all.append(s.accel_dps2[m, :2] * 3600.0 * T ** 2)
        d_all.append(p.att_arcsec[m, :2])
    return np.concatenate(a_all).reshape(-1, 2), np.concatenate(d_all).reshape(-1, 2)


def accel_slopes(seqs: Sequence[SequenceResult], predictor: str) -> dict:
    """The prediction's ``δθ`` against ``a = α T²`` on frames under a steady acceleration, across
    the boresight (the roll of a prediction is tens of arcseconds noisier and the relation is the
    same on every axis): the least-squares ratio ``Σ δθ·a / Σ a·a`` (1 for a held rate, ½ for
    thesis 004's weights, 0 for the exact quadratic), the RMS about ``ratio·a``, and what the
    ratio means in pixels at 1 °/s² and the sequences' frame rate (``ratio·αT²`` over the plate
    scale)."""
    a, d = accel_terms(seqs, predictor)
    moving = np.linalg.norm(a, axis=1) > 0
    analytic = ANALYTIC_ACCEL_RATIO.get(predictor)
    if not moving.any():
        return dict(ratio=math.nan, residual_arcsec=math.nan, n=0, n_rest=len(a), px_at_1dps2=math.nan,
                    analytic=analytic)
    ratio = float(np.sum(d * a) / np.sum(a * a))
    resid = d - ratio * a
    fps = next(s.spec.fps for s in seqs if np.any(s.steady_accel & (np.abs(s.accel_dps2).max(axis=1) > 0)))
    px = ratio * 3600.0 / fps ** 2 / (CAMERA.plate_scale_rad / _ARCSEC)
    return dict(ratio=ratio, residual_arcsec=float(np.sqrt(np.mean(resid ** 2))), n=int(moving.sum()),
                n_rest=int((~moving).sum()), px_at_1dps2=px, analytic=analytic)


# --- the whole study --------------------------------------------------------------------------------
@dataclass
class TrackingStudy:
    """Every sequence's records (the pendulum last), the Table 5-1 rows, and the settings."""

    sequences: list
    timing: list
    settings: dict

    def by_name(self, name: str) -> SequenceResult:
        return next(s for s in self.sequences if s.spec.name == name)

    @property
    def accuracy_sequences(self) -> list:
        return [s for s in self.sequences if s.spec.profile != "pendulum"]
