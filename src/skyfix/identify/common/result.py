"""What every identification method returns: :class:`Identification`."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skyfix.camera import Camera
from skyfix.errors import InputError

__all__ = ["Identification", "finite_centroids"]


@dataclass(frozen=True)
class Identification:
    """Result of an identification method (:mod:`skyfix.identify.methods`).

    Attributes
    ----------
    success : bool
    reason : str — why it failed ("" on success).
    star_index : (M,) int — indices into the input centroids of the identified stars.
    catalog_ids : (M,) int — their Hipparcos numbers.
    catalog_vectors : (M, 3) — their ICRS unit vectors at ``epoch``.
    catalog_mag : (M,) — their magnitudes.
    A_icrs_to_cam : (3, 3) or None — attitude (``b = A r``).
    camera : Camera or None — the camera used, focal length (and k1) refitted when the
        camera was not given.
    prob_false : float — probability that the match is chance (look-elsewhere included).
    n_patterns_tried : int — image patterns looked up (the method's unit of work).
    n_candidates : int — catalogue candidates verified.
    method : str — the method's name in :data:`skyfix.identify.METHODS`.
    time_s : float — wall time of the identification (attitude fit included).
    match_radius_px : float — radius of the last matching pass of the refit, px.
    database : PatternDatabase or None — the database whose catalogue stars were matched (the
        final fit re-matches against the same stars).
    """

    success: bool
    reason: str = ""
    star_index: np.ndarray = None
    catalog_ids: np.ndarray = None
    catalog_vectors: np.ndarray = None
    catalog_mag: np.ndarray = None
    A_icrs_to_cam: np.ndarray | None = None
    camera: Camera | None = None
    prob_false: float = 1.0
    n_patterns_tried: int = 0
    n_candidates: int = 0
    method: str = ""
    time_s: float = 0.0
    match_radius_px: float = 0.0
    database: object = None

    @property
    def n_matched(self) -> int:
        return 0 if self.star_index is None else len(self.star_index)


def finite_centroids(xy) -> tuple[np.ndarray, np.ndarray | None]:
    """The centroids an identification method can use: ``xy`` as (N, 2) float64 without its
    non-finite rows, and the indices of the rows kept (``None`` when all were), to map its
    results back to the caller's indices.

    Raises
    ------
    skyfix.errors.InputError
        ``xy`` is not an (N, 2) array of numbers.
    """
    try:
        xy = np.asarray(xy, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("centroids must be numbers, an (N, 2) array of x, y pixels") from None
    if xy.size == 0:
        xy = xy.reshape(0, 2)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise InputError(f"centroids must be an (N, 2) array of x, y pixels, got shape {xy.shape}")
    if math.isfinite(xy.sum()):  # the common case in one reduction (a NaN or inf makes it non-finite)
        return xy, None
    finite = np.isfinite(xy).all(axis=1)  # (or finite values that overflow the sum)
    kept = None if finite.all() else np.flatnonzero(finite)
    return (xy if kept is None else xy[kept]), kept
