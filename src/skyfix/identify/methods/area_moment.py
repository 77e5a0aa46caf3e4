"""The ``area-moment`` method: star triangles recognised by their area and polar moment.

Thesis 000's chosen method (§2.6.3, after Cole & Crassidis 2006). Three unit vectors make a
planar triangle whose sides are chords ``|v_i − v_j|`` (not the thesis's printed ``|v_i| − |v_j|``);
its Heron area ``A`` and polar moment ``J = A·(a² + b² + c²)/36`` are the same in the camera and
in the sky. skyfix:

1. forms the triangles of the ``triangle_stars`` brightest centroids, breadth-first
   (:func:`skyfix.identify.catalogue.triangles.image_triangles`), and gives each the tolerances of its own
   noise: ``n_sigma`` × Cole & Crassidis's σ_A, σ_J for a centroid noise of
   ``centroid_sigma_px`` (:func:`skyfix.identify.catalogue.triangles.area_moment_sigma`, derived with the
   chord sides);
2. finds the catalogue triangles (:func:`skyfix.identify.catalogue.triangles.triangle_table`) within them:
   with a calibrated camera a range of areas by binary search, moments filtered; with a FOV only
   the focal length is free, so ``A`` and ``J`` may be off by ``(1 ± ε)²`` and ``(1 ± ε)⁴``
   (ε: :attr:`~skyfix.identify.common.hypothesis.Frame.scale_tolerance`) and the search runs on the
   scale-free ``K = J/A²`` instead (its own σ_K, same derivation), area and moment filtered
   within their widened ranges — the thesis scans the whole catalogue linearly, with no tolerance;
3. assigns the vertices explicitly — each vertex by the side opposite it, sorted, in both
   triangles, and both orders where two sides are equal within the noise — and keeps only the
   orders whose handedness (the sign of the triple product) is the catalogue triangle's: area and
   moment cannot tell a triangle from its mirror image (the correction in docs/seeds.md);
4. confirms with a fourth star (Cole & Crassidis's "pivoting"): one of the ``confirm_stars``
   brightest other centroids whose angles to the three, at the scale the triangle implies, are
   a catalogue star's angles to theirs within the noise
   (:func:`skyfix.identify.catalogue.triangles.confirm_fourth`, among the first vertex's neighbours in the
   pair table). A frame of three stars has no fourth: this method fails it (the ``triangle``
   method judges lone triangles);
5. proposes each confirmed 4-star correspondence, image triangles breadth-first and each one's
   catalogue triangles by closeness, to :func:`skyfix.identify.common.hypothesis.first_accepted`, which
   applies every acceptance rule (the chance of a wrong match with every proposal counted).

Measured success and speed: docs/identification-methods.md#area-moment.
"""

from __future__ import annotations

import numpy as np

from skyfix.camera import Camera
from skyfix.identify.accept import CENTROID_SIGMA_PX, PROB_THRESHOLD
from skyfix.identify.catalogue.database import PatternDatabase
from skyfix.identify.catalogue.triangles import (
    AREA,
    BY_AREA,
    BY_SHAPE,
    MOMENT,
)
from skyfix.identify.common.hypothesis import Frame, failure, first_accepted, frame_for
from skyfix.identify.common.image_triangles import (
    ImageTriangles,
    SearchStats,
    check_options,
    frame_triangle_table,
    image_triangles,
    triangle_proposals,
)
from skyfix.identify.common.result import Identification

__all__ = ["METHOD", "identify"]

METHOD = "area-moment"


def _tolerances(frame: Frame, image: ImageTriangles, n_sigma: float):
    """The index searched and each image triangle's features and tolerances in its columns."""
    f = image.features
    sig = image.feature_sigma
    eps = frame.scale_tolerance
    tol_a = n_sigma * sig[:, 0] + ((1.0 + eps) ** 2 - 1.0) * f[:, AREA]
    tol_j = n_sigma * sig[:, 1] + ((1.0 + eps) ** 4 - 1.0) * f[:, MOMENT]
    if frame.calibrated:
        return f[:, list(BY_AREA)], np.column_stack([tol_a, tol_j])
    return f[:, list(BY_SHAPE)], np.column_stack([n_sigma * sig[:, 2], tol_a, tol_j])


# Over ten parameters: the interface of every method (skyfix.identify.methods) and this method's
# options, all keywords with a documented default.
def identify(xy: np.ndarray, width: int, height: int, *, fov_deg: float | None = None,
             fov_tolerance_deg: float | None = None, camera: Camera | None = None,
             database: PatternDatabase | None = None, epoch: float | None = None,
             centroid_sigma_px: float = CENTROID_SIGMA_PX, n_sigma: float = 3.0, triangle_stars: int = 10,
             confirm_stars: int = 20, per_field: int = 8, max_candidates: int = 2000,
             max_matches: int = 200_000, prob_threshold: float = PROB_THRESHOLD) -> Identification:
    """Identify the stars of one frame by the area and polar moment of its star triangles,
    confirmed by a fourth star (module text).

    Parameters
    ----------
    xy, width, height, fov_deg, fov_tolerance_deg, camera, database, epoch
        The interface of every method (:mod:`skyfix.identify.methods`). A FOV or a camera is
        required.
    centroid_sigma_px : float
        Expected centroid noise (1σ per axis), pixels; raise it for noisier centroids
        (sets σ_A, σ_J and the fourth star's tolerance).
    n_sigma : float
        Tolerances are ``n_sigma`` standard deviations.
    triangle_stars : int
        Work bound: triangles are formed from this many brightest centroids (C(n, 3) of them).
    confirm_stars : int
        The brightest centroids tried as the fourth star.
    per_field : int
        The triangle table's brightest stars per lattice field
        (:func:`~skyfix.identify.catalogue.triangles.triangle_table`).
    max_candidates : int
        Work bound: confirmed correspondences verified.
    max_matches : int
        Work bound: catalogue triangles kept from the search.
    prob_threshold : float
        Largest accepted probability that the match is chance.

    Returns
    -------
    Identification
        ``method`` is ``"area-moment"``; on failure, ``reason`` says why.

    Raises
    ------
    skyfix.errors.InputError
        An impossible option, centroids that are not (N, 2) numbers, or a frame size below 1.
    skyfix.errors.CameraError
        An impossible ``fov_deg``.
    """
    check_options(centroid_sigma_px, n_sigma, xy, width, height, triangle_stars=triangle_stars,
                  confirm_stars=confirm_stars, per_field=per_field, max_candidates=max_candidates,
                  max_matches=max_matches)
    frame = frame_for(METHOD, xy, width, height, fov_deg=fov_deg, fov_tolerance_deg=fov_tolerance_deg,
                      camera=camera, database=database, epoch=epoch, min_stars=4,
                      prob_threshold=prob_threshold, centroid_sigma_px=centroid_sigma_px)
    if isinstance(frame, Identification):
        return frame
    table = frame_triangle_table(frame, per_field)
    image = image_triangles(frame, triangle_stars, centroid_sigma_px, n_sigma)
    stats = SearchStats()
    index = table.by_area if frame.calibrated else table.by_shape
    centre, tol = _tolerances(frame, image, n_sigma)
    proposals = triangle_proposals(frame, table, image, index, centre, tol, n_sigma=n_sigma,
                                   confirm_stars=confirm_stars, max_matches=max_matches, stats=stats)
    result = first_accepted(frame, proposals,
                            n_tried=len(image.stars), max_candidates=max_candidates)
    if result.success:
        return result
    reason = (f"no match: {stats.found} catalogue triangles matched {len(image.stars)} image triangles "
              f"in area and moment (and handedness), a fourth star confirmed {stats.confirmed} of "
              f"{stats.tried} vertex assignments, none verified")
    if result.n_candidates >= max_candidates:
        reason += f" (stopped at max_candidates={max_candidates})"
    return failure(METHOD, reason, frame.t0, len(image.stars), result.n_candidates)
