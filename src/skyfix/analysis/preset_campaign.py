"""The seed presets solved lost in space: ``skyfix analyze presets``.

For each seed camera preset, :func:`run_campaign` renders N frames at random attitudes (seeded)
at the preset's ``[defaults]`` exposure, and solves each with no hint (``skyfix.solve(image)``)
and, for reference, with the preset's camera given (``camera=``). It runs on the campaign engine
(:func:`skyfix.montecarlo.engine.run_campaign`): a frame is a trial of :class:`PresetStudy`, one
Parquet row, the same whether run in this process, on local worker processes or on a Dask
scheduler's workers. Each solve is compared with the truth attitude at the pixel the solution
calls its boresight (:func:`skyfix.analysis.truth.attitude_error_rad`); a solve is **wrong** when
that boresight error exceeds max(60″, 1 px) or the roll error 0.5°
(:func:`skyfix.analysis.truth.is_wrong`).

A frame's **detectable** stars are those of its truth whose expected detection SNR reaches
:data:`DETECTABLE_SNR` (:func:`skyfix.analysis.preset_check.detection_snr`: the star's expected
peak in the extractor's smoothed frame over that frame's noise). Issue 10's bar: of the frames
with at least 4 detectable stars, ≥ 95% solve and none is wrong.

By default the solves use skyfix's own databases (the FOV bands, :mod:`skyfix.identify.catalogue.bands`).
Given a ``database`` (a file), they use it instead, and the presets whose field it does not serve
(:func:`~skyfix.identify.catalogue.bands.served_fov_deg`) are also solved with a database built for their
field (:meth:`PatternDatabase.build` over ``FOV / 1.1 … FOV · 1.1``): the rest of the path tested
apart from the database's range. :data:`CAMPAIGN_ROWS` adds configurations beyond the presets'
own exposures (the Droid X2 at its sensor's 1 s).

:func:`write_campaign` writes ``presets.json``, ``presets.md`` (the table, headed by the
command) and ``presets.png`` (the boresight errors per configuration); ``skyfix analyze presets``
has the engine write the trial rows beside them (``presets.parquet``). docs/presets.md has a run.
"""

from __future__ import annotations

import functools
import json
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple

import numpy as np

from skyfix.analysis._json import strict_json
from skyfix.analysis.preset_check import THESIS_FIGURES, detection_snr
from skyfix.analysis.truth import judge
from skyfix.camera import Camera
from skyfix.identify import PatternDatabase
from skyfix.identify.catalogue.bands import served_fov_deg
from skyfix.montecarlo.engine import run_rows, trial_progress
from skyfix.montecarlo.study import BatchedStudy

if TYPE_CHECKING:
    import pyarrow as pa

__all__ = ["CAMPAIGN_ROWS", "DETECTABLE_BINS", "DETECTABLE_SNR", "MIN_DETECTABLE", "Campaign", "CampaignRow",
           "FrameResult", "PresetStudy", "SolveOutcome", "campaign_of", "campaign_study", "run_campaign",
           "summarize_row", "markdown", "plot_campaign", "write_campaign"]

#: A star is detectable when its expected detection SNR reaches this: the extractor's 5σ threshold
#: plus what its 3-pixel footprint and the sub-pixel phase need. Measured (docs/presets.md): stars
#: at 8–12 are found 92–100% of the time on every preset, at 5–6 12–90%.
DETECTABLE_SNR = 8.0
#: Frames with at least this many detectable stars should solve (identification needs 4).
MIN_DETECTABLE = 4
#: The solve rate is also given by detectable stars a frame, in bins from these lower bounds.
DETECTABLE_BINS = (0, 4, 6, 8)
_ARCSEC = math.pi / (180.0 * 3600.0)


class CampaignRow(NamedTuple):
    """One configuration of the campaign: a preset at an exposure (None: its ``[defaults]``)."""

    preset: str
    exposure_s: float | None = None
    note: str = ""


#: The campaign's configurations: every preset at its own exposure, and the Droid X2 at 1 s, the
#: longest its sensor allows (thesis 003 ch. 10: the 66 ms the phone's app allowed is why it failed).
CAMPAIGN_ROWS: tuple[CampaignRow, ...] = (
    CampaignRow("generic"), CampaignRow("mt9v022"), CampaignRow("has2"), CampaignRow("sunsat"),
    CampaignRow("mt9p031"), CampaignRow("droid_x2"),
    CampaignRow("droid_x2", 1.0, "the sensor's longest exposure"), CampaignRow("ov5642"),
)


class SolveOutcome(NamedTuple):
    """One solve against the truth: errors and σ about the solution's camera axes (x, y, roll),
    radians (NaN when it failed); ``time_s`` the wall time of ``solve``."""

    solved: bool
    reason: str
    wrong: bool
    error_rad: np.ndarray
    sigma_rad: np.ndarray
    n_matched: int
    time_s: float

    @property
    def boresight_arcsec(self) -> float:
        return float(math.hypot(self.error_rad[0], self.error_rad[1]) / _ARCSEC)

    @property
    def roll_arcsec(self) -> float:
        return float(abs(self.error_rad[2]) / _ARCSEC)


class FrameResult(NamedTuple):
    """One rendered frame and its solves: ``solves`` maps ``"<database>/<blind|camera>"`` to a
    :class:`SolveOutcome` (database ``"bands"``: skyfix's default, ``"given A–B°"``: the one passed
    to :func:`run_campaign`, or ``"built A–B°"``)."""

    index: int
    ra_deg: float
    dec_deg: float
    roll_deg: float
    n_stars: int
    n_detectable: int
    solves: dict


class Campaign(NamedTuple):
    """A campaign's settings and, per configuration, its frames."""

    settings: dict
    rows: list           # [(CampaignRow, {database label: (fov_min, fov_max) or None}, [FrameResult])]


def _outcome(sol, A_true: np.ndarray, camera_true, seconds: float) -> SolveOutcome:
    nan = np.full(3, np.nan)
    if not sol.solved:
        return SolveOutcome(False, sol.reason, False, nan, nan, 0, seconds)
    verdict = judge(sol.A_icrs_to_cam, sol.camera, A_true, camera_true)
    sigma = np.sqrt(np.diag(np.asarray(sol.frame_covariance_arcsec2, dtype=np.float64))) * _ARCSEC
    return SolveOutcome(True, "", verdict.wrong, verdict.error_rad, sigma, int(sol.n_matched), seconds)


def _databases(camera, database: str | None, epoch: float) -> dict:
    """The databases a preset is solved with: {label: database or None (skyfix's bands)}. With
    ``database`` (a file) given, it, and one built for the preset's field when it does not serve it."""
    if database is None:
        return {"bands": None}
    given = _given_database(database)
    dbs = {f"given {given.fov_min_deg:g}–{given.fov_max_deg:g}°": given}
    lo, hi = served_fov_deg(given)
    fov = camera.fov_deg
    if not lo <= fov <= hi:
        lo, hi = round(fov / 1.1, 2), round(fov * 1.1, 2)
        dbs[f"built {lo:g}–{hi:g}°"] = _built_database(lo, hi, epoch)
    return dbs


@functools.lru_cache(maxsize=2)
def _given_database(path: str) -> PatternDatabase:
    """The database in ``path``, loaded once per process (a worker keeps it for its batches)."""
    return PatternDatabase.load(path)


@functools.lru_cache(maxsize=4)
def _built_database(lo: float, hi: float, epoch: float) -> PatternDatabase:
    """A database built for ``lo … hi``°, once per process."""
    return PatternDatabase.build(lo, hi, epoch=epoch)


@functools.lru_cache(maxsize=4)
def _attitudes(n: int, seed: int) -> np.ndarray:
    """The campaign's ``n`` attitudes for ``seed`` (the same for every configuration)."""
    from skyfix.analysis.synthetic_centroids import random_attitudes

    return random_attitudes(n, np.random.default_rng(seed))


#: The solves of a frame in a trial's row: (column prefix, database slot, mode). Slot "" is the
#: database the campaign was given (or skyfix's bands), slot "built_" the one built for a field
#: the given one does not serve (its columns null when there is none).
_SOLVES = (("blind_", "", "blind"), ("camera_", "", "camera"),
           ("built_blind_", "built_", "blind"), ("built_camera_", "built_", "camera"))
_AXES = ("x", "y", "roll")
_SOLVE_COLUMNS = {"solved": "bool", "wrong": "bool", "reason": "string", "n_matched": "int64",
                  **{f"{what}_{a}_rad": "float64" for what in ("error", "sigma") for a in _AXES},
                  **{f"normalised_{a}": "float64" for a in _AXES},
                  "boresight_arcsec": "float64", "roll_arcsec": "float64", "time_s": "float64"}


@dataclass(frozen=True)
class PresetStudy(BatchedStudy):
    """The campaign on the engine (:func:`skyfix.montecarlo.engine.run_campaign`): trial
    ``r·n + k`` is frame ``k`` of configuration ``r`` (``settings["rows"]``), rendered at the
    ``k``-th of the ``n`` attitudes drawn from ``seed`` with noise seed ``seed·100003 + k`` and
    solved as :func:`run_campaign` describes. Its row: the configuration, the truth, and each
    solve's outcome (columns ``blind_…``, ``camera_…``; ``built_blind_…``, ``built_camera_…``
    with a database built for the field). The databases are loaded or built once per process."""

    kind: ClassVar[str] = "preset campaign"
    columns: ClassVar[Mapping[str, str]] = {
        "trial": "int64", "preset": "string", "exposure_s": "float64", "note": "string", "frame": "int64",
        "seed": "int64", "ra_deg": "float64", "dec_deg": "float64", "roll_deg": "float64",
        "n_stars": "int64", "n_detectable": "int64",
        "database": "string", "database_fov_deg": "list<float64>",
        "built_database": "string", "built_database_fov_deg": "list<float64>",
        **{p + name: kind for p, _, _ in _SOLVES for name, kind in _SOLVE_COLUMNS.items()}}

    def run_trial(self, trial: int) -> dict[str, Any]:
        from skyfix.pipeline import solve
        from skyfix.simulate import render

        st = self.settings
        n, seed, epoch = st["n"], st["seed"], st["epoch"]
        preset, exposure_s, note = st["rows"][trial // n]
        k = trial % n
        A = _attitudes(n, seed)[k]
        frame = render(A, preset, exposure_s=exposure_s, epoch=epoch, seed=seed * 100003 + k)
        camera = Camera.from_dict(frame.truth["camera"])
        dbs = dict(zip(("", "built_"), _databases(camera, st["database"], epoch).items(), strict=False))
        truth = frame.truth
        row: dict[str, Any] = dict(
            trial=trial, preset=preset, exposure_s=exposure_s, note=note, frame=k, seed=seed * 100003 + k,
            ra_deg=truth["ra_deg"], dec_deg=truth["dec_deg"], roll_deg=truth["roll_deg"],
            n_stars=len(truth["stars"]), n_detectable=int(np.sum(detection_snr(truth) >= DETECTABLE_SNR)))
        for slot, (label, db) in dbs.items():
            row[slot + "database"] = label
            row[slot + "database_fov_deg"] = None if db is None else [db.fov_min_deg, db.fov_max_deg]
        for prefix, slot, mode in _SOLVES:
            if slot not in dbs:
                continue
            t0 = time.perf_counter()
            sol = solve(frame.image, epoch=epoch, database=dbs[slot][1],
                        **({"camera": camera} if mode == "camera" else {}))
            o = _outcome(sol, A, camera, time.perf_counter() - t0)
            row.update({prefix + name: value for name, value in _outcome_columns(o).items()})
        return row

    def warm(self) -> None:
        from skyfix import warmup

        warmup.ensure(["solve", "simulate"], missing_ok=True)


def _outcome_columns(o: SolveOutcome) -> dict[str, Any]:
    """A solve's columns (without their prefix)."""
    with np.errstate(invalid="ignore"):
        z = o.error_rad / o.sigma_rad
    return dict(solved=o.solved, wrong=o.wrong, reason=o.reason, n_matched=o.n_matched,
                **{f"error_{a}_rad": float(v) for a, v in zip(_AXES, o.error_rad, strict=True)},
                **{f"sigma_{a}_rad": float(v) for a, v in zip(_AXES, o.sigma_rad, strict=True)},
                **{f"normalised_{a}": float(v) for a, v in zip(_AXES, z, strict=True)},
                boresight_arcsec=o.boresight_arcsec, roll_arcsec=o.roll_arcsec, time_s=o.time_s)


def _outcome_of(row: Mapping[str, Any], prefix: str) -> SolveOutcome:
    """The :class:`SolveOutcome` a row's columns ``prefix…`` hold."""
    def axes(what: str) -> np.ndarray:
        return np.array([row[f"{prefix}{what}_{a}_rad"] for a in _AXES], dtype=np.float64)

    return SolveOutcome(row[prefix + "solved"], row[prefix + "reason"], row[prefix + "wrong"], axes("error"),
                        axes("sigma"), row[prefix + "n_matched"], row[prefix + "time_s"])


def campaign_study(n: int = 100, seed: int = 0, *, rows: tuple[CampaignRow, ...] = CAMPAIGN_ROWS,
                   epoch: float = 2025.0, database: str | Path | None = None,
                   batch_size: int = 10) -> PresetStudy:
    """The campaign as a study for :func:`skyfix.montecarlo.engine.run_campaign`: ``n`` frames of
    each configuration in ``rows``; ``database``: a pattern database file (its path, size and
    modification time are in the settings, so another file there is another campaign)."""
    path, file = None, None
    if database is not None:
        path = str(Path(database).resolve())
        stat = Path(path).stat()
        file = {"bytes": stat.st_size, "mtime_ns": stat.st_mtime_ns}
    settings = dict(n=n, seed=seed, epoch=epoch, rows=[[r.preset, r.exposure_s, r.note] for r in rows],
                    database=path, database_file=file,
                    detectable_snr=DETECTABLE_SNR, min_detectable=MIN_DETECTABLE)
    return PresetStudy(n * len(rows), batch_size, settings)


def campaign_of(study: PresetStudy, table: pa.Table) -> Campaign:
    """The :class:`Campaign` (its configurations and frames) that the engine's rows of ``study`` hold."""
    st = study.settings
    n, records = st["n"], table.to_pylist()
    out = []
    for r, (preset, exposure_s, note) in enumerate(st["rows"]):
        mine = records[r * n:(r + 1) * n]
        slots = [s for s in ("", "built_") if mine[0][s + "database"] is not None]
        dbs = {mine[0][s + "database"]: None if mine[0][s + "database_fov_deg"] is None
               else tuple(mine[0][s + "database_fov_deg"]) for s in slots}
        frames = [FrameResult(rec["frame"], rec["ra_deg"], rec["dec_deg"], rec["roll_deg"], rec["n_stars"],
                              rec["n_detectable"],
                              {f"{rec[slot + 'database']}/{mode}": _outcome_of(rec, prefix)
                               for prefix, slot, mode in _SOLVES if slot in slots})
                  for rec in mine]
        out.append((CampaignRow(preset, exposure_s, note), dbs, frames))
    return Campaign({k: st[k] for k in ("n", "seed", "epoch", "detectable_snr", "min_detectable")}, out)


def run_campaign(n: int = 100, seed: int = 0, *, rows: tuple[CampaignRow, ...] = CAMPAIGN_ROWS,
                 epoch: float = 2025.0, database: str | Path | None = None, workers: int = 0,
                 scheduler: str | None = None, output: str | Path | None = None, batch_size: int = 10,
                 progress: Callable[[int, int], None] | None = None) -> Campaign:
    """Render ``n`` frames per configuration in ``rows`` at random attitudes (seeded; the same
    attitudes for every configuration) and solve each with no hint and with the camera given,
    with skyfix's databases or, given one (a file), with ``database`` and, for fields it does not
    serve, one built for the field — on the campaign engine: ``workers=0`` in this process, else
    that many local worker processes, or the Dask ``scheduler``'s workers
    (:func:`skyfix.montecarlo.engine.run_rows`). ``output``: the trial rows' Parquet file
    (resumable; default: a temporary one). ``progress(frames done, frames)``."""
    study = campaign_study(n, seed, rows=rows, epoch=epoch, database=database, batch_size=batch_size)
    table = run_rows(study, output, workers=workers, scheduler=scheduler,
                     progress=trial_progress(study, progress))
    return campaign_of(study, table)


def _percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else math.nan


def summarize_row(frames: list[FrameResult], key: str) -> dict:
    """The numbers of one configuration's solves ``key`` (``"bands/blind"``, …): frames, frames
    with ≥ 4 detectable stars and how many of those solved, wrong solves (all frames), boresight
    and roll errors (median, 95th percentile, arcsec), normalised error RMS per axis (x, y, roll)
    and the median solve time."""
    outs = [f.solves[key] for f in frames]
    able = [f.n_detectable >= MIN_DETECTABLE for f in frames]
    solved = [o for o in outs if o.solved]
    bore = [o.boresight_arcsec for o in solved]
    roll = [o.roll_arcsec for o in solved]
    z = np.array([o.error_rad / o.sigma_rad for o in solved]) if solved else np.zeros((0, 3))
    n_able = int(sum(able))
    n_able_solved = sum(1 for o, a in zip(outs, able, strict=True) if a and o.solved)
    reasons: dict[str, int] = {}
    for o in outs:
        if not o.solved:
            short = o.reason.split(":")[0].split(" after ")[0].split("(")[0][:60].strip()
            reasons[short] = reasons.get(short, 0) + 1
    return dict(
        frames=len(frames), detectable_median=float(np.median([f.n_detectable for f in frames])),
        frames_4_detectable=n_able, solved=len(solved), solved_of_4_detectable=n_able_solved,
        solved_pct_of_4_detectable=100.0 * n_able_solved / n_able if n_able else math.nan,
        wrong=sum(o.wrong for o in solved),
        boresight_median_arcsec=_percentile(bore, 50), boresight_p95_arcsec=_percentile(bore, 95),
        roll_median_arcsec=_percentile(roll, 50), roll_p95_arcsec=_percentile(roll, 95),
        normalised_rms=np.sqrt(np.mean(z**2, axis=0)).tolist() if len(z) else [math.nan] * 3,
        time_median_ms=1000.0 * float(np.median([o.time_s for o in outs])),
        solved_by_detectable=_by_detectable(frames, outs),
        failures=dict(sorted(reasons.items(), key=lambda kv: -kv[1])))


_MODE_TEXT = {"blind": "no hint", "camera": "camera given"}


def _by_detectable(frames: list[FrameResult], outs: list[SolveOutcome]) -> dict:
    """{bin label: [solved, frames]} over :data:`DETECTABLE_BINS`."""
    edges = (*DETECTABLE_BINS, math.inf)
    out = {}
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        label = f"{lo}–{hi - 1:g}" if math.isfinite(hi) else f"≥ {lo}"
        sel = [o.solved for f, o in zip(frames, outs, strict=True) if lo <= f.n_detectable < hi]
        out[label] = [sum(sel), len(sel)]
    return out


def _fmt(v: float, digits: int = 1) -> str:
    return "–" if v is None or not math.isfinite(v) else f"{v:.{digits}f}"


def _thesis_text(preset: str) -> str:
    fig = THESIS_FIGURES.get(preset)
    if fig is None or fig.boresight_arcsec is None:
        return "–"
    return f"{fig.boresight_arcsec:g}″ ({fig.thesis})"


def markdown(campaign: Campaign, command: str) -> str:
    """The campaign's tables (Markdown), headed by the command that made them: the numbers of each
    configuration, its solve rate by detectable stars a frame, then why frames failed."""
    st = campaign.settings
    summaries = [(f"{row.preset} | {_exposure_text(row)} | {label} | {_MODE_TEXT[mode]}", row.preset,
                  summarize_row(frames, f"{label}/{mode}"))
                 for row, dbs, frames in campaign.rows for label in dbs for mode in ("blind", "camera")]
    lines = [f"Generated by `{command}` (N = {st['n']} frames a configuration, seed {st['seed']}, epoch "
             f"{st['epoch']}; detectable: expected detection SNR ≥ {st['detectable_snr']:g}).", "",
             "| preset | exposure | database | solve | frames | median detectable | ≥ 4 detectable | "
             "solved of those | solved (all) | wrong | boresight median / p95 (″) | roll median / p95 (″) | "
             "normalised RMS x / y / roll | median time (ms) | thesis boresight |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for config, preset, s in summaries:
        z = " / ".join(_fmt(v, 2) for v in s["normalised_rms"])
        lines.append(
            f"| {config} | {s['frames']} | {s['detectable_median']:g} | {s['frames_4_detectable']} | "
            f"{s['solved_of_4_detectable']} ({_fmt(s['solved_pct_of_4_detectable'], 0)}%) | {s['solved']} | "
            f"{s['wrong']} | {_fmt(s['boresight_median_arcsec'], 2)} / "
            f"{_fmt(s['boresight_p95_arcsec'], 2)} | "
            f"{_fmt(s['roll_median_arcsec'])} / {_fmt(s['roll_p95_arcsec'])} | {z} | "
            f"{_fmt(s['time_median_ms'], 0)} | {_thesis_text(preset)} |")
    bins = list(summaries[0][2]["solved_by_detectable"]) if summaries else []
    lines += ["", "Solved by detectable stars a frame (solved / frames):", "",
              "| preset | exposure | database | solve | " + " | ".join(bins) + " |",
              "|---|---|---|---|" + "---|" * len(bins)]
    for config, _, s in summaries:
        cells = [f"{a}/{b}" if b else "–" for a, b in s["solved_by_detectable"].values()]
        lines.append(f"| {config} | " + " | ".join(cells) + " |")
    lines += ["", "Failures:", ""]
    failures = [f"- {config.replace(' | ', ', ')}: {_failure_text(s['failures'])}"
                for config, _, s in summaries if s["failures"]]
    return "\n".join(lines + (failures or ["- none"]) + [""])


def _failure_text(failures: dict) -> str:
    return "; ".join(f"{why} × {n}" for why, n in failures.items())


def _exposure_text(row: CampaignRow) -> str:
    if row.exposure_s is None:
        from skyfix.simulate import load_preset

        return f"{load_preset(row.preset)['defaults']['exposure_s']:g} s"
    return f"{row.exposure_s:g} s"


def plot_campaign(campaign: Campaign, path: str | Path) -> Path:
    """Histograms of the boresight errors (no hint and camera given), one panel per configuration
    and database with a solve, the thesis's figure as a dashed line; the configurations with none
    are named under the panels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def errors(frames, key):
        return [f.solves[key].boresight_arcsec for f in frames if f.solves[key].solved]

    panels, empty = [], []
    for row, dbs, frames in campaign.rows:
        for label in dbs:
            has_any = any(errors(frames, f"{label}/{mode}") for mode in ("blind", "camera"))
            (panels if has_any else empty).append((row, label, frames))
    ncol = 3
    nrow = max(1, math.ceil(len(panels) / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 2.8 * nrow + 0.5), squeeze=False)
    bins = np.logspace(-2, 4, 49)
    for ax, (row, label, frames) in zip(axes.ravel(), panels, strict=False):
        for mode, colour in (("blind", "#1f77b4"), ("camera", "#ff7f0e")):
            errs = errors(frames, f"{label}/{mode}")
            ax.hist(np.clip(errs, 1e-2, 1e4), bins=bins, histtype="step", color=colour,
                    label=f"{_MODE_TEXT[mode]}: {len(errs)}/{len(frames)} solved")
        thesis = THESIS_FIGURES.get(row.preset)
        if thesis is not None and thesis.boresight_arcsec:
            ax.axvline(thesis.boresight_arcsec, color="k", ls="--", lw=1, label=f"thesis {thesis.thesis}")
        ax.set_xscale("log")
        ax.set_title(f"{row.preset} {_exposure_text(row)}, {label}", fontsize=9)
        ax.set_xlabel("boresight error (″)", fontsize=8)
        ax.legend(fontsize=7)
    for ax in axes.ravel()[len(panels):]:
        ax.axis("off")
    if empty:
        names = ", ".join(f"{row.preset} {_exposure_text(row)} ({label})" for row, label, _ in empty)
        fig.text(0.01, 0.005, f"no frame solved: {names}", fontsize=8)
    fig.tight_layout(rect=(0, 0.03 if empty else 0, 1, 1))
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def _frame_json(frame: FrameResult) -> dict:
    solves = {k: dict(o._asdict(), boresight_arcsec=o.boresight_arcsec, roll_arcsec=o.roll_arcsec)
              for k, o in frame.solves.items()}
    return dict(frame._asdict(), solves=solves)


def write_campaign(campaign: Campaign, out_dir: str | Path, command: str = "skyfix analyze presets"
                   ) -> list[Path]:
    """Write ``presets.json`` (every frame's solves), ``presets.md`` and ``presets.png``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for row, dbs, frames in campaign.rows:
        summary = {f"{label}/{mode}": summarize_row(frames, f"{label}/{mode}") for label in dbs
                   for mode in ("blind", "camera")}
        rows.append(dict(preset=row.preset, exposure_s=row.exposure_s, note=row.note, databases=dbs,
                         summary=summary, frames=[_frame_json(f) for f in frames]))
    pj = out / "presets.json"
    pj.write_text(json.dumps(strict_json({"settings": campaign.settings, "command": command, "rows": rows})))
    pm = out / "presets.md"
    pm.write_text(markdown(campaign, command))
    return [pj, pm, plot_campaign(campaign, out / "presets.png")]
