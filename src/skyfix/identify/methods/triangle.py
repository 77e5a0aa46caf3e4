"""The ``triangle`` method: three stars are enough when their triangle is unique.

Thesis 000's camera was designed around three stars per 30° frame (§1, §2.6.7); the 4-star
hash cannot see such a frame. This method matches triangles of the brightest centroids to
catalogue triangles through the pair table (:mod:`skyfix.identify.catalogue.pairs`: the longest side by a
range search over pair angles, the third vertex among the first vertex's neighbours, the last
side checked), and judges what it finds in one of two ways:

*Rich frames* (the usual case with five or more stars): a catalogue triangle that fits counts
only when a fourth image star confirms it (a catalogue neighbour at the right three angles,
checked in the compiled search), and the four stars are a proposal judged by the common rules
(:func:`skyfix.identify.common.hypothesis.first_accepted`), exactly as any other method's.

*Sparse frames* (three or four stars, or up to
:data:`~skyfix.identify.common.lone.LONE_MAX_STARS` that the first way did not settle): a lone
triangle has nothing else to verify it against, so its own chance is computed, honestly, by the
rules :mod:`skyfix.identify.common.lone` states and holds (the catalogue triangles near it, every
look, every other star, nothing bright missing, unique).

The sparse frame is accepted when the product is at most ``lone_prob_threshold`` (rule 15) (1e-4 by
default: a lone triangle cannot reach the 1e-9 of a rich frame; a solution reports the chance it
was given, ``prob_false``). A mirror image is rejected as everywhere, since no proper rotation
fits it — and where a near-symmetric group of stars fits one all the same, by
:func:`unless_mirrored`: the frame flipped left-right matching more surely refuses the match.
"""

from __future__ import annotations

import math
import time
from itertools import combinations

import numpy as np

from skyfix._kernels.robust import rayleigh_inliers
from skyfix._kernels.rotation import chord_angle
from skyfix.camera import Camera
from skyfix.errors import InputError
from skyfix.identify.accept import CENTROID_SIGMA_PX, PROB_THRESHOLD
from skyfix.identify.catalogue.database import PatternDatabase
from skyfix.identify.catalogue.pairs import PairTable, pair_table, pairs_in_range
from skyfix.identify.common.angle_match import LONE_PROB_THRESHOLD
from skyfix.identify.common.hypothesis import (
    Frame,
    Hypothesis,
    failure,
    first_accepted,
    fits,
    frame_for,
    hypothesis,
    rays_at,
)
from skyfix.identify.common.lone import (
    AMBIGUITY_RATIO,
    LONE_MAX_STARS,
    NO_CONFIRM,
    LoneJudgement,
    judge_lone,
    pair_angles3,
    triangle_matches,
)
from skyfix.identify.common.result import Identification

__all__ = ["METHOD", "identify", "unless_mirrored"]

METHOD = "triangle"
_MAX_MATCHES = 4096  # catalogue triangles kept per image triangle (more are counted, not kept)
_FIRST_STARS = 5  # the image triangles among this many brightest stars are searched cheapest first


def _sides_order(frame: Frame, table: PairTable, tri: tuple[int, int, int],
                 tol: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The triangle's vertices ordered for the search, and its sides (θ01, θ02, θ12).

    Side 01 is searched in the pair table; its pairs are the work. With a calibrated camera its
    range is ± the tolerance whichever side it is, so the longest side (fewest pairs per radian
    is not the point: its relative error is the smallest). With a FOV only, its range is the
    focal range's (±10 %) and the other sides' tolerance grows as ``θ_other / θ01``: the side
    whose pairs in range times that growth is least is searched. Returns the vertices, the
    sides and that cost (the search's work, to order image triangles by)."""
    i, j, k = tri
    best, best_cost = None, math.inf
    s_tol = frame.scale_tolerance
    for a, b, c in ((i, j, k), (j, i, k), (i, k, j), (k, i, j), (j, k, i), (k, j, i)):
        s = pair_angles3(frame.rays[[a, b, c]])
        if s[1] < s[2]:
            continue  # of the two orientations of a side, the one whose first vertex sees the longer side
        if frame.calibrated:
            cost = -s[0]
        else:
            lo, hi = pairs_in_range(table.angle_rad, s[0] * (1 - s_tol) - tol, s[0] * (1 + s_tol) + tol)
            cost = (hi - lo) * (1.0 + s[1] / max(s[0], 1e-12))
        if cost < best_cost:
            best, best_cost = (np.array([a, b, c], np.int64), s), cost
    return best[0], best[1], best_cost


def _angles_to(rays: np.ndarray, extra: np.ndarray, verts: np.ndarray) -> np.ndarray:
    """(M, 3) angles from centroid rows ``extra`` to the three ``verts``."""
    if not len(extra):
        return NO_CONFIRM
    return chord_angle(np.linalg.norm(rays[extra][:, None, :] - rays[verts][None, :, :], axis=2))


def _ratio_spread(frame: Frame, verts: np.ndarray) -> float:
    """How much the ratios θ02/θ01, θ12/θ01 of an image triangle move across the focal range."""
    if frame.calibrated:
        return 0.0
    lo, hi = frame.focal_range_px
    r = [(lambda s: s[1:] / s[0])(pair_angles3(rays_at(frame, verts, f))) for f in (lo, hi)]
    return float(np.abs(r[0] - r[1]).max())


def _image_triangles(n: int):
    """Image triangles of the ``n`` brightest centroids, those of the brightest stars first."""
    return sorted(combinations(range(n), 3), key=lambda t: (t[2], t[1], t[0]))


def _triangle_holds(frame: Frame, judgement: LoneJudgement) -> bool:
    """Whether each of the hypothesis's own three stars fits the attitude the other matched
    stars give without it (accept rule 12; rule 16's Rayleigh cut over their residuals and its own,
    :func:`skyfix._kernels.robust.rayleigh_inliers`, floored at 0.1 px).

    A triangle of two true stars and a false one lands near the truth: the stars around it verify
    it, but the false star pulls its attitude off (a 15° frame with 10 false stars came back 240″
    and 1.7° off with P 2.5e-9 before this check; fitted with it, the false star's residual was
    only 3× the others', as it had pulled them too). Needs five or more matched stars."""
    n = len(judgement.stars)
    if n < 5:
        return True
    for i in range(3):
        rest = np.arange(n) != i
        fit = hypothesis(frame, judgement.stars[rest], judgement.catalog[rest])
        if not fit.focal_px == fit.focal_px:
            return False
        order = np.concatenate([np.flatnonzero(rest), [i]])
        stars, catalog = judgement.stars[order], judgement.catalog[order]
        b = rays_at(frame, stars, float(fit.focal_px))
        r = frame.stars.vectors[catalog] @ fit.A_icrs_to_cam.T
        resid = chord_angle(np.linalg.norm(b - r, axis=1))
        if not rayleigh_inliers(np.ascontiguousarray(resid), 0.1 / float(fit.focal_px))[-1]:
            return False
    return True


def _lone_identification(frame: Frame, h: Hypothesis, judgement: LoneJudgement, n_tried: int,
                         n_candidates: int) -> Identification:
    """The Identification of an accepted sparse frame: the attitude refitted (SVD) on every
    matched star, with the chance it was given."""
    full = hypothesis(frame, judgement.stars, judgement.catalog)
    if not fits(frame, full):
        full = h
    db = frame.database
    camera = frame.camera
    if not frame.calibrated:
        f = float(full.focal_px)
        camera = Camera(width=camera.width, height=camera.height, fx=f, fy=f, cx=camera.cx, cy=camera.cy)
    order = np.argsort(full.stars)
    star_index, cat_index = full.stars[order], full.catalog[order]
    if frame.kept is not None:
        star_index = frame.kept[star_index]
    star_ids, star_mag, _ = db.star_arrays()
    return Identification(True, "", star_index, star_ids[cat_index], db.vectors_at(cat_index, frame.epoch),
                          star_mag[cat_index], full.A_icrs_to_cam, camera, math.exp(judgement.log_chance),
                          n_tried, n_candidates, METHOD, time.perf_counter() - frame.t0, frame.radius_px,
                          database=db)


def identify(xy: np.ndarray, width: int, height: int, *, fov_deg: float | None = None,
             fov_tolerance_deg: float | None = None, camera: Camera | None = None,
             database: PatternDatabase | None = None, epoch: float | None = None, triangle_stars: int = 8,
             centroid_sigma_px: float = CENTROID_SIGMA_PX, n_sigma: float = 3.0, mag_margin: float = 1.0,
             missing_margin: float = 0.75, min_error_px: float = 0.05,
             lone_prob_threshold: float = LONE_PROB_THRESHOLD,
             prob_threshold: float = PROB_THRESHOLD, max_candidates: int = 2000, max_per_triangle: int = 64,
             per_field: int = 12) -> Identification:
    """Identify a frame's stars from triangles of its brightest centroids (the module text).

    Parameters (beyond the interface of :mod:`skyfix.identify.methods`)
    -------------------------------------------------------------------
    triangle_stars : int — the brightest centroids whose triangles are tried (3–12).
    centroid_sigma_px : float — the centroids' noise per axis; an angle's tolerance is
        ``n_sigma · √2 · centroid_sigma_px / f`` (plus the focal range's with a FOV only).
    mag_margin : float — catalogue stars this much fainter than a match's faintest still count
        as its competitors and verifiers (the image's brightness order is not the catalogue's).
    missing_margin : float — a catalogue star this much brighter than the match's faintest, in
        the frame and on no centroid, refutes the match.
    min_error_px : float — the floor of a match's side error in rule 8 (no centroid is exact).
    lone_prob_threshold : float — the largest chance accepted for a sparse frame.
    prob_threshold : float — the largest chance accepted for a rich frame (as the 4-star method's).
    max_candidates : int — catalogue triangles judged at most.
    max_per_triangle : int — on rich frames, an image triangle that more catalogue triangles
        match (with a fourth star confirming) than this is skipped: it cannot tell them apart.
    per_field : int — catalogue stars per field in the pair table
        (:func:`skyfix.identify.catalogue.pairs.pair_table`).
    """
    options = {"fov_deg": fov_deg, "fov_tolerance_deg": fov_tolerance_deg, "camera": camera,
               "database": database, "epoch": epoch, "triangle_stars": triangle_stars,
               "centroid_sigma_px": centroid_sigma_px, "n_sigma": n_sigma, "mag_margin": mag_margin,
               "missing_margin": missing_margin, "min_error_px": min_error_px,
               "lone_prob_threshold": lone_prob_threshold, "prob_threshold": prob_threshold,
               "max_candidates": max_candidates, "max_per_triangle": max_per_triangle, "per_field": per_field}
    t0 = time.perf_counter()
    result, lone = _identify(xy, width, height, **options)
    return unless_mirrored(result, xy, width, height, options, t0) if lone else result


def unless_mirrored(result: Identification, xy: np.ndarray, width: int, height: int, options: dict,
                    t0: float) -> Identification:
    """Accept rule 14, the mirror image (docs/identification-methods.md#triangle): a sparse frame's
    lone triangle ``result`` is refused when the same centroids flipped left-right (about the
    principal point) are identified more surely (a smaller chance of a wrong match). A frame
    flipped by its reader (a FITS row order, a mirror in the optics) is a real input, and a
    near-symmetric constellation seen mirrored can put three or four of its stars on the sky's
    own within the tolerance: Orion's Rigel and belt, mirrored, were named with a chance of 8e-5
    (``tests/identify/test_identify_every_method.py``); flipped back they match with 3e-15. A flipped
    frame is the rarer input, so a mirror that fits only about as well (within
    :data:`AMBIGUITY_RATIO`, rule 13's margin between two hypotheses of the same frame) does not
    refuse: it would cost 2 of the 40 noise-free three-star fields of
    ``tests/identify/test_identify_triangle.py``, whose mirrored triangles match other catalogue ones."""
    flipped = np.array(xy, dtype=np.float64)
    flipped[:, 0] = 2.0 * float(result.camera.cx) - flipped[:, 0]
    mirror, _ = _identify(flipped, width, height, **options)
    if not mirror.success or mirror.prob_false >= result.prob_false:
        return result
    return failure(METHOD, "ambiguous: the stars fit the sky mirrored left-right better (chance "
                           f"{mirror.prob_false:.1e} against {result.prob_false:.1e}): a mirror image? "
                           "Solve it with --parity mirrored or either", t0,
                   result.n_patterns_tried, result.n_candidates)


def _identify(xy: np.ndarray, width: int, height: int, *, fov_deg: float | None,
              fov_tolerance_deg: float | None, camera: Camera | None, database: PatternDatabase | None,
              epoch: float | None, triangle_stars: int, centroid_sigma_px: float, n_sigma: float,
              mag_margin: float, missing_margin: float, min_error_px: float, lone_prob_threshold: float,
              prob_threshold: float, max_candidates: int, max_per_triangle: int,
              per_field: int) -> tuple[Identification, bool]:
    """:func:`identify` without the mirror rule: the Identification, and whether it is a sparse
    frame's lone triangle (accepted by rules 8–13)."""
    if not 3 <= int(triangle_stars) <= 12:
        raise InputError(f"triangle_stars must be 3–12, not {triangle_stars}")
    frame = frame_for(METHOD, xy, width, height, fov_deg=fov_deg, fov_tolerance_deg=fov_tolerance_deg,
                      camera=camera, database=database, epoch=epoch, min_stars=3,
                      prob_threshold=prob_threshold, centroid_sigma_px=centroid_sigma_px)
    if isinstance(frame, Identification):
        return frame, False
    cam = frame.camera
    f0 = float(cam.fx)
    s_tol = frame.scale_tolerance
    fov = math.degrees(2.0 * math.atan(cam.width / 2.0 / f0))
    diag = math.degrees(2.0 * math.atan(math.hypot(cam.width, cam.height) / 2.0 / f0))
    table = pair_table(frame.database, fov, diag * (1.0 + s_tol) * 1.02 + 0.05, per_field=per_field)
    vectors = frame.stars.vectors
    _, star_mag, _ = frame.database.star_arrays()
    tol = n_sigma * math.sqrt(2.0) * centroid_sigma_px / f0
    n = min(len(frame.xy), int(triangle_stars))
    triangles = _image_triangles(n)
    # Of the first image triangles (those of the five brightest stars), the cheapest to search
    # first: with a FOV only a long side's range holds ten thousand pairs, a short one's hundreds.
    first = sum(1 for t in triangles if t[2] < _FIRST_STARS)
    plan = [(tri, *_sides_order(frame, table, tri, tol)) for tri in triangles[:first]]
    plan.sort(key=lambda e: e[3])
    plan += [(tri, None, None, 0.0) for tri in triangles[first:]]
    out = np.empty((_MAX_MATCHES, 5), np.int32)
    err = np.empty(_MAX_MATCHES)
    n_all = len(star_mag)
    sparse = len(frame.xy) <= 4
    n_cand = 0

    def candidates(confirm: bool):
        """(image triangle number, its vertices (and the confirming star's) and sides, catalogue
        stars) in search order; with ``confirm``, only triangles a fourth star confirms."""
        nonlocal n_cand
        for t, (tri, verts, sides, _) in enumerate(plan):
            if verts is None:
                verts, sides, _ = _sides_order(frame, table, tri, tol)
            # FOV only: the scale side 01 implies carries its error into the other sides, and a
            # focal length across its range bends the sides' ratios a little (projection).
            spread = _ratio_spread(frame, verts)
            t_other = tol * (1.0 + sides[1:].max() / sides[0]) + spread * sides[0]
            extra = np.setdiff1d(np.arange(n), verts) if confirm else np.zeros(0, np.int64)
            # With a FOV only one confirming star is often found by chance: ask for two when
            # three or more could confirm.
            need = 2.0 if not frame.calibrated and len(extra) >= 3 else 1.0
            bounds = np.array([sides[0] * (1 - s_tol) - tol, sides[0] * (1 + s_tol) + tol, t_other, t_other,
                               tol, spread, need])
            if frame.calibrated:
                bounds[2] = bounds[3] = tol
            angles = _angles_to(frame.rays, extra, verts)
            k = triangle_matches(table, vectors, sides, bounds, frame.calibrated, n_all, angles, out, err)
            if confirm and k > max_per_triangle:
                continue  # an image triangle that many catalogue ones confirm tells nothing (pyramid's rule)
            k = min(k, len(out))
            for a, b, c, d, e in out[:k][np.argsort(err[:k], kind="stable")]:  # the closest shapes first
                if n_cand >= max_candidates:
                    return
                n_cand += 1
                if d >= 0:
                    yield t, np.append(verts, extra[d]), sides, np.array([a, b, c, e], np.int64)
                else:
                    yield t, verts, sides, np.array([a, b, c], np.int64)

    if not sparse:
        result = first_accepted(frame, ((v, c) for _, v, _, c in candidates(True)), n_tried=len(triangles),
                                max_candidates=max_candidates)
        if result.success or len(frame.xy) > LONE_MAX_STARS:
            return result, False
        n_cand = 0
    lone: list[tuple[float, Hypothesis, LoneJudgement]] = []
    for _, verts, sides, cat in candidates(False):
        h = hypothesis(frame, verts, cat)
        if not fits(frame, h):
            continue
        # Every image triangle counts (rule 9): the best match is chosen among all of them.
        j = judge_lone(frame, h, table, star_mag, sides_img=sides, tolerance_rad=tol, n_triangles=len(plan),
                       mag_margin=mag_margin, missing_margin=missing_margin, min_error_px=min_error_px)
        if j.n_missing == 0 and _triangle_holds(frame, j):
            lone.append((j.log_chance, h, j))
    if not lone:
        return failure(METHOD, f"no catalogue triangle fits ({n_cand} candidates from {len(triangles)} "
                               "image triangles)", frame.t0, len(triangles), n_cand), False
    lone.sort(key=lambda e: e[0])
    best_log, best_h, best_j = lone[0]
    if best_log > math.log(lone_prob_threshold):
        return failure(METHOD, "no triangle unique enough: best chance of a wrong match "
                               f"{math.exp(best_log):.1e} > {lone_prob_threshold:g}", frame.t0,
                       len(triangles), n_cand), False
    apart = 3.0 * frame.radius_px / float(best_h.focal_px)
    rivals = {tuple(j.catalog[:3]) for lp, h, j in lone
              if lp <= best_log + math.log(AMBIGUITY_RATIO) and _rotation_angle(h, best_h) > apart}
    if rivals:
        return failure(METHOD, f"ambiguous: {len(rivals) + 1} catalogue triangles fit these stars about "
                               "equally well", frame.t0, len(triangles), n_cand), False
    return _lone_identification(frame, best_h, best_j, len(triangles), n_cand), True


def _rotation_angle(a: Hypothesis, b: Hypothesis) -> float:
    """The angle (radians) of the rotation between two hypotheses' attitudes. Two hypotheses
    that put the camera in different places are rivals whatever stars they name (an equilateral
    triangle's three vertex assignments name the same stars at three rolls)."""
    c = (np.trace(a.A_icrs_to_cam @ b.A_icrs_to_cam.T) - 1.0) / 2.0
    return math.acos(min(max(c, -1.0), 1.0))
