"""The identification study's safety case (:func:`run_safety`, ``skyfix analyze identification
--case safety``; in the full study beside the grid): issue 11's "no method reports a wrong attitude
in ≥ 10⁴ noisy trials".

Each frame draws the study's axes at random (:func:`safety_draw`: FOV, centroid noise, false
stars, dropped stars, magnitude noise, camera given or FOV only; a share of frames holding only
their 3, or 4–5, brightest stars) and every method solves it as a user would, through
:func:`skyfix.pipeline.solve_centroids` (:func:`safety_trial`); a solve is wrong by the one
definition (:func:`skyfix.analysis.truth.is_wrong`: boresight beyond max(60″, 1 px) or roll beyond
0.5°). Every frame is a function of (seed, frame number), so a wrong one is replayed by
:func:`replay_safety`.

The case is a study on the campaign engine (:class:`SafetyStudy`,
:func:`skyfix.montecarlo.engine.run_campaign`): a trial is one method on one frame, a row of
``identification_safety.parquet``; a stopped run keeps its finished batches and the same command
continues it (:func:`read_safety` reads a stopped run's rows).
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from skyfix.analysis._json import strict_json
from skyfix.analysis.identification_jobs import (
    EPOCH,
    HEIGHT,
    MAG_LIMIT,
    WIDTH,
    MethodTrials,
    method_names,
    record_columns,
    upper_bound_95,
)
from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
from skyfix.analysis.truth import judge
from skyfix.camera import Camera
from skyfix.catalog import load_hipparcos
from skyfix.identify import default_database
from skyfix.montecarlo.engine import cluster, run_rows

if TYPE_CHECKING:
    import pyarrow as pa

__all__ = ["SAFETY_BOUNDS", "SAFETY_FULL", "SAFETY_MIX", "SAFETY_QUICK", "SAFETY_STUDY", "SafetyDraw",
           "SafetyMix", "SafetySettings", "SafetyStudy", "SafetyTrial", "read_safety", "replay_safety",
           "run_safety", "run_safety_block", "safety_draw", "safety_field", "safety_frame", "safety_json",
           "safety_markdown", "safety_plot", "safety_records", "safety_result", "safety_study",
           "safety_summary", "safety_trial", "write_safety"]

_ARCSEC = math.pi / (180.0 * 3600.0)


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
    wrong: bool  # solved and wrong (truth.is_wrong: boresight > max(60″, 1 px) or roll > 0.5°)
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


def safety_trial(method: str, draw: SafetyDraw, camera: Camera, field, bounds: dict[str, dict] | None = None,
                 database=None) -> SafetyTrial:
    """``method`` on one safety frame, through the solve a user calls
    (:func:`skyfix.pipeline.solve_centroids` with ``identify_method=method``: the final fit, the
    precision rule and — for the default method — the sparse-field fallback included), judged
    against the truth. ``database``: the one pattern database to search (None: the default FOV
    bands, as a user's solve)."""
    from skyfix.pipeline import solve_centroids

    told = {"camera": camera} if draw.camera_given else {"fov_deg": draw.fov_deg,
                                                        "fov_tolerance_deg": 0.1 * draw.fov_deg}
    options = _safety_options(method, SAFETY_BOUNDS if bounds is None else bounds)
    t0 = time.perf_counter()
    try:
        sol = solve_centroids(field.xy, WIDTH, HEIGHT, identify_method=method, epoch=EPOCH, database=database,
                              **told, **options)
        solved, reason = sol.solved, sol.reason
    except Exception as exc:  # a method's bug is its failure here, not the study's end
        sol, solved, reason = None, False, f"error: {type(exc).__name__}: {exc}"
    dt = 1e3 * (time.perf_counter() - t0)
    bore = roll = norm = math.nan
    wrong = False
    if solved:
        verdict = judge(sol.A_icrs_to_cam, sol.camera, field.A_icrs_to_cam, camera)
        wrong, bore, roll = verdict.wrong, verdict.boresight_arcsec, verdict.roll_deg
        e = verdict.error_rad / _ARCSEC
        try:
            norm = float(math.sqrt(e @ np.linalg.solve(np.asarray(sol.frame_covariance_arcsec2), e)))
        except (np.linalg.LinAlgError, ValueError):
            norm = math.inf
    return SafetyTrial(method, draw.trial, draw.fov_deg, draw.sigma_px, draw.n_false, draw.dropout,
                       draw.mag_sigma, draw.camera_given, draw.bright_stars, int(np.sum(field.star_id > 0)),
                       len(field.xy), bool(solved), bool(wrong), bore, roll, norm,
                       int(sol.n_matched) if solved else 0, float(sol.prob_false) if solved else math.nan, dt,
                       reason)


def _safety_context(bands: bool) -> tuple:
    """The catalogue and the database (None: the default bands) a batch of safety frames shares."""
    catalog = load_hipparcos(epoch=EPOCH, mag_limit=MAG_LIMIT + 1.0)
    return catalog, None if bands else default_database(progress=False)


def safety_frame(trial: int, methods: list[str], seed: int, mix: SafetyMix, bounds: dict[str, dict] | None,
                 catalog, database) -> list[SafetyTrial]:
    """Every method in ``methods`` on safety frame ``trial``."""
    draw = safety_draw(trial, seed, mix)
    camera, field = safety_field(draw, catalog, seed)
    return [safety_trial(m, draw, camera, field, bounds, database) for m in methods]


def run_safety_block(trials: range, methods: list[str], seed: int = 0, mix: SafetyMix = SAFETY_MIX,
                     bounds: dict[str, dict] | None = None, bands: bool = True) -> list[SafetyTrial]:
    """Every method on the safety frames ``trials``, interleaved frame by frame; ``bands`` as
    :class:`SafetySettings`'s."""
    context = _safety_context(bands)
    return [r for t in trials for r in safety_frame(t, methods, seed, mix, bounds, *context)]


def replay_safety(trial: int, method: str, seed: int = 0, mix: SafetyMix = SAFETY_MIX,
                  bounds: dict[str, dict] | None = None, bands: bool = True) -> SafetyTrial:
    """Replay one safety trial (a wrong one from the JSON's ``safety.wrong``; ``bands`` as its
    settings')."""
    return run_safety_block(range(trial, trial + 1), [method], seed, mix, bounds, bands)[0]


class SafetySettings(NamedTuple):
    """What :func:`run_safety` runs."""

    trials: int = 10_000  # frames; every method solves each one
    first: int = 0  # the first frame's number (a campaign split in parts: frames first … first + trials − 1)
    methods: tuple[str, ...] = ()  # empty: every registered method
    seed: int = 0
    workers: int = 0  # 0: in this process; N: a local Dask cluster of N worker processes
    mix: SafetyMix = SAFETY_MIX
    block: int = 1  # frames per engine batch (~0.64 CPU-s a frame for the nine methods on average)
    # Solve against the default FOV bands, each built on first need (as a user's solve); False: the
    # standard band's database alone (nothing else built: the quick run's frames are all 15°).
    bands: bool = True


SAFETY_FULL = SafetySettings()  # 10⁴ frames: ~0.64 CPU-s a frame for the nine methods (~53 min on 2 cores)
# The whole study's share: 10³ frames (~5 min of 2 cores), so that grid, safety sample and seed
# experiments run in one command; the 10⁴ frames are `--case safety` alone (SAFETY_FULL).
SAFETY_STUDY = SafetySettings(trials=1_000)
# The quick run's: 15° frames with the FOV told (the grid's tables serve them: none built for other
# fields or for a calibrated camera, ~130 MB) against the standard band's database alone (the
# narrow, wide and fine bands and the Gaia catalogue, ~290 MB on disk, are neither built nor
# loaded, and a frame that fails is not searched again in them).
SAFETY_QUICK = SafetySettings(trials=20, block=2, bands=False,
                              mix=SAFETY_MIX._replace(fovs_deg=(15.0,), camera_given_share=0.0))


@dataclass(frozen=True)
class SafetyStudy(MethodTrials):
    """The safety case on the campaign engine: frame ``k`` of the study is safety frame
    ``first + k`` (:func:`safety_draw`), solved by every method (a row each: :class:`SafetyTrial`,
    the frame's number the column ``frame``). Build it with :func:`safety_study`."""

    kind = "identification-safety"
    record = SafetyTrial
    number = "frame"
    columns = record_columns(SafetyTrial, "frame")

    def context(self) -> Any:
        return _safety_context(self.settings["bands"])

    def solve_frame(self, context: Any, frame: int, methods: list[str]) -> list[SafetyTrial]:
        s = self.settings
        mix = SafetyMix(**{**s["mix"], "fovs_deg": tuple(s["mix"]["fovs_deg"])})
        return safety_frame(s["first"] + frame, methods, s["seed"], mix, s["bounds"], *context)

    def warm_args(self) -> tuple[list[str], tuple[float, ...], bool]:
        mix = self.settings["mix"]
        return self.methods, tuple(mix["fovs_deg"]), mix["camera_given_share"] > 0


def safety_study(settings: SafetySettings, methods: list[str]) -> SafetyStudy:
    """The safety case of ``settings`` (its workers aside) as a study of ``methods``."""
    return SafetyStudy(settings.trials * len(methods), max(1, int(settings.block)) * len(methods),
                       {"methods": list(methods), "first": settings.first, "seed": settings.seed,
                        "mix": settings.mix._asdict(), "bounds": SAFETY_BOUNDS, "bands": settings.bands})


def run_safety(settings: SafetySettings = SAFETY_FULL,
               progress: Callable[[int, int], None] | None = None, *, out: str | Path | None = None,
               scheduler: str | None = None) -> dict:
    """The safety case: ``settings.trials`` random frames (:func:`safety_draw`), each solved by
    every method through :func:`skyfix.pipeline.solve_centroids`, on the campaign engine
    (``settings.workers`` local processes, or ``scheduler``; 0 and none: in this process).
    ``out``: the rows' Parquet (a stopped run's finished batches are kept beside it and the same
    call continues; None: a temporary file). ``progress(done, total)``: batches finished.
    Returns ``{"settings", "records"}`` (records as :class:`SafetyTrial`, in frame then method
    order)."""
    methods = method_names(settings.methods)
    with cluster(settings.workers, scheduler) as client:
        table = run_rows(safety_study(settings, methods), out, client=client, fresh=True, progress=progress)
    return safety_result(settings, methods, safety_records(table))


def safety_records(table: pa.Table) -> list[SafetyTrial]:
    """A safety study's rows as records, in frame then method order."""
    return SafetyStudy.records(table)


def safety_result(settings: SafetySettings, methods: list[str], records: list[SafetyTrial]) -> dict:
    meta = dict(settings._asdict(), mix=settings.mix._asdict(), methods=methods, camera=f"{WIDTH}×{HEIGHT}",
                mag_limit=MAG_LIMIT, epoch=EPOCH, bounds=SAFETY_BOUNDS, cpu_count=os.cpu_count())
    return {"settings": meta, "records": records}


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
             "identify_method=NAME)`; **wrong**: solved with the boresight > max(60″, 1 px) or the "
             "roll > 0.5° from the truth.\n",
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
        lines += ["\nWrong trials (replay: `identification_safety.replay_safety(trial, method, seed)`):\n",
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


def read_safety(path: str | Path) -> list[SafetyTrial]:
    """The records of a safety run's Parquet — or of a stopped run, its finished batches
    (``identification_safety.parquet.parts``; several parts' tables may be given one by one and
    added) — in frame then method order, for :func:`safety_summary`, :func:`safety_markdown` and
    :func:`safety_plot` when a run was stopped or split."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = Path(path)
    files = sorted(path.glob("batch-*.parquet")) if path.is_dir() else [path]
    table = pa.concat_tables([pq.read_table(p) for p in files]).sort_by("trial")
    return safety_records(table)
