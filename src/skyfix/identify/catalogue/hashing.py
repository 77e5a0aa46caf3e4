"""The 4-star pattern key and the open-addressed hash table that indexes it.

A pattern of four stars has six pairwise angular distances. Sorted and divided by the largest,
the five smaller ones (the *edge ratios*, each in (0, 1]) are invariant to rotation and to
scale, so the key can be computed from an image whose focal length is unknown. Each ratio is
quantised into ``n_bins`` bins; the five bin numbers form an integer *key code*.

Patterns are stored sorted by key code, so the patterns sharing a code form one contiguous
run (sequential memory for the candidate checks). Each distinct code has an entry in a
power-of-two open-addressed table: a multiplicative hash of the code gives the home slot,
collisions are resolved by linear probing, and the slot holds the code's index into
``key_codes`` / ``key_start`` (``-1`` = empty).
"""

from __future__ import annotations

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.rotation import chord_angle

__all__ = [
    "EDGE_PAIRS",
    "edge_angles",
    "edge_ratios",
    "key_codes",
    "build_table",
    "lookup_run",
]

# The six (i, j) vertex pairs of a 4-star pattern.
EDGE_PAIRS = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)
_HASH_MULT = np.uint64(0x9E3779B97F4A7C15)  # Fibonacci hashing (2^64 / golden ratio)


def edge_angles(vectors: np.ndarray) -> np.ndarray:
    """The six pairwise angles (radians) of 4-star patterns.

    Parameters
    ----------
    vectors : (P, 4, 3) unit vectors.

    Returns
    -------
    (P, 6) angles in :data:`EDGE_PAIRS` order (chord formula: accurate at small angles).
    """
    v = np.asarray(vectors, dtype=np.float64)
    chord = np.linalg.norm(v[:, EDGE_PAIRS[:, 0]] - v[:, EDGE_PAIRS[:, 1]], axis=-1)
    return chord_angle(chord)


def edge_ratios(vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sorted edge ratios and largest edge of 4-star patterns.

    Parameters
    ----------
    vectors : (P, 4, 3) unit vectors.

    Returns
    -------
    ratios : (P, 5) the five smaller edges divided by the largest, ascending.
    largest : (P,) the largest edge, radians.
    """
    ang = np.sort(edge_angles(vectors), axis=1)
    largest = ang[:, 5]
    return ang[:, :5] / largest[:, None], largest


def key_codes(ratios: np.ndarray, n_bins: int) -> np.ndarray:
    """Integer key codes (P,) int64 of sorted edge ratios (P, 5) quantised into ``n_bins`` bins."""
    bins = np.clip((np.asarray(ratios) * n_bins).astype(np.int64), 0, n_bins - 1)
    weights = n_bins ** np.arange(5, dtype=np.int64)
    return bins @ weights


@njit(cache=True, inline="always")
def _home_slot(code: np.int64, mask: np.int64) -> np.int64:
    h = np.uint64(code) * np.uint64(0x9E3779B97F4A7C15)
    return np.int64(h >> np.uint64(20)) & mask


@njit(cache=True)
def _insert_all(codes: np.ndarray, table: np.ndarray) -> None:
    mask = np.int64(len(table) - 1)
    for k in range(len(codes)):
        slot = _home_slot(codes[k], mask)
        while table[slot] >= 0:
            slot = (slot + 1) & mask
        table[slot] = k


def build_table(codes: np.ndarray, load_factor: float = 0.5
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sort patterns by key code and index the distinct codes in an open-addressed table.

    Parameters
    ----------
    codes : (P,) int64 key codes, one per pattern.
    load_factor : float
        Largest fraction of occupied slots; the size is the next power of two.

    Returns
    -------
    order : (P,) int64 — the permutation that sorts the patterns by code.
    unique : (K,) int64 — the distinct codes, ascending.
    start : (K + 1,) int64 — run ``k`` is ``sorted_patterns[start[k]:start[k + 1]]``.
    table : (T,) int32 — slot -> index into ``unique`` (``-1`` empty).
    """
    order = np.argsort(codes, kind="stable")
    unique, first = np.unique(np.asarray(codes)[order], return_index=True)
    start = np.append(first, len(codes)).astype(np.int64)
    size = 1 << int(np.ceil(np.log2(max(len(unique) / load_factor, 16))))
    table = np.full(size, -1, dtype=np.int32)
    _insert_all(np.ascontiguousarray(unique, dtype=np.int64), table)
    return order, unique.astype(np.int64), start, table


@njit(cache=True)
def lookup_run(code: np.int64, table: np.ndarray, key_codes: np.ndarray, key_start: np.ndarray):
    """The run ``(start, stop)`` of sorted patterns whose key code is ``code`` (empty if none)."""
    mask = np.int64(len(table) - 1)
    slot = _home_slot(code, mask)
    while True:
        k = table[slot]
        if k < 0:
            return 0, 0
        if key_codes[k] == code:
            return key_start[k], key_start[k + 1]
        slot = (slot + 1) & mask
