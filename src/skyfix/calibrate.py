"""Camera calibration from star fields: fit intrinsics and distortion to matched stars.

A solved image gives pixel positions ``xy`` of stars and their catalogue directions ``r``;
the camera model and the attitude are fitted together by least squares on the reprojection
error in pixels. Which parameters are free is a choice of model; :func:`select_camera_model`
picks the one the data support (Bayesian information criterion), so a field of 20 stars does
not fit a 10-parameter lens and a strongly distorted lens is not forced into a pinhole.

Either projection of :class:`~skyfix.camera.Camera` is fitted: the starting camera's. A
pinhole's ``k1 … k3`` are Brown–Conrady's, a Kannala–Brandt (fisheye) camera's ``k1 … k4`` its
θ polynomial's, each with its own derivatives (:mod:`skyfix._kernels.camera_jacobian`); ``tangential``
is a pinhole's only, ``k4`` a fisheye's only (:data:`CAMERA_PARAMETERS`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from skyfix._kernels import camera_fit as kernels
from skyfix._kernels import lens, rotation
from skyfix.camera import PROJECTION_ALIASES, Camera
from skyfix.errors import unknown_name

__all__ = ["CAMERA_PARAMETERS", "CameraFit", "CameraPrior", "ModelScore", "PriorFit", "fit_camera",
           "fit_camera_with_prior", "frame_at_pixel", "frame_covariance_at_pixel", "frame_rotation_at_pixel",
           "prior_parameters", "score_camera_models", "select_camera_model", "PRIOR_PARAMETERS",
           "UNCALIBRATED_DISTORTION", "PARAMETERS", "MODEL_LADDER"]

_BOTH = ("pinhole", "kannala-brandt")


class CameraParameter(NamedTuple):
    """A camera parameter a fit may free: its kernel code
    (:mod:`skyfix._kernels.camera_jacobian`), how many numbers it is, what it moves, and the
    projections (:data:`skyfix.camera.PROJECTIONS`) that have it."""

    code: int
    size: int
    doc: str
    projections: tuple[str, ...] = _BOTH


# The registry of camera parameters, chosen by name (fit_camera's ``params``).
CAMERA_PARAMETERS: dict[str, CameraParameter] = {
    "f": CameraParameter(kernels.F, 1, "common focal scale (fx and fy together)"),
    "aspect": CameraParameter(kernels.ASPECT, 1, "pixel aspect fy/fx"),
    "principal_point": CameraParameter(kernels.PRINCIPAL_POINT, 2, "cx, cy"),
    "k1": CameraParameter(kernels.K1_TERM, 1, "radial distortion: a pinhole's r² term, a fisheye's θ³"),
    "k2": CameraParameter(kernels.K2_TERM, 1, "radial distortion: a pinhole's r⁴ term, a fisheye's θ⁵"),
    "k3": CameraParameter(kernels.K3_TERM, 1, "radial distortion: a pinhole's r⁶ term, a fisheye's θ⁷"),
    "k4": CameraParameter(kernels.K4_TERM, 1, "a fisheye's θ⁹ term", ("kannala-brandt",)),
    "tangential": CameraParameter(kernels.TANGENTIAL, 2, "decentring distortion p1, p2", ("pinhole",)),
}
# How many numbers each parameter is (CAMERA_PARAMETERS's sizes).
PARAMETERS = {name: p.size for name, p in CAMERA_PARAMETERS.items()}


def _codes(params: Sequence[str]) -> np.ndarray:
    return np.array([CAMERA_PARAMETERS[name].code for name in params], dtype=np.int64)


def _check_parameters(params: Sequence[str], camera: Camera) -> None:
    """A ValueError naming the parameters that are unknown or not ``camera``'s projection's."""
    unknown = set(params) - set(PARAMETERS)
    if unknown:
        raise ValueError(f"unknown camera parameters: {', '.join(sorted(unknown))}")
    other = [p for p in params if camera.projection not in CAMERA_PARAMETERS[p].projections]
    if other:
        raise ValueError(f"{', '.join(other)}: not a parameter of the {camera.projection} projection")


def _camera_after_step(camera: Camera, params: Sequence[str], p: np.ndarray) -> Camera:
    """The camera after the parameter step ``p`` (rotations first, then ``params``' numbers, in
    the scaled units of :mod:`skyfix._kernels.camera_jacobian`)."""
    rmax = math.hypot(camera.width, camera.height) / 2.0 / camera.fx
    cam = kernels.apply_step(lens.camera_numbers(camera), rmax, _codes(params),
                             np.asarray(p, dtype=np.float64))
    return camera.replace(**dict(zip(lens.CAMERA_NUMBERS, cam.tolist(), strict=True)))

# Models tried by select_camera_model, simplest first. The principal point and tangential
# terms are left out: from one field they trade off against the pointing itself, so they
# belong to a calibration over many fields, not to a per-image fit.
MODEL_LADDER: tuple[tuple[str, ...], ...] = (
    ("f",),
    ("f", "k1"),
    ("f", "aspect"),
    ("f", "aspect", "k1"),
    ("f", "k1", "k2"),
    ("f", "aspect", "k1", "k2"),
)


@dataclass(frozen=True)
class CameraFit:
    """A fitted camera and attitude, with the fit's quality.

    Attributes
    ----------
    camera : Camera — the fitted model.
    A_icrs_to_cam : (3, 3) — the fitted attitude.
    params : tuple of str — the free parameters.
    rss_px2 : float — sum of squared reprojection residuals, px².
    n_stars : int
    residuals_px : (N, 2) — reprojection residuals, px.
    attitude_covariance_rad2 : (3, 3) — covariance of the attitude error about the camera
        axes (x, y cross-boresight, z roll), rad², with the camera parameters marginalised
        and σ taken from the residuals.
    """

    camera: Camera
    A_icrs_to_cam: np.ndarray
    params: tuple[str, ...]
    rss_px2: float
    n_stars: int
    residuals_px: np.ndarray
    attitude_covariance_rad2: np.ndarray

    @property
    def n_free(self) -> int:
        """Free numbers: 3 attitude angles plus the camera's."""
        return 3 + sum(PARAMETERS[p] for p in self.params)

    @property
    def sigma_px(self) -> float:
        """Per-axis residual σ, px, with the fitted degrees of freedom removed."""
        return math.sqrt(self.rss_px2 / max(2 * self.n_stars - self.n_free, 1))

    @property
    def bic(self) -> float:
        """Bayesian information criterion of the fit (Gaussian residuals)."""
        n = 2 * self.n_stars
        return n * math.log(max(self.rss_px2, 1e-300) / n) + self.n_free * math.log(n)


def _residuals(camera: Camera, params: tuple[str, ...], p: np.ndarray, rays0: np.ndarray,
               xy: np.ndarray) -> np.ndarray:
    return _residuals_fast(camera, params, p[None, :], rays0, xy)[0]


def _residuals_fast(camera: Camera, params: tuple[str, ...], ps: np.ndarray, rays0: np.ndarray,
                    xy: np.ndarray) -> np.ndarray:
    """Residuals (K, 2N) of the stars after each parameter step of ``ps`` (K, P)
    (:func:`skyfix._kernels.camera_jacobian.residuals_for_steps`)."""
    cam = lens.camera_numbers(camera)
    rmax = math.hypot(camera.width, camera.height) / 2.0 / camera.fx
    codes = _codes(params)
    return kernels.residuals_for_steps(cam, rmax, codes, np.ascontiguousarray(ps, dtype=np.float64),
                             np.ascontiguousarray(rays0, dtype=np.float64),
                             np.ascontiguousarray(xy, dtype=np.float64))


def _jacobian(camera: Camera, params: tuple[str, ...], p: np.ndarray, rays0: np.ndarray, xy: np.ndarray,
              r0: np.ndarray) -> np.ndarray:
    """Forward-difference Jacobian (2N, P) of the residuals, all steps in one batch; the model
    is smooth and nearly linear at these scales, so a fixed step of 1e-7 is accurate to ~1e-7."""
    h = 1e-7
    steps = p[None, :] + h * np.eye(p.size)
    return ((_residuals_fast(camera, params, steps, rays0, xy) - r0) / h).T


def fit_camera(xy: np.ndarray, r_icrs: np.ndarray, camera: Camera, A_icrs_to_cam: np.ndarray,
               params: Sequence[str] = ("f",), *, iterations: int = 8) -> CameraFit:
    """Fit the attitude and the named camera parameters to matched stars (Gauss–Newton on the
    reprojection error in pixels).

    Parameters
    ----------
    xy : (N, 2) array
        Pixel positions of the stars (docs/design.md#pixel-coordinates).
    r_icrs : (N, 3) array
        Their catalogue unit vectors.
    camera : Camera
        Starting model; parameters not named stay fixed.
    A_icrs_to_cam : (3, 3) array
        Starting attitude.
    params : sequence of str
        Free parameters, from :data:`PARAMETERS`: ``f`` (common focal scale), ``aspect``
        (``fy/fx``), ``principal_point`` (``cx, cy``), ``k1``, ``k2``, ``k3`` (the camera's
        projection's), ``k4`` (Kannala–Brandt only), ``tangential`` (``p1, p2``, pinhole only).
    iterations : int
        Most Gauss–Newton steps (it stops when a step moves no star by 1e-6 px).

    Returns
    -------
    CameraFit
    """
    params = tuple(params)
    _check_parameters(params, camera)
    xy = np.asarray(xy, dtype=np.float64)
    r = np.asarray(r_icrs, dtype=np.float64)
    n_free = 3 + sum(PARAMETERS[p] for p in params)
    if 2 * len(xy) <= n_free:
        raise ValueError(f"fitting {n_free} numbers needs more than {n_free // 2} stars, got {len(xy)}")
    return _fit(xy, r, camera, np.asarray(A_icrs_to_cam, dtype=np.float64), params, iterations)


def _fit(xy: np.ndarray, r: np.ndarray, camera: Camera, A0: np.ndarray, params: tuple[str, ...],
         iterations: int, J: np.ndarray | None = None, res: np.ndarray | None = None) -> CameraFit:
    """Gauss–Newton with the Jacobian of the starting point, recomputed only when the steps
    stop shrinking (the model is nearly linear over the few pixels a fit moves stars)."""
    rays0 = r @ A0.T
    n_free = 3 + sum(PARAMETERS[name] for name in params)
    p = np.zeros(n_free)
    if res is None:
        res = _residuals(camera, params, p, rays0, xy)
    if J is None:
        J = _jacobian(camera, params, p, rays0, xy, res)
    last = math.inf
    for _ in range(iterations):
        p = p + np.linalg.lstsq(J, -res, rcond=None)[0]
        new = _residuals(camera, params, p, rays0, xy)
        moved = float(np.max(np.abs(new - res)))
        res = new
        if moved < 1e-6:
            break
        if moved > 0.5 * last:
            J = _jacobian(camera, params, p, rays0, xy, res)
        last = moved
    R = rotation.rodrigues(p)
    ch = _camera_after_step(camera, params, p)
    sigma2 = float(res @ res) / max(res.size - n_free, 1)
    # Columns 0–2 are rotations of the camera frame, so this block is the attitude error
    # about the camera axes with every camera parameter marginalised.
    cov = sigma2 * _inverse(J.T @ J)[:3, :3]
    return CameraFit(camera=ch, A_icrs_to_cam=R @ A0, params=params,
                     rss_px2=float(res @ res), n_stars=len(xy), residuals_px=res.reshape(-1, 2),
                     attitude_covariance_rad2=cov)


def _inverse(M: np.ndarray) -> np.ndarray:
    """Inverse of a small normal matrix; the pseudo-inverse only when it is singular."""
    try:
        return np.linalg.inv(M)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(M)


@dataclass(frozen=True)
class ModelScore:
    """A camera model scored from the linearisation about the starting point.

    Attributes
    ----------
    params : tuple of str
    bic : float
    rss_px2 : float — residual sum of squares after the linear step, px².
    attitude_covariance_rad2 : (3, 3) — attitude error about the camera axes, camera
        parameters marginalised, σ from ``rss_px2``.
    """

    params: tuple[str, ...]
    bic: float
    rss_px2: float
    attitude_covariance_rad2: np.ndarray


def score_camera_models(xy: np.ndarray, r_icrs: np.ndarray, camera: Camera, A_icrs_to_cam: np.ndarray,
                        models: Sequence[Sequence[str]] = MODEL_LADDER, *,
                        min_stars_per_number: float = 2.0) -> list[ModelScore]:
    """Score each model the number of stars supports, from one linearisation.

    The models' parameters are subsets of their union, so one analytic Jacobian serves all:
    each score is a small linear least-squares problem on a block of ``JᵀJ``. A model with
    ``k`` free numbers is scored only with at least ``min_stars_per_number · k`` stars (the
    first model is always scored), so sparse fields keep simple models.
    """
    scored, bic, rss, cov = _model_scores(xy, r_icrs, camera, A_icrs_to_cam, models, min_stars_per_number)
    return [ModelScore(tuple(params), float(bic[i]), float(rss[i]), cov[i])
            for i, params in enumerate(scored)]


def _model_scores(xy: np.ndarray, r_icrs: np.ndarray, camera: Camera, A_icrs_to_cam: np.ndarray,
                  models: Sequence[Sequence[str]] = MODEL_LADDER, min_stars_per_number: float = 2.0,
                  ) -> tuple[list, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`score_camera_models` as arrays: the models scored, their BIC (K,), RSS (K,) px²
    and attitude covariances (K, 3, 3) rad² (no ModelScore objects: the final fit's hot path)."""
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    r = np.ascontiguousarray(r_icrs, dtype=np.float64)
    A = np.ascontiguousarray(A_icrs_to_cam, dtype=np.float64)
    if models is not MODEL_LADDER:  # the ladder's parameters are every projection's
        models = tuple(tuple(m) for m in models)
        _check_parameters(tuple(dict.fromkeys(p for m in models for p in m)), camera)
    codes, cols, n_cols = _model_blocks(models)
    rmax = math.hypot(camera.width, camera.height) / 2.0 / camera.fx
    cam = lens.camera_numbers(camera)
    sc = kernels.score_models(xy, r, A, cam, rmax, codes, cols, n_cols, float(min_stars_per_number))
    chosen, bic, rss, cov = sc.chosen, sc.bic, sc.rss, sc.covariance
    ok, JtJ, Jtr, rr = sc.ok, sc.JtJ, sc.Jtr, sc.rr
    if not chosen.any():
        raise ValueError(f"too few stars ({len(xy)}) to fit a camera model")
    if not ok:  # a block not numerically positive definite: LU inverses (pseudo-inverse if singular)
        n = 2 * len(xy)
        for m in np.flatnonzero(chosen):
            c = cols[m, :n_cols[m]]
            inv = _inverse(JtJ[np.ix_(c, c)])
            rss[m] = max(rr - float(Jtr[c] @ inv @ Jtr[c]), 1e-300)
            bic[m] = n * math.log(rss[m] / n) + len(c) * math.log(n)
            cov[m] = rss[m] / max(n - len(c), 1) * inv[:3, :3]
    if chosen.all():
        return list(models), bic, rss, cov
    k = np.flatnonzero(chosen)
    return [models[i] for i in k], bic[k], rss[k], cov[k]


_BLOCKS_CACHE: dict = {}

# Codes of the parameters in the numba kernels.


def _model_blocks(models: tuple[tuple[str, ...], ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Kernel codes (U,) of the union of the models' parameters (in order of first appearance),
    and each model's columns of the union's Jacobian (rotations 0–2 first): ``cols[m, :n_cols[m]]``."""
    hit = _BLOCKS_CACHE.get(models)
    if hit is None:
        union = tuple(dict.fromkeys(p for m in models for p in m))
        unknown = set(union) - set(PARAMETERS)
        if unknown:
            raise ValueError(f"unknown camera parameters: {', '.join(sorted(unknown))}")
        columns, i = {}, 3
        for name in union:
            columns[name] = list(range(i, i + PARAMETERS[name]))
            i += PARAMETERS[name]
        blocks = [[0, 1, 2] + [c for name in m for c in columns[name]] for m in models]
        cols = np.zeros((len(models), i), dtype=np.int64)
        for k, c in enumerate(blocks):
            cols[k, :len(c)] = c
        hit = (_codes(union), cols,
               np.array([len(c) for c in blocks], dtype=np.int64))
        if len(_BLOCKS_CACHE) < 64:
            _BLOCKS_CACHE[models] = hit
    return hit


def select_camera_model(xy: np.ndarray, r_icrs: np.ndarray, camera: Camera, A_icrs_to_cam: np.ndarray,
                        models: Sequence[Sequence[str]] = MODEL_LADDER, *,
                        min_stars_per_number: float = 2.0) -> CameraFit:
    """Choose the camera model the stars support (lowest BIC, :func:`score_camera_models`)
    and fit it to convergence (:func:`fit_camera`)."""
    scores = score_camera_models(xy, r_icrs, camera, A_icrs_to_cam, models,
                                 min_stars_per_number=min_stars_per_number)
    best = min(scores, key=lambda sc: sc.bic)
    return fit_camera(xy, r_icrs, camera, A_icrs_to_cam, best.params)


# --- an uncalibrated camera: every parameter free, each with a Gaussian prior ------------------

# The parameters of an uncalibrated camera, in the order of :func:`fit_camera_with_prior`'s
# parameter vector (after the three rotations): a pinhole's, and a Kannala–Brandt camera's
# (prior_parameters gives them by projection).
PRIOR_PARAMETERS: tuple[str, ...] = ("f", "aspect", "principal_point", "k1", "k2")
_PRIOR_PARAMETERS_OF = {"pinhole": PRIOR_PARAMETERS,
                        "kannala-brandt": ("f", "aspect", "principal_point", "k1", "k2", "k3", "k4")}


def prior_parameters(projection: str, tangential: bool = False) -> tuple[str, ...]:
    """The parameters :func:`fit_camera_with_prior` fits for a camera of ``projection``
    (:data:`PRIOR_PARAMETERS` for a pinhole, and ``tangential`` (p1, p2) when its prior has a
    tangential σ; a Kannala–Brandt camera's adds ``k3``, ``k4``)."""
    if tangential and projection == "pinhole":
        return PRIOR_PARAMETERS + ("tangential",)
    return _PRIOR_PARAMETERS_OF[projection]


class CameraPrior(NamedTuple):
    """What is known of a camera before its image is solved: a Gaussian prior on each parameter
    but the focal length (free) — the principal point about ``(cx, cy)``, the pixel aspect
    ``fy/fx`` about ``aspect`` (1), radial distortion about ``k1``, ``k2`` (0; OpenCV's normalised
    units), for a ``kannala-brandt`` camera ``k3``, ``k4`` (0: the equidistant fisheye) and, for a
    pinhole with ``sigma_tangential`` > 0, the decentring distortion ``p1``, ``p2`` (0; at 0 σ
    they are held, not fitted). The prior's ``projection`` must be the fitted camera's.

    The prior keeps a sparse field from fitting an absurd lens (``k2 = 400``) and lets the
    attitude's covariance include what the stars leave unknown; many stars overrule it.
    """

    cx: float
    cy: float
    sigma_principal_point_px: float
    sigma_aspect: float = 0.05
    sigma_k1: float = 0.3
    sigma_k2: float = 0.3
    aspect: float = 1.0
    k1: float = 0.0
    k2: float = 0.0
    projection: str = "pinhole"
    sigma_k3: float = 0.05  # k3, k4: a Kannala–Brandt camera's only (a pinhole's fit holds its k3)
    sigma_k4: float = 0.02
    k3: float = 0.0
    k4: float = 0.0
    sigma_tangential: float = 0.0  # p1, p2 (a pinhole's only): held unless > 0
    p1: float = 0.0
    p2: float = 0.0

    @property
    def parameters(self) -> tuple[str, ...]:
        """The camera parameters a fit under this prior frees (:func:`prior_parameters`)."""
        return prior_parameters(self.projection, self.sigma_tangential > 0.0)

    @classmethod
    def uncalibrated(cls, width: int, height: int, projection: str = "pinhole") -> CameraPrior:
        """The prior for an unknown camera of this frame size: principal point at the image
        centre within a quarter of the half-diagonal (lens mounting — or an off-centre crop of a
        larger frame: with 5% the error bars of 60% crops were 6–8× too small), aspect within
        5%, and the projection's distortion (:data:`UNCALIBRATED_DISTORTION`): a pinhole's
        |k1|, |k2| ≲ 0.3 (most lenses narrower than 60°) and |p1|, |p2| ≲ 1e-3, a fisheye's
        about the equidistant projection."""
        name = PROJECTION_ALIASES.get(projection, projection)
        if name not in UNCALIBRATED_DISTORTION:
            raise unknown_name("camera projection", projection, UNCALIBRATED_DISTORTION)
        return _uncalibrated(cls, width, height, name)


@functools.lru_cache(maxsize=64)
def _uncalibrated(cls: type[CameraPrior], width: int, height: int, name: str) -> CameraPrior:
    """:meth:`CameraPrior.uncalibrated`'s prior, made once per frame size and projection (a
    final fit asks for it several times a solve; the NamedTuple cannot change)."""
    return cls(cx=(width - 1) / 2.0, cy=(height - 1) / 2.0,
               sigma_principal_point_px=0.25 * math.hypot(width, height) / 2.0, projection=name,
               **UNCALIBRATED_DISTORTION[name])


UNCALIBRATED_DISTORTION: dict[str, dict[str, float]] = {
    # Decentring p1, p2 with σ 1e-3 each: OpenCV calibrations of machine-vision lenses give
    # |p1|, |p2| ≲ 1e-3 (thesis 003's MT9P031 lens 2.3e-4, presets/mt9p031.toml), so a real lens
    # sits within 1σ and the attitude's error bar carries what the stars leave of them; a p held
    # at 0 goes into the principal point and the boresight (5.6–6.1" at 50°, normalised RMS 5.6).
    "pinhole": {"sigma_k1": 0.3, "sigma_k2": 0.3, "sigma_tangential": 1e-3},
    # θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸) about the equidistant fisheye (all 0). The
    # classical fisheye projections in this form: equisolid 2 sin(θ/2) has k1 = −1/24, k2 = 1/1920;
    # stereographic 2 tan(θ/2) k1 = 1/12, k2 = 1/120; orthographic sin θ k1 = −1/6, k2 = 1/120;
    # each within a σ of these; a rectilinear lens (tan θ: 1/3, 2/15, 17/315, 62/2835) within 2σ.
    # OpenCV calibrations of real fisheyes (|k_j| ≲ 0.05, the higher terms trading off) inside.
    "kannala-brandt": {"sigma_k1": 0.2, "sigma_k2": 0.1, "sigma_k3": 0.05, "sigma_k4": 0.02},
}
"""The distortion part of :meth:`CameraPrior.uncalibrated` by projection: the σ of each
coefficient about 0."""


class PriorFit(NamedTuple):
    """The result of :func:`fit_camera_with_prior`.

    Attributes
    ----------
    camera : Camera — the fitted model (maximum a posteriori of the model fitted).
    A_icrs_to_cam : (3, 3) — the fitted attitude.
    residuals_px : (M, 2) — reprojection residuals of the stars kept, px.
    sigma_px : float — centroid noise per axis estimated from the residuals, px.
    covariance_rad2 : (3, 3) — attitude error about the camera axes (x, y, roll), rad², at the
        principal point, with every camera parameter of :attr:`parameters` marginalised over its
        posterior (those held too: what the stars leave of them is in the error bar).
    n_effective : float — effective number of fitted numbers of that posterior, every parameter
        of :attr:`parameters` free (3 rotations + the camera's share: ``trace`` of the hat
        matrix); the camera's part is what a re-match through this camera pays for.
    outlier_chi2 : (M,) — each kept star's residual against what the others predict for it
        under the model fitted (studentised: ``rᵀ (σ² (I − H))⁻¹ r`` with ``H`` its 2×2 block of
        the hat matrix, and σ from the other stars' residuals unless ``robust``): for a star that
        fits the model, twice an F(2, dof − 2) variable, dof = ``2M`` less the model's numbers.
    parameter_covariance : (P, P) — posterior covariance of the parameter step (rotations,
        then the camera's :attr:`parameters` in the scaled units of
        :mod:`skyfix._kernels.camera_jacobian`).
    largest_move_px : float — the largest distance by which the fit moved a kept star's
        predicted position from where the starting camera and attitude put it.
    parameters : tuple[str, ...] — the camera parameters of the posterior
        (:attr:`CameraPrior.parameters`).
    fitted : tuple[str, ...] — those of them the fit moved from the prior's values (the model
        the stars chose; ``f`` always).
    kept : (N,) bool — which of the stars given the fit kept (all but the outliers it dropped).
    """

    camera: Camera
    A_icrs_to_cam: np.ndarray
    residuals_px: np.ndarray
    sigma_px: float
    covariance_rad2: np.ndarray
    n_effective: float
    outlier_chi2: np.ndarray
    parameter_covariance: np.ndarray
    largest_move_px: float = 0.0
    parameters: tuple[str, ...] = PRIOR_PARAMETERS
    fitted: tuple[str, ...] = PRIOR_PARAMETERS
    kept: np.ndarray | None = None

    def prediction_sigma_px(self, r_icrs: np.ndarray) -> np.ndarray:
        """How uncertain (px, the larger axis's σ) the fitted model's pixel position of each
        catalogue direction ``r_icrs`` (M, 3) is, from :attr:`parameter_covariance`."""
        cam = self.camera
        rays = np.ascontiguousarray(np.asarray(r_icrs, dtype=np.float64) @ self.A_icrs_to_cam.T)
        rmax = math.hypot(cam.width, cam.height) / 2.0 / cam.fx
        numbers = lens.camera_numbers(cam)
        codes = _codes(self.parameters)
        Js, _ = kernels.jacobian_rows(np.zeros((len(rays), 2)), rays, numbers, rmax, codes)
        C = (Js @ self.parameter_covariance) @ Js.transpose(0, 2, 1)
        half_tr = (C[:, 0, 0] + C[:, 1, 1]) / 2.0
        return np.sqrt(half_tr + np.sqrt(np.maximum(half_tr**2 - (C[:, 0, 0] * C[:, 1, 1] - C[:, 0, 1] ** 2),
                                                    0.0)))


_PRINCIPAL_POINT_MODES = {"hold": kernels.PP_HOLD, "auto": kernels.PP_AUTO, "fit": kernels.PP_FIT}


def fit_camera_with_prior(xy: np.ndarray, r_icrs: np.ndarray, camera: Camera, A_icrs_to_cam: np.ndarray,
                          prior: CameraPrior, *, robust: bool = False, iterations: int = 12,
                          sigma_floor_px: float = 0.05, principal_point: str = "auto",
                          model: str = "evidence", drop_outliers: bool = False,
                          weights: np.ndarray | None = None) -> PriorFit:
    """Fit attitude, focal length, aspect, principal point and the distortion to matched stars,
    each camera parameter but the focal length held by its ``prior`` (maximum a posteriori):
    :attr:`CameraPrior.parameters` — a pinhole's k1, k2 (its k3 held) and, with a tangential σ
    (:meth:`CameraPrior.uncalibrated`'s), p1, p2; a Kannala–Brandt camera's k1 … k4.

    Gauss–Newton on ``Σ w |residual|²/σ² + Σ ((θ − θ₀)/τ)²`` with the analytic Jacobian of
    :func:`skyfix._kernels.camera_jacobian.jacobian_rows`, in one numba kernel
    (:func:`skyfix._kernels.camera_fit.prior_gauss_newton`). σ, the centroid
    noise, is re-estimated at every step: from the residuals (``σ² = RSS / (2N − n_eff)``), or
    with ``robust`` from their median (a
    2-D Gaussian's residual length has median 1.1774 σ) and with Cauchy weights
    ``w = 1 / (1 + (|residual| / 3σ)²)``, so that a few wrong stars cannot hold the model away
    from the many right ones; floored at ``sigma_floor_px``.

    ``model``: ``"evidence"`` fits only the camera numbers the stars call for — of the models
    that free the focal length and any subset of the other parameters (the principal point as
    ``principal_point`` says), the one of largest marginal likelihood under the prior
    (:func:`skyfix._kernels.camera_models.log_evidence`), the others held at the prior's values
    (square pixels, no distortion) — so an ordinary lens is fitted as what it is, a pinhole, and
    a distorted one with the terms it needs; ``"all"`` frees every parameter (never chosen with
    ``robust``, which frees all). Either way the covariance is the posterior's with every
    parameter free, ``(JᵀWJ/σ² + Λ)⁻¹`` at the result: what the stars leave unknown of a
    parameter held is in the attitude's error bar. Its attitude block is taken for the frame at
    the principal point *as a pixel*: a principal-point shift moves the optical axis but not the
    sky position of that pixel, so only what the principal point does beyond a shift (the
    field's perspective and the distortion centre) enters the attitude's error bar.

    ``principal_point``: ``"fit"`` moves the principal point from the prior's as the stars
    ask; ``"hold"`` keeps it at the prior's (the image centre), so that the attitude refers to
    that pixel, with its uncertainty (free under its prior at the held solution) in the
    covariance; ``"auto"`` fits it where the stars pin it down (posterior σ below a third of the
    prior's, the move beyond χ² = 13.8 of its posterior: a wide or distorted field, a crop) and
    holds it elsewhere.

    ``drop_outliers``: as the fit converges, drop the star whose studentised residual is the
    worst beyond the 3.4e-4 tail (:func:`skyfix._kernels.camera_fit.outlier_limit`), one at a time,
    and fit on (at most half the stars; three always kept): :attr:`PriorFit.kept`.

    Parameters
    ----------
    xy : (N, 2) — star positions, px.
    r_icrs : (N, 3) — their catalogue unit vectors.
    camera, A_icrs_to_cam : the starting model and attitude.
    prior : CameraPrior — of the camera's projection (:meth:`CameraPrior.uncalibrated`).
    robust : bool — Cauchy weights and a median σ (for matches that may hold wrong stars).
    iterations : int — most Gauss–Newton steps (per model fitted).
    sigma_floor_px : float — smallest centroid noise believed, px.
    principal_point : str — ``"auto"``, ``"fit"`` or ``"hold"`` (above).
    model : str — ``"evidence"`` or ``"all"`` (above).
    drop_outliers : bool — drop outliers as the fit goes (above).
    weights : (N,), optional — each star's inverse variance, relative (σ, :attr:`PriorFit.sigma_px`,
        is then that of a star of weight 1): stars whose centroids are better (brighter) count more.
    """
    if principal_point not in _PRINCIPAL_POINT_MODES:
        raise ValueError(f"principal_point must be 'auto', 'fit' or 'hold', not {principal_point!r}")
    if model not in ("evidence", "all"):
        raise ValueError(f"model must be 'evidence' or 'all', not {model!r}")
    if prior.projection != camera.projection:
        raise ValueError(f"a {prior.projection} prior for a {camera.projection} camera: "
                         f"CameraPrior.uncalibrated(..., projection={camera.projection!r})")
    options = kernels.PriorFitOptions(bool(robust), int(iterations), float(sigma_floor_px),
                                      _PRINCIPAL_POINT_MODES[principal_point], model == "evidence",
                                      bool(drop_outliers))
    half_diag = float(math.hypot(camera.width, camera.height) / 2.0)
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    weights = np.ones(len(xy)) if weights is None else np.ascontiguousarray(weights, dtype=np.float64)
    gn = kernels.prior_gauss_newton(xy, np.ascontiguousarray(r_icrs, dtype=np.float64),
                                    np.ascontiguousarray(A_icrs_to_cam, dtype=np.float64),
                                    lens.camera_numbers(camera), half_diag, _prior_numbers(prior), options,
                                    weights)
    camera = camera.replace(**dict(zip(lens.CAMERA_NUMBERS, gn.cam.tolist(), strict=True)))
    parameters = prior.parameters
    fitted = tuple(name for name, free in zip(parameters, gn.fitted.tolist(), strict=True) if free)
    return PriorFit(camera, gn.A, gn.residuals, math.sqrt(gn.sigma2), gn.attitude_covariance, gn.n_effective,
                    gn.chi2, gn.covariance, float(gn.moved), parameters, fitted, gn.kept)


@functools.lru_cache(maxsize=64)
def _prior_numbers(prior: CameraPrior) -> np.ndarray:
    """The prior's numbers as the kernel takes them (:data:`skyfix._kernels.camera_fit.PRIOR_NUMBERS`),
    made once per prior (the kernel only reads them)."""
    return np.array([getattr(prior, k) for k in kernels.PRIOR_NUMBERS], dtype=np.float64)


def frame_at_pixel(A_icrs_to_cam: np.ndarray, camera: Camera, pixel: tuple[float, float],
                   along: str = "column") -> np.ndarray:
    """The attitude (3, 3) of the frame that ``camera`` and ``A_icrs_to_cam`` give at ``pixel``:
    z along that pixel's sky direction and, with ``along="column"``, x along the direction in
    which the column grows there (made perpendicular to z), y = z × x; with ``along="row"``, y
    along the direction in which the row grows there, x = y × z — so that its roll is the
    position angle of image-up at ``pixel`` exactly (docs/design.md's roll). Away from the principal
    point the sky's image of the pixel grid is not square (perspective, distortion), so the two
    differ by that skew (0.01–0.05° 100 px off the axis of a 20° camera). At the principal
    point of a camera without skew both are ``A_icrs_to_cam``."""
    if along not in ("column", "row"):
        raise ValueError(f"along must be 'column' or 'row', not {along!r}")
    return _frame_axes(camera, (float(pixel[0]), float(pixel[1])), along) @ np.asarray(A_icrs_to_cam,
                                                                                       dtype=np.float64)


@functools.lru_cache(maxsize=64)
def _frame_axes(camera: Camera, pixel: tuple[float, float], along: str) -> np.ndarray:
    """:func:`frame_at_pixel`'s axes (3, 3) in ``camera``'s frame (read-only; a campaign's
    judgements ask for the same camera and pixel every trial)."""
    rows = _axes_at_pixel(camera.numbers(), pixel, along)
    rows.flags.writeable = False
    return rows


def _axes_at_pixel(numbers: np.ndarray, pixel: tuple[float, float], along: str) -> np.ndarray:
    """The axes (3, 3) of the frame at ``pixel`` (:func:`frame_at_pixel`) in the frame of the camera
    whose kernel numbers are ``numbers`` (:data:`skyfix._kernels.lens.CAMERA_NUMBERS`): z the
    pixel's ray, the column's (or the row's) direction from the ray half a pixel on."""
    x, y = pixel
    pixels = np.array([[x, y], [x + 0.5, y] if along == "column" else [x, y + 0.5]], dtype=np.float64)
    ray0, ray1 = lens.pixel_rays(pixels, numbers)  # one call for both pixels
    z = ray0 / math.sqrt(ray0 @ ray0)
    t = ray1 - ray0
    t -= (t @ z) * z
    t /= math.sqrt(t @ t)
    return np.array([t, _cross(z, t), z] if along == "column" else [_cross(t, z), t, z])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a × b`` of two 3-vectors (``np.cross`` costs tens of µs a call: the frame covariance makes
    a dozen frames)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def frame_covariance_at_pixel(fit: PriorFit, pixel: tuple[float, float], along: str = "row") -> np.ndarray:
    """The covariance (3, 3) rad² of the error of the frame at ``pixel`` (:func:`frame_at_pixel`:
    its sky direction, and the roll of the row's — or the column's — direction there) about that
    frame's own axes, from the posterior of the camera fit ``fit``
    (:attr:`PriorFit.parameter_covariance`: the attitude and every camera number of
    :attr:`PriorFit.parameters`): ``T C Tᵀ`` with ``T`` (3, P) the Jacobian of that frame's rotation
    by the fit's step. A rotation ``δθ`` of the camera turns the frame at the pixel by ``M δθ``
    (``M`` its axes in the camera frame); a camera number moves the pixel's ray and the row's
    direction, a column found by central differences (a hundredth of the number's posterior σ).
    At the principal point of a camera without skew it is :attr:`PriorFit.covariance_rad2` to
    first order; away from it, the principal point's own uncertainty moves the pixel's sky
    direction less than the axes' (the camera axes' covariance is the rotation block of ``C``)."""
    cov = np.asarray(fit.parameter_covariance, dtype=np.float64)
    cam = fit.camera
    numbers = cam.numbers()
    pixel = (float(pixel[0]), float(pixel[1]))
    M = _axes_at_pixel(numbers, pixel, along)
    T = np.zeros((3, cov.shape[0]))
    T[:, :3] = M
    rmax = math.hypot(cam.width, cam.height) / 2.0 / cam.fx  # the fit's scaled units (fit_camera_with_prior)
    codes = _codes(fit.parameters)
    apply_step = kernels.apply_step.py_func  # a dozen numbers: no kernel call for it
    for k in range(3, cov.shape[0]):
        h = 0.01 * math.sqrt(max(cov[k, k], 0.0))
        if h == 0.0:
            continue
        p = np.zeros(cov.shape[0])
        p[k] = h
        plus = _axes_at_pixel(apply_step(numbers, rmax, codes, p), pixel, along) @ M.T
        minus = _axes_at_pixel(apply_step(numbers, rmax, codes, -p), pixel, along) @ M.T
        d = (plus - minus) / (2.0 * h)  # the small rotation's matrix: its antisymmetric part [δφ]×
        T[:, k] = 0.5 * (d[2, 1] - d[1, 2]), 0.5 * (d[0, 2] - d[2, 0]), 0.5 * (d[1, 0] - d[0, 1])
    return T @ cov @ T.T


def frame_rotation_at_pixel(A: np.ndarray, camera: Camera, A_ref: np.ndarray, camera_ref: Camera,
                            pixel: tuple[float, float]) -> np.ndarray:
    """Rotation vector (3,) rad, about ``camera``'s axes, from the frame that (``A_ref``,
    ``camera_ref``) give at ``pixel`` (:func:`frame_at_pixel`) to the camera frame of ``A``.
    For ``pixel`` at ``camera``'s principal point it is the error of ``A`` when the reference is
    the truth."""
    return rotation.rotation_vector(np.ascontiguousarray(A @ frame_at_pixel(A_ref, camera_ref, pixel).T))
