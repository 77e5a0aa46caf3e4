"""The named data the identification kernels take and return.

What travels together is one :class:`typing.NamedTuple` (numba compiles a NamedTuple of arrays
and scalars into a plain struct: a field costs what a separate argument costs, and the kernels
cache as usual):

- :class:`StarIndex` — the catalogue stars and the sky cells that index them (verification,
  refit); :class:`PatternTable` — the 4-star patterns and their hash table (the search). Both
  come from :meth:`skyfix.identify.PatternDatabase.star_index` / ``.pattern_table``.
- :class:`ImageStars` — the centroids as the kernels see them: undistorted offsets from the
  principal point, and the frame's extent in the same coordinates.
- :class:`FocalRange`, :class:`Tolerances`, :class:`VerifySettings`, :class:`RefineSettings` —
  the settings of one search or refit.
- :class:`SearchResult`, :class:`Refit` — what :func:`skyfix.identify.common.search.search` and
  :func:`skyfix.identify.common.refine.refine` return.
- :class:`ViewBuffers`, :class:`CentroidGrid` — work arrays the verification kernels share.

*Calling a kernel from Python.* numba types a plain tuple argument in its C dispatcher but a
NamedTuple in Python, about 2 µs per NamedTuple argument per call (numba 0.68, measured on this
project's search: six of them cost more than the median search call's own work on a solvable
frame). The kernels called from Python once per chunk of patterns therefore have a twin
(``search_entry``, ``refine_entry``) that takes each NamedTuple as ``tuple(nt)`` — the same
fields in the same order — and names them again inside the compiled code, at no cost.

*Cached kernels.* numba's cache keys a kernel by its argument types, which name a NamedTuple's
class and field types but not its field names: reordering two fields of one type here would let
a cached ``@njit`` kernel read the wrong one. This file therefore counts as a kernel source for
:func:`skyfix._kernels.drop_stale_kernel_caches` (it hashes the files that mention ``njit``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["CentroidGrid", "FocalRange", "ImageStars", "PatternTable", "Refit", "RefineSettings",
           "SearchResult", "StarIndex", "Tolerances", "VerifySettings", "ViewBuffers"]


class StarIndex(NamedTuple):
    """Catalogue stars and the sky cells that index them: what the kernels read to find the
    stars in a field.

    vectors : (S, 3) float64 — ICRS unit vectors at the database epoch, brightest first (a
        star's index is its brightness rank).
    cell_centres : (M, 3) float64 — centres of the sky cells, ordered by decreasing z (a
        Fibonacci lattice; :func:`skyfix.identify.common.verify.cell_band` relies on the order).
    cell_start : (M + 1,) int64 — cell ``i``'s stars are ``cell_stars[cell_start[i]:cell_start[i + 1]]``.
    cell_stars : (S,) int32 — star indices grouped by cell, brightest first within a cell.
    cell_radius_rad : float — the largest angle between a star and its cell's centre.
    """

    vectors: np.ndarray
    cell_centres: np.ndarray
    cell_start: np.ndarray
    cell_stars: np.ndarray
    cell_radius_rad: float


class PatternTable(NamedTuple):
    """The 4-star patterns sorted by key code and the open-addressed hash table over the codes
    (:mod:`skyfix.identify.catalogue.hashing`).

    n_bins : int — quantisation bins per edge ratio (a key code has five base-``n_bins`` digits).
    table : (T,) int32 — slot -> index into ``key_codes`` (``-1`` empty).
    key_codes : (K,) int64 — the distinct key codes, ascending.
    key_start : (K + 1,) int64 — patterns ``key_start[k]:key_start[k + 1]`` have code ``key_codes[k]``.
    ratios : (P, 5) float32 — each pattern's sorted edge ratios (edges / largest edge).
    largest_rad : (P,) float32 — each pattern's largest edge.
    stars : (P, 4) int32 — each pattern's star indices (into :attr:`StarIndex.vectors`).
    """

    n_bins: int
    table: np.ndarray
    key_codes: np.ndarray
    key_start: np.ndarray
    ratios: np.ndarray
    largest_rad: np.ndarray
    stars: np.ndarray


class ImageStars(NamedTuple):
    """The centroids as the kernels see them.

    offsets_px : (N, 2) float64 — undistorted offsets from the principal point at the assumed
        focal length ``f0``: ``x_n · f0`` (so a calibrated camera's distortion never enters the
        kernels), brightest first.
    frame_px : (4,) float64 — ``x_lo, x_hi, y_lo, y_hi``: the frame's extent in the same
        coordinates (its corners undistorted: a bounding box).
    """

    offsets_px: np.ndarray
    frame_px: np.ndarray


class FocalRange(NamedTuple):
    """The focal lengths a candidate pattern may imply, pixels.

    f0_px : float — the assumed focal length (:attr:`ImageStars.offsets_px` are scaled by it).
    lo_px, hi_px : float — the allowed range.
    fixed : bool — a calibrated camera: use ``f0_px`` itself, estimate nothing.
    """

    f0_px: float
    lo_px: float
    hi_px: float
    fixed: bool


class Tolerances(NamedTuple):
    """The edge-ratio tolerances of one search tier.

    key : float — ratio tolerance of the key probe (covers the unknown focal length).
    sigma_px : float — expected centroid noise.
    model : float — ratio error of the unmodelled camera (distortion); the tight tolerance is
        :func:`skyfix.identify.accept.ratio_tolerance`.
    """

    key: float
    sigma_px: float
    model: float


class VerifySettings(NamedTuple):
    """How a candidate attitude is verified.

    n_stars : int — brightest centroids (and at most as many catalogue stars) matched.
    radius_px : float — match radius.
    log_threshold : float — log of the largest accepted probability that the match is chance.
    """

    n_stars: int
    radius_px: float
    log_threshold: float


class SearchResult(NamedTuple):
    """What one call of :func:`skyfix.identify.common.search.search` found.

    success : bool — a candidate was accepted (the fields below describe it).
    n_done : int — image combinations processed.
    n_candidates : int — candidates verified in this call.
    A_icrs_to_cam : (3, 3) float64 — the accepted attitude (zeros when none).
    focal_px : float — its focal length.
    log_prob_false : float — log P(so many matches by chance), look-elsewhere included.
    combo_index, pattern_index : int — the image combination and the catalogue pattern.
    n_matched, n_catalog : int — verification matches and catalogue stars tried.
    n_compared : int — catalogue patterns whose ratios were compared (the key runs walked): with
        ``n_done`` and ``n_candidates``, the work the call did
        (:func:`skyfix.identify.methods.quad.search_work`).
    """

    success: bool
    n_done: int
    n_candidates: int
    A_icrs_to_cam: np.ndarray
    focal_px: float
    log_prob_false: float
    combo_index: int
    pattern_index: int
    n_matched: int
    n_catalog: int
    n_compared: int


class RefineSettings(NamedTuple):
    """What :func:`skyfix.identify.common.refine.refine` fits and matches.

    fit_focal : bool — fit the focal length (and k1 where significant): no camera was given.
    fit_k1_min : int — fewest matched stars for which k1 may be freed.
    n_first : int — brightest centroids matched on the first pass.
    n_img : int — brightest centroids matched on the later passes.
    radius_px : float — the first match radius (the largest).
    sigma_px : float — expected centroid noise (floor of the shrinking radius).
    iterations : int — fit-and-rematch passes after the first match.
    """

    fit_focal: bool
    fit_k1_min: int
    n_first: int
    n_img: int
    radius_px: float
    sigma_px: float
    iterations: int


class Refit(NamedTuple):
    """What :func:`skyfix.identify.common.refine.refine` returns.

    n_pairs : int — matched pairs.
    star_index : (n_pairs,) int64 — their centroids (indices into :attr:`ImageStars.offsets_px`).
    catalog_index : (n_pairs,) int64 — their catalogue stars (indices into :attr:`StarIndex.vectors`).
    A_icrs_to_cam : (3, 3) float64 — the refitted attitude.
    focal_px : float — the refitted focal length (the given one when not fitted).
    k1 : float — the fitted radial distortion (``p = f·x_n·(1 + k1·r²)``), 0 when not freed.
    rms_px : float — RMS residual of the last fit.
    radius_px : float — match radius of the last matching pass.
    n_catalog : int — catalogue stars projected in the frame on the last matching pass.
    """

    n_pairs: int
    star_index: np.ndarray
    catalog_index: np.ndarray
    A_icrs_to_cam: np.ndarray
    focal_px: float
    k1: float
    rms_px: float
    radius_px: float
    n_catalog: int


class ViewBuffers(NamedTuple):
    """Work arrays of the projections and matches, allocated once per kernel call.

    index : (L,) int64 — catalogue index of each star projected into the frame.
    x_px, y_px : (L,) float64 — its position (in :attr:`ImageStars.offsets_px` coordinates).
    used : (N,) bool — centroids already matched.
    match : (L,) int64 — the centroid each projected star matched, or -1.
    """

    index: np.ndarray
    x_px: np.ndarray
    y_px: np.ndarray
    used: np.ndarray
    match: np.ndarray


class CentroidGrid(NamedTuple):
    """Centroids bucketed into square cells (:func:`skyfix.identify.common.verify.grid_index`).

    x0_px, y0_px : float — the grid's corner (the frame's ``x_lo``, ``y_lo``).
    cell_px : float — cell side.
    nx, ny : int — cells across and down.
    start : (nx·ny + 1,) int64 — cell ``c``'s centroids are ``items[start[c]:start[c + 1]]``.
    items : (n,) int64 — centroid indices grouped by cell, brightest first within a cell.
    """

    x0_px: float
    y0_px: float
    cell_px: float
    nx: int
    ny: int
    start: np.ndarray
    items: np.ndarray
