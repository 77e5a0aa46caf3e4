"""Field-of-view bands: the pattern databases that let a solve serve any field from 1° to 90°
with no hint, each built on first need and cached.

One pattern database serves fields up to :data:`FOV_MARGIN` beyond its FOV range on either
side (its lattice fields' patterns are still among an image's brightest stars there). Four
bands cover 0.74–120°:

========  ==========  ===========================  ===================================
band      built for   serves                       stars
========  ==========  ===========================  ===================================
standard  10–30°      7.4–40.5°                    Hipparcos 2 (Hp ≤ 8.5 form patterns)
narrow    2–6°        1.5–8.1°                     Gaia DR3 to G 10 + Hipparcos
wide      40–90°      29.6–121°                    Hipparcos 2
fine      1–1.45°     0.74–1.96°                   Gaia DR3 to G 10 + Hipparcos
========  ==========  ===========================  ===================================

Below ~6° Hipparcos has too few stars (a 2° × 1.5° field holds 4 stars of Hp ≤ 8.5 on average,
against 35 of G ≤ 10 and at least 6 anywhere: docs/catalogues.md):
the narrow band uses the deeper catalogue. Its lattice is sparser and its fields give 6 stars'
patterns (15) instead of 8 (70), or it would be 20 times larger (its fields are 25 times as many
as the standard band's). The fine band serves fields of ~1°, where G 10 holds 8.8 stars a frame
on average: sparser still (5 stars a field, 5 patterns), or it would be 3.5 times the narrow
band's size. Narrower fields need a deeper catalogue of the user's (:data:`DEEP`).

:func:`bands_for` orders the bands a frame is tried against: the one(s) its FOV hint or camera
falls in; with none, all of them, the standard band first (the common case stays as fast as it
was). :func:`band_database` loads a band's database from the user cache, building it (with a
progress bar) the first time it is needed; a cached file that is corrupt, truncated, of another
version or built with other settings is rebuilt, never used (one written before files carried a
member index is saved again with one: :mod:`skyfix.cache`).
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
from pathlib import Path
from typing import NamedTuple

from skyfix.cache import cache_dir, exclusive_lock, has_index, notice
from skyfix.catalog import epoch_now, load_gaia
from skyfix.errors import DatabaseError, unknown_name
from skyfix.identify.catalogue.database import DATABASE_VERSION, PatternDatabase, ProgressCallback

__all__ = ["BANDS", "Band", "DEEP", "FOV_MARGIN", "band_database", "bands_for", "database_for_fov",
           "default_database", "default_database_path", "log_overlap", "served_fov_deg", "served_range_deg"]

log = logging.getLogger(__name__)

FOV_MARGIN = 1.35
"""A database serves horizontal fields from its ``fov_min_deg / FOV_MARGIN`` to its
``fov_max_deg · FOV_MARGIN``."""


class Band(NamedTuple):
    """A FOV range and how its pattern database is built (:meth:`PatternDatabase.build`'s settings)."""

    name: str
    fov_min_deg: float
    fov_max_deg: float
    catalog: str = "hipparcos"  # or "gaia": Gaia DR3 to G 10 with Hipparcos for the brightest
    stars_per_field: int = 8
    lattice_step: float = 0.5
    band_ratio: float = 1.35
    pattern_mag_limit: float = 8.5
    # The search's loose tolerance tier (key, model error) with no camera given; None: the
    # default (0.015, 0.008), which absorbs the distortion of 10–40° lenses.
    loose_tolerance: tuple[float, float] | None = None

    @property
    def served_fov_deg(self) -> tuple[float, float]:
        """The horizontal fields this band serves, degrees."""
        return self.fov_min_deg / FOV_MARGIN, self.fov_max_deg * FOV_MARGIN

    @property
    def path(self) -> Path:
        """Its file in the user cache."""
        return default_database_path(self.fov_min_deg, self.fov_max_deg, self)


STANDARD = Band("standard", 10.0, 30.0)
NARROW = Band("narrow", 2.0, 6.0, catalog="gaia", stars_per_field=6, lattice_step=0.8, band_ratio=1.5,
              pattern_mag_limit=10.0, loose_tolerance=(0.010, 0.004))
WIDE = Band("wide", 40.0, 90.0)
FINE = Band("fine", 1.0, 1.45, catalog="gaia", stars_per_field=5, lattice_step=1.0, band_ratio=1.5,
            pattern_mag_limit=10.0, loose_tolerance=(0.010, 0.004))
BANDS: tuple[Band, ...] = (STANDARD, NARROW, WIDE, FINE)
DEEP = FINE._replace(name="deep")
"""How a database is built from a deep catalogue file (``skyfix database build --catalog``): the
fine band's lattice, 5 stars a field (such a catalogue holds many stars in every field)."""
"""The default bands, in the order a frame with no FOV hint is tried."""


def served_range_deg() -> tuple[float, float]:
    """The horizontal fields the default bands serve together, degrees (narrowest, widest)."""
    return min(b.served_fov_deg[0] for b in BANDS), max(b.served_fov_deg[1] for b in BANDS)


def served_fov_deg(database: PatternDatabase) -> tuple[float, float]:
    """The horizontal fields ``database`` serves, degrees (see :data:`FOV_MARGIN`)."""
    return database.fov_min_deg / FOV_MARGIN, database.fov_max_deg * FOV_MARGIN


def bands_for(fov_lo_deg: float | None = None, fov_hi_deg: float | None = None) -> list[Band]:
    """The default bands to try for a frame whose horizontal FOV lies in ``fov_lo_deg``–``fov_hi_deg``
    (None: unknown), in the order to try them: those that serve part of the range, the one whose
    range holds the most of it (on a log scale) first; with no range, :data:`BANDS` as they are.
    Empty when no band serves any of the range."""
    if fov_lo_deg is None or fov_hi_deg is None:
        return list(BANDS)
    scored = [(log_overlap(b.served_fov_deg, fov_lo_deg, fov_hi_deg), i, b) for i, b in enumerate(BANDS)]
    return [b for score, _, b in sorted(scored, key=lambda s: (-s[0], s[1])) if score >= 0.0]


def log_overlap(served_deg: tuple[float, float], fov_lo_deg: float | None = None,
                fov_hi_deg: float | None = None) -> float:
    """How much of the fields ``fov_lo_deg``–``fov_hi_deg`` (None: any) a database serving
    ``served_deg`` covers, on a log scale: ``ln(min(hi, fov_hi) / max(lo, fov_lo))`` (negative when
    they do not meet). It orders the bands (:func:`bands_for`) and shares the search's time among
    them (:func:`skyfix.identify.methods.quad.identify`): a field's width has no preferred scale,
    so with nothing else known each ratio of widths is as likely as any other."""
    lo, hi = served_deg
    lo = lo if fov_lo_deg is None else max(lo, fov_lo_deg)
    hi = hi if fov_hi_deg is None else min(hi, fov_hi_deg)
    return math.log(hi) - math.log(lo)


def database_for_fov(fov_deg: float, *, progress: bool | ProgressCallback = True) -> PatternDatabase:
    """The default band's database that best serves a horizontal field of ``fov_deg`` (its catalogue
    stars are those a known attitude is matched against: :mod:`skyfix.identify.hint`, the tracker).

    Raises
    ------
    DatabaseError
        No default band serves that field.
    """
    bands = bands_for(fov_deg, fov_deg)
    if not bands:
        lo, hi = served_range_deg()
        raise DatabaseError(f"field of view {fov_deg:.3g}° is outside every default FOV band "
                            f"({lo:.3g}–{hi:.3g}°)")
    return band_database(bands[0], progress=progress)


def default_database_path(fov_min_deg: float = 10.0, fov_max_deg: float = 30.0,
                          band: Band | None = None) -> Path:
    """Where the database for a FOV range lives in the user cache (``band`` gives its other settings;
    default: those of :meth:`PatternDatabase.build`)."""
    prefix = "" if band is None or band.catalog == "hipparcos" else f"{band.catalog}_"
    return cache_dir() / f"patterns_v{DATABASE_VERSION}_{prefix}{fov_min_deg:g}-{fov_max_deg:g}deg.npz"


_LOADED: dict[tuple[Band, str | None], PatternDatabase] = {}


def band_database(band: Band, *, progress: bool | ProgressCallback = True) -> PatternDatabase:
    """The band's database from the user cache (built, with a progress bar, and saved if absent).

    A cached file that is corrupt, truncated, unreadable or built with other settings is removed and
    rebuilt. Processes that need the same missing database build it once: the others wait for it
    (a lock). ``progress`` is as for :meth:`PatternDatabase.build`.
    """
    key = (band, os.environ.get("SKYFIX_CACHE"))  # cheaper than the path (cache_dir asks platformdirs)
    if key in _LOADED:
        return _LOADED[key]
    path = band.path
    db = _load_cached(path, band, remove_bad=False)
    if db is None:
        with exclusive_lock(path, lambda: _tell(progress, "waiting for another skyfix process to build "
                                                          f"the pattern database {path.name}")):
            db = _load_cached(path, band, remove_bad=True)  # another process may have built it
            if db is None:
                log.info("building the %s-field pattern database %s (first use)", band.name, path)
                db = _build(band, progress)
                try:
                    db.save(path)
                    db = PatternDatabase.load(path)
                except (OSError, DatabaseError) as exc:  # unwritable cache: use the one in memory
                    log.warning("cannot cache the pattern database in %s: %s", path, exc)
    _LOADED[key] = db
    return db


def default_database(fov_min_deg: float = 10.0, fov_max_deg: float = 30.0, *,
                     progress: bool | ProgressCallback = True) -> PatternDatabase:
    """The cached database for a FOV range built with the default settings (Hipparcos); with no
    arguments, the standard band's (10–30°). See :func:`band_database`."""
    if (fov_min_deg, fov_max_deg) == (STANDARD.fov_min_deg, STANDARD.fov_max_deg):
        return band_database(STANDARD, progress=progress)
    return band_database(Band("custom", float(fov_min_deg), float(fov_max_deg)), progress=progress)


def _build(band: Band, progress: bool | ProgressCallback) -> PatternDatabase:
    catalog = None
    if band.catalog == "gaia":
        catalog = load_gaia(epoch=epoch_now())
    elif band.catalog != "hipparcos":
        raise unknown_name("catalogue", band.catalog, ("hipparcos", "gaia"))
    return PatternDatabase.build(band.fov_min_deg, band.fov_max_deg, catalog=catalog,
                                 band_ratio=band.band_ratio, stars_per_field=band.stars_per_field,
                                 lattice_step=band.lattice_step, pattern_mag_limit=band.pattern_mag_limit,
                                 progress=progress, catalog_source=band.catalog)


def _settings_differ(db: PatternDatabase, band: Band) -> str:
    """Why ``db`` is not the database ``band`` builds ("" when it is)."""
    meta = db.meta
    want = dict(fov_min_deg=band.fov_min_deg, fov_max_deg=band.fov_max_deg,
                stars_per_field=band.stars_per_field, lattice_step=band.lattice_step,
                pattern_mag_limit=band.pattern_mag_limit, catalog_source=band.catalog)
    have = dict(meta, catalog_source=meta.get("catalog_source", "hipparcos"))
    for key, value in want.items():
        if have.get(key) != value:
            return f"built with {key} = {have.get(key)!r}, not {value!r}"
    n_bands = len(meta.get("band_fovs_deg", ()))
    if n_bands != PatternDatabase.n_bands(band.fov_min_deg, band.fov_max_deg, band.band_ratio):
        return f"built with {n_bands} FOV bands, not the band ratio {band.band_ratio:g}'s"
    return ""


def _tell(progress: bool | ProgressCallback, message: str) -> None:
    """A message while waiting: to the progress callable, or a notice if ``progress`` is True."""
    if callable(progress):
        progress(message, 0.0)
    elif progress:
        notice(message)
    else:
        log.info("%s", message)


def _with_index(db: PatternDatabase, path: Path) -> PatternDatabase:
    """``db``, loaded from ``path``, a file written before databases carried a member index: saved
    again (the same arrays: a copy, not a rebuild), so later loads skip the zip directory walk."""
    log.info("adding a member index to the cached pattern database %s", path)
    try:
        db.save(path)
        return PatternDatabase.load(path)
    except (OSError, DatabaseError) as exc:  # a read-only cache: it loads as it is
        log.warning("cannot rewrite the pattern database %s: %s", path, exc)
        return db


def _load_cached(path: Path, band: Band, *, remove_bad: bool) -> PatternDatabase | None:
    """The database cached at ``path``, or None if absent, unusable or built with settings other than
    ``band``'s (then removed if ``remove_bad``)."""
    if not path.exists():
        return None
    try:
        db = PatternDatabase.load(path)
        stale = _settings_differ(db, band)
        if stale:
            raise DatabaseError(f"pattern database {path} was {stale}")
        return db if has_index(path) else _with_index(db, path)
    except DatabaseError as exc:
        if remove_bad:
            log.warning("rebuilding the cached pattern database: %s", exc)
            with contextlib.suppress(OSError):  # then the new file is renamed over it
                path.unlink(missing_ok=True)
        return None
