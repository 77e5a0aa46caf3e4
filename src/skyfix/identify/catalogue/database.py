"""The pattern database: 4-star patterns of catalogue stars, indexed by their edge-ratio key.

Build (vectorised in chunks: a few seconds and ~0.3 GB for 10–30°): the field-of-view range is
split into bands spaced geometrically (``band_ratio``). For each band, *lattice fields* — circles of radius
``field_radius`` × band FOV centred on a Fibonacci lattice that oversamples the sphere — each
contribute every 4-combination of their ``stars_per_field`` brightest stars. Whatever way
a camera of that FOV points, some lattice field nearly coincides with its view, so the
image's brightest stars form patterns that are in the database. Close doubles (which a
detector merges) are dropped per band. Patterns found by several fields or bands are kept once.

The file is an uncompressed ``.npz`` whose members are memory-mapped on load (one map of the file,
found from an index in the zip comment), written atomically with a checksum that is checked on
load (:mod:`skyfix.cache`).
"""

from __future__ import annotations

import json
import logging
import math
import zipfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from itertools import combinations
from pathlib import Path
from typing import NamedTuple

import numpy as np

from skyfix._kernels.rotation import chord_angle
from skyfix.cache import CorruptFileError, map_npz, verify, write_npz
from skyfix.catalog import Catalog, epoch_now, fibonacci_sphere, load_hipparcos, propagate
from skyfix.errors import DatabaseError
from skyfix.identify.catalogue.hashing import build_table, edge_ratios, key_codes
from skyfix.identify.catalogue.kernel_data import PatternTable, StarIndex
from skyfix.validate import check_fov_range  # the range solve and the CLI accept too

__all__ = ["PatternDatabase", "DATABASE_VERSION", "ProgressCallback", "brightest_per_field", "readonly_view"]

DATABASE_VERSION = 3
_ARRAYS = ("star_ids", "star_vectors", "star_mag", "star_pm", "pattern_stars", "pattern_ratios",
           "pattern_largest", "key_codes", "key_start", "table", "cell_centres", "cell_start",
           "cell_stars")
# Sky cells of the star index used in verification: 3072 (~3.7° apart) per 120,000 stars, so a
# cell holds ~40 stars whatever the catalogue (Hipparcos: 3072; Gaia to G 10: 12,288, ~1.8° apart).
_N_CELLS = 3072
_STARS_PER_N_CELLS = 120_000
# Build in chunks, so the peak memory is a few times the database's own size: lattice fields
# per chunk ((fields, 70, 4) int32 combinations, ~18 MB at 8 stars per field) and patterns per
# chunk of the edge-ratio computation (~200 bytes of float64 temporaries per pattern).
_CHUNK_FIELDS = 16384
_CHUNK_PATTERNS = 1 << 17

ProgressCallback = Callable[[str, float], None]
"""Called as ``progress(what, fraction_done)`` while a database is built."""

log = logging.getLogger(__name__)


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

    def pattern_table(self) -> PatternTable:
        """The patterns and their hash table as the compiled search reads them: read-only
        plain-ndarray views, no copies (read-only whether memory-mapped or built in memory: one
        compiled signature)."""
        table = self.__dict__.get("_views", {}).get("pattern_table")
        if table is None:
            table = PatternTable(self.n_bins, *self._plain_views(
                ("table", "key_codes", "key_start", "pattern_ratios", "pattern_largest", "pattern_stars")))
            self.__dict__["_views"]["pattern_table"] = table
        return table

    def star_index(self) -> StarIndex:
        """The stars and their sky cells as the compiled verification and refit read them
        (read-only plain-ndarray views, as :meth:`pattern_table`)."""
        index = self.__dict__.get("_views", {}).get("star_index")
        if index is None:
            views = self._plain_views(("star_vectors", "cell_centres", "cell_start", "cell_stars"))
            index = StarIndex(*views, self.cell_radius)
            self.__dict__["_views"]["star_index"] = index
        return index

    def star_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Read-only plain-ndarray views of ``star_ids``, ``star_mag``, ``star_vectors`` (indexing a
        memory map costs several microseconds a call; a plain view, well under one)."""
        return self._plain_views(("star_ids", "star_mag", "star_vectors"))

    def derived(self, key: tuple, make: Callable[[], object]) -> object:
        """What ``make()`` builds from this database (a pair table, a triangle table), built once
        per ``key`` and kept with the database for as long as it lives."""
        cache = self.__dict__.setdefault("_derived", {})
        value = cache.get(key)
        if value is None:
            value = cache[key] = make()
        return value

    def _plain_views(self, names: tuple[str, ...]) -> tuple[np.ndarray, ...]:
        cache = self.__dict__.setdefault("_views", {})
        views = cache.get(names)
        if views is None:
            views = cache[names] = tuple(readonly_view(getattr(self, k)) for k in names)
        return views

    def __setattr__(self, name: str, value) -> None:
        # A replaced array invalidates the cached views.
        self.__dict__.pop("_views", None)
        self.__dict__.pop("_derived", None)
        super().__setattr__(name, value)

    def vectors_at(self, index: np.ndarray, epoch: float | None) -> np.ndarray:
        """ICRS unit vectors of stars ``index`` moved by proper motion to ``epoch`` (default: as
        built), by the catalogue's own formula (:func:`skyfix.catalog.propagate`)."""
        v = np.asarray(self.star_arrays()[2][index], dtype=np.float64)
        if epoch is None or epoch == self.epoch:
            return v
        pm = np.asarray(self.star_pm[index], dtype=np.float64)
        return propagate(v, pm[..., 0], pm[..., 1], epoch - self.epoch)

    # --- build ----------------------------------------------------------------------------
    # Over ten parameters: the build's settings, keywords with documented defaults (the options
    # of ``skyfix database build``); _build takes them as one _BuildSettings.
    @classmethod
    def build(cls, fov_min_deg: float = 10.0, fov_max_deg: float = 30.0, *,
              catalog: Catalog | None = None, band_ratio: float = 1.35, stars_per_field: int = 8,
              field_radius: float = 0.4, lattice_step: float = 0.5, double_star_sep: float = 1 / 150,
              pattern_mag_limit: float = 8.5, n_bins: int = 25, epoch: float | None = None,
              progress: bool | ProgressCallback = False,
              catalog_source: str = "hipparcos") -> PatternDatabase:
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
        progress : bool or callable
            True: a progress bar on stderr when it is a terminal (else log messages);
            a callable: called as ``progress(what, fraction_done)``.
        catalog_source : str
            What ``catalog`` is, recorded in ``meta`` (``"hipparcos"``, ``"gaia"``): a cached
            database built from another is rebuilt (:mod:`skyfix.identify.catalogue.bands`).
        """
        check_fov_range(fov_min_deg, fov_max_deg)
        if not (0 < fov_min_deg <= fov_max_deg < 120):
            raise DatabaseError(f"bad FOV range {fov_min_deg}–{fov_max_deg}°")
        if not 4 <= stars_per_field <= 16:
            raise DatabaseError("stars_per_field must be 4–16")
        with _reporter(progress, "building the pattern database") as report:
            settings = _BuildSettings(fov_min_deg, fov_max_deg, band_ratio, stars_per_field, field_radius,
                                      lattice_step, double_star_sep, pattern_mag_limit, n_bins)
            db = cls._build(settings, catalog, epoch, report)
            db.meta["catalog_source"] = catalog_source
            return db

    @staticmethod
    def n_bands(fov_min_deg: float, fov_max_deg: float, band_ratio: float) -> int:
        """How many FOV bands a build splits ``fov_min_deg``–``fov_max_deg`` into."""
        return max(1, math.ceil(math.log(fov_max_deg / fov_min_deg) / math.log(band_ratio) - 1e-9) + 1)

    @classmethod
    def _build(cls, settings: _BuildSettings, catalog: Catalog | None, epoch: float | None,
               report: ProgressCallback) -> PatternDatabase:
        (fov_min_deg, fov_max_deg, band_ratio, stars_per_field, field_radius, lattice_step, double_star_sep,
         pattern_mag_limit, n_bins) = settings
        report("reading the star catalogue", 0.0)
        epoch = epoch_now() if epoch is None else float(epoch)
        cat = load_hipparcos(epoch=epoch) if catalog is None else catalog
        n_bands = cls.n_bands(fov_min_deg, fov_max_deg, band_ratio)
        fovs = (np.geomspace(fov_min_deg, fov_max_deg, n_bands) if n_bands > 1
                else np.array([fov_min_deg]))
        bright = np.flatnonzero(cat.mag <= pattern_mag_limit)
        bright_vectors = cat.vectors[bright]
        combos = np.array(list(combinations(range(stars_per_field), 4)), dtype=np.int32)
        quad_set = _QuadSet(len(bright))

        # Patterns of each band, a chunk of lattice fields at a time, kept once (as packed codes).
        # Their count is what takes the time (it grows as 1 / FOV^2): progress is counted in fields.
        radii = [math.radians(f) * field_radius for f in fovs]
        field_counts = [_n_fields(r, lattice_step) for r in radii]
        total, done = sum(field_counts), 0
        bands = []
        for fov_deg, radius in zip(fovs, radii, strict=True):
            chunks = []
            for quads, n in _band_patterns(bright_vectors, radius, lattice_step,
                                           math.radians(fov_deg) * double_star_sep, stars_per_field,
                                           combos):
                chunks.append(quad_set.unique(quads))
                done += n
                report(f"patterns of {fov_deg:.3g}° fields", 0.8 * done / total)
            bands.append(quad_set.merge(chunks))
            del chunks
        report("merging the patterns", 0.8)
        quads = quad_set.unpack(quad_set.merge(bands), bright)  # sorted rows of catalogue indices
        del bands

        # Sort by key code: codes from the float64 ratios, then the ratios again in the new order
        # (computed in chunks, they are never all held in float64).
        codes = np.empty(len(quads), dtype=np.int64)
        for part in _chunks(len(quads)):
            codes[part] = key_codes(edge_ratios(cat.vectors[quads[part]])[0], n_bins)
            report("key codes of the patterns", 0.8 + 0.06 * part.stop / len(quads))
        report("sorting the patterns by key", 0.86)
        order, unique, start, table = build_table(codes)
        del codes
        quads = quads[order]
        del order
        ratios = np.empty((len(quads), 5), dtype=np.float32)
        largest = np.empty(len(quads), dtype=np.float32)
        for part in _chunks(len(quads)):
            ratios[part], largest[part] = edge_ratios(cat.vectors[quads[part]])
            report("edge ratios of the patterns", 0.92 + 0.06 * part.stop / len(quads))
        report("star index", 0.98)
        cell_centres, cell_start, cell_stars, cell_radius = _cell_index(
            cat.vectors, _N_CELLS * max(1, round(len(cat.vectors) / _STARS_PER_N_CELLS)))
        meta = dict(version=DATABASE_VERSION, cell_radius=cell_radius, fov_min_deg=float(fov_min_deg),
                    fov_max_deg=float(fov_max_deg), band_fovs_deg=[float(f) for f in fovs],
                    n_bins=int(n_bins), epoch=epoch, stars_per_field=stars_per_field,
                    field_radius=field_radius, lattice_step=lattice_step,
                    double_star_sep=double_star_sep, pattern_mag_limit=pattern_mag_limit,
                    catalog=cat.name)
        report("done", 1.0)
        return cls(star_ids=np.asarray(cat.ids, np.int64), star_vectors=np.asarray(cat.vectors, np.float64),
                   star_mag=np.asarray(cat.mag, np.float32),
                   star_pm=np.stack([cat.pm_ra, cat.pm_dec], axis=-1).astype(np.float64),
                   pattern_stars=quads, pattern_ratios=ratios, pattern_largest=largest,
                   key_codes=unique, key_start=start, table=table, cell_centres=cell_centres,
                   cell_start=cell_start, cell_stars=cell_stars, meta=meta)

    # --- I/O ------------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write an uncompressed ``.npz`` with a checksum, atomically (a temporary file unique to
        this writer, then rename: :func:`skyfix.cache.write_npz`)."""
        write_npz(path, {"meta": np.array(json.dumps(self.meta)),
                         **{k: np.ascontiguousarray(getattr(self, k)) for k in _ARRAYS}})

    @classmethod
    def load(cls, path: str | Path) -> PatternDatabase:
        """Memory-map a database written by :meth:`save`, after checking its checksum (hashed
        once; while the file is unchanged later loads only compare a stamp: :func:`skyfix.cache.verify`).

        Raises
        ------
        DatabaseError
            The file is missing, truncated, corrupt or of another version.
        """
        path = Path(path)
        try:
            with open(path, "rb") as fh:
                verify(fh)
                arrays = map_npz(fh)
            meta = json.loads(str(arrays.pop("meta")[()])) if "meta" in arrays else {}
        except CorruptFileError as exc:
            raise DatabaseError(f"pattern database {path} is unusable: {exc}; rebuild it "
                                "(skyfix database build)") from None
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


class _BuildSettings(NamedTuple):
    """The settings of :meth:`PatternDatabase.build` (documented there)."""

    fov_min_deg: float
    fov_max_deg: float
    band_ratio: float
    stars_per_field: int
    field_radius: float
    lattice_step: float
    double_star_sep: float
    pattern_mag_limit: float
    n_bins: int


def readonly_view(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a`` as a plain ndarray (no copy)."""
    view = np.asarray(a).view()
    view.flags.writeable = False
    return view


def _cell_index(vectors: np.ndarray, n_cells: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Stars grouped by nearest Fibonacci-lattice cell: centres, start offsets, stars, radius."""
    from scipy.spatial import cKDTree

    centres = fibonacci_sphere(n_cells)
    dist, cell = cKDTree(centres).query(vectors)
    order = np.lexsort((np.arange(len(vectors)), cell))  # by cell, then brightness
    start = np.searchsorted(cell[order], np.arange(n_cells + 1)).astype(np.int64)
    radius = float(chord_angle(float(dist.max(initial=0.0))))
    return centres, start, order.astype(np.int32), radius


def _n_fields(radius: float, lattice_step: float) -> int:
    """Lattice fields of a band whose fields have angular ``radius``."""
    return int(math.ceil(4 * math.pi / (lattice_step * radius) ** 2))


def brightest_per_field(vectors: np.ndarray, radius: float, lattice_step: float, double_sep: float,
                        per_field: int) -> Iterator[np.ndarray]:
    """The ``per_field`` brightest stars of every lattice field, a chunk of fields at a time.

    Fields are circles of angular ``radius`` centred on a Fibonacci lattice ``lattice_step`` ×
    ``radius`` apart; close doubles (within ``double_sep``, radians: a detector merges them)
    lose their fainter member first. Yields (F, per_field) int32 rows of indices into
    ``vectors`` (brightest first, so each row is ascending), ``-1`` where a field has fewer
    stars. The pattern database (4-combinations of each row) and the pair table
    (:mod:`skyfix.identify.catalogue.pairs`) choose their stars this way.
    """
    from scipy.spatial import cKDTree

    tree = cKDTree(vectors)
    # Drop the fainter member of close pairs (vectors are brightest first).
    pairs = tree.query_pairs(2 * math.sin(double_sep / 2), output_type="ndarray")
    keep = np.ones(len(vectors), bool)
    keep[pairs.max(axis=1)] = False
    kept = np.flatnonzero(keep).astype(np.int32)
    tree = cKDTree(vectors[kept])
    n_fields = _n_fields(radius, lattice_step)
    for first in range(0, n_fields, _CHUNK_FIELDS):
        centres = fibonacci_sphere(n_fields, first, first + _CHUNK_FIELDS)
        members = tree.query_ball_point(centres, 2 * math.sin(radius / 2), return_sorted=True)
        top = np.full((len(centres), per_field), -1, dtype=np.int32)
        for i, m in enumerate(members):  # one cheap slice per field; the rest is vectorised
            m = m[:per_field]
            top[i, :len(m)] = m
        yield np.where(top >= 0, kept[np.maximum(top, 0)], -1).astype(np.int32)


def _band_patterns(vectors: np.ndarray, radius: float, lattice_step: float, double_sep: float,
                   per_field: int, combos: np.ndarray) -> Iterator[tuple[np.ndarray, int]]:
    """The patterns of one FOV band, a chunk of lattice fields at a time: ``(quads, n_fields)``,
    quads (Q, 4) int32 indices into ``vectors``, each row ascending, rows possibly repeated."""
    for top in brightest_per_field(vectors, radius, lattice_step, double_sep, per_field):
        quads = top[:, combos].reshape(-1, 4)
        # Members ascending and combinations ascending: each row is ascending already.
        yield quads[(quads >= 0).all(axis=1)], len(top)


class _QuadSet:
    """Sets of patterns (rows of 4 ascending star indices) as sorted unique arrays.

    With fewer than 2^16 stars a row is packed into one uint64 (index i in bits 48-16i..63-16i),
    whose order is the rows' lexicographic order; 4× less memory and a plain sort. Otherwise
    the rows themselves (np.unique along axis 0). Either way, :meth:`unpack` of a merge gives
    the same sorted unique rows.
    """

    _BITS = 16

    def __init__(self, n_stars: int) -> None:
        self.packed = n_stars <= 1 << self._BITS

    def unique(self, quads: np.ndarray) -> np.ndarray:
        """The distinct patterns of ``quads`` (Q, 4), sorted."""
        if not self.packed:
            return np.unique(quads, axis=0)
        q = quads.astype(np.uint64)
        code = q[:, 0] << np.uint64(3 * self._BITS)
        for j in (1, 2, 3):
            code |= q[:, j] << np.uint64((3 - j) * self._BITS)
        return _sorted_unique(code)

    def merge(self, parts: list[np.ndarray]) -> np.ndarray:
        """The union of sets from :meth:`unique` / :meth:`merge`."""
        if not parts:
            return np.empty((0,) if self.packed else (0, 4), np.uint64 if self.packed else np.int32)
        if not self.packed:
            return np.unique(np.concatenate(parts), axis=0)
        return _sorted_unique(np.concatenate(parts))

    def unpack(self, codes: np.ndarray, index: np.ndarray) -> np.ndarray:
        """(P, 4) int32 rows of a set, each star number ``i`` replaced by ``index[i]`` (an
        increasing map keeps the order)."""
        index = np.asarray(index).astype(np.int32)
        if not self.packed:
            return index[codes]
        rows = np.empty((len(codes), 4), dtype=np.int32)
        mask = np.uint64((1 << self._BITS) - 1)
        for part in _chunks(len(codes)):
            for j in range(4):
                rows[part, j] = index[(codes[part] >> np.uint64((3 - j) * self._BITS)) & mask]
        return rows


def _sorted_unique(a: np.ndarray) -> np.ndarray:
    """The distinct values of 1-d ``a``, ascending, by sorting in place (NumPy 2.4's np.unique
    hashes first: 40x slower on a million uint64)."""
    a.sort()
    keep = np.empty(len(a), dtype=bool)
    keep[:1] = True
    np.not_equal(a[1:], a[:-1], out=keep[1:])
    return a[keep]


def _chunks(n: int) -> Iterator[slice]:
    """Slices of ``range(n)`` of :data:`_CHUNK_PATTERNS` patterns."""
    for first in range(0, n, _CHUNK_PATTERNS):
        yield slice(first, min(first + _CHUNK_PATTERNS, n))


@contextmanager
def _reporter(progress: bool | ProgressCallback, title: str) -> Iterator[ProgressCallback]:
    """A ``report(what, fraction)`` callable for ``progress`` (see :meth:`PatternDatabase.build`):
    the callable itself; for True a transient rich bar on stderr if it is a terminal, else
    one log line per stage; for False nothing."""
    if callable(progress):
        yield lambda what, fraction: progress(what, round(fraction, 4))  # no 0.8000000000000002
        return
    if not progress:
        yield lambda what, fraction: None
        return
    from rich.console import Console

    console = Console(stderr=True)
    if not console.is_terminal:
        last = [None]

        def log_stage(what: str, fraction: float) -> None:
            if what != last[0]:
                last[0] = what
                log.info("%s: %s", title, what)

        yield log_stage
        return
    from rich.progress import BarColumn, Progress, TaskProgressColumn, TextColumn, TimeElapsedColumn

    bar = Progress(TextColumn(title), BarColumn(), TaskProgressColumn(), TimeElapsedColumn(),
                   TextColumn("{task.description}"), console=console, transient=True)
    task = bar.add_task("starting", total=1.0)
    with bar:
        yield lambda what, fraction: bar.update(task, description=what, completed=fraction)
