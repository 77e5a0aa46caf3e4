"""The grid method (Padgett & Kreutz-Delgado 1997; thesis 000 §2.6.5,
docs/identification-methods.md#grid).

A star is recognised by the picture of its neighbourhood:

1. **Pattern** of a reference star ``v``: its ``pattern_stars`` brightest neighbours between the
   buffer radius ``buffer_deg`` and the pattern radius ``pattern_radius_deg``; the nearest of
   them defines the orientation (+x); each neighbour's gnomonic coordinates in that frame
   (``x = w·e1 / w·v``, ``y = w·e2 / w·v`` with ``e1`` toward the nearest neighbour and
   ``e2 = v × e1``, right-handed, so a mirror image does not match) fall in one cell of a grid
   of ``g`` columns over the pattern radius's square (and ``g + 1`` rows offset by half a cell,
   so the orienting neighbour, at y = 0, sits in the middle of a cell, not on an edge); the
   pattern is the set of cells. :func:`pattern_cells` computes it, for catalogue and image alike.
2. **Catalogue patterns**: one per star of the shared pair table
   (:func:`skyfix.identify.catalogue.pairs.pair_table`, its per-field brightest stars), from the table's
   neighbour lists, built once and kept with the database, as a sparse cell → stars inverted
   index (:func:`catalogue_patterns`, :class:`GridPatterns`).
3. **Matching** (:func:`image_candidates`): the image's patterns are made of its
   ``image_stars`` brightest centroids (about as many as the table holds in a frame); each of
   the ``n_references`` of them nearest the frame centre (their pattern circles inside the
   frame) gets a pattern oriented by each of its ``n_orient`` nearest neighbours (the
   catalogue's nearest may be missing from the image, or the image's from the table); every
   catalogue star scores the cells it shares (one compiled pass over the inverted lists of the
   image's cells); the ``top`` best scoring at least ``min_score`` are the reference's
   candidates. With only a FOV known, the image pattern is also binned at scales across the
   focal range, a cell apart at the pattern radius, and each candidate keeps its best score.
4. **Agreement**: candidates of different references whose catalogue angle is the references'
   measured angle (within the tolerance and the focal range) agree; each candidate with those
   that agree with it and with each other (greedily, by score) is a proposal, the largest and
   best scoring first, to :func:`skyfix.identify.common.hypothesis.first_accepted`, which accepts only
   what every method must pass.

Differences from the paper: its pattern holds every catalogue star within the pattern radius to
the sensor's magnitude limit, oriented by the nearest; skyfix's catalogue stars are the pair
table's (the brightest of each field), so the image's patterns are made of its brightest
centroids only and each reference is tried with its few nearest neighbours as the orientation.
Candidates are confirmed by agreeing references and the shared verification, not by a score
threshold alone.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.rotation import chord_angle
from skyfix.camera import Camera
from skyfix.errors import InputError
from skyfix.identify.accept import CENTROID_SIGMA_PX, PROB_THRESHOLD
from skyfix.identify.catalogue.database import PatternDatabase
from skyfix.identify.catalogue.pairs import PairTable, neighbours_in_range
from skyfix.identify.common.angle_match import consistent_set, frame_table
from skyfix.identify.common.hypothesis import Frame, failure, first_accepted, frame_for
from skyfix.identify.common.result import Identification

__all__ = ["METHOD", "GridPatterns", "GridSettings", "catalogue_patterns", "identify", "image_candidates",
           "pattern_cells"]

METHOD = "grid"


class GridSettings(NamedTuple):
    """What a pattern is made of.

    g : int — cells per side of the grid.
    pattern_radius_rad : float — neighbours farther than this are not in the pattern.
    buffer_rad : float — neighbours closer than this are not either (a detector merges them).
    pattern_stars : int — the brightest neighbours kept.
    """

    g: int
    pattern_radius_rad: float
    buffer_rad: float
    pattern_stars: int


class GridPatterns(NamedTuple):
    """The catalogue's patterns: one per pair-table star, as an inverted index.

    cell_start : (g (g + 1) + 1,) int64 — cell ``c``'s stars are
        ``cell_star[cell_start[c]:cell_start[c + 1]]``.
    cell_star : (E,) int32 — table rows (of :attr:`PairTable.stars`) whose pattern holds the cell.
    n_cells : (T,) int32 — cells in each table star's pattern.
    """

    cell_start: np.ndarray
    cell_star: np.ndarray
    n_cells: np.ndarray


@njit(cache=True)
def pattern_cells(center, neighbours, settings, scale, orient, out):
    """The cells of the pattern of unit vector ``center`` among ``neighbours`` ((M, 3) unit
    vectors, brightest first; the centre itself may be among them): the first
    ``settings.pattern_stars`` between the buffer and the pattern radius, oriented by the
    ``orient``-th nearest of them (0: the nearest), their gnomonic coordinates multiplied by
    ``scale``. Writes the distinct cells (``x_cell · (g + 1) + y_cell``) to ``out`` and returns how
    many (0: fewer than ``orient + 1`` neighbours)."""
    g = settings.g
    kept = np.empty(settings.pattern_stars, np.int64)
    dist = np.empty(settings.pattern_stars)
    n_kept = 0
    for i in range(neighbours.shape[0]):
        d2 = 0.0
        for j in range(3):
            x = neighbours[i, j] - center[j]
            d2 += x * x
        a = chord_angle(math.sqrt(d2))
        if a <= 0.0 or a < settings.buffer_rad or a > settings.pattern_radius_rad:
            continue
        kept[n_kept] = i
        dist[n_kept] = a
        n_kept += 1
        if n_kept == settings.pattern_stars:
            break
    if n_kept <= orient:
        return 0
    n = neighbours[kept[np.argsort(dist[:n_kept])[orient]]]
    dot = n[0] * center[0] + n[1] * center[1] + n[2] * center[2]
    e1 = n - dot * center
    e1 /= math.sqrt(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2])
    e2 = np.empty(3)
    e2[0] = center[1] * e1[2] - center[2] * e1[1]
    e2[1] = center[2] * e1[0] - center[0] * e1[2]
    e2[2] = center[0] * e1[1] - center[1] * e1[0]
    half = math.tan(settings.pattern_radius_rad)
    n_out = 0
    for k in range(n_kept):
        w = neighbours[kept[k]]
        wv = w[0] * center[0] + w[1] * center[1] + w[2] * center[2]
        x = scale * (w[0] * e1[0] + w[1] * e1[1] + w[2] * e1[2]) / wv
        y = scale * (w[0] * e2[0] + w[1] * e2[1] + w[2] * e2[2]) / wv
        # rows are offset by half a cell, so that the orienting neighbour (y = 0) lies in the
        # middle of one, not on an edge where rounding would flip it: g + 1 rows
        cx = int(math.floor((x / half + 1.0) * 0.5 * g))
        cy = int(math.floor((y / half + 1.0) * 0.5 * g + 0.5))
        if cx < 0 or cx >= g or cy < 0 or cy > g:
            continue
        c = cx * (g + 1) + cy
        new = True
        for m in range(n_out):
            if out[m] == c:
                new = False
                break
        if new:
            out[n_out] = c
            n_out += 1
    return n_out


@njit(cache=True)
def _catalogue_cells(table, vectors, settings, cells, counts):
    """Each table star's pattern cells into ``cells[t, :counts[t]]``."""
    stars = table.stars
    for t in range(stars.shape[0]):
        s = stars[t]
        a, b = neighbours_in_range(table, s, settings.buffer_rad, settings.pattern_radius_rad)
        near = np.sort(table.neighbour[a:b])[:settings.pattern_stars]  # brightest first (row = rank)
        nb = np.empty((near.shape[0], 3))
        for i in range(near.shape[0]):
            nb[i] = vectors[near[i]]
        counts[t] = pattern_cells(vectors[s], nb, settings, 1.0, 0, cells[t])


def catalogue_patterns(frame: Frame, table: PairTable, settings: GridSettings) -> GridPatterns:
    """The :class:`GridPatterns` of ``table``'s stars, built once and kept with the database."""

    def make() -> GridPatterns:
        n = len(table.stars)
        cells = np.empty((n, settings.pattern_stars), np.int64)
        counts = np.zeros(n, np.int64)
        _catalogue_cells(table, frame.stars.vectors, settings, cells, counts)
        star = np.repeat(np.arange(n, dtype=np.int32), counts)
        cell = cells[np.arange(settings.pattern_stars) < counts[:, None]]  # row by row, as ``star``
        order = np.argsort(cell, kind="stable")
        start = np.searchsorted(cell[order], np.arange(settings.g * (settings.g + 1) + 1)).astype(np.int64)
        return GridPatterns(start, star[order], counts.astype(np.int32))

    key = ("grid", id(table), settings.g, round(settings.pattern_radius_rad, 9),
           round(settings.buffer_rad, 9), settings.pattern_stars)
    return frame.database.derived(key, make)


@njit(cache=True)
def _candidates(rays, references, settings, scales, n_orient, patterns, min_score, top, out_ref, out_star,
                out_score):
    """For each reference centroid, the ``top`` table stars sharing the most cells (at least
    ``min_score``) at its best scale and orientation. Returns the candidates written."""
    n_local = patterns.n_cells.shape[0]
    score = np.zeros(n_local, np.int64)
    best = np.zeros(n_local, np.int64)
    touched = np.empty(patterns.cell_star.shape[0] + 1, np.int64)
    cells = np.empty(settings.pattern_stars, np.int64)
    n_out = 0
    for r in references:
        n_touched = 0
        for o in range(n_orient):
            for s in scales:
                n_cells = pattern_cells(rays[r], rays, settings, s, o, cells)
                for c in cells[:n_cells]:
                    for e in range(patterns.cell_start[c], patterns.cell_start[c + 1]):
                        t = patterns.cell_star[e]
                        if score[t] == 0 and best[t] == 0:
                            touched[n_touched] = t
                            n_touched += 1
                        score[t] += 1
                for i in range(n_touched):
                    t = touched[i]
                    if score[t] > best[t]:
                        best[t] = score[t]
                    score[t] = 0
        for _ in range(top):
            arg, hi = -1, min_score - 1
            for i in range(n_touched):
                t = touched[i]
                if best[t] > hi:
                    arg, hi = t, best[t]
            if arg < 0:
                break
            out_ref[n_out], out_star[n_out], out_score[n_out] = r, arg, hi
            n_out += 1
            best[arg] = -best[arg]  # taken; restored below
        for i in range(n_touched):
            best[touched[i]] = 0
    return n_out


class Candidates(NamedTuple):
    """Each reference centroid's best catalogue stars (rows of the star index) and their scores."""

    reference: np.ndarray
    star: np.ndarray
    score: np.ndarray


def image_candidates(frame: Frame, table: PairTable, patterns: GridPatterns, settings: GridSettings,
                     references: np.ndarray, scales: np.ndarray, *, image_stars: int = 20, n_orient: int = 3,
                     min_score: int = 4, top: int = 3) -> Candidates:
    """Step 3: the ``top`` catalogue stars whose patterns share the most cells (≥ ``min_score``)
    with each reference centroid's (rows of :attr:`Frame.xy`) among the ``image_stars``
    brightest, at its best of ``scales`` and of the orientations by its ``n_orient`` nearest
    neighbours."""
    m = len(references) * top
    ref, star, score = np.empty(m, np.int64), np.empty(m, np.int64), np.empty(m, np.int64)
    rays = np.ascontiguousarray(frame.rays[:image_stars])
    k = _candidates(rays, np.asarray(references, np.int64), settings, np.asarray(scales, np.float64),
                    int(n_orient), patterns, int(min_score), int(top), ref, star, score)
    return Candidates(ref[:k], table.stars[star[:k]].astype(np.int64), score[:k])


@njit(cache=True)
def _agreeing_sets(agree, order):
    """For each candidate ``u``: ``u`` and, greedily in ``order``, every candidate that agrees
    with all those taken so far (:func:`~skyfix.identify.common.angle_match.consistent_set`, seeded
    at each candidate in turn). Row ``u`` of the result marks its set."""
    n = agree.shape[0]
    member = np.zeros((n, n), np.bool_)
    taken = np.empty(n, np.int64)
    for u in range(n):
        k = consistent_set(agree, order, u, taken)
        for i in range(k):
            member[u, taken[i]] = True
    return member


def _proposals(frame: Frame, cand: Candidates, tolerance_rad: float, min_agree: int
               ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Step 4: candidates whose references agree, largest and best scoring sets first."""
    if len(cand.star) < min_agree:
        return
    lo, hi = frame.focal_range_px
    f = float(frame.camera.fx)
    rays = frame.rays[cand.reference]
    cat = frame.stars.vectors[cand.star]
    measured = chord_angle(np.linalg.norm(rays[:, None] - rays[None], axis=2))
    catalogued = chord_angle(np.linalg.norm(cat[:, None] - cat[None], axis=2))
    agree = ((catalogued >= measured * f / hi - tolerance_rad)
             & (catalogued <= measured * f / lo + tolerance_rad)
             & (cand.reference[:, None] != cand.reference[None]) & (cand.star[:, None] != cand.star[None]))
    member = _agreeing_sets(agree, np.argsort(-cand.score, kind="stable"))
    size = member.sum(axis=1)
    member, size = member[size >= min_agree], size[size >= min_agree]
    if not len(size):
        return
    score = member.astype(np.int64) @ cand.score
    first = np.unique(np.packbits(member, axis=1), axis=0, return_index=True)[1]
    for u in first[np.lexsort((-score[first], -size[first]))]:
        idx = np.flatnonzero(member[u])
        yield cand.reference[idx], cand.star[idx]


def identify(xy: np.ndarray, width: int, height: int, *, fov_deg: float | None = None,
             fov_tolerance_deg: float | None = None, camera: Camera | None = None,
             database: PatternDatabase | None = None, epoch: float | None = None, g: int = 32,
             pattern_radius_deg: float | None = None, buffer_deg: float | None = None,
             pattern_stars: int = 32, image_stars: int = 20, n_orient: int = 3,
             n_references: int = 8, min_score: int = 4, top: int = 3, min_agree: int = 2,
             centroid_sigma_px: float = CENTROID_SIGMA_PX, n_sigma: float = 3.0,
             max_candidates: int = 100, prob_threshold: float = PROB_THRESHOLD) -> Identification:
    """Identify the stars of one frame by the grid method (the module text).

    Parameters
    ----------
    xy, width, height, fov_deg, fov_tolerance_deg, camera, database, epoch
        The interface's (:mod:`skyfix.identify.methods`); a camera or a FOV is needed.
    g : int
        Grid cells per side (paper: 8–40).
    pattern_radius_deg : float, optional
        Pattern radius (default: half the horizontal FOV).
    buffer_deg : float, optional
        Buffer radius: closer neighbours are ignored (default: 1 % of the FOV).
    pattern_stars : int
        The brightest neighbours in a pattern, at most.
    image_stars : int
        The brightest centroids that make the image's patterns (about as many as the pair
        table holds in a frame: its 12 brightest per field).
    n_orient : int
        Image patterns per reference: oriented by each of its ``n_orient`` nearest neighbours
        (the catalogue's nearest may be missing from the image, or an image star from it).
    n_references : int
        Reference centroids tried: those of the ``image_stars`` brightest nearest the centre.
    min_score : int
        Cells a catalogue pattern must share to be a candidate.
    top : int
        Candidates kept per reference.
    min_agree : int
        References whose candidates must agree for a proposal.
    centroid_sigma_px, n_sigma : float
        Angle tolerance of the agreement, ``n_sigma · centroid_sigma_px · √2 / f`` (plus the
        focal range's share with only a FOV).
    max_candidates : int
        Work bound: proposals verified.
    prob_threshold : float
        The largest chance of a false match accepted (accept rule 5; every method's, default 1e-9).

    Returns
    -------
    Identification
        Success with the matched stars and attitude, or the reason it failed.

    Raises
    ------
    skyfix.errors.InputError
        ``g``, ``pattern_stars``, ``n_references``, ``min_agree`` or the radii out of range.
    skyfix.errors.CameraError
        An impossible ``fov_deg``.
    """
    t0 = time.perf_counter()
    if not (2 <= int(g) <= 256 and 1 <= int(pattern_stars) <= 256 and n_references >= 1 and min_agree >= 2
            and image_stars >= 3 and n_orient >= 1):
        raise InputError(f"grid options out of range: g={g} (2–256), pattern_stars={pattern_stars} (1–256), "
                         f"n_references={n_references} (≥ 1), min_agree={min_agree} (≥ 2), "
                         f"image_stars={image_stars} (≥ 3), n_orient={n_orient} (≥ 1)")
    frame = frame_for(METHOD, xy, width, height, fov_deg=fov_deg, fov_tolerance_deg=fov_tolerance_deg,
                      camera=camera, database=database, epoch=epoch, min_stars=3,
                      prob_threshold=prob_threshold, centroid_sigma_px=centroid_sigma_px)
    if isinstance(frame, Identification):
        return frame
    fov = float(frame.camera.fov_deg)
    radius = 0.5 * fov if pattern_radius_deg is None else float(pattern_radius_deg)
    buffer = 0.01 * fov if buffer_deg is None else float(buffer_deg)
    if not 0.0 <= buffer < radius < 90.0:
        raise InputError(f"grid radii out of range: need 0 ≤ buffer_deg ({buffer}) < pattern_radius_deg "
                         f"({radius}) < 90")
    table, _ = frame_table(frame)
    settings = GridSettings(int(g), math.radians(radius), math.radians(buffer), int(pattern_stars))
    patterns = catalogue_patterns(frame, table, settings)
    # references: among the brightest, those nearest the centre (their patterns inside the frame)
    bright = np.arange(min(len(frame.xy), int(image_stars)))
    off = np.hypot(*frame.image.offsets_px[bright].T)
    references = bright[np.argsort(off, kind="stable")[:n_references]]
    # scales across the focal range, one cell apart at the pattern radius
    lo, hi = frame.focal_range_px
    f = float(frame.camera.fx)
    n_scales = math.ceil((f / lo - f / hi) * g / 2.0 - 1e-9) + 1
    scales = np.linspace(f / hi, f / lo, n_scales) if n_scales > 1 else np.array([1.0])
    tolerance = n_sigma * centroid_sigma_px * math.sqrt(2.0) / f
    n_tried = len(references) * n_scales * n_orient
    found = [0]

    def proposals() -> Iterator[tuple[np.ndarray, np.ndarray]]:
        # the references nearest the centre first (most frames are solved by them), then all
        seen: set[bytes] = set()
        cand = None
        for part in (references[:(len(references) + 1) // 2], references[(len(references) + 1) // 2:]):
            more = image_candidates(frame, table, patterns, settings, part, scales, image_stars=image_stars,
                                    n_orient=n_orient, min_score=min_score, top=top)
            cand = more if cand is None else Candidates(*(np.concatenate(ab) for ab in zip(cand, more,
                                                                                             strict=True)))
            found[0] = len(cand.star)
            for stars, catalog in _proposals(frame, cand, tolerance, int(min_agree)):
                key = np.sort(stars).tobytes() + np.sort(catalog).tobytes()
                if key not in seen:
                    seen.add(key)
                    yield stars, catalog

    result = first_accepted(frame, proposals(), n_tried=n_tried, max_candidates=max_candidates)
    if not result.success:
        return failure(METHOD, f"no agreeing grid candidates verified ({found[0]} candidates of "
                               f"{len(references)} references, {result.n_candidates} proposals)", t0, n_tried,
                       result.n_candidates)
    return result
