"""The final fit after identification: camera fitted, stars re-matched and re-verified,
outliers out, attitude and its covariance.

Identification proves *which* stars are in the image; this stage makes the attitude as good
and its error bar as honest as the stars allow. With a camera given by the user the camera is
taken as exact and Wahba's problem is solved with the chosen method (QUEST covariance). With
no camera, every camera number is fitted under a prior
(:func:`skyfix.calibrate.fit_camera_with_prior`: aspect, k1, k2, principal point held at the
image centre but free in the covariance), the catalogue is re-matched through the fitted model
and the re-matched stars must again be beyond chance, paying for the camera numbers fitted to
them (:mod:`skyfix.identify.accept`). ``docs/solving-without-a-camera.md`` walks through it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numba
import numpy as np
from scipy.spatial import cKDTree

from skyfix._kernels import lens, rotation
from skyfix.attitude import attitude_covariance, solve_attitude
from skyfix.calibrate import PRIOR_PARAMETERS, CameraPrior, fit_camera_with_prior
from skyfix.camera import Camera
from skyfix.identify.accept import chance_log_probability

__all__ = ["FinalFit", "final_fit"]


@dataclass(frozen=True)
class FinalFit:
    """Attitude, camera and the stars that support them.

    Attributes
    ----------
    A_icrs_to_cam : (3, 3)
    camera : Camera — the camera model used (fitted when none was given).
    star_index : (M,) int — indices into the centroids.
    catalog_ids : (M,) int
    catalog_vectors : (M, 3)
    catalog_mag : (M,)
    residuals_rad : (M,) — angle between each star's ray and its catalogue direction.
    covariance_rad2 : (3, 3) — attitude error about the camera axes (x, y, roll).
    camera_params : tuple of str — camera parameters fitted (empty when the camera was given).
    log_prob_chance : float — log probability that the final matches are chance (with the
        fitted camera's freedom paid for; identification's when the stars were not re-matched).
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


def angles(b: np.ndarray, r: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Angles (rad) between observed rays ``b`` and catalogue vectors ``r`` rotated by ``A``."""
    f64 = np.float64
    return rotation.angles(np.ascontiguousarray(b, dtype=f64), np.ascontiguousarray(r, dtype=f64),
                           np.ascontiguousarray(A, dtype=f64))


def inliers(resid: np.ndarray, floor: float) -> np.ndarray:
    """Stars to fit: residual lengths of 2-D Gaussian errors are Rayleigh distributed (median
    1.177 σ); those beyond 4 σ (P = 3e-4 by chance; σ floored at ``floor``) are blends or
    mismatched faint stars. At least half of the stars, and three, are always kept."""
    return _inliers(np.ascontiguousarray(resid, dtype=np.float64), float(floor))


@numba.njit(cache=True)
def _sorted(a):
    """A sorted copy of a short 1-D array (Shell sort: compiles in a fraction of np.sort's time)."""
    out = a.copy()
    n = out.shape[0]
    for gap in (701, 301, 132, 57, 23, 10, 4, 1):  # Ciura's gaps
        for i in range(gap, n):
            v = out[i]
            j = i
            while j >= gap and out[j - gap] > v:
                out[j] = out[j - gap]
                j -= gap
            out[j] = v
    return out


@numba.njit(cache=True)
def _inliers(resid, floor):
    """:func:`inliers` in one pass."""
    n = resid.shape[0]
    if n == 0:
        return np.zeros(0, dtype=np.bool_)
    ordered = _sorted(resid)
    median = ordered[n // 2] if n % 2 else (ordered[n // 2 - 1] + ordered[n // 2]) / 2.0
    sigma = max(median / 1.177, floor)
    keep = resid <= 4.0 * sigma
    n_min = min(n, max(3, n // 2))
    if keep.sum() < n_min:
        keep = resid <= ordered[n_min - 1]
    return keep


def final_fit(xy: np.ndarray, ident, *, camera_given: bool, database=None, epoch: float | None = None,
              method: str = "svd", prob_threshold: float = 1e-9, n_img: int = 200) -> FinalFit:
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
    """
    if not camera_given:
        return _fit_unknown_camera(xy, ident, database, epoch, method, math.log(prob_threshold), n_img)
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
    # Per-axis σ from the fit's own residuals (3 attitude dof used), floored at 0.05 px
    # so a lucky tiny residual does not claim an impossible precision.
    dof = max(2 * len(idx) - 3, 1)
    sigma = max(math.sqrt(float(np.sum(resid**2)) / dof), 0.05 * camera.plate_scale_rad)
    cov = attitude_covariance(A, b, sigma)
    log_p = math.log(max(ident.prob_false, 1e-300))
    return FinalFit(A, camera, idx, ids, r, mag, resid, cov, (), log_p)


class _Matches(NamedTuple):
    """Centroid index, catalogue id, unit vector and magnitude of each matched star."""

    idx: np.ndarray
    ids: np.ndarray
    r: np.ndarray
    mag: np.ndarray

    def take(self, keep: np.ndarray) -> _Matches:
        return _Matches(self.idx[keep], self.ids[keep], self.r[keep], self.mag[keep])

    def same_as(self, other: _Matches) -> bool:
        a, b = np.argsort(self.idx), np.argsort(other.idx)
        return (len(self.idx) == len(other.idx) and np.array_equal(self.idx[a], other.idx[b])
                and np.array_equal(self.ids[a], other.ids[b]))


class _Rematch(NamedTuple):
    """What re-matching the catalogue through a fitted camera needs (:func:`_grow`)."""

    prior: CameraPrior  # the camera prior the fits are under
    database: object  # PatternDatabase: its star index
    epoch: float | None
    area_px2: float  # the frame's area, for the chance probability
    log_threshold: float  # matches must be beyond chance at this log probability
    n_use: int  # re-match against the brightest this many centroids


def _fit_unknown_camera(xy: np.ndarray, ident, database, epoch: float | None, method: str,
                        log_threshold: float, n_img: int) -> FinalFit:
    """No camera given: fit every camera parameter under its prior
    (:func:`skyfix.calibrate.fit_camera_with_prior`), re-match the catalogue through the fitted
    model, and repeat until the matches stop changing (:func:`_grow`). The re-matched stars must
    be beyond chance *after paying for the camera numbers fitted to them*
    (:func:`skyfix.identify.accept.chance_log_probability`); if they are not, the stars
    identification verified are kept, fitted the same way.

    A sparse result (fewer than :data:`_ROBUST_MIN_STARS` stars) can hold a wrong star that a
    flexible camera bends to fit, and then the re-match cannot grow; each verified star is
    therefore also left out in turn, and a start that grows to at least two more stars wins.
    """
    cam0: Camera = ident.camera
    prior = CameraPrior.uncalibrated(cam0.width, cam0.height)
    if database is None:
        database = ident.database
    if database is None:
        from skyfix.identify import default_database

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
    fit = _prior_fit(xy[verified.idx], verified.r, cam0, ident.A_icrs_to_cam, prior)
    fit, cur = _drop_outliers(xy, fit, verified, prior)
    if len(verified.idx) - len(cur.idx) > max(2, len(verified.idx) // 20):
        # Many stars off the model: least squares may have bent to the wrong ones; fit robustly.
        fit, cur = _robust_prior_fit(xy, verified, cam0, ident.A_icrs_to_cam, prior)
    if len(cur.idx) >= _ROBUST_MIN_STARS:
        # A model that moves no star by a quarter of identification's match radius (3.5 σ of its
        # residuals) cannot change which stars matched but for a rare one at the radius's edge;
        # with 18 or more stars spread over the frame, theirs are the moves that count.
        if fit.largest_move_px < max(0.5, 0.25 * ident.match_radius_px):
            return _final(xy, fit, cur, log_p, method)
        new, _, _ = _match_catalogue(xy[:n_use], fit, database, epoch)
        if new.same_as(cur):
            return _final(xy, fit, cur, log_p, method)
    rematch = _Rematch(prior, database, epoch, area, log_threshold, n_use)
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
    return _final(xy, *best, method)


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
    miss it dropped (:func:`_drop_outliers`), then grown under the real prior (:func:`_grow`,
    against the brightest ``rematch.n_use`` centroids): a wrong neighbour that the free fit
    bent the camera to fit misses a held camera near the true one and is dropped."""
    cam = replace(camera, fy=camera.fx * start.aspect, k1=start.k1)
    fit = fit_camera_with_prior(xy[verified.idx], verified.r, cam, A, start, principal_point="hold")
    fit, cur = _drop_outliers(xy, fit, verified, start)
    return _grow(xy[:rematch.n_use], fit, cur, rematch, math.inf)


def _final(xy: np.ndarray, fit, cur: _Matches, log_p: float, method: str) -> FinalFit:
    """The attitude by the chosen Wahba solver through the fitted camera, and the fit's
    covariance."""
    b = lens.pixel_rays(np.ascontiguousarray(xy[cur.idx], dtype=np.float64), lens.camera_numbers(fit.camera))
    A = solve_attitude(b, cur.r, method=method)
    resid = rotation.angles(b, cur.r, np.ascontiguousarray(A))
    return FinalFit(A, fit.camera, cur.idx, cur.ids, cur.r, cur.mag, resid, fit.covariance_rad2,
                    PRIOR_PARAMETERS, log_p)


def _grow(xy: np.ndarray, fit, cur: _Matches, rematch: _Rematch, log_p: float):
    """Re-match through ``fit`` and refit (least squares and :func:`_drop_outliers`) until the
    matches stop changing, as long as each re-match is beyond chance with the fitted camera paid
    for.
    Returns (fit, matches, log P(chance)) of the last accepted step (``log_p`` for the start)."""
    for _ in range(6):
        new, n_cat, radius = _match_catalogue(xy, fit, rematch.database, rematch.epoch)
        if len(new.idx) < 3:
            break
        n_extra = fit.n_effective - 4.0  # beyond the rotations and the focal length
        log_p_new = chance_log_probability(len(new.idx), n_cat, len(xy), radius, rematch.area_px2, n_extra)
        if log_p_new > rematch.log_threshold:
            break  # these matches are not beyond chance: keep the last ones that were
        log_p = log_p_new
        if new.same_as(cur):
            break
        # Matched within the model's own gates: least squares and the outlier test suffice.
        fit, cur = _drop_outliers(xy, _prior_fit(xy[new.idx], new.r, fit.camera, fit.A_icrs_to_cam,
                                                 rematch.prior), new, rematch.prior)
    return fit, cur, log_p


# A star whose studentised residual (χ², 2 dof) exceeds this is dropped: P = 3.4e-4 for a star
# that fits, the tail of a 4σ cut.
_OUTLIER_CHI2 = 16.0
# A robust fit needs redundancy: with fewer stars than twice the camera's and attitude's nine
# numbers, its median σ is too optimistic and drops good stars.
_ROBUST_MIN_STARS = 18


def _prior_fit(xy: np.ndarray, r: np.ndarray, camera: Camera, A: np.ndarray, prior: CameraPrior,
               **options):
    """:func:`~skyfix.calibrate.fit_camera_with_prior` with the principal point moved only where
    the stars pin it down (a distorted or wide field, an off-centre crop) and otherwise held at
    the image centre with its uncertainty in the covariance."""
    return fit_camera_with_prior(xy, r, camera, A, prior, principal_point="auto", **options)


def _outlier_limit(dof: float) -> float:
    """The externally studentised χ² a good star exceeds with probability 3.4e-4 (the tail of
    :data:`_OUTLIER_CHI2`): twice the F(2, m) quantile, m = dof − 2, in closed form
    (``P(F > x) = (1 + 2x/m)^(−m/2)``); it tends to :data:`_OUTLIER_CHI2` for many stars."""
    m = max(dof - 2.0, 1.0)
    return m * (math.exp(_OUTLIER_CHI2 / m) - 1.0)


def _robust_prior_fit(xy: np.ndarray, m: _Matches, camera: Camera, A: np.ndarray, prior: CameraPrior):
    """:func:`fit_camera_with_prior` on the matches: a robust fit first (a few wrong stars
    cannot hold the model), the stars it finds beyond :data:`_OUTLIER_CHI2` dropped (at least
    half and three kept), then least squares and :func:`_drop_outliers`."""
    if len(m.idx) >= _ROBUST_MIN_STARS:
        fit = _prior_fit(xy[m.idx], m.r, camera, A, prior, robust=True, iterations=20)
        keep = fit.outlier_chi2 <= _OUTLIER_CHI2
        if keep.sum() >= max(3, len(keep) // 2):
            m = m.take(keep)
        camera, A = fit.camera, fit.A_icrs_to_cam
    return _drop_outliers(xy, _prior_fit(xy[m.idx], m.r, camera, A, prior), m, prior)


def _drop_outliers(xy: np.ndarray, fit, m: _Matches, prior: CameraPrior):
    """While the worst star's studentised residual (its miss against what the other stars
    predict, :attr:`~skyfix.calibrate.PriorFit.outlier_chi2`) is beyond :func:`_outlier_limit`,
    drop it and fit again (three stars are always kept)."""
    for _ in range(max(len(m.idx) // 2, 1)):
        worst = int(np.argmax(fit.outlier_chi2))
        if fit.outlier_chi2[worst] <= _outlier_limit(2 * len(m.idx) - fit.n_effective) or len(m.idx) <= 3:
            break
        m = m.take(np.arange(len(m.idx)) != worst)
        fit = _prior_fit(xy[m.idx], m.r, fit.camera, fit.A_icrs_to_cam, prior)
    return fit, m


@numba.njit(cache=True)
def _rays_and_inliers(xy, r, A, cam):
    """``camera.pixel_to_ray(xy)`` for the camera ``cam`` (:func:`skyfix._kernels.lens.pixel_rays`), and the
    :func:`inliers` of their :func:`angles` to ``r`` rotated by ``A`` (σ floored at a tenth of
    the plate scale), and how many those are."""
    b = lens.pixel_rays(xy, cam)
    keep = _inliers(rotation.angles(b, r, A), 0.1 * (1.0 / np.sqrt(cam[lens.FX] * cam[lens.FY])))
    n_kept = 0
    for k in keep:
        n_kept += k
    return b, keep, n_kept


def _star_tree(database) -> cKDTree:
    tree = database.__dict__.get("_star_tree")
    if tree is None:
        tree = cKDTree(np.asarray(database.star_vectors, dtype=np.float64))
        database.__dict__["_star_tree"] = tree
    return tree


def _match_catalogue(xy: np.ndarray, fit, database, epoch: float | None) -> tuple[_Matches, int, float]:
    """Match the catalogue stars in view (the brightest, twice as many as centroids) to the
    centroids ``xy`` through the fitted camera and attitude of ``fit`` (a
    :class:`~skyfix.calibrate.PriorFit`). Each star is searched within 3.5 σ of its predicted
    position, σ combining the centroid noise with the model's own uncertainty there (large
    where the stars fitted so far leave the camera unknown: far from them, or with the pixel
    aspect unconstrained), at least 1 px. Unambiguous pairs only (a centroid with two catalogue
    stars within the radius, a blend, or a star claimed by two centroids says nothing reliable).
    Returns the matches, how many catalogue stars were predicted in the frame, and the RMS
    search radius (px) for the chance test."""
    camera, A = fit.camera, fit.A_icrs_to_cam
    half_diag = math.radians(camera.fov_diagonal_deg) / 2.0 * 1.05
    near = np.sort(np.asarray(_star_tree(database).query_ball_point(A[2], 2.0 * math.sin(half_diag / 2.0)),
                              dtype=np.int64))
    # The brightest first (database order); the cone is at most ~2.5× the frame's area, so
    # 6× as many as will be kept is enough to fill the frame's quota.
    near = near[:12 * len(xy)]
    empty = _Matches(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0))
    if len(near) == 0:
        return empty, 0, 1.0
    v = database.vectors_at(near, epoch)
    uv, front = camera.ray_to_pixel(v @ A.T)
    seen = np.flatnonzero(front & camera.in_frame(uv))[:2 * len(xy)]  # brightest first (database order)
    near, v, uv = near[seen], v[seen], uv[seen]
    if len(near) == 0:
        return empty, 0, 1.0
    radius = np.maximum(3.5 * np.hypot(fit.sigma_px, fit.prediction_sigma_px(v)), 1.0)
    dist, j = cKDTree(xy).query(uv, distance_upper_bound=float(radius.max()))
    hit = dist <= radius
    star, cen = np.flatnonzero(hit), j[hit]
    # Ambiguity: another predicted star within the larger of the two radii of this centroid.
    n_stars_near = cKDTree(uv).query_ball_point(xy[cen], radius[star], return_length=True)
    n_claims = np.bincount(cen, minlength=len(xy))[cen]
    ok = (n_stars_near == 1) & (n_claims == 1)
    star, cen = star[ok], cen[ok]
    star_ids, star_mag, _ = database.star_arrays()
    ids = star_ids[near[star]].astype(np.int64)
    mag = star_mag[near[star]].astype(np.float64)
    rms_radius = float(np.sqrt(np.mean(radius**2)))
    return _Matches(cen.astype(np.int64), ids, v[star], mag), len(near), rms_radius
