"""One record per input of ``skyfix solve``: :func:`solve_input` solves one input (an image, or
a centroid table), writes its outputs (``--wcs``, ``--plot``, ``--save-camera``) and returns its
record — the JSON line's fields — whatever happened: ``"solved"``, ``"failed"`` (the solver was
unsure; ``reason`` says why) or ``"error"`` (the input could not be read or solved; ``reason`` is
the one-line error). It never raises for a bad input, so a batch (in a loop, or mapped over
workers) prints one record per input in input order. The fields are documented in
docs/design.md#the-solution.

Imports of what a solve runs sit inside the functions: this module is loaded at every
``skyfix solve`` start (tests/cli/test_cli_start.py keeps ``-h`` light).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

from skyfix.cli.common import input_error_line

__all__ = ["CentroidTable", "InputOutputs", "Outcome", "error_record", "records_table", "solve_input",
           "write_parquet"]


class InputOutputs(NamedTuple):
    """The files one input writes (None: not asked for)."""

    wcs: Path | None = None
    plot: Path | None = None
    camera: Path | None = None


class CentroidTable(NamedTuple):
    """An input that is a table of centroids, not an image: ``skyfix solve --centroids FILE.csv
    --size W,H`` (:func:`skyfix.cli.inputs.read_centroid_table`)."""

    path: Path
    width: int
    height: int


class Outcome(NamedTuple):
    """One input's record (the JSON line), and its Solution (None when ``status`` is ``"error"``)."""

    record: dict
    solution: Any


def error_record(image: str | Path, reason: str) -> dict:
    """The record of an input that could not be read or solved: ``image``, ``status: "error"``
    and the one-line ``reason`` (docs/design.md#the-solution)."""
    return {"image": str(image), "status": "error", "reason": reason}


def solve_input(source: Path | CentroidTable, outputs: InputOutputs, options: dict) -> Outcome:
    """Solve one input with the keywords ``options`` of :func:`skyfix.pipeline.solve` (an image)
    or :func:`skyfix.pipeline.solve_centroids` (a :class:`CentroidTable`), write its outputs, and
    return its :class:`Outcome`. Errors become an ``"error"`` record, never an exception."""
    path = source.path if isinstance(source, CentroidTable) else source
    try:
        sol = _solve(source, options)
        _write_outputs(sol, source, outputs)
    except Exception as exc:  # this input's record says what went wrong; the batch goes on
        reason = input_error_line(exc, path)
        return Outcome(error_record(path, reason.removeprefix(f"{path}: ")), None)
    return Outcome(sol.to_dict(), sol)


def _solve(source: Path | CentroidTable, options: dict) -> Any:
    from skyfix import pipeline

    if isinstance(source, CentroidTable):
        from skyfix.cli.inputs import read_centroid_table

        xy = read_centroid_table(source.path)
        return pipeline.solve_centroids(xy, source.width, source.height, name=str(source.path), **options)
    return pipeline.solve(source, **options)


def _write_outputs(sol: Any, source: Path | CentroidTable, outputs: InputOutputs) -> None:
    if sol.solved and outputs.wcs is not None:
        from skyfix.wcs import write_wcs

        # against the catalogue places, as a WCS is read (docs/time-and-corrections.md)
        write_wcs(outputs.wcs, sol.A_apparent_to_cam, sol.camera, mirrored=sol.mirrored)
    if sol.solved and outputs.camera is not None:
        sol.frame_camera.save(outputs.camera)
    if outputs.plot is not None and not isinstance(source, CentroidTable):
        from skyfix.io import read_image
        from skyfix.plot import plot_solution

        plot_solution(read_image(source), sol, outputs.plot)


def records_table(records: list[dict]):
    """The records as one ``pyarrow.Table``, a row per record in order: a field whose values are
    all numbers (or all booleans, or all text) is a column of that type; any other (the lists
    and tables: quaternion, covariance, matches, …) is a column of JSON text. A field a record
    lacks (an error's) is null there. The columns are in the order the fields first appear."""
    import json
    import math

    import pyarrow as pa

    names: dict[str, None] = {}
    for r in records:
        names.update(dict.fromkeys(r))
    columns = {}
    for name in names:
        values = [r.get(name) for r in records]
        present = [v for v in values if v is not None]
        if present and all(isinstance(v, bool) for v in present):
            kind = pa.bool_()
        elif present and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in present):
            kind = pa.int64() if all(isinstance(v, int) for v in present) else pa.float64()
            values = [None if v is None or (isinstance(v, float) and not math.isfinite(v)) else v
                      for v in values]
        elif all(isinstance(v, str) for v in present):
            kind = pa.string()
        else:
            kind = pa.string()
            values = [None if v is None else json.dumps(v, separators=(",", ":")) for v in values]
        columns[name] = pa.array(values, type=kind)
    return pa.table(columns)


def write_parquet(records: list[dict], path: Path) -> None:
    """:func:`records_table` written to ``path`` (Parquet, by pyarrow)."""
    import pyarrow.parquet as pq

    pq.write_table(records_table(records), str(path))
