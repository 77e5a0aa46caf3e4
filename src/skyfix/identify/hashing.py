"""The 4-star pattern key and the open-addressed hash table that indexes it.

A pattern of four stars has six pairwise angular distances. Sorted and divided by the largest,
the five smaller ones (the *edge ratios*, each in (0, 1]) are invariant to rotation and to
scale, so the key can be computed from an image whose focal length is unknown. Each ratio is
quantised into ``n_bins`` bins; the five bin numbers form an integer *key code*; a
multiplicative hash of the code gives the home slot in a power-of-two table, and collisions
are resolved by linear probing. The table stores pattern indices (``-1`` = empty).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = [
    "EDGE_PAIRS",
    "edge_angles",
    "edge_ratios",
    "key_codes",
    "build_table",
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
    return 2.0 * np.arcsin(np.minimum(chord / 2.0, 1.0))


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


@numba.njit(cache=True, inline="always")
def _home_slot(code: np.int64, mask: np.int64) -> np.int64:
    h = np.uint64(code) * np.uint64(0x9E3779B97F4A7C15)
    return np.int64(h >> np.uint64(20)) & mask


@numba.njit(cache=True)
def _insert_all(codes: np.ndarray, table: np.ndarray) -> None:
    mask = np.int64(len(table) - 1)
    for p in range(len(codes)):
        slot = _home_slot(codes[p], mask)
        while table[slot] >= 0:
            slot = (slot + 1) & mask
        table[slot] = p


def build_table(codes: np.ndarray, load_factor: float = 0.5) -> np.ndarray:
    """Open-addressed (linear probing) table of pattern indices for key ``codes``.

    Parameters
    ----------
    codes : (P,) int64 key codes, one per pattern.
    load_factor : float
        Largest fraction of occupied slots; the size is the next power of two.

    Returns
    -------
    (T,) int32 table, ``-1`` for empty slots.
    """
    size = 1 << int(np.ceil(np.log2(max(len(codes) / load_factor, 16))))
    table = np.full(size, -1, dtype=np.int32)
    _insert_all(np.ascontiguousarray(codes, dtype=np.int64), table)
    return table


@numba.njit(cache=True)
def lookup_code(code: np.int64, table: np.ndarray, pattern_codes: np.ndarray,
                out: np.ndarray, n_out: int) -> int:
    """Append to ``out[n_out:]`` the patterns whose key code equals ``code``; return the new count."""
    mask = np.int64(len(table) - 1)
    slot = _home_slot(code, mask)
    while True:
        p = table[slot]
        if p < 0:
            return n_out
        if pattern_codes[p] == code and n_out < len(out):
            out[n_out] = p
            n_out += 1
        slot = (slot + 1) & mask
