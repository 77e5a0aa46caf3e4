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

With ``workers > 1`` the (FOV, condition) blocks run in that many processes
(``concurrent.futures`` with spawned workers, as :mod:`skyfix.analysis.tracking_study` —
Dask is not installed here).

The seeds' experiments (:mod:`skyfix.analysis.identification_cases`) and the safety case
(:mod:`skyfix.analysis.identification_safety`) run as jobs of the same pool when asked
(:func:`run_study`'s ``cases`` and ``safety``); what all three share — frames, conditions, the
judge of a solve, the pool — is :mod:`skyfix.analysis.identification_jobs`.

docs/identification-study.md has a full run's numbers beside the theses'.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from skyfix.analysis._json import strict_json
from skyfix.analysis.identification_cases import CASES
from skyfix.analysis.identification_jobs import (
    CONDITIONS,
    EPOCH,
    HEIGHT,
    MAG_LIMIT,
    WIDTH,
    Condition,
    judge_identification,
    method_names,
    pool_steps,
    run_pool,
    study_field,
    upper_bound_95,
    warm_methods,
)
from skyfix.analysis.identification_safety import (
    SafetySettings,
    run_safety_block,
    safety_job_label,
    safety_jobs,
    safety_json,
    safety_markdown,
    safety_plot,
    safety_result,
    safety_summary,
)
from skyfix.catalog import load_hipparcos
from skyfix.identify import Identification, default_database, default_database_path, identify

__all__ = ["FULL", "QUICK", "StudySettings", "TrialRecord", "cell_summary", "markdown", "plots", "run_block",
           "run_study", "study_steps", "summarize", "write_study"]


class StudySettings(NamedTuple):
    """What :func:`run_study` runs."""

    fovs_deg: tuple[float, ...] = (8.0, 15.0, 30.0)
    conditions: tuple[Condition, ...] = CONDITIONS
    trials: int = 100
    methods: tuple[str, ...] = ()  # empty: every registered method
    seed: int = 0
    workers: int = 1
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


def run_block(fov: float, cond: Condition, trials: range, methods: list[str], seed: int,
              fov_tolerance: float = 0.1) -> list[TrialRecord]:
    """Every method on the fields ``trials`` of one FOV and condition (a worker's job)."""
    catalog = load_hipparcos(epoch=EPOCH, mag_limit=MAG_LIMIT + 1.0)
    db = default_database(progress=False)
    kw = dict(fov_deg=fov, fov_tolerance_deg=fov * fov_tolerance, database=db, epoch=EPOCH)
    records = []
    for t in trials:
        camera, f = study_field(fov, cond, t, seed, catalog)
        n_stars = int(np.sum(f.star_id > 0))
        for m in methods:
            t0 = time.perf_counter()
            try:
                ident = identify(f.xy, WIDTH, HEIGHT, method=m, **kw)
            except Exception as exc:  # a method's bug is its failure here, not the study's end
                ident = Identification(False, f"error: {type(exc).__name__}: {exc}")
            dt = 1e3 * (time.perf_counter() - t0)
            verdict = judge_identification(ident, f.A_icrs_to_cam, camera) if ident.success else None
            wrong, bore = (verdict.wrong, verdict.boresight_arcsec) if verdict else (False, math.nan)
            records.append(TrialRecord(m, fov, cond.name, t, n_stars, bool(ident.success), bool(wrong), bore,
                                       dt, ident.reason))
    return records


def run_study(settings: StudySettings = FULL, progress: Callable[[str], None] | None = None,
              safety: SafetySettings | None = None, cases: tuple[str, ...] = ()) -> dict:
    """Run the grid and, when asked, the safety case (:func:`run_safety`, with ``safety``'s frames,
    seed and bounds; its methods and workers are the grid's) and seed experiments (``cases``,
    names of :data:`CASES` with their defaults), all as jobs of one pool of ``settings.workers``
    processes. Returns ``{"settings", "records", "tables"}`` (records as :class:`TrialRecord`),
    with ``"safety"`` (as :func:`run_safety`'s) and ``"cases"`` (name → result) when run."""
    methods = method_names(settings.methods)
    tables = warm_methods(methods, settings.fovs_deg)  # in this process: the tables' sizes and build times
    path = default_database_path()
    tables["pattern_database"] = {"bytes": int(path.stat().st_size) if path.exists() else 0}
    blocks = [(fov, c) for fov in settings.fovs_deg for c in settings.conditions]
    case_jobs = [(CASES[c],) for c in cases]  # the longest first: they set the pool's end
    grid_jobs = [(run_block, fov, c, range(settings.trials), methods, settings.seed, settings.fov_tolerance)
                 for fov, c in blocks]
    safety_part = [] if safety is None else safety_jobs(safety, methods)
    warm_fovs = tuple(sorted(set(settings.fovs_deg) | set(() if safety is None else safety.mix.fovs_deg)))
    cameras = bool(case_jobs) or (safety is not None and safety.mix.camera_given_share > 0)
    parts = run_pool(case_jobs + grid_jobs + safety_part, settings.workers, methods, warm_fovs, progress,
                     _job_label, cameras=cameras)
    records: list[TrialRecord] = [r for part in parts[len(case_jobs):len(case_jobs) + len(grid_jobs)]
                                  for r in part]
    order = {(fov, c.name): i for i, (fov, c) in enumerate(blocks)}
    records.sort(key=lambda r: (order[(r.fov_deg, r.condition)], r.trial, methods.index(r.method)))
    meta = dict(settings._asdict(), conditions=[c._asdict() for c in settings.conditions], methods=methods,
                camera=f"{WIDTH}×{HEIGHT}", mag_limit=MAG_LIMIT, epoch=EPOCH, cpu_count=os.cpu_count())
    study = {"settings": meta, "records": records, "tables": tables}
    if safety is not None:
        study["safety"] = safety_result(safety._replace(methods=tuple(methods), workers=settings.workers),
                                        methods, parts[len(case_jobs) + len(grid_jobs):])
    if cases:
        study["cases"] = dict(zip(cases, parts[:len(case_jobs)], strict=True))
    return study


def study_steps(settings: StudySettings, safety: SafetySettings | None = None, cases: tuple[str, ...] = ()
                ) -> int:
    """How many progress steps :func:`run_study` reports with these arguments."""
    n_jobs = (len(settings.fovs_deg) * len(settings.conditions) + len(cases)
              + (len(safety_jobs(safety, [])) if safety is not None else 0))
    return pool_steps(n_jobs, settings.workers)


def _job_label(job: tuple) -> str:
    """What a job of :func:`run_study`'s pool did, for the progress bar."""
    fn = job[0]
    if fn is run_block:
        return f"{job[1]:g}° {job[2].name}"
    if fn is run_safety_block:
        return safety_job_label(job)
    return next((name for name, f in CASES.items() if f is fn), getattr(fn, "__name__", "case"))


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
