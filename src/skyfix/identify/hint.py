"""Identification from a known attitude: catalogue stars matched near where a hint puts them.

When the attitude is roughly known — the frame before, a filter's prediction, the spacecraft's
coarse attitude, a user who knows where the camera points — no pattern search is needed: the
catalogue stars are projected into the frame at the hint and matched to the centroids near
their predicted places. This is thesis 003's overlay (ch. 6 §III.B: catalogue stars drawn over
the detected spots and moved onto them) made automatic, and thesis 004 §4's catalogue-predicted
search windows (``r_search = r_star + r_uncert + r_rotation``) turned into a gate that grows
with the hint's uncertainty (``docs/seeds.md``). :func:`identify_near` does it:

1. *Catalogue stars near the hint.* The stars of the default database's star index
   (:meth:`skyfix.identify.PatternDatabase.star_index`: the same catalogue, epoch handling and
   projection as lost in space) within the field plus the uncertainty of the hint's boresight,
   projected at the hint (:func:`skyfix.identify.common.verify.project_stars`) into the frame grown by
   the gate.
2. *The gate.* A rotation by at most ``θ`` (the hint's uncertainty) moves a star at angle
   ``α`` from the boresight by at most ``f·θ·sec²(α + θ)`` pixels in the undistorted image
   plane (about the boresight it moves ``f·tan α·θ``, less); centroid noise (3√2 σ), 2 px, and
   with a field of view only guessed, the focal length's range times the frame's half
   diagonal, are added. Each of the brightest centroids (``pin_stars``) may pair with any
   bright catalogue star predicted within the gate.
3. *Pinning.* A gate of a few degrees holds several catalogue stars, so nearest neighbours
   would be a guess. Instead every two pairings (centroid ``a`` ↔ star ``s``, centroid ``b`` ↔
   star ``t``, ``a`` and ``b`` at least ``min_baseline`` apart) whose chord in the image
   matches the catalogue's (centroid noise and, with the field of view only guessed, 0.8 % for
   unmodelled distortion; the focal length the pair implies must be in the allowed range:
   accept rule 2) gives an attitude by TRIAD (``_kernels.rotation.triad``, thesis 004 §4.5),
   kept only when it is within the uncertainty of the hint. It is scored by how many of the brightest
   catalogue stars it puts on the brightest centroids (:func:`skyfix.identify.common.verify.match_grid`);
   the best-scoring attitude wins. Pairings that the best attitude already matches are not
   scored again (a good hint scores one or two attitudes).
4. *Verification* — the rules of lost in space (:mod:`skyfix.identify.accept`): the best
   attitude's match, its own two stars not counted, must be beyond chance at the same radii
   (:func:`skyfix.identify.common.verify.verify_attitude`) with every pairing the gate let compete
   counted as a trial (the look-elsewhere effect; rule 5). A wider gate lets more catalogue
   stars and centroids compete, so it must be beaten by a better match.
5. *Refit* on all stars (:func:`skyfix.identify.common.refine.refine`: the attitude, and with the
   field of view only guessed the focal length and k1; two fit-and-rematch passes, not lost
   in space's three: the pinned attitude starts closer, and the final fit refits anyway), which
   must itself be beyond chance (rule 6) with its focal length in the allowed range (rule 7).

``ok`` says the stars are identified. How precise the attitude is, is the final fit's
(:func:`skyfix.final_fit.final_fit`) covariance to say, and the precision rule
(:func:`skyfix.identify.accept.precision_failure`) to judge: a sparse, noisy field can be
identified beyond doubt and still leave the boresight a pixel or two uncertain (the pipeline
then fails the hint path and tries lost in space; a tracker should weigh the fit by its
covariance).

The result converts to an :class:`~skyfix.identify.Identification`
(:meth:`HintResult.identification`), so that :func:`skyfix.final_fit.final_fit` and the
precision rule of :func:`skyfix.pipeline.solve_centroids` judge it exactly as a lost-in-space
identification: a hint can make a frame faster to solve, never a wrong attitude "solved".
``skyfix.solve(..., attitude_hint=...)`` falls back to lost in space when this fails.

A scale is needed: a calibrated :class:`~skyfix.camera.Camera`, or a camera from a field of
view (``fit_camera=True``: the focal length is searched within ``fov_tolerance_deg``).
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.lens import offset_ray
from skyfix._kernels.rotation import det3, triad
from skyfix.camera import Camera
from skyfix.errors import InputError
from skyfix.geometry import attitude_from_radec_roll
from skyfix.identify.accept import (
    PROB_THRESHOLD,
    focal_allowed,
    is_verified,
    log_prob_false,
    refit_accepted,
    refit_focal_allowed,
)
from skyfix.identify.catalogue.bands import database_for_fov
from skyfix.identify.catalogue.database import PatternDatabase
from skyfix.identify.catalogue.kernel_data import ImageStars, RefineSettings, Refit, StarIndex, ViewBuffers
from skyfix.identify.common.refine import refine
from skyfix.identify.common.result import Identification, finite_centroids
from skyfix.identify.common.verify import (
    gather_stars,
    grid_index,
    match_grid,
    project_stars,
    star_limit,
    verify_attitude,
)

__all__ = ["DEFAULT_UNCERTAINTY_DEG", "MAX_UNCERTAINTY_DEG", "METHOD", "AttitudeHint", "HintResult",
           "HintSearch", "HintSettings", "check_attitude_hint", "identify_near", "near_entry", "search_near",
           "triad"]

METHOD = "attitude-hint"  # the Solution's ``method`` when the hint solved the frame
DEFAULT_UNCERTAINTY_DEG = 1.0
MAX_UNCERTAINTY_DEG = 30.0  # beyond that a hint hardly narrows the sky: solve lost in space
_HINT_FORM = "RA,DEC,ROLL[,UNCERTAINTY_DEG] in degrees (e.g. 84.0,-2.0,20.0,1.0)"
_BUFFER = 16384  # projected stars a kernel call can hold (as refine's)


# --- the hint itself --------------------------------------------------------------------------
class AttitudeHint(NamedTuple):
    """A rough attitude and how far the true one may be from it.

    A_icrs_to_cam : (3, 3) — the hinted attitude (``docs/design.md#attitude-matrix``).
    uncertainty_rad : float — the largest rotation angle between the hint and the true
        attitude (a bound, e.g. 3σ of a filter's error), radians.
    """

    A_icrs_to_cam: np.ndarray
    uncertainty_rad: float


def _finite_numbers(parts: Sequence[object]) -> list[float] | None:
    try:
        values = [float(v) for v in parts]
    except (TypeError, ValueError):
        return None
    return values if all(map(math.isfinite, values)) else None


def check_attitude_hint(value: object, name: str = "attitude_hint") -> AttitudeHint:
    """An :class:`AttitudeHint` from what a caller may give, checked before any work.

    Accepted: an :class:`AttitudeHint`; a string ``"RA,DEC,ROLL[,UNCERTAINTY_DEG]"`` (the command
    line's form, degrees); a sequence of those 3 or 4 numbers (degrees); a (3, 3) rotation
    matrix (``A_icrs_to_cam``). The uncertainty defaults to :data:`DEFAULT_UNCERTAINTY_DEG`.
    RA and roll are any finite angles, Dec within ±90°, the uncertainty in
    (0, :data:`MAX_UNCERTAINTY_DEG`] degrees.

    Raises
    ------
    skyfix.errors.InputError
        One line naming ``name`` (``--attitude-hint`` from the command line) and what it takes.
    """
    if isinstance(value, AttitudeHint):
        unc_deg = _degrees_or_nan(value.uncertainty_rad)
        _check_uncertainty(unc_deg, name)
        return AttitudeHint(_rotation_matrix(value.A_icrs_to_cam, name), math.radians(unc_deg))
    if isinstance(value, str):
        parts: list | None = value.split(",")
    else:
        try:
            array = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            array = None
        if array is not None and array.shape == (3, 3):
            return AttitudeHint(_rotation_matrix(array, name), math.radians(DEFAULT_UNCERTAINTY_DEG))
        parts = array.tolist() if array is not None and array.ndim == 1 else None
    numbers = _finite_numbers(parts) if parts is not None and len(parts) in (3, 4) else None
    if numbers is None:
        raise InputError(f"{name} {_show(value)} must be {_HINT_FORM}")
    ra, dec, roll, *rest = numbers
    if not -90.0 <= dec <= 90.0:
        raise InputError(f"{name}: Dec {dec:g} is outside -90..90 degrees")
    unc_deg = rest[0] if rest else DEFAULT_UNCERTAINTY_DEG
    _check_uncertainty(unc_deg, name)
    A = attitude_from_radec_roll(math.radians(ra), math.radians(dec), math.radians(roll))
    return AttitudeHint(A, math.radians(unc_deg))


def _degrees_or_nan(rad: object) -> float:
    try:
        return math.degrees(float(rad))
    except (TypeError, ValueError):
        return math.nan


def _show(value: object) -> str:
    text = repr(value) if isinstance(value, str) else str(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _check_uncertainty(unc_deg: float, name: str) -> None:
    if not 0.0 < unc_deg <= MAX_UNCERTAINTY_DEG:  # NaN fails too
        raise InputError(f"{name}: uncertainty {unc_deg:g}° must be a positive number of degrees up to "
                         f"{MAX_UNCERTAINTY_DEG:g} (a looser hint does not help: solve without one)")


def _rotation_matrix(A: object, name: str) -> np.ndarray:
    """``A`` as a C-contiguous float64 proper rotation (InputError otherwise)."""
    try:
        M = np.ascontiguousarray(A, dtype=np.float64)
    except (TypeError, ValueError):
        M = None
    if M is None or M.shape != (3, 3):
        raise InputError(f"{name} must be a 3×3 attitude matrix (A_icrs_to_cam) or {_HINT_FORM}")
    if not _is_rotation(M, 1e-6):
        raise InputError(f"{name} is not a rotation matrix (A·Aᵀ ≠ I or det < 0)")
    return M


@njit(cache=True)
def _is_rotation(M, tol):
    """Whether ``M`` (3, 3) is a proper rotation: finite, ``M·Mᵀ = I`` within ``tol``, det > 0
    (a kernel: the numpy checks cost 20 µs, a tenth of a good hint's identification)."""
    for i in range(3):
        for j in range(3):
            d = M[i, 0] * M[j, 0] + M[i, 1] * M[j, 1] + M[i, 2] * M[j, 2] - (1.0 if i == j else 0.0)
            if not abs(d) <= tol:  # NaN fails too
                return False
    return det3(M) > 0.0


# --- the kernels ------------------------------------------------------------------------------
class HintSettings(NamedTuple):
    """How :func:`search_near` pins and verifies; lengths in the offset space of
    :class:`~skyfix.identify.catalogue.kernel_data.ImageStars` (``x_n · f_px``).

    f_px : float — the focal length the offsets were scaled by (the camera's or the FOV's).
    f_lo_px, f_hi_px : float — the allowed focal lengths (both ``f_px`` for a calibrated camera).
    fit_focal : bool — the focal length is searched (a field of view only guessed).
    uncertainty_rad : float — the largest rotation between the hint and the true attitude.
    gate_px : float — the largest distance between a star's place predicted at the hint and
        its centroid.
    n_pin : int — brightest centroids paired with catalogue stars.
    n_pin_catalog : int — brightest catalogue stars, predicted in the frame grown by the gate,
        they may pair with.
    min_baseline_px : float — the shortest distance between two pinned centroids.
    pair_tolerance_px : float — how far a pair's chord may differ from the catalogue's (noise).
    pair_tolerance_rel : float — and in proportion to its length (unmodelled distortion).
    n_verify : int — brightest centroids (and catalogue stars) in scoring and verification.
    radius_px : float — match radius of scoring and verification.
    log_threshold : float — log of the largest accepted chance probability.
    """

    f_px: float
    f_lo_px: float
    f_hi_px: float
    fit_focal: bool
    uncertainty_rad: float
    gate_px: float
    n_pin: int
    n_pin_catalog: int
    min_baseline_px: float
    pair_tolerance_px: float
    pair_tolerance_rel: float
    n_verify: int
    radius_px: float
    log_threshold: float


class HintSearch(NamedTuple):
    """What :func:`search_near` found.

    success : bool — the best attitude passed verification (accept rule 5).
    n_trials : int — pairings of two centroids with two catalogue stars that the gate let
        compete (the look-elsewhere count).
    n_candidates : int — attitudes scored.
    log_prob_false : float — rule 5's number for the best attitude (0 when there is none).
    A_icrs_to_cam : (3, 3) — the best attitude (the hint when there is none).
    focal_px : float — its focal length.
    n_matched, n_catalog : int — its verification matches and catalogue stars.
    """

    success: bool
    n_trials: int
    n_candidates: int
    log_prob_false: float
    A_icrs_to_cam: np.ndarray
    focal_px: float
    n_matched: int
    n_catalog: int


@njit(cache=True, inline="always")
def _ray(p, i, f, out):
    """The unit camera ray of offset ``p[i]`` at focal length ``f`` into ``out``."""
    out[0], out[1], out[2] = offset_ray(p[i, 0], p[i, 1], f)


@njit(cache=True, inline="always")
def _chord(u, v):
    return np.sqrt((u[0] - v[0]) ** 2 + (u[1] - v[1]) ** 2 + (u[2] - v[2]) ** 2)


@njit(cache=True)
def search_near(image, A_hint, settings, stars):
    """Steps 1–4 of the module text: the catalogue stars near the hint ``A_hint`` (of the
    :class:`StarIndex` ``stars``), the pairings the gate allows, each consistent pairing's
    TRIAD attitude scored, and the best one verified. ``image`` is an :class:`ImageStars`,
    ``settings`` a :class:`HintSettings`. Returns a :class:`HintSearch`."""
    p, frame = image.offsets_px, image.frame_px
    s = settings
    n = p.shape[0]
    n_verify = min(n, s.n_verify)
    n_pin = min(n, s.n_pin)
    f0 = s.f_px
    vectors = stars.vectors
    view = ViewBuffers(np.empty(_BUFFER, dtype=np.int64), np.empty(_BUFFER), np.empty(_BUFFER),
                       np.zeros(n, dtype=np.bool_), np.empty(_BUFFER, dtype=np.int64))
    # 1. The stars that can be in the frame at any attitude within the uncertainty, deep enough
    # for the verification, and the brightest predicted in the frame grown by the gate.
    ext = np.sqrt(max(frame[0] ** 2, frame[1] ** 2) + max(frame[2] ** 2, frame[3] ** 2))
    cone = np.arctan(ext / s.f_lo_px) + s.uncertainty_rad + 0.02
    limit = star_limit(len(vectors), n_verify, frame, s.f_hi_px, 3.0)
    near = gather_stars(A_hint[2], cone, limit, stars)
    g = s.gate_px
    grown = np.array([frame[0] - g, frame[1] + g, frame[2] - g, frame[3] + g])
    n_pc = project_stars(near, A_hint, f0, 0.0, grown, s.n_pin_catalog, stars, view)
    pc_idx = view.index[:n_pc].copy()
    # 2. Each pinned centroid's catalogue stars within the gate.
    cand = np.empty((max(n_pin, 1), max(n_pc, 1)), dtype=np.int64)
    n_cand_of = np.zeros(max(n_pin, 1), dtype=np.int64)
    for a in range(n_pin):
        for j in range(n_pc):
            if (p[a, 0] - view.x_px[j]) ** 2 + (p[a, 1] - view.y_px[j]) ** 2 <= g * g:
                cand[a, n_cand_of[a]] = j
                n_cand_of[a] += 1
    # 3. Pairings of two pinned centroids with two of their catalogue stars. The pinned rays at
    # f0 and the candidates' vectors are gathered once (the inner loop runs thousands of times
    # for a gate of degrees); rays at another focal length only for a pair that may fit.
    pc_v = np.empty((max(n_pc, 1), 3))
    for j in range(n_pc):
        pc_v[j] = vectors[pc_idx[j]]
    rays0 = np.empty((max(n_pin, 1), 3))
    for a in range(n_pin):
        _ray(p, a, f0, rays0[a])
    grid = grid_index(p, n_verify, frame, 2.0 * s.radius_px)
    best_of_img = np.full(n, -1, dtype=np.int64)  # the catalogue star of each centroid, best attitude
    best_k = 0
    best_A = A_hint.copy()
    best_f = f0
    pattern = np.full(4, -1, dtype=np.int64)  # the best attitude's two catalogue stars
    combo = np.full(4, -1, dtype=np.int64)  # and centroids (not counted in verification)
    ba = np.empty(3)
    bb = np.empty(3)
    n_trials = 0
    n_scored = 0
    for a in range(n_pin):
        for b in range(a + 1, n_pin):
            baseline = np.sqrt((p[a, 0] - p[b, 0]) ** 2 + (p[a, 1] - p[b, 1]) ** 2)
            if baseline < s.min_baseline_px:
                continue
            chord0 = _chord(rays0[a], rays0[b])
            for ia in range(n_cand_of[a]):
                cs = cand[a, ia]
                for ib in range(n_cand_of[b]):
                    ct = cand[b, ib]
                    if ct == cs:
                        continue
                    n_trials += 1
                    chord_cat = _chord(pc_v[cs], pc_v[ct])
                    f1 = f0
                    if s.fit_focal:  # chords scale ~ 1/f: the focal length the pair implies, refined once
                        f1 = f0 * chord0 / chord_cat
                        if not focal_allowed(f1, 0.99 * s.f_lo_px, 1.01 * s.f_hi_px):
                            continue
                        _ray(p, a, f1, ba)
                        _ray(p, b, f1, bb)
                        f1 = f1 * _chord(ba, bb) / chord_cat
                        if not focal_allowed(f1, s.f_lo_px, s.f_hi_px):  # accept rule 2
                            continue
                        _ray(p, a, f1, ba)
                        _ray(p, b, f1, bb)
                        chord1 = _chord(ba, bb)
                    else:
                        chord1 = chord0
                    if abs(chord1 - chord_cat) > s.pair_tolerance_px / f1 + s.pair_tolerance_rel * chord_cat:
                        continue
                    js, jt = pc_idx[cs], pc_idx[ct]
                    if best_of_img[a] == js and best_of_img[b] == jt:
                        continue  # the best attitude already matches this pairing
                    if not s.fit_focal:
                        ba[:] = rays0[a]
                        bb[:] = rays0[b]
                    A, ok = triad(ba, bb, pc_v[cs], pc_v[ct], 1e-12)
                    if not ok:
                        continue
                    # Within the uncertainty of the hint, plus what two noisy stars leave of the roll.
                    trace = 0.0
                    for i in range(3):
                        for k in range(3):
                            trace += A[i, k] * A_hint[i, k]
                    allowed = s.uncertainty_rad + s.pair_tolerance_px * (1.0 / f1 + 1.0 / baseline)
                    if (trace - 1.0) / 2.0 < np.cos(min(allowed, np.pi)):
                        continue
                    n_scored += 1
                    n_cat = project_stars(near, A, f1, 0.0, frame, n_verify, stars, view)
                    k = match_grid(view, n_cat, p, n_verify, grid, s.radius_px)
                    if k > best_k:
                        best_k, best_A, best_f = k, A, f1
                        pattern[0], pattern[1], combo[0], combo[1] = js, jt, a, b
                        best_of_img[:] = -1
                        for j in range(n_cat):
                            if view.match[j] >= 0:
                                best_of_img[view.match[j]] = view.index[j]
    if best_k == 0:
        return HintSearch(False, n_trials, n_scored, 0.0, best_A, best_f, 0, 0)
    # 4. Verification of the best attitude, its own two stars left out (rules 5).
    logp, k_match, n_cat = verify_attitude(best_A, best_f, image, n_verify, n_verify, s.radius_px, pattern,
                                           combo, stars, view)
    logp = log_prob_false(logp, max(n_trials, 1))  # every pairing the gate let compete
    return HintSearch(is_verified(logp, s.log_threshold), n_trials, n_scored, logp, best_A, best_f, k_match,
                      n_cat)


@njit(cache=True)
def near_entry(image, A_hint, settings, refine_settings, stars):
    """:func:`search_near` and, when it verified an attitude, the refit on all stars
    (:func:`skyfix.identify.common.refine.refine`): ``(HintSearch, Refit)``. The NamedTuple arguments
    come as plain tuples (``tuple(nt)``), as :func:`skyfix.identify.common.refine.refine_entry`'s
    (:mod:`skyfix.identify.catalogue.kernel_data` says why)."""
    image = ImageStars(*image)
    stars = StarIndex(*stars)
    hit = search_near(image, A_hint, HintSettings(*settings), stars)
    if hit.success:
        return hit, refine(image, hit.A_icrs_to_cam, hit.focal_px, RefineSettings(*refine_settings), stars)
    none = np.zeros(1, dtype=np.int64)[:0]
    return hit, Refit(0, none, none, hit.A_icrs_to_cam.copy(), hit.focal_px, 0.0, 0.0, 0.0, 0)


# --- the Python entry -------------------------------------------------------------------------
class HintResult(NamedTuple):
    """What :func:`identify_near` returns.

    success : bool — the stars are identified near the hint (accept rules 2 and 5–7).
    reason : str — why not ("" on success).
    A_icrs_to_cam : (3, 3) or None — the refitted attitude (its precision: the final fit's)...
    camera : Camera or None — the camera given, or (``fit_camera``) one with the focal length
        and k1 fitted.
    star_index : (M,) int — the matched centroids (indices into ``xy``: image rows, as
        :attr:`Identification.star_index`), ascending.
    catalog_index : (M,) int — their catalogue stars: indices into the database's star arrays
        (:meth:`~skyfix.identify.PatternDatabase.star_arrays`, brightness ranks).
    catalog_ids : (M,) int — their Hipparcos numbers.
    catalog_vectors : (M, 3) — their ICRS unit vectors at ``epoch``.
    catalog_mag : (M,) — their Hp magnitudes.
    prob_false : float — probability that the match is chance, every pairing counted (rule 5).
    n_trials : int — pairings the gate let compete; n_candidates : int — attitudes scored.
    gate_px : float — the gate; match_radius_px : float — the refit's last match radius.
    rms_px : float — the refit's RMS residual.
    time_s : float — wall time.
    """

    success: bool
    reason: str
    A_icrs_to_cam: np.ndarray | None
    camera: Camera | None
    star_index: np.ndarray
    catalog_index: np.ndarray
    catalog_ids: np.ndarray
    catalog_vectors: np.ndarray
    catalog_mag: np.ndarray
    prob_false: float
    n_trials: int
    n_candidates: int
    gate_px: float
    match_radius_px: float
    rms_px: float
    time_s: float

    def identification(self) -> Identification:
        """The same result as an :class:`~skyfix.identify.Identification` (``method`` is
        :data:`METHOD`), for :func:`skyfix.final_fit.final_fit`."""
        return Identification(self.success, self.reason, self.star_index, self.catalog_ids,
                              self.catalog_vectors,
                              self.catalog_mag, self.A_icrs_to_cam, self.camera, self.prob_false, 0,
                              self.n_candidates, METHOD, self.time_s, self.match_radius_px)


def _failure(reason: str, t0: float, gate_px: float = 0.0, n_trials: int = 0, n_candidates: int = 0,
             prob_false: float = 1.0) -> HintResult:
    empty = np.zeros(0, np.int64)
    return HintResult(False, reason, None, None, empty, empty, empty, np.zeros((0, 3)), np.zeros(0),
                      prob_false, n_trials, n_candidates, gate_px, 0.0, 0.0, time.perf_counter() - t0)


@functools.lru_cache(maxsize=16)
def _frame_px(camera: Camera) -> np.ndarray:
    """The frame's extent ``x_lo, x_hi, y_lo, y_hi`` in the offsets of :func:`identify_near`
    (``x_n · fx``; the corners undistorted: a bounding box), once per camera (the kernels only
    read it)."""
    w, h = camera.width, camera.height
    corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]])
    c_p = camera.pixel_to_normalized(corners) * float(camera.fx)
    return np.array([c_p[:, 0].min(), c_p[:, 0].max(), c_p[:, 1].min(), c_p[:, 1].max()])


# Over ten parameters: the interface the spec names (xy, camera, hint, uncertainty, database,
# epoch, mag_limit) and the options lost in space shares (thresholds and star counts, the
# names of skyfix.identify.methods.quad.identify's), all keywords with a documented default.
def identify_near(xy: np.ndarray, camera: Camera, A_hint: np.ndarray, uncertainty_rad: float, *,
                  database: PatternDatabase | None = None, epoch: float | None = None,
                  mag_limit: float | None = None, fit_camera: bool = False,
                  fov_tolerance_deg: float | None = None, prob_threshold: float = PROB_THRESHOLD,
                  pin_stars: int = 10, verify_stars: int = 60, refine_stars: int = 200,
                  match_radius: float = 0.01, centroid_sigma_px: float = 1.0) -> HintResult:
    """Identify the stars of one frame near a known attitude, and refit it (the module text).

    Parameters
    ----------
    xy : (N, 2) float
        Centroids, pixels, brightest first (``docs/design.md#pixel-coordinates``); non-finite
        rows are skipped (the indices returned refer to the caller's rows).
    camera : Camera
        The camera model (its distortion is removed before matching). With ``fit_camera`` it
        is only a guess of the scale (``Camera.from_fov``).
    A_hint : (3, 3)
        The hinted attitude ``A_icrs_to_cam``.
    uncertainty_rad : float
        The largest rotation angle between the hint and the true attitude, radians
        (0 < it ≤ 30°). The gate, and with it the work and the chance matches to beat, grow
        with it.
    database : PatternDatabase, optional
        Whose star index is matched (default: the default FOV band's that serves the camera,
        :func:`~skyfix.identify.catalogue.bands.database_for_fov`).
    epoch : float, optional
        Julian year of the catalogue positions returned (default: the database's).
    mag_limit : float, optional
        Only catalogue stars at least this bright (Hp) are predicted.
    fit_camera : bool
        The camera is a field-of-view guess: search the focal length within
        ``fov_tolerance_deg`` (default 10 % of the FOV) and fit it and k1 to the stars.
    prob_threshold : float
        Largest accepted probability that the match is chance (as lost in space).
    pin_stars : int
        Brightest centroids paired with catalogue stars to pin the attitude.
    verify_stars, refine_stars, match_radius, centroid_sigma_px
        As :func:`skyfix.identify.methods.quad.identify`'s: centroids in verification and in the refit,
        the match radius (fraction of the frame's larger side), the centroid noise (px).

    Returns
    -------
    HintResult
        ``ok`` with the attitude and the matched stars, or the reason it failed (a frame that
        cannot be identified near the hint is a result, never an exception).

    Raises
    ------
    skyfix.errors.InputError
        ``A_hint`` is not a rotation, the uncertainty is out of range, ``camera`` is not a Camera.

    Examples
    --------
    >>> from skyfix.identify.hint import identify_near
    >>> res = identify_near(xy, camera, A_prev, math.radians(0.5))   # doctest: +SKIP
    >>> res.success, res.A_icrs_to_cam, res.catalog_ids                     # doctest: +SKIP
    """
    if not isinstance(camera, Camera):
        raise InputError(f"camera must be a Camera (Camera.load(path) or Camera.from_fov), "
                         f"got {type(camera).__name__}")
    A_hint = _rotation_matrix(A_hint, "A_hint")
    _check_uncertainty(_degrees_or_nan(uncertainty_rad), "uncertainty_rad")
    from skyfix import warmup

    warmup.ensure("hint")  # its kernels, compiled up front on first use (not counted in its time)
    t0 = time.perf_counter()
    theta = float(uncertainty_rad)
    xy, kept = finite_centroids(xy)  # kept maps back to the caller's indices
    n = len(xy)
    if n < 4:
        return _failure(f"too few stars ({n} detected, need 4)", t0)
    db = database_for_fov(camera.fov_deg) if database is None else database
    stars = db.star_index()
    if mag_limit is not None:  # the kernels read no star beyond len(vectors)
        n_bright = int(np.searchsorted(db.star_arrays()[1], mag_limit, side="right"))
        stars = stars._replace(vectors=stars.vectors[:n_bright])
    width, height = camera.width, camera.height
    f0 = float(camera.fx)
    f_lo = f_hi = f0
    if fit_camera:
        fov = camera.fov_deg
        tol = 0.1 * fov if fov_tolerance_deg is None else float(fov_tolerance_deg)
        f_lo = Camera.from_fov(width, height, min(fov + tol, 169.0)).fx
        f_hi = Camera.from_fov(width, height, max(fov - tol, 0.02)).fx
    # The centroids as undistorted offsets at f0, and the frame's extent (its corners undistorted).
    n_use = min(n, max(pin_stars, verify_stars, refine_stars))
    p = camera.pixel_to_normalized(xy[:n_use]) * f0
    frame = _frame_px(camera)
    # The gate (module text, step 2).
    ext = math.sqrt(max(frame[0] ** 2, frame[1] ** 2) + max(frame[2] ** 2, frame[3] ** 2))
    alpha = math.atan(ext / f_lo)
    noise_px = 3.0 * math.sqrt(2.0) * centroid_sigma_px
    gate = f0 * theta * (1.0 + math.tan(min(alpha + theta, 1.5)) ** 2) + noise_px + 2.0
    if fit_camera:
        gate += ext * max(f_hi / f0 - 1.0, 1.0 - f_lo / f0)
    frame_w, frame_h = frame[1] - frame[0], frame[3] - frame[2]
    area = frame_w * frame_h
    grown_ratio = (frame_w + 2 * gate) * (frame_h + 2 * gate) / area
    n_verify = min(n, verify_stars)
    radius = match_radius * max(width, height)
    log_threshold = math.log(prob_threshold)
    settings = HintSettings(f0, f_lo, f_hi, bool(fit_camera), theta, gate, int(pin_stars),
                            int(min(400, math.ceil(3 * pin_stars * grown_ratio))),
                            0.15 * max(frame_w, frame_h), noise_px + 1.0, 0.008 if fit_camera else 0.002,
                            int(n_verify), float(radius), log_threshold)
    refit = RefineSettings(bool(fit_camera), 12, n_verify, min(n, refine_stars), float(radius),
                           float(centroid_sigma_px), 2)
    image = ImageStars(np.ascontiguousarray(p), frame)
    hit, fit = near_entry(tuple(image), A_hint, tuple(settings), tuple(refit), tuple(stars))
    prob = float(min(math.exp(hit.log_prob_false), 1.0))
    counts = dict(gate_px=gate, n_trials=int(hit.n_trials), n_candidates=int(hit.n_candidates),
                  prob_false=prob)
    if hit.n_candidates == 0:
        return _failure(f"no two of the {min(n, pin_stars)} brightest stars match catalogue stars within "
                        f"{gate:.0f} px of where the attitude hint puts them", t0, **counts)
    if not hit.success:
        return _failure(f"the best match near the attitude hint is not beyond chance ({hit.n_matched} of "
                        f"{hit.n_catalog} catalogue stars matched, P(chance) {prob:.2g} with {hit.n_trials} "
                        f"pairings tried)", t0, **counts)
    if not refit_accepted(fit.n_pairs, fit.n_catalog, refit.n_img, float(fit.radius_px), area,
                          log_threshold):  # accept rule 6
        return _failure(f"the refit near the attitude hint is not beyond chance ({fit.n_pairs} of "
                        f"{fit.n_catalog} catalogue stars matched)", t0, **counts)
    if fit_camera and not refit_focal_allowed(float(fit.focal_px), f_lo, f_hi):  # accept rule 7
        fov_fit = 2.0 * math.degrees(math.atan(width / 2.0 / float(fit.focal_px)))
        return _failure(f"the field of view fitted near the attitude hint, {fov_fit:.3g}°, is outside the "
                        f"one given", t0, **counts)
    image_index, cat_index = fit.star_index, fit.catalog_index
    order = np.argsort(image_index)
    image_index, cat_index = image_index[order], cat_index[order]
    if fit_camera:
        f_fit = float(fit.focal_px)
        camera = Camera(width=width, height=height, fx=f_fit, fy=f_fit, cx=camera.cx, cy=camera.cy,
                        k1=float(fit.k1))
    if kept is not None:
        image_index = kept[image_index]
    star_ids, star_mag, _ = db.star_arrays()
    return HintResult(True, "", fit.A_icrs_to_cam, camera, image_index, cat_index, star_ids[cat_index],
                      db.vectors_at(cat_index, epoch), star_mag[cat_index], prob, int(hit.n_trials),
                      int(hit.n_candidates), gate, float(fit.radius_px), float(fit.rms_px),
                      time.perf_counter() - t0)
