"""Star-field calibration over many images: ``skyfix calibrate stars``.

1. **Each image is solved** lost in space (:func:`skyfix.solve_centroids`, no camera needed),
   from up to ``max_stars`` centroids; an image that does not solve, or matches fewer than
   :data:`MIN_STARS` stars, is an error naming it.
2. **One camera and one attitude per image** are fitted to every matched star at once
   (:func:`skyfix.calibration.joint.fit_joint`: robust Gauss–Newton, then least squares on the
   inliers; the 1σ of each camera number from the Jacobian).
3. **The model is chosen by the Bayesian information criterion** along the chosen family's
   ladder (:data:`CALIBRATION_MODELS`, simplest first), and **parameters the data cannot
   constrain are refused** — held at their defaults, with the reason kept
   (:attr:`StarCalibration.refused`): the principal point when its 1σ exceeds
   :data:`PRINCIPAL_POINT_SIGMA_PX`, a distortion coefficient (or the skew, or the pixel aspect)
   within :data:`SIGNIFICANCE` σ of its default. (Thesis 003 fixed a coefficient at 0 when its
   toolbox's printed uncertainty — about 3σ — exceeded its value.)
4. **The stars are re-identified** through the improved camera — the catalogue projected into
   each image, each centroid paired with its nearest prediction within
   ``max(REMATCH_SIGMA·σ, REMATCH_FLOOR_PX)`` when the pairing is mutual — and 2–4 repeat until
   the matches stop changing (at most ``max_rounds``).

"Before" is the uncalibrated camera: the pinhole of the images' median focal length, centred,
no distortion, fitted (focal length and attitudes) to the same stars with every star counted
(:attr:`StarCalibration.before`); each image's own blind solve (its own camera fitted under the
prior, :mod:`skyfix.final_fit`) is :attr:`StarCalibration.solve_rms_arcsec`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

import skyfix
from skyfix.calibration.camera_file import camera_file
from skyfix.calibration.joint import SKEW, JointFit, MatchedImage, fit_joint, numbers_of_parameters
from skyfix.camera import Camera
from skyfix.errors import CalibrationError, InputError, unknown_name
from skyfix.geometry import radec_to_vector, rotation_angle_between

if TYPE_CHECKING:
    from skyfix.corrections.observation import Observation

__all__ = ["CALIBRATION_MODELS", "MIN_IMAGES", "MIN_STARS", "PRINCIPAL_POINT_SIGMA_PX", "REMATCH_FLOOR_PX",
           "REMATCH_SIGMA", "SAME_FIELD_DEG", "SIGNIFICANCE", "CalibrationModel", "StarCalibration",
           "StarFrame", "calibrate_frames", "calibrate_stars", "calibration_model", "check_not_one_field",
           "choose_model", "CALIBRATION_CENTROIDER", "frame_catalogues", "ground_observation",
           "parameter_table", "prepare_frames", "rematch_frame", "seen_directions", "solution_matches"]

MIN_IMAGES = 3
"""Fewest images a star calibration takes (one image pins a pinhole down in principle, but its
pointing and the principal point trade off; three at different pointings separate them)."""
MIN_STARS = 8
"""Fewest matched stars an image must give (its three rotations and a share of the camera)."""
PRINCIPAL_POINT_SIGMA_PX = 2.0
"""A principal point known worse than this (1σ, px, either axis) is refused: held at the centre."""
SIGNIFICANCE = 2.0
"""A coefficient within this many σ of its default (0; the aspect 1) is refused: held there."""
REMATCH_SIGMA = 5.0
REMATCH_FLOOR_PX = 1.5
"""Re-identification pairs a centroid with a catalogue star predicted within
``max(REMATCH_SIGMA·σ, REMATCH_FLOOR_PX)`` px (σ the fit's per-axis residual)."""
SAME_FIELD_DEG = 0.05
"""Images whose attitudes all lie within this of the first are one field: they cannot separate
the camera from the pointing (a degenerate set)."""


@dataclass(frozen=True)
class CalibrationModel:
    """A family of camera models: its projection and its ladder of parameter sets, simplest
    first, each holding the one before (:data:`skyfix.calibrate.CAMERA_PARAMETERS` names).

    (This module's records are dataclasses, not NamedTuples, as :mod:`.joint`'s are: the tracker
    imports this module, and the kernel cache's digest of every kernel module the tracker imports
    takes in the NamedTuples of the tracker's imports — an edit here would drop them all.)"""

    projection: str
    ladder: tuple[tuple[str, ...], ...]
    doc: str


_BASE = ("f", "aspect", "principal_point")
# The registry of calibration models, chosen by name (``--model``).
CALIBRATION_MODELS: dict[str, CalibrationModel] = {
    "pinhole": CalibrationModel("pinhole", (_BASE,), "fx, fy, cx, cy; no distortion"),
    "brown-conrady": CalibrationModel(
        "pinhole", (_BASE, _BASE + ("k1",), _BASE + ("k1", "k2"), _BASE + ("k1", "k2", "tangential"),
                    _BASE + ("k1", "k2", "tangential", "k3")),
        "fx, fy, cx, cy and OpenCV's k1, k2, k3, p1, p2, as many as the stars support"),
    "fisheye": CalibrationModel(
        "kannala-brandt", (_BASE, _BASE + ("k1",), _BASE + ("k1", "k2"), _BASE + ("k1", "k2", "k3"),
                           _BASE + ("k1", "k2", "k3", "k4")),
        "Kannala–Brandt (OpenCV cv::fisheye) fx, fy, cx, cy and k1 … k4, as many as the stars support"),
}

# The coefficients refused when within SIGNIFICANCE σ of their default: parameter → its numbers'
# defaults.
_DEFAULTS = {"k1": {"k1": 0.0}, "k2": {"k2": 0.0}, "k3": {"k3": 0.0}, "k4": {"k4": 0.0},
             "tangential": {"p1": 0.0, "p2": 0.0}, SKEW: {"skew": 0.0}}


@dataclass(frozen=True)
class StarFrame:
    """An image ready to calibrate: its name, size, centroids (N, 2) brightest first, their flux
    (N,), its blind solution (:class:`skyfix.solution.Solution`), and the circumstances it was
    taken in (:class:`skyfix.corrections.observation.Observation`, None: unknown) — with a time
    and a site, the catalogue is fitted as the camera saw it (aberrated, refracted:
    :func:`seen_directions`)."""

    name: str
    width: int
    height: int
    xy: np.ndarray
    flux: np.ndarray
    solution: object
    observation: Observation | None = None


@dataclass(frozen=True)
class StarCalibration:
    """The result of :func:`calibrate_frames`.

    Attributes
    ----------
    fit : JointFit — the calibrated camera, attitudes and residuals.
    before : JointFit — the uncalibrated pinhole fitted to the same stars (every star counted).
    model : str — the family (:data:`CALIBRATION_MODELS`).
    scores : dict — BIC of each parameter set tried (the ladder).
    refused : dict — parameter → why it was held (not constrained, not significant).
    rounds : int — fit / re-identification rounds.
    solve_rms_arcsec : (M,) — each image's RMS from its own blind solve.
    observation : Observation or None — the images' time and site the catalogue was corrected
        for (:func:`ground_observation`; None: the catalogue's places were fitted).
    """

    fit: JointFit
    before: JointFit
    model: str
    scores: dict = field(repr=False)
    refused: dict
    rounds: int
    solve_rms_arcsec: np.ndarray = field(repr=False)
    observation: Observation | None = field(default=None, repr=False)

    @property
    def camera(self) -> Camera:
        return self.fit.camera

    def boresights_altaz(self) -> list | None:
        """Each image's fitted boresight as :class:`~skyfix.corrections.refraction.AltAz` (observed
        altitude and azimuth, degrees) when a site and time were given, else None: a check of the
        time given (a camera's commanded Alt/Az against these)."""
        obs = self.observation
        if obs is None or obs.ground is None:
            return None
        from skyfix.corrections.refraction import altaz_of

        return [altaz_of(A[2], obs.ground) for A in self.fit.attitudes]

    def to_toml(self) -> str:
        """The camera file: the ``[camera]`` table (:meth:`Camera.to_toml`, read back bit for bit)
        and a ``[calibration]`` table of how it was made — each number's 1σ, the residuals."""
        fit = self.fit
        table: dict[str, object] = {
            "method": "stars", "model": self.model, "parameters": list(fit.params),
            "images": len(fit.attitudes), "stars": fit.n_stars, "sigma_px": fit.sigma_px,
            "rms_arcsec": float(np.sqrt(np.nanmean(fit.rms_arcsec() ** 2)))}
        if self.refused:
            table["refused"] = list(self.refused)
        obs = self.observation
        if obs is not None:
            table["corrections"] = list(obs.applied)
            if obs.time.known:
                table["time"] = obs.time.iso
            if obs.site is not None:
                table["site"] = [obs.site.lat_deg, obs.site.lon_deg, obs.site.height_m]
                table["refraction"] = obs.refraction
        return camera_file(self.camera, table, fit.sigma)


def _read(image: str | Path | np.ndarray, index: int) -> tuple[str, np.ndarray]:
    from skyfix.io import read_image

    if isinstance(image, np.ndarray):
        return f"image {index + 1}", read_image(image)
    return str(image), read_image(image)


CALIBRATION_CENTROIDER = "gaussian"
"""The centroider a star calibration extracts with by default (:data:`skyfix.detect.CENTROIDERS`):
a calibration runs once, offline, and the Gaussian fit's centroids are the most precise — on the
8 ESA frames σ 0.161 → 0.122 px per axis, the calibrated residual RMS 9.3 → 7.1″, against the
thresholded centre of mass a solve uses (docs/calibration.md)."""


def prepare_frames(images: Sequence[str | Path | np.ndarray], *, max_stars: int = 300,
                   fov_deg: float | None = None, centroid: str = CALIBRATION_CENTROIDER,
                   observation: Observation | None = None) -> list[StarFrame]:
    """Read, extract (with the centroider ``centroid``) and solve each image lost in space
    (:class:`StarFrame`), under ``observation`` when one is given (:func:`ground_observation`:
    every image's time and site; the solve's final fit and the calibration then fit the catalogue
    as the camera saw it).

    Raises :class:`~skyfix.errors.CalibrationError` naming the image for too few images, images
    of different sizes, an image that does not solve or matches fewer than :data:`MIN_STARS`."""
    from skyfix.detect import extract_centroids

    if len(images) < MIN_IMAGES:
        raise CalibrationError(f"a star calibration needs at least {MIN_IMAGES} images, got {len(images)}")
    frames: list[StarFrame] = []
    for i, image in enumerate(images):
        name, data = _read(image, i)
        h, w = data.shape
        if frames and (w, h) != (frames[0].width, frames[0].height):
            raise CalibrationError(f"{name}: {w}×{h}, but {frames[0].name} is "
                                   f"{frames[0].width}×{frames[0].height}: one camera, one frame size")
        stars = extract_centroids(data, max_stars=max_stars, centroid=centroid)
        sol = skyfix.solve_centroids(stars.xy, w, h, fov_deg=fov_deg, name=name, observation=observation)
        if not sol.solved:
            raise CalibrationError(f"{name}: not solved ({sol.reason})")
        if sol.n_matched < MIN_STARS:
            raise CalibrationError(f"{name}: too few stars matched ({sol.n_matched}; a calibration needs "
                                   f"{MIN_STARS} an image)")
        frames.append(StarFrame(name, w, h, stars.xy, stars.flux, sol, observation))
    return frames


def ground_observation(time=None, site=None, weather=None, refraction: str = "erfa") -> Observation | None:
    """The :class:`~skyfix.corrections.observation.Observation` of images taken from ``site`` at
    ``time`` (their text as ``--time``, ``--site``, ``--weather`` take it), or None when neither is
    given. A site needs a time (refraction and the Earth's rotation depend on it): an
    :class:`~skyfix.errors.InputError` otherwise."""
    if time is None and site is None and weather is None:
        return None
    from skyfix.corrections.observation import observe

    obs = observe(time, site=site, weather=weather, refraction=refraction)
    if obs.site is not None and not obs.time.known:
        raise InputError("a site needs a time (--time): where the zenith is among the stars depends on it")
    return obs


def seen_directions(frame: StarFrame, vectors: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Catalogue unit vectors (K, 3) of the stars numbered ``ids`` as ``frame``'s camera saw them
    (:meth:`~skyfix.corrections.observation.Observation.seen`: aberration, and on the ground the
    refraction of each star), or themselves when the frame's observation is unknown. Parallaxes
    are Hipparcos's, looked up only for a Hipparcos solve's numbers."""
    obs = frame.observation
    if obs is None or not obs.moves_stars:
        return vectors
    hip = np.asarray(ids, dtype=np.int64)
    if str(frame.solution.catalog).startswith("Gaia"):
        hip = np.zeros_like(hip)
    return obs.seen(np.ascontiguousarray(vectors, dtype=np.float64), hip)


def calibrate_stars(images: Sequence[str | Path | np.ndarray], *, model: str = "brown-conrady",
                    skew: bool = False, max_stars: int = 300, fov_deg: float | None = None,
                    max_rounds: int = 5, centroid: str = CALIBRATION_CENTROIDER,
                    observation: Observation | None = None) -> StarCalibration:
    """Calibrate one camera from star images: :func:`prepare_frames`, then :func:`calibrate_frames`
    (``observation``: :func:`ground_observation`, the images' time and site)."""
    calibration_model(model)
    frames = prepare_frames(images, max_stars=max_stars, fov_deg=fov_deg, centroid=centroid,
                            observation=observation)
    return calibrate_frames(frames, model=model, skew=skew, max_rounds=max_rounds)


def calibration_model(name: str) -> CalibrationModel:
    if name not in CALIBRATION_MODELS:
        raise unknown_name("calibration model", name, CALIBRATION_MODELS)
    return CALIBRATION_MODELS[name]


def solution_matches(frame: StarFrame) -> MatchedImage:
    """The frame's solution's matched stars as a :class:`MatchedImage` (with each star's flux,
    looked up among the frame's centroids, and catalogue magnitude), at its attitude."""
    sol = frame.solution
    xy = np.array([(m.x, m.y) for m in sol.matches], dtype=np.float64).reshape(-1, 2)
    ra = np.radians([m.ra_deg for m in sol.matches])
    r = radec_to_vector(ra, np.radians([m.dec_deg for m in sol.matches])).reshape(-1, 3)
    mag = np.array([m.mag for m in sol.matches], dtype=np.float64)
    r = seen_directions(frame, r, np.array([m.id for m in sol.matches], dtype=np.int64))
    A = np.asarray(sol.A_icrs_to_cam, dtype=np.float64)
    return MatchedImage(frame.name, xy, r, A, _flux_at(frame, xy), mag)


def _flux_at(frame: StarFrame, xy: np.ndarray) -> np.ndarray:
    """The flux of the frame's centroid nearest each position (NaN beyond 0.01 px: none)."""
    from scipy.spatial import cKDTree

    if len(frame.xy) == 0 or len(xy) == 0:
        return np.full(len(xy), np.nan)
    d, i = cKDTree(frame.xy).query(xy)
    flux = np.asarray(frame.flux, dtype=np.float64)
    return np.where(d < 0.01, flux[np.minimum(i, len(flux) - 1)], np.nan)


def frame_catalogues(frames: Sequence[StarFrame]) -> list:
    """Each frame's catalogue — the one its solution matched, at its epoch, a magnitude past the
    faintest star any frame matched — loaded once for frames that share it."""
    from skyfix.catalog import load_gaia, load_hipparcos

    limit = max(m.mag for f in frames for m in f.solution.matches) + 1.0
    loaded: dict[tuple[bool, float], object] = {}
    out = []
    for f in frames:
        key = (f.solution.catalog.startswith("Gaia"), f.solution.catalog_epoch)
        if key not in loaded:
            load = load_gaia if key[0] else load_hipparcos
            loaded[key] = load(epoch=key[1], mag_limit=limit)
        out.append(loaded[key])
    return out


def rematch_frame(frame: StarFrame, catalogue, camera: Camera, A: np.ndarray, radius_px: float
                  ) -> MatchedImage:
    """The frame's centroids paired with the catalogue stars ``camera`` and ``A`` predict within
    ``radius_px`` of them, mutual nearest neighbours only (with their fluxes and magnitudes).
    ``frame.solution`` is not used: a frame tracked, not solved, may be re-identified too."""
    from scipy.spatial import cKDTree

    half = math.radians(camera.fov_diagonal_deg) / 2.0 * 1.05
    idx = catalogue.cone(A[2], half)
    r = seen_directions(frame, catalogue.vectors[idx], np.asarray(catalogue.ids)[idx])
    uv, front = camera.ray_to_pixel(r @ A.T)
    seen = front & camera.in_frame(uv, margin=-radius_px)
    r, uv, mag = r[seen], uv[seen], np.asarray(catalogue.mag, dtype=np.float64)[idx][seen]
    if len(uv) == 0 or len(frame.xy) == 0:
        return MatchedImage(frame.name, np.empty((0, 2)), np.empty((0, 3)), A, np.empty(0), np.empty(0))
    d_cat, near_star = cKDTree(frame.xy).query(uv, distance_upper_bound=radius_px)
    _, near_pred = cKDTree(uv).query(frame.xy, distance_upper_bound=radius_px)
    ok = np.flatnonzero(np.isfinite(d_cat))
    ok = ok[near_pred[near_star[ok]] == ok]  # mutual
    stars = near_star[ok]
    flux = np.asarray(frame.flux, dtype=np.float64)[stars]
    return MatchedImage(frame.name, frame.xy[stars], r[ok], A, flux, mag[ok])


def check_not_one_field(matched: Sequence[MatchedImage]) -> None:
    """Raise :class:`~skyfix.errors.CalibrationError` when every image's attitude lies within
    :data:`SAME_FIELD_DEG` of the first's (a degenerate set)."""
    A0 = matched[0].A_icrs_to_cam
    if all(math.degrees(rotation_angle_between(A0, m.A_icrs_to_cam)) < SAME_FIELD_DEG for m in matched[1:]):
        raise CalibrationError(f"degenerate set: all {len(matched)} images are of one field (attitudes "
                               f"within {SAME_FIELD_DEG}°): the camera cannot be told from the pointing; "
                               "point the camera elsewhere between images")


def choose_model(matched: Sequence[MatchedImage], start: Camera, family: CalibrationModel, skew: bool, *,
                 principal_point_sigma_px: float = PRINCIPAL_POINT_SIGMA_PX) -> tuple[JointFit, dict, dict]:
    """Fit the ladder, keep the lowest BIC, then refuse what the stars cannot constrain
    (steps 2–3 of the module text): the fit, the BIC of each parameter set, and the refusals.

    The richest model's robust fit decides the outliers; every model is then scored by least
    squares on the same inliers (BICs of different stars would not compare), each started from
    the one before (its other numbers at ``start``'s: no distortion, the centre). The principal
    point is refused when its 1σ exceeds ``principal_point_sigma_px`` (``math.inf``: never)."""
    extra = (SKEW,) if skew else ()
    richest = fit_joint(matched, start, family.ladder[-1] + extra)
    inliers = [m.subset(k, A) for m, k, A in zip(matched, richest.inliers, richest.attitudes, strict=True)]
    scores: dict[tuple[str, ...], float] = {}
    best: JointFit | None = None
    camera = start
    for params in family.ladder:
        fit = fit_joint(inliers, camera, params + extra, robust=False)
        scores[params + extra] = fit.bic
        if best is None or fit.bic < best.bic:
            best = fit
        camera = fit.camera
    assert best is not None
    refused: dict[str, str] = {}
    while True:
        drop = _refusals(best, principal_point_sigma_px)
        if not drop:
            return best, scores, refused
        refused.update(drop)
        params = tuple(p for p in best.params if p not in drop)
        held = {k: v for p in drop for k, v in _held(p, start).items()}
        best = fit_joint(inliers, best.camera.replace(**held), params, robust=False)


def _held(param: str, start: Camera) -> dict[str, float]:
    if param == "principal_point":
        return {"cx": start.cx, "cy": start.cy}
    if param == "aspect":
        return {"fy": start.fy}
    return _DEFAULTS[param]


def _refusals(fit: JointFit, principal_point_sigma_px: float) -> dict[str, str]:
    """Parameters of ``fit`` the stars do not constrain, each with the reason."""
    sigma, cam = fit.sigma, fit.camera
    out = {}
    if "principal_point" in fit.params:
        s = max(sigma["cx"], sigma["cy"])
        if s > principal_point_sigma_px:
            out["principal_point"] = (f"not constrained: 1σ {s:.3g} px > {principal_point_sigma_px} px; "
                                      "held at the centre")
    for p in fit.params:
        if p not in _DEFAULTS:
            continue
        z = max(abs(getattr(cam, k) - v) / max(sigma[k], 1e-300) for k, v in _DEFAULTS[p].items())
        if z < SIGNIFICANCE:
            out[p] = f"not significant: within {z:.2g}σ of {_DEFAULTS[p]}; held there"
    return out


def _before(matched: Sequence[MatchedImage], start: Camera) -> JointFit:
    """The uncalibrated pinhole fitted to the stars: focal length and attitudes, every star."""
    return fit_joint(matched, start, ("f",), robust=False)


def calibrate_frames(frames: Sequence[StarFrame], *, model: str = "brown-conrady", skew: bool = False,
                     max_rounds: int = 5, allow_one_field: bool = False,
                     principal_point_sigma_px: float = PRINCIPAL_POINT_SIGMA_PX) -> StarCalibration:
    """Fit one camera to solved frames (steps 2–4 of the module text).

    ``allow_one_field``: frames of one field are not refused (:func:`check_not_one_field`) — a
    tracker starting at rest has nothing else, and fits what they constrain;
    ``principal_point_sigma_px``: :func:`choose_model`'s."""
    family = calibration_model(model)
    if len(frames) < MIN_IMAGES:
        raise CalibrationError(f"a star calibration needs at least {MIN_IMAGES} images, got {len(frames)}")
    w, h = frames[0].width, frames[0].height
    fx = float(np.median([f.solution.camera.fx for f in frames]))
    start = Camera(width=w, height=h, fx=fx, fy=fx, cx=(w - 1) / 2.0, cy=(h - 1) / 2.0)
    if family.projection != "pinhole":
        start = Camera.from_fov(w, h, start.fov_deg, projection=family.projection)
    matched = [solution_matches(f) for f in frames]
    if not allow_one_field:
        check_not_one_field(matched)
    catalogues = frame_catalogues(frames)
    fit, scores, refused = choose_model(matched, start, family, skew,
                                        principal_point_sigma_px=principal_point_sigma_px)
    rounds = 1
    while rounds < max_rounds:
        radius = max(REMATCH_SIGMA * fit.sigma_px, REMATCH_FLOOR_PX)
        again = [rematch_frame(f, c, fit.camera, A, radius)
                 for f, c, A in zip(frames, catalogues, fit.attitudes, strict=True)]
        for f, m in zip(frames, again, strict=True):
            if len(m.xy) < MIN_STARS:
                raise CalibrationError(f"{f.name}: too few stars re-identified ({len(m.xy)}) through the "
                                       "camera fitted to the other images")
        same = all(len(a.xy) == len(b.xy) and np.array_equal(a.xy, b.xy)
                   for a, b in zip(again, matched, strict=True))
        matched = again
        if same:
            break
        rounds += 1
        fit, scores, refused = choose_model(matched, start, family, skew,
                                            principal_point_sigma_px=principal_point_sigma_px)
    before = _before([replace(m, A_icrs_to_cam=A) for m, A in zip(matched, fit.attitudes, strict=True)],
                     start)
    solve_rms = np.array([f.solution.rmse_arcsec for f in frames])
    return StarCalibration(fit=fit, before=before, model=model, scores=scores, refused=refused, rounds=rounds,
                           solve_rms_arcsec=solve_rms, observation=frames[0].observation)


def parameter_table(calibration: StarCalibration) -> list[tuple[str, float, float]]:
    """(camera number, value, 1σ) of each fitted number, for reports."""
    fit = calibration.fit
    names = numbers_of_parameters(fit.params, fit.camera.projection)
    return [(n, float(getattr(fit.camera, n)), fit.sigma[n]) for n in names]
