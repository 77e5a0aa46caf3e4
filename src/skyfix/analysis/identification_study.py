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
(:func:`skyfix.analysis.blind_campaign.is_wrong`); each cell's wrong rate carries its one-sided
95 % Clopper–Pearson upper bound (:func:`upper_bound_95`: 3/n, the rule of three, with none
wrong). Times are wall-clock per call (median, p99) after two warm-up calls per method and
FOV; each method's own tables (what it builds beside the shared pattern database) are sized and
timed as those first calls build them.

With ``workers > 1`` the (FOV, condition) blocks run in that many processes
(``concurrent.futures`` with spawned workers, as :mod:`skyfix.analysis.tracking_study` —
Dask is not installed here).

**The cases** (:data:`CASES`, ``skyfix analyze identification --case NAME``):

- ``quest-catalogue`` — thesis 000 §6.1.3: every 3-star cluster of the catalogue fed to QUEST
  as both image and reference (:func:`quest_catalogue`), and the same clusters as 3-star
  frames through identification (:func:`three_star_frames`);
- ``table-3-7`` — thesis 004 Table 3-7: 1000 attitudes per tolerance row inside the Table 3-5
  envelope, the Sunsat camera, the ≤ 8 brightest stars, van Bezooijen's match groups on a
  database of the envelope's sub-catalogue (:func:`table_3_7`);
- ``sparse-fields`` — issue 11's 3-star fields: 30° frames that detect exactly their three
  brightest stars, noise-free (:func:`sparse_fields`);
- ``perturbation`` — thesis 000 Table 6 and §6.4: one star of a catalogue cluster moved along
  x by a growing shift, the fraction still identified right (:func:`perturbation_sweep`).

**The safety case** (:func:`run_safety`, ``--case safety``; in the full run beside the grid):
issue 11's "no method reports a wrong attitude in ≥ 10⁴ noisy trials". Each frame draws the
study's axes at random (:func:`safety_draw`: FOV, centroid noise, false stars, dropped stars,
magnitude noise, camera given or FOV only; a share of frames holding only their 3, or 4–5,
brightest stars) and every method solves it as a user would, through
:func:`skyfix.pipeline.solve_centroids` (:func:`safety_trial`); a solve is wrong when its
boresight is more than 60″ or its roll more than 0.5° from the truth — at any pixel scale.
Every frame is a function of (seed, frame number), so a wrong one is replayed by
:func:`replay_safety`.

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
from skyfix.analysis.blind_campaign import attitude_error_rad, is_wrong
from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
from skyfix.camera import Camera

__all__ = ["CASES", "Condition", "FULL", "QUICK", "SAFETY_BOUNDS", "SAFETY_FULL", "SAFETY_MIX",
           "SAFETY_QUICK", "SAFETY_STUDY", "SafetyDraw", "SafetyMix", "SafetySettings", "SafetyTrial",
           "StudySettings",
           "TrialRecord", "cell_summary", "method_names", "perturbation_sweep", "quest_catalogue",
           "replay_safety", "run_block", "run_safety", "run_safety_block", "run_study", "safety_draw",
           "safety_field", "safety_summary", "safety_trial", "sparse_fields", "summarize", "table_3_7",
           "read_checkpoint", "three_star_frames", "upper_bound_95", "write_safety", "write_study"]

EPOCH = 2025.0
WIDTH, HEIGHT = 1280, 960
MAG_LIMIT = 6.5
_ARCSEC = math.pi / (180.0 * 3600.0)


class Condition(NamedTuple):
    """How a simulated frame departs from the truth."""

    name: str
    sigma_px: float = 0.0
    n_false: int = 0
    dropout: float = 0.0
    mag_sigma: float = 0.0


CONDITIONS = (
    Condition("noise-free"),
    Condition("σ 0.5 px", sigma_px=0.5),
    Condition("σ 1 px", sigma_px=1.0),
    Condition("σ 2 px", sigma_px=2.0),
    Condition("3 false stars", n_false=3),
    Condition("10 false stars", n_false=10),
    Condition("20 % dropped", dropout=0.2),
    Condition("0.5 mag noise", mag_sigma=0.5),
    Condition("all: σ 1 px, 5 false, 10 % dropped, 0.3 mag", 1.0, 5, 0.1, 0.3),
)


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


def method_names(methods: tuple[str, ...] | list[str] = ()) -> list[str]:
    """The methods to run: those named (checked), or every registered one; a name that is an
    alias of an earlier one's function (``hash`` of ``quad-hash``) is run once."""
    from skyfix.identify import METHODS, get_method

    names = [m.strip().lower() for m in methods if m.strip()] or list(METHODS)
    seen: dict[int, str] = {}
    out = []
    for m in names:
        fn = get_method(m)  # InputError for an unknown name
        if id(fn) not in seen:
            seen[id(fn)] = m
            out.append(m)
    return out


def upper_bound_95(k: int, n: int) -> float:
    """One-sided 95 % Clopper–Pearson upper bound of a rate seen ``k`` times in ``n`` (with
    ``k = 0``: 1 − 0.05^(1/n) ≈ 3/n, the rule of three)."""
    from scipy.stats import beta

    if n <= 0:
        return 1.0
    return 1.0 if k >= n else float(beta.ppf(0.95, k + 1, n - k))


def _field(fov: float, cond: Condition, trial: int, seed: int, catalog):
    rng = np.random.default_rng([seed, int(round(fov * 100)), _cond_key(cond), trial])
    camera = Camera.from_fov(WIDTH, HEIGHT, fov)
    A = random_attitudes(1, rng)[0]
    f = synthetic_centroids(camera, A, catalog, mag_limit=MAG_LIMIT, sigma_px=cond.sigma_px,
                            n_false=cond.n_false, dropout=cond.dropout, mag_sigma=cond.mag_sigma, rng=rng)
    return camera, f


def _cond_key(cond: Condition) -> int:
    return int(round(cond.sigma_px * 100)) * 10**7 + cond.n_false * 10**5 + int(round(
        cond.dropout * 100)) * 10**3 + int(round(cond.mag_sigma * 100))


def _judge(ident, A_true: np.ndarray, camera: Camera) -> tuple[bool, float]:
    """(wrong, boresight error ″) of a solved identification."""
    err = attitude_error_rad(ident.A_icrs_to_cam, ident.camera or camera, A_true, camera)
    return is_wrong(err, math.degrees(camera.plate_scale_rad) * 3600.0), math.hypot(err[0], err[1]) / _ARCSEC


def run_block(fov: float, cond: Condition, trials: range, methods: list[str], seed: int,
              fov_tolerance: float = 0.1) -> list[TrialRecord]:
    """Every method on the fields ``trials`` of one FOV and condition (a worker's job)."""
    from skyfix.catalog import load_hipparcos
    from skyfix.identify import Identification, default_database, identify

    catalog = load_hipparcos(epoch=EPOCH, mag_limit=MAG_LIMIT + 1.0)
    db = default_database(progress=False)
    kw = dict(fov_deg=fov, fov_tolerance_deg=fov * fov_tolerance, database=db, epoch=EPOCH)
    records = []
    for t in trials:
        camera, f = _field(fov, cond, t, seed, catalog)
        n_stars = int(np.sum(f.star_id > 0))
        for m in methods:
            t0 = time.perf_counter()
            try:
                ident = identify(f.xy, WIDTH, HEIGHT, method=m, **kw)
            except Exception as exc:  # a method's bug is its failure here, not the study's end
                ident = Identification(False, f"error: {type(exc).__name__}: {exc}")
            dt = 1e3 * (time.perf_counter() - t0)
            wrong, bore = _judge(ident, f.A_icrs_to_cam, camera) if ident.success else (False, math.nan)
            records.append(TrialRecord(m, fov, cond.name, t, n_stars, bool(ident.success), bool(wrong), bore,
                                       dt, ident.reason))
    return records


def _warm(methods: list[str], fovs_deg: tuple[float, ...] = (8.0, 15.0, 30.0), cameras: bool = False
          ) -> dict[str, dict]:
    """Two calls per method and FOV outside the clock (the first builds the method's tables
    beside the shared database and loads its compiled kernels). Returns per method the bytes of
    the tables it added to the database (:meth:`~skyfix.identify.PatternDatabase.derived`) and
    its first calls' time beyond the second's (the build). With ``cameras``, then one call per
    method and FOV with the camera given (the tables a calibrated camera's search builds), not
    counted."""
    from skyfix.catalog import load_hipparcos
    from skyfix.identify import default_database, identify

    catalog = load_hipparcos(epoch=EPOCH, mag_limit=MAG_LIMIT + 1.0)
    db = default_database(progress=False)
    fields = [(fov, _field(fov, CONDITIONS[0], 10**6 + 1, 12345, catalog)[1]) for fov in fovs_deg]
    out = {}
    for m in methods:
        before = set(db.__dict__.get("_derived", {}))
        build = 0.0
        for fov, f in fields:
            for k in range(2):
                t0 = time.perf_counter()
                identify(f.xy, WIDTH, HEIGHT, method=m, fov_deg=fov, fov_tolerance_deg=0.1 * fov, database=db,
                         epoch=EPOCH)
                build += (1 if k == 0 else -1) * (time.perf_counter() - t0)
        derived = db.__dict__.get("_derived", {})
        added = [v for key, v in derived.items() if key not in before]
        out[m] = {"bytes": _nbytes(added), "tables": len(added), "build_s": max(build, 0.0)}
    for m in methods if cameras else ():
        for fov, f in fields:
            identify(f.xy, WIDTH, HEIGHT, method=m, camera=Camera.from_fov(WIDTH, HEIGHT, fov), database=db,
                     epoch=EPOCH)
    return out


def _nbytes(value, seen: set | None = None) -> int:
    """Bytes of the numpy arrays in a (nested) table."""
    seen = set() if seen is None else seen
    if id(value) in seen:
        return 0
    seen.add(id(value))
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if isinstance(value, dict):
        return sum(_nbytes(v, seen) for v in value.values())
    if isinstance(value, (list, tuple)):
        return sum(_nbytes(v, seen) for v in value)
    if hasattr(value, "__dict__"):
        return sum(_nbytes(v, seen) for v in vars(value).values())
    return 0


def run_study(settings: StudySettings = FULL, progress: Callable[[str], None] | None = None,
              safety: SafetySettings | None = None, cases: tuple[str, ...] = ()) -> dict:
    """Run the grid and, when asked, the safety case (:func:`run_safety`, with ``safety``'s frames,
    seed and bounds; its methods and workers are the grid's) and seed experiments (``cases``,
    names of :data:`CASES` with their defaults), all as jobs of one pool of ``settings.workers``
    processes. Returns ``{"settings", "records", "tables"}`` (records as :class:`TrialRecord`),
    with ``"safety"`` (as :func:`run_safety`'s) and ``"cases"`` (name → result) when run."""
    from skyfix.identify import default_database_path

    methods = method_names(settings.methods)
    tables = _warm(methods, settings.fovs_deg)  # in this process: the tables' sizes and build times
    path = default_database_path()
    tables["pattern_database"] = {"bytes": int(path.stat().st_size) if path.exists() else 0}
    blocks = [(fov, c) for fov in settings.fovs_deg for c in settings.conditions]
    case_jobs = [(CASES[c],) for c in cases]  # the longest first: they set the pool's end
    grid_jobs = [(run_block, fov, c, range(settings.trials), methods, settings.seed, settings.fov_tolerance)
                 for fov, c in blocks]
    safety_jobs = [] if safety is None else _safety_jobs(safety, methods)
    warm_fovs = tuple(sorted(set(settings.fovs_deg) | set(() if safety is None else safety.mix.fovs_deg)))
    parts = _pool(case_jobs + grid_jobs + safety_jobs, settings.workers, methods, warm_fovs, progress,
                  _job_label)
    records: list[TrialRecord] = [r for part in parts[len(case_jobs):len(case_jobs) + len(grid_jobs)]
                                  for r in part]
    order = {(fov, c.name): i for i, (fov, c) in enumerate(blocks)}
    records.sort(key=lambda r: (order[(r.fov_deg, r.condition)], r.trial, methods.index(r.method)))
    meta = dict(settings._asdict(), conditions=[c._asdict() for c in settings.conditions], methods=methods,
                camera=f"{WIDTH}×{HEIGHT}", mag_limit=MAG_LIMIT, epoch=EPOCH, cpu_count=os.cpu_count())
    study = {"settings": meta, "records": records, "tables": tables}
    if safety is not None:
        study["safety"] = _safety_result(safety._replace(methods=tuple(methods), workers=settings.workers),
                                         methods, parts[len(case_jobs) + len(grid_jobs):])
    if cases:
        study["cases"] = dict(zip(cases, parts[:len(case_jobs)], strict=True))
    return study


def _job_label(job: tuple) -> str:
    """What a job of :func:`run_study`'s pool did, for the progress bar."""
    fn = job[0]
    if fn is run_block:
        return f"{job[1]:g}° {job[2].name}"
    if fn is run_safety_block:
        return f"safety frames {job[1].start}–{job[1].stop - 1}"
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


# --- the seeds' experiments ---------------------------------------------------------------------
def _clusters(vectors: np.ndarray, max_angle_rad: float) -> np.ndarray:
    """Every triangle (i < j < k) of ``vectors`` whose three sides are at most ``max_angle_rad``,
    from the pair table's neighbour lists."""
    from skyfix.identify.pairs import build_pair_table

    table = build_pair_table(vectors, np.arange(len(vectors), dtype=np.int32), max_angle_rad)
    i, j = table.first.astype(np.int64), table.second.astype(np.int64)
    adj = np.zeros((len(vectors), len(vectors)), bool)
    adj[i, j] = adj[j, i] = True
    # third vertices k > j adjacent to both: one boolean row product per pair (vectorised over k)
    tri = []
    for chunk in range(0, len(i), 20000):
        a, b = i[chunk:chunk + 20000], j[chunk:chunk + 20000]
        rows, ks = np.nonzero(adj[a] & adj[b])
        keep = ks > b[rows]
        tri.append(np.stack([a[rows][keep], b[rows][keep], ks[keep]], 1))
    return np.concatenate(tri) if tri else np.zeros((0, 3), np.int64)


def quest_catalogue(n_stars: int = 513, max_angle_deg: float = 21.25) -> dict:
    """Thesis 000 §6.1.3: every 3-star cluster of the ``n_stars`` brightest stars (000 used a
    BSC cut of ~V 4: 513 stars) with all sides ≤ ``max_angle_deg`` (≈ 26,500 clusters, as
    000's 26,437), each fed to QUEST as image and reference: success when the attitude is the
    identity to 1″. 000: 25,564 of 26,437 (96.7 %)."""
    from skyfix.attitude import solve_attitude
    from skyfix.catalog import load_hipparcos
    from skyfix.geometry import rotation_angle_between

    cat = load_hipparcos(epoch=EPOCH)
    v = cat.vectors[:n_stars]
    tri = _clusters(v, math.radians(max_angle_deg))
    ok = 0
    worst = 0.0
    for t in tri:
        A = solve_attitude(v[t], v[t], method="quest")
        err = rotation_angle_between(A, np.eye(3)) / _ARCSEC
        worst = max(worst, err)
        ok += err < 1.0
    return {"case": "quest-catalogue", "n_stars": n_stars, "max_angle_deg": max_angle_deg,
            "clusters": len(tri), "identity": int(ok), "success_pct": 100.0 * ok / max(len(tri), 1),
            "worst_arcsec": worst, "thesis": {"clusters": 26437, "identity": 25564, "success_pct": 96.7}}


SHIFTS_PX = (0.0, 0.0004, 0.0008, 0.01, 0.1, 0.5, 1.0, 2.0, 5.0, 10.0)
"""Thesis 000's sweep moved one star by 0.01 % steps of a pixel up to 1 % (its Table 6 means:
0.04–0.06 %); skyfix's tolerances are set by the centroid noise, so the sweep goes on to 5 px."""


def perturbation_sweep(shifts_px: tuple[float, ...] = SHIFTS_PX, n_stars: int = 513,
                       max_angle_deg: float = 21.25, n_clusters: int = 200, method: str = "triangle",
                       seed: int = 0, exactly_three: bool = False) -> dict:
    """Thesis 000 Table 6 and §6.4: the clusters of :func:`quest_catalogue` as frames — each
    seen by thesis 000's camera (preset ``mt9v022``, calibrated) at a random roll with its
    centroid on the boresight, with every other catalogue star in view (``exactly_three``: only
    the clusters with none) — one cluster star moved along x by each of ``shifts_px``,
    identified by ``method`` and judged against the truth: right, wrong, or refused. As in the
    thesis, the catalogue is identified against itself: the database is built from the same
    stars. (The thesis's frames held the cluster alone; skyfix rejects a match that leaves a
    catalogue star in view undetected, so such a frame is not a frame it can be given.)"""
    from skyfix.camera import camera_from_preset
    from skyfix.catalog import load_hipparcos
    from skyfix.geometry import attitude_from_radec_roll, normalize, vector_to_radec
    from skyfix.identify import PatternDatabase, identify

    cat = load_hipparcos(epoch=EPOCH)
    v = cat.vectors[:n_stars]
    tri = _clusters(v, math.radians(max_angle_deg))
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(tri), size=min(n_clusters, len(tri)), replace=False)
    camera = camera_from_preset("mt9v022")
    # the thesis identified the catalogue against itself: a database of the same stars
    stars = cat.subset(np.arange(n_stars))
    db = PatternDatabase.build(camera.fov_deg / 1.2, camera.fov_deg * 1.2, catalog=stars, epoch=EPOCH)
    frames = []
    for t in tri[pick]:
        ra, dec = vector_to_radec(normalize(v[t].sum(0)))
        A = attitude_from_radec_roll(float(ra), float(dec), rng.uniform(0, 2 * math.pi))
        xy, front = camera.ray_to_pixel(v[t] @ A.T)
        if not (front.all() and camera.in_frame(xy).all()):
            continue
        # the frame holds every catalogue star in view (a camera sees them all), the cluster first
        near = np.setdiff1d(stars.cone(A[2], math.radians(40.0)), t)
        other, front = camera.ray_to_pixel(v[near] @ A.T)
        seen = front & camera.in_frame(other)
        if exactly_three and seen.any():
            continue
        ids = np.concatenate([stars.ids[t], stars.ids[near][seen]])
        frames.append((A, np.vstack([xy, other[seen]]), int(rng.integers(3)), ids))
    rows = []
    for shift in shifts_px:
        right = wrong = 0
        reasons: dict[str, int] = {}
        wrong_detail = []
        for A, xy, star, ids in frames:
            moved = xy.copy()
            moved[star, 0] += shift
            ident = identify(moved, camera.width, camera.height, method=method, camera=camera, database=db,
                             epoch=EPOCH)
            if not ident.success:
                key = ident.reason.split(":")[0].split("(")[0].strip()
                reasons[key] = reasons.get(key, 0) + 1
            elif _judge(ident, A, camera)[0]:
                wrong += 1
                err = attitude_error_rad(ident.A_icrs_to_cam, ident.camera or camera, A, camera)
                wrong_detail.append({"boresight_arcsec": math.hypot(err[0], err[1]) / _ARCSEC,
                                     "roll_deg": math.degrees(abs(err[2])), "matched": ident.n_matched,
                                     "matched_true": int(np.sum(ids[ident.star_index] == ident.catalog_ids)),
                                     "moved_star_matched": bool(star in set(ident.star_index.tolist()))})
            else:
                right += 1
        n = len(frames)
        rows.append({"shift_px": shift, "frames": n, "right": right, "wrong": wrong,
                     "wrong_detail": wrong_detail, "refused": n - right - wrong,
                     "right_pct": 100.0 * right / max(n, 1),
                     "wrong_upper95_pct": 100.0 * upper_bound_95(wrong, n), "refusals": reasons})
    return {"case": "perturbation", "method": method, "clusters": len(tri),
            "not_used": len(pick) - len(frames),
            "rows": rows, "thesis": {"table_6_mean_tolerance_pct_px": {"x": 0.04, "y": 0.05, "z": 0.06},
                                     "success_at_0.04pct_px": 75, "success_beyond_0.08pct_px": "< 50"}}


def three_star_frames(n_clusters: int = 10_000, method: str = "triangle", seed: int = 0) -> dict:
    """:func:`perturbation_sweep` with no shift on the clusters of the 170 brightest stars (000's
    magnitude-3 catalogue) alone in thesis 000's frame (exactly three catalogue stars in view):
    3-star fields, solved or refused as ambiguous."""
    return {**perturbation_sweep((0.0,), n_stars=170, max_angle_deg=31.8, n_clusters=n_clusters,
                                 method=method, seed=seed, exactly_three=True), "case": "three-star-frames"}


CASES: dict[str, Callable[..., dict]] = {
    "quest-catalogue": quest_catalogue,
    "three-star-frames": three_star_frames,
    "perturbation": perturbation_sweep,
}



class MatchingRow(NamedTuple):
    """One row of thesis 004's Table 3-7: the errors simulated and the tolerances matched with
    (µrad, mag), and the thesis's outcome of 1000 trials."""

    sigma_p_urad: float
    sigma_mv: float
    d_uncert_urad: float
    mv_uncert: float
    thesis_fail_lt3: int
    thesis_fail_gt3: int
    thesis_success_pct: float


TABLE_3_7_ROWS = (
    MatchingRow(50, 0.3, 50, 0.3, 4, 177, 81.9),
    MatchingRow(50, 0.3, 75, 0.45, 5, 17, 97.8),
    MatchingRow(50, 0.3, 100, 0.6, 3, 9, 98.8),
    MatchingRow(50, 0.3, 150, 0.6, 2, 4, 99.4),
    MatchingRow(100, 0.3, 200, 0.45, 4, 24, 97.2),
)


def table_3_7(trials: int = 1000, method: str = "van-bezooijen", seed: int = 0,
              rows: tuple[MatchingRow, ...] = TABLE_3_7_ROWS) -> dict:
    """Thesis 004 Table 3-7: ``trials`` attitudes drawn uniformly inside the Table 3-5 envelope,
    the Sunsat camera (preset ``sunsat``), Gaussian errors σ_p on each star's position and σ_Mv on
    its magnitude, the ≤ 8 brightest stars (thesis 004's V ≤ 6: the 5,026 brightest) identified
    by ``method`` against a pattern database of the envelope's sub-catalogue
    (:func:`skyfix.analysis.coverage.sub_catalogue`, 588 stars; thesis 540). For van Bezooijen
    the tolerances are the thesis's: the distance tolerance d_uncert (the noise stated as it is,
    ``centroid_sigma_px`` = σ_p · f / √2, and ``n_sigma`` = d_uncert / σ_p) and Mv_uncert on the
    magnitudes given. Counted as in
    the thesis: failures with < 3 stars in view, failures with more, wrong, success.

    σ_p is the error of a measured *distance* (Table 3-6 pairs it with "the uncertainty in the
    distance measured between two stars", and the uncertainties "were set equal to the 1σ
    errors"): each axis gets σ_p/√2. The method is given the ≤ 20 stars the sensor's region
    growing extracts (§3.2) and matches the 8 brightest (``max_stars``); the rest only verify.
    ``fail_thesis_found``: failures whose true stars among the 8 hold a group of ≥ 3 that passes
    (3.1) and (3.2) for every pair — a group the thesis's largest-group rule could take, refused
    here as not beyond chance (``refused_log10_p``: the verification's chance of each such true
    group proposed alone, with its first four stars as the core)."""
    import itertools

    from skyfix.analysis import coverage as cv
    from skyfix.camera import camera_from_preset
    from skyfix.catalog import load_hipparcos
    from skyfix.identify import PatternDatabase, identify
    from skyfix.identify.hypothesis import chance_log_probability, frame_for, hypothesis

    camera = camera_from_preset("sunsat")
    f = math.sqrt(camera.fx * camera.fy)
    full = load_hipparcos(epoch=EPOCH)
    limit = cv.limit_for_count(full.brighter_than(8.0), cv.THESIS_004_CATALOG_SIZE)
    t0 = time.perf_counter()
    sub = cv.sub_catalogue(full, cv.sunsat_attitudes(cv.TABLE_3_5), 11.17, 8.32, limit)
    db = PatternDatabase.build(8.0, 12.0, catalog=sub, epoch=EPOCH)
    rng = np.random.default_rng(seed)
    env = cv.TABLE_3_5
    angles = [np.radians(rng.uniform(lo, hi, trials)) for lo, hi in env]
    attitudes = cv.sunsat_attitude_matrix(*angles)
    warm = synthetic_centroids(camera, attitudes[0], full, mag_limit=limit, rng=seed)
    identify(warm.xy[:8], camera.width, camera.height, method=method, camera=camera, database=db, epoch=EPOCH)
    build_s = time.perf_counter() - t0  # the sub-catalogue, its database and the method's tables
    star_ids, star_mag, _ = db.star_arrays()
    row_of = {int(s): i for i, s in enumerate(star_ids)}

    def thesis_group(field, row: MatchingRow) -> list[tuple[int, int]]:
        # the largest set of true (centroid, star) matches among the 8 brightest whose magnitudes
        # and pairwise distances all pass the thesis's tests (3.1), (3.2)
        rays = camera.pixel_to_ray(field.xy[:8])
        cand = [(i, row_of[int(s)]) for i, s in enumerate(field.star_id[:8])
                if int(s) in row_of and abs(field.mag[i] - star_mag[row_of[int(s)]]) <= row.mv_uncert]
        vec = db.star_index().vectors
        for size in range(len(cand), 2, -1):
            for group in itertools.combinations(cand, size):
                if all(abs(math.acos(min(1.0, rays[a] @ rays[b])) - math.acos(min(1.0, vec[ga] @ vec[gb])))
                       <= row.d_uncert_urad * 1e-6 for (a, ga), (b, gb) in itertools.combinations(group, 2)):
                    return list(group)
        return []

    def refused_log10_p(xy: np.ndarray, group: list[tuple[int, int]]) -> float:
        frame = frame_for(method, xy, camera.width, camera.height, fov_deg=None, fov_tolerance_deg=None,
                          camera=camera, database=db, epoch=EPOCH)
        stars, cat = np.array(group).T
        core = hypothesis(frame, stars[:4], cat[:4])
        return chance_log_probability(frame, core) / math.log(10.0)

    out_rows = []
    for row in rows:
        fail_lt3 = fail_gt3 = wrong = ok = 0
        refused: list[float] = []
        times = []
        reasons: dict[str, int] = {}
        for k, A in enumerate(attitudes):
            field = synthetic_centroids(camera, A, full, mag_limit=limit, mag_sigma=row.sigma_mv,
                                        sigma_px=row.sigma_p_urad * 1e-6 * f / math.sqrt(2.0),
                                        rng=np.random.default_rng([seed, k]))
            xy, mag = field.xy[:20], field.mag[:20]
            options = {}
            if method == "van-bezooijen":
                options = dict(magnitudes=mag, magnitude_tolerance=row.mv_uncert,
                               n_sigma=row.d_uncert_urad / row.sigma_p_urad,
                               centroid_sigma_px=row.sigma_p_urad * 1e-6 * f / math.sqrt(2.0), max_stars=8)
            t1 = time.perf_counter()
            ident = identify(xy, camera.width, camera.height, method=method, camera=camera, database=db,
                             epoch=EPOCH, **options)
            times.append(1e3 * (time.perf_counter() - t1))
            if not ident.success:
                key = ident.reason.split(":")[0].split("(")[0].strip()
                reasons[key] = reasons.get(key, 0) + 1
                if len(xy) < 3:
                    fail_lt3 += 1
                else:
                    fail_gt3 += 1
                    group = thesis_group(field, row)
                    if len(group) >= 3:
                        refused.append(refused_log10_p(xy, group))
            elif _judge(ident, A, camera)[0]:
                wrong += 1
            else:
                ok += 1
        out_rows.append({**row._asdict(), "trials": trials, "fail_lt3": fail_lt3, "fail_gt3": fail_gt3,
                         "wrong": wrong, "wrong_upper95_pct": 100.0 * upper_bound_95(wrong, trials),
                         "success_pct": 100.0 * ok / trials, "median_ms": float(np.median(times)),
                         "max_ms": float(np.max(times)), "failures": reasons,
                         "fail_thesis_found": len(refused), "refused_log10_p": sorted(refused)})
    return {"case": "table-3-7", "method": method, "sub_catalogue_stars": len(sub), "mag_limit_hp": limit,
            "database_build_s": build_s, "rows": out_rows}


CASES["table-3-7"] = table_3_7


def sparse_fields(fov_deg: float = 30.0, n_fields: int = 200, n_bright: int = 3,
                  methods: tuple[str, ...] = ("triangle", "quad-hash"), seed: int = 0,
                  calibrated: bool = False) -> dict:
    """Issue 11's 3-star fields: ``n_fields`` random attitudes of a 1280 × 960 camera ``fov_deg``
    wide, each detecting exactly its ``n_bright`` brightest catalogue stars (the limit set between
    the ``n_bright``-th and the next), noise-free, identified by each of ``methods`` with the FOV
    told to ±10 % (``calibrated``: the camera given): right, wrong, refused (reasons counted;
    "ambiguous" when the stars are not unique enough to name)."""
    from skyfix.catalog import load_hipparcos
    from skyfix.identify import Identification, default_database, identify

    catalog = load_hipparcos(epoch=EPOCH)
    db = default_database(progress=False)
    camera = Camera.from_fov(WIDTH, HEIGHT, fov_deg)
    rng = np.random.default_rng(seed)
    tally = {m: {"right": 0, "wrong": 0, "refused": 0, "reasons": {}} for m in methods}
    used = 0
    for A in random_attitudes(n_fields, rng):
        every = synthetic_centroids(camera, A, catalog, mag_limit=9.0, sigma_px=0.0)
        mags = np.sort(every.mag)
        if len(mags) <= n_bright or mags[n_bright] - mags[n_bright - 1] < 0.05:
            continue  # too few stars, or no clean limit between the n-th and the next
        limit = 0.5 * (mags[n_bright - 1] + mags[n_bright])
        field = synthetic_centroids(camera, A, catalog, mag_limit=limit, sigma_px=0.0)
        used += 1
        for m in methods:
            try:
                told = {"camera": camera} if calibrated else {"fov_deg": fov_deg,
                                                              "fov_tolerance_deg": 0.1 * fov_deg}
                ident = identify(field.xy, WIDTH, HEIGHT, method=m, database=db, epoch=EPOCH, **told)
            except Exception as exc:  # a method's bug is its failure here
                ident = Identification(False, f"error: {type(exc).__name__}")
            t = tally[m]
            if not ident.success:
                t["refused"] += 1
                key = ident.reason.split(":")[0].split("(")[0].strip()
                t["reasons"][key] = t["reasons"].get(key, 0) + 1
            elif _judge(ident, A, camera)[0]:
                t["wrong"] += 1
            else:
                t["right"] += 1
    for t in tally.values():
        t["right_pct"] = 100.0 * t["right"] / max(used, 1)
        t["wrong_upper95_pct"] = 100.0 * upper_bound_95(t["wrong"], used)
    return {"case": "sparse-fields", "fov_deg": fov_deg, "stars": n_bright, "calibrated": calibrated,
            "fields": used, "methods": tally}


CASES["sparse-fields"] = sparse_fields


# --- the safety case ----------------------------------------------------------------------------
class SafetyDraw(NamedTuple):
    """One random frame of the safety case (:func:`safety_draw`): the study's axes drawn at random."""

    trial: int
    fov_deg: float
    sigma_px: float
    n_false: int
    dropout: float
    mag_sigma: float
    camera_given: bool  # the true camera given, else the FOV told to ±10 %
    bright_stars: int  # 0: every star to Hp 6.5; 3, 4 or 5: only that many brightest stars


class SafetyMix(NamedTuple):
    """How the safety case draws its frames (:func:`safety_draw`)."""

    fovs_deg: tuple[float, ...] = (8.0, 15.0, 30.0)
    max_sigma_px: float = 2.0
    max_false: int = 10
    max_dropout: float = 0.2
    max_mag_sigma: float = 0.5
    camera_given_share: float = 0.5
    three_star_share: float = 0.2  # frames of exactly their 3 brightest catalogue stars
    few_star_share: float = 0.2  # frames of their 4 or 5 brightest


SAFETY_MIX = SafetyMix()
SAFETY_KEY = 5_417  # a seed word of the safety case's fields (apart from the grid's)


class SafetyTrial(NamedTuple):
    """One method's solve (:func:`skyfix.pipeline.solve_centroids`) of one safety frame."""

    method: str
    trial: int
    fov_deg: float
    sigma_px: float
    n_false: int
    dropout: float
    mag_sigma: float
    camera_given: bool
    bright_stars: int
    n_stars: int  # catalogue stars among the centroids
    n_centroids: int
    solved: bool
    wrong: bool  # solved, and the boresight > 60″ or the roll > 0.5° from the truth
    boresight_arcsec: float  # NaN when not solved
    roll_deg: float
    normalised: float  # √(δθᵀ P⁻¹ δθ) with the reported covariance P (NaN when not solved)
    n_matched: int
    prob_false: float
    time_ms: float
    reason: str


def safety_draw(trial: int, seed: int = 0, mix: SafetyMix = SAFETY_MIX) -> SafetyDraw:
    """The parameters of safety frame ``trial``: a function of ``(seed, trial)`` alone, so any
    frame can be replayed (:func:`safety_field`, :func:`replay_safety`)."""
    rng = np.random.default_rng([seed, SAFETY_KEY, trial, 0])
    kind = rng.random()
    bright = 3 if kind < mix.three_star_share else (
        int(rng.integers(4, 6)) if kind < mix.three_star_share + mix.few_star_share else 0)
    return SafetyDraw(trial, float(rng.choice(mix.fovs_deg)), float(rng.uniform(0.0, mix.max_sigma_px)),
                      int(rng.integers(0, mix.max_false + 1)), float(rng.uniform(0.0, mix.max_dropout)),
                      float(rng.uniform(0.0, mix.max_mag_sigma)), bool(rng.random() < mix.camera_given_share),
                      bright)


def safety_field(draw: SafetyDraw, catalog, seed: int = 0):
    """The camera and the centroids (:class:`~skyfix.analysis.synthetic_centroids.SyntheticField`)
    of a safety frame: a random attitude, the catalogue stars to Hp 6.5 — or, for a sparse frame,
    to a limit halfway between its ``bright_stars``-th and next brightest star (``catalog`` must
    reach Hp 7.5) — with the draw's centroid noise, dropped stars, magnitude noise and false stars."""
    rng = np.random.default_rng([seed, SAFETY_KEY, draw.trial, 1])
    camera = Camera.from_fov(WIDTH, HEIGHT, draw.fov_deg)
    A = random_attitudes(1, rng)[0]
    limit = MAG_LIMIT
    if draw.bright_stars:
        mags = np.sort(synthetic_centroids(camera, A, catalog, mag_limit=MAG_LIMIT + 1.0, sigma_px=0.0).mag)
        k = draw.bright_stars
        limit = 0.5 * (mags[k - 1] + mags[k]) if len(mags) > k else MAG_LIMIT + 1.0
    f = synthetic_centroids(camera, A, catalog, mag_limit=limit, sigma_px=draw.sigma_px, n_false=draw.n_false,
                            dropout=draw.dropout, mag_sigma=draw.mag_sigma, rng=rng)
    return camera, f


def _safety_options(method: str, bounds: dict[str, dict]) -> dict:
    """The options the safety case gives ``method`` (its work bounds, :data:`SAFETY_BOUNDS`)."""
    return dict(bounds.get(method, {}))


SAFETY_BOUNDS: dict[str, dict] = {
    "triangle": {"max_candidates": 200},
    "liebe": {"max_candidates": 200},
    "pyramid": {"max_candidates": 50, "time_limit_s": 0.25},
    "van-bezooijen": {"max_candidates": 50, "time_limit_s": 0.25},
}
"""Work bounds the safety case gives a method (its own options, as a user could), so that 10⁴
frames per method fit the study's time: the refusals, not the solves, take the time (a search
that finds nothing runs to its bound), and these bounds cut their cost by ~35 % with 2 of 360
solves lost (40 frames, ``van-bezooijen``). The others run with their defaults — and the default
solve (``quad-hash``) with its sparse-field fallback to ``triangle`` at the latter's defaults."""


def safety_trial(method: str, draw: SafetyDraw, camera: Camera, field, bounds: dict[str, dict] | None = None
                 ) -> SafetyTrial:
    """``method`` on one safety frame, through the solve a user calls
    (:func:`skyfix.pipeline.solve_centroids` with ``identify_method=method``: the final fit, the
    precision rule and — for the default method — the sparse-field fallback included), judged
    against the truth."""
    from skyfix.pipeline import solve_centroids

    told = {"camera": camera} if draw.camera_given else {"fov_deg": draw.fov_deg,
                                                        "fov_tolerance_deg": 0.1 * draw.fov_deg}
    options = _safety_options(method, SAFETY_BOUNDS if bounds is None else bounds)
    t0 = time.perf_counter()
    try:
        sol = solve_centroids(field.xy, WIDTH, HEIGHT, identify_method=method, epoch=EPOCH, **told, **options)
        solved, reason = sol.solved, sol.reason
    except Exception as exc:  # a method's bug is its failure here, not the study's end
        sol, solved, reason = None, False, f"error: {type(exc).__name__}: {exc}"
    dt = 1e3 * (time.perf_counter() - t0)
    bore = roll = norm = math.nan
    wrong = False
    if solved:
        from skyfix.identify.accept import WRONG_BORESIGHT_ARCSEC, WRONG_ROLL_DEG

        err = attitude_error_rad(sol.A_icrs_to_cam, sol.camera, field.A_icrs_to_cam, camera)
        bore, roll = math.hypot(err[0], err[1]) / _ARCSEC, math.degrees(abs(err[2]))
        wrong = bore > WRONG_BORESIGHT_ARCSEC or roll > WRONG_ROLL_DEG
        e = err / _ARCSEC
        try:
            norm = float(math.sqrt(e @ np.linalg.solve(np.asarray(sol.covariance_arcsec2), e)))
        except (np.linalg.LinAlgError, ValueError):
            norm = math.inf
    return SafetyTrial(method, draw.trial, draw.fov_deg, draw.sigma_px, draw.n_false, draw.dropout,
                       draw.mag_sigma, draw.camera_given, draw.bright_stars, int(np.sum(field.star_id > 0)),
                       len(field.xy), bool(solved), bool(wrong), bore, roll, norm,
                       int(sol.n_matched) if solved else 0, float(sol.prob_false) if solved else math.nan, dt,
                       reason)


def run_safety_block(trials: range, methods: list[str], seed: int = 0, mix: SafetyMix = SAFETY_MIX,
                     bounds: dict[str, dict] | None = None) -> list[SafetyTrial]:
    """Every method on the safety frames ``trials`` (a worker's job), interleaved frame by frame."""
    from skyfix.catalog import load_hipparcos

    catalog = load_hipparcos(epoch=EPOCH, mag_limit=MAG_LIMIT + 1.0)
    out = []
    for t in trials:
        draw = safety_draw(t, seed, mix)
        camera, field = safety_field(draw, catalog, seed)
        out += [safety_trial(m, draw, camera, field, bounds) for m in methods]
    return out


def replay_safety(trial: int, method: str, seed: int = 0, mix: SafetyMix = SAFETY_MIX,
                  bounds: dict[str, dict] | None = None) -> SafetyTrial:
    """Replay one safety trial (a wrong one from the JSON's ``safety.wrong``)."""
    return run_safety_block(range(trial, trial + 1), [method], seed, mix, bounds)[0]


class SafetySettings(NamedTuple):
    """What :func:`run_safety` runs."""

    trials: int = 10_000  # frames; every method solves each one
    first: int = 0  # the first frame's number (a campaign split in parts: frames first … first + trials − 1)
    methods: tuple[str, ...] = ()  # empty: every registered method
    seed: int = 0
    workers: int = 1
    mix: SafetyMix = SAFETY_MIX
    block: int = 100  # frames per worker job (and per checkpoint)


SAFETY_FULL = SafetySettings()  # 10⁴ frames: ~0.64 CPU-s a frame for the nine methods (~53 min on 2 cores)
# The whole study's share: 10³ frames (~5 min of 2 cores), so that grid, safety sample and seed
# experiments run in one command; the 10⁴ frames are `--case safety` alone (SAFETY_FULL).
SAFETY_STUDY = SafetySettings(trials=1_000)
SAFETY_QUICK = SafetySettings(trials=20, block=10)


def _pool(jobs: list[tuple], workers: int, methods: list[str], fovs_deg: tuple[float, ...],
          progress: Callable[[str], None] | None, label: Callable[[tuple], str],
          done: Callable[[object], None] | None = None) -> list:
    """Run ``jobs`` — ``(function, *args)`` tuples — in ``workers`` spawned processes (each warmed
    by :func:`_warm`, calibrated cameras included) or, with one worker, here; returns their
    results in the jobs' order (``done`` is given each result as it comes)."""
    results: list = [None] * len(jobs)
    workers = max(1, min(int(workers), len(jobs)))
    if workers == 1:
        _warm(methods, fovs_deg, cameras=True)
        for i, (fn, *args) in enumerate(jobs):
            results[i] = fn(*args)
            if done is not None:
                done(results[i])
            if progress is not None:
                progress(label(jobs[i]))
        return results
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    ctx = mp.get_context("spawn")  # no fork of a process holding numba's and rich's threads
    with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_warm,
                             initargs=(methods, fovs_deg, True)) as pool:
        futures = {pool.submit(fn, *args): i for i, (fn, *args) in enumerate(jobs)}
        for fut in as_completed(futures):
            i = futures[fut]
            results[i] = fut.result()
            if done is not None:
                done(results[i])
            if progress is not None:
                progress(label(jobs[i]))
    return results


def run_safety(settings: SafetySettings = SAFETY_FULL, progress: Callable[[str], None] | None = None,
               checkpoint: str | Path | None = None) -> dict:
    """The safety case: ``settings.trials`` random frames (:func:`safety_draw`), each solved by
    every method through :func:`skyfix.pipeline.solve_centroids`. Returns ``{"settings",
    "records"}`` (records as :class:`SafetyTrial`, in frame then method order). With
    ``checkpoint``, each block's records are appended to that file as JSON lines as they come
    (a long run's work survives its end)."""
    methods = method_names(settings.methods)
    done = None
    if checkpoint is not None:
        path = Path(checkpoint)
        path.write_text("")

        def done(part: list[SafetyTrial]) -> None:
            with path.open("a") as fh:
                fh.writelines(json.dumps(strict_json(r._asdict())) + "\n" for r in part)

    parts = _pool(_safety_jobs(settings, methods), settings.workers, methods, settings.mix.fovs_deg, progress,
                  _job_label, done)
    return _safety_result(settings, methods, parts)


def _safety_jobs(settings: SafetySettings, methods: list[str]) -> list[tuple]:
    step, end = max(1, int(settings.block)), settings.first + settings.trials
    return [(run_safety_block, range(a, min(a + step, end)), methods, settings.seed, settings.mix)
            for a in range(settings.first, end, step)]


def _safety_result(settings: SafetySettings, methods: list[str], parts: list[list[SafetyTrial]]) -> dict:
    meta = dict(settings._asdict(), mix=settings.mix._asdict(), methods=methods, camera=f"{WIDTH}×{HEIGHT}",
                mag_limit=MAG_LIMIT, epoch=EPOCH, bounds=SAFETY_BOUNDS, cpu_count=os.cpu_count())
    return {"settings": meta, "records": [r for part in parts for r in part]}


def _kind(r: SafetyTrial) -> str:
    return {0: "full", 3: "3-star"}.get(r.bright_stars, "4–5-star")


def safety_summary(records: list[SafetyTrial]) -> dict:
    """Per method: trials, solved, wrong with its 95 % upper bound, median and p99 time, median
    boresight error and the normalised error's median and p99 over the solved, solved % per
    kind of frame (3-star, 4–5-star, full; camera given or FOV only), and every wrong trial."""
    out: dict[str, dict] = {}
    for m in dict.fromkeys(r.method for r in records):
        mine = [r for r in records if r.method == m]
        n = len(mine)
        solved = [r for r in mine if r.solved]
        wrong = [r for r in mine if r.wrong]
        t = np.array([r.time_ms for r in mine])
        right = [r for r in solved if not r.wrong]
        norm = np.array([r.normalised for r in right]) if right else np.array([np.nan])
        kinds = {}
        for kind in ("3-star", "4–5-star", "full"):
            for given in (True, False):
                sub = [r for r in mine if _kind(r) == kind and r.camera_given == given]
                key = f"{kind}, {'camera' if given else 'FOV only'}"
                kinds[key] = {"n": len(sub), "solved": sum(r.solved for r in sub),
                              "wrong": sum(r.wrong for r in sub),
                              "solved_pct": 100.0 * sum(r.solved for r in sub) / max(len(sub), 1)}
        out[m] = {"n": n, "solved": len(solved), "solved_pct": 100.0 * len(solved) / max(n, 1),
                  "wrong": len(wrong), "wrong_upper95_pct": 100.0 * upper_bound_95(len(wrong), n),
                  "with_false_stars": sum(r.n_false > 0 for r in mine),
                  "median_ms": float(np.median(t)) if n else math.nan,
                  "p99_ms": float(np.percentile(t, 99)) if n else math.nan,
                  "total_s": float(t.sum()) / 1e3 if n else 0.0,
                  "median_boresight_arcsec": float(np.median([r.boresight_arcsec for r in right]))
                  if right else math.nan,
                  "median_normalised": float(np.median(norm)),
                  "p99_normalised": float(np.percentile(norm, 99)),
                  "kinds": kinds, "wrong_trials": [r._asdict() for r in wrong]}
    return out


def safety_markdown(safety: dict, summary: dict, command: str = "") -> str:
    """The safety case's table in Markdown."""
    s = safety["settings"]
    mix = s["mix"]
    lines = [f"## Safety: {s['trials']:,} frames per method\n",
             (f"`{command}` — " if command else "")
             + f"seed {s['seed']}; each frame a random attitude, FOV from {mix['fovs_deg']}, centroid σ "
             f"0–{mix['max_sigma_px']:g} px, 0–{mix['max_false']} false stars, "
             f"0–{100 * mix['max_dropout']:.0f} % dropped, magnitude noise 0–{mix['max_mag_sigma']:g}, "
             f"the camera given to "
             f"{100 * mix['camera_given_share']:.0f} % (else the FOV to ±10 %); "
             f"{100 * mix['three_star_share']:.0f} % of the frames hold only their 3 brightest stars, "
             f"{100 * mix['few_star_share']:.0f} % their 4 or 5. Solved through `solve_centroids(..., "
             "identify_method=NAME)`; **wrong**: solved with the boresight > 60″ or the roll > 0.5° from the "
             "truth.\n",
             "| method | trials | with false stars | solved % | wrong | wrong ≤ (95 %) | median ms | p99 ms "
             "| median boresight ″ | normalised error median / p99 |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for m, a in summary.items():
        lines.append(f"| {m} | {a['n']} | {a['with_false_stars']} | {a['solved_pct']:.1f} | {a['wrong']} | "
                     f"{a['wrong_upper95_pct']:.3f} % | {a['median_ms']:.1f} | {a['p99_ms']:.0f} | "
                     f"{a['median_boresight_arcsec']:.1f} | {a['median_normalised']:.2f} / "
                     f"{a['p99_normalised']:.2f} |")
    kinds = list(next(iter(summary.values()))["kinds"]) if summary else []
    lines += ["\nSolved % per kind of frame (frames; wrong in brackets when any):\n",
              "| frames | n | " + " | ".join(summary) + " |", "|---|---|" + "---|" * len(summary)]
    for k in kinds:
        first = next(iter(summary.values()))["kinds"][k]
        cells = [a["kinds"][k] for a in summary.values()]
        row = [f"{c['solved_pct']:.1f}" + (f" ({c['wrong']})" if c["wrong"] else "") for c in cells]
        lines.append(f"| {k} | {first['n']} | " + " | ".join(row) + " |")
    wrong = [w for a in summary.values() for w in a["wrong_trials"]]
    if wrong:
        lines += ["\nWrong trials (replay: `identification_study.replay_safety(trial, method, seed)`):\n",
                  "| method | trial | FOV | camera | stars / centroids | σ px | false | boresight ″ | roll ° "
                  "| P(false) |", "|---|---|---|---|---|---|---|---|---|---|"]
        for w in wrong:
            lines.append(f"| {w['method']} | {w['trial']} | {w['fov_deg']:g}° | {w['camera_given']} | "
                         f"{w['n_stars']} / {w['n_centroids']} | {w['sigma_px']:.2f} | {w['n_false']} | "
                         f"{w['boresight_arcsec']:.0f} | {w['roll_deg']:.2f} | {w['prob_false']:.2g} |")
    return "\n".join(lines) + "\n"


def safety_plot(summary: dict, out: Path) -> Path:
    """safety.png: solved % per method and kind of frame, the wrong count over each group."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = list(summary)
    kinds = list(summary[methods[0]]["kinds"])
    fig, ax = plt.subplots(figsize=(10, 4.2), dpi=100)
    width = 0.8 / len(kinds)
    x = np.arange(len(methods))
    for i, k in enumerate(kinds):
        ax.bar(x + i * width, [summary[m]["kinds"][k]["solved_pct"] for m in methods], width, label=k)
    for j, m in enumerate(methods):
        ax.text(x[j] + 0.4 - width / 2, 102, f"wrong {summary[m]['wrong']}/{summary[m]['n']}", ha="center",
                fontsize=7)
    ax.set_ylim(0, 110)
    ax.set_xticks(x + 0.4 - width / 2)
    ax.set_xticklabels(methods, rotation=30, ha="right")
    ax.set_ylabel("solved %")
    ax.legend(fontsize=7, ncol=3, loc="lower center", bbox_to_anchor=(0.5, 1.0))
    fig.tight_layout()
    path = out / "safety.png"
    fig.savefig(path)
    plt.close(fig)
    return path


def safety_json(safety: dict, summary: dict) -> dict:
    """The safety case for the study's JSON: settings, summary (every wrong trial with its frame's
    number, to replay) and the records as columns."""
    recs = safety["records"]
    columns = {f: [getattr(r, f) for r in recs] for f in SafetyTrial._fields}
    return {"settings": safety["settings"], "summary": summary, "records": columns}


def write_safety(safety: dict, out_dir: str | Path, command: str = "") -> list[Path]:
    """Write the safety case alone (:func:`run_safety`): ``identification_safety.json`` (settings,
    summary with every wrong trial, records as columns), ``identification_safety.md`` and safety.png."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary = safety_summary(safety["records"])
    pj = out / "identification_safety.json"
    pj.write_text(json.dumps(strict_json(safety_json(safety, summary))))
    pm = out / "identification_safety.md"
    pm.write_text(safety_markdown(safety, summary, command))
    return [pj, pm, safety_plot(summary, out)]


def read_checkpoint(path: str | Path) -> list[SafetyTrial]:
    """The records a safety run checkpointed (:func:`run_safety`'s ``checkpoint``; several parts'
    files may be concatenated), in frame then method order — for :func:`safety_summary`,
    :func:`safety_markdown` and :func:`safety_plot` when a run was stopped or split."""
    nan_fields = ("boresight_arcsec", "roll_deg", "normalised", "prob_false")
    records = []
    for line in Path(path).read_text().splitlines():
        if line.strip():
            row = json.loads(line)
            row.update({k: math.nan for k in nan_fields if row[k] is None})
            records.append(SafetyTrial(**row))
    order = {m: i for i, m in enumerate(dict.fromkeys(r.method for r in records))}
    return sorted(records, key=lambda r: (r.trial, order[r.method]))
