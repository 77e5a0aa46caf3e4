"""The identification study: every registered method on the same simulated centroid sets
(issue 11 item 5), and the seeds' identification experiments as named cases.

**The grid** (:func:`run_study`). For each field of view (8°, 15°, 30° on a 1280 × 960 sensor)
and each condition (:class:`Condition`: centroid noise 0–2 px, 0–10 false stars, 0–20 %
dropped stars, magnitude noise 0–0.5 mag, and all together), ``trials`` random attitudes give
one set of centroids each (:func:`skyfix.analysis.synthetic_centroids.synthetic_centroids`,
Hipparcos to Hp 6.5, seeded by FOV, condition and trial), and *every* method of
:data:`skyfix.identify.METHODS` (aliases of one function run once) identifies the same set with
the field of view known to 10 % — interleaved field by field, so the machine's load falls on all
alike. A trial is **wrong** when it is reported solved and its boresight is more than
max(60″, 1 px) or its roll more than 0.5° from the truth
(:func:`skyfix.analysis.truth.is_wrong`); each cell's wrong rate carries its one-sided
95 % Clopper–Pearson upper bound (:func:`upper_bound_95`: 3/n, the rule of three, with none
wrong). Times are wall-clock per call (median, p99) after two warm-up calls per method and
FOV; each method's own tables (what it builds beside the shared pattern database) are sized and
timed as those first calls build them.

The grid is a study on the campaign engine (:class:`GridStudy`,
:func:`skyfix.montecarlo.engine.run_campaign`): a trial is one method on one field, a pure
function of the settings and the trial's number (the field seeded by FOV, condition and field
number as always), a row of ``identification_study.parquet``. ``workers=0`` runs its batches in
this process; ``workers=N`` on a local Dask cluster of N processes, ``scheduler`` on a running
one — each worker warmed once (:func:`~skyfix.analysis.identification_jobs.warm_once`) before its
first batch; the rows are the same whichever runs them.

The seeds' experiments (:mod:`skyfix.analysis.identification_cases`, :class:`CaseStudy`) and the
safety case (:mod:`skyfix.analysis.identification_safety`, :class:`SafetyStudy`) run on the same
cluster when asked (:func:`run_study`'s ``cases`` and ``safety``); what all three share — frames,
conditions, the judge of a solve, the warm-up, the engine — is
:mod:`skyfix.analysis.identification_jobs`.

docs/identification-study.md has a full run's numbers beside the theses'.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from skyfix.analysis._json import strict_json
from skyfix.analysis.identification_cases import case_results, case_study
from skyfix.analysis.identification_jobs import (
    CONDITIONS,
    EPOCH,
    HEIGHT,
    MAG_LIMIT,
    WIDTH,
    Condition,
    MethodTrials,
    judge_identification,
    method_names,
    record_columns,
    study_field,
    upper_bound_95,
    warm_methods,
)
from skyfix.analysis.identification_safety import (
    SafetySettings,
    safety_json,
    safety_markdown,
    safety_plot,
    safety_records,
    safety_result,
    safety_study,
    safety_summary,
)
from skyfix.catalog import load_hipparcos
from skyfix.identify import Identification, default_database, default_database_path, identify
from skyfix.montecarlo.engine import cluster, run_rows

__all__ = ["FIELDS_PER_BATCH", "FULL", "QUICK", "GridStudy", "StudySettings", "TrialRecord",
           "cell_summary", "field_trials", "grid_study", "markdown", "plots", "run_block", "run_study",
           "summarize", "write_study"]


class StudySettings(NamedTuple):
    """What :func:`run_study` runs."""

    fovs_deg: tuple[float, ...] = (8.0, 15.0, 30.0)
    conditions: tuple[Condition, ...] = CONDITIONS
    trials: int = 100
    methods: tuple[str, ...] = ()  # empty: every registered method
    seed: int = 0
    workers: int = 0  # 0: in this process; N: a local Dask cluster of N worker processes
    fov_tolerance: float = 0.1  # the FOV the methods are told, relative


FULL = StudySettings()
QUICK = StudySettings(fovs_deg=(15.0,), conditions=(CONDITIONS[0], CONDITIONS[-1]), trials=20)


class TrialRecord(NamedTuple):
    """One method on one simulated frame."""

    method: str
    fov_deg: float
    condition: str
    trial: int
    n_stars: int  # catalogue stars among the centroids
    solved: bool
    wrong: bool
    boresight_arcsec: float  # NaN when not solved
    time_ms: float
    reason: str


def field_trials(fov: float, cond: Condition, trial: int, methods: list[str], seed: int, fov_tolerance: float,
                 catalog, database) -> list[TrialRecord]:
    """Every method in ``methods`` on field ``trial`` of one FOV and condition."""
    camera, f = study_field(fov, cond, trial, seed, catalog)
    n_stars = int(np.sum(f.star_id > 0))
    kw = dict(fov_deg=fov, fov_tolerance_deg=fov * fov_tolerance, database=database, epoch=EPOCH)
    records = []
    for m in methods:
        t0 = time.perf_counter()
        try:
            ident = identify(f.xy, WIDTH, HEIGHT, method=m, **kw)
        except Exception as exc:  # a method's bug is its failure here, not the study's end
            ident = Identification(False, f"error: {type(exc).__name__}: {exc}")
        dt = 1e3 * (time.perf_counter() - t0)
        verdict = judge_identification(ident, f.A_icrs_to_cam, camera) if ident.success else None
        wrong, bore = (verdict.wrong, verdict.boresight_arcsec) if verdict else (False, math.nan)
        records.append(TrialRecord(m, fov, cond.name, trial, n_stars, bool(ident.success), bool(wrong), bore,
                                   dt, ident.reason))
    return records


def _grid_context() -> tuple:
    return load_hipparcos(epoch=EPOCH, mag_limit=MAG_LIMIT + 1.0), default_database(progress=False)


def run_block(fov: float, cond: Condition, trials: range, methods: list[str], seed: int,
              fov_tolerance: float = 0.1) -> list[TrialRecord]:
    """Every method on the fields ``trials`` of one FOV and condition (to replay a cell's fields)."""
    catalog, db = _grid_context()
    return [r for t in trials for r in field_trials(fov, cond, t, methods, seed, fov_tolerance, catalog, db)]


FIELDS_PER_BATCH = 2
"""Fields per engine batch, each solved by every method: ~0.75 CPU-s for the nine methods on
average (the full grid, 2700 fields, took ~17 min of CPU), 0.1 s at 30° to ~7 s at 8° under load 6."""


@dataclass(frozen=True)
class GridStudy(MethodTrials):
    """The grid on the campaign engine: field ``k`` is field ``k % fields`` of the (FOV, condition)
    block ``k // fields`` (FOVs outer, conditions inner), each solved by every method (a row each:
    :class:`TrialRecord`, its field's number the column ``field``). Build it with :func:`grid_study`."""

    kind = "identification-grid"
    record = TrialRecord
    number = "field"
    columns = record_columns(TrialRecord, "field")

    def context(self) -> Any:
        return _grid_context()

    def solve_frame(self, context: Any, frame: int, methods: list[str]) -> list[TrialRecord]:
        s = self.settings
        fov, cond = s["blocks"][frame // s["fields"]]
        return field_trials(fov, Condition(**cond), frame % s["fields"], methods, s["seed"],
                            s["fov_tolerance"], *context)

    def warm_args(self) -> tuple[list[str], tuple[float, ...], bool]:
        return self.methods, tuple(sorted({fov for fov, _ in self.settings["blocks"]})), False


def grid_study(settings: StudySettings, methods: list[str]) -> GridStudy:
    """The grid of ``settings`` (its workers aside) as a study: ``methods`` on ``settings.trials``
    fields per FOV and condition."""
    blocks = [[float(fov), c._asdict()] for fov in settings.fovs_deg for c in settings.conditions]
    return GridStudy(len(blocks) * settings.trials * len(methods), FIELDS_PER_BATCH * len(methods),
                     {"methods": list(methods), "blocks": blocks, "fields": settings.trials,
                      "seed": settings.seed, "fov_tolerance": settings.fov_tolerance})


def run_study(settings: StudySettings = FULL, progress: Callable[[str, int, int], None] | None = None,
              safety: SafetySettings | None = None, cases: tuple[str, ...] = (), *,
              out: str | Path | None = None, scheduler: str | None = None) -> dict:
    """Run the grid and, when asked, the safety case (:func:`run_safety`, with ``safety``'s frames,
    seed and bounds; its methods are the grid's) and seed experiments (``cases``, names of
    :data:`CASES` with their defaults), each a study on the campaign engine, all on one cluster
    (``settings.workers`` local processes, or ``scheduler``; 0 and none: in this process).
    ``out``: the folder for their rows (``identification_study.parquet``,
    ``identification_safety.parquet``, ``identification_cases.parquet``; None: temporary files);
    when a stopped run left finished batches there (``NAME.parquet.parts``), the run continues —
    its studies already finished kept — else every study runs afresh.
    ``progress(stage, done, total)``: the batches of each stage finished. Returns
    ``{"settings", "records", "tables"}`` (records as :class:`TrialRecord`), with ``"safety"``
    (as :func:`run_safety`'s) and ``"cases"`` (name → result) when run."""
    from skyfix.montecarlo.engine import parts_folder

    methods = method_names(settings.methods)
    folder = None if out is None else Path(out)
    names = ["study", *(["safety"] if safety is not None else []), *(["cases"] if cases else [])]
    fresh = folder is None or not any(parts_folder(folder / f"identification_{n}.parquet").exists()
                                      for n in names)

    def stage(name: str) -> Callable[[int, int], None] | None:
        return None if progress is None else (lambda done, total: progress(name, done, total))

    def output(name: str) -> Path | None:
        return None if folder is None else folder / name

    with cluster(settings.workers, scheduler) as client:
        tables = warm_methods(methods, settings.fovs_deg)  # here: the tables' sizes and build times
        path = default_database_path()
        tables["pattern_database"] = {"bytes": int(path.stat().st_size) if path.exists() else 0}
        grid = grid_study(settings, methods)
        records = GridStudy.records(run_rows(grid, output("identification_study.parquet"), client=client,
                                             progress=stage("identification grid"), fresh=fresh))
        meta = dict(settings._asdict(), conditions=[c._asdict() for c in settings.conditions],
                    methods=methods, camera=f"{WIDTH}×{HEIGHT}", mag_limit=MAG_LIMIT, epoch=EPOCH,
                    cpu_count=os.cpu_count())
        study = {"settings": meta, "records": records, "tables": tables}
        if safety is not None:
            run = safety._replace(methods=tuple(methods), workers=settings.workers)
            table = run_rows(safety_study(run, methods), output("identification_safety.parquet"),
                             client=client, progress=stage("safety frames"), fresh=fresh)
            study["safety"] = safety_result(run, methods, safety_records(table))
        if cases:
            table = run_rows(case_study(cases), output("identification_cases.parquet"), client=client,
                             progress=stage("seed experiments"), fresh=fresh)
            study["cases"] = case_results(table)
    return study


def cell_summary(records: list[TrialRecord]) -> dict:
    """Solved, wrong (with its 95 % upper bound), solved among fields with ≥ 5 stars, median and
    p99 time, median boresight error of one method's trials in one cell."""
    n = len(records)
    solved = sum(r.solved for r in records)
    wrong = sum(r.wrong for r in records)
    rich = [r for r in records if r.n_stars >= 5]
    t = np.array([r.time_ms for r in records]) if records else np.array([np.nan])
    bore = [r.boresight_arcsec for r in records if r.solved and not r.wrong]
    return {"n": n, "solved": solved, "wrong": wrong, "solved_pct": 100.0 * solved / max(n, 1),
            "wrong_pct": 100.0 * wrong / max(n, 1), "wrong_upper95_pct": 100.0 * upper_bound_95(wrong, n),
            "n_rich": len(rich), "solved_rich_pct": 100.0 * sum(r.solved for r in rich) / max(len(rich), 1),
            "median_ms": float(np.median(t)), "p99_ms": float(np.percentile(t, 99)),
            "median_boresight_arcsec": float(np.median(bore)) if bore else math.nan}


def summarize(study: dict) -> dict:
    """Per method: per (FOV, condition) cell and over all trials."""
    recs: list[TrialRecord] = study["records"]
    out: dict[str, dict] = {}
    for m in study["settings"]["methods"]:
        mine = [r for r in recs if r.method == m]
        cells = {}
        for fov in study["settings"]["fovs_deg"]:
            for c in study["settings"]["conditions"]:
                cells[f"{fov:g}° {c['name']}"] = cell_summary(
                    [r for r in mine if r.fov_deg == fov and r.condition == c["name"]])
        out[m] = {"all": cell_summary(mine), "cells": cells}
    return out


def markdown(study: dict, summary: dict, command: str) -> str:
    """The study's tables in Markdown."""
    s = study["settings"]
    methods = s["methods"]
    lines = [f"# Identification study\n\n`{command}` — {s['trials']} fields per cell, {s['camera']} sensor, "
             f"Hipparcos to Hp {s['mag_limit']}, FOV told to ±{100 * s['fov_tolerance']:.0f} %, "
             f"seed {s['seed']}.\n",
             "## Over all cells\n",
             "| method | trials | solved % | solved % (≥ 5 stars) | wrong | wrong ≤ (95 %) | median ms "
             "| p99 ms | median boresight ″ | own tables MB | build s |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    tables = study.get("tables", {})
    for m in methods:
        a = summary[m]["all"]
        tb = tables.get(m, {})
        lines.append(f"| {m} | {a['n']} | {a['solved_pct']:.1f} | {a['solved_rich_pct']:.1f} | "
                     f"{a['wrong']} | {a['wrong_upper95_pct']:.2f} % | {a['median_ms']:.2f} | "
                     f"{a['p99_ms']:.1f} | "
                     f"{a['median_boresight_arcsec']:.1f} | {tb.get('bytes', 0) / 1e6:.1f} | "
                     f"{tb.get('build_s', math.nan):.2f} |")
    if "pattern_database" in tables:
        lines.append(f"\nShared pattern database (the 4-star hash's table and every method's verification "
                     f"stars): {tables['pattern_database']['bytes'] / 1e6:.1f} MB on disk.\n")
    lines += ["## Solved % per cell (wrong in brackets when any)\n",
              "| FOV, condition | " + " | ".join(methods) + " |", "|---|" + "---|" * len(methods)]
    for cell in summary[methods[0]]["cells"]:
        row = []
        for m in methods:
            c = summary[m]["cells"][cell]
            row.append(f"{c['solved_pct']:.0f}" + (f" ({c['wrong']})" if c["wrong"] else ""))
        lines.append(f"| {cell} | " + " | ".join(row) + " |")
    lines += ["\n## Median / p99 time per FOV (ms), noise-free\n",
              "| FOV | " + " | ".join(methods) + " |", "|---|" + "---|" * len(methods)]
    for fov in s["fovs_deg"]:
        cell = f"{fov:g}° {s['conditions'][0]['name']}"
        lines.append(f"| {fov:g}° | " + " | ".join(
            f"{summary[m]['cells'][cell]['median_ms']:.1f} / {summary[m]['cells'][cell]['p99_ms']:.0f}"
            for m in methods) + " |")
    return "\n".join(lines) + "\n"


def plots(study: dict, summary: dict, out: Path) -> list[Path]:
    """solved.png (solved % per condition and method, a panel per FOV), time.png (median and p99
    per method)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = study["settings"]["methods"]
    fovs = study["settings"]["fovs_deg"]
    conds = [c["name"] for c in study["settings"]["conditions"]]
    fig, axes = plt.subplots(len(fovs), 1, figsize=(max(8, 1.1 * len(conds)), 2.6 * len(fovs) + 1.2), dpi=100,
                             sharex=True, squeeze=False)
    width = 0.8 / len(methods)
    for ax, fov in zip(axes[:, 0], fovs, strict=True):
        for i, m in enumerate(methods):
            y = [summary[m]["cells"][f"{fov:g}° {c}"]["solved_pct"] for c in conds]
            ax.bar(np.arange(len(conds)) + i * width, y, width, label=m)
        ax.set_ylim(0, 105)
        ax.set_ylabel(f"{fov:g}°: solved %")
    ax = axes[-1, 0]
    ax.set_xticks(np.arange(len(conds)) + 0.4 - width / 2)
    ax.set_xticklabels(conds, rotation=30, ha="right", fontsize=7)
    axes[0, 0].legend(fontsize=7, ncol=len(methods), loc="lower center", bbox_to_anchor=(0.5, 1.02))
    fig.tight_layout()
    p1 = out / "solved.png"
    fig.savefig(p1)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(7, 4), dpi=100)
    x = np.arange(len(methods))
    ax.bar(x - 0.2, [summary[m]["all"]["median_ms"] for m in methods], 0.4, label="median")
    ax.bar(x + 0.2, [summary[m]["all"]["p99_ms"] for m in methods], 0.4, label="p99")
    ax.set_yscale("log")
    ax.set_xticks(x)
    ax.set_xticklabels(methods, rotation=30, ha="right")
    ax.set_ylabel("time per frame, ms")
    ax.legend()
    fig.tight_layout()
    p2 = out / "time.png"
    fig.savefig(p2)
    plt.close(fig)
    return [p1, p2]


def write_study(study: dict, out_dir: str | Path, command: str = "skyfix analyze identification"
                ) -> list[Path]:
    """Write ``identification_study.json`` (every trial), ``identification_study.md`` and the plots
    (with ``study["safety"]`` from :func:`run_safety`: its table, its records and safety.png too)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary = summarize(study)
    doc = {"settings": study["settings"], "tables": study["tables"], "summary": summary,
           "cases": study.get("cases", {}), "records": [r._asdict() for r in study["records"]]}
    text = markdown(study, summary, command)
    extra = []
    if study.get("safety"):
        safe = safety_summary(study["safety"]["records"])
        doc["safety"] = safety_json(study["safety"], safe)
        text += "\n" + safety_markdown(study["safety"], safe, command)
        extra.append(safety_plot(safe, out))
    pj = out / "identification_study.json"
    pj.write_text(json.dumps(strict_json(doc)))
    pm = out / "identification_study.md"
    pm.write_text(text)
    return [pj, pm, *plots(study, summary, out), *extra]
