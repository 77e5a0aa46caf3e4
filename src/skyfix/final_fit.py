"""The final fit after identification: camera fitted, stars re-matched and re-verified,
outliers out, attitude and its covariance.

Identification proves *which* stars are in the image; this stage makes the attitude as good
and its error bar as honest as the stars allow. With a camera given by the user the camera is
taken as exact and Wahba's problem is solved with the chosen method (QUEST covariance). With
no camera, the camera numbers the stars call for are fitted under a prior, the others held at the
prior's values but free in the covariance (:func:`skyfix.calibrate.fit_camera_with_prior`: aspect,
k1, k2, p1, p2 chosen by evidence, the principal point held at the image centre unless the stars
pin it elsewhere), the catalogue is re-matched through the fitted model
and the re-matched stars must again be beyond chance, paying for the camera numbers fitted to
them (:mod:`skyfix.identify.accept`). A field 60° wide or more may be a fisheye's: a
Kannala–Brandt camera (k1..k4) is fitted and grown too, and the stars choose between the two
(:func:`_pinhole_or_fisheye`). ``docs/solving-without-a-camera.md`` walks through it.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix._kernels import lens, robust, rotation
from skyfix._kernels.camera_fit import OUTLIER_CHI2
from skyfix._rematch import CatalogueCone, equidistant_consensus, match_catalogue
from skyfix._rematch import Matches as _Matches
from skyfix.attitude import CENTROID_NOISE_FLOOR_PX, attitude_covariance, solve_attitude
from skyfix.calibrate import (
    CameraPrior,
    PriorFit,
    fit_camera_with_prior,
    frame_at_pixel,
    frame_covariance_at_pixel,
)
from skyfix.camera import MAX_FOV_DEG, Camera
from skyfix.errors import CameraError
from skyfix.identify import default_database
from skyfix.identify.accept import PROB_THRESHOLD, chance_log_probability

__all__ = ["FinalFit", "covariance_at_pixel", "final_fit"]


@dataclass(frozen=True)
class FinalFit:
    """Attitude, camera and the stars that support them.

    Attributes
    ----------
    A_icrs_to_cam : (3, 3)
    camera : Camera — the camera model used (fitted when none was given).
    star_index : (M,) int — indices into the centroids.
    catalog_ids : (M,) int
    catalog_vectors : (M, 3) — the catalogue directions fitted: as the camera sees them with ``seen``.
    catalog_mag : (M,)
    residuals_rad : (M,) — angle between each star's ray and its catalogue direction.
    covariance_rad2 : (3, 3) — attitude error about the camera axes (x, y, roll): with a fitted
        principal point (``camera``'s away from the image centre) the principal point's own
        uncertainty is in it, as the axes move with it; with the principal point at the centre
        (given, or held there by the fit) it is the frame at that pixel's.
    camera_params : tuple of str — camera parameters fitted (empty when the camera was given).
    log_prob_chance : float — log probability that the final matches are chance (with the
        fitted camera's freedom paid for; identification's when the stars were not re-matched).
    noise_sigma_rad : float — the per-axis centroid noise the covariance is scaled by, with a
        given camera (NaN with a fitted one, whose covariance also holds the camera prior's).
    residual_dof : float — the degrees of freedom of the residuals that noise was estimated
        from: 2M − 3 with a given camera, 2M less the fit's effective number of parameters
        (:attr:`skyfix.calibrate.PriorFit.n_effective`, the divisor of its σ²) with a fitted one.
    camera_fit : PriorFit or None — the fitted camera's posterior, from which any pixel's frame
        covariance follows (:func:`covariance_at_pixel`); None with a camera given.
    precision_covariance_rad2 : (3, 3) or None — what the precision rule judges
        (:func:`skyfix.identify.accept.precision_failure`): the frame at the principal point's
        pixel, where a wrong attitude is judged (:mod:`skyfix.analysis.truth`); an all-sky
        fisheye's, the axes' (:func:`_fit_fisheye_camera`). None: ``covariance_rad2``.
    """

    A_icrs_to_cam: np.ndarray
    camera: Camera
    star_index: np.ndarray
    catalog_ids: np.ndarray
    catalog_vectors: np.ndarray
    catalog_mag: np.ndarray
    residuals_rad: np.ndarray
    covariance_rad2: np.ndarray
    camera_params: tuple[str, ...]
    log_prob_chance: float = 0.0
    noise_sigma_rad: float = math.nan
    residual_dof: float = math.nan
    camera_fit: PriorFit | None = None
    precision_covariance_rad2: np.ndarray | None = None


def covariance_at_pixel(fit: FinalFit, pixel: tuple[float, float], along: str = "row") -> np.ndarray:
    """The covariance (3, 3) rad² of the error of the frame at ``pixel`` of the final fit ``fit``
    (:func:`skyfix.calibrate.frame_at_pixel`: the pixel's sky direction and, with ``along="row"``,
    the roll of image-up there, as :meth:`skyfix.solution.Solution.center_pointing` reports the
    image centre's), about that frame's axes — the same σ scale as ``fit.covariance_rad2``. With a
    camera given, the attitude's turned into that frame (``M P Mᵀ``); with a fitted one, from the
    fit's posterior of attitude and camera (:func:`skyfix.calibrate.frame_covariance_at_pixel`),
    so that the principal point's uncertainty counts only as far as it moves the pixel's
    direction. At the principal point of a camera without skew it is ``fit.covariance_rad2``."""
    cam = fit.camera
    pixel = (float(pixel[0]), float(pixel[1]))
    if pixel == (float(cam.cx), float(cam.cy)) and cam.skew == 0.0:
        return fit.covariance_rad2
    if fit.camera_fit is None:
        M = frame_at_pixel(np.eye(3), cam, pixel, along)
        return M @ fit.covariance_rad2 @ M.T
    return frame_covariance_at_pixel(fit.camera_fit, pixel, along)


def angles(b: np.ndarray, r: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Angles (rad) between observed rays ``b`` and catalogue vectors ``r`` rotated by ``A``."""
    f64 = np.float64
    return rotation.angles(np.ascontiguousarray(b, dtype=f64), np.ascontiguousarray(r, dtype=f64),
                           np.ascontiguousarray(A, dtype=f64))


def inliers(resid: np.ndarray, floor: float) -> np.ndarray:
    """Stars to fit: residual lengths of 2-D Gaussian errors are Rayleigh distributed (median
    1.177 σ); those beyond 4 σ (P = 3e-4 by chance; σ floored at ``floor``) are blends or
    mismatched faint stars. At least half of the stars, and three, are always kept
    (:func:`skyfix._kernels.robust.rayleigh_inliers`)."""
    return robust.rayleigh_inliers(np.ascontiguousarray(resid, dtype=np.float64), float(floor))


def final_fit(xy: np.ndarray, ident, *, camera_given: bool, database=None, epoch: float | None = None,
              method: str = "svd", prob_threshold: float = PROB_THRESHOLD, n_img: int = 200,
              seen=None) -> FinalFit:
    """Refine a successful identification into the final attitude (see the module text).

    Parameters
    ----------
    xy : (N, 2) centroids, px, brightest first.
    ident : skyfix.identify.Identification (successful).
    camera_given : bool — the user gave the camera: take it as exact.
    database : PatternDatabase, optional — its star table serves the re-matching.
    epoch : float, optional — Julian year of the catalogue positions.
    method : str — Wahba solver for the attitude.
    prob_threshold : float — largest accepted probability that the final matches are chance
        (:mod:`skyfix.identify.accept`); with no camera given the re-matched stars are tested
        again, paying for the camera numbers fitted to them.
    n_img : int — brightest centroids the catalogue is re-matched to.
    seen : callable, optional — the directions the camera sees catalogue stars in,
        ``seen(vectors (K, 3) at the epoch, catalogue ids (K,)) -> (K, 3)``
        (:meth:`skyfix.corrections.observation.Observation.seen`: aberration, refraction, …).
        Every star is then fitted and re-matched by those, so the attitude is the camera's
        physical one (``catalog_vectors`` holds them); identification's own search and
        verification stay on the catalogue's places, which its tolerances cover.
    """
    if seen is not None:
        ident = replace(ident, catalog_vectors=seen(np.asarray(ident.catalog_vectors, dtype=np.float64),
                                                    np.asarray(ident.catalog_ids)))
    if not camera_given and ident.camera.projection != "pinhole":  # an all-sky frame's model
        return _fit_fisheye_camera(xy, ident, database, epoch, method, math.log(prob_threshold), n_img, seen)
    if not camera_given:
        return _fit_unknown_camera(xy, ident, database, epoch, method, math.log(prob_threshold), n_img, seen)
    camera: Camera = ident.camera
    idx = np.asarray(ident.star_index)
    ids = np.asarray(ident.catalog_ids)
    r = np.ascontiguousarray(ident.catalog_vectors, dtype=np.float64)
    mag = np.asarray(ident.catalog_mag, dtype=np.float64)
    A = np.ascontiguousarray(ident.A_icrs_to_cam, dtype=np.float64)
    xy_idx = np.ascontiguousarray(xy[idx], dtype=np.float64)
    b, keep, n_kept = _rays_and_inliers(xy_idx, r, A, lens.camera_numbers(camera))
    if n_kept < len(keep):
        idx, ids, r, mag, b = idx[keep], ids[keep], r[keep], mag[keep], b[keep]
    A = solve_attitude(b, r, method=method)
    resid = rotation.angles(b, r, np.ascontiguousarray(A))
    # Per-axis σ from the fit's own residuals (3 attitude dof used), floored at
    # CENTROID_NOISE_FLOOR_PX so a lucky tiny residual does not claim an impossible precision.
    dof = max(2 * len(idx) - 3, 1)
    sigma = max(math.sqrt(float(np.sum(resid**2)) / dof), CENTROID_NOISE_FLOOR_PX * camera.plate_scale_rad)
    cov = attitude_covariance(A, b, sigma)
    log_p = math.log(max(ident.prob_false, 1e-300))
    return FinalFit(A, camera, idx, ids, r, mag, resid, cov, (), log_p, sigma, 2 * len(idx) - 3)


class _Rematch(NamedTuple):
    """What re-matching the catalogue through a fitted camera needs (:func:`_grow`)."""

    prior: CameraPrior  # the camera prior the fits are under
    stars: CatalogueCone  # the catalogue stars about the boresight
    area_px2: float  # the frame's area, for the chance probability
    log_threshold: float  # matches must be beyond chance at this log probability
    n_use: int  # re-match against the brightest this many centroids
    max_radius_px: float = math.inf  # stars the model places less surely are not looked for yet
    # each fit's re-matches so far ((id(fit), max_radius_px) -> (fit, result)): see _matched
    memo: dict | None = None
    # a refit that is no camera (CameraError: a θ polynomial folding inside the frame) ends the
    # grow at the last one that was, instead of raising (an all-sky frame's: _fit_fisheye_camera)
    keep_last_camera: bool = False


def _matched(xy: np.ndarray, fit, rematch: _Rematch, max_radius_px: float = math.inf):
    """:func:`match_catalogue` of the brightest ``rematch.n_use`` centroids of ``xy`` through
    ``fit`` (the matches, the catalogue stars predicted, the RMS radius), computed once per fit
    and radius: a grow's last re-match, which confirms its fit, is the re-match the first check
    made or the choice between models scores (the fit object held in the memo, so its id is
    never another's); and a re-match limited to ``max_radius_px`` that left no star out is the
    unlimited one (a fisheye's grow, then its score)."""
    memo = rematch.memo
    if memo is not None:
        for (fit_id, radius), (held, result) in memo.items():
            if fit_id == id(fit) and held is fit and (radius == max_radius_px
                                                      or (max_radius_px == math.inf and result.complete)):
                return result[:3]
    result = match_catalogue(xy[:rematch.n_use], fit, rematch.stars, max_radius_px)
    if memo is not None:
        memo[id(fit), max_radius_px] = (fit, result)
    return result[:3]


def _fit_unknown_camera(xy: np.ndarray, ident, database, epoch: float | None, method: str,
                        log_threshold: float, n_img: int, seen=None) -> FinalFit:
    """No camera given: fit the camera parameters the stars call for under their prior
    (:func:`skyfix.calibrate.fit_camera_with_prior`), re-match the catalogue through the fitted
    model, and repeat until the matches stop changing (:func:`_grow`). The re-matched stars must
    be beyond chance *after paying for the camera numbers fitted to them*
    (:func:`skyfix.identify.accept.chance_log_probability`); if they are not, the stars
    identification verified are kept, fitted the same way.

    A sparse result (fewer than :data:`_ROBUST_MIN_STARS` stars) can hold a wrong star that a
    flexible camera bends to fit, and then the re-match cannot grow; each verified star is
    therefore also left out in turn, and a start that grows to at least two more stars wins.

    A field whose identified camera is :data:`_FISHEYE_MIN_FOV_DEG` wide or more also gets a
    Kannala–Brandt camera, and the stars choose (:func:`_pinhole_or_fisheye`).
    """
    cam0: Camera = ident.camera
    prior = CameraPrior.uncalibrated(cam0.width, cam0.height)
    if database is None:
        database = ident.database
    if database is None:
        database = default_database()
    verified = _Matches(np.asarray(ident.star_index), np.asarray(ident.catalog_ids),
                        np.ascontiguousarray(ident.catalog_vectors, dtype=np.float64),
                        np.asarray(ident.catalog_mag, dtype=np.float64))
    area = float(cam0.width * cam0.height)
    n_use = min(len(xy), n_img)
    log_p = math.log(max(ident.prob_false, 1e-300))
    # The common case: identification's simpler model (focal length, k1) already fitted every
    # star; if the full model fits them too and hardly moves any star, re-matching through it
    # would find the same stars.
    fit, cur = _fit_without_outliers(xy, verified, cam0, ident.A_icrs_to_cam, prior)
    if len(verified.idx) - len(cur.idx) > max(2, len(verified.idx) // 20):
        # Many stars off the model: least squares may have bent to the wrong ones; fit robustly.
        fit, cur = _robust_prior_fit(xy, verified, cam0, ident.A_icrs_to_cam, prior)
    stars = CatalogueCone(database, epoch, seen)
    rematch = _Rematch(prior, stars, area, log_threshold, n_use, memo={})
    best = None
    if len(cur.idx) >= _ROBUST_MIN_STARS:
        # A model that moves no star by a quarter of identification's match radius (3.5 σ of its
        # residuals) cannot change which stars matched but for a rare one at the radius's edge;
        # with 18 or more stars spread over the frame, theirs are the moves that count.
        if fit.largest_move_px < max(0.5, 0.25 * ident.match_radius_px):
            best = fit, cur, log_p
        else:
            new, _, _ = _matched(xy, fit, rematch)
            if new.same_as(cur):
                best = fit, cur, log_p
    if best is None:
        best = _grown_pinhole(xy, fit, cur, verified, ident, rematch, log_p)
    if cam0.fov_deg >= _FISHEYE_MIN_FOV_DEG:
        best = _pinhole_or_fisheye(xy, best, verified, rematch)
    return _final(xy, *best, method)


def _grown_pinhole(xy: np.ndarray, fit, cur: _Matches, verified: _Matches, ident, rematch: _Rematch,
                   log_p: float):
    """The pinhole's (fit, matches, log P(chance)) grown by re-matching from ``fit`` and ``cur``;
    for a sparse result also from the verified stars less each in turn, and from starts across
    the prior (see :func:`_fit_unknown_camera`)."""
    n_use, prior, log_threshold = rematch.n_use, rematch.prior, rematch.log_threshold
    cam0 = ident.camera
    best = _grow(xy[:n_use], fit, cur, rematch, log_p)
    if len(best[1].idx) < _ROBUST_MIN_STARS and len(verified.idx) > 4:
        for i in range(len(verified.idx)):
            m = verified.take(np.arange(len(verified.idx)) != i)
            fit_i = _prior_fit(xy[m.idx], m.r, cam0, ident.A_icrs_to_cam, prior)
            grown = _grow(xy[:n_use], fit_i, m, rematch, math.inf)
            if grown[2] <= log_threshold and len(grown[1].idx) >= len(best[1].idx) + 2:
                best = grown
    if len(best[1].idx) < _ROBUST_MIN_STARS and len(best[1].idx) < _EXPLAINED * n_use:
        for start in _prior_starts(prior):
            grown = _grow_from_start(xy, verified, cam0, ident.A_icrs_to_cam, start, rematch)
            if grown[2] <= log_threshold and len(grown[1].idx) >= len(best[1].idx) + 2:
                best = grown
    return best


# A field at least this wide (the identified camera's horizontal field, degrees: a 90° equidistant
# fisheye's reads 76–81°, a 60° k1 −0.3 pinhole's 55°) may be a fisheye's that a pinhole cannot
# follow to the corners: a Kannala–Brandt camera is fitted too and the stars choose.
_FISHEYE_MIN_FOV_DEG = 60.0
# A fisheye's re-match looks for the stars that a centroid would meet by chance with at most this
# probability (n_img·π·radius²/area): 10 px for 200 centroids on a 1280 × 960 frame.
_FISHEYE_CHANCE = 0.05


def _pinhole_or_fisheye(xy: np.ndarray, pinhole, verified: _Matches, rematch: _Rematch):
    """Of the pinhole's result (fit, matches, log P(chance)) and a Kannala–Brandt camera's, the one
    the stars prefer (:func:`_scored`: the pinhole on a tie). The fisheye is fitted under
    :meth:`CameraPrior.uncalibrated`'s fisheye prior and grown by re-matching through it
    (:func:`_grow`), from two starts:

    - the pinhole's matches and the verified stars it lost (identification's reach into the
      corners, where a pinhole may not follow a fisheye), equidistant (every k = 0) at the
      pinhole's focal lengths and principal point — the two agree near the centre,
      ``r = f·tan θ ≈ f·θ`` — and its attitude;
    - when neither explains :data:`_EXPLAINED` of the centroids, the verified stars' consensus
      (:func:`equidistant_consensus`): identification's pinhole may have verified a fisheye's
      stars with a quarter of them wrong neighbours and its attitude a degree off, and a fit
      from there keeps a camera bent to fit them.

    Each is grown outward: a star is looked for once the model places it within the radius at
    which a centroid lands there by chance with probability :data:`_FISHEYE_CHANCE` (a fit to
    the centre's stars leaves the corners to the prior, and their wide radii would drown the
    match). A start whose grow is never beyond chance is not a candidate."""
    fit, cur, _ = pinhole
    candidates = [_scored(xy, pinhole, rematch)]
    lost = ~np.isin(verified.idx, cur.idx) & ~np.isin(verified.ids, cur.ids)
    if lost.any():
        cur = _Matches(*(np.concatenate([a, b]) for a, b in zip(cur, verified.take(lost), strict=True)))
    cam = fit.camera
    prior = CameraPrior.uncalibrated(cam.width, cam.height, "kannala-brandt")
    max_radius = math.sqrt(_FISHEYE_CHANCE * rematch.area_px2 / (math.pi * rematch.n_use))
    fisheye = rematch._replace(prior=prior, max_radius_px=max_radius)
    grown = _fisheye_from(xy, cur, (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy), fit.A_icrs_to_cam,
                          fisheye)
    if grown is not None:
        candidates.append(_scored(xy, grown, rematch))
    if max(c.n_matched for c in candidates) < _EXPLAINED * rematch.n_use and len(verified.idx) >= 4:
        # the consensus's equidistant camera, centred, at the pinhole's focal length to start from
        numbers = lens.camera_numbers(cam)
        numbers[[lens.FY, lens.CX, lens.CY]] = cam.fx, prior.cx, prior.cy
        numbers[lens.PROJECTION] = lens.KANNALA_BRANDT
        f, A, agree = equidistant_consensus(np.ascontiguousarray(xy[verified.idx], dtype=np.float64),
                                             np.ascontiguousarray(verified.r, dtype=np.float64), numbers,
                                             _CONSENSUS_STARS, _consensus_tolerance(cam))
        start = (cam.width, cam.height, f, f, prior.cx, prior.cy)
        grown = _fisheye_from(xy, verified.take(agree), start, A, fisheye) if agree.sum() >= 4 else None
        if grown is not None:
            candidates.append(_scored(xy, grown, rematch))
    return min(candidates, key=lambda c: c.log_p_chance).result


class _Scored(NamedTuple):
    """A result (fit, matches, log P(chance)), re-matched once more through its fitted camera: how
    many stars that matched, and their log probability by chance with the camera paid for."""

    result: tuple
    n_matched: int
    log_p_chance: float


def _scored(xy: np.ndarray, result, rematch: _Rematch) -> _Scored:
    """``result`` re-matched through its fitted camera against the whole frame, and how likely by
    chance that is with its camera's numbers paid for
    (:func:`skyfix.identify.accept.chance_log_probability`: more stars matched, or the same
    stars within a tighter radius, is less likely); ``inf`` for a result whose grow was never
    beyond chance (the pinhole's always counts)."""
    fit = result[0]
    if not result[2] <= rematch.log_threshold and fit.camera.projection != "pinhole":
        return _Scored(result, 0, math.inf)
    new, n_cat, radius = _matched(xy, fit, rematch)
    log_p = chance_log_probability(len(new.idx), n_cat, rematch.n_use, radius, rematch.area_px2,
                                   fit.n_effective - 4.0)
    return _Scored(result, len(new.idx), log_p)


def _fit_fisheye_camera(xy: np.ndarray, ident, database, epoch: float | None, method: str,
                        log_threshold: float, n_img: int, seen=None) -> FinalFit:
    """No camera given, and identification's camera a fisheye's (an all-sky frame:
    :mod:`skyfix.allsky`): a Kannala–Brandt camera fitted under the uncalibrated fisheye prior
    about identification's principal point (within :data:`_ALLSKY_CENTRE_SIGMA` of its focal
    length) to the verified stars (robustly, k1..k4 held near 0) and grown by re-matching
    (:func:`_grow`) in stages, k1 freed first and then k2..k4, each step beyond chance with the
    camera paid for, over the sky's disc (its area, not the frame's); a refit that folds its θ
    polynomial inside the frame ends a stage's grow. Raises CameraError when no such camera fits
    the identified stars.

    The covariance is the camera axes' (as every fit whose principal point is off the image
    centre: :func:`_final`): the principal point the boresight's RA/Dec and the quaternion refer
    to is fitted, known to 0.02–0.08 px, which at an all-sky frame's 300–700″ a pixel is 4–40″, 4×
    the error of the sky direction of that pixel. Campaign seeds 0–39, the error (x, y) against the
    truth's quaternion over the σ reported: RMS 5.3, 5.3 with the pixel's covariance, 1.10, 1.05
    with this (docs/all-sky.md#error-bars). The precision rule judges the axes' covariance here
    too (``judge_axes``), as since session 10."""
    cam0: Camera = ident.camera
    prior = CameraPrior.uncalibrated(cam0.width, cam0.height, cam0.projection)._replace(
        cx=cam0.cx, cy=cam0.cy, sigma_principal_point_px=_ALLSKY_CENTRE_SIGMA * cam0.fx)
    verified = _Matches(np.asarray(ident.star_index), np.asarray(ident.catalog_ids),
                        np.ascontiguousarray(ident.catalog_vectors, dtype=np.float64),
                        np.asarray(ident.catalog_mag, dtype=np.float64))
    disc = math.pi * (cam0.fx * math.pi / 2.0) ** 2
    area = min(float(cam0.width * cam0.height), disc)
    n_use = min(len(xy), n_img)
    stars = CatalogueCone(database if database is not None else ident.database or default_database(), epoch,
                          seen)
    max_radius = math.sqrt(_FISHEYE_CHANCE * area / (math.pi * n_use))
    rematch = _Rematch(prior, stars, area, log_threshold, n_use, max_radius, memo={}, keep_last_camera=True)
    # the zenith's stars say little of the rim's distortion: k1..k4 held near 0 while their
    # outliers are found, then freed as the grow reaches the horizon
    held = prior._replace(**{f"sigma_{k}": _START_HOLD * getattr(prior, f"sigma_{k}")
                             for k in ("k1", "k2", "k3", "k4")})
    try:
        fit, cur = _robust_prior_fit(xy, verified, cam0, ident.A_icrs_to_cam, held)
    except CameraError as exc:
        raise CameraError(f"no fisheye camera fits the stars identified ({exc})") from None
    log_p = math.inf
    # grown in stages, k1 freed first, then k2..k4: each stage's camera places the rim's stars
    # only as surely as the stars so far allow, so the grow reaches out step by step
    k1_only = prior._replace(**{f"sigma_{k}": _START_HOLD * getattr(prior, f"sigma_{k}")
                                for k in ("k2", "k3", "k4")})
    for stage in (k1_only, prior):
        with contextlib.suppress(CameraError):
            freed = _fit_without_outliers(xy, cur, fit.camera, fit.A_icrs_to_cam, stage)
            fit, cur, log_p = _grow(xy[:n_use], *freed, rematch._replace(prior=stage), log_p)
    return _final(xy, fit, cur, max(log_p, math.log(max(ident.prob_false, 1e-300))), method, prior,
                  judge_axes=True)


# An all-sky frame's principal point is known from its disc to within this share of the focal length.
_ALLSKY_CENTRE_SIGMA = 0.1


def _fisheye_from(xy: np.ndarray, m: _Matches, start: tuple, A: np.ndarray, rematch: _Rematch,
                  widest: float = MAX_FOV_DEG["pinhole"]):
    """:func:`_robust_prior_fit` to the matches ``m`` of the equidistant camera ``start`` (width,
    height, fx, fy, cx, cy) at the attitude ``A``, grown (:func:`_grow`); None when a camera is
    impossible (a field of ``widest`` degrees or more, or a fit's θ polynomial folding back inside the frame:
    fitted to wrong stars)."""
    try:
        camera = Camera(*start, projection="kannala-brandt")
        fit, cur = _robust_prior_fit(xy, m, camera, A, rematch.prior)
        grown = _grow(xy[:rematch.n_use], fit, cur, rematch, math.inf)
    except CameraError:
        return None
    # a fisheye camera may be wider (an all-sky frame's: _fit_fisheye_camera), not one fitted to a
    # frame identified through a pinhole
    return grown if grown[0].camera.fov_deg < widest else None


# Consensus start: pairs among this many verified stars (the brightest), and the largest miss
# (px, or this share of the half-diagonal) at which a star agrees with a pair's hypothesis.
_CONSENSUS_STARS = 30
_CONSENSUS_TOLERANCE = 0.003


def _consensus_tolerance(camera: Camera) -> float:
    return max(3.0, _CONSENSUS_TOLERANCE * math.hypot(camera.width, camera.height) / 2.0)


# A sparse result that explains fewer than this share of the centroids it was matched against
# may be a local optimum of the camera fit (the stars identification verified through its
# square-pixel model, a wrong neighbour among them, a camera bent to fit it): the fit is
# started again across the prior (:func:`_prior_starts`).
_EXPLAINED = 0.8
# Starts across the prior, in units of its σ: aspect and k1 at 0 and ±0.6 σ (the 3×3 grid),
# each held within a tenth of its prior σ while the start's outliers are found.
_START_STEPS = (-0.6, 0.0, 0.6)
_START_HOLD = 0.01


def _prior_starts(prior: CameraPrior) -> list[CameraPrior]:
    """Priors held tightly (:data:`_START_HOLD` of their σ) about points of the prior's
    aspect–k1 plane (:data:`_START_STEPS`), to start the camera fit of a sparse result from."""
    return [prior._replace(aspect=prior.aspect + a * prior.sigma_aspect, k1=prior.k1 + k * prior.sigma_k1,
                           sigma_aspect=_START_HOLD * prior.sigma_aspect,
                           sigma_k1=_START_HOLD * prior.sigma_k1)
            for a in _START_STEPS for k in _START_STEPS]


def _grow_from_start(xy: np.ndarray, verified: _Matches, camera: Camera, A: np.ndarray,
                     start: CameraPrior, rematch: _Rematch):
    """The verified stars fitted with the camera held near ``start`` (aspect, k1), those that
    miss it dropped (:func:`_fit_without_outliers`), then grown under the real prior (:func:`_grow`,
    against the brightest ``rematch.n_use`` centroids): a wrong neighbour that the free fit
    bent the camera to fit misses a held camera near the true one and is dropped."""
    cam = replace(camera, fy=camera.fx * start.aspect, k1=start.k1)
    fit, cur = _fit_without_outliers(xy, verified, cam, A, start, principal_point="hold")
    return _grow(xy[:rematch.n_use], fit, cur, rematch, math.inf)


# A centroid noise that grows with the stars' magnitude (:func:`_magnitude_noise`) is believed when
# its likelihood ratio against one noise for every star is beyond this (χ², the 1e-3 tail of 2 dof),
# on at least this many stars.
_NOISE_MODEL_CHI2 = 13.8
_NOISE_MODEL_MIN_STARS = 20


def _final(xy: np.ndarray, fit, cur: _Matches, log_p: float, method: str,
           prior: CameraPrior | None = None, judge_axes: bool = False) -> FinalFit:
    """The attitude by the chosen Wahba solver through the fitted camera, and the fit's
    covariance. Where the stars' centroid noise grows with their magnitude (a faint star's
    centroid is worse; :func:`_magnitude_noise` on the fit's residuals and the stars' catalogue
    magnitudes), the camera is fitted again with each star weighted by its inverse variance
    (outliers against it dropped), and Wahba's problem is solved with the same weights: on
    rendered 8° / 15° frames the boresight's median error 0.25 → 0.11″ / 0.19 → 0.11″
    (``benchmarks/bench_final_fit.py --kinds r8,r15``). The weighted fit is under ``prior``
    (default: the uncalibrated one of the camera's projection); one that is no camera (its θ
    polynomial folding inside the frame) leaves the unweighted fit.

    The covariance is that of the camera's axes, the principal point's own uncertainty in it (the
    rotation block of :attr:`~skyfix.calibrate.PriorFit.parameter_covariance`), when the principal
    point is away from the image centre; held at the centre, that of the frame at that pixel
    (:attr:`skyfix.calibrate.PriorFit.covariance_rad2`), the image centre's
    (:func:`covariance_at_pixel` gives any pixel's). The precision rule judges the frame at the
    principal point's pixel (where a wrong attitude is judged), or with ``judge_axes`` the axes'."""
    weights = None
    if len(cur.idx) >= _NOISE_MODEL_MIN_STARS and len(fit.residuals_px) == len(cur.idx):
        variance, ratio = _magnitude_noise(np.sum(fit.residuals_px**2, axis=1),
                                           np.ascontiguousarray(cur.mag, dtype=np.float64),
                                           CENTROID_NOISE_FLOOR_PX**2)
        if ratio > _NOISE_MODEL_CHI2:
            cam = fit.camera
            if prior is None:
                prior = CameraPrior.uncalibrated(cam.width, cam.height, cam.projection)
            with contextlib.suppress(CameraError):
                weighted = fit_camera_with_prior(xy[cur.idx], cur.r, cam, fit.A_icrs_to_cam, prior,
                                                 weights=variance.mean() / variance, drop_outliers=True)
                fit, weights = weighted, (variance.mean() / variance)[weighted.kept]
                cur = cur if weighted.kept.all() else cur.take(weighted.kept)
    b = lens.pixel_rays(np.ascontiguousarray(xy[cur.idx], dtype=np.float64), lens.camera_numbers(fit.camera))
    A = solve_attitude(b, cur.r, weights=weights, method=method)
    resid = rotation.angles(b, cur.r, np.ascontiguousarray(A))
    cam = fit.camera
    axes = fit.parameter_covariance[:3, :3]
    centred = (cam.cx, cam.cy) == ((cam.width - 1) / 2.0, (cam.height - 1) / 2.0)
    covariance = fit.covariance_rad2 if centred else axes
    judged = axes if judge_axes else fit.covariance_rad2
    return FinalFit(A, cam, cur.idx, cur.ids, cur.r, cur.mag, resid, covariance, fit.fitted, log_p,
                    residual_dof=2 * len(cur.idx) - fit.n_effective, camera_fit=fit,
                    precision_covariance_rad2=None if judged is covariance else judged)


@njit(cache=True)
def _magnitude_noise(d2, mag, floor2):
    """The centroid noise of each star from its squared residual ``d2`` (N,) px² and catalogue
    magnitude ``mag`` (N,): the per-axis variance ``v = a + b·10^(0.4 (m − m_faintest))``, a, b ≥ 0
    (a floor — pixel phase, the PSF model — and a term that grows as the flux falls), floored at
    ``floor2``; fitted by maximum likelihood (iteratively reweighted least squares: ``d²/2`` is
    ``v`` times an exponential variable), and the likelihood ratio (``2 Δ log L``) against one
    variance for every star. Returns (v (N,), ratio)."""
    n = d2.shape[0]
    faint = mag.max()
    f = np.empty(n)
    y = np.empty(n)
    mean = 0.0
    for i in range(n):
        f[i] = 10.0 ** (0.4 * (mag[i] - faint))
        y[i] = d2[i] / 2.0
        mean += y[i] / n
    v0 = max(mean, floor2)
    v = np.full(n, v0)
    for _ in range(8):
        s00 = s01 = s11 = t0 = t1 = 0.0
        for i in range(n):
            wi = 1.0 / (v[i] * v[i])
            s00 += wi
            s01 += wi * f[i]
            s11 += wi * f[i] * f[i]
            t0 += wi * y[i]
            t1 += wi * f[i] * y[i]
        det = s00 * s11 - s01 * s01
        a = (s11 * t0 - s01 * t1) / det if det > 0.0 else t0 / s00
        b = (s00 * t1 - s01 * t0) / det if det > 0.0 else 0.0
        if a < 0.0:
            a, b = 0.0, max(t1 / s11, 0.0)
        elif b < 0.0:
            a, b = t0 / s00, 0.0
        for i in range(n):
            v[i] = max(a + b * f[i], floor2)
    ratio = 0.0
    for i in range(n):
        ratio += 2.0 * (math.log(v0 / v[i]) + y[i] / v0 - y[i] / v[i])
    return v, ratio


def _grow(xy: np.ndarray, fit, cur: _Matches, rematch: _Rematch, log_p: float):
    """Re-match through ``fit`` and refit (least squares, outliers dropped:
    :func:`_fit_without_outliers`) until the matches stop changing — or repeat the last
    re-match, the outlier test dropping again what the re-match adds — as long as each re-match
    is beyond chance with the fitted camera paid for.
    Returns (fit, matches, log P(chance)) of the last accepted step (``log_p`` for the start)."""
    last = None
    for _ in range(6):
        new, n_cat, radius = _matched(xy, fit, rematch, rematch.max_radius_px)
        if len(new.idx) < 3:
            break
        n_extra = fit.n_effective - 4.0  # beyond the rotations and the focal length
        log_p_new = chance_log_probability(len(new.idx), n_cat, len(xy), radius, rematch.area_px2, n_extra)
        if log_p_new > rematch.log_threshold:
            break  # these matches are not beyond chance: keep the last ones that were
        log_p = log_p_new
        if new.same_as(cur) or (last is not None and new.same_as(last)):
            break
        last = new
        # Matched within the model's own gates: least squares and the outlier test suffice.
        try:
            fit, cur = _fit_without_outliers(xy, new, fit.camera, fit.A_icrs_to_cam, rematch.prior)
        except CameraError:
            if not rematch.keep_last_camera:
                raise
            break
    return fit, cur, log_p


# A robust fit needs redundancy: with fewer stars than twice the camera's and attitude's nine
# numbers, its median σ is too optimistic and drops good stars.
_ROBUST_MIN_STARS = 18


def _prior_fit(xy: np.ndarray, r: np.ndarray, camera: Camera, A: np.ndarray, prior: CameraPrior,
               **options):
    """:func:`~skyfix.calibrate.fit_camera_with_prior` with the principal point moved only where
    the stars pin it down (a distorted or wide field, an off-centre crop) and otherwise held at
    the image centre with its uncertainty in the covariance, and the other camera numbers fitted
    where the stars call for them (``model="evidence"``)."""
    return fit_camera_with_prior(xy, r, camera, A, prior, principal_point="auto", **options)


def _fit_without_outliers(xy: np.ndarray, m: _Matches, camera: Camera, A: np.ndarray, prior: CameraPrior,
                          principal_point: str = "auto"):
    """:func:`~skyfix.calibrate.fit_camera_with_prior` on the matches ``m``, dropping the star whose
    studentised residual (its miss against what the other stars predict) is the worst beyond the
    3.4e-4 tail, one at a time, as the fit goes (``drop_outliers``; three stars always kept):
    the fit and the matches it kept."""
    fit = fit_camera_with_prior(xy[m.idx], m.r, camera, A, prior, principal_point=principal_point,
                                drop_outliers=True)
    return fit, (m if fit.kept.all() else m.take(fit.kept))


def _robust_prior_fit(xy: np.ndarray, m: _Matches, camera: Camera, A: np.ndarray, prior: CameraPrior):
    """:func:`fit_camera_with_prior` on the matches: a robust fit first (a few wrong stars
    cannot hold the model), the stars it finds beyond :data:`~skyfix._kernels.camera_fit.OUTLIER_CHI2`
    dropped (at least half and three kept), then least squares without the outliers
    (:func:`_fit_without_outliers`)."""
    if len(m.idx) >= _ROBUST_MIN_STARS:
        fit = _prior_fit(xy[m.idx], m.r, camera, A, prior, robust=True, iterations=20)
        keep = fit.outlier_chi2 <= OUTLIER_CHI2
        if keep.sum() >= max(3, len(keep) // 2):
            m = m.take(keep)
        camera, A = fit.camera, fit.A_icrs_to_cam
    return _fit_without_outliers(xy, m, camera, A, prior)


@njit(cache=True)
def _rays_and_inliers(xy, r, A, cam):
    """``camera.pixel_to_ray(xy)`` for the camera ``cam`` (:func:`skyfix._kernels.lens.pixel_rays`), and the
    :func:`inliers` of their :func:`angles` to ``r`` rotated by ``A`` (σ floored at a tenth of
    the plate scale), and how many those are."""
    b = lens.pixel_rays(xy, cam)
    floor = 0.1 * (1.0 / np.sqrt(cam[lens.FX] * cam[lens.FY]))
    keep = robust.rayleigh_inliers(rotation.angles(b, r, A), floor)
    n_kept = 0
    for k in keep:
        n_kept += k
    return b, keep, n_kept
