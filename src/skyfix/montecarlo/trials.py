"""One Monte Carlo trial: simulate → solve → compare, a pure function of (campaign, trial index).

**Seeding.** Trial ``i`` of a campaign seeded ``s`` has the seed
``SeedSequence(s, spawn_key=(i,))``'s first 63 bits (:func:`trial_seed`, the ``seed`` column),
split into four independent streams: the true attitude, the drawn ``{min, max}`` parameters,
the simulation's noise and what the solver is told wrong (calibration and time-stamp errors).
Nothing else is random, so a trial's result does not depend on which worker runs it, in which
batch or in which order; ``run_trial(campaign, i)`` replays trial ``i``.

**Levels.** ``centroid``: the catalogue stars in view to ``mag_limit``, with centroid noise,
missed stars, false stars and magnitude noise
(:func:`skyfix.analysis.synthetic_centroids.synthetic_centroids`), solved by
:func:`skyfix.pipeline.solve_centroids` — no image, a few ms a trial. ``image``: the frame
rendered by :func:`skyfix.simulate.render` with the camera's sensor and optics, solved by
:func:`skyfix.pipeline.solve`.

**Judging** is the one definition of :mod:`skyfix.analysis.truth`: the error rotation at the
solution's boresight pixel, wrong beyond max(60″, 1 px) in boresight or 0.5° in roll. The
normalised error divides each axis by the σ the solution reports; at the centroid level the
predicted σ is the Cramér–Rao bound of the true stars in the frame
(:func:`skyfix.montecarlo.budget.predicted_covariance_rad2`).
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from skyfix.camera import Camera
from skyfix.montecarlo.campaign import Campaign

__all__ = ["EARTH_RATE_RAD_S", "LEVEL_TRIALS", "CampaignTrials", "Setup", "Simulated", "TrialInput",
           "run_batch", "run_trial", "setup_for", "stamped_attitude", "told_camera", "trial_seed",
           "trial_values", "true_attitude"]

_ARCSEC = math.pi / (180.0 * 3600.0)
_STREAMS = ("attitude", "parameters", "noise", "told")  # spawn order: never reorder (it changes every draw)
#: The Earth's sidereal rotation rate, rad/s (a fixed ground camera's attitude turns at it).
EARTH_RATE_RAD_S = 7.2921150e-5
_CATALOG_MARGIN_MAG = 0.5


def trial_seed(campaign_seed: int, trial: int) -> int:
    """The seed of trial ``trial`` (0 ≤ seed < 2⁶³; see the module text)."""
    word = np.random.SeedSequence(int(campaign_seed), spawn_key=(int(trial),)).generate_state(1, np.uint64)[0]
    return int(word >> np.uint64(1))


class _Streams(dict):
    """A trial's random streams by name (:data:`_STREAMS`), each made when first asked for: child
    ``k`` is ``SeedSequence(seed).spawn(4)[k]`` (the same ``SeedSequence(seed, spawn_key=(k,))``),
    so a trial that never draws from a stream does not pay for it (~15 µs each) and the draws
    are those of spawning all four."""

    def __init__(self, seed: int) -> None:
        super().__init__()
        self.seed = seed

    def __missing__(self, name: str) -> np.random.Generator:
        child = np.random.SeedSequence(self.seed, spawn_key=(_STREAMS.index(name),))
        self[name] = rng = np.random.default_rng(child)
        return rng


def _streams(seed: int) -> _Streams:
    return _Streams(seed)


def trial_values(campaign: Campaign, trial: int, rng: Mapping[str, np.random.Generator] | np.random.Generator
                 ) -> dict[str, Any]:
    """Every parameter's value in trial ``trial``: fixed, grid point, then the drawn axes in
    file order from ``rng`` (the trial's parameter stream, or its streams: the stream is then
    made only if an axis is drawn)."""
    values = dict(campaign.fixed)
    values.update(campaign.grid_point(trial))
    for axis in campaign.sweep:
        if axis.drawn:
            if isinstance(rng, Mapping):
                rng = rng["parameters"]
            values[axis.name] = float(rng.uniform(axis.low, axis.high))
    return {name: values[name] for name in campaign.parameter_names}


def true_attitude(campaign: Campaign, trial: int, rng: np.random.Generator | None, profile=None
                  ) -> tuple[np.ndarray, np.ndarray | None]:
    """The true attitude (3, 3) of trial ``trial`` and the body rate (rad/s, camera axes) a
    motion profile has then (None otherwise). ``uniform``: uniform over SO(3) from ``rng``;
    ``scan``: the boresight at 360°·i/trials along the great circle about ``pole_deg``, roll
    ``roll_deg``; ``profile``: the profile of :mod:`skyfix.simulate.profiles` from ``start_deg``
    at t = i · ``frame_period_s`` (``profile``: that profile, made already)."""
    from skyfix.geometry import attitude_from_radec_roll, radec_to_vector, vector_to_radec

    opts = campaign.attitude_options
    if campaign.attitude == "uniform":
        from skyfix.analysis.synthetic_centroids import random_attitudes

        return random_attitudes(1, rng)[0], None
    if campaign.attitude == "scan":
        pole = radec_to_vector(*np.radians(opts["pole_deg"]))
        u = np.cross(pole, [0.0, 0.0, 1.0] if abs(pole[2]) < 0.9 else [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        phi = 2.0 * math.pi * trial / campaign.trials
        ra, dec = vector_to_radec(math.cos(phi) * u + math.sin(phi) * np.cross(pole, u))
        return attitude_from_radec_roll(float(ra), float(dec), math.radians(opts["roll_deg"])), None
    profile = profile or campaign.profile()
    t = trial * opts["frame_period_s"]
    return profile.attitude(t), profile.rate(t)


class Setup(NamedTuple):
    """What every trial of a campaign shares, made once per worker (:func:`setup_for`): the
    camera, its sensor, optics and exposure, the catalogue (to the faintest ``mag_limit``), its
    rows by star number, and the motion profile."""

    camera: Camera
    sensor: Any
    optics: Any
    exposure_s: float
    catalog: Any
    row_of_id: tuple[np.ndarray, np.ndarray]  # sorted ids, their rows
    profile: Any
    calibration_sigma: dict[str, float]  # the camera's [calibration.sigma]


_SETUPS: dict[str, Setup] = {}
_SETUP_LOCK = threading.Lock()


def setup_for(campaign: Campaign) -> Setup:
    """The campaign's :class:`Setup`, cached per process (threads of one worker share it)."""
    key = campaign.fingerprint
    with _SETUP_LOCK:
        if key not in _SETUPS:
            _SETUPS.clear()  # one campaign at a time per worker
            _SETUPS[key] = _make_setup(campaign)
        return _SETUPS[key]


def _make_setup(campaign: Campaign) -> Setup:
    from skyfix.montecarlo.campaign import calibration_sigma
    from skyfix.simulate import resolve_setup

    camera, sensor, optics, exposure_s = resolve_setup(campaign.camera, None, None, None)
    catalog, rows = None, (np.zeros(0, np.int64), np.zeros(0, np.int64))
    if campaign.level == "centroid":
        from skyfix.catalog import load_hipparcos

        faintest = max([campaign.fixed.get("mag_limit", 0.0)]
                       + [v for a in campaign.sweep if a.name == "mag_limit" for v in (*a.values, a.high)
                          if math.isfinite(v)])
        catalog = load_hipparcos(epoch=campaign.epoch, mag_limit=faintest + _CATALOG_MARGIN_MAG)
        order = np.argsort(catalog.ids, kind="stable")
        rows = (catalog.ids[order], order)
    profile = campaign.profile() if campaign.attitude == "profile" else None
    return Setup(camera, sensor, optics, exposure_s, catalog, rows, profile,
                 calibration_sigma(campaign.camera))


def trial_camera(setup: Setup, values: dict[str, Any]) -> Camera:
    """The true camera of a trial: the campaign's, or with ``fov_deg`` set a distortion-free one
    of that field and the same size."""
    if values["fov_deg"]:
        return Camera.from_fov(setup.camera.width, setup.camera.height, values["fov_deg"],
                               projection=setup.camera.projection)
    return setup.camera


def told_camera(camera: Camera, values: dict[str, Any], sigma: dict[str, float],
                rng: Mapping[str, np.random.Generator] | np.random.Generator) -> Camera:
    """The camera the solver is told: ``camera`` with the focal length off by ``focal_error``,
    each coefficient of ``sigma`` (its 1σ) off by ``calibration_error`` × σ × a Gaussian draw
    (in sorted order, from ``rng``: the trial's ``told`` stream, or its streams), and the radial
    distortion times ``1 + distortion_error``."""
    told, scale = camera, 1.0 + values["focal_error"]
    if scale != 1.0:
        told = dataclasses.replace(camera, fx=camera.fx * scale, fy=camera.fy * scale)
    if values["calibration_error"]:
        if isinstance(rng, Mapping):
            rng = rng["told"]
        known = {f.name for f in dataclasses.fields(Camera)}
        told = dataclasses.replace(told, **{
            k: getattr(told, k) + values["calibration_error"] * sigma[k] * float(rng.standard_normal())
            for k in sorted(sigma) if k in known})
    if values["distortion_error"]:
        f = 1.0 + values["distortion_error"]
        told = dataclasses.replace(told, k1=told.k1 * f, k2=told.k2 * f, k3=told.k3 * f)
    return told


def stamped_attitude(A: np.ndarray, error_s: float) -> np.ndarray:
    """The attitude a camera fixed on the ground has ``error_s`` seconds later: ``A`` turned by
    the Earth's rotation about the ICRS pole (precession over seconds left out)."""
    c, s = math.cos(EARTH_RATE_RAD_S * error_s), math.sin(EARTH_RATE_RAD_S * error_s)
    return A @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _solver_options(campaign: Campaign, values: dict[str, Any], camera: Camera, told: Camera,
                    A: np.ndarray) -> dict[str, Any]:
    """What the solver is told (``given``: the told camera, or its field; ``hint``: the true
    attitude ``A`` or none) and how it searches."""
    from skyfix.identify import method_options

    opts: dict[str, Any] = dict(epoch=campaign.epoch, identify_method=values["identify_method"],
                                attitude_method=values["attitude_method"],
                                prob_threshold=values["prob_threshold"])
    known = method_options(values["identify_method"])  # a method without a time limit or lone frames
    if "time_limit_s" in known:
        opts["time_limit_s"] = values["time_limit_s"]
    if values["lone_prob_threshold"] and "lone_prob_threshold" in known:
        opts["lone_prob_threshold"] = values["lone_prob_threshold"]
    if values["given"] == "camera":
        opts["camera"] = told
    elif values["given"] == "fov":
        opts["fov_deg"] = camera.fov_deg / (1.0 + values["focal_error"])
    if values["hint"] == "truth":
        opts["attitude_hint"] = A
    if values.get("sigma_known"):
        opts["centroid_sigma_px"] = max(values["sigma_px"], 1e-3)
    return opts


def run_trial(campaign: Campaign, trial: int, setup: Setup | None = None) -> dict[str, Any]:
    """Trial ``trial`` of ``campaign``: one results row (:data:`skyfix.montecarlo.results.COLUMNS`)
    (``setup``: the campaign's :func:`setup_for`, when the caller has it already)."""
    setup = setup or setup_for(campaign)
    seed = trial_seed(campaign.seed, trial)
    rng = _streams(seed)
    values = trial_values(campaign, trial, rng)
    A, rate = true_attitude(campaign, trial, rng["attitude"] if campaign.attitude == "uniform" else None,
                            setup.profile)
    camera = trial_camera(setup, values)
    row: dict[str, Any] = {"trial": trial, "seed": seed, **values}
    from skyfix.geometry import radec_roll_from_attitude

    row["ra_true_deg"], row["dec_true_deg"], row["roll_true_deg"] = np.degrees(radec_roll_from_attitude(A))
    row["plate_scale_arcsec"] = camera.plate_scale_rad / _ARCSEC
    told = told_camera(camera, values, setup.calibration_sigma, rng)
    A_truth = A  # what the truth says: a fixed mount's attitude at the stamped time
    if values["timestamp_error_s"]:
        A_truth = stamped_attitude(A, values["timestamp_error_s"] * float(rng["told"].standard_normal()))
    try:
        sol, t_sim, n_stars, predicted, true_ids = LEVEL_TRIALS[campaign.level](
            TrialInput(campaign, setup, values, A, rate, camera, told, seed, rng))
    except Exception as exc:  # a bug in a stage: the trial is kept, with what went wrong
        first = (str(exc).strip().splitlines() or [""])[0]
        return _failed(row, "error", f"{type(exc).__name__}: {first}")
    row.update(n_stars=n_stars, n_detected=sol.n_detected, simulate_ms=t_sim, time_ms=sol.time_ms["wall"])
    row.update(zip(("predicted_sigma_x_arcsec", "predicted_sigma_y_arcsec", "predicted_sigma_roll_arcsec"),
                   predicted, strict=True))
    if not sol.solved:
        return _failed(row, "failed", sol.reason)
    return _judged(row, sol, A_truth, camera, true_ids)


class TrialInput(NamedTuple):
    """What a level's simulate-and-solve gets: the campaign, the worker's :class:`Setup`, the
    trial's parameter values, true attitude and rate, true camera, the camera told the solver,
    seed and random streams."""

    campaign: Campaign
    setup: Setup
    values: dict[str, Any]
    A: np.ndarray
    rate: np.ndarray | None
    camera: Camera
    told: Camera
    seed: int
    rng: dict[str, np.random.Generator]


class Simulated(NamedTuple):
    """A level's simulate-and-solve: the Solution (its ``time_ms["wall"]`` the solve's), the
    simulation's ms, the stars in the frame, the predicted σ (x, y, roll) ″ (NaN: none) and each
    centroid's true star number by its (x, y) (0: a false star; None: not known)."""

    solution: Any
    simulate_ms: float
    n_stars: int
    predicted_sigma_arcsec: tuple[float, float, float]
    true_ids: dict[tuple[float, float], int] | None = None


def _centroid_solve(t: TrialInput) -> Simulated:
    """Centroid level: synthetic centroids, :func:`skyfix.pipeline.solve_centroids`."""
    campaign, setup, values, A, camera = t.campaign, t.setup, t.values, t.A, t.camera
    from skyfix.analysis.synthetic_centroids import synthetic_centroids
    from skyfix.montecarlo.budget import predicted_covariance_rad2
    from skyfix.pipeline import solve_centroids

    t0 = time.perf_counter()
    field = synthetic_centroids(camera, A, setup.catalog, mag_limit=values["mag_limit"],
                                sigma_px=values["sigma_px"], n_false=values["false_stars"],
                                dropout=values["dropout"], mag_sigma=values["mag_sigma"], rng=t.rng["noise"])
    real = field.star_id > 0
    ids, rows = setup.row_of_id
    b_true = setup.catalog.vectors[rows[np.searchsorted(ids, field.star_id[real])]] @ A.T
    predicted = np.sqrt(np.diag(predicted_covariance_rad2(camera, b_true, values["sigma_px"]))) / _ARCSEC
    t_sim = 1e3 * (time.perf_counter() - t0)
    t0 = time.perf_counter()
    sol = solve_centroids(field.xy, camera.width, camera.height,
                          **_solver_options(campaign, values, camera, t.told, A))
    sol.time_ms["wall"] = 1e3 * (time.perf_counter() - t0)
    return Simulated(sol, t_sim, int(real.sum()), tuple(predicted),
                     dict(zip(map(tuple, field.xy.tolist()), field.star_id.tolist(), strict=True)))


def _image_solve(t: TrialInput) -> Simulated:
    """Image level: :func:`skyfix.simulate.render`, :func:`skyfix.pipeline.solve`."""
    campaign, setup, values, A, rate, camera = t.campaign, t.setup, t.values, t.A, t.rate, t.camera
    from skyfix.pipeline import solve
    from skyfix.simulate import render
    from skyfix.simulate.atmosphere import Atmosphere

    if values["rate_dps"]:
        axis = t.rng["parameters"].normal(size=3)
        turn = math.radians(values["rate_dps"]) * axis / np.linalg.norm(axis)
        rate = turn if rate is None else rate + turn
    t0 = time.perf_counter()
    optics = setup.optics.replace(psf_growth_edge=values["psf_growth"])
    air = Atmosphere(values["seeing_arcsec"], values["scintillation"], values["airmass"],
                     values["altitude_m"])
    frame = render(A, camera, sensor=setup.sensor, optics=optics,
                   exposure_s=values["exposure_s"] or setup.exposure_s, epoch=campaign.epoch, rate_rad_s=rate,
                   seed=t.seed, false_stars=values["false_stars"], hot_pixels=values["hot_pixels"],
                   atmosphere=air, jpeg_quality=values["jpeg_quality"] or None,
                   mag_limit=values["render_mag_limit"] or None)
    t_sim = 1e3 * (time.perf_counter() - t0)
    t0 = time.perf_counter()
    sol = solve(frame.image, max_stars=values["max_stars"],
                **_solver_options(campaign, values, camera, t.told, A))
    sol.time_ms["wall"] = 1e3 * (time.perf_counter() - t0)
    return Simulated(sol, t_sim, len(frame.truth["stars"]), (math.nan,) * 3)


#: Each level's simulate-and-solve (a new level, a tracked sequence say, registers here and in
#: :data:`skyfix.montecarlo.campaign.LEVELS`).
LEVEL_TRIALS = {"centroid": _centroid_solve, "image": _image_solve}


def _failed(row: dict[str, Any], status: str, reason: str) -> dict[str, Any]:
    row.update(status=status, reason=reason, wrong=False)
    return row


def _judged(row: dict[str, Any], sol, A: np.ndarray, camera: Camera,
            true_ids: dict[tuple[float, float], int] | None) -> dict[str, Any]:
    from skyfix.analysis.truth import judge

    j = judge(sol.A_icrs_to_cam, sol.camera, A, camera)
    err = j.error_rad / _ARCSEC
    sigma = np.sqrt(np.diag(np.asarray(sol.frame_covariance_arcsec2, dtype=np.float64)))  # the error's pixel
    if true_ids is not None:  # the matches whose catalogue star is not the centroid's own
        row["n_mismatched"] = sum(true_ids.get((m.x, m.y), -1) != m.id for m in sol.matches)
    row.update(status="solved", reason="", wrong=j.wrong, n_matched=sol.n_matched, prob_false=sol.prob_false,
               ra_deg=sol.ra_deg, dec_deg=sol.dec_deg, roll_deg=sol.roll_deg,
               boresight_error_arcsec=j.boresight_arcsec, roll_error_arcsec=j.roll_deg * 3600.0)
    for k, axis in enumerate(("x", "y", "roll")):
        row[f"error_{axis}_arcsec"] = err[k]
        row[f"sigma_{axis}_arcsec"] = sigma[k]
        row[f"normalised_{axis}"] = err[k] / sigma[k]
    return row


def run_batch(campaign: Campaign, batch: int) -> list[dict[str, Any]]:
    """The rows of batch ``batch`` (trials :meth:`Campaign.batch_trials`), in trial order."""
    setup = setup_for(campaign)
    return [run_trial(campaign, i, setup) for i in campaign.batch_trials(batch)]


@dataclasses.dataclass(frozen=True)
class CampaignTrials:
    """A campaign file as the engine's :class:`skyfix.montecarlo.study.Study`: its batches run
    :func:`run_batch`, its rows have :func:`skyfix.montecarlo.results.schema`."""

    campaign: Campaign

    @property
    def trials(self) -> int:
        return self.campaign.trials

    @property
    def batch_size(self) -> int:
        return self.campaign.batch_size

    @property
    def n_batches(self) -> int:
        return self.campaign.n_batches

    @property
    def fingerprint(self) -> str:
        return self.campaign.fingerprint

    def batch_trials(self, batch: int) -> range:
        return self.campaign.batch_trials(batch)

    def to_dict(self) -> dict:
        return self.campaign.to_dict()

    def schema(self):
        from skyfix.montecarlo.results import schema

        return schema(self.campaign)

    def run_batch(self, batch: int) -> list[dict[str, Any]]:
        return run_batch(self.campaign, batch)

    def warm(self) -> None:
        """Compile (or load) the kernels the trials need once, before the workers start."""
        from skyfix import warmup

        c = self.campaign
        methods = {c.fixed.get("identify_method")} | {v for a in c.sweep if a.name == "identify_method"
                                                       for v in a.values}
        paths = ["solve", *(["simulate"] if c.level == "image" else []),
                 *(f"method-{m}" for m in sorted(m for m in methods if m))]
        warmup.ensure(paths, missing_ok=True)
