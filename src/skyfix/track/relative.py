"""Star IDs from frame to frame without a catalogue (thesis 002 §2.5; OpenStarTracker's
``match_rel``).

Centroids come out in raster order, and stars enter, leave and change order between frames, so
the arrays of two frames cannot be differenced element by element. Each star therefore carries
an ID:

1. **First-time IDs** (:func:`first_ids`, the thesis's state 1): ``next_id, next_id + 1, …`` in
   raster order (by row ``y``, then column ``x``).
2. **Assign IDs** (:func:`match_relative`, state 10): each current star takes the ID of its
   nearest previous star if that lies within the gate (``|Δxy| ≤ gate_px``, compared squared,
   no square root); a current star with no previous star within the gate is new and gets the
   next unused ID (new stars in raster order); previous IDs no current star took are retired.
3. **Error flag** (sends the thesis's state machine back to state 1): fewer than 2 matched pairs
   (the rate needs two), or one previous star claimed by more than one current star (clustered
   stars). The IDs are still returned — the closest claimant keeps the ID, the others get new
   ones — but a tracker should not difference them.

At high rates a star moves more than any sensible gate between frames: pass the previous
positions *propagated to the current frame* (e.g. :func:`skyfix.track.rate.predict_positions`)
as ``prev_xy`` and the gate need only cover the prediction error.

Nearest neighbours come from one (N_cur, N_prev) matrix of squared distances for the few dozen
stars a tracker follows, and from a k-d tree above :data:`_MATRIX_MAX` pairs; both give the same
result.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from skyfix.errors import InputError

__all__ = ["RelativeMatch", "first_ids", "match_relative", "MIN_PAIRS"]

MIN_PAIRS = 2
"""Fewest matched pairs without the error flag (thesis 002 §4.2.2: the rate needs two)."""

_MATRIX_MAX = 16384  # N_cur × N_prev above which the k-d tree is used (same answer, less memory)


class RelativeMatch(NamedTuple):
    """The IDs of the current frame's stars and what changed since the previous frame."""

    ids: np.ndarray          # (N_cur,) int64, one ID per current star (input order)
    new_mask: np.ndarray     # (N_cur,) bool, True for a star that got a new ID
    retired_ids: np.ndarray  # (K,) int64, previous IDs that no current star took (ascending)
    next_id: int             # the first unused ID after this frame
    error: bool              # < MIN_PAIRS pairs, or a previous star claimed twice
    reason: str              # why ``error`` ("" when False)


def _points(xy, name: str) -> np.ndarray:
    a = np.asarray(xy, dtype=np.float64)
    if a.size == 0:
        return a.reshape(0, 2)
    if a.ndim != 2 or a.shape[1] != 2:
        raise InputError(f"{name} must be an (N, 2) array of pixel positions, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name} must be finite")
    return a


def _raster_order(xy: np.ndarray) -> np.ndarray:
    """Indices that sort positions by row ``y``, then column ``x``."""
    return np.lexsort((xy[:, 0], xy[:, 1]))


def first_ids(xy: np.ndarray, next_id: int = 1) -> np.ndarray:
    """IDs ``next_id, next_id + 1, …`` (int64, input order) given in raster order (thesis 002's
    "Assign First Time Star IDs")."""
    pts = _points(xy, "xy")
    ids = np.empty(len(pts), dtype=np.int64)
    ids[_raster_order(pts)] = np.arange(next_id, next_id + len(pts), dtype=np.int64)
    return ids


def _nearest(prev: np.ndarray, cur: np.ndarray, gate_px: float) -> tuple[np.ndarray, np.ndarray]:
    """For each current star: the index of the nearest previous star and its distance², or
    (−1, inf) when none lies within the gate."""
    if len(prev) * len(cur) <= _MATRIX_MAX:
        d2 = ((cur[:, None, :] - prev[None, :, :]) ** 2).sum(axis=2)
        nearest = np.argmin(d2, axis=1)
        best = d2[np.arange(len(cur)), nearest]
    else:
        dist, nearest = cKDTree(prev).query(cur, k=1, distance_upper_bound=gate_px * (1 + 1e-12))
        best = dist * dist
    inside = best <= gate_px * gate_px
    return np.where(inside, nearest, -1), np.where(inside, best, np.inf)


def match_relative(prev_xy: np.ndarray, prev_ids: np.ndarray, cur_xy: np.ndarray, gate_px: float,
                   next_id: int) -> RelativeMatch:
    """Give the current frame's stars IDs by nearest neighbour to the previous frame's.

    Parameters
    ----------
    prev_xy : (M, 2) previous positions (pixels), or those propagated to the current frame.
    prev_ids : (M,) their IDs.
    cur_xy : (N, 2) current positions.
    gate_px : largest distance (pixels) at which a previous star can match (> 0).
    next_id : first unused ID (new stars are numbered from it, in raster order).

    Returns
    -------
    RelativeMatch
        With no previous stars every current star is new (first-time IDs, raster order) and
        ``error`` is set (no pairs).

    Raises
    ------
    InputError
        Shapes that do not match, non-finite positions, a gate that is not a positive number,
        or repeated previous IDs.
    """
    prev = _points(prev_xy, "prev_xy")
    cur = _points(cur_xy, "cur_xy")
    pids = np.asarray(prev_ids, dtype=np.int64).reshape(-1)
    if len(pids) != len(prev):
        raise InputError(f"prev_ids must give one ID per previous star, got {len(pids)} for {len(prev)}")
    if len(np.unique(pids)) != len(pids):
        raise InputError("prev_ids must be distinct")
    if not (np.isfinite(gate_px) and gate_px > 0):
        raise InputError(f"gate_px must be a positive number of pixels, got {gate_px!r}")
    next_id = int(next_id)
    if len(pids) and next_id <= int(pids.max()):
        raise InputError(f"next_id {next_id} is already in use (previous IDs reach {int(pids.max())})")

    if len(prev) and len(cur):
        nearest, d2 = _nearest(prev, cur, float(gate_px))
    else:
        nearest, d2 = np.full(len(cur), -1), np.full(len(cur), np.inf)
    matched = nearest >= 0
    claims = np.bincount(nearest[matched], minlength=len(prev))
    clustered = bool(np.any(claims > 1))
    if clustered:
        # The closest claimant of each previous star keeps it; the others become new.
        order = np.lexsort((d2, nearest))  # by previous star, then distance
        first = np.ones(len(order), dtype=bool)
        first[1:] = nearest[order][1:] != nearest[order][:-1]
        keep = np.zeros(len(cur), dtype=bool)
        keep[order[first]] = True
        matched &= keep

    ids = np.empty(len(cur), dtype=np.int64)
    ids[matched] = pids[nearest[matched]]
    new = ~matched
    new_idx = np.flatnonzero(new)
    new_idx = new_idx[_raster_order(cur[new_idx])]
    ids[new_idx] = np.arange(next_id, next_id + len(new_idx), dtype=np.int64)
    taken = np.zeros(len(prev), dtype=bool)
    taken[nearest[matched]] = True
    n_pairs = int(matched.sum())
    reason = ""
    if clustered:
        reason = "a previous star is claimed by more than one current star"
    elif n_pairs < MIN_PAIRS:
        reason = f"{n_pairs} matched pair{'s' if n_pairs != 1 else ''}, fewer than {MIN_PAIRS}"
    return RelativeMatch(ids, new, np.sort(pids[~taken]), next_id + len(new_idx), bool(reason), reason)
