"""The ``planar`` method: star triangles recognised by the interior angles of their planar triangle.

Thesis 000 §2.6.2: three unit vectors make a planar triangle with sides the chords
``a = |v1 − v2|, b = |v2 − v3|, c = |v1 − v3|`` (the thesis prints ``|v1| − |v2|``, which is always
0: the correction in docs/seeds.md) and interior angles by the law of cosines; a rotation keeps them, and
they do not depend on the focal length (to second order in the field angle), so the method works
with a FOV only. skyfix:

1. forms the triangles of the ``triangle_stars`` brightest centroids, breadth-first
   (:func:`skyfix.identify.catalogue.triangles.image_triangles`), vertices ordered by the sides opposite
   them (so the angles are ascending too);
2. finds the catalogue triangles (:func:`skyfix.identify.catalogue.triangles.triangle_table`) whose two
   smaller interior angles are the image's within ``n_sigma`` times their noise — an angle's
   error from centroid noise σ is about ``σ√2 (1/b + 1/c)`` for the sides ``b, c`` that meet at
   it — plus, with a FOV only, ``ε·a²`` for a wrong focal length (ε:
   :attr:`~skyfix.identify.common.hypothesis.Frame.scale_tolerance`), by a binary search on the smallest
   angle and a filter on the next; and whose longest side fits the focal range (the catalogue's
   side over the image's within ``1 ± ε``, plus the noise) — a filter the thesis does not have:
   it costs nothing and a triangle of the wrong size cannot be the one seen;
3. keeps only the vertex orders of the catalogue triangle's handedness (the sign of the triple
   product; both orders where two sides are equal within the noise): interior angles cannot tell
   a triangle from its mirror image;
4. with ``confirm`` (the default) and four centroids or more, keeps only the correspondences a
   fourth star confirms (its angles to the three match a catalogue star's; Liebe's "confirm with
   additional stars", which the thesis's review of this method does not spell out: without it a
   FOV-only frame with false stars sends ~10× more triangles to verification);
5. proposes each correspondence, image triangles breadth-first and each one's catalogue triangles
   by closeness, to :func:`skyfix.identify.common.hypothesis.first_accepted`, which applies every
   acceptance rule (the chance of a wrong match with every proposal counted; the stars beyond
   the triangle verify it).

Measured success and speed: docs/identification-methods.md#planar.
"""

from __future__ import annotations

import math

import numpy as np

from skyfix.camera import Camera
from skyfix.identify.accept import CENTROID_SIGMA_PX, PROB_THRESHOLD
from skyfix.identify.catalogue.database import PatternDatabase
from skyfix.identify.catalogue.triangles import (
    BY_ANGLE,
    SIDES,
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

__all__ = ["METHOD", "angle_tolerances", "identify"]

METHOD = "planar"


def angle_tolerances(frame: Frame, image: ImageTriangles, n_sigma: float) -> np.ndarray:
    """Each image triangle's allowed errors (M, 3) of :data:`~skyfix.identify.catalogue.triangles.BY_ANGLE`'s
    columns: the two smaller interior angles and the longest side (module text, step 2)."""
    s = image.features[:, SIDES:SIDES + 3]
    noise = n_sigma * math.sqrt(2.0) * image.sigma_rad
    eps = frame.scale_tolerance
    with np.errstate(divide="ignore"):
        phi0 = noise * (1.0 / s[:, 1] + 1.0 / s[:, 2]) + eps * s[:, 2] ** 2
        phi1 = noise * (1.0 / s[:, 0] + 1.0 / s[:, 2]) + eps * s[:, 2] ** 2
    side = noise + eps * s[:, 2]
    return np.column_stack([phi0, phi1, side])


# Over ten parameters: the interface of every method (skyfix.identify.methods) and this method's
# options, all keywords with a documented default.
def identify(xy: np.ndarray, width: int, height: int, *, fov_deg: float | None = None,
             fov_tolerance_deg: float | None = None, camera: Camera | None = None,
             database: PatternDatabase | None = None, epoch: float | None = None,
             centroid_sigma_px: float = CENTROID_SIGMA_PX, n_sigma: float = 3.0, triangle_stars: int = 10,
             confirm: bool = True, confirm_stars: int = 20, per_field: int = 8, max_candidates: int = 2000,
             max_matches: int = 200_000,
             prob_threshold: float = PROB_THRESHOLD) -> Identification:
    """Identify the stars of one frame by the interior angles of its star triangles (module text).

    Parameters
    ----------
    xy, width, height, fov_deg, fov_tolerance_deg, camera, database, epoch
        The interface of every method (:mod:`skyfix.identify.methods`). A FOV or a camera is
        required.
    centroid_sigma_px : float
        Expected centroid noise (1σ per axis), pixels; raise it for noisier centroids
        (sets the angle tolerances).
    n_sigma : float
        Tolerances are ``n_sigma`` standard deviations.
    triangle_stars : int
        Work bound: triangles are formed from this many brightest centroids (C(n, 3) of them).
    confirm : bool
        Propose only the triangles a fourth star confirms (frames of four stars or more).
    confirm_stars : int
        The brightest centroids tried as the fourth star.
    per_field : int
        The triangle table's brightest stars per lattice field
        (:func:`~skyfix.identify.catalogue.triangles.triangle_table`).
    max_candidates : int
        Work bound: correspondences verified.
    max_matches : int
        Work bound: catalogue triangles kept from each search.
    prob_threshold : float
        Largest accepted probability that the match is chance.

    Returns
    -------
    Identification
        ``method`` is ``"planar"``; on failure, ``reason`` says why.

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
                      camera=camera, database=database, epoch=epoch, min_stars=3,
                      prob_threshold=prob_threshold, centroid_sigma_px=centroid_sigma_px)
    if isinstance(frame, Identification):
        return frame
    table = frame_triangle_table(frame, per_field)
    image = image_triangles(frame, triangle_stars, centroid_sigma_px, n_sigma)
    stats = SearchStats()
    centre = image.features[:, list(BY_ANGLE)]
    tol = angle_tolerances(frame, image, n_sigma)
    proposals = triangle_proposals(frame, table, image, table.by_angle, centre, tol, n_sigma=n_sigma,
                                   confirm_stars=confirm_stars, max_matches=max_matches, stats=stats,
                                   confirm=confirm)
    result = first_accepted(frame, proposals, n_tried=len(image.stars), max_candidates=max_candidates)
    if result.success:
        return result
    reason = (f"no match: {stats.found} catalogue triangles matched {len(image.stars)} image triangles in "
              f"interior angles, size and handedness")
    if confirm:
        reason += f", a fourth star confirmed {stats.confirmed} of {stats.tried} vertex assignments"
    reason += f"; {result.n_candidates} verified, none accepted"
    if result.n_candidates >= max_candidates:
        reason += f" (stopped at max_candidates={max_candidates})"
    return failure(METHOD, reason, frame.t0, len(image.stars), result.n_candidates)
