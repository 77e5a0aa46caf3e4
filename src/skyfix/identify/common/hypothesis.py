"""What the identification methods that propose star correspondences share.

A method of :data:`skyfix.identify.METHODS` other than the 4-star hash (the seeds' triangle,
angle, pyramid, grid, voting and match-group methods) proposes *hypotheses*: a few centroids
paired with catalogue stars. Whatever found them, a hypothesis is judged the same way, by the
rules of :mod:`skyfix.identify.accept`, so that no method can be less safe than another:

1. :func:`frame_for` — the frame as the verification kernels see it (a :class:`Frame`): the
   finite centroids, brightest first; the camera (the calibrated one given, else a pinhole of
   the FOV given, its focal length free within the FOV's tolerance: a method needs a scale);
   each centroid's ray; the database whose catalogue stars are matched (the one given, else
   the default band serving the field: :func:`skyfix.identify.catalogue.bands.database_for_fov`).
2. :func:`hypothesis` — what a correspondence implies (a :class:`Hypothesis`): with a FOV only,
   the focal length that makes the stars' angles the catalogue's (rule 2: within the allowed
   range); the proper rotation (SVD) that best brings the catalogue vectors onto the rays, and
   its largest residual. A mirror image has no proper rotation that fits: its residual is
   large and :func:`fits` rejects it (rule 3, :func:`skyfix.identify.accept.pattern_fits`).
3. :func:`chance_log_probability` — the verification (rule 5): the catalogue stars in view at
   that attitude, the hypothesis's own stars not counted, land on centroids; log P(a wrong
   attitude does as well) is their binomial tail (:func:`skyfix.identify.common.verify.verify_attitude`),
   and :func:`skyfix.identify.accept.log_prob_false` multiplies it by every hypothesis examined
   so far (the look-elsewhere effect: the method must count each one it verifies).
4. :func:`finish` — the refit on all matched stars (:func:`skyfix.identify.common.refine.refine`),
   itself beyond chance (rule 6) with its focal length in the allowed range (rule 7), packaged
   as an :class:`~skyfix.identify.Identification` the final fit takes as it takes the hash's.

A hypothesis of exactly three stars in a frame of three has nothing else to verify it against;
how much a lone triangle can prove is the triangle method's to say
(:mod:`skyfix.identify.methods.triangle`).
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Iterable
from typing import NamedTuple

import numpy as np

from skyfix._kernels.rotation import chord_angle
from skyfix.attitude import solve_attitude
from skyfix.camera import Camera
from skyfix.errors import CameraError
from skyfix.identify.accept import (
    CENTROID_SIGMA_PX,
    PROB_THRESHOLD,
    focal_allowed,
    log_prob_false,
    pattern_fits,
    refit_accepted,
    refit_focal_allowed,
)
from skyfix.identify.catalogue.bands import database_for_fov
from skyfix.identify.catalogue.database import PatternDatabase
from skyfix.identify.catalogue.kernel_data import ImageStars, RefineSettings, StarIndex, ViewBuffers
from skyfix.identify.common.refine import refine_entry
from skyfix.identify.common.result import Identification, finite_centroids
from skyfix.identify.common.verify import verify_attitude
from skyfix.validate import check_positive

__all__ = ["CORE_STARS", "Frame", "Hypothesis", "chance_log_probability", "failure", "finish",
           "first_accepted", "fits", "frame_for", "hypothesis", "rays_at"]

_VIEW = 8192  # catalogue stars projected per verification at most
CORE_STARS = 4
"""The stars of a proposal whose attitude the verification judges (:func:`first_accepted`): as
many as the 4-star method's pattern, so that every method's evidence is counted alike."""


class Frame(NamedTuple):
    """One frame as the correspondence methods see it (:func:`frame_for`).

    method : str — the method's registered name (it goes into the Identification).
    xy : (N, 2) — the finite centroids, brightest first; ``kept`` maps their rows back to the
        caller's (None: all were finite).
    camera : Camera — the calibrated camera, or a centred pinhole of the FOV given.
    calibrated : bool — ``camera`` was given (else its focal length is refitted).
    focal_range_px : (lo, hi) — the focal lengths allowed (equal for a calibrated camera).
    rays : (N, 3) — each centroid's unit vector in the camera frame through ``camera``.
    image : ImageStars — the centroids as the kernels see them (offsets at ``camera.fx``).
    database : PatternDatabase — whose catalogue stars are matched; ``stars`` its star index.
    n_verify : int — the brightest centroids (and as many catalogue stars) a verification matches.
    radius_px : float — the verification's match radius.
    log_threshold : float — log of the largest accepted probability of a chance match.
    refit : RefineSettings — the refit's settings.
    epoch : float or None — Julian year of the catalogue positions returned.
    t0 : float — ``time.perf_counter()`` when the method started.
    view : ViewBuffers — work space of the verification kernel.
    """

    method: str
    xy: np.ndarray
    kept: np.ndarray | None
    camera: Camera
    calibrated: bool
    focal_range_px: tuple[float, float]
    rays: np.ndarray
    image: ImageStars
    database: PatternDatabase
    stars: StarIndex
    n_verify: int
    radius_px: float
    log_threshold: float
    refit: RefineSettings
    epoch: float | None
    t0: float
    view: ViewBuffers

    @property
    def scale_tolerance(self) -> float:
        """The relative error of an angle measured through ``camera`` that the focal length's
        range allows (0 for a calibrated camera)."""
        lo, hi = self.focal_range_px
        f = self.camera.fx
        return max(f / lo - 1.0, 1.0 - f / hi)


def failure(method: str, reason: str, t0: float, n_tried: int = 0, n_candidates: int = 0) -> Identification:
    """A failed :class:`~skyfix.identify.Identification` of ``method`` with its ``reason``."""
    empty = np.zeros(0, np.int64)
    return Identification(False, reason, empty, empty, np.zeros((0, 3)), np.zeros(0, np.float32),
                          n_patterns_tried=n_tried, n_candidates=n_candidates, method=method,
                          time_s=time.perf_counter() - t0)


def _focal_from_fov(width: int, fov_deg: float) -> float:
    return width / 2.0 / math.tan(math.radians(fov_deg) / 2.0)


def frame_for(method: str, xy: np.ndarray, width: int, height: int, *, fov_deg: float | None,
              fov_tolerance_deg: float | None, camera: Camera | None, database: PatternDatabase | None,
              epoch: float | None, min_stars: int = 3, verify_stars: int = 60, refine_stars: int = 200,
              match_radius: float = 0.01, prob_threshold: float = PROB_THRESHOLD,
              centroid_sigma_px: float = CENTROID_SIGMA_PX) -> Frame | Identification:
    """The :class:`Frame` of one identification by ``method`` (the interface's arguments, see
    :mod:`skyfix.identify.methods`; the rest as :func:`skyfix.identify.methods.quad.identify`'s), or a
    failed Identification saying why it cannot be tried: fewer than ``min_stars`` centroids, or
    neither a camera nor a FOV (a correspondence method measures angles: it needs the scale).

    Raises
    ------
    skyfix.errors.CameraError
        An impossible ``fov_deg``.
    skyfix.errors.InputError
        A ``fov_deg`` or ``fov_tolerance_deg`` that is not a positive number; centroids that are
        not an (N, 2) array of numbers.
    """
    t0 = time.perf_counter()
    xy, kept = finite_centroids(xy)
    n = len(xy)
    if n < min_stars:
        return failure(method, f"too few stars ({n} detected, need {min_stars})", t0)
    if camera is None and fov_deg is None:
        return failure(method, f"the {method!r} method needs a field of view or a camera (it measures "
                               "angles between stars); give fov_deg or camera, or use the default method", t0)
    if camera is not None:
        cam, lo, hi = camera, float(camera.fx), float(camera.fx)
    else:
        fov_deg = check_positive(fov_deg, "fov_deg")  # a number (a string or NaN: one line)
        if fov_tolerance_deg is not None:
            fov_tolerance_deg = check_positive(fov_tolerance_deg, "fov_tolerance_deg")
        if not 0.01 < fov_deg < 170.0:
            raise CameraError(f"impossible field of view {fov_deg}° (must be 0.01°–170°)")
        tol = 0.1 * fov_deg if fov_tolerance_deg is None else fov_tolerance_deg
        cam = Camera.from_fov(int(width), int(height), float(fov_deg))
        lo = _focal_from_fov(width, min(fov_deg + tol, 179.0))
        hi = _focal_from_fov(width, max(fov_deg - tol, 1e-3))
    if database is None:
        database = database_for_fov(cam.fov_deg)
    f0 = float(cam.fx)
    p = cam.pixel_to_normalized(xy) * f0
    corners = np.array([[-0.5, -0.5], [width - 0.5, -0.5], [-0.5, height - 0.5], [width - 0.5, height - 0.5]])
    c_p = cam.pixel_to_normalized(corners) * f0
    extent = np.array([c_p[:, 0].min(), c_p[:, 0].max(), c_p[:, 1].min(), c_p[:, 1].max()])
    rays = np.column_stack([p / f0, np.ones(n)])
    rays /= np.linalg.norm(rays, axis=1)[:, None]
    radius = match_radius * max(width, height)
    n_verify = min(n, verify_stars)
    refit = RefineSettings(camera is None, 12, n_verify, min(n, refine_stars), float(radius),
                           float(centroid_sigma_px), 3)
    view = ViewBuffers(np.empty(_VIEW, np.int64), np.empty(_VIEW), np.empty(_VIEW), np.zeros(n, np.bool_),
                       np.empty(_VIEW, np.int64))
    return Frame(method, xy, kept, cam, camera is not None, (lo, hi), rays, ImageStars(p, extent),
                 database, database.star_index(), n_verify, float(radius), math.log(prob_threshold), refit,
                 epoch, t0, view)


class Hypothesis(NamedTuple):
    """A correspondence and the attitude it implies (:func:`hypothesis`).

    stars, catalog : (M,) int64 — centroid rows of :attr:`Frame.xy` and their catalogue stars
        (rows of :attr:`Frame.stars`).
    A_icrs_to_cam : (3, 3) — the proper rotation (SVD) that best brings the catalogue vectors
        onto the rays (``b ≈ A r``).
    focal_px : float — the focal length of the rays: the camera's, or with a FOV only the one
        that makes the stars' angles the catalogue's (NaN: outside the allowed range).
    max_residual_rad : float — the largest angle between a ray and its star at ``A`` (a mirror
        image's is large: no proper rotation fits it).
    """

    stars: np.ndarray
    catalog: np.ndarray
    A_icrs_to_cam: np.ndarray
    focal_px: float
    max_residual_rad: float


def rays_at(frame: Frame, stars: np.ndarray, focal_px: float) -> np.ndarray:
    """The unit rays of centroid rows ``stars`` at focal length ``focal_px``: their undistorted
    offsets from the principal point (:attr:`ImageStars.offsets_px`, pixels) over it."""
    p = frame.image.offsets_px[stars]
    v = np.column_stack([p, np.full(len(p), focal_px)])
    return v / np.linalg.norm(v, axis=1)[:, None]


@functools.lru_cache(maxsize=32)
def _pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    return np.triu_indices(n, 1)


def _pair_angles(v: np.ndarray) -> np.ndarray:
    i, j = _pairs(len(v))
    return chord_angle(np.sqrt(((v[i] - v[j]) ** 2).sum(axis=1)))


def _focal(frame: Frame, stars: np.ndarray, r: np.ndarray) -> float:
    """The focal length at which the stars' angles best match the catalogue's (secant steps on
    the summed angles, which shrink as the focal length grows); the camera's when calibrated."""
    f = float(frame.camera.fx)
    if frame.calibrated:
        return f
    target = float(_pair_angles(r).sum())
    p = frame.image.offsets_px[stars]
    v = np.empty((len(p), 3))
    v[:, :2] = p
    for _ in range(4):
        v[:, 2] = f
        seen = float(_pair_angles(v / np.sqrt((v * v).sum(axis=1))[:, None]).sum())
        if not (seen > 0.0 and target > 0.0):
            return math.nan
        f_next = f * seen / target
        if abs(f_next - f) < 1e-9 * f:
            break
        f = f_next
    return f


def hypothesis(frame: Frame, stars: np.ndarray, catalog: np.ndarray) -> Hypothesis:
    """The :class:`Hypothesis` that centroid rows ``stars`` (M ≥ 2) are catalogue stars
    ``catalog``: its focal length (rule 2: NaN outside :attr:`Frame.focal_range_px`), attitude
    and largest residual."""
    stars = np.asarray(stars, np.int64)
    catalog = np.asarray(catalog, np.int64)
    r = frame.stars.vectors[catalog]
    f = _focal(frame, stars, r)
    lo, hi = frame.focal_range_px
    if not (f == f and focal_allowed(f, lo, hi)):
        return Hypothesis(stars, catalog, np.eye(3), math.nan, math.inf)
    b = rays_at(frame, stars, f)
    A = solve_attitude(b, r, method="svd")
    cos = np.clip(np.einsum("ij,ij->i", b, r @ A.T), -1.0, 1.0)
    return Hypothesis(stars, catalog, A, f, float(np.arccos(cos).max()))


def fits(frame: Frame, h: Hypothesis) -> bool:
    """Accept rules 2 and 3 for a hypothesis: its focal length is allowed and its stars fit one
    proper rotation within the match radius (:func:`skyfix.identify.accept.pattern_fits`)."""
    return h.focal_px == h.focal_px and bool(pattern_fits(h.max_residual_rad, h.focal_px, frame.radius_px))


def chance_log_probability(frame: Frame, h: Hypothesis) -> float:
    """log P(a wrong attitude puts as many catalogue stars on centroids as the hypothesis's
    does), its own centroids and catalogue stars (all of them: a method's chosen stars match by
    construction) not counted — accept rule 5 before the look-elsewhere factor
    (:func:`skyfix.identify.accept.log_prob_false` with the hypotheses examined)."""
    own_catalog = np.ascontiguousarray(h.catalog, np.int64)
    own_stars = np.ascontiguousarray(h.stars, np.int64)
    logp, _, _ = verify_attitude(np.ascontiguousarray(h.A_icrs_to_cam), float(h.focal_px), frame.image,
                                 np.int64(frame.n_verify), np.int64(frame.n_verify), frame.radius_px,
                                 own_catalog, own_stars, frame.stars, frame.view)
    return float(logp)


def finish(frame: Frame, h: Hypothesis, log_p_match: float, n_tried: int,
           n_candidates: int) -> Identification | None:
    """The Identification of an accepted hypothesis ``h`` (its match's
    :func:`chance_log_probability` ``log_p_match``; ``n_tried`` image patterns and
    ``n_candidates`` hypotheses examined): refitted on all matched stars, or None when the
    refit is not itself beyond chance (rule 6) or leaves the focal range (rule 7)."""
    db = frame.database
    fit = refine_entry(tuple(frame.image), np.ascontiguousarray(h.A_icrs_to_cam),
                       float(h.focal_px), tuple(frame.refit), tuple(frame.stars))
    extent = frame.image.frame_px
    area = (extent[1] - extent[0]) * (extent[3] - extent[2])
    if not refit_accepted(fit.n_pairs, int(fit.n_catalog), frame.refit.n_img, float(fit.radius_px), area,
                          frame.log_threshold):
        return None
    lo, hi = frame.focal_range_px
    if not frame.calibrated and not refit_focal_allowed(float(fit.focal_px), lo, hi):
        return None
    order = np.argsort(fit.star_index)
    star_index, cat_index = fit.star_index[order], fit.catalog_index[order]
    camera = frame.camera
    if not frame.calibrated:
        f = float(fit.focal_px)
        camera = Camera(width=camera.width, height=camera.height, fx=f, fy=f, cx=camera.cx, cy=camera.cy,
                        k1=float(fit.k1))
    if frame.kept is not None:
        star_index = frame.kept[star_index]
    star_ids, star_mag, _ = db.star_arrays()
    prob = math.exp(min(log_prob_false(log_p_match, max(n_candidates, 1)), 0.0))
    return Identification(True, "", star_index, star_ids[cat_index], db.vectors_at(cat_index, frame.epoch),
                          star_mag[cat_index], fit.A_icrs_to_cam, camera, prob, n_tried, n_candidates,
                          frame.method, time.perf_counter() - frame.t0, float(fit.radius_px), database=db)


def first_accepted(frame: Frame, proposals: Iterable[tuple[np.ndarray, np.ndarray]], *, n_tried: int = 0,
                   max_candidates: int = 10_000) -> Identification:
    """The first of ``proposals`` — ``(stars, catalog)`` correspondences in the order a method
    ranks them — that passes every rule (:func:`fits`, :func:`chance_log_probability` with every
    proposal examined so far counted, :func:`finish`), or a failure saying how many were tried.
    ``n_tried``: the image patterns the method looked at (reported). A method that proposes
    through this function is exactly as safe as any other.

    A proposal of more than :data:`CORE_STARS` stars (a voting set, a match group) must fit as a
    whole, but is verified at the attitude of its first :data:`CORE_STARS` alone, the rest of
    its stars counted as evidence like any catalogue star in view: stars a method chose *because*
    they agree with each other would otherwise be evidence by construction (with all of them
    left out, a 20-star set has nothing left to verify it)."""
    n = 0
    for stars, catalog in proposals:
        n += 1
        if n > max_candidates:
            n -= 1
            break
        h = hypothesis(frame, stars, catalog)
        if not fits(frame, h):
            continue
        core = h
        if len(h.stars) > CORE_STARS:
            core = hypothesis(frame, h.stars[:CORE_STARS], h.catalog[:CORE_STARS])
        if not fits(frame, core):
            continue
        log_p = chance_log_probability(frame, core)
        if log_prob_false(log_p, n) > frame.log_threshold:
            continue
        result = finish(frame, h, log_p, n_tried, n)
        if result is not None:
            return result
    return failure(frame.method, f"no match after {n} candidate correspondences", frame.t0, n_tried, n)
