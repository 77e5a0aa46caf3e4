"""Sky coverage and the seeds' catalogue tools: stars per field, the sorted distance table,
sub-catalogues from an attitude envelope (thesis 004 ch. 5, thesis 000 §1.3.3).

- :func:`star_counts` — 004 §5.1's ``Stats.mod``: the catalogue stars inside a rectangular
  field at uniformly random pointings *and rolls* (a uniform rotation), counted for every
  pointing at once: the catalogue's unit vectors and the boresights in two k-d trees, every
  (pointing, star) pair within the half-diagonal cone found by one tree-to-tree search, then the
  rectangle test in camera coordinates (``|x/z| <= tan(W/2)``, ``|y/z| <= tan(H/2)``).
- :func:`distance_table` — 004 §5.3's ``DistTab.mod``: every catalogue pair between 0.25° and
  the FOV diagonal, sorted by angle (built by :func:`skyfix.identify.catalogue.pairs.build_pair_table`).
- :func:`sub_catalogue` — 004 §5.2's ``MakeCat.mod``: the stars that can appear in view over a
  set of attitudes (:func:`sunsat_attitudes` samples 004's orbit/roll/pitch/yaw envelope,
  :func:`cone_attitudes` a boresight cone at any roll), optionally through 004's 1° × 1° RA/Dec
  blocks.

Magnitudes are Hipparcos Hp (the only band :func:`skyfix.catalog.load_hipparcos` carries).
Thesis 004's catalogue is 5,026 stars to V 6; Hp runs fainter than V for most stars
(Hp − V ≈ +0.1 for a K star), so Hp ≤ 6 holds only 4,559 stars and the same 5,026 stars are
Hp ≤ 6.086: :func:`limit_for_count` gives that limit, and docs/identification-study.md compares
both with the thesis.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from skyfix.catalog import Catalog, fibonacci_sphere, load_hipparcos
from skyfix.errors import InputError
from skyfix.frames import (
    elementary_rotation,
    matrix_from_euler123,
    orbit_frame_from_elements,
    sunsat_mounting,
)
from skyfix.geometry import radec_to_vector, vector_to_radec
from skyfix.identify.catalogue.pairs import build_pair_table
from skyfix.validate import check_count, check_fov

__all__ = ["CATALOG_EPOCH", "DistanceTable", "StarCounts", "SunsatEnvelope", "TABLE_3_5", "TABLE_5_2",
           "format_counts", "plot_counts",
           "THESIS_004_CATALOG_SIZE", "cone_attitudes", "coverage_catalog", "distance_table",
           "half_diagonal_rad", "limit_for_count", "star_counts", "stars_in_fields", "sub_catalogue",
           "sunsat_attitude_matrix", "sunsat_attitudes"]

CATALOG_EPOCH = 2000.0  # positions for the statistics (the counts do not depend on it at 1e-4)
THESIS_004_CATALOG_SIZE = 5026  # stars ≤ Mv 6 in thesis 004 (§7.2, App. A)
_CHUNK = 50_000  # pointings per tree search (~1 M candidate pairs at 14° diagonal, V ≤ 6)


class StarCounts(NamedTuple):
    """Catalogue stars per field over random pointings (:func:`star_counts`).

    counts : (n,) int32 — stars inside the field at each pointing.
    fov_w_deg, fov_h_deg : float — the field's full width and height, degrees.
    mag_limit : float — the catalogue's faintest magnitude (Hp).
    n_catalog : int — stars in the catalogue used.
    seed : int — the pointings' random seed.
    p_lt3, p_lt4, p_lt5 : float — fraction of pointings with fewer than 3, 4, 5 stars.
    mean : float — mean stars per field.
    max : int — most stars in one field; ``n_at_max`` pointings had that many.
    """

    counts: np.ndarray
    fov_w_deg: float
    fov_h_deg: float
    mag_limit: float
    n_catalog: int
    seed: int
    p_lt3: float
    p_lt4: float
    p_lt5: float
    mean: float
    max: int
    n_at_max: int

    @property
    def n_pointings(self) -> int:
        return len(self.counts)

    def probability(self) -> np.ndarray:
        """P(k stars) for k = 0 … max (the histogram of 004's Fig. 5-1 / Table 5-1)."""
        return np.bincount(self.counts, minlength=self.max + 1) / max(len(self.counts), 1)

    def standard_error(self, p: float) -> float:
        """The binomial sampling error of a fraction ``p`` of these pointings."""
        return math.sqrt(max(p * (1.0 - p), 0.0) / max(len(self.counts), 1))

    def summary(self) -> dict:
        """The settings and summary numbers (no per-pointing counts), JSON-ready."""
        d = {k: getattr(self, k) for k in self._fields if k != "counts"}
        d["n_pointings"] = self.n_pointings
        d["band"] = "Hp"
        d["p_lt3_stderr"] = self.standard_error(self.p_lt3)
        d["probability"] = self.probability().round(8).tolist()
        return d


class DistanceTable(NamedTuple):
    """Thesis 004's sorted distance table (App. D.1): catalogue pairs by increasing angle.

    angle_rad : (P,) float64 — ascending, each in [min_angle_rad, max_angle_rad].
    first, second : (P,) int32 — the pairs' stars (rows of the catalogue given), ``first < second``.
    n_stars : int — stars in the catalogue given.
    min_angle_rad, max_angle_rad : float — the range held.
    """

    angle_rad: np.ndarray
    first: np.ndarray
    second: np.ndarray
    n_stars: int
    min_angle_rad: float
    max_angle_rad: float

    @property
    def n_pairs(self) -> int:
        return len(self.angle_rad)

    @property
    def size_bytes(self) -> int:
        """Its size in 004's record format: two 2-byte star numbers and a 4-byte REAL per pair."""
        return 8 * self.n_pairs


class SunsatEnvelope(NamedTuple):
    """Thesis 004's attitude envelope (Tables 3-5, 5-2): (min, max) of each angle, degrees.

    roll, pitch, yaw : body attitude in the orbit frame (Euler 1-2-3).
    arg_lat : ω′, argument of perigee + true anomaly.
    incl : orbit inclination i.
    node : right ascension of the ascending node Ω.
    """

    roll: tuple[float, float]
    pitch: tuple[float, float]
    yaw: tuple[float, float]
    arg_lat: tuple[float, float]
    incl: tuple[float, float]
    node: tuple[float, float]


TABLE_3_5 = SunsatEnvelope((-10.0, 10.0), (-5.0, 5.0), (130.0, 140.0), (0.0, 360.0), (97.0, 97.0),
                           (0.0, 120.0))  # 004's matching simulations: 540 stars, 16,281 pairs
TABLE_5_2 = SunsatEnvelope((-10.0, 10.0), (-5.0, 5.0), (130.0, 140.0), (0.0, 360.0), (97.0, 97.0),
                           (133.0, 149.0))  # a typical two-week envelope: 113 stars


def half_diagonal_rad(fov_w_deg: float, fov_h_deg: float) -> float:
    """The angle from the boresight to a corner of a ``fov_w_deg`` × ``fov_h_deg`` pinhole field."""
    return math.atan(math.hypot(math.tan(math.radians(fov_w_deg) / 2.0),
                                math.tan(math.radians(fov_h_deg) / 2.0)))


def limit_for_count(catalog: Catalog, n_stars: int) -> float:
    """The magnitude limit that keeps the ``n_stars`` brightest stars of ``catalog`` (e.g. the Hp
    limit of as many stars as thesis 004's 5,026 stars ≤ V 6: 6.086)."""
    n_stars = check_count(n_stars, "n_stars")
    if n_stars > len(catalog):
        raise InputError(f"n_stars {n_stars} exceeds the catalogue's {len(catalog)} stars")
    return float(np.sort(catalog.mag)[n_stars - 1])


def coverage_catalog(mag_limit: float) -> Catalog:
    """Hipparcos to Hp ``mag_limit`` at :data:`CATALOG_EPOCH`, the catalogue the statistics use
    by default."""
    if not math.isfinite(float(mag_limit)):
        raise InputError(f"magnitude limit {mag_limit} is not a number")
    return load_hipparcos(epoch=CATALOG_EPOCH, mag_limit=float(mag_limit))


def stars_in_fields(vectors: np.ndarray, A_icrs_to_cam: np.ndarray, fov_w_deg: float, fov_h_deg: float,
                    tree: cKDTree | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Every (field, star) with star ``vectors[star]`` inside the rectangular pinhole field of
    attitude ``A_icrs_to_cam[field]``.

    Parameters
    ----------
    vectors : (S, 3) — unit vectors (ICRS).
    A_icrs_to_cam : (n, 3, 3) — attitudes, ``b = A r``; the field is centred on ``A[2]``, its
        width along the camera x axis.
    fov_w_deg, fov_h_deg : float — full width and height of the field.
    tree : cKDTree, optional — a k-d tree on ``vectors`` (built if not given).

    Returns
    -------
    field, star : (K,) int64 arrays, ordered by field.
    """
    A = np.asarray(A_icrs_to_cam, np.float64).reshape(-1, 3, 3)
    v = np.asarray(vectors, np.float64)
    tree = cKDTree(v) if tree is None else tree
    chord = 2.0 * math.sin(min(half_diagonal_rad(fov_w_deg, fov_h_deg), math.pi / 2) / 2.0) + 1e-12
    found = cKDTree(A[:, 2]).sparse_distance_matrix(tree, chord, output_type="ndarray")
    field, star = found["i"].astype(np.int64), found["j"].astype(np.int64)
    order = np.lexsort((star, field))
    field, star = field[order], star[order]
    b = np.einsum("kij,kj->ki", A[field], v[star])
    tw, th = math.tan(math.radians(fov_w_deg) / 2.0), math.tan(math.radians(fov_h_deg) / 2.0)
    inside = (b[:, 2] > 0) & (np.abs(b[:, 0]) <= tw * b[:, 2]) & (np.abs(b[:, 1]) <= th * b[:, 2])
    return field[inside], star[inside]


def star_counts(fov_w_deg: float, fov_h_deg: float, mag_limit: float, n_pointings: int, seed: int = 0, *,
                catalog: Catalog | None = None,
                progress: Callable[[int], None] | None = None) -> StarCounts:
    """Stars per field at ``n_pointings`` uniformly random attitudes (pointing and roll).

    Parameters
    ----------
    fov_w_deg, fov_h_deg : float
        The field's full width and height, degrees (004: 11.17 × 8.32).
    mag_limit : float
        Faintest magnitude counted (Hp; 004 used V ≤ 6, about Hp ≤ 6.086: :func:`limit_for_count`).
    n_pointings : int
        Random attitudes (004: 10⁶).
    seed : int
        Seed of the attitudes.
    catalog : Catalog, optional
        Stars (default: :func:`coverage_catalog`); cut to ``mag_limit``.
    progress : callable, optional
        Called with the number of pointings done after each chunk.

    Returns
    -------
    StarCounts

    Raises
    ------
    skyfix.errors.InputError
        An implausible field, a non-finite magnitude or a count below 1.
    """
    fov_w_deg, fov_h_deg = check_fov(fov_w_deg, "fov width"), check_fov(fov_h_deg, "fov height")
    if fov_w_deg >= 180.0 or fov_h_deg >= 180.0:
        raise InputError("a rectangular pinhole field must be narrower than 180 degrees")
    n_pointings = check_count(n_pointings, "n_pointings")
    if not math.isfinite(float(mag_limit)):
        raise InputError(f"magnitude limit {mag_limit} is not a number")
    cat = coverage_catalog(mag_limit) if catalog is None else catalog.brighter_than(float(mag_limit))
    rng = np.random.default_rng(seed)
    counts = np.zeros(n_pointings, np.int32)
    tree = cKDTree(cat.vectors)
    for start in range(0, n_pointings, _CHUNK):
        n = min(_CHUNK, n_pointings - start)
        A = Rotation.random(n, random_state=rng).as_matrix()
        field, _ = stars_in_fields(cat.vectors, A, fov_w_deg, fov_h_deg, tree)
        counts[start:start + n] = np.bincount(field, minlength=n)
        if progress is not None:
            progress(n)
    top = int(counts.max())
    return StarCounts(counts, float(fov_w_deg), float(fov_h_deg), float(mag_limit), len(cat), int(seed),
                      float(np.mean(counts < 3)), float(np.mean(counts < 4)), float(np.mean(counts < 5)),
                      float(counts.mean()), top, int(np.sum(counts == top)))


def distance_table(catalog_subset: Catalog, max_angle_deg: float, min_angle_deg: float = 0.25
                   ) -> DistanceTable:
    """Thesis 004's sorted distance table: every pair of ``catalog_subset``'s stars between
    ``min_angle_deg`` (004: 0.25°, closer pairs merge on the detector) and ``max_angle_deg``
    (004: 13.9°, the FOV diagonal), by increasing angle.

    Raises
    ------
    skyfix.errors.InputError
        Angles not with 0 <= min < max <= 180.
    """
    lo, hi = float(min_angle_deg), float(max_angle_deg)
    if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo < hi <= 180.0):
        raise InputError(f"distance table range {min_angle_deg}–{max_angle_deg} degrees "
                         "is not 0 <= min < max <= 180")
    table = build_pair_table(catalog_subset.vectors, np.arange(len(catalog_subset), dtype=np.int32),
                             math.radians(hi))
    start = int(np.searchsorted(table.angle_rad, math.radians(lo), side="left"))
    return DistanceTable(table.angle_rad[start:], table.first[start:], table.second[start:],
                         len(catalog_subset), math.radians(lo), math.radians(hi))


def sunsat_attitudes(envelope: SunsatEnvelope = TABLE_3_5, step_deg: float = 2.0,
                     arg_lat_step_deg: float = 5.0) -> np.ndarray:
    """Camera attitudes (n, 3, 3) ``A_icrs_to_cam`` over thesis 004's envelope, every angle
    stepped by at most ``step_deg``, ω′ by ``arg_lat_step_deg`` (ω′ turns the field about an
    axis within 11° of its boresight: a 5° step moves a corner by 0.6°, less than a 2° step of
    Ω or roll moves the field).

    Thesis 004 §1.3–1.4's chain, with Appendix Z's corrections, from :mod:`skyfix.frames`:
    A_c→o = A_y(−ω′)·A_x(−90°)·A_y(−i)·A_z(90° + Ω) (:func:`~skyfix.frames.orbit_frame_from_elements`);
    A_o→b = A_z(ψ)·A_y(θ)·A_x(φ) (:func:`~skyfix.frames.matrix_from_euler123`); the sensor on the
    body, A_ss→b = A_z(−45°)·A_x(180°), with skyfix's camera frame (x_ss, −z_ss, y_ss)
    (:func:`~skyfix.frames.sunsat_mounting`). 004's B1950 frame is taken as ICRS: the
    0.7° precession moves a sub-catalogue's edge, not its size.
    """
    if not all(math.isfinite(s) and s > 0 for s in (step_deg, arg_lat_step_deg)):
        raise InputError(f"steps {step_deg}, {arg_lat_step_deg} degrees are not positive")

    def grid(rng_deg: tuple[float, float], step: float) -> np.ndarray:
        lo, hi = rng_deg
        n = max(1, math.ceil((hi - lo) / step - 1e-9)) + 1 if hi > lo else 1
        return np.radians(np.linspace(lo, hi, n))

    axes = [grid(envelope.roll, step_deg), grid(envelope.pitch, step_deg), grid(envelope.yaw, step_deg),
            grid(envelope.arg_lat, arg_lat_step_deg), grid(envelope.incl, step_deg),
            grid(envelope.node, step_deg)]
    return sunsat_attitude_matrix(*(a.ravel() for a in np.meshgrid(*axes, indexing="ij")))


def sunsat_attitude_matrix(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray, arg_lat: np.ndarray,
                           incl: np.ndarray, node: np.ndarray) -> np.ndarray:
    """Thesis 004's camera attitudes ``A_icrs_to_cam`` (n, 3, 3) for arrays of its six angles,
    radians (the chain of :func:`sunsat_attitudes`)."""
    roll, pitch, yaw, u, incl, node = (np.atleast_1d(np.asarray(a, np.float64))
                                       for a in (roll, pitch, yaw, arg_lat, incl, node))
    A_icrs_to_body = matrix_from_euler123(roll, pitch, yaw) @ orbit_frame_from_elements(node, incl, u)
    return sunsat_mounting().camera_attitude(A_icrs_to_body)


def cone_attitudes(axis: np.ndarray, radius_deg: float, step_deg: float = 1.0) -> np.ndarray:
    """Attitudes (n, 3, 3) whose boresights cover the cone of ``radius_deg`` about unit vector
    ``axis`` (a lattice ``step_deg`` apart) at rolls ``step_deg`` apart: "any roll"."""
    if not (math.isfinite(step_deg) and step_deg > 0 and 0 <= radius_deg <= 180):
        raise InputError(f"cone radius {radius_deg} / step {step_deg} degrees out of range")
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    lattice = fibonacci_sphere(max(1, math.ceil(4.0 * math.pi / math.radians(step_deg) ** 2)))
    near = lattice[lattice[:, 2] >= math.cos(math.radians(radius_deg))]
    up = np.array([0.0, 0.0, 1.0])
    towards = Rotation.align_vectors(axis[None], up[None])[0]
    boresights = np.vstack([axis[None], towards.apply(near)])
    rolls = np.radians(np.arange(0.0, 360.0, step_deg))
    # a frame per boresight: z the boresight, x perpendicular; then every roll about z
    helper = np.where(np.abs(boresights[:, 2:3]) < 0.9, up, np.array([1.0, 0.0, 0.0]))
    x = np.cross(helper, boresights)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(boresights, x)
    base = np.stack([x, y, boresights], axis=1)  # (m, 3, 3): rows are the camera axes
    roll = elementary_rotation(2, rolls)  # (r, 3, 3)
    return (roll[None] @ base[:, None]).reshape(-1, 3, 3)


def sub_catalogue(catalog: Catalog, attitudes: np.ndarray, fov_w_deg: float, fov_h_deg: float,
                  mag_limit: float, *, block_deg: float | None = None) -> Catalog:
    """The stars of ``catalog`` to ``mag_limit`` that appear in the ``fov_w_deg`` × ``fov_h_deg``
    field at any of ``attitudes`` (thesis 004 §5.2, ``MakeCat.mod``), brightest first.

    With ``block_deg`` (004: 1°), 004's own rule: the sky in ``block_deg`` × ``block_deg``
    RA/Dec blocks, a block marked when its centre is in a field, every star of a marked block
    kept (a ragged edge up to a block wide).
    """
    cat = catalog.brighter_than(float(mag_limit))
    A = np.asarray(attitudes, np.float64).reshape(-1, 3, 3)
    if block_deg is None:
        seen = np.zeros(len(cat), bool)
        tree = cKDTree(cat.vectors)
        for s in range(0, len(A), _CHUNK):
            seen[stars_in_fields(cat.vectors, A[s:s + _CHUNK], fov_w_deg, fov_h_deg, tree)[1]] = True
        return cat.subset(np.flatnonzero(seen))
    if not (math.isfinite(block_deg) and 0 < block_deg <= 90):
        raise InputError(f"block size {block_deg} degrees is not in (0, 90]")
    n_ra, n_dec = math.ceil(360.0 / block_deg), math.ceil(180.0 / block_deg)
    ra_c = np.radians((np.arange(n_ra) + 0.5) * block_deg)
    dec_c = np.radians(-90.0 + (np.arange(n_dec) + 0.5) * block_deg)
    rr, dd = np.meshgrid(ra_c, dec_c, indexing="ij")
    centres = radec_to_vector(rr.ravel(), dd.ravel())
    marked = np.zeros(len(centres), bool)
    tree = cKDTree(centres)
    for s in range(0, len(A), _CHUNK):
        marked[stars_in_fields(centres, A[s:s + _CHUNK], fov_w_deg, fov_h_deg, tree)[1]] = True
    ra, dec = vector_to_radec(cat.vectors)
    i_ra = np.minimum((np.degrees(ra) % 360.0 // block_deg).astype(int), n_ra - 1)
    i_dec = np.minimum(((np.degrees(dec) + 90.0) // block_deg).astype(int), n_dec - 1)
    return cat.subset(np.flatnonzero(marked[i_ra * n_dec + i_dec]))


def format_counts(counts: StarCounts) -> str:
    """A few lines: the settings, P(< 3, 4, 5 stars) with their sampling errors, mean and maximum."""
    c = counts
    lines = [f"{c.fov_w_deg:g}° × {c.fov_h_deg:g}° field, {c.n_catalog} stars to Hp {c.mag_limit:.3f}, "
             f"{c.n_pointings} random pointings (seed {c.seed})"]
    for k, p in ((3, c.p_lt3), (4, c.p_lt4), (5, c.p_lt5)):
        lines.append(f"P(< {k} stars) = {p:.5f} ± {c.standard_error(p):.5f}")
    lines.append(f"mean {c.mean:.2f} stars per field, maximum {c.max} ({c.n_at_max} pointings), "
                 f"none in {int(np.sum(c.counts == 0))}")
    return "\n".join(lines)


def plot_counts(counts: StarCounts, path) -> None:
    """Write a PNG histogram of stars per field (log scale, as 004's Fig. 5-1) with the summary."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p = counts.probability()
    fig, ax = plt.subplots(figsize=(7, 4), dpi=100)
    ax.bar(np.arange(len(p)), np.where(p > 0, p, np.nan), width=0.9, color="#4a7ab8")
    ax.set_yscale("log")
    ax.set_xlabel("catalogue stars in the field")
    ax.set_ylabel("probability")
    ax.set_title(f"{counts.fov_w_deg:g}° × {counts.fov_h_deg:g}°, Hp ≤ {counts.mag_limit:.2f} "
                 f"({counts.n_catalog} stars), {counts.n_pointings} pointings")
    text = (f"P(<3) = {counts.p_lt3:.4f}\nP(<4) = {counts.p_lt4:.4f}\nP(<5) = {counts.p_lt5:.4f}\n"
            f"mean {counts.mean:.1f}, max {counts.max}")
    ax.text(0.98, 0.95, text, transform=ax.transAxes, ha="right", va="top")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
