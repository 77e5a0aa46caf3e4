"""A star catalogue from a user's file: deeper than the bundled ones, for fields they cannot serve.

The bundled catalogues hold stars to G 10 (Gaia DR3) and Hp ≈ 9 (Hipparcos): about 11.7 stars a
square degree, so a field under ~1° wide holds fewer than the 8 stars a lost-in-space solve needs.
A table exported from the Gaia archive, VizieR or any other source — CSV, ECSV, FITS or VOTable,
read by astropy — becomes a :class:`~skyfix.catalog.Catalog` here, and ``skyfix database build
--catalog FILE`` builds a pattern database from it (docs/catalogues.md#a-deeper-catalogue).

Columns are found by name (case-insensitive; the first of each list present is used):

=========  ==================================================  ==============================
quantity   names                                               unit
=========  ==================================================  ==============================
RA         ``ra``, ``ra_deg``, ``raj2000``, ``ra_icrs``        degrees (ICRS)
Dec        ``dec``, ``dec_deg``, ``dej2000``, ``de_icrs``      degrees
magnitude  ``mag``, ``phot_g_mean_mag``, ``gmag``, ``g``,      magnitudes (G unless the column
           ``hpmag``, ``vmag``, ``v``                          is ``hpmag``: Hp)
pm RA      ``pmra`` (optional)                                 mas/yr, including cos δ
pm Dec     ``pmdec`` (optional)                                mas/yr
parallax   ``parallax``, ``plx`` (optional)                    mas
id         ``source_id``, ``id``, ``hip`` (optional)           integer
=========  ==================================================  ==============================

A missing proper motion or parallax is 0; a row without RA, Dec or magnitude is dropped.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from skyfix.catalog import Catalog, epoch_now
from skyfix.errors import CatalogError
from skyfix.geometry import radec_to_vector

__all__ = ["COLUMN_NAMES", "load_catalog_file"]

COLUMN_NAMES: dict[str, tuple[str, ...]] = {
    "ra": ("ra", "ra_deg", "raj2000", "ra_icrs"),
    "dec": ("dec", "dec_deg", "dej2000", "de_icrs"),
    "mag": ("mag", "phot_g_mean_mag", "gmag", "g", "hpmag", "vmag", "v"),
    "pmra": ("pmra",),
    "pmdec": ("pmdec",),
    "parallax": ("parallax", "plx"),
    "id": ("source_id", "id", "hip"),
}
"""The column names each quantity is read from (see the module text)."""

_MAS = math.radians(1.0 / 3.6e6)


def load_catalog_file(path: str | Path, *, position_epoch: float = 2016.0, epoch: float | None = None,
                      mag_limit: float | None = None) -> Catalog:
    """The stars of a catalogue file, brightest first, moved to ``epoch`` by their proper motion.

    Parameters
    ----------
    path : str or Path
        A table astropy reads: ``.csv``, ``.ecsv``, ``.fits``, ``.vot``/``.xml`` (columns: the
        module text).
    position_epoch : float
        Julian year of the file's positions (default 2016.0, Gaia DR3's).
    epoch : float, optional
        Julian year to move the positions to (default: now).
    mag_limit : float, optional
        Keep only stars with magnitude ``<= mag_limit``.

    Raises
    ------
    CatalogError
        The file cannot be read, lacks a column RA, Dec or magnitude, or holds no star.
    """
    from astropy.table import Table

    path = Path(path)
    try:
        table = Table.read(path, format=_format(path))
    except (OSError, ValueError, TypeError, IndexError, KeyError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise CatalogError(f"cannot read the catalogue {path}: {first}") from None
    if len(table) == 0:
        raise CatalogError(f"the catalogue {path} holds no star")
    columns = {name.lower(): name for name in table.colnames}

    def column(quantity: str, required: bool = True) -> tuple[np.ndarray | None, str]:
        for name in COLUMN_NAMES[quantity]:
            if name in columns:
                values = np.ma.filled(np.ma.asarray(table[columns[name]], dtype=float), np.nan)
                return np.asarray(values, dtype=float), name
        if required:
            raise CatalogError(f"the catalogue {path} has no {quantity} column (one of "
                               f"{', '.join(COLUMN_NAMES[quantity])}; it has {', '.join(table.colnames)})")
        return None, ""

    ra, _ = column("ra")
    dec, _ = column("dec")
    mag, mag_name = column("mag")
    keep = np.isfinite(ra) & np.isfinite(dec) & np.isfinite(mag) & (np.abs(dec) <= 90.0)
    if mag_limit is not None:
        keep &= mag <= mag_limit
    if not keep.any():
        raise CatalogError(f"the catalogue {path} holds no star with RA, Dec and a magnitude"
                           + (f" of {mag_limit:g} or brighter" if mag_limit is not None else ""))
    order = np.flatnonzero(keep)[np.argsort(mag[keep], kind="stable")]

    def optional(quantity: str, scale: float) -> np.ndarray:
        values, _ = column(quantity, required=False)
        if values is None:
            return np.zeros(len(order))
        out = values[order] * scale
        return np.where(np.isfinite(out), out, 0.0)

    ids, _ = column("id", required=False)
    ids = (np.arange(1, len(order) + 1, dtype=np.int64) if ids is None
           else np.nan_to_num(ids[order]).astype(np.int64))
    parallax = optional("parallax", _MAS)
    base = Catalog(ids, radec_to_vector(np.radians(ra[order]), np.radians(dec[order])),
                   mag[order].astype(np.float32), optional("pmra", _MAS), optional("pmdec", _MAS),
                   float(position_epoch), f"{path.name} (positions at J{position_epoch:g})",
                   "Hp" if mag_name == "hpmag" else "G", np.zeros(len(order), dtype=np.int64),
                   np.where(parallax > 0.0, parallax, 0.0))
    return base.at_epoch(epoch_now() if epoch is None else float(epoch))


def _format(path: Path) -> str | None:
    """astropy's format name for a file's suffix (None: let astropy guess)."""
    suffix = path.suffix.lower()
    return {".csv": "ascii.csv", ".ecsv": "ascii.ecsv", ".fits": "fits", ".fit": "fits",
            ".vot": "votable", ".xml": "votable"}.get(suffix)
