"""The ``liebe`` method: a star, its two nearest neighbours, and the angle between them.

Liebe (1995), thesis 000 §2.6.1: a star's pattern is the angles θ1, θ2 from it to its first and
second nearest neighbours and the angle φ at the star between the two (the spherical angle
between the great circles towards them). The catalogue holds each star's pattern; an image star's
pattern, measured the same way, is looked up within the noise and confirmed with further stars.
skyfix:

1. holds, for each star of the pair table (:func:`skyfix.identify.catalogue.pairs.pair_table`, the
   brightest stars of every field of the frame's size — as many per field as the frame's
   centroids suggest, :func:`per_field_for`: the catalogue's nearest neighbours must be the
   image's, and a sparse frame lost ~6 % of its fields against a 12-per-field table), the
   patterns of every pair among its ``k_nearest`` nearest neighbours beyond ``buffer_deg`` — not
   only the two nearest: a neighbour
   missing from the image (too faint, off the edge, merged) or an extra one in it (a false star,
   a star fainter than the table's) would otherwise lose the star
   (:func:`skyfix.identify.catalogue.triangles.star_triangle_table`, indexed by θ1);
2. measures, for each of the brightest image stars as pivot (brightest first), every pair among
   its ``k_nearest`` nearest neighbours among the ``neighbour_stars`` brightest centroids (as many
   as the table holds in a frame, half as many again, by default), nearest pairs first;
3. finds the catalogue patterns within ``n_sigma`` times the noise — θ: ``σ√2`` plus ``ε·θ`` with
   a FOV only (ε: :attr:`~skyfix.identify.common.hypothesis.Frame.scale_tolerance`); φ: ``σ√2 (1/θ1 +
   1/θ2)`` plus ``ε·θ2²`` — by a binary search on θ1 (on φ with a FOV only: θ is then known to
   ±ε only, φ does not depend on the scale), the other two filtered
   (:func:`skyfix.identify.catalogue.triangles.feature_matches`). φ is signed (the sign of the triple
   product), so a mirror image's patterns do not match: the paper's φ is unsigned;
4. confirms each with a fourth star, as Liebe does with additional stars: a bright centroid
   whose angles to the three match a catalogue star's
   (:func:`skyfix.identify.catalogue.triangles.confirmed_matches`);
5. proposes each confirmed 4-star correspondence, pivots by brightness and each one's patterns
   by closeness, to :func:`skyfix.identify.common.hypothesis.first_accepted`, which applies every
   acceptance rule (the chance of a wrong match with every proposal counted).

Measured success and speed: docs/identification-methods.md#liebe.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._kernels.rotation import chord_angle
from skyfix.camera import Camera
from skyfix.errors import InputError
from skyfix.identify.accept import CENTROID_SIGMA_PX, PROB_THRESHOLD
from skyfix.identify.catalogue.database import PatternDatabase
from skyfix.identify.catalogue.triangles import (
    SIDES,
    StarTriangleTable,
    describe_star_triangles,
    describe_triangles,
    feature_matches,
    star_triangle_table,
)
from skyfix.identify.common.hypothesis import Frame, failure, first_accepted, frame_for
from skyfix.identify.common.image_triangles import (
    SearchStats,
    check_options,
    confirmed_matches,
    frame_angles_deg,
    ranked,
)
from skyfix.identify.common.result import Identification

__all__ = ["METHOD", "PER_FIELD_STEPS", "StarPatterns", "identify", "per_field_for", "star_patterns"]

METHOD = "liebe"


class StarPatterns(NamedTuple):
    """The image's Liebe patterns (:func:`star_patterns`).

    stars : (P, 3) int64 — (pivot, nearer, farther neighbour), centroid rows.
    features : (P, 3) float64 — θ1, θ2, φ.
    sides : (P, 3) float64 — the chord sides, ascending.
    pivot_start : (n + 1,) int64 — pivot ``i``'s patterns are rows ``pivot_start[i]:pivot_start[i + 1]``.
    """

    stars: np.ndarray
    features: np.ndarray
    sides: np.ndarray
    pivot_start: np.ndarray


def star_patterns(rays: np.ndarray, k_nearest: int, buffer_rad: float) -> StarPatterns:
    """Liebe's patterns of unit ``rays`` (n, 3) (module text, step 2): each ray as pivot with
    every pair among its ``k_nearest`` nearest others beyond ``buffer_rad``, nearest pairs first."""
    n = len(rays)
    angle = chord_angle(np.sqrt(np.maximum(2.0 - 2.0 * (rays @ rays.T), 0.0)))
    angle[np.arange(n), np.arange(n)] = np.inf
    angle[angle <= buffer_rad] = np.inf
    k = min(k_nearest, max(n - 1, 0))
    near = np.argsort(angle, axis=1, kind="stable")[:, :k]
    finite = np.isfinite(np.take_along_axis(angle, near, axis=1))
    ii, jj = np.triu_indices(k, 1)
    keep = finite[:, ii] & finite[:, jj]
    pivot = np.broadcast_to(np.arange(n)[:, None], keep.shape)
    stars = np.stack([pivot[keep], near[:, ii][keep], near[:, jj][keep]], axis=1).astype(np.int64)
    pivot_start = np.concatenate([[0], np.cumsum(keep.sum(axis=1))]).astype(np.int64)
    stars = np.ascontiguousarray(stars.reshape(-1, 3))
    sides = np.ascontiguousarray(describe_triangles(rays, stars)[1][:, SIDES:SIDES + 3])
    return StarPatterns(stars, describe_star_triangles(rays, stars), sides, pivot_start)


PER_FIELD_STEPS = (4, 6, 8, 12)  # the pair tables Liebe chooses from (each built once, kept)


def per_field_for(frame: Frame) -> int:
    """The pair table's stars per lattice field for ``frame``: the smallest of
    :data:`PER_FIELD_STEPS` at least the centroids a field-sized disc of the frame holds (its
    shorter side across: ~0.6 of a 4:3 frame's centroids), else the largest."""
    cam = frame.camera
    disc = math.pi / 4.0 * min(cam.width, cam.height) ** 2 / (cam.width * cam.height)
    need = math.ceil(disc * len(frame.xy))
    return next((k for k in PER_FIELD_STEPS if k >= need), PER_FIELD_STEPS[-1])


def _neighbour_stars(frame: Frame, table: StarTriangleTable) -> int:
    """Half as many again as the table's stars expected in the frame (their density times the
    frame's solid angle)."""
    cam = frame.camera
    solid = cam.width * cam.height / float(cam.fx) ** 2
    return int(np.clip(round(1.5 * len(table.pairs.stars) * solid / (4.0 * math.pi)), 6, 40))


def _proposals(frame: Frame, table: StarTriangleTable, patterns: StarPatterns, centroid_sigma_px: float,
               n_sigma: float, confirm_stars: int, max_matches: int, stats: SearchStats):
    """Confirmed 4-star correspondences in rank order (module text, steps 3–5), one pivot's
    patterns at a time."""
    f = patterns.features
    sigma = centroid_sigma_px / float(frame.camera.fx)
    noise = n_sigma * math.sqrt(2.0) * sigma
    eps = frame.scale_tolerance
    tol = np.column_stack([noise + eps * f[:, 0], noise + eps * f[:, 1],
                           noise * (1.0 / f[:, 0] + 1.0 / f[:, 1]) + eps * f[:, 1] ** 2])
    # with a FOV only θ1 and θ2 are known to ±ε; φ is scale-free: the search's key
    index = table.by_theta if frame.calibrated else table.by_phi
    columns = list(index.columns)
    n_patterns = len(patterns.stars)
    no_flags = np.zeros((n_patterns, 2), np.bool_)
    every_order = np.ones(n_patterns, np.bool_)  # φ's sign already holds the handedness
    no_hand = np.zeros(n_patterns, np.int8)
    table_hand = np.zeros(len(table.stars), np.int8)
    candidates = np.arange(min(len(frame.xy), confirm_stars), dtype=np.int64)
    out = np.empty((4096, 4), np.int64)
    for p in range(len(patterns.pivot_start) - 1):
        rows = np.arange(patterns.pivot_start[p], patterns.pivot_start[p + 1])
        if len(rows) == 0:
            continue
        matches = feature_matches(index, f[rows][:, columns], tol[rows][:, columns], no_hand[rows],
                                  max_matches=max_matches)
        stats.found += matches.n_found
        k = ranked(matches)
        image_rows, table_rows = rows[matches.image[k]], matches.row[k]
        n, tried = confirmed_matches(image_rows, table_rows, patterns.stars, no_flags, every_order, no_hand,
                                     patterns.sides, table.stars, table_hand, table.sides, table.pairs,
                                     frame.stars.vectors, frame.rays, candidates, noise, frame.calibrated,
                                     out)
        stats.tried += tried
        stats.confirmed += n
        for c in range(n):
            j, _, star, catalog = out[c]
            img = patterns.stars[image_rows[j]]
            cat = table.stars[table_rows[j]]
            yield np.append(img, star).astype(np.int64), np.append(cat, catalog).astype(np.int64)


# Over ten parameters: the interface of every method (skyfix.identify.methods) and this method's
# options, all keywords with a documented default.
def identify(xy: np.ndarray, width: int, height: int, *, fov_deg: float | None = None,
             fov_tolerance_deg: float | None = None, camera: Camera | None = None,
             database: PatternDatabase | None = None, epoch: float | None = None,
             centroid_sigma_px: float = CENTROID_SIGMA_PX, n_sigma: float = 3.0, k_nearest: int = 4,
             buffer_deg: float = 0.0, pivots: int = 12, neighbour_stars: int | None = None,
             confirm_stars: int = 20, per_field: int | None = None, max_candidates: int = 2000,
             max_matches: int = 100_000, prob_threshold: float = PROB_THRESHOLD) -> Identification:
    """Identify the stars of one frame by Liebe's star patterns (module text).

    Parameters
    ----------
    xy, width, height, fov_deg, fov_tolerance_deg, camera, database, epoch
        The interface of every method (:mod:`skyfix.identify.methods`). A FOV or a camera is
        required.
    centroid_sigma_px : float
        Expected centroid noise (1σ per axis), pixels; raise it for noisier centroids
        (sets the tolerances).
    n_sigma : float
        Tolerances are ``n_sigma`` standard deviations.
    k_nearest : int
        Patterns are the pairs among a star's ``k_nearest`` nearest neighbours (Liebe: 2), in
        the catalogue and in the image.
    buffer_deg : float
        Neighbours closer than this are ignored (Liebe's buffer radius; 0: none).
    pivots : int
        Work bound: the brightest centroids tried as the pattern's star.
    neighbour_stars : int, optional
        The brightest centroids among which neighbours are found (default: half as many again
        as the table's stars expected in the frame, 6–40).
    confirm_stars : int
        The brightest centroids tried as the confirming fourth star.
    per_field : int, optional
        The pair table's brightest stars per lattice field
        (:func:`~skyfix.identify.catalogue.pairs.pair_table`).
        Default: as many as the frame's centroids would put in a field (:data:`PER_FIELD_STEPS`,
        :func:`per_field_for`): a star's nearest neighbours in the catalogue must be the ones the
        image shows, so a sparse frame needs a sparse table.
    max_candidates : int
        Work bound: confirmed correspondences verified.
    max_matches : int
        Work bound: catalogue patterns kept from each pivot's search.
    prob_threshold : float
        Largest accepted probability that the match is chance.

    Returns
    -------
    Identification
        ``method`` is ``"liebe"``; on failure, ``reason`` says why.

    Raises
    ------
    skyfix.errors.InputError
        An impossible option, centroids that are not (N, 2) numbers, or a frame size below 1.
    skyfix.errors.CameraError
        An impossible ``fov_deg``.
    """
    check_options(centroid_sigma_px, n_sigma, xy, width, height, k_nearest=k_nearest, pivots=pivots,
                  confirm_stars=confirm_stars, max_candidates=max_candidates, max_matches=max_matches,
                  **({} if neighbour_stars is None else {"neighbour_stars": neighbour_stars}),
                  **({} if per_field is None else {"per_field": per_field}))
    if k_nearest < 2:
        raise InputError(f"k_nearest must be at least 2 (a pattern needs two neighbours), got {k_nearest}")
    if not (0.0 <= buffer_deg < 90.0):
        raise InputError(f"buffer_deg must be between 0 and 90 degrees, got {buffer_deg!r}")
    frame = frame_for(METHOD, xy, width, height, fov_deg=fov_deg, fov_tolerance_deg=fov_tolerance_deg,
                      camera=camera, database=database, epoch=epoch, min_stars=4,
                      prob_threshold=prob_threshold, centroid_sigma_px=centroid_sigma_px)
    if isinstance(frame, Identification):
        return frame
    short_deg, diag_deg = frame_angles_deg(frame)
    per_field = per_field_for(frame) if per_field is None else per_field
    table = star_triangle_table(frame.database, short_deg, diag_deg, per_field=per_field, k_nearest=k_nearest,
                                buffer_deg=buffer_deg)
    n_stars = min(len(frame.xy), neighbour_stars or _neighbour_stars(frame, table))
    patterns = star_patterns(frame.rays[:n_stars], k_nearest, math.radians(buffer_deg))
    last = patterns.pivot_start[min(pivots, n_stars)]
    patterns = StarPatterns(patterns.stars[:last], patterns.features[:last], patterns.sides[:last],
                            patterns.pivot_start[:min(pivots, n_stars) + 1])
    stats = SearchStats()
    proposals = _proposals(frame, table, patterns, centroid_sigma_px, n_sigma, confirm_stars, max_matches,
                           stats)
    result = first_accepted(frame, proposals, n_tried=len(patterns.stars), max_candidates=max_candidates)
    if result.success:
        return result
    reason = (f"no match: {stats.found} catalogue patterns matched {len(patterns.stars)} image patterns "
              f"(θ1, θ2, signed φ), a fourth star confirmed {stats.confirmed} of {stats.tried}; "
              f"{result.n_candidates} verified, none accepted")
    if result.n_candidates >= max_candidates:
        reason += f" (stopped at max_candidates={max_candidates})"
    return failure(METHOD, reason, frame.t0, len(patterns.stars), result.n_candidates)
