"""What ``skyfix solve`` takes as input besides image files: a folder (its images, sorted by
name), a list file (``@list.txt``: one path a line), and a centroid table (``--centroids
FILE.csv --size W,H``). Checked before any work, each with a one-line error naming the input.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

from skyfix.cli.common import fail
from skyfix.errors import InputError

__all__ = ["expand_inputs", "frame_size", "read_centroid_table"]


def expand_inputs(args: list[Path]) -> list[Path]:
    """The inputs in order: a folder becomes its image files (:data:`skyfix.io.IMAGE_SUFFIXES`,
    sorted by name, not recursive), ``@FILE`` the paths it lists (one a line; blank lines and
    lines starting with ``#`` skipped; a relative path is relative to the list file's folder),
    anything else stays itself (a missing or unreadable file gets its own error record)."""
    out: list[Path] = []
    for arg in args:
        text = str(arg)
        if text.startswith("@") and len(text) > 1:
            out += _listed(Path(text[1:]))
        elif arg.is_dir():
            out += _folder_images(arg)
        else:
            out.append(arg)
    return out


def _folder_images(folder: Path) -> list[Path]:
    from skyfix.io import IMAGE_SUFFIXES

    try:
        images = sorted(p for p in folder.iterdir()
                        if p.is_file() and p.name.lower().endswith(IMAGE_SUFFIXES))
    except OSError as exc:
        fail(f"{folder}: cannot list the folder ({exc.strerror or type(exc).__name__})")
    if not images:
        fail(f"{folder}: no images in the folder (FITS, TIFF, PNG or JPEG: {', '.join(IMAGE_SUFFIXES)})")
    return images


def _listed(list_file: Path) -> list[Path]:
    try:
        lines = list_file.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        fail(f"@{list_file}: cannot read the list file ({getattr(exc, 'strerror', None) or exc})")
    paths = [line.strip() for line in lines]
    paths = [p for p in paths if p and not p.startswith("#")]
    if not paths:
        fail(f"@{list_file}: the list file names no image (one path a line)")
    return [p if p.is_absolute() else list_file.parent / p for p in map(Path, paths)]


def frame_size(text: str, option: str = "--size") -> tuple[int, int]:
    """``W,H``: the frame's width and height, whole pixels >= 1."""
    parts = text.replace("x", ",").split(",")
    try:
        w, h = (int(p) for p in parts)
    except ValueError:
        w = h = 0
    if len(parts) != 2 or w < 1 or h < 1:
        fail(f"{option} wants the frame's width and height in pixels as W,H (e.g. 1024,768), got {text!r}")
    return w, h


def read_centroid_table(path: Path):
    """Centroids (N, 2) from a CSV table: columns ``x,y[,flux]`` (pixels; ``(0, 0)`` is the
    centre of the top-left pixel, docs/design.md), an optional header row naming them, brightest
    first — sorted by ``flux`` when the table has it, else in the table's order. Raises
    :class:`~skyfix.errors.InputError` naming the row of a bad value."""
    import numpy as np

    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the centroid table "
                         f"({getattr(exc, 'strerror', None) or exc})") from None
    rows = [r for r in csv.reader(text.splitlines()) if r and any(c.strip() for c in r)]
    if rows and rows[0] and not _is_number(rows[0][0]):
        header = [c.strip().lower() for c in rows.pop(0)]
        if header[:2] != ["x", "y"] or header[2:] not in ([], ["flux"]):
            raise InputError(f"{path}: the centroid table's columns are x,y[,flux], got {','.join(header)}")
    table = []
    for i, row in enumerate(rows, start=1):
        values = [c.strip() for c in row]
        if len(values) not in (2, 3) or not all(_is_number(v) for v in values):
            raise InputError(f"{path}: row {i} is not x,y[,flux] numbers: {','.join(row)!r}")
        table.append([float(v) for v in values] + [math.nan] * (3 - len(values)))
    if not table:
        raise InputError(f"{path}: the centroid table has no rows x,y[,flux]")
    a = np.array(table)
    if not np.all(np.isnan(a[:, 2])):
        if np.any(np.isnan(a[:, 2])):
            raise InputError(f"{path}: give flux on every row or on none")
        a = a[np.argsort(-a[:, 2], kind="stable")]
    return np.ascontiguousarray(a[:, :2])


def _is_number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False
