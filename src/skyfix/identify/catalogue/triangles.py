"""Star triangles and their features: the one table the triangle-feature methods share.

Thesis 000 reviews three ways to recognise a star triangle (§2.6.1–2.6.3): Liebe's two
inter-star angles and the angle between them at the first star (:mod:`skyfix.identify.methods.liebe`),
the interior angles of the planar triangle (:mod:`skyfix.identify.methods.planar`) and the area and
polar moment of the planar triangle (Cole & Crassidis; :mod:`skyfix.identify.methods.area_moment`). Each
formula is written once here, as a small compiled helper, and serves both the catalogue's
triangles (the tables) and the image's (:func:`describe_triangles`):

- sides — chords between unit vectors, ``|v_i − v_j|`` (not ``|v_i| − |v_j|``, the thesis's
  printed typo, which is always 0): :func:`chord_sides`, side ``i`` opposite vertex ``i``;
- the planar triangle's interior angles by the law of cosines: :func:`interior_angles`;
- its area by Heron's formula (in Kahan's stable arrangement): :func:`heron_area`;
- its polar moment ``J = A·(a² + b² + c²)/36``: :func:`polar_moment`;
- handedness, the sign of the triple product ``v0·(v1 × v2)`` (a rotation keeps it, a mirror
  image flips it; area, moment and angles cannot tell the two apart): :func:`triple_product`;
- Liebe's included angle at a star, signed the same way: :func:`included_angle`;
- the noise of area, moment and ``J/A²`` (Cole & Crassidis's σ_A, σ_J, derived with the chord
  sides): :func:`area_moment_sigma`.

**Vertex assignment.** A triangle's vertices are ordered by the sides opposite them, shortest
first (:func:`describe_triangles`), in the catalogue and in the image alike, so a match of
features is also a match of vertices; where two sides are equal within the noise the methods try
both assignments.

**The field-triangle table** (:func:`triangle_table`): every triangle of the ``per_field`` (8)
brightest stars of each field of the pair table's lattice (fields as wide as the frame's shorter
side, :func:`skyfix.identify.catalogue.pairs.pair_table`'s choice of stars), so every vertex is a pair-table
star. Not every triangle of the pair table's stars that fits in the frame: the count grows as
the cube of the stars per field (15°: 1.6 M triangles of 12 per field; the per-field limit keeps
83 k). The image forms its triangles from its brightest stars, which are the ones the table
holds. Rows are kept in one order; three sorted keys index them (:class:`FeatureIndex`, each
with its compared features copied in its order): by area (calibrated area–moment searches), by
the smallest interior angle (planar) and by ``J/A²`` (area–moment with the scale free).

**The star-triangle table** (:func:`star_triangle_table`, Liebe's): each star of the pair table
with every pair among its ``k_nearest`` nearest neighbours beyond a buffer radius (Liebe used the
two nearest; pairs among the k nearest tolerate a neighbour that is missing or extra in the
image), features (θ1, θ2, φ): the angles to the nearer and the farther neighbour and the signed
included angle at the star; indexed by θ1 and by φ (scale-free, for frames with a FOV only).

Both are built on first use and kept with their database
(:meth:`~skyfix.identify.PatternDatabase.derived`). :func:`feature_matches` is the one compiled
search: a range on the key feature by binary search, every other feature filtered.

Table sizes and build times: docs/identification-methods.md#the-triangle-table.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.rotation import chord_angle
from skyfix.identify.catalogue.database import PatternDatabase
from skyfix.identify.catalogue.pairs import (
    PairTable,
    field_members,
    neighbours_in_range,
    pair_table,
    pairs_in_range,
    rounded_fov_deg,
)

__all__ = ["ANGLES", "AREA", "BY_ANGLE", "BY_AREA", "BY_SHAPE", "MOMENT", "SHAPE", "SIDES",
           "FeatureIndex", "FeatureMatches", "StarTriangleTable", "TriangleTable",
           "area_moment_sigma", "breadth_first_triangles", "chord", "chord_sides", "confirm_fourth",
           "describe_star_triangles", "describe_triangles", "feature_index", "feature_matches",
           "field_triangles", "heron_area", "included_angle", "interior_angles", "polar_moment",
           "star_triangle_table", "triangle_table", "triple_product"]

# Columns of TriangleTable.features (and of describe_triangles' output).
SIDES = 0  # 0, 1, 2: chord sides, ascending (side i opposite vertex i)
AREA = 3  # Heron's area of the planar triangle
MOMENT = 4  # its polar moment
ANGLES = 5  # 5, 6, 7: interior angles at vertices 0, 1, 2 (ascending, as the sides)
SHAPE = 8  # J / A², scale-free: (a² + b² + c²) / (36 A)
N_FEATURES = 9
# The columns each index of TriangleTable compares, its key first.
BY_AREA = (AREA, MOMENT)  # calibrated area-moment
BY_SHAPE = (SHAPE, AREA, MOMENT)  # area-moment with the scale free
BY_ANGLE = (ANGLES, ANGLES + 1, SIDES + 2)  # planar: two interior angles, the longest side

# The lattice of fields whose brightest stars the triangles join: the pair table's
# (skyfix.identify.catalogue.pairs), so that every triangle star is a pair-table star.


# ---- each formula once ---------------------------------------------------------------------

@njit(cache=True, inline="always")
def chord(u, v):
    """``|u − v|``: the chord between two unit vectors."""
    dx, dy, dz = u[0] - v[0], u[1] - v[1], u[2] - v[2]
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True)
def chord_sides(v0, v1, v2):
    """The planar triangle's sides, chords ``(|v1 − v2|, |v0 − v2|, |v0 − v1|)``: side ``i``
    opposite vertex ``i`` (thesis 000 §2.6.2, corrected: chords, not ``|v1| − |v2|``)."""
    return chord(v1, v2), chord(v0, v2), chord(v0, v1)


@njit(cache=True)
def heron_area(a, b, c):
    """Heron's area ``√(s(s−a)(s−b)(s−c))`` of the triangle with sides ``a, b, c``, in Kahan's
    arrangement (sides sorted, parentheses as written), accurate for needle-thin triangles."""
    if a < b:
        a, b = b, a
    if b < c:
        b, c = c, b
    if a < b:
        a, b = b, a
    p = (a + (b + c)) * (c - (a - b)) * (c + (a - b)) * (a + (b - c))
    return 0.25 * math.sqrt(max(p, 0.0))


@njit(cache=True)
def polar_moment(a, b, c, area):
    """The polar moment of the planar triangle about its centroid, ``A·(a² + b² + c²)/36``."""
    return area * (a * a + b * b + c * c) / 36.0


@njit(cache=True)
def interior_angles(a, b, c):
    """The interior angles opposite sides ``a, b, c`` (law of cosines), radians."""
    ca = (b * b + c * c - a * a) / (2.0 * b * c)
    cb = (a * a + c * c - b * b) / (2.0 * a * c)
    cc = (a * a + b * b - c * c) / (2.0 * a * b)
    return (math.acos(min(max(ca, -1.0), 1.0)), math.acos(min(max(cb, -1.0), 1.0)),
            math.acos(min(max(cc, -1.0), 1.0)))


@njit(cache=True)
def triple_product(u, v, w):
    """``u·(v × w)``: positive when ``u, v, w`` turn counter-clockwise seen from outside the
    sphere; a rotation keeps its sign, a mirror image flips it."""
    return (u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
            + u[2] * (v[0] * w[1] - v[1] * w[0]))


@njit(cache=True)
def included_angle(p, a, b):
    """The signed spherical angle at ``p`` from the great circle towards ``a`` to the one
    towards ``b``, radians in (−π, π]: ``atan2(p·(a × b), a·b − (p·a)(p·b))`` (the sign is
    :func:`triple_product`'s)."""
    pa = p[0] * a[0] + p[1] * a[1] + p[2] * a[2]
    pb = p[0] * b[0] + p[1] * b[1] + p[2] * b[2]
    ab = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    return math.atan2(triple_product(p, a, b), ab - pa * pb)


@njit(cache=True, inline="always")
def _sub(u, v):
    return u[0] - v[0], u[1] - v[1], u[2] - v[2]


@njit(cache=True, inline="always")
def _cross(u, v):
    return u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]


@njit(cache=True, inline="always")
def _dot(u, v):
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


@njit(cache=True)
def area_moment_sigma(v0, v1, v2, sigma_rad):
    """Standard deviations ``(σ_A, σ_J, σ_K)`` of the area, the polar moment and the
    scale-free shape ``K = J/A²`` of the planar triangle of unit vectors ``v0, v1, v2``, each
    vector measured with the covariance ``σ²(I − v vᵀ)`` (the QUEST measurement model; ``σ =
    sigma_rad``), to first order (Cole & Crassidis 2006, derived with the chord sides).

    Notes
    -----
    With ``n`` the unit normal of ``m = (v1 − v0) × (v2 − v0)`` and ``A = |m|/2``, the area's
    gradient at vertex ``i`` is ``g_i = ½ (v_j − v_k) × n`` (``i, j, k`` cyclic). With ``S = a² +
    b² + c²`` (``∂S/∂v_i = 2(3v_i − v0 − v1 − v2)``), ``J = A·S/36`` has ``∂J/∂v_i = (S g_i +
    A ∂S/∂v_i)/36`` and ``K = S/(36A)`` has ``∂K/∂v_i = (A ∂S/∂v_i − S g_i)/(36A²)``. Each
    variance is ``σ² Σ_i |P_i ∂/∂v_i|²``, ``P_i = I − v_i v_iᵀ``.
    """
    m = _cross(_sub(v1, v0), _sub(v2, v0))
    norm = math.sqrt(_dot(m, m))
    if norm == 0.0:
        return math.inf, math.inf, math.inf
    n = (m[0] / norm, m[1] / norm, m[2] / norm)
    area = 0.5 * norm
    e01, e02, e12 = _sub(v1, v0), _sub(v2, v0), _sub(v2, v1)
    s = _dot(e01, e01) + _dot(e02, e02) + _dot(e12, e12)
    tot = (v0[0] + v1[0] + v2[0], v0[1] + v1[1] + v2[1], v0[2] + v1[2] + v2[2])
    var_a = var_j = var_k = 0.0
    for i in range(3):
        vi = v0 if i == 0 else (v1 if i == 1 else v2)
        vj = v1 if i == 0 else (v2 if i == 1 else v0)
        vk = v2 if i == 0 else (v0 if i == 1 else v1)
        c = _cross(_sub(vj, vk), n)
        g = (0.5 * c[0], 0.5 * c[1], 0.5 * c[2])
        ds = (2.0 * (3.0 * vi[0] - tot[0]), 2.0 * (3.0 * vi[1] - tot[1]), 2.0 * (3.0 * vi[2] - tot[2]))
        h = ((s * g[0] + area * ds[0]) / 36.0, (s * g[1] + area * ds[1]) / 36.0,
             (s * g[2] + area * ds[2]) / 36.0)
        w = 36.0 * area * area
        k = ((area * ds[0] - s * g[0]) / w, (area * ds[1] - s * g[1]) / w, (area * ds[2] - s * g[2]) / w)
        gi, hi, ki = _dot(g, vi), _dot(h, vi), _dot(k, vi)
        var_a += _dot(g, g) - gi * gi
        var_j += _dot(h, h) - hi * hi
        var_k += _dot(k, k) - ki * ki
    return (sigma_rad * math.sqrt(max(var_a, 0.0)), sigma_rad * math.sqrt(max(var_j, 0.0)),
            sigma_rad * math.sqrt(max(var_k, 0.0)))


# ---- describing triangles (catalogue and image alike) ---------------------------------------

@njit(cache=True)
def describe_triangles(vectors, triangles):
    """The features of ``triangles`` (T, 3) (rows of unit ``vectors``), vertices reordered so
    that side ``i`` (opposite vertex ``i``) is the ``i``-th shortest.

    Returns
    -------
    stars : (T, 3) int32 — the reordered vertices.
    features : (T, 9) float64 — columns :data:`SIDES` (3), :data:`AREA`, :data:`MOMENT`,
        :data:`ANGLES` (3), :data:`SHAPE`.
    handedness : (T,) int8 — the sign of :func:`triple_product` of the reordered vertices.
    """
    t = triangles.shape[0]
    stars = np.empty((t, 3), np.int32)
    features = np.empty((t, N_FEATURES))
    hand = np.empty(t, np.int8)
    for r in range(t):
        i0, i1, i2 = triangles[r, 0], triangles[r, 1], triangles[r, 2]
        s = np.array(chord_sides(vectors[i0], vectors[i1], vectors[i2]))
        order = np.argsort(s)
        vs = (i0, i1, i2)
        for q in range(3):
            stars[r, q] = vs[order[q]]
        a, b, c = s[order[0]], s[order[1]], s[order[2]]
        area = heron_area(a, b, c)
        moment = polar_moment(a, b, c, area)
        p0, p1, p2 = interior_angles(a, b, c)
        features[r, 0], features[r, 1], features[r, 2] = a, b, c
        features[r, AREA] = area
        features[r, MOMENT] = moment
        features[r, ANGLES], features[r, ANGLES + 1], features[r, ANGLES + 2] = p0, p1, p2
        features[r, SHAPE] = (a * a + b * b + c * c) / (36.0 * area) if area > 0.0 else math.inf
        tp = triple_product(vectors[stars[r, 0]], vectors[stars[r, 1]], vectors[stars[r, 2]])
        hand[r] = 1 if tp > 0.0 else (-1 if tp < 0.0 else 0)
    return stars, features, hand


@njit(cache=True)
def describe_star_triangles(vectors, triangles):
    """Liebe's features of ``triangles`` (T, 3) = (star, nearer neighbour, farther neighbour):
    (T, 3) columns θ1, θ2 (the angles from the star to each, radians) and φ (the signed
    :func:`included_angle` at the star from the first to the second)."""
    t = triangles.shape[0]
    out = np.empty((t, 3))
    for r in range(t):
        p, a, b = vectors[triangles[r, 0]], vectors[triangles[r, 1]], vectors[triangles[r, 2]]
        out[r, 0] = chord_angle(chord(p, a))
        out[r, 1] = chord_angle(chord(p, b))
        out[r, 2] = included_angle(p, a, b)
    return out


def breadth_first_triangles(n: int) -> np.ndarray:
    """All 3-subsets of ``range(n)`` (int64 (C, 3), each row ascending), those of the brightest
    stars first: sorted by their largest member, then lexicographically."""
    i, j, k = np.meshgrid(*[np.arange(n)] * 3, indexing="ij")
    sel = (i < j) & (j < k)
    c = np.stack([i[sel], j[sel], k[sel]], axis=1)
    return np.ascontiguousarray(c[np.lexsort((c[:, 1], c[:, 0], c[:, 2]))], dtype=np.int64)


# ---- the tables ------------------------------------------------------------------------------

class FeatureIndex(NamedTuple):
    """A table's rows sorted by one feature, with the features a search compares copied in
    that order (a search then reads memory in sequence, not at random: ~10× faster).

    order : (T,) int32 — the table's rows, by ``features[:, 0]`` ascending (non-finite last).
    key : (T,) float64 — ``features[:, 0]``, contiguous (the binary search's).
    features : (T, C) float64 — the compared features of ``order``'s rows (``columns`` of the
        table's), the key first.
    handedness : (T,) int8 — the rows' handedness (0: not compared).
    columns : tuple — the table's feature columns copied.
    """

    order: np.ndarray
    key: np.ndarray
    features: np.ndarray
    handedness: np.ndarray
    columns: tuple


def feature_index(features: np.ndarray, columns: tuple, handedness: np.ndarray | None = None) -> FeatureIndex:
    """The :class:`FeatureIndex` of ``features`` by ``columns[0]``, copying ``columns``."""
    order = np.argsort(features[:, columns[0]], kind="stable").astype(np.int32)
    copied = np.ascontiguousarray(features[order][:, list(columns)])
    hand = np.zeros(len(order), np.int8) if handedness is None else np.ascontiguousarray(handedness[order])
    return FeatureIndex(order, np.ascontiguousarray(copied[:, 0]), copied, hand, tuple(columns))


class TriangleTable(NamedTuple):
    """The field-triangle table (module text).

    stars : (T, 3) int32 — vertices (rows of the star index), ordered by the sides opposite them.
    features : (T, 9) float64 — :func:`describe_triangles`' columns (chords, unit sphere).
    handedness : (T,) int8 — sign of the vertices' triple product.
    by_area, by_angle, by_shape : FeatureIndex — the rows by area, by smallest interior angle
        and by :data:`SHAPE`.
    pairs : PairTable — the pairs of the table's stars (the fourth-star confirmation's).
    max_angle_rad : float — the widest side held.
    """

    stars: np.ndarray
    features: np.ndarray
    handedness: np.ndarray
    by_area: FeatureIndex
    by_angle: FeatureIndex
    by_shape: FeatureIndex
    pairs: PairTable
    max_angle_rad: float


class StarTriangleTable(NamedTuple):
    """Liebe's star-triangle table (module text).

    stars : (T, 3) int32 — (star, nearer neighbour, farther neighbour).
    features : (T, 3) float64 — θ1, θ2, φ (:func:`describe_star_triangles`).
    sides : (T, 3) float64 — the chord sides, ascending (the fourth star's scale).
    by_theta : FeatureIndex — the rows by θ1 (columns θ1, θ2, φ).
    by_phi : FeatureIndex — the rows by φ (columns φ, θ1, θ2): the key when the scale is free.
    pairs : PairTable — the pair table whose stars and neighbours they are.
    """

    stars: np.ndarray
    features: np.ndarray
    sides: np.ndarray
    by_theta: FeatureIndex
    by_phi: FeatureIndex
    pairs: PairTable


def field_triangles(vectors: np.ndarray, fov_rad: float, per_field: int) -> np.ndarray:
    """Every triangle (T, 3) int32, rows ascending and unique, of the ``per_field`` brightest
    stars of each lattice field of radius ``fov_rad / 2`` (the pair table's lattice)."""
    combos = breadth_first_triangles(per_field)
    packed = []
    for top in field_members(vectors, fov_rad, per_field):
        tri = top[:, combos].reshape(-1, 3).astype(np.int64)  # members and combinations ascending
        tri = tri[(tri >= 0).all(axis=1)]
        packed.append(np.unique((tri[:, 0] << 42) | (tri[:, 1] << 21) | tri[:, 2]))
    key = np.unique(np.concatenate(packed)) if packed else np.zeros(0, np.int64)
    mask = (1 << 21) - 1
    return np.ascontiguousarray(np.column_stack([key >> 42, (key >> 21) & mask, key & mask]).astype(np.int32))


def triangle_table(database: PatternDatabase, fov_deg: float, max_angle_deg: float, *,
                   per_field: int = 8, pair_stars: int = 12) -> TriangleTable:
    """The field-triangle table of ``database`` for frames about ``fov_deg`` wide: every triangle
    of the ``per_field`` brightest stars of each lattice field; its :attr:`TriangleTable.pairs`
    the pair table of ``pair_stars`` per field with pairs up to ``max_angle_deg`` (the frame's
    diagonal with its tolerance). Built on first use and kept with the database (15° with a FOV
    known to 10 %: 83 k triangles, ~1.7 s)."""
    pairs = pair_table(database, fov_deg, max_angle_deg, per_field=pair_stars)
    fov_rad = math.radians(rounded_fov_deg(fov_deg))

    def make() -> TriangleTable:
        vectors = database.star_index().vectors
        stars, features, hand = describe_triangles(vectors, field_triangles(vectors, fov_rad, per_field))
        return TriangleTable(stars, features, hand, feature_index(features, BY_AREA, hand),
                             feature_index(features, BY_ANGLE, hand), feature_index(features, BY_SHAPE, hand),
                             pairs, pairs.max_angle_rad)

    return database.derived(("triangles", fov_rad, per_field, id(pairs)), make)


def star_triangle_table(database: PatternDatabase, fov_deg: float, max_angle_deg: float, *,
                        per_field: int = 12, k_nearest: int = 4,
                        buffer_deg: float = 0.0) -> StarTriangleTable:
    """Liebe's star-triangle table: each star of the pair table (``per_field``) with every pair
    among its ``k_nearest`` nearest neighbours farther than ``buffer_deg``; kept with the
    database."""
    pairs = pair_table(database, fov_deg, max_angle_deg, per_field=per_field)

    def make() -> StarTriangleTable:
        vectors = database.star_index().vectors
        start, neighbour, angle = pairs.neighbour_start, pairs.neighbour, pairs.neighbour_angle
        buffer = math.radians(buffer_deg)
        rows = []
        ii, jj = np.triu_indices(k_nearest, 1)
        for s in pairs.stars:  # one slice per star; the triangles are vectorised
            lo = start[s] + np.searchsorted(angle[start[s]:start[s + 1]], buffer, side="right")
            near = neighbour[lo:min(lo + k_nearest, start[s + 1])]
            keep = jj < len(near)
            if keep.any():
                rows.append(np.column_stack([np.full(keep.sum(), s), near[ii[keep]], near[jj[keep]]]))
        tri = np.concatenate(rows).astype(np.int32) if rows else np.zeros((0, 3), np.int32)
        tri = np.ascontiguousarray(tri)
        features = describe_star_triangles(vectors, tri)
        sides = np.ascontiguousarray(describe_triangles(vectors, tri)[1][:, SIDES:SIDES + 3])
        return StarTriangleTable(tri, features, sides, feature_index(features, (0, 1, 2)),
                                 feature_index(features, (2, 0, 1)), pairs)

    return database.derived(("star-triangles", id(pairs), k_nearest, float(buffer_deg)), make)


# ---- the search ------------------------------------------------------------------------------

class FeatureMatches(NamedTuple):
    """What :func:`feature_matches` found: ``image`` (K,) the image triangle (row of the query),
    ``row`` (K,) the table row, ``score`` (K,) Σ ((feature − measured) / tolerance)², ``n_found``
    how many matched (more than K when the output filled up)."""

    image: np.ndarray
    row: np.ndarray
    score: np.ndarray
    n_found: int


@njit(cache=True)
def _feature_matches(key, features, table_hand, centre, tolerance, image_hand, out_image, out_row, out_score):
    n = 0
    for m in range(centre.shape[0]):
        start, stop = pairs_in_range(key, centre[m, 0] - tolerance[m, 0], centre[m, 0] + tolerance[m, 0])
        for t in range(start, stop):
            if image_hand[m] != 0 and table_hand[t] != image_hand[m]:
                continue
            score = ((key[t] - centre[m, 0]) / tolerance[m, 0]) ** 2
            ok = True
            for f in range(1, centre.shape[1]):
                d = abs(features[t, f] - centre[m, f])
                if not d <= tolerance[m, f]:
                    ok = False
                    break
                score += (d / tolerance[m, f]) ** 2
            if ok:
                if n < out_row.shape[0]:
                    out_image[n] = m
                    out_row[n] = t
                    out_score[n] = score
                n += 1
    return n


def feature_matches(index: FeatureIndex, centre: np.ndarray, tolerance: np.ndarray, image_hand: np.ndarray, *,
                    max_matches: int = 100_000) -> FeatureMatches:
    """The table rows whose features match each image triangle's.

    Parameters
    ----------
    index : FeatureIndex
        The table's rows sorted by the key feature, with the features compared.
    centre, tolerance : (M, C) float64
        Each image triangle's measured features (``index.columns``) and their allowed errors (a
        row matches when ``|feature − centre| ≤ tolerance`` in every column).
    image_hand : (M,) int8
        Handedness each image triangle requires of its matches (0: either; a near-isosceles or
        flat triangle).
    max_matches : int
        Work bound: matches returned at most (all are counted).
    """
    out_image = np.empty(max_matches, np.int64)
    out_row = np.empty(max_matches, np.int64)
    out_score = np.empty(max_matches)
    n = _feature_matches(index.key, index.features, index.handedness,
                         np.ascontiguousarray(centre, np.float64),
                         np.ascontiguousarray(tolerance, np.float64),
                         np.ascontiguousarray(image_hand, np.int8), out_image, out_row, out_score)
    k = min(n, max_matches)
    return FeatureMatches(out_image[:k], index.order[out_row[:k]].astype(np.int64), out_score[:k], int(n))


@njit(cache=True)
def confirm_fourth(pairs, vectors, rays, triangle_stars, triangle_catalog, scale, tolerance, relative,
                   candidates, out):
    """Fourth stars that confirm a triangle match: image stars (rows of ``rays``, in the order
    of ``candidates``, the triangle's own skipped) whose angles ``t`` to the three matched stars,
    times ``scale`` (catalogue over image angle), are within ``tolerance + relative·t`` of a
    catalogue star's angles to ``triangle_catalog`` (that star among the first vertex's
    neighbours in ``pairs``), on the same side of the first edge (three angles fix a point up
    to its mirror image; not tested when the star is within the noise of that edge's great
    circle). Writes (image star, catalogue star) rows into ``out``; returns how
    many there are."""
    n = 0
    c0 = triangle_catalog[0]
    for star in candidates:
        if star == triangle_stars[0] or star == triangle_stars[1] or star == triangle_stars[2]:
            continue
        t0 = chord_angle(chord(rays[star], rays[triangle_stars[0]])) * scale
        t1 = chord_angle(chord(rays[star], rays[triangle_stars[1]])) * scale
        t2 = chord_angle(chord(rays[star], rays[triangle_stars[2]])) * scale
        w0, w1, w2 = tolerance + relative * t0, tolerance + relative * t1, tolerance + relative * t2
        side = triple_product(rays[star], rays[triangle_stars[0]], rays[triangle_stars[1]])
        sure = abs(side) > tolerance * (t0 + t1 + chord(rays[triangle_stars[0]], rays[triangle_stars[1]]))
        hand = (1.0 if side > 0.0 else -1.0) if sure else 0.0
        start, stop = neighbours_in_range(pairs, c0, t0 - w0, t0 + w0)
        for q in range(start, stop):
            d = pairs.neighbour[q]
            if d == triangle_catalog[1] or d == triangle_catalog[2]:
                continue
            if abs(chord_angle(chord(vectors[d], vectors[triangle_catalog[1]])) - t1) > w1:
                continue
            if abs(chord_angle(chord(vectors[d], vectors[triangle_catalog[2]])) - t2) > w2:
                continue
            # three angles fix the fourth star up to a mirror image: its side of the first edge too
            if hand != 0 and hand * triple_product(vectors[d], vectors[c0], vectors[triangle_catalog[1]]) < 0:
                continue
            if n < out.shape[0]:
                out[n, 0] = star
                out[n, 1] = d
            n += 1
    return n
