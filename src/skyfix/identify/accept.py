"""When a match of image stars to catalogue stars counts as an identification.

A match is accepted only when chance cannot explain it. The test is the same wherever a set of
matches is judged — after a pattern's refit (:mod:`skyfix.identify.methods.quad`) and after the final
fit with a camera model fitted to the same stars (:mod:`skyfix.final_fit`):

*Chance.* ``n_cat`` catalogue stars are predicted in the frame; each lands within ``radius``
pixels of one of ``n_img`` centroids scattered over ``area`` pixels with probability
``p = n_img·π·radius² / area`` (capped at 1). ``k`` or more chance matches out of ``n_cat``
is a binomial tail, and the match is accepted when that tail is below ``exp(log_threshold)``
(``prob_threshold`` of :func:`skyfix.identify.identify`, 1e-9 by default).

*Freedom paid for.* A camera model fitted to the matched stars can bend to fit them: each
number it fits beyond the focal length can put about half a star (two coordinates) where it
wants. The test therefore discounts ``ceil(n_extra / 2)`` matches, ``n_extra`` being the
effective number of camera numbers the fit took beyond the focal length (the trace of its hat
matrix less the rotations and the focal length). Without this a sparse field whose model was
chosen from the same few stars it was verified against was accepted with wrong stars
(``tests/core/test_final_fit.py::test_sparse_non_square_never_wrong``).

*Precise enough to be right.* Identification can be sure of the stars while the attitude is
not sure enough to be called right: a sparse field from an unknown camera (aspect, distortion
and principal point unknown) can leave the boresight uncertain by tens of arcseconds. A
solution counts as solved only when its own covariance gives it a chance of at most
:data:`MAX_WRONG_PROBABILITY` (1e-3) of an error beyond what makes it wrong — boresight
max(60″, 1 px), roll 0.5° (:func:`wrong_probability`, :func:`precision_failure`); otherwise it
fails with the σ in the reason. A bar on 2σ (the first rule) let through solutions with a 1–10 %
chance of being wrong: on 10 000 blind uncalibrated sparse fields with honest error bars
(normalised RMS 1.02–1.08) that bound summed to 5.3 expected wrong attitudes and one came
70″ off at 2.6σ; at 1e-3 the bound sums to 0.24 and 667 of 8767 solutions (7.6 %) fail instead
(``tests/core/test_final_fit.py::test_precision_rule_bounds_the_chance_of_a_wrong_attitude``).
The σ behind a covariance is estimated from the fit's residuals, with Student's tails for their
few degrees of freedom; a centroid noise stated beside a calibrated camera is combined with them
(:func:`noise_posterior`): three stars' six residuals cannot bound their own noise
(``tests/identify/test_noise_prior.py``).

The rules, in the order a frame meets them
------------------------------------------
Each rule has a function or a constant of its own; a rule that runs inside a compiled kernel
is a small ``@njit(inline="always")`` helper here that the kernel calls (as fast as the
arithmetic written out). The tests named pin them.

Identification by the 4-star method (:func:`skyfix.identify.methods.quad.identify`). Rules 1–5 run for
each candidate pattern inside the compiled search (:func:`skyfix.identify.common.search.search`):

1. :func:`ratio_tolerance` — the candidate's five edge ratios agree with the image pattern's.
2. :func:`focal_allowed` — the focal length the candidate implies is in the allowed range.
3. :func:`pattern_fits` — its four stars fit one proper rotation within the match radius.
4. :func:`quick_check_fails` — a quick verification on the brightest stars rejects most false
   candidates cheaply.
5. :func:`log_prob_false`, :func:`is_verified` — the verification: the catalogue stars in view
   land on centroids far beyond chance, every candidate examined so far counted.
6. :func:`refit_accepted` — the refit on all matched stars is itself beyond chance (*Chance*
   above, :func:`is_beyond_chance`).
7. :func:`refit_focal_allowed` — the refit's focal length stays near the allowed range.

A sparse frame (three to :data:`~skyfix.identify.common.lone.LONE_MAX_STARS` centroids) that
rules 1–7 cannot settle is judged as a lone triangle on its own chance
(:func:`skyfix.identify.common.lone.judge_lone` holds 8–11, for the ``triangle`` method and the
pair-table methods' sparse frames; docs/identification-methods.md#triangle):

8. How unusual a match this close is: λ, the catalogue triangles within the window around the
   measured one (:func:`~skyfix.identify.common.lone.window_rad`) not refuted by rule 11 where
   they stand, scaled to the box the match falls in.
9. Every look counted: λ times the image triangles tried.
10. Every other star counted: times the binomial tail of the other catalogue stars in view that
    land on centroids (:func:`chance_log_probability`).
11. Nothing bright missing: a catalogue star in the frame brighter than the triangle's faintest
    by ``missing_margin`` on no centroid refutes the hypothesis.
12. The triangle holds: with five or more stars matched, each of its three fits the attitude the
    others give (``methods.triangle._triangle_holds``, a Rayleigh cut as rule 16's).
13. Unique: two hypotheses that put the camera in different places within
    :data:`~skyfix.identify.common.lone.AMBIGUITY_RATIO` of the best chance fail "ambiguous".
14. Not mirrored: the frame flipped left-right matching more surely refuses the match
    (:func:`skyfix.identify.methods.triangle.unless_mirrored`).
15. The product of 8–10 is at most ``lone_prob_threshold`` (1e-4 by default), reported as
    ``prob_false``.

The final fit (:func:`skyfix.final_fit.final_fit`), whose rules live beside the fits they judge:

16. A calibrated camera: a star more than 4 σ (median-based, floored at 0.1 px) from the fitted
    attitude is dropped, at least half and three kept — :func:`skyfix.final_fit.inliers`
    (``tests/_kernels/test_final_fit_kernels.py::test_inliers_drop_outliers_keep_half``).
17. No camera: while the worst star's externally studentised χ² is beyond
    ``skyfix._kernels.camera_fit.outlier_limit`` (a good star's chance 3.4e-4, ``OUTLIER_CHI2``)
    it is dropped and the camera refitted (``fit_camera_with_prior(..., drop_outliers=True)``;
    ``tests/core/test_final_fit.py::test_outlier_cut_drops_a_star_off_the_fitted_camera_and_only_it``).
18. No camera: the stars re-matched through the fitted camera must be beyond chance with the
    camera's freedom paid for (*Freedom paid for* above, :func:`chance_log_probability`);
    otherwise the verified stars are kept.

The solution (:func:`skyfix.pipeline.solve_centroids`):

19. :func:`precision_failure` — precise enough to be right (above).

Every "rule N" in skyfix's code, tests and docs is this list's.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.probability import log_binom_sf

__all__ = ["CENTROID_SIGMA_PX", "MAX_WRONG_PROBABILITY", "PROB_THRESHOLD", "QUAD_CENTROID_SIGMA_PX",
           "MIN_REFIT_PAIRS", "MIN_VARIANCE_DOF", "NOISE_PRIOR_DOF", "NoiseEstimate",
           "QUICK_CATALOG_STARS", "QUICK_CENTROIDS", "QUICK_LOG_P", "WRONG_BORESIGHT_ARCSEC",
           "WRONG_ROLL_DEG", "chance_log_probability", "error_covariance", "focal_allowed",
           "is_beyond_chance",
           "is_verified", "log_prob_false", "no_rotation_fits", "noise_posterior", "pattern_fits",
           "precision_failure", "quick_check_fails", "ratio_tolerance", "refit_accepted",
           "refit_focal_allowed", "wrong_probability"]

# What makes an attitude wrong (the campaigns' and the benchmarks' bar): boresight error beyond
# max(WRONG_BORESIGHT_ARCSEC, one pixel), or roll error beyond WRONG_ROLL_DEG.
WRONG_BORESIGHT_ARCSEC = 60.0
WRONG_ROLL_DEG = 0.5
_ARCSEC = math.pi / (180.0 * 3600.0)


def chance_log_probability(n_pairs: int, n_cat: int, n_img: int, radius_px: float, area_px2: float,
                           n_extra: float = 0.0) -> float:
    """log P(a match at least this good by chance), see the module text.

    Parameters
    ----------
    n_pairs : int — catalogue stars matched.
    n_cat : int — catalogue stars predicted in the frame (the trials).
    n_img : int — centroids they could match.
    radius_px : float — match radius, px.
    area_px2 : float — frame area, px².
    n_extra : float — camera numbers fitted to these stars beyond the focal length.
    """
    p_chance = min(1.0, n_img * math.pi * radius_px**2 / max(area_px2, 1e-300))
    k = n_pairs - math.ceil(max(n_extra, 0.0) / 2.0 - 1e-9)
    return float(log_binom_sf(k, int(n_cat), p_chance))


def is_beyond_chance(n_pairs: int, n_cat: int, n_img: int, radius_px: float, area_px2: float,
                     log_threshold: float, n_extra: float = 0.0) -> bool:
    """Whether a match passes :func:`chance_log_probability` ``<= log_threshold``."""
    return chance_log_probability(n_pairs, n_cat, n_img, radius_px, area_px2, n_extra) <= log_threshold

# --- 1–5: each candidate pattern, inside the compiled search ---------------------------------
@njit(cache=True, inline="always")
def ratio_tolerance(sigma_px: float, largest_edge_rad: float, f_px: float, model_err: float) -> float:
    """Rule 1: how far a candidate's edge ratios may be from the image pattern's (each of the
    five, after the focal length is estimated).

    Why: a centroid off by σ per axis moves an edge by up to about √2·σ at each end, so a ratio
    to the largest edge ``L`` (``largest_edge_rad · f_px`` pixels) by about 2·√2·σ / L; twice
    that covers the noise's tail, and ``model_err`` (the search tier's allowance for an
    unmodelled camera: distortion, a far-off focal length) is added. Tighter, true patterns are
    lost; looser, more false candidates reach verification (slower, never wrong: rule 5).
    Pinned by ``tests/identify/test_identify_accept.py::test_ratio_tolerance_covers_the_centroid_noise``
    (99.9 % of true patterns with noise σ pass, fewer than 90 % with 2σ). The solve-rate tests
    do not pin it: they still pass with a tolerance ten times tighter (a field needs one pattern).
    """
    return 4.0 * 1.4142 * sigma_px / (largest_edge_rad * f_px) + model_err


@njit(cache=True, inline="always")
def focal_allowed(f_px: float, lo_px: float, hi_px: float) -> bool:
    """Rule 2: the focal length a candidate implies (from its largest edge) is in the allowed
    range — the FOV hint ± its tolerance, a calibrated camera's ± 3 %, or what the database
    serves.

    Why: a pattern of the right shape at the wrong scale is another pattern, and it is cheaper
    to reject it here than after verification. Pinned with rule 7 by
    ``tests/identify/test_identify.py::test_fov_hint_wrong_by_two_fails``: either rule alone makes that
    test pass (rule 7 rejects the refit of a candidate this one let through), both removed fail
    it. (NaN passes, as the kernel always had it; rule 3 rejects it.)
    """
    return not (f_px < lo_px or f_px > hi_px)


@njit(cache=True, inline="always")
def pattern_fits(max_residual_rad: float, f_px: float, radius_px: float) -> bool:
    """Rule 3: the candidate's four stars, in their best vertex correspondence, fit one proper
    rotation (``det = +1``) with every star within the match radius.

    Why: a mirror image or an inconsistent correspondence has the right edge lengths but no
    rotation that carries it onto the sky. Two shortcuts in the search reject such candidates
    before the SVD and reject nothing this rule would keep: an edge mismatch beyond twice the
    allowed star error, and ``no_rotation_fits`` (triple products,
    ``tests/identify/test_identify.py::test_rotation_bound_rejects_mirror_images_only``). Correctness
    does not rest on it: without it the verification (rule 5) still rejects mirror images
    (``tests/identify/test_identify.py::test_mirror_image_fails`` passes); it saves verifications.
    Its definition is pinned by
    ``tests/identify/test_identify_accept.py::test_rule_helpers_are_the_kernel_arithmetic``.
    """
    return not (max_residual_rad * f_px > radius_px)


# The quick verification (rule 4): this many brightest catalogue stars against this many
# brightest centroids, and the log probability above which it rejects.
QUICK_CATALOG_STARS = 15
QUICK_CENTROIDS = 30
QUICK_LOG_P = -3.0


@njit(cache=True, inline="always")
def quick_check_fails(n_catalog: int, log_p: float) -> bool:
    """Rule 4: the quick verification — the :data:`QUICK_CATALOG_STARS` brightest catalogue
    stars in view against the :data:`QUICK_CENTROIDS` brightest centroids — fails when at least
    three catalogue stars were tried and their matches are unremarkable (log P > :data:`QUICK_LOG_P`,
    P > 5 %).

    Why: speed. Most false candidates fail here at a third of the full verification's cost; a
    true one matches its brightest stars. It can only reject: without it the same fields solve.
    Its thresholds are pinned by ``tests/identify/test_identify_accept.py::test_quick_check_rule``.
    """
    return n_catalog >= 3 and log_p > QUICK_LOG_P


@njit(cache=True, inline="always")
def log_prob_false(log_p_match: float, n_trials: int) -> float:
    """Rule 5, the number: log P(a wrong candidate matches as well), ``log_p_match`` from
    :func:`skyfix.identify.common.verify.verify_attitude` (the best of five match radii, binomial
    tails of the catalogue stars in view landing on centroids, the pattern's own stars not
    counted), times ``n_trials``, the candidates examined so far (the look-elsewhere effect: a
    search that tries many candidates meets a good chance match sooner)."""
    return log_p_match + np.log(n_trials)


@njit(cache=True, inline="always")
def is_verified(log_prob: float, log_threshold: float) -> bool:
    """Rule 5: a candidate is accepted when :func:`log_prob_false` is at most ``log_threshold``
    (``prob_threshold`` of :func:`skyfix.identify.identify`, 1e-9 by default).

    Why: with 1e-9 and the look-elsewhere count, a false candidate is accepted about once in a
    billion frames. Pinned by
    ``tests/identify/test_identify_accept.py::test_prob_threshold_bounds_the_reported_chance`` and
    ``tests/identify/test_identify.py::test_false_match_probability_is_the_binomial_tail`` (the tail);
    ``tests/identify/test_identify.py::test_random_points_fail`` does not pin it alone: it passes with
    this rule loosened to P ≤ 1, as rule 6 rejects random points too.
    """
    return log_prob <= log_threshold


# --- 6–7: the refit of an accepted candidate (skyfix.identify.methods.quad) ---------------------------
MIN_REFIT_PAIRS = 4  # a refit on fewer stars than a pattern's proves nothing


def refit_accepted(n_pairs: int, n_cat: int, n_img: int, radius_px: float, area_px2: float,
                   log_threshold: float) -> bool:
    """Rule 6: the refit on all matched stars has at least :data:`MIN_REFIT_PAIRS` pairs and is
    itself beyond chance (:func:`is_beyond_chance`) at its final match radius ``radius_px``.

    Why: a pattern that is right only locally (three stars of a dense cluster and a false star)
    passes the verification on the cluster's stars, but its refit matches barely more stars than
    a random attitude would at the radius its scatter needs. Pinned by
    ``tests/identify/test_identify.py::test_cluster_pattern_with_a_false_star_is_not_accepted`` (a
    1560″ wrong attitude before).
    """
    return n_pairs >= MIN_REFIT_PAIRS and is_beyond_chance(n_pairs, n_cat, n_img, radius_px, area_px2,
                                                           log_threshold)


def refit_focal_allowed(f_px: float, lo_px: float, hi_px: float) -> bool:
    """Rule 7: the refitted focal length is within 3 % of the allowed range of rule 2.

    Why: the refit frees the focal length (and k1) on all matched stars; a candidate whose refit
    leaves the range is a different camera than the one asked for (the search goes on). The
    3 % are the search's own slack: its focal length comes from one pattern's largest edge.
    Pinned with rule 2 by ``tests/identify/test_identify.py::test_fov_hint_wrong_by_two_fails`` (see
    :func:`focal_allowed`); ``tests/identify/test_identify_accept.py::test_refit_focal_range_rule`` checks
    that identify applies it.
    """
    return lo_px * 0.97 <= f_px <= hi_px * 1.03


def wrong_probability(covariance_rad2: np.ndarray, plate_scale_rad: float, dof: float = math.inf) -> float:
    """An upper bound on the chance, under the error the covariance describes, that the
    attitude is wrong: boresight error beyond max(60″, 1 px) or roll error beyond 0.5°.

    The boresight error's length is bounded by a circular distribution with the larger
    eigenvalue λ of the cross-boresight block, the roll's is two-sided. With ``dof`` finite —
    the degrees of freedom of the residuals the covariance's σ was estimated from — the tails
    are Student's (bivariate t: ``P(|e| > L) ≤ (1 + L²/(ν λ))^(−ν/2)``; t for the roll), not
    Gaussian (``exp(−L²/2λ)``, ν = ∞): a σ estimated from three stars' six residuals may be
    several times too small, and a three-star solution 4σ off was called solved before
    (``tests/identify/test_identify_triangle.py::test_sparse_noisy_fields_with_false_stars_are_never_wrong``).
    NaN or negative variances give 1. (Compiled, :func:`_wrong_probability`: a solve's final
    fit asks once, and the Python arithmetic of the tails cost it ~15 µs.)"""
    c = np.ascontiguousarray(covariance_rad2, dtype=np.float64)
    return float(_wrong_probability(c, float(plate_scale_rad), float(dof)))


@njit(cache=True)
def _wrong_probability(c, plate_scale_rad, dof):
    """:func:`wrong_probability` of the (3, 3) float64 covariance ``c``."""
    for i in range(3):
        for j in range(3):
            if not math.isfinite(c[i, j]):
                return 1.0
    a, b, d, var_roll = c[0, 0], c[0, 1], c[1, 1], c[2, 2]
    lam = (a + d) / 2.0 + math.sqrt(max(((a - d) / 2.0) ** 2 + b * b, 0.0))
    bound = max(WRONG_BORESIGHT_ARCSEC * _ARCSEC, plate_scale_rad)
    roll = math.radians(WRONG_ROLL_DEG)
    nu = max(dof, 1.0)
    if math.isinf(nu):
        p_bore = math.exp(-bound * bound / (2.0 * lam)) if lam > 0.0 else 0.0
        p_roll = math.erfc(roll / math.sqrt(2.0 * var_roll)) if var_roll > 0.0 else 0.0
    else:
        p_bore = (1.0 + bound * bound / (nu * lam)) ** (-nu / 2.0) if lam > 0.0 else 0.0
        p_roll = _student_t(roll / math.sqrt(var_roll), nu) if var_roll > 0.0 else 0.0
    return min(p_bore + p_roll, 1.0) if lam >= 0.0 and var_roll >= 0.0 else 1.0


def student_t_two_sided(t: float, nu: float) -> float:
    """``P(|T| > t)`` for Student's t with ``nu`` > 0 degrees of freedom (``2 stdtr(ν, −|t|)``
    in scipy.special; within 5e-13 relative of mpmath's for ν ≤ 1000, lgamma's cancellation
    growing beyond, 2e-11 at ν = 1e5; tests/identify/test_identify_accept.py): the regularised incomplete
    beta ``I_x(ν/2, 1/2)`` at ``x = ν / (ν + t²)``, by its continued fraction (modified Lentz).
    Written here because importing scipy.special costs a solving process ~0.06 s of CPU."""
    return float(_student_t(float(t), float(nu)))


@njit(cache=True)
def _student_t(t, nu):
    """:func:`student_t_two_sided`, compiled (:func:`_wrong_probability` calls it)."""
    t = abs(t)
    if not t > 0.0:
        return 1.0 if t == 0.0 else math.nan
    a, b = nu / 2.0, 0.5
    t2 = t * t
    x, y = nu / (nu + t2), t2 / (nu + t2)  # x + y = 1, each without cancellation
    if x == 0.0:
        return 0.0
    front = math.exp(math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log(y))
    if x < (a + 1.0) / (a + b + 2.0):
        return front * _beta_fraction(a, b, x) / a if front > 0.0 else 0.0  # (the fraction is finite)
    return 1.0 - front * _beta_fraction(b, a, y) / b if front > 0.0 else 1.0


@njit(cache=True)
def _beta_fraction(a, b, x):
    """The continued fraction of the incomplete beta function ``I_x(a, b)`` (Numerical Recipes
    §6.4's ``betacf``), converging fast for ``x < (a + 1) / (a + b + 2)``."""
    tiny = 1e-300
    c, d = 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 500):
        m2 = 2 * m
        for step in range(2):
            if step == 0:
                num = m * (b - m) * x / ((a + m2 - 1.0) * (a + m2))
            else:
                num = -(a + m) * (a + b + m) * x / ((a + m2) * (a + m2 + 1.0))
            d = 1.0 + num * d
            d = 1.0 / (d if abs(d) > tiny else tiny)
            c = 1.0 + num / c
            c = c if abs(c) > tiny else tiny
            h *= d * c
        if abs(d * c - 1.0) < 1e-16:
            break
    return h


#: The largest chance of a false match accepted (rule 5): every method's ``prob_threshold``
#: default, the hint's and the final fit's.
PROB_THRESHOLD = 1e-9
#: The centroid noise per axis (pixels) a method assumes when told none (``centroid_sigma_px``):
#: every correspondence method's angle tolerance (``n_sigma``·σ·√2) and the refit's noise prior.
CENTROID_SIGMA_PX = 0.5
#: ``quad``'s own default for ``centroid_sigma_px``: there it also widens the 4-star hash's
#: edge-ratio tolerance tiers, which were tuned with 1 px. Measured on the solve-from-centroids
#: sets (``benchmarks/suite_synthetic.py``'s four configurations, σ 0.5 and 1 px, 200 sets each,
#: FOV given and not): 0.5 solves the same 1600/1600 with 0 wrong, so the difference costs
#: nothing there; it is kept so that the default solve's results stay bit for bit those before.
QUAD_CENTROID_SIGMA_PX = 1.0


# A centroid noise stated a priori (solve's ``centroid_sigma_px`` beside a calibrated camera) is
# worth this many residual degrees of freedom in :func:`noise_posterior`: as sure as a σ measured
# from six stars' residuals, not more (a stated noise can be off by tens of percent).
NOISE_PRIOR_DOF = 10.0


class NoiseEstimate(NamedTuple):
    """The centroid noise a covariance is scaled by, and how surely it is known."""

    sigma_rad: float  #: per-axis centroid noise, radians
    dof: float  #: degrees of freedom behind it (Student's tails in :func:`wrong_probability`)


def noise_posterior(residuals_rad: np.ndarray, dof: float, prior_sigma_rad: float,
                    prior_dof: float = NOISE_PRIOR_DOF) -> NoiseEstimate:
    """The centroid noise from a stated value and the fit's residuals together.

    Three stars leave ν = 3 residual degrees of freedom: their σ alone, ``s² = Σ r² / ν``, may
    be several times too small, and Student's tails (:func:`wrong_probability`) then give even
    a noise-free three-star attitude (σ at the final fit's floor,
    :data:`skyfix.attitude.CENTROID_NOISE_FLOOR_PX`) a real chance of a 12σ error when its
    stars are bunched — a chance the data cannot lower, since all-but-zero residuals are only
    polynomially (``∝ σ^−ν``) less likely under a larger noise. What lowers it honestly is
    knowing the noise beforehand: a stated ``σ₀``
    counts as a scaled-inverse-χ² prior of ``ν₀`` degrees of freedom, and the posterior is

        ``σ² = (ν₀ σ₀² + ν s²) / (ν₀ + ν)``, with ``ν₀ + ν`` degrees of freedom

    (the conjugate update of a normal model's variance): residuals far beyond ``σ₀`` still
    raise σ, three lucky tiny ones lower it only to ``σ₀ √(ν₀ / (ν₀ + ν))``. The noise stated
    must be the centroids' own: stated 3.3 times too small, 300 three- to five-star 30° fields
    (benchmarks/sparse_noise_prior.py) came back with none wrong but error bars 2.2 times too
    small (normalised RMS 2.1–2.2; 1.0–1.1 stated right). Refusing a stated noise the residuals
    refute (F test, 1 %) did not help: the fields it let through were those whose residuals
    happened to agree with the wrong noise.

    Parameters
    ----------
    residuals_rad : (M,) angles between the stars' rays and their catalogue directions, rad.
    dof : float — the residuals' degrees of freedom (2M less the numbers fitted).
    prior_sigma_rad : float — the stated per-axis centroid noise, rad.
    prior_dof : float — what it is worth (:data:`NOISE_PRIOR_DOF`).
    """
    r = np.asarray(residuals_rad, dtype=np.float64)
    ss = float(r @ r)
    total = prior_dof + max(float(dof), 0.0)
    return NoiseEstimate(math.sqrt((prior_dof * prior_sigma_rad**2 + ss) / total), total)


#: The fewest residual degrees of freedom :func:`error_covariance` scales for: Student's t with
#: ν ≤ 2 has no variance, so a covariance from so few is reported as from ν = 3 (three times the
#: scale's). Such a solution's tails are judged by :func:`precision_failure`, at its own ν.
MIN_VARIANCE_DOF = 3.0


def error_covariance(covariance_rad2: np.ndarray, dof: float) -> np.ndarray:
    """The covariance of the attitude error, from the covariance its noise σ was estimated into.

    A σ estimated from ``dof`` = ν residual degrees of freedom makes each error, divided by the
    σ-scaled covariance's standard deviation, Student's t with ν degrees of freedom, whose
    variance is ``ν / (ν − 2)``: 1.29 for a calibrated camera's four stars (ν = 5), 1.13 for
    six. Reported unscaled, the error bar of a sparse field was too small by that much and more
    — normalised error RMS 1.2–2.1 over 40–60° fields of 6–10 stars with a camera given (the
    ``prob-false`` campaign, docs/montecarlo.md), against 1.11 with the noise stated. This is
    what :class:`skyfix.solution.Solution` reports (``covariance_arcsec2``); the precision rule
    (:func:`precision_failure`) takes the scale and ν itself, for the tails.
    """
    nu = max(float(dof), MIN_VARIANCE_DOF) if math.isfinite(dof) else math.inf
    c = np.asarray(covariance_rad2, dtype=np.float64)
    return c if nu == math.inf else c * (nu / (nu - 2.0))


# The largest chance of a wrong attitude (wrong_probability) a solution may carry.
MAX_WRONG_PROBABILITY = 1e-3


def precision_failure(covariance_rad2: np.ndarray, plate_scale_rad: float, dof: float = math.inf,
                      camera_given: bool = False) -> str:
    """Why an attitude is too uncertain to report as solved ("" when it is not): its
    :func:`wrong_probability` (with the residuals' ``dof``) beyond :data:`MAX_WRONG_PROBABILITY`.
    The reason ends with what would help: with no camera, the camera; with one, more stars."""
    p_wrong = wrong_probability(covariance_rad2, plate_scale_rad, dof)
    if not p_wrong <= MAX_WRONG_PROBABILITY:  # NaN fails too
        c = np.asarray(covariance_rad2, dtype=np.float64)
        sigma_bore = math.sqrt(max(c[0, 0] + c[1, 1], 0.0)) / _ARCSEC
        sigma_roll = math.degrees(math.sqrt(max(c[2, 2], 0.0)))
        why = ("too few stars, or too noisy, to pin the attitude down" if camera_given else
               "the stars matched do not pin down an uncalibrated camera: give one, --camera FILE")
        bound = max(WRONG_BORESIGHT_ARCSEC, plate_scale_rad / _ARCSEC)
        return (f"attitude too uncertain: σ boresight {sigma_bore:.0f}″, roll {sigma_roll:.2f}° "
                f"({p_wrong:.1g} chance of an error beyond {bound:.0f}″ or {WRONG_ROLL_DEG}°; {why})")
    return ""


@njit(cache=True)
def _cross_norm(u: np.ndarray, v: np.ndarray) -> float:
    cx = u[1] * v[2] - u[2] * v[1]
    cy = u[2] * v[0] - u[0] * v[2]
    cz = u[0] * v[1] - u[1] * v[0]
    return np.sqrt(cx * cx + cy * cy + cz * cz)


@njit(cache=True)
def _triple(u: np.ndarray, v: np.ndarray, w: np.ndarray) -> float:
    return (u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
            + u[2] * (v[0] * w[1] - v[1] * w[0]))


@njit(cache=True)
def no_rotation_fits(b: np.ndarray, r: np.ndarray, eps: float) -> bool:
    """True if no proper rotation A brings every ``r[a]`` within ``eps`` (chord) of ``b[a]``: the
    search's shortcut of rule 3 (:func:`pattern_fits`), rejecting nothing that rule would keep.

    A rotation keeps each triangle's triple product ``det[v_i, v_j, v_k]``; moving the vectors
    by at most ``eps`` changes it by at most ``eps·Σ|v×v'| + 3eps² + eps³``. A mirror image
    flips the sign of every triple product, so it fails this test without an SVD.
    """
    for t in range(4):
        i, j, k = (1, 2, 3) if t == 0 else ((0, 2, 3) if t == 1 else ((0, 1, 3) if t == 2 else (0, 1, 2)))
        det_b = _triple(b[i], b[j], b[k])
        det_r = _triple(r[i], r[j], r[k])
        bound = (eps * (_cross_norm(r[j], r[k]) + _cross_norm(r[i], r[k]) + _cross_norm(r[i], r[j]))
                 + 3.0 * eps * eps + eps * eps * eps)
        if abs(det_b - det_r) > bound * (1.0 + 1e-9) + 1e-12:
            return True
    return False
