"""The pattern database: 4-star patterns of catalogue stars, indexed by their edge-ratio key.

Build (vectorised, a few seconds for 10–30°): the field-of-view range is split into bands
spaced geometrically (``band_ratio``). For each band, *lattice fields* — circles of radius
``field_radius`` × band FOV centred on a Fibonacci lattice that oversamples the sphere — each
contribute every 4-combination of their ``stars_per_field`` brightest stars. Whatever way
a camera of that FOV points, some lattice field nearly coincides with its view, so the
image's brightest stars form patterns that are in the database. Close doubles (which a
detector merges) are dropped per band. Patterns found by several fields or bands are kept once.

The file is an uncompressed ``.npz`` whose members are memory-mapped on load.
"""

from __future__ import annotations

import json
import math
import os
import zipfile
from dataclasses import dataclass, field
from itertools import combinations
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from skyfix.catalog import Catalog, cache_dir, epoch_now, fibonacci_sphere, load_hipparcos
from skyfix.errors import DatabaseError
from skyfix.identify.hashing import build_table, edge_ratios, key_codes

__all__ = ["PatternDatabase", "default_database", "DATABASE_VERSION"]

DATABASE_VERSION = 3
_ARRAYS = ("star_ids", "star_vectors", "star_mag", "star_pm", "pattern_stars", "pattern_ratios",
           "pattern_largest", "key_codes", "key_start", "table", "cell_centres", "cell_start",
           "cell_stars")
_N_CELLS = 3072  # sky cells of the star index used in verification (~3.7° apart)


@dataclass
class PatternDatabase:
    """Catalogue stars, their 4-star patterns and the hash table indexing them.

    Attributes
    ----------
    star_ids : (S,) int64 — Hipparcos numbers, brightest first.
    star_vectors : (S, 3) float64 — ICRS unit vectors at ``epoch``.
    star_mag : (S,) float32 — magnitudes.
    star_pm : (S, 2) float64 — proper motion (RA·cos δ, Dec), rad/yr.
    pattern_stars : (P, 4) int32 — star indices of each pattern.
    pattern_ratios : (P, 5) float32 — sorted edge ratios (edges / largest edge).
    pattern_largest : (P,) float32 — largest edge, radians.
    key_codes : (K,) int64 — the distinct quantised key codes, ascending (patterns are sorted
        by code, so each code's patterns form one run).
    key_start : (K + 1,) int64 — patterns ``key_start[k]:key_start[k + 1]`` have code ``key_codes[k]``.
    table : (T,) int32 — open-addressed hash table: slot -> index into ``key_codes`` (-1 empty).
    cell_centres : (M, 3) float64 — centres of the sky cells of the star index.
    cell_start : (M + 1,) int64 — ``cell_stars[cell_start[i]:cell_start[i + 1]]`` are cell i's stars.
    cell_stars : (S,) int32 — star indices grouped by cell, brightest first within a cell.
    meta : dict — build parameters (``fov_min_deg``, ``fov_max_deg``, ``n_bins``, ``epoch``, ...).
    """

    star_ids: np.ndarray
    star_vectors: np.ndarray
    star_mag: np.ndarray
    star_pm: np.ndarray
    pattern_stars: np.ndarray
    pattern_ratios: np.ndarray
    pattern_largest: np.ndarray
    key_codes: np.ndarray
    key_start: np.ndarray
    table: np.ndarray
    cell_centres: np.ndarray
    cell_start: np.ndarray
    cell_stars: np.ndarray
    meta: dict = field(default_factory=dict)

    # --- properties -----------------------------------------------------------------------
    @property
    def n_bins(self) -> int:
        return int(self.meta["n_bins"])

    @property
    def fov_min_deg(self) -> float:
        return float(self.meta["fov_min_deg"])

    @property
    def fov_max_deg(self) -> float:
        return float(self.meta["fov_max_deg"])

    @property
    def cell_radius(self) -> float:
        """Largest angle (radians) between a star and its cell centre."""
        return float(self.meta["cell_radius"])

    @property
    def epoch(self) -> float:
        return float(self.meta["epoch"])

    def __len__(self) -> int:
        return len(self.pattern_stars)

    def __reduce__(self):
        # A loaded database travels between processes (dask, multiprocessing) as its path.
        path = self.__dict__.get("_path")
        if path is not None:
            return (PatternDatabase.load, (path,))
        return super().__reduce__()

    def search_arrays(self) -> tuple[np.ndarray, ...]:
        """Read-only plain-ndarray views (no copies) of the arrays the compiled search reads, in
        its order (read-only whether memory-mapped or built in memory: one compiled signature)."""
        return self._plain_views(("table", "key_codes", "key_start", "pattern_ratios", "pattern_largest",
                                  "pattern_stars", "star_vectors", "cell_centres", "cell_start",
                                  "cell_stars"))

    def star_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Read-only plain-ndarray views of ``star_ids``, ``star_mag``, ``star_vectors`` (indexing a
        memory map costs several microseconds a call; a plain view, well under one)."""
        return self._plain_views(("star_ids", "star_mag", "star_vectors"))

    def _plain_views(self, names: tuple[str, ...]) -> tuple[np.ndarray, ...]:
        cache = self.__dict__.setdefault("_views", {})
        views = cache.get(names)
        if views is None:
            views = cache[names] = tuple(readonly_view(getattr(self, k)) for k in names)
        return views

    def __setattr__(self, name: str, value) -> None:
        # A replaced array invalidates the cached views.
        self.__dict__.pop("_views", None)
        super().__setattr__(name, value)

    def vectors_at(self, index: np.ndarray, epoch: float | None) -> np.ndarray:
        """ICRS unit vectors of stars ``index`` moved by proper motion to ``epoch`` (default: as built)."""
        v = np.asarray(self.star_arrays()[2][index], dtype=np.float64)
        if epoch is None or epoch == self.epoch:
            return v
        pm = np.asarray(self.star_pm[index], dtype=np.float64)
        z = np.array([0.0, 0.0, 1.0])
        east = np.cross(z, v)
        norm = np.linalg.norm(east, axis=-1, keepdims=True)
        east = np.where(norm > 1e-12, east / np.maximum(norm, 1e-12), [0.0, 1.0, 0.0])
        north = np.cross(v, east)
        moved = v + (epoch - self.epoch) * (pm[:, :1] * east + pm[:, 1:] * north)
        return moved / np.linalg.norm(moved, axis=-1, keepdims=True)

    # --- build ----------------------------------------------------------------------------
    @classmethod
    def build(cls, fov_min_deg: float = 10.0, fov_max_deg: float = 30.0, *,
              catalog: Catalog | None = None, band_ratio: float = 1.35, stars_per_field: int = 8,
              field_radius: float = 0.4, lattice_step: float = 0.5, double_star_sep: float = 1 / 150,
              pattern_mag_limit: float = 8.5, n_bins: int = 25, epoch: float | None = None,
              progress: bool = False) -> PatternDatabase:
        """Build the database for cameras whose horizontal FOV is ``fov_min_deg``–``fov_max_deg``.

        Parameters
        ----------
        fov_min_deg, fov_max_deg : float
            Horizontal field-of-view range, degrees.
        catalog : Catalog, optional
            Stars to use (default: all of Hipparcos at ``epoch``).
        band_ratio : float
            Ratio between successive FOV bands.
        stars_per_field : int
            Brightest stars per lattice field that form patterns (all 4-combinations).
        field_radius : float
            Lattice field radius as a fraction of the band FOV.
        lattice_step : float
            Lattice spacing as a fraction of the field radius (smaller: more overlap).
        double_star_sep : float
            Stars closer than this fraction of the band FOV to a brighter one are not pattern stars.
        pattern_mag_limit : float
            Faintest magnitude of pattern stars (all stars are kept for verification).
        n_bins : int
            Quantisation bins per edge ratio.
        epoch : float, optional
            Julian year of the star positions (default: now).
        progress : bool
            Show a progress bar.
        """
        from skyfix.validate import check_fov_range  # the range solve and the CLI accept too

        check_fov_range(fov_min_deg, fov_max_deg)
        if not (0 < fov_min_deg <= fov_max_deg < 120):
            raise DatabaseError(f"bad FOV range {fov_min_deg}–{fov_max_deg}°")
        if not 4 <= stars_per_field <= 16:
            raise DatabaseError("stars_per_field must be 4–16")
        epoch = epoch_now() if epoch is None else float(epoch)
        cat = load_hipparcos(epoch=epoch) if catalog is None else catalog
        n_bands = max(1, math.ceil(math.log(fov_max_deg / fov_min_deg) / math.log(band_ratio) - 1e-9) + 1)
        fovs = (np.geomspace(fov_min_deg, fov_max_deg, n_bands) if n_bands > 1
                else np.array([fov_min_deg]))
        bright = np.flatnonzero(cat.mag <= pattern_mag_limit)
        combos = np.array(list(combinations(range(stars_per_field), 4)), dtype=np.int64)

        quads = []
        bands = _progress(progress, "building pattern database", len(fovs))
        for fov_deg in fovs:
            fov = math.radians(fov_deg)
            quads.append(_band_patterns(cat.vectors[bright], fov * field_radius, lattice_step,
                                        fov * double_star_sep, stars_per_field, combos, bright))
            bands.advance()
        bands.close()
        quads = np.unique(np.concatenate(quads), axis=0)
        ratios, largest = edge_ratios(cat.vectors[quads])
        order, unique, start, table = build_table(key_codes(ratios, n_bins))
        quads, ratios, largest = quads[order], ratios[order], largest[order]
        cell_centres, cell_start, cell_stars, cell_radius = _cell_index(cat.vectors, _N_CELLS)
        meta = dict(version=DATABASE_VERSION, cell_radius=cell_radius, fov_min_deg=float(fov_min_deg),
                    fov_max_deg=float(fov_max_deg), band_fovs_deg=[float(f) for f in fovs],
                    n_bins=int(n_bins), epoch=epoch, stars_per_field=stars_per_field,
                    field_radius=field_radius, lattice_step=lattice_step,
                    double_star_sep=double_star_sep, pattern_mag_limit=pattern_mag_limit,
                    catalog=cat.name)
        return cls(star_ids=np.asarray(cat.ids, np.int64), star_vectors=np.asarray(cat.vectors, np.float64),
                   star_mag=np.asarray(cat.mag, np.float32),
                   star_pm=np.stack([cat.pm_ra, cat.pm_dec], axis=-1).astype(np.float64),
                   pattern_stars=quads.astype(np.int32), pattern_ratios=ratios.astype(np.float32),
                   pattern_largest=largest.astype(np.float32), key_codes=unique, key_start=start,
                   table=table, cell_centres=cell_centres, cell_start=cell_start,
                   cell_stars=cell_stars, meta=meta)

    # --- I/O ------------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write an uncompressed ``.npz`` (atomically: a temporary file, then rename)."""
        path = Path(path)
        tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")  # concurrent builders don't collide
        with open(tmp, "wb") as fh:
            np.savez(fh, meta=np.array(json.dumps(self.meta)),
                     **{k: np.ascontiguousarray(getattr(self, k)) for k in _ARRAYS})
        os.replace(tmp, path)

    @classmethod
    def load(cls, path: str | Path) -> PatternDatabase:
        """Memory-map a database written by :meth:`save`.

        Raises
        ------
        DatabaseError
            The file is missing, truncated, corrupt or of another version.
        """
        path = Path(path)
        try:
            arrays, meta = _mmap_npz(path)
        except DatabaseError:
            raise
        except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError, json.JSONDecodeError) as exc:
            raise DatabaseError(f"cannot read pattern database {path}: {exc.__class__.__name__}: "
                                f"{str(exc).splitlines()[0] if str(exc) else ''}".rstrip(": ")) from None
        if meta.get("version") != DATABASE_VERSION:
            raise DatabaseError(f"pattern database {path} has version {meta.get('version')}, "
                                f"expected {DATABASE_VERSION}; rebuild it (skyfix database build)")
        missing = [k for k in _ARRAYS if k not in arrays]
        if missing:
            raise DatabaseError(f"pattern database {path} lacks {', '.join(missing)}")
        db = cls(**{k: arrays[k] for k in _ARRAYS}, meta=meta)
        db.__dict__["_path"] = path.resolve()
        p, s = len(db.pattern_stars), len(db.star_ids)
        if (db.pattern_stars.shape != (p, 4) or db.pattern_ratios.shape != (p, 5)
                or len(db.pattern_largest) != p or len(db.key_start) != len(db.key_codes) + 1
                or db.star_vectors.shape != (s, 3) or len(db.table) & (len(db.table) - 1)):
            raise DatabaseError(f"pattern database {path} is inconsistent (array shapes)")
        z = np.asarray(db.cell_centres)[:, 2] if db.cell_centres.ndim == 2 else None
        if z is None or db.cell_centres.shape[1] != 3 or np.any(np.diff(z) > 0):
            # The verification scans only a z band of cells (verify.cell_band).
            raise DatabaseError(f"pattern database {path} is inconsistent (sky cells not ordered by z)")
        return db


def readonly_view(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a`` as a plain ndarray (no copy)."""
    view = np.asarray(a).view()
    view.flags.writeable = False
    return view


def _cell_index(vectors: np.ndarray, n_cells: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Stars grouped by nearest Fibonacci-lattice cell: centres, start offsets, stars, radius."""
    centres = fibonacci_sphere(n_cells)
    dist, cell = cKDTree(centres).query(vectors)
    order = np.lexsort((np.arange(len(vectors)), cell))  # by cell, then brightness
    start = np.searchsorted(cell[order], np.arange(n_cells + 1)).astype(np.int64)
    radius = 2.0 * math.asin(min(float(dist.max(initial=0.0)) / 2.0, 1.0))
    return centres, start, order.astype(np.int32), radius


def _band_patterns(vectors: np.ndarray, radius: float, lattice_step: float, double_sep: float,
                   per_field: int, combos: np.ndarray, index: np.ndarray) -> np.ndarray:
    """(Q, 4) sorted star-index quads of one FOV band (indices mapped through ``index``)."""
    tree = cKDTree(vectors)
    # Drop the fainter member of close pairs (vectors are brightest first).
    pairs = tree.query_pairs(2 * math.sin(double_sep / 2), output_type="ndarray")
    keep = np.ones(len(vectors), bool)
    keep[pairs.max(axis=1)] = False
    kept = np.flatnonzero(keep)
    tree = cKDTree(vectors[kept])
    n_fields = int(math.ceil(4 * math.pi / (lattice_step * radius) ** 2))
    centres = fibonacci_sphere(n_fields)
    members = tree.query_ball_point(centres, 2 * math.sin(radius / 2), return_sorted=True)
    top = np.full((n_fields, per_field), -1, dtype=np.int64)
    for i, m in enumerate(members):  # one cheap slice per field; the rest is vectorised
        m = m[:per_field]
        top[i, :len(m)] = m
    quads = top[:, combos].reshape(-1, 4)
    quads = quads[(quads >= 0).all(axis=1)]
    quads = index[kept[quads]]
    return np.unique(np.sort(quads, axis=1), axis=0)


class _NoProgress:
    def advance(self) -> None:
        pass

    def close(self) -> None:
        pass


class _RichProgress:
    def __init__(self, description: str, total: int) -> None:
        from rich.progress import Progress

        self._p = Progress(transient=True)
        self._p.start()
        self._task = self._p.add_task(description, total=total)

    def advance(self) -> None:
        self._p.advance(self._task)

    def close(self) -> None:
        self._p.stop()


def _progress(show: bool, description: str, total: int):
    return _RichProgress(description, total) if show else _NoProgress()


def _mmap_npz(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    """Memory-map the members of an uncompressed ``.npz``; returns (arrays, meta)."""
    arrays: dict[str, np.ndarray] = {}
    meta: dict = {}
    size = path.stat().st_size
    with zipfile.ZipFile(path) as zf, open(path, "rb") as fh:
        for info in zf.infolist():
            name = info.filename.removesuffix(".npy")
            if info.compress_type != zipfile.ZIP_STORED:
                raise DatabaseError(f"pattern database {path} is compressed; rebuild it")
            fh.seek(info.header_offset)
            local = fh.read(30)
            if len(local) < 30 or local[:4] != b"PK\x03\x04":
                raise DatabaseError(f"pattern database {path} is corrupt (bad zip member {name})")
            n_name = int.from_bytes(local[26:28], "little")
            n_extra = int.from_bytes(local[28:30], "little")
            fh.seek(info.header_offset + 30 + n_name + n_extra)
            version = np.lib.format.read_magic(fh)
            read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                           else np.lib.format.read_array_header_2_0)
            shape, fortran, dtype = read_header(fh)
            offset = fh.tell()
            nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
            if offset + nbytes > size:
                raise DatabaseError(f"pattern database {path} is truncated")
            if name == "meta":
                meta = json.loads(str(np.load(zf.open(info.filename))))
                continue
            if dtype.hasobject:
                raise DatabaseError(f"pattern database {path} holds object arrays")
            arrays[name] = (np.memmap(path, dtype=dtype, mode="r", offset=offset, shape=shape,
                                      order="F" if fortran else "C") if nbytes else
                            np.zeros(shape, dtype))
    return arrays, meta


def default_database_path(fov_min_deg: float = 10.0, fov_max_deg: float = 30.0) -> Path:
    """Where the default database for a FOV range lives in the user cache."""
    return cache_dir() / f"patterns_v{DATABASE_VERSION}_{fov_min_deg:g}-{fov_max_deg:g}deg.npz"


_DEFAULT: dict[Path, PatternDatabase] = {}


def default_database(fov_min_deg: float = 10.0, fov_max_deg: float = 30.0, *,
                     progress: bool = True) -> PatternDatabase:
    """The cached default database (built, with a progress bar, and saved if absent).

    A corrupt cached file raises :class:`~skyfix.errors.DatabaseError`; delete it (or run
    ``skyfix database build``) to rebuild.
    """
    path = default_database_path(fov_min_deg, fov_max_deg)
    if path in _DEFAULT:
        return _DEFAULT[path]
    if path.exists():
        try:
            db = PatternDatabase.load(path)
        except DatabaseError as exc:
            raise DatabaseError(f"{exc} (delete it, or rebuild with `skyfix database build`)") from None
    else:
        db = PatternDatabase.build(fov_min_deg, fov_max_deg, progress=progress)
        db.save(path)
        db = PatternDatabase.load(path)
    _DEFAULT[path] = db
    return db
