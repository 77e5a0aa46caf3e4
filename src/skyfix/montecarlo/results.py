"""A campaign's results: one Parquet row per trial (:data:`COLUMNS`), its summary and its plots.

The row holds the trial's inputs (every parameter of the level, the true attitude), the
solution, its errors — per axis about the solution's camera axes (x, y cross-boresight, roll),
the boresight and roll errors, each axis normalised by the σ the solution reports — the
predicted σ (centroid level), the status and the times.

The **summary** (:func:`summarize`) is a function of the rows sorted by trial, the times left
out, so it is bit-identical whatever the worker count and however the run was interrupted:

- availability: solved / trials;
- wrong-attitude rate: wrong / solved (:func:`skyfix.analysis.truth.is_wrong`) with its one-sided
  95 % Clopper–Pearson upper bound;
- error percentiles (50, 90, 99 %, max) of the right solutions' boresight and roll errors, the
  per-axis RMS, the normalised errors' RMS (honest error bars: 1), and the RMS predicted by
  :mod:`skyfix.montecarlo.budget` beside the measured one;
- ``prob_false`` calibration: the wrong solutions expected, Σ ``prob_false`` over the solved
  trials, against those seen, with the Poisson chance of seeing that many or more (below 5 %:
  ``prob_false`` underestimates the risk);
- the same figures per value of each swept parameter (a drawn parameter in 5 equal bins).

The times go into a separate ``timing`` entry (trials per second, median solve and simulate ms).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from skyfix.montecarlo.campaign import PARAMETERS, Campaign

if TYPE_CHECKING:
    import pyarrow as pa

__all__ = ["COLUMNS", "Column", "batch_table", "plot_results", "schema", "summary_lines", "summarize",
           "timing", "write_summary"]


class Column(NamedTuple):
    """A result column: its Arrow type name and what it holds."""

    type: str
    help: str


_AXES = ("x", "y", "roll")
#: The columns of a results row, in order; the level's parameters follow ``seed``.
COLUMNS: dict[str, Column] = {
    "trial": Column("int64", "trial index, 0 … trials − 1"),
    "seed": Column("int64", "the trial's seed (skyfix.montecarlo.trials.trial_seed): it replays the trial"),
    "ra_true_deg": Column("float64", "true boresight RA, °"),
    "dec_true_deg": Column("float64", "true boresight Dec, °"),
    "roll_true_deg": Column("float64", "true roll, °"),
    "plate_scale_arcsec": Column("float64", "one pixel of the true camera at its centre, ″"),
    "n_stars": Column("int32", "catalogue stars in the frame (centroid level: those detected)"),
    "n_detected": Column("int32", "centroids the solver was given or found"),
    "status": Column("string", "solved, failed or error (an exception in a stage; reason says which)"),
    "reason": Column("string", "why it failed"),
    "wrong": Column("bool", "solved but wrong (skyfix.analysis.truth.is_wrong)"),
    "n_matched": Column("int32", "stars matched"),
    "n_mismatched": Column("int32", "matches whose catalogue star is not the centroid's true star (a false "
                                    "star matched counts; centroid level, null at the image level)"),
    "prob_false": Column("float64", "the solution's chance of being a coincidence"),
    "ra_deg": Column("float64", "solved boresight RA, °"),
    "dec_deg": Column("float64", "solved boresight Dec, °"),
    "roll_deg": Column("float64", "solved roll, °"),
    "boresight_error_arcsec": Column("float64", "boresight error, ″"),
    "roll_error_arcsec": Column("float64", "roll error (absolute), ″"),
    **{f"error_{a}_arcsec": Column("float64", f"error about the solution's {a} axis, ″ (signed)")
       for a in _AXES},
    **{f"sigma_{a}_arcsec": Column("float64", f"reported σ about {a}, ″") for a in _AXES},
    **{f"normalised_{a}": Column("float64", f"error / reported σ about {a}") for a in _AXES},
    **{f"predicted_sigma_{a}_arcsec": Column("float64", f"Cramér–Rao σ about {a}, ″ (centroid level)")
       for a in _AXES},
    "simulate_ms": Column("float64", "time to simulate the frame, ms"),
    "time_ms": Column("float64", "time to solve, ms"),
}
_PARAMETER_TYPES = {float: "float64", int: "int64", str: "string", bool: "bool"}
_TIMES = ("simulate_ms", "time_ms")
_PERCENTILES = (50, 90, 99)
_DRAWN_BINS = 5
#: The edges of the ``prob_false`` bins of the calibration (the last bin holds 1 too).
_PROB_FALSE_BINS = (0.0, 1e-9, 1e-6, 1e-4, 1e-3, 1e-2, 1e-1, 1.0)


def schema(campaign: Campaign) -> pa.Schema:
    """The Arrow schema of ``campaign``'s results, the campaign (JSON) in its metadata."""
    import pyarrow as pa

    names = list(COLUMNS)
    fields = [pa.field(n, COLUMNS[n].type) for n in names[:2]]
    fields += [pa.field(n, _PARAMETER_TYPES[PARAMETERS[n].kind]) for n in campaign.parameter_names]
    fields += [pa.field(n, COLUMNS[n].type) for n in names[2:]]
    meta = {"skyfix.campaign": json.dumps(campaign.to_dict(), default=str),
            "skyfix.fingerprint": campaign.fingerprint}
    return pa.schema(fields, metadata=meta)


def batch_table(campaign: Campaign, rows: Iterable[Mapping[str, Any]]) -> pa.Table:
    """Rows (dicts from :func:`skyfix.montecarlo.trials.run_trial`) as a table of :func:`schema`;
    a column a row lacks (a failed trial's solution) is null."""
    import pyarrow as pa

    return pa.Table.from_pylist([dict(r) for r in rows], schema=schema(campaign))


# --- summary -----------------------------------------------------------------------------------
def _upper_bound_95(k: int, n: int) -> float:
    from skyfix.analysis.truth import upper_bound_95

    return upper_bound_95(k, n)


def _column(table: pa.Table, name: str, dtype=np.float64) -> np.ndarray:
    return table.column(name).to_numpy(zero_copy_only=False).astype(dtype)


def _figures(table: pa.Table) -> dict[str, Any]:
    """Availability, wrong rate, errors and calibration of a set of rows (see the module text)."""
    status = _column(table, "status", object)
    wrong = np.array([bool(w) for w in table.column("wrong").to_pylist()])
    n, solved = len(status), int(np.sum(status == "solved"))
    k = int(wrong.sum())
    out: dict[str, Any] = {
        "trials": n, "solved": solved, "failed": int(np.sum(status == "failed")),
        "errors": int(np.sum(status == "error")), "wrong": k,
        "availability": solved / n if n else math.nan,
        "wrong_rate": k / solved if solved else math.nan,
        "wrong_rate_upper_95": _upper_bound_95(k, solved),
    }
    right = (status == "solved") & ~wrong
    err = {a: _column(table, f"error_{a}_arcsec")[right] for a in _AXES}
    for name in ("boresight_error_arcsec", "roll_error_arcsec"):
        v = _column(table, name)[right]
        out[name] = ({f"p{p}": float(np.percentile(v, p)) for p in _PERCENTILES} | {"max": float(v.max())}
                     if len(v) else {})
    out["rms_arcsec"] = {a: _rms(err[a]) for a in _AXES}
    out["normalised_rms"] = {a: _rms(_column(table, f"normalised_{a}")[right]) for a in _AXES}
    predicted = {a: _column(table, f"predicted_sigma_{a}_arcsec")[right] for a in _AXES}
    out["predicted_rms_arcsec"] = {a: _rms(predicted[a]) for a in _AXES}
    out["rms_over_predicted"] = {a: _ratio(out["rms_arcsec"][a], out["predicted_rms_arcsec"][a])
                                 for a in _AXES}
    solved_mask = status == "solved"
    mismatched = _column(table, "n_mismatched")
    # wrong by identification: a wrong star among the matches (not known at the image level: all)
    by_match = wrong & ~(mismatched == 0)
    out["wrong_identification"] = int(by_match.sum())
    out["wrong_precision"] = k - out["wrong_identification"]
    out["prob_false"] = _calibration(_column(table, "prob_false")[solved_mask], by_match[solved_mask])
    return out


def _calibration(prob_false: np.ndarray, wrong: np.ndarray) -> dict[str, Any]:
    """``prob_false`` against the solutions wrong by identification: overall, Σ ``prob_false``
    (the wrong ones expected) against those seen with the Poisson chance of seeing as many or
    more; and per bin of ``prob_false`` (:data:`_PROB_FALSE_BINS`), the wrong rate seen with its
    one-sided 95 % Clopper–Pearson bounds beside the mean ``prob_false`` — calibrated while the
    lower bound is not above it (the rate seen is never above the predicted one beyond its
    bound)."""
    k, expected = int(wrong.sum()), float(np.nansum(prob_false))
    bins = []
    for low, high in zip(_PROB_FALSE_BINS[:-1], _PROB_FALSE_BINS[1:], strict=True):
        inside = (prob_false >= low) & (prob_false < high) if high < 1 else (prob_false >= low)
        n, kb = int(inside.sum()), int(wrong[inside].sum())
        if not n:
            continue
        mean = float(np.mean(prob_false[inside]))
        lower = _lower_bound_95(kb, n)
        bins.append({"low": low, "high": high, "solved": n,
                     "expected_wrong": float(np.sum(prob_false[inside])), "mean_prob_false": mean,
                     "wrong": kb, "rate": kb / n, "rate_lower_95": lower,
                     "rate_upper_95": _upper_bound_95(kb, n), "calibrated": bool(lower <= mean)})
    p = _poisson_tail(k, expected)
    return {"expected_wrong": expected, "observed_wrong": k, "p_value": p, "calibrated": bool(p >= 0.05),
            "bins_calibrated": all(b["calibrated"] for b in bins), "bins": bins}


def _lower_bound_95(k: int, n: int) -> float:
    """One-sided 95 % Clopper–Pearson lower bound of a rate seen ``k`` times in ``n``."""
    if k <= 0 or n <= 0:
        return 0.0
    from scipy.stats import beta

    return float(beta.ppf(0.05, k, n - k + 1))


def _rms(v: np.ndarray) -> float:
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v**2))) if len(v) else math.nan


def _ratio(a: float, b: float) -> float:
    return a / b if math.isfinite(a) and math.isfinite(b) and b > 0 else math.nan


def _poisson_tail(k: int, mean: float) -> float:
    """P(X ≥ k) for X ~ Poisson(``mean``)."""
    if k <= 0:
        return 1.0
    from scipy.stats import poisson

    return float(poisson.sf(k - 1, mean))


def summarize(table: pa.Table, campaign: Campaign) -> dict[str, Any]:
    """The campaign's summary (see the module text): overall, per swept value, and the timing."""
    table = table.sort_by("trial")
    out: dict[str, Any] = {"campaign": campaign.name, "level": campaign.level,
                           "fingerprint": campaign.fingerprint, **_figures(table)}
    by: dict[str, list] = {}
    for axis in campaign.sweep:
        values = table.column(axis.name).to_numpy(zero_copy_only=False)
        groups = []
        if axis.drawn:
            edges = np.linspace(axis.low, axis.high, _DRAWN_BINS + 1)
            which = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, _DRAWN_BINS - 1)
            for b in range(_DRAWN_BINS):
                groups.append(({"low": float(edges[b]), "high": float(edges[b + 1])}, which == b))
        else:
            groups = [({"value": v}, values == v) for v in axis.values]
        by[axis.name] = [{**key, **_figures(table.filter(mask))} for key, mask in groups if mask.any()]
    out["by_parameter"] = by
    return out


def timing(table: pa.Table, n: int, wall_s: float, workers: int) -> dict[str, float]:
    """Throughput of a run that ran ``n`` trials in ``wall_s`` (its start-up included): trials per
    second overall and per worker, median simulate and solve ms of ``table`` (not part of
    :func:`summarize`: times differ run to run)."""
    return {"wall_s": wall_s, "workers": workers, "trials_per_s": n / wall_s if wall_s > 0 else math.nan,
            "trials_per_s_per_worker": n / wall_s / max(workers, 1) if wall_s > 0 else math.nan,
            **{f"median_{t}": float(np.nanmedian(_column(table, t))) if table.num_rows else math.nan
                for t in _TIMES}}


def summary_lines(summary: Mapping[str, Any]) -> list[str]:
    """The summary in a few lines of text."""
    s = summary
    lines = [f"{s['campaign']}: {s['trials']} trials ({s['level']} level): {s['solved']} solved "
             f"({100 * s['availability']:.2f} %), {s['failed']} failed, {s['errors']} errors; "
             f"{s['wrong']} wrong (rate ≤ {s['wrong_rate_upper_95']:.2g} at 95 %)"]
    if s["boresight_error_arcsec"]:
        b, r = s["boresight_error_arcsec"], s["roll_error_arcsec"]
        lines.append("boresight error p50/p90/p99/max " + "/".join(f"{b[k]:.2f}" for k in b) + "″, roll "
                     + "/".join(f"{r[k]:.1f}" for k in r) + "″")
        rms, z, pred = s["rms_arcsec"], s["normalised_rms"], s["predicted_rms_arcsec"]
        lines.append("RMS x/y/roll " + "/".join(f"{rms[a]:.3f}" for a in _AXES) + "″; normalised "
                     + "/".join(f"{z[a]:.3f}" for a in _AXES)
                     + ("" if not math.isfinite(pred["x"]) else
                        "; predicted " + "/".join(f"{pred[a]:.3f}" for a in _AXES) + "″ (measured/predicted "
                        + "/".join(f"{s['rms_over_predicted'][a]:.3f}" for a in _AXES) + ")"))
    pf = s["prob_false"]
    lines.append(f"prob_false: {pf['expected_wrong']:.3g} wrong identifications expected, "
                 f"{pf['observed_wrong']} seen (P = {pf['p_value']:.3g}: "
                 f"{'calibrated' if pf['calibrated'] else 'UNDERESTIMATES the risk'}); "
                 f"{s['wrong_precision']} wrong with every star right (the precision rule's)")
    for b in pf["bins"]:
        lines.append(f"  prob_false {b['low']:.0e}–{b['high']:.0e}: {b['wrong']} wrong of {b['solved']}, "
                     f"rate ≥ {b['rate_lower_95']:.2g} at 95 % vs mean predicted {b['mean_prob_false']:.2g}"
                     f"{'' if b['calibrated'] else ': UNDERESTIMATED'}")
    if "timing" in s:
        t = s["timing"]
        lines.append(f"{t['trials_per_s']:.1f} trials/s with {t['workers']} worker(s) "
                     f"({t['trials_per_s_per_worker']:.1f}/s/worker; median simulate "
                     f"{t['median_simulate_ms']:.2f} ms, solve {t['median_time_ms']:.2f} ms), "
                     f"{t['wall_s']:.1f} s")
    return lines


def write_summary(summary: Mapping[str, Any], path: Path) -> None:
    """The summary as strict JSON."""
    from skyfix.analysis._json import strict_json

    path.write_text(json.dumps(strict_json(dict(summary)), indent=1) + "\n")


# --- plots -------------------------------------------------------------------------------------
def plot_results(table: pa.Table, campaign: Campaign, path: Path) -> None:
    """One PNG: error histograms, normalised errors against N(0, 1), the errors against each swept
    parameter, and a sky map of the failed and wrong trials."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table = table.sort_by("trial")
    status = _column(table, "status", object)
    wrong = np.array([bool(w) for w in table.column("wrong").to_pylist()])
    right = (status == "solved") & ~wrong
    n_sweep = len(campaign.sweep)
    fig = plt.figure(figsize=(12, 8 + 3.2 * math.ceil(n_sweep / 2)))
    rows = 2 + math.ceil(n_sweep / 2)
    ax = fig.add_subplot(rows, 2, 1)
    for name, label in (("boresight_error_arcsec", "boresight"), ("roll_error_arcsec", "roll")):
        v = _column(table, name)[right]
        if len(v):
            ax.hist(v, bins=60, histtype="step", label=label)
    ax.set_xlabel("error, arcsec")
    ax.set_ylabel("trials")
    ax.legend()
    ax.set_title("errors of the right solutions")
    ax = fig.add_subplot(rows, 2, 2)
    grid = np.linspace(-4, 4, 81)
    for a in _AXES:
        z = _column(table, f"normalised_{a}")[right]
        z = z[np.isfinite(z)]
        if len(z):
            ax.hist(z, bins=grid, density=True, histtype="step", label=f"{a} (RMS {_rms(z):.2f})")
    ax.plot(grid, np.exp(-grid**2 / 2) / math.sqrt(2 * math.pi), "k--", label="N(0, 1)")
    ax.set_xlabel("error / reported σ")
    ax.legend(fontsize=8)
    ax = fig.add_subplot(rows, 2, (3, 4), projection="mollweide")
    ra = np.radians(((_column(table, "ra_true_deg") + 180.0) % 360.0) - 180.0)
    dec = np.radians(_column(table, "dec_true_deg"))
    ax.scatter(-ra, dec, s=1, c="0.75", label="all")
    for mask, style, label in ((status == "failed", dict(c="tab:orange", s=6), "failed"),
                               (status == "error", dict(c="tab:purple", s=6), "error"),
                               (wrong, dict(c="red", s=30, marker="x"), "wrong")):
        if mask.any():
            ax.scatter(-ra[mask], dec[mask], label=f"{label} ({int(mask.sum())})", **style)
    ax.set_xticklabels([])
    ax.grid(True, alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title("true boresights (RA increasing to the left)")
    summary = summarize(table, campaign)
    for i, axis in enumerate(campaign.sweep):
        ax = fig.add_subplot(rows, 2, 5 + i)
        groups = summary["by_parameter"][axis.name]
        xs = [g.get("value", (g.get("low", 0) + g.get("high", 0)) / 2) for g in groups]
        labels = [str(x) for x in xs]
        pos = np.arange(len(xs))
        for a, marker in zip(_AXES, "os^", strict=True):
            ax.plot(pos, [g["rms_arcsec"][a] for g in groups], marker=marker, label=f"RMS {a}")
        ax.set_xticks(pos, labels, fontsize=8)
        ax.set_yscale("log")
        ax.set_xlabel(axis.name)
        ax.set_ylabel("RMS error, arcsec")
        twin = ax.twinx()
        twin.plot(pos, [100 * g["availability"] for g in groups], "k:", label="availability")
        twin.set_ylabel("availability, %")
        ax.legend(fontsize=7, loc="upper left")
    fig.suptitle(f"{campaign.name}: {table.num_rows} trials, {campaign.level} level")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
