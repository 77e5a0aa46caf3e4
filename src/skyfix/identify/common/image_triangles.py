"""The image's side of the triangle-feature methods (``liebe``, ``planar``, ``area-moment``): a
frame's triangles described with the catalogue's formulas (:mod:`skyfix.identify.catalogue.triangles`),
matched against the catalogue's tables, their vertex orders and handedness, and the proposals the
methods judge (:func:`triangle_proposals`); one options check for the three methods
(:func:`check_options`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix.errors import InputError
from skyfix.identify.catalogue.triangles import (
    AREA,
    FeatureIndex,
    FeatureMatches,
    TriangleTable,
    area_moment_sigma,
    breadth_first_triangles,
    confirm_fourth,
    describe_triangles,
    feature_matches,
    triangle_table,
)
from skyfix.identify.common.hypothesis import Frame

__all__ = ["ORDER_PARITY", "VERTEX_ORDERS", "ImageTriangles", "SearchStats", "area_moment_sigmas",
           "check_options", "confirmed_matches", "frame_angles_deg", "frame_triangle_table",
           "image_hand_filter", "image_triangles", "order_allowed", "ranked", "triangle_batches",
           "triangle_proposals", "vertex_orders"]


def check_options(centroid_sigma_px: float, n_sigma: float, xy, width, height, **bounds: int) -> None:
    """Raise :class:`~skyfix.errors.InputError` (one line) for centroids ``xy`` that are not an
    (N, 2) array of numbers (an empty one is fine), a frame size below one pixel, or an
    impossible option."""
    try:
        shape = np.shape(np.asarray(xy, dtype=np.float64))
    except (TypeError, ValueError):
        raise InputError("centroids must be an (N, 2) array of pixel positions (numbers)") from None
    if not ((len(shape) == 2 and shape[1] == 2) or (xy is not None and np.size(xy) == 0)):
        raise InputError(f"centroids must be an (N, 2) array of pixel positions, got shape {shape}")
    for name, size in (("width", width), ("height", height)):
        if not (isinstance(size, (int, np.integer, float)) and size >= 1):
            raise InputError(f"frame {name} must be a positive number of pixels, got {size!r}")
    if not (centroid_sigma_px > 0.0 and math.isfinite(centroid_sigma_px)):
        raise InputError(f"centroid_sigma_px must be a positive number of pixels, got {centroid_sigma_px!r}")
    if not (n_sigma > 0.0 and math.isfinite(n_sigma)):
        raise InputError(f"n_sigma must be positive, got {n_sigma!r}")
    for name, value in bounds.items():
        if not (isinstance(value, (int, np.integer)) and value >= 1):
            raise InputError(f"{name} must be a positive integer, got {value!r}")


def frame_triangle_table(frame: Frame, per_field: int) -> TriangleTable:
    """The triangle table for ``frame``: lattice fields as wide as the frame's shorter side
    (a field's stars are then in the frame), pairs up to the frame's diagonal at the shortest
    focal length allowed."""
    short_deg, diag_deg = frame_angles_deg(frame)
    return triangle_table(frame.database, short_deg, diag_deg, per_field=per_field)


def frame_angles_deg(frame: Frame) -> tuple[float, float]:
    """The angles across ``frame``'s shorter side and (2 % more than) its diagonal, degrees, at
    the shortest focal length allowed: the tables' field size and widest pair."""
    cam = frame.camera
    lo = frame.focal_range_px[0]
    short_deg = math.degrees(2.0 * math.atan(min(cam.width, cam.height) / 2.0 / lo))
    diag_deg = math.degrees(2.0 * math.atan(math.hypot(cam.width, cam.height) / 2.0 / lo))
    return short_deg, 1.02 * diag_deg


# ---- the image's triangles -------------------------------------------------------------------

@njit(cache=True)
def area_moment_sigmas(vectors, triangles, sigma_rad):
    """:func:`area_moment_sigma` of each of ``triangles`` (T, 3): (T, 3) columns σ_A, σ_J, σ_K."""
    out = np.empty((triangles.shape[0], 3))
    for r in range(triangles.shape[0]):
        out[r, 0], out[r, 1], out[r, 2] = area_moment_sigma(vectors[triangles[r, 0]],
                                                            vectors[triangles[r, 1]],
                                                            vectors[triangles[r, 2]], sigma_rad)
    return out


class ImageTriangles(NamedTuple):
    """The triangles of a frame's brightest centroids (:func:`image_triangles`), brightest first.

    stars : (M, 3) int32 — centroid rows, ordered by the sides opposite them (as the table's).
    features : (M, 9) float64 — :func:`describe_triangles`' columns, of the rays at the nominal
        focal length.
    handedness : (M,) int8 — the sign of the triple product of ``stars``' rays.
    sigma_rad : float — one centroid's angular noise, ``centroid_sigma_px / f``.
    feature_sigma : (M, 3) float64 — σ of area, moment and shape (:func:`area_moment_sigma`).
    ambiguous : (M, 2) bool — sides 0–1 and 1–2 equal within their noise (either vertex order).
    flat : (M,) bool — the triple product within its noise of 0 (handedness unknown).
    """

    stars: np.ndarray
    features: np.ndarray
    handedness: np.ndarray
    sigma_rad: float
    feature_sigma: np.ndarray
    ambiguous: np.ndarray
    flat: np.ndarray


def image_triangles(frame: Frame, n_stars: int, centroid_sigma_px: float, n_sigma: float) -> ImageTriangles:
    """Every triangle of ``frame``'s ``n_stars`` brightest centroids, breadth-first
    (:func:`breadth_first_triangles`), described as the table's are. Two sides are ambiguous
    when they differ by less than ``n_sigma`` times their difference's noise (2σ; a wrong
    focal length scales both alike); a triangle is
    flat when its triple product (≈ 2A) is within ``n_sigma`` of its noise (≈ 2σ_A)."""
    n = min(len(frame.xy), int(n_stars))
    tri = breadth_first_triangles(n)
    stars, features, hand = describe_triangles(frame.rays, tri)
    sigma = centroid_sigma_px / float(frame.camera.fx)
    tol = n_sigma * 2.0 * sigma
    ambiguous = np.column_stack([features[:, 1] - features[:, 0] <= tol,
                                 features[:, 2] - features[:, 1] <= tol])
    sig = area_moment_sigmas(frame.rays, stars, sigma)
    flat = features[:, AREA] <= n_sigma * sig[:, 0]
    return ImageTriangles(stars, features, hand, sigma, sig, ambiguous, flat)


# Vertex orders (of the sorted-side order) and their parity: +1 keeps the handedness, −1 flips it.
VERTEX_ORDERS = np.array([[0, 1, 2], [1, 0, 2], [0, 2, 1], [1, 2, 0], [2, 0, 1], [2, 1, 0]], np.int64)
ORDER_PARITY = np.array([1, -1, -1, 1, 1, -1], np.int64)


@njit(cache=True)
def order_allowed(o, ambiguous01, ambiguous12, flat, image_hand, table_hand):
    """Whether vertex order ``o`` (a row of :data:`VERTEX_ORDERS`) of an image triangle is tried
    against a catalogue triangle of handedness ``table_hand``: the sorted-side order, the swaps
    its ambiguous sides allow (all six when both pairs are), and of those only the ones with the
    catalogue's handedness, unless the image triangle is ``flat``."""
    if not (ambiguous01 and ambiguous12):
        if not (o == 0 or (o == 1 and ambiguous01) or (o == 2 and ambiguous12)):
            return False
    return flat or image_hand * ORDER_PARITY[o] == table_hand


def vertex_orders(image: ImageTriangles, m: int, table_hand: int) -> list[np.ndarray]:
    """The vertex orders (:func:`order_allowed`) of image triangle ``m`` against a catalogue
    triangle of handedness ``table_hand``: the image stars in each order."""
    a01, a12 = image.ambiguous[m]
    return [image.stars[m][VERTEX_ORDERS[o]].astype(np.int64) for o in range(6)
            if order_allowed(o, a01, a12, image.flat[m], int(image.handedness[m]), table_hand)]


def triangle_batches(n_triangles: int):
    """``(start, stop)`` runs of :func:`breadth_first_triangles` rows with the same largest
    star (the triangles star ``k`` adds), so that a method searches the brightest stars' first."""
    k, start = 2, 0
    while start < n_triangles:
        stop = min(n_triangles, (k + 1) * k * (k - 1) // 6)
        yield start, stop
        start, k = stop, k + 1


def image_hand_filter(image: ImageTriangles) -> np.ndarray:
    """The handedness :func:`feature_matches` may filter each image triangle on: its own, or 0
    (either) when the triangle is flat or its vertex order ambiguous."""
    return np.where(image.flat | image.ambiguous.any(axis=1), 0, image.handedness).astype(np.int8)


def ranked(matches: FeatureMatches) -> np.ndarray:
    """The order in which to propose ``matches``: image triangles breadth-first, each one's
    catalogue triangles by increasing score."""
    return np.lexsort((matches.score, matches.image))


@njit(cache=True)
def confirmed_matches(image_rows, table_rows, image_stars, ambiguous, flat, image_hand, image_sides,
                      table_stars, table_hand, table_sides, pairs, vectors, rays, candidates, noise,
                      calibrated, out):
    """The triangle matches (``image_rows[k]`` ↔ ``table_rows[k]``, ranked) whose sides, sorted,
    are the catalogue triangle's (the vertex assignment: each vertex is known by the side
    opposite it) and that a fourth star confirms, each vertex order :func:`order_allowed`
    tried: rows ``(k, order, image star, catalogue star)`` of ``out``.

    Sides and the fourth star's angles are compared at the scale the triangle implies (its
    catalogue over image perimeter; 1 with a calibrated camera), within ``noise``
    (``n_sigma·σ√2``, an angle's) plus, with the scale free, that scale's own noise (``noise·√3``
    over the perimeter) times the angle. Returns how many rows were written (at most
    ``len(out)``) and how many orders were tried."""
    n = 0
    tried = 0
    buf = np.empty((8, 2), np.int64)
    img = np.empty(3, np.int64)
    cat = np.empty(3, np.int64)
    for k in range(image_rows.shape[0]):
        m, r = image_rows[k], table_rows[k]
        per = image_sides[m, 0] + image_sides[m, 1] + image_sides[m, 2]
        scale = 1.0 if calibrated else (table_sides[r, 0] + table_sides[r, 1] + table_sides[r, 2]) / per
        relative = 0.0 if calibrated else noise * math.sqrt(3.0) / per
        # the vertex assignment: each vertex's opposite side (sorted) is the catalogue's, at that scale
        same = True
        for q in range(3):
            cat[q] = table_stars[r, q]
            seen = scale * image_sides[m, q]
            if abs(table_sides[r, q] - seen) > noise + relative * seen:
                same = False
        if not same:
            continue
        for o in range(6):
            if not order_allowed(o, ambiguous[m, 0], ambiguous[m, 1], flat[m], image_hand[m], table_hand[r]):
                continue
            tried += 1
            for q in range(3):
                img[q] = image_stars[m, VERTEX_ORDERS[o, q]]
            c = confirm_fourth(pairs, vectors, rays, img, cat, scale, noise, relative, candidates, buf)
            for q in range(min(c, buf.shape[0])):
                if n < out.shape[0]:
                    out[n, 0], out[n, 1], out[n, 2], out[n, 3] = k, o, buf[q, 0], buf[q, 1]
                    n += 1
        if n >= out.shape[0]:
            break
    return n, tried


class SearchStats:
    """What :func:`triangle_proposals` did, for a failure's reason: catalogue triangles
    ``found``, vertex assignments ``tried`` against a fourth star, and ``confirmed``."""

    def __init__(self) -> None:
        self.found = 0
        self.tried = 0
        self.confirmed = 0


_CHUNK = 256  # ranked triangle matches confirmed per kernel call


def triangle_proposals(frame: Frame, table: TriangleTable, image: ImageTriangles, index: FeatureIndex,
                       centre: np.ndarray, tolerance: np.ndarray, *, n_sigma: float, confirm_stars: int,
                       max_matches: int, stats: SearchStats, confirm: bool = True):
    """Correspondences of image triangles with catalogue triangles, in rank order, for
    :func:`~skyfix.identify.common.hypothesis.first_accepted`: the image triangles a batch at a time
    (those each new star adds, :func:`triangle_batches`), each batch's matches in ``index``
    (:func:`feature_matches` with ``centre`` ± ``tolerance`` in its columns, handedness
    :func:`image_hand_filter`) ranked (:func:`ranked`), each in the vertex orders
    :func:`order_allowed`; with ``confirm`` (and four centroids or more) only those a fourth star
    confirms (:func:`confirmed_matches` among the ``confirm_stars`` brightest), as 4-star
    correspondences."""
    usable = np.isfinite(centre).all(axis=1) & np.isfinite(tolerance).all(axis=1) & (tolerance[:, 0] > 0)
    hand = image_hand_filter(image)
    candidates = np.arange(min(len(frame.xy), confirm_stars), dtype=np.int64)
    confirm = confirm and len(frame.xy) >= 4
    noise = n_sigma * math.sqrt(2.0) * image.sigma_rad
    out = np.empty((4096, 4), np.int64)
    for start, stop in triangle_batches(len(image.stars)):
        rows = start + np.flatnonzero(usable[start:stop])
        matches = feature_matches(index, centre[rows], tolerance[rows], hand[rows], max_matches=max_matches)
        stats.found += matches.n_found
        k = ranked(matches)
        image_rows, table_rows = rows[matches.image[k]], matches.row[k]
        if not confirm:
            for m, row in zip(image_rows, table_rows, strict=True):
                cat = table.stars[row].astype(np.int64)
                for img in vertex_orders(image, m, int(table.handedness[row])):
                    yield img, cat
            continue
        for first in range(0, len(k), _CHUNK):  # a chunk of ranked matches at a time
            n, tried = confirmed_matches(image_rows[first:first + _CHUNK], table_rows[first:first + _CHUNK],
                                         image.stars, image.ambiguous, image.flat, image.handedness,
                                         image.features, table.stars, table.handedness, table.features,
                                         table.pairs, frame.stars.vectors, frame.rays, candidates, noise,
                                         frame.calibrated, out)
            stats.tried += tried
            stats.confirmed += n
            for c in range(n):
                j, o, star, catalog = out[c]
                img = image.stars[image_rows[first + j]][VERTEX_ORDERS[o]]
                cat = table.stars[table_rows[first + j]]
                yield np.append(img, star).astype(np.int64), np.append(cat, catalog).astype(np.int64)
