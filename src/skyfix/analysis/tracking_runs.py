"""The tracking study on the campaign engine (issue 27): a sequence per trial, a Parquet row per
sequence.

:func:`run_study` times the centroiding first (Table 5-1, on an idle machine), then runs the
sequences of :func:`skyfix.analysis.tracking_study.sequence_specs` as the trials of a
:class:`TrackingSequences` study on :func:`skyfix.montecarlo.engine.run_campaign` — in this
process (``workers=0``), on a local Dask cluster, or on a running scheduler — and turns the rows
back into the :class:`~skyfix.analysis.tracking_study.SequenceResult` records the analyses and
:mod:`skyfix.analysis.tracking_report` read.

A trial is a whole sequence (hundreds of frames, each tracked and solved lost in space): the
engine keeps one row per trial (it checks every trial is there exactly once), so a row holds the
sequence's inputs (its :class:`~skyfix.analysis.tracking_study.SequenceSpec`, one column a
field, ``params`` as JSON) and each per-frame series as a list column — ``t_s``, ``event``,
``mode``, ``tracked``, …, an ``(n, 3)`` series as three (``err_track_x``, ``_y``, ``_z``) — and
each predictor's errors (``pred_mekf_meas_px``, …, ``pred_late_*`` for thesis 002's predictor
told wrong times, named in ``late_predictor``). Row and record convert both ways exactly
(:func:`sequence_row`, :func:`sequence_of`), so the tables are those of the records.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from skyfix.analysis.tracking_study import (
    EPOCH,
    FULL,
    PREDICTOR_NAMES,
    PredictionErrors,
    SequenceResult,
    SequenceSpec,
    StudySettings,
    TrackingStudy,
    run_sequence,
    sequence_specs,
)
from skyfix.analysis.window_timing import run_timing
from skyfix.montecarlo.study import BatchedStudy

__all__ = ["COLUMNS", "TrackingSequences", "run_study", "sequence_of", "sequence_row", "study_steps"]

_AXES = "xyz"
#: The per-frame series of a :class:`SequenceResult` and their element type ("xyz": an (n, 3)
#: float series, three columns).
_SERIES = {"t_s": "float64", "event": "string", "mode": "string", "tracked": "bool", "coasting": "bool",
           "n_matched": "int64", "n_visible": "int64", "err_track": "xyz", "sigma_track": "xyz",
           "nees_track": "float64", "err_lis": "xyz", "n_lis": "int64", "time_track_ms": "float64",
           "time_lis_ms": "float64", "rate_dps": "xyz", "accel_dps2": "xyz", "steady_accel": "bool"}
_DTYPES = {"float64": np.float64, "int64": np.int64, "bool": np.bool_}
#: A predictor's per-frame errors (:class:`PredictionErrors`): px, px, and δθ (arcsec) per axis.
_PREDICTION = ("meas_px", "true_px", "att_x", "att_y", "att_z")
#: The predictors' column prefixes: thesis 002's predictor told wrong times is ``late``.
_SLUGS = {**{n: n.replace("-", "_") for n in PREDICTOR_NAMES}, None: "late"}
_SPEC = {"name": "string", "profile": "string", "params": "string", "n_frames": "int64", "fps": "float64",
         "exposure_s": "float64", "ra_deg": "float64", "dec_deg": "float64", "roll_deg": "float64",
         "blank_frame": "int64", "jump_frame": "int64", "seed": "int64", "time_error_s": "float64"}


def _series_columns() -> dict[str, str]:
    out = {}
    for name, kind in _SERIES.items():
        names = [f"{name}_{a}" for a in _AXES] if kind == "xyz" else [name]
        out.update({n: "list<float64>" if kind == "xyz" else f"list<{kind}>" for n in names})
    return out


#: The row of a sequence: its trial, its spec, its per-frame series, its predictors' errors, the
#: frames tracked and its wall time.
COLUMNS: dict[str, str] = {
    "trial": "int64", **_SPEC, **_series_columns(), "late_predictor": "string",
    **{f"pred_{slug}_{e}": "list<float64>" for slug in _SLUGS.values() for e in _PREDICTION},
    "frames_tracked": "int64", "wall_s": "float64"}


def _spec_json(spec: SequenceSpec) -> dict:
    """A spec as plain JSON data (what the study's settings hold)."""
    return json.loads(json.dumps(spec._asdict()))


def _spec_of(data: Mapping[str, Any]) -> SequenceSpec:
    return SequenceSpec(**{**data, "radec_roll_deg": tuple(data["radec_roll_deg"])})


def sequence_row(trial: int, seq: SequenceResult, wall_s: float) -> dict[str, Any]:
    """The Parquet row of trial ``trial``'s sequence (:data:`COLUMNS`)."""
    spec = seq.spec
    row: dict[str, Any] = {"trial": trial, **{k: getattr(spec, k) for k in _SPEC if k in spec._fields},
                           "params": json.dumps(spec.params)}
    row.update(zip(("ra_deg", "dec_deg", "roll_deg"), map(float, spec.radec_roll_deg), strict=True))
    for name, kind in _SERIES.items():
        v = getattr(seq, name)
        if kind == "xyz":
            row.update({f"{name}_{a}": v[:, i].tolist() for i, a in enumerate(_AXES)})
        else:
            row[name] = list(v) if isinstance(v, list) else v.tolist()
    late = [n for n in seq.predictions if n not in PREDICTOR_NAMES]
    if len(late) > 1:
        raise ValueError(f"a sequence has one late predictor at most, got {late}")
    row["late_predictor"] = late[0] if late else None
    for name, slug in _SLUGS.items():
        p = seq.predictions.get(late[0] if name is None and late else name)
        for e in _PREDICTION:
            row[f"pred_{slug}_{e}"] = None if p is None else _prediction_series(p, e).tolist()
    row["frames_tracked"] = int(np.count_nonzero(seq.tracked))
    row["wall_s"] = float(wall_s)
    return row


def _prediction_series(p: PredictionErrors, e: str) -> np.ndarray:
    return p.att_arcsec[:, _AXES.index(e[-1])] if e.startswith("att_") else getattr(p, e)


def sequence_of(row: Mapping[str, Any]) -> SequenceResult:
    """The record of a row of :func:`sequence_row` (every number as it was)."""
    spec = _spec_of({k: row[k] for k in SequenceSpec._fields if k not in ("params", "radec_roll_deg")}
                    | {"params": json.loads(row["params"]),
                       "radec_roll_deg": (row["ra_deg"], row["dec_deg"], row["roll_deg"])})
    rec: dict[str, Any] = {}
    for name, kind in _SERIES.items():
        if kind == "xyz":
            rec[name] = np.stack([np.asarray(row[f"{name}_{a}"], np.float64) for a in _AXES], axis=1)
        elif kind == "string":
            rec[name] = list(row[name])
        else:
            rec[name] = np.asarray(row[name], _DTYPES[kind])
    preds = {}
    for name, slug in _SLUGS.items():
        if name is None:
            name = row["late_predictor"]
        if name is None or row[f"pred_{slug}_meas_px"] is None:
            continue
        a = {e: np.asarray(row[f"pred_{slug}_{e}"], np.float64) for e in _PREDICTION}
        preds[name] = PredictionErrors(a["meas_px"], a["true_px"],
                                       np.stack([a[f"att_{x}"] for x in _AXES], axis=1))
    return SequenceResult(spec=spec, predictions=preds, **rec)


@dataclass(frozen=True)
class TrackingSequences(BatchedStudy):
    """The study's sequences as trials: ``settings["sequences"]`` holds each
    :class:`SequenceSpec` (JSON); trial ``i`` tracks and solves sequence ``i``
    (:func:`run_sequence`: its noise is seeded by the spec alone) into its row."""

    kind: ClassVar[str] = "tracking"
    columns: ClassVar[Mapping[str, str]] = COLUMNS

    @classmethod
    def of(cls, specs: list[SequenceSpec]) -> TrackingSequences:
        """A sequence a batch: a sequence is hundreds of frames, a task's overhead nothing."""
        return cls(trials=len(specs), batch_size=1, settings={"sequences": [_spec_json(s) for s in specs]})

    def spec(self, trial: int) -> SequenceSpec:
        return _spec_of(self.settings["sequences"][trial])

    def run_trial(self, trial: int) -> dict[str, Any]:
        t0 = time.perf_counter()
        seq = run_sequence(self.spec(trial))
        return sequence_row(trial, seq, time.perf_counter() - t0)

    def warm(self) -> None:
        from skyfix import warmup

        warmup.ensure(["solve", "simulate", "track"], missing_ok=True)


def study_steps(settings: StudySettings) -> int:
    """The steps :func:`run_study` reports: the Table 5-1 cells, then the sequences."""
    return len(settings.rois) * len(settings.star_counts) + len(sequence_specs(settings))


def run_study(settings: StudySettings = FULL, progress: Callable[[int, int], None] | None = None, *,
              output: str | Path | None = None, scheduler: str | None = None, client=None) -> TrackingStudy:
    """Time the centroiding (first, on an idle machine), then run every sequence on the campaign
    engine: ``settings.workers`` local worker processes (0: one after another in this process),
    or the Dask scheduler at ``scheduler`` (through ``client`` when given: a client of it). The
    rows go to ``output`` (Parquet; None: a temporary file), replacing a finished run's; a run
    stopped part-way continues from its finished sequences (``output``'s parts folder).
    ``progress(done, total)`` is called after each Table 5-1 cell and each finished sequence
    (:func:`study_steps`)."""
    from skyfix.montecarlo.engine import connect, run_rows

    owned = None
    if scheduler is not None and client is None:  # out of reach: say so before the timing's minute
        client = owned = connect(0, scheduler)[0]
    try:
        total = study_steps(settings)
        cells = iter(range(1, total + 1))
        timing = run_timing(settings.rois, settings.star_counts, settings.timing_repeats, settings.seed,
                            None if progress is None else lambda _what: progress(next(cells), total))
        n_cells = len(settings.rois) * len(settings.star_counts)
        study = TrackingSequences.of(sequence_specs(settings))
        engine_progress = None if progress is None else (lambda done, _n: progress(n_cells + done, total))
        # a finished run's rows are run again (fresh); a stopped one's batches are kept
        rows = run_rows(study, output, workers=int(settings.workers), client=client, fresh=True,
                        progress=engine_progress).to_pylist()
    finally:
        if owned is not None:
            owned.close()
    meta = dict(settings._asdict(), camera="1280×960, 15°", epoch=EPOCH, cpu_count=os.cpu_count())
    if scheduler is not None:
        meta["scheduler"] = scheduler
    return TrackingStudy(sequences=[sequence_of(r) for r in rows], timing=timing, settings=meta)
