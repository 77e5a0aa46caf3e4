"""Tables and plots of the tracking study (:mod:`skyfix.analysis.tracking_study`), with thesis
002's numbers beside skyfix's, and the files they go to (:func:`write_study`; docs/tracking-study.md
reads a full run). The study does not import its report: the command composes the two."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from skyfix.analysis._json import strict_json
from skyfix.analysis.tracking_study import (
    CAMERA,
    PREDICTOR_NAMES,
    THESIS_INTERCEPT_PX,
    THESIS_SLOPES,
    THESIS_TABLE_5_1,
    TrackingStudy,
    accel_slopes,
    accel_terms,
    accuracy_summary,
    constant_rate_slopes,
    error_correlations,
    normalised_errors,
    rate_slopes,
    time_error_slope,
)

__all__ = ["markdown", "plots", "write_study"]

_ARCSEC = math.pi / (180 * 3600)


def _f(v, fmt: str = ".2f") -> str:
    return "—" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, fmt)


def _accuracy_table(study: TrackingStudy) -> list[str]:
    lines = ["### Tracking against lost in space on the same frames", "",
             "Boresight `|δθx, δθy|` and roll `|δθz|` against the truth, arcsec (median, 95th percentile), "
             "on frames both solved with the tracker in tracking mode. *Should be tracked*: ≥ 3 stars of "
             "SNR ≥ 10 in the frame, not the two acquisition frames at the start or after the jump. "
             "Recovery: frames from the forced loss to the first frame tracked with stars again.", "",
             "| sequence | tracked / should be | coasting | boresight tracking | boresight LIS "
             "| roll tracking | roll LIS | stars tracking / LIS | recovery blank / jump "
             "| ms tracking / LIS |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    missed = []
    for s in study.accuracy_sequences:
        a = accuracy_summary(s)
        lines.append(
            f"| {a['name']} | {a['tracked_eligible']} / {a['eligible']} | {a['coasting']} | "
            f"{_f(a['bore_track'])} ({_f(a['bore_track_p95'], '.1f')}) | {_f(a['bore_lis'])} "
            f"({_f(a['bore_lis_p95'], '.1f')}) | {_f(a['roll_track'], '.1f')} "
            f"({_f(a['roll_track_p95'], '.0f')}) | "
            f"{_f(a['roll_lis'], '.1f')} ({_f(a['roll_lis_p95'], '.0f')}) | {_f(a['stars_track'], '.0f')} / "
            f"{_f(a['stars_lis'], '.0f')} | {a['recover_blank']} / "
            f"{a['recover_jump']} | {_f(a['ms_track'])} / {_f(a['ms_lis'], '.1f')} |")
        if a["missed"]:
            missed.append(f"{a['name']}: frames " + ", ".join(f"{k} ({m})" for k, m in a["missed"][:12])
                          + (" …" if len(a["missed"]) > 12 else ""))
    if missed:
        lines += ["", "Frames that should have been tracked and were not (their mode): "
                  + "; ".join(missed) + "."]
    return lines + [""]


def _nees_table(study: TrackingStudy) -> list[str]:
    seqs = study.accuracy_sequences
    total = normalised_errors(seqs)
    lines = ["### Error bars: error / reported σ", "",
             "Per axis over the tracked frames: RMS of `δθ/σ` (1 when honest; the issue asks 0.7–1.5), "
             "mean, the mean 3-axis NEES `δθᵀP⁻¹δθ` (3) and the share of `|δθ/σ|` > 3 (0.27 % for a "
             "normal).", "",
             "| frames | RMS x | RMS y | RMS roll | mean x | mean y | mean roll | NEES | > 3σ |",
             "|---|---|---|---|---|---|---|---|---|"]

    def row(name, z):
        r, m = z["rms"], z["mean"]
        return (f"| {name}: {z['n_frames']} | {r[0]:.2f} | {r[1]:.2f} | {r[2]:.2f} | {m[0]:+.2f} | "
                f"{m[1]:+.2f} | {m[2]:+.2f} | {z['nees_mean']:.2f} | {100 * z['beyond_3sigma']:.1f} % |")

    lines.append(row("all", total))
    for s in seqs:
        if s.tracked.any():
            lines.append(row(s.spec.name, normalised_errors([s])))
    return lines + [""]


def _prediction_tables(study: TrackingStudy) -> list[str]:
    seqs = study.accuracy_sequences
    names = _names(seqs)
    const = {p: constant_rate_slopes(seqs, p) for p in names}
    true = {p: constant_rate_slopes(seqs, p, error="true_px") for p in names}
    rates = [r for r, *_ in const[PREDICTOR_NAMES[0]]["rows"]]
    lines = ["### Prediction error against rate (constant rates, 10 Hz)", "",
             "Mean ± std over frames of the mean |predicted − measured| star position, px (thesis 002's "
             "definition); the slope of the means against the rate, px per arcsec/s, and the same against "
             f"the true positions. Thesis 002 (air bearing, Fig 5-9): slope {THESIS_SLOPES['mean']} (mean − "
             f"std {THESIS_SLOPES['mean − std']}, mean + std {THESIS_SLOPES['mean + std']}), "
             f"≈ {THESIS_INTERCEPT_PX} px at rest.", "",
             "| predictor | " + " | ".join(f"{r / 3600:g} °/s" for r in rates)
             + " | slope | slope vs truth |",
             "|---|" + "---|" * (len(rates) + 2)]
    for p in names:
        cells = " | ".join(f"{m:.3f} ± {s:.3f}" for _, m, s, _ in const[p]["rows"])
        lines.append(f"| {p} | {cells} | {const[p]['slope']:.2e} | {true[p]['slope']:.2e} |")
    late = [s.spec.time_error_s for s in seqs if s.spec.time_error_s > 0]
    if late:
        ms = 1e3 * late[0]
        lines += ["", f"*times ±{ms:g} ms*: thesis 002's held-rate predictor told each frame's time off by "
                  f"an independent σ = {ms:g} ms (the frames are where they are): the rate of the last "
                  "interval applied over the next misses the turn by ω·(δₖ − 2δₖ₋₁ + δₖ₋₂), a "
                  f"mean √(12/π)·σ·|ω|, i.e. {time_error_slope(late[0]):.2e} px per arcsec/s on this camera "
                  f"({CAMERA.plate_scale_rad / _ARCSEC:.1f}″/px)."]
    lines += ["", "### Prediction error against angular acceleration", "",
              "On frames whose acceleration was steady over the predictor's history (the slew's ramps; "
              "the constant rates give α = 0): the predicted attitude's error δθ against `αT²` across the "
              "boresight (x, y: roll is tens of arcseconds noisier), least-squares ratio (analytic: 1 for a "
              "held rate, ½ for thesis 004's weights, 0 for the exact quadratic), the RMS about the line, "
              "and the ratio as a star's offset at 1 °/s² and the slew's 10 Hz (αT² = 36″).", "",
              "| predictor | δθ / αT² | analytic | residual ″ | px at 1 °/s² | frames with α ≠ 0 |",
              "|---|---|---|---|---|---|"]
    for p in PREDICTOR_NAMES:
        a = accel_slopes(seqs, p)
        analytic = "—" if a["analytic"] is None else f"{a['analytic']:g}"
        lines.append(f"| {p} | {_f(a['ratio'], '.3f')} | {analytic} | {_f(a['residual_arcsec'], '.1f')} | "
                     f"{_f(a['px_at_1dps2'], '.2f')} | {a['n']} |")
    pend = [s for s in study.sequences if s.spec.profile == "pendulum"]
    if pend:
        lines += _pendulum_tables(pend[0])
    return lines + [""]


def _names(seqs) -> list[str]:
    """The predictors of :data:`PREDICTOR_NAMES`, then any other variant the sequences hold."""
    extra = [n for s in seqs for n in s.predictions if n not in PREDICTOR_NAMES]
    return [*PREDICTOR_NAMES, *dict.fromkeys(extra)]


def _pendulum_tables(p0) -> list[str]:
    names = _names([p0])
    late = names[len(PREDICTOR_NAMES):]
    lines = ["", "### Thesis 002's air-bearing analysis on a simulated pendulum (4 Hz, 62.5 ms)", "",
             f"Damped pendulum, mostly pitch ({len(p0.t_s)} frames; peak pitch rate "
             f"{np.nanmax(np.abs(p0.rate_dps[:, 1])) * 3600:.0f} arcsec/s). First, what the prediction "
             "error follows (thesis Figs 5-5, 5-6): its correlation with |pitch acceleration| and with "
             "|pitch rate| over the frames.", "",
             "| predictor | corr. with \\|α\\| | corr. with \\|ω\\| | frames |", "|---|---|---|---|"]
    for p in names:
        c = error_correlations(p0, p)
        lines.append(f"| {p} | {_f(c['accel'])} | {_f(c['rate'])} | {c['n']} |")
    lines += ["", "Then thesis Fig 5-9: |predicted − measured| against |pitch rate| in up to 6 bins, lines "
              "through mean − std, mean, mean + std, px per arcsec/s (intercept of the mean, px). Filters: "
              "*thesis* keeps pitch acceleration ≤ μ − 1.5σ as printed, *\\|α\\|* keeps |α| ≤ half the "
              "largest, *none* keeps all.", "",
              "| predictor | filter | mean − std | mean | mean + std | intercept |",
              "|---|---|---|---|---|---|",
              f"| thesis 002 | thesis | {THESIS_SLOPES['mean − std']} | {THESIS_SLOPES['mean']} | "
              f"{THESIS_SLOPES['mean + std']} | ≈ {THESIS_INTERCEPT_PX} |"]
    for p in names:
        for filt in ("thesis", "abs", "none"):
            fits, _ = rate_slopes(p0, p, filt)
            label = r"\|α\|" if filt == "abs" else filt  # a bare | would split the table cell
            lines.append(f"| {p} | {label} | " + " | ".join(_f(f.slope, '.2e') for f in fits)
                         + f" | {_f(fits[1].intercept, '.3f')} |")
    if late:
        sigma = p0.spec.time_error_s
        lines += ["", f"*{late[0]}*: the same predictor told each frame's time off by an independent "
                  f"σ = {1e3 * sigma:g} ms (the frames are where they are). Its error grows with the rate by "
                  f"√(12/π)·σ per plate scale = {time_error_slope(sigma):.2e} px per arcsec/s on this camera "
                  f"({CAMERA.plate_scale_rad / _ARCSEC:.1f}″/px)."]
    return lines


def _timing_table(study: TrackingStudy) -> list[str]:
    rows = study.timing
    counts = sorted({r.n_stars for r in rows})
    rois = sorted({r.roi_px for r in rows}, reverse=True)
    get = {(r.roi_px, r.n_stars): r for r in rows}
    lines = ["### Windowed against full-frame centroiding (thesis 002 Table 5-1)", "",
             "2560 × 1920 frame, ms (fastest of repeated calls). Thesis: DM355, 5 stars, full-frame COM "
             "with the same ROI. skyfix: `extract_centroids` on the whole frame (no ROI), N windows cut "
             "and centroided (`centroid_windows`, CoM over sky + 5σ). Every window found its star within "
             f"0.5 px: {'yes' if all(r.found_windowed == r.n_stars for r in rows) else 'no'}; the full "
             f"frame found every star: {'yes' if all(r.found_full == r.n_stars for r in rows) else 'no'}.",
             "",
             "| ROI px | thesis full | thesis windowed | thesis ratio | " + " | ".join(
                 f"skyfix full N={n} | windowed N={n} | ratio N={n}" for n in counts) + " |",
             "|---|---|---|---|" + "---|---|---|" * len(counts)]
    for roi in rois:
        th = THESIS_TABLE_5_1.get(roi)
        cells = " | ".join(f"{get[roi, n].full_ms:.1f} | {get[roi, n].windowed_ms:.3f} | "
                           f"{get[roi, n].ratio:.0f}×" if (roi, n) in get else "— | — | —" for n in counts)
        thesis = f"{th[0]:g} | {th[1]:g} | {th[0] / th[1]:.1f}×" if th else "— | — | —"
        lines.append(f"| {roi} | {thesis} | {cells} |")
    lines += ["", "Centroid RMS error of the windows, px, predictions 1 px off (N = "
              f"{counts[-1]}): the timed CoM over sky + 5σ, and over sky + 3σ (thesis 002's noise threshold "
              "just above the floor lets the noise pixels of a large window pull the centre).", "",
              "| ROI px | " + " | ".join(str(r) for r in rois) + " |", "|---|" + "---|" * len(rois),
              "| sky + 5σ | " + " | ".join(f"{get[r, counts[-1]].rms_windowed_px:.3f}" for r in rois) + " |",
              "| sky + 3σ | " + " | ".join(f"{get[r, counts[-1]].rms_windowed_3sigma_px:.3f}" for r in rois)
              + " |"]
    return lines + [""]


def markdown(study: TrackingStudy, command: str) -> str:
    """The study's tables (Markdown), headed by the command that made them."""
    st = study.settings
    where = (f"the Dask scheduler at {st['scheduler']}" if st.get("scheduler")
             else f"{st['workers']} workers" if st["workers"] else "in one process")
    head = [f"Generated by `{command}` (seed {st['seed']}, {where}, {st['cpu_count']} CPUs; "
            f"camera {st['camera']}, generic sensor noise, epoch {st['epoch']}).", ""]
    return "\n".join(head + _accuracy_table(study) + _nees_table(study) + _prediction_tables(study)
                     + _timing_table(study))


# --- plots -------------------------------------------------------------------------------------------
def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


_COLOURS = {"mekf": "#1f77b4", "small-angle": "#d62728", "three-point": "#2ca02c",
            "three-point-thesis": "#9467bd"}


def _thesis_lines(ax, x_max: float) -> None:
    x = np.array([0.0, x_max])
    ax.plot(x, THESIS_INTERCEPT_PX + THESIS_SLOPES["mean"] * x, "k--", lw=1,
            label=f"thesis 002: {THESIS_INTERCEPT_PX} px + {THESIS_SLOPES['mean']} px/(″/s)")
    ax.fill_between(x, THESIS_INTERCEPT_PX + THESIS_SLOPES["mean − std"] * x,
                    THESIS_INTERCEPT_PX + THESIS_SLOPES["mean + std"] * x, color="k", alpha=0.08)


def _plot_rate(study: TrackingStudy, out: Path) -> Path:
    plt = _pyplot()
    pend = [s for s in study.sequences if s.spec.profile == "pendulum"]
    fig, axes = plt.subplots(1, 1 + len(pend), figsize=(6.0 * (1 + len(pend)), 4.4), squeeze=False)
    ax = axes[0, 0]
    x_max = 1.0
    for p in _names(study.accuracy_sequences):
        rows = np.array(constant_rate_slopes(study.accuracy_sequences, p)["rows"]).reshape(-1, 4)
        if len(rows):
            ax.errorbar(rows[:, 0], rows[:, 1], rows[:, 2], fmt="o-", color=_COLOURS.get(p, "#7f7f7f"),
                        capsize=3, label=p, ms=4)
            x_max = max(x_max, rows[:, 0].max())
    _thesis_lines(ax, x_max)
    ax.set_yscale("log")
    ax.set_xlabel("rate, arcsec/s")
    ax.set_ylabel("|predicted − measured|, px")
    ax.set_title("constant rates, 10 Hz")
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)
    for ax, s in zip(axes[0, 1:], pend, strict=True):
        rate = np.abs(s.rate_dps[:, 1]) * 3600
        for p in ("small-angle", "mekf", *_names([s])[len(PREDICTOR_NAMES):]):
            ax.plot(rate, s.predictions[p].meas_px, ".", color=_COLOURS.get(p, "#7f7f7f"), alpha=0.5, ms=4,
                    label=f"{p} (frames)")
            fits, bins = rate_slopes(s, p, "abs")
            if len(bins):
                ax.errorbar(bins[:, 0], bins[:, 1], bins[:, 2], fmt="s", color=_COLOURS.get(p, "#7f7f7f"),
                            capsize=3)
                xx = np.array([0, rate.max()])
                ax.plot(xx, fits[1].intercept + fits[1].slope * xx, "-", color=_COLOURS.get(p, "#7f7f7f"),
                        lw=1, label=f"{p}, |α| filter: {fits[1].slope:.1e} px/(″/s)")
        _thesis_lines(ax, float(np.nanmax(rate)))
        ax.set_xlabel("|pitch rate|, arcsec/s")
        ax.set_title("pendulum, 4 Hz, 62.5 ms (thesis 002 §5.4)")
        ax.legend(fontsize=7)
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    path = out / "prediction_error_vs_rate.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _plot_accel(study: TrackingStudy, out: Path) -> Path:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    x_max = 0.0
    for p in PREDICTOR_NAMES:
        a, d = accel_terms(study.sequences, p)
        x = np.linalg.norm(a, axis=1)
        moving = x > 0
        y = np.sum(d[moving] * a[moving], axis=1) / x[moving]  # along α
        x = x[moving]
        ratio = accel_slopes(study.sequences, p)["ratio"]
        ax.plot(x, y, ".", color=_COLOURS[p], alpha=0.5, label=f"{p}: ratio {ratio:.2f}")
        x_max = max(x_max, float(x.max()) if len(x) else 0.0)
    xx = np.array([0.0, max(x_max, 1.0)])
    for c, name in ((1.0, "held rate"), (0.5, "thesis 004 weights"), (0.0, "exact quadratic")):
        ax.plot(xx, c * xx, "k:", lw=1)
        ax.annotate(name, (xx[1], c * xx[1]), fontsize=7, ha="right", va="bottom")
    ax.set_xlabel("|α| T², arcsec")
    ax.set_ylabel("predicted attitude error along α (across the boresight), ″")
    ax.set_title("prediction error under a steady acceleration")
    ax.legend(fontsize=7)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    path = out / "prediction_error_vs_acceleration.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _plot_timing(study: TrackingStudy, out: Path) -> Path:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    counts = sorted({r.n_stars for r in study.timing})
    cmap = plt.get_cmap("viridis")
    for i, n in enumerate(counts):
        rows = sorted((r for r in study.timing if r.n_stars == n), key=lambda r: r.roi_px)
        c = cmap(i / max(len(counts) - 1, 1))
        ax.plot([r.roi_px for r in rows], [r.windowed_ms for r in rows], "o-", color=c,
                label=f"skyfix windowed, N={n}")
        ax.axhline(rows[0].full_ms, color=c, ls="--", lw=1, label=f"skyfix full frame, N={n}")
    th = sorted(THESIS_TABLE_5_1.items())
    ax.plot([r for r, _ in th], [v[1] for _, v in th], "kx-", label="thesis 002 windowed (DM355, 5 stars)")
    ax.plot([r for r, _ in th], [v[0] for _, v in th], "k+:", label="thesis 002 full frame")
    ax.set_yscale("log")
    ax.set_xlabel("ROI (window side), px")
    ax.set_ylabel("time per frame, ms")
    ax.set_title("2560 × 1920: windowed vs full-frame centroiding")
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    path = out / "centroid_time_vs_roi.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _plot_nees(study: TrackingStudy, out: Path) -> Path:
    plt = _pyplot()
    z = normalised_errors(study.accuracy_sequences)
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), sharey=True)
    grid = np.linspace(-5, 5, 201)
    for i, (ax, name) in enumerate(zip(axes, ("x", "y", "roll"), strict=True)):
        ax.hist(np.clip(z["z"][:, i], -5, 5), bins=41, range=(-5, 5), density=True, color="#1f77b4",
                alpha=0.7)
        ax.plot(grid, np.exp(-grid ** 2 / 2) / math.sqrt(2 * math.pi), "k-", lw=1, label="N(0, 1)")
        ax.set_title(f"{name}: RMS {z['rms'][i]:.2f} over {z['n_frames']} frames")
        ax.set_xlabel("error / reported σ")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    path = out / "normalised_error_hist.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _plot_errors(study: TrackingStudy, out: Path) -> Path:
    plt = _pyplot()
    seqs = study.accuracy_sequences
    fig, axes = plt.subplots(len(seqs), 2, figsize=(12, 2.3 * len(seqs)), squeeze=False, sharex="row")
    for row, s in zip(axes, seqs, strict=True):
        bt, bl = np.hypot(*s.err_track[:, :2].T), np.hypot(*s.err_lis[:, :2].T)
        sb = np.hypot(*s.sigma_track[:, :2].T)
        for ax, track, lis, sig, what in ((row[0], bt, bl, sb, "boresight"),
                                          (row[1], np.abs(s.err_track[:, 2]), np.abs(s.err_lis[:, 2]),
                                           s.sigma_track[:, 2], "|roll|")):
            ax.plot(s.t_s, lis, ".", color="#aaaaaa", ms=3, label="lost in space")
            ax.plot(s.t_s, track, "-", color="#1f77b4", lw=1, label="tracking")
            ax.fill_between(s.t_s, 0, sig, color="#1f77b4", alpha=0.15, label="tracker 1σ")
            for k, ev in enumerate(s.event):
                if ev:
                    ax.axvline(s.t_s[k], color="r", lw=0.8, ls=":")
            ax.set_yscale("log")
            ax.set_ylabel(f"{what} error, ″")
            ax.set_title(f"{s.spec.name}: {what}", fontsize=9)
            ax.grid(True, which="both", alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("time, s (red: blank frame, 90° jump)")
    fig.tight_layout()
    path = out / "error_vs_time.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plots(study: TrackingStudy, out: Path) -> list[Path]:
    """Write the five PNG plots to ``out``; returns their paths."""
    return [_plot_rate(study, out), _plot_accel(study, out), _plot_timing(study, out), _plot_nees(study, out),
            _plot_errors(study, out)]


def write_study(study: TrackingStudy, out_dir: str | Path, command: str = "skyfix analyze tracking"
                ) -> list[Path]:
    """Write ``tracking_study.json``, ``tracking_study.md`` and the PNG plots to ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    pj = out / "tracking_study.json"
    pj.write_text(json.dumps(strict_json({"settings": study.settings,
                                     "sequences": [s.to_json() for s in study.sequences],
                                     "timing": [t._asdict() for t in study.timing]}), indent=None))
    pm = out / "tracking_study.md"
    pm.write_text(markdown(study, command))
    return [pj, pm, *plots(study, out)]
