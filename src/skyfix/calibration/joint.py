"""One camera and one attitude per image, fitted jointly to the stars of many images.

The per-image fit (:mod:`skyfix.calibrate`) sees one field: the principal point and the
decentring trade off against that field's pointing, and twenty stars cannot carry ten camera
numbers. Over many images the camera is shared and only the attitudes are each image's own,
so the camera is pinned down by every star at once.

The model and its derivatives are :mod:`skyfix._kernels.camera_jacobian`'s, written once:
:func:`~skyfix._kernels.camera_jacobian.jacobian_rows` gives each image's rows (its three rotations
and the shared camera's columns, in that module's scaled units) and
:func:`~skyfix._kernels.camera_jacobian.apply_step` moves the camera. Only the skew, which no
per-image fit frees, has its column here: ``∂u/∂skew = y_d`` (``y_d`` read from the predicted
``v = fy·y_d + cy``), ``∂v/∂skew = 0``.

The fit (:func:`fit_joint`) is Gauss–Newton on the pixel residuals, robust first (Cauchy
weights at 3σ, σ from the residuals' median: a wrong star cannot hold the camera), then with
the stars beyond :data:`OUTLIER_SIGMA` σ left out and every other star weighted alike, so that
the covariance ``σ² (JᵀJ)⁻¹`` (σ² = RSS / (2N − n_free)) is that of least squares: the 1σ of
each camera number is the square root of its diagonal, mapped from the scaled units to the
camera's own (:attr:`JointFit.sigma`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from skyfix._kernels import camera_jacobian as kernels
from skyfix._kernels import lens, rotation
from skyfix.calibrate import CAMERA_PARAMETERS
from skyfix.camera import Camera

__all__ = ["FREE_NUMBERS", "OUTLIER_SIGMA", "SKEW", "JointFit", "MatchedImage", "fit_joint",
           "numbers_of_parameters"]

# A star whose residual is beyond this many σ (σ from the residuals' median) is left out of the
# final least squares: 5σ of a 2-D Gaussian is exp(−12.5) ≈ 4e-6 by chance.
OUTLIER_SIGMA = 5.0
# The skew's name: a camera number of the joint fit beside calibrate.CAMERA_PARAMETERS' parameters.
SKEW = "skew"
# The median of a 2-D Gaussian residual's length is 1.1774 σ (√(2 ln 2)).
_MEDIAN_RADIUS = math.sqrt(2.0 * math.log(2.0))
# Cauchy weights' scale, in σ.
_CAUCHY_SCALE = 3.0
# Gauss–Newton stops when a step moves no star by more than this, px.
_CONVERGED_PX = 1e-6
# Levenberg–Marquardt's damping, relative to the normal matrix's diagonal: where it starts (a
# Gauss–Newton step, near enough) and where it gives up.
_DAMPING_START = 1e-9
_DAMPING_MAX = 1e6
# … and its robust stage (whose weights move with every step) when no star moves by this, px.
_ROBUST_CONVERGED_PX = 1e-3


def numbers_of_parameters(params: Sequence[str], projection: str) -> tuple[str, ...]:
    """The camera numbers (``lens.CAMERA_NUMBERS`` names) the parameters ``params`` move, in
    that order: ``f`` → fx, fy; ``aspect`` → fy; ``principal_point`` → cx, cy; ``tangential`` →
    p1, p2; ``skew``; ``k1`` … ``k4``."""
    moved: dict[str, None] = {}
    for p in params:
        moved.update(dict.fromkeys({"f": ("fx", "fy"), "aspect": ("fy",), "principal_point": ("cx", "cy"),
                                    "tangential": ("p1", "p2"), SKEW: (SKEW,)}.get(p, (p,))))
    return tuple(n for n in lens.CAMERA_NUMBERS if n in moved)


# Every camera number a joint fit may report a σ for (the projection's coefficients among them).
FREE_NUMBERS = ("fx", "fy", "cx", "cy", "skew", "k1", "k2", "k3", "p1", "p2", "k4")


@dataclass(frozen=True)
class MatchedImage:
    """One image's stars matched to the catalogue: pixel positions (N, 2) (docs/design.md's
    convention), catalogue unit vectors (N, 3, ICRS) and a starting attitude (3, 3); optionally
    each star's measured flux and catalogue magnitude (N,), which the fit carries along for the
    calibration statistics (:mod:`skyfix.calibration.bench`) and does not use.

    (A dataclass, not a NamedTuple: this module imports the kernels, whose cache digest takes in
    the NamedTuples of every module that imports them.)"""

    name: str
    xy: np.ndarray
    r_icrs: np.ndarray
    A_icrs_to_cam: np.ndarray
    flux: np.ndarray | None = None
    mag: np.ndarray | None = None

    def subset(self, keep: np.ndarray, A_icrs_to_cam: np.ndarray | None = None) -> MatchedImage:
        """The stars ``keep`` (a mask or indices) of this image, every per-star array alike; the
        attitude replaced when one is given."""
        return replace(self, xy=self.xy[keep], r_icrs=self.r_icrs[keep],
                       flux=None if self.flux is None else self.flux[keep],
                       mag=None if self.mag is None else self.mag[keep],
                       A_icrs_to_cam=self.A_icrs_to_cam if A_icrs_to_cam is None else A_icrs_to_cam)


@dataclass(frozen=True)
class JointFit:
    """A camera fitted jointly to many images.

    Attributes
    ----------
    camera : Camera — the fitted camera.
    attitudes : (M, 3, 3) — each image's fitted attitude ``A_icrs_to_cam``.
    params : tuple of str — the free camera parameters (:data:`skyfix.calibrate.CAMERA_PARAMETERS`
        names, and ``skew``).
    sigma_px : float — per-axis residual σ of the inliers, px (fitted numbers removed).
    covariance : (12, 12) — covariance of the camera numbers (``lens.CAMERA_NUMBERS`` order, the
        camera's own units; zero for numbers held).
    residuals_px : list of (N_i, 2) — each image's residuals (model − measured), px.
    inliers : list of (N_i,) bool — the stars of the final least squares.
    names : tuple of str — the images.
    xy : list of (N_i, 2) — the stars' measured positions, px.
    flux, mag : list of (N_i,) or None — the stars' fluxes and catalogue magnitudes, when the
        images carried them (:class:`MatchedImage`).
    """

    camera: Camera
    attitudes: np.ndarray
    params: tuple[str, ...]
    sigma_px: float
    covariance: np.ndarray = field(repr=False)
    residuals_px: list = field(repr=False)
    inliers: list = field(repr=False)
    names: tuple[str, ...] = ()
    xy: list = field(default_factory=list, repr=False)
    flux: list = field(default_factory=list, repr=False)
    mag: list = field(default_factory=list, repr=False)

    @property
    def n_stars(self) -> int:
        """Stars in the final least squares."""
        return int(sum(int(k.sum()) for k in self.inliers))

    @property
    def n_free(self) -> int:
        """Fitted numbers: three rotations an image and the camera's."""
        return 3 * len(self.attitudes) + _n_columns(self.params)

    @property
    def rss_px2(self) -> float:
        pairs = zip(self.residuals_px, self.inliers, strict=True)
        return float(sum(float(np.sum(r[k] ** 2)) for r, k in pairs))

    @property
    def bic(self) -> float:
        """Bayesian information criterion (Gaussian residuals, the inliers)."""
        n = 2 * self.n_stars
        return n * math.log(max(self.rss_px2, 1e-300) / n) + self.n_free * math.log(n)

    @property
    def sigma(self) -> dict[str, float]:
        """1σ of each camera number the fit freed (:func:`numbers_of_parameters`), its own units."""
        names = numbers_of_parameters(self.params, self.camera.projection)
        index = {n: lens.CAMERA_NUMBERS.index(n) for n in names}
        return {n: math.sqrt(max(float(self.covariance[i, i]), 0.0)) for n, i in index.items()}

    def rms_arcsec(self) -> np.ndarray:
        """Each image's residual RMS (the length of a star's miss, inliers), arcsec at the centre."""
        scale = 206264.80624709636 * self.camera.plate_scale_rad
        return np.array([scale * math.sqrt(float(np.mean(np.sum(r[k] ** 2, axis=1)))) if k.any() else math.nan
                         for r, k in zip(self.residuals_px, self.inliers, strict=True)])


def _n_columns(params: Sequence[str]) -> int:
    return sum(1 if p == SKEW else CAMERA_PARAMETERS[p].size for p in params)


def _codes(params: Sequence[str]) -> np.ndarray:
    return np.array([CAMERA_PARAMETERS[p].code for p in params if p != SKEW], dtype=np.int64)


def _check(params: Sequence[str], camera: Camera) -> None:
    for p in params:
        if p == SKEW:
            continue
        if p not in CAMERA_PARAMETERS:
            raise ValueError(f"unknown camera parameter {p!r}")
        if camera.projection not in CAMERA_PARAMETERS[p].projections:
            raise ValueError(f"{p}: not a parameter of the {camera.projection} projection")


def _rows(images: Sequence[MatchedImage], attitudes: np.ndarray, cam: np.ndarray, rmax: float,
          codes: np.ndarray, skew: bool) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Each image's Jacobian rows (N_i, 2, 3 + P) and residuals (N_i, 2) at the camera ``cam``
    and the attitudes: :func:`skyfix._kernels.camera_jacobian.jacobian_rows`, with the skew's column
    appended when it is free."""
    Js, rs = [], []
    for img, A in zip(images, attitudes, strict=True):
        rays0 = np.ascontiguousarray(img.r_icrs @ A.T)
        J, res = kernels.jacobian_rows(img.xy, rays0, cam, rmax, codes)
        if skew:  # ∂u/∂skew·fx = fx·y_d, y_d = (v − cy)/fy with v the predicted row
            yd = (res[:, 1] + img.xy[:, 1] - cam[lens.CY]) / cam[lens.FY]
            col = np.zeros((len(res), 2, 1))
            col[:, 0, 0] = cam[lens.FX] * yd
            J = np.concatenate([J, col], axis=2)
        Js.append(J)
        rs.append(res)
    return Js, rs


def _normal_equations(Js: list[np.ndarray], rs: list[np.ndarray], weights: list[np.ndarray]
                      ) -> tuple[np.ndarray, np.ndarray, float]:
    """``JᵀWJ`` (3M + P, 3M + P), ``JᵀWr`` and ``rᵀWr`` of every image together: each image's
    three rotation columns its own, the camera's P columns shared (built a block an image)."""
    M = len(Js)
    P = Js[0].shape[2] - 3
    H = np.zeros((3 * M + P, 3 * M + P))
    g = np.zeros(3 * M + P)
    rr = 0.0
    for m, (Ji, ri, wi) in enumerate(zip(Js, rs, weights, strict=True)):
        J = Ji.reshape(-1, 3 + P)
        w = np.repeat(wi, 2)
        r = ri.reshape(-1)
        Hm = (J * w[:, None]).T @ J
        gm = J.T @ (w * r)
        own = slice(3 * m, 3 * m + 3)
        H[own, own] = Hm[:3, :3]
        H[own, 3 * M:] = Hm[:3, 3:]
        H[3 * M:, own] = Hm[3:, :3]
        H[3 * M:, 3 * M:] += Hm[3:, 3:]
        g[own] = gm[:3]
        g[3 * M:] += gm[3:]
        rr += float(r @ (w * r))
    return H, g, rr


def _largest_move(Js: list[np.ndarray], step: np.ndarray) -> float:
    """The largest pixel move the linearised step makes of any star."""
    M = len(Js)
    return max(float(np.max(np.abs(Ji.reshape(-1, Ji.shape[2]) @ np.concatenate([step[3 * m:3 * m + 3],
                                                                                  step[3 * M:]])),
                            initial=0.0)) for m, Ji in enumerate(Js))


def _inverse(H: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(H)


def _moved(cam: np.ndarray, rmax: float, codes: np.ndarray, step: np.ndarray, skew: bool) -> np.ndarray:
    """The camera numbers after the camera part of a step (``apply_step``'s units; the skew's
    in focal lengths)."""
    p = np.concatenate([np.zeros(3), step[:len(step) - int(skew)]])
    out = kernels.apply_step(cam, rmax, codes, np.ascontiguousarray(p))
    if skew:
        out[lens.SKEW] = cam[lens.SKEW] + step[-1] * cam[lens.FX]
    return out


def _step_to_numbers(cam: np.ndarray, rmax: float, codes: np.ndarray, skew: bool, P: int) -> np.ndarray:
    """The linear map (12, P) from a step of the camera's columns to its numbers (the derivative
    of :func:`_moved` at 0, by differences: it is linear in each column but ``fy``'s product)."""
    h = 1e-7
    T = np.empty((len(cam), P))
    for j in range(P):
        e = np.zeros(P)
        e[j] = h
        T[:, j] = (_moved(cam, rmax, codes, e, skew) - cam) / h
    return T


def _sigma_robust(rs: list[np.ndarray], keep: list[np.ndarray]) -> float:
    lengths = np.concatenate([np.hypot(r[k, 0], r[k, 1]) for r, k in zip(rs, keep, strict=True)])
    return max(float(np.median(lengths)) / _MEDIAN_RADIUS, 1e-6)


def fit_joint(images: Sequence[MatchedImage], camera: Camera, params: Sequence[str], *,
              iterations: int = 30, robust: bool = True) -> JointFit:
    """Fit one camera (the parameters ``params``, :data:`skyfix.calibrate.CAMERA_PARAMETERS`
    names and ``skew``) and one attitude per image to the images' matched stars.

    Parameters
    ----------
    images : sequence of MatchedImage — stars, catalogue directions and starting attitudes.
    camera : Camera — the starting camera; numbers not freed stay as they are.
    params : sequence of str — the free camera parameters (the projection's).
    iterations : int — most Gauss–Newton steps of each stage (robust, then least squares).
    robust : bool — the robust stage first (Cauchy weights; outliers beyond
        :data:`OUTLIER_SIGMA` σ left out of the least squares).

    Returns
    -------
    JointFit
    """
    params = tuple(params)
    _check(params, camera)
    skew = SKEW in params
    codes = _codes([p for p in params if p != SKEW])
    images = [replace(i, xy=np.ascontiguousarray(i.xy, dtype=np.float64),
                      r_icrs=np.ascontiguousarray(i.r_icrs, dtype=np.float64),
                      A_icrs_to_cam=np.asarray(i.A_icrs_to_cam, dtype=np.float64)) for i in images]
    cam = lens.camera_numbers(camera)
    rmax = math.hypot(camera.width, camera.height) / 2.0 / camera.fx
    attitudes = np.array([i.A_icrs_to_cam for i in images])
    keep = [np.ones(len(i.xy), dtype=bool) for i in images]
    M = len(images)

    def gauss_newton(weights_of, n_steps: int, tolerance_px: float) -> tuple[list, list]:
        """Levenberg–Marquardt: a step is taken only when it lowers the weighted RSS; the damping
        (relative to the normal matrix's diagonal) grows tenfold until it does."""
        nonlocal cam, attitudes
        Js, rs = _rows(images, attitudes, cam, rmax, codes, skew)
        damping = _DAMPING_START
        for _ in range(n_steps):
            weights = weights_of(rs)
            H, g, cost = _normal_equations(Js, rs, weights)
            while True:
                step = -np.linalg.solve(H + damping * np.diag(np.diag(H)), g)
                cam_new = _moved(cam, rmax, codes, step[3 * M:], skew)
                att_new = np.array([rotation.rodrigues(np.ascontiguousarray(step[3 * m:3 * m + 3])) @ A
                                    for m, A in enumerate(attitudes)])
                ok = cam_new[lens.FX] > 0 and cam_new[lens.FY] > 0
                if ok:
                    Js_new, rs_new = _rows(images, att_new, cam_new, rmax, codes, skew)
                    pairs = zip(rs_new, weights, strict=True)
                    ok = sum(float(np.sum(w[:, None] * r**2)) for r, w in pairs) <= cost
                if ok or damping > _DAMPING_MAX:
                    break
                damping *= 10.0
            if not ok:  # no step lowers the RSS: converged (or stuck) here
                break
            moved = _largest_move(Js, step)
            cam, attitudes, Js, rs = cam_new, att_new, Js_new, rs_new
            damping = max(damping / 10.0, _DAMPING_START)
            if moved < tolerance_px:
                break
        return Js, rs

    if robust:
        def cauchy(rs):
            s = _CAUCHY_SCALE * _sigma_robust(rs, keep)
            return [1.0 / (1.0 + (np.hypot(r[:, 0], r[:, 1]) / s) ** 2) for r in rs]

        _, rs = gauss_newton(cauchy, iterations, _ROBUST_CONVERGED_PX)
        s = _sigma_robust(rs, keep)
        keep = [np.hypot(r[:, 0], r[:, 1]) <= OUTLIER_SIGMA * s for r in rs]
    unit = [k.astype(np.float64) for k in keep]
    Js, rs = gauss_newton(lambda rs: unit, iterations, _CONVERGED_PX)
    H, _, rr = _normal_equations(Js, rs, unit)
    n_cols = H.shape[0]
    n_obs = 2 * sum(int(k.sum()) for k in keep)
    sigma2 = rr / max(n_obs - n_cols, 1)
    inv = _inverse(H)
    P = n_cols - 3 * M
    T = _step_to_numbers(cam, rmax, codes, skew, P)
    cov = T @ (sigma2 * inv[3 * M:, 3 * M:]) @ T.T
    fitted = camera.replace(**dict(zip(lens.CAMERA_NUMBERS, cam.tolist(), strict=True)))
    return JointFit(camera=fitted, attitudes=attitudes, params=params, sigma_px=math.sqrt(sigma2),
                    covariance=cov, residuals_px=rs, inliers=keep, names=tuple(i.name for i in images),
                    xy=[i.xy for i in images], flux=[i.flux for i in images], mag=[i.mag for i in images])
