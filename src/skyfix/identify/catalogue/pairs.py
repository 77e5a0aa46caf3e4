"""The pair table: catalogue star pairs sorted by their angle, searched by range.

The seeds' correspondence methods (thesis 000 §2.6, thesis 004 §5.3) start from the angle
between two stars: every pair of catalogue stars closer than the widest angle a frame can hold,
sorted by angle, so that the pairs a measured angle ± its tolerance can be are one contiguous
run found by two binary searches (:func:`pairs_in_range`; a k-vector would find the same run
with one multiply each, at no gain measurable here). Thesis 004 calls this the sorted distance
table (288,464 pairs for its 5,026-star catalogue).

Which stars: the :func:`~skyfix.identify.catalogue.database.brightest_per_field` ``per_field``
brightest stars of every field of the frame's size on a lattice over the sky — as the pattern
database chooses them — so that a field in any direction has its brightest stars in the table,
and no more (a magnitude limit would give the galactic plane ten times the stars of the poles).

Each star's neighbours are also listed by star, by increasing angle (:attr:`PairTable.neighbour`):
a method that has matched one vertex finds the candidates for the next by
:func:`neighbours_in_range`. Both searches compile (``@njit``) and run from Python alike.

Tables are built on first use (about 0.1–1 s) and kept with their database
(:meth:`~skyfix.identify.PatternDatabase.derived`): :func:`pair_table`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.rotation import chord_angle
from skyfix.identify.catalogue.database import PatternDatabase, brightest_per_field

__all__ = ["DOUBLE_SEP", "LATTICE_STEP", "PairTable", "build_pair_table", "field_members",
           "neighbours_in_range", "pair_table", "pairs_in_range", "rounded_fov_deg", "table_stars"]

LATTICE_STEP = 0.5
"""Lattice fields half a field radius apart, as the pattern database's."""
DOUBLE_SEP = 1.0 / 150.0
"""The fainter of two stars closer than this × FOV is dropped (a detector merges them)."""
_FOV_STEP = math.log(1.05)  # tables are built for FOVs ~5 % apart


class PairTable(NamedTuple):
    """Catalogue star pairs sorted by angle, and each star's neighbours.

    angle_rad : (P,) float64 — the pairs' angles, ascending.
    first, second : (P,) int32 — the pairs' stars (rows of
        :attr:`~skyfix.identify.catalogue.kernel_data.StarIndex.vectors`, brightest first),
        ``first < second``.
    neighbour_start : (S + 1,) int64 — star ``s``'s neighbours are
        ``neighbour[neighbour_start[s]:neighbour_start[s + 1]]`` (S: every star of the index).
    neighbour : (2P,) int32 — each star's neighbours, by increasing angle.
    neighbour_angle : (2P,) float64 — their angles.
    stars : (T,) int32 — the stars the table holds, ascending (brightest first).
    max_angle_rad : float — the widest pair held.
    """

    angle_rad: np.ndarray
    first: np.ndarray
    second: np.ndarray
    neighbour_start: np.ndarray
    neighbour: np.ndarray
    neighbour_angle: np.ndarray
    stars: np.ndarray
    max_angle_rad: float


def field_members(vectors: np.ndarray, fov_rad: float, per_field: int):
    """The ``per_field`` brightest stars of every field of radius ``fov_rad / 2`` on the tables'
    lattice (:func:`~skyfix.identify.catalogue.database.brightest_per_field` with :data:`LATTICE_STEP`
    and :data:`DOUBLE_SEP`), a chunk of fields at a time."""
    return brightest_per_field(vectors, fov_rad / 2.0, LATTICE_STEP, fov_rad * DOUBLE_SEP, per_field)


def table_stars(vectors: np.ndarray, fov_rad: float, per_field: int) -> np.ndarray:
    """The ``per_field`` brightest stars of every field of radius ``fov_rad / 2`` on a lattice
    over the sky (rows of ``vectors``, brightest first; ascending)."""
    rows = [top.ravel() for top in field_members(vectors, fov_rad, per_field)]
    stars = np.unique(np.concatenate(rows))
    return stars[stars >= 0].astype(np.int32)


def rounded_fov_deg(fov_deg: float) -> float:
    """``fov_deg`` rounded to the tables' ~5 % steps: nearby fields share one table."""
    return math.exp(round(math.log(fov_deg) / _FOV_STEP) * _FOV_STEP)


def build_pair_table(vectors: np.ndarray, stars: np.ndarray, max_angle_rad: float) -> PairTable:
    """Every pair of ``stars`` (rows of ``vectors``) at most ``max_angle_rad`` apart, sorted by angle."""
    from scipy.spatial import cKDTree

    stars = np.asarray(stars, np.int32)
    v = np.asarray(vectors, np.float64)
    local = cKDTree(v[stars]).query_pairs(2.0 * math.sin(max_angle_rad / 2.0), output_type="ndarray")
    a = stars[local[:, 0]]
    b = stars[local[:, 1]]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    angle = chord_angle(np.linalg.norm(v[lo] - v[hi], axis=1))
    order = np.argsort(angle, kind="stable")
    angle, lo, hi = angle[order], lo[order].astype(np.int32), hi[order].astype(np.int32)
    # Each star's neighbours by increasing angle: both ends of every pair, grouped by star.
    owner = np.concatenate([lo, hi])
    other = np.concatenate([hi, lo])
    both = np.concatenate([angle, angle])
    by_star = np.lexsort((both, owner))
    start = np.searchsorted(owner[by_star], np.arange(len(v) + 1)).astype(np.int64)
    return PairTable(angle, lo, hi, start, other[by_star].astype(np.int32), both[by_star], stars,
                     float(max_angle_rad))


def pair_table(database: PatternDatabase, fov_deg: float, max_angle_deg: float, *,
               per_field: int = 12) -> PairTable:
    """The pair table of ``database``'s stars for frames about ``fov_deg`` wide whose stars are
    at most ``max_angle_deg`` apart (the frame's diagonal with its tolerance), built on first
    use and kept with the database. Sizes are rounded up to steps of ~5 % so that nearby
    fields share one table."""
    fov_key = round(math.log(fov_deg) / _FOV_STEP)
    max_key = math.ceil(math.log(max_angle_deg) / _FOV_STEP)

    def make() -> PairTable:
        vectors = database.star_index().vectors
        stars = table_stars(vectors, math.radians(rounded_fov_deg(fov_deg)), per_field)
        return build_pair_table(vectors, stars, math.radians(math.exp(max_key * _FOV_STEP)))

    return database.derived(("pairs", fov_key, max_key, per_field), make)


@njit(cache=True)
def pairs_in_range(angle_rad, lo, hi):
    """The run ``[start, stop)`` of a sorted ``angle_rad`` with ``lo <= angle <= hi``."""
    return np.searchsorted(angle_rad, lo, side="left"), np.searchsorted(angle_rad, hi, side="right")


@njit(cache=True)
def neighbours_in_range(table, star, lo, hi):
    """The run ``[start, stop)`` of :attr:`PairTable.neighbour` holding the neighbours of
    ``star`` between ``lo`` and ``hi`` radians from it."""
    s, e = table.neighbour_start[star], table.neighbour_start[star + 1]
    a, b = pairs_in_range(table.neighbour_angle[s:e], lo, hi)
    return s + a, s + b
