"""Suite (e): blind solves that must never be wrong, with honest error bars (issue 7).

skyfix only (the peers have no error bars to judge): every solve with no camera file and no
FOV hint, as a new user would.

- ``uncalibrated``: synthetic centroids from random uncalibrated cameras — pixel aspect
  0.95–1.05, principal point up to 20 px off centre, k1 within ±0.3, 8–40 stars, 0–5 false
  stars, centroid noise 0.1–1 px, fields 8–35° (``--n-blind``, default 10 000).
- one row per seed camera preset and scene: images rendered by skyfix's simulator at random
  pointings, without and with 3 false stars + 20 hot pixels (``--n-preset`` each, default 500,
  so 1000 per preset).

Wrong = boresight error beyond max(60″, 1 px) or roll beyond 0.5°, measured at the
solution's boresight pixel (``skyfix.analysis.blind_campaign``). Normalised error = error /
reported σ per axis (x, y, roll); honest error bars give an RMS between 0.7 and 1.5.

Each set runs on the campaign engine (``skyfix.montecarlo.engine``): ``--workers N`` local
processes (default 0: this process, as before) or ``--scheduler tcp://HOST:PORT``; the trial
rows go to ``results/blind-SET.parquet`` beside ``results/blind.json`` (written afresh each run).

    python benchmarks/suite_blind.py [--n-blind 10000] [--n-preset 500] [--workers 2 | --scheduler ADDR]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS_DIR  # noqa: E402
from report import print_table, say  # noqa: E402

PRESETS = ("sunsat", "generic", "has2", "mt9v022", "mt9p031", "droid_x2", "ov5642")
SCENES = (("clean", 0, 0), ("3 false + 20 hot", 3, 20))


def _progress(total: int, label: str):
    try:
        from rich.progress import Progress

        bar = Progress(transient=True)
        bar.start()
        task = bar.add_task(label, total=total)
        return bar, (lambda k: bar.advance(task, k))
    except ImportError:  # pragma: no cover
        return None, None


def _row(name: str, s: dict, wall: float) -> list:
    rms = s.get("normalised_rms", [float("nan")] * 3)
    return [name, s["n"], s["solved"], s["wrong"], *rms, s.get("median_boresight_arcsec", float("nan")),
            s.get("median_roll_arcsec", float("nan")), s["n"] / max(wall, 1e-9)]


def _fresh(name: str) -> Path:
    """``results/NAME.parquet``, with any earlier run's file and parts removed (a timed run)."""
    from skyfix.montecarlo.engine import parts_folder

    path = RESULTS_DIR / f"{name}.parquet"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.unlink(missing_ok=True)
    shutil.rmtree(parts_folder(path), ignore_errors=True)
    return path


def run(n_blind: int = 10_000, n_preset: int = 500, presets=PRESETS, seed: int = 1, workers: int = 0,
        scheduler: str | None = None) -> dict:
    """Every set; with ``workers`` ≥ 1 or a ``scheduler``, one Dask cluster for them all (its
    start-up, ~10 s, in the first set's time)."""
    if n_blind < 1 or n_preset < 1:
        raise ValueError(f"suite e needs ≥ 1 trial a set (--n-blind {n_blind}, --n-preset {n_preset})")
    if not workers and not scheduler:
        return _run(n_blind, n_preset, presets, seed, None)
    from skyfix import warmup
    from skyfix.montecarlo.engine import connect

    t0 = time.time()
    warmup.ensure(["solve", "simulate"], missing_ok=True)  # compiled once, loaded by every worker
    client, cluster = connect(workers, scheduler)
    try:
        return _run(n_blind, n_preset, presets, seed, client, time.time() - t0)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _run(n_blind: int, n_preset: int, presets, seed: int, client, start_s: float = 0.0) -> dict:
    from skyfix.analysis.blind_campaign import preset_image_trials, summarize, uncalibrated_centroid_trials

    out, rows = {}, []
    t0 = time.time() - start_s
    bar, step = _progress(n_blind, "uncalibrated centroids")
    try:
        s = summarize(uncalibrated_centroid_trials(n_blind, seed=seed, progress=step, client=client,
                                                   output=_fresh("blind-uncalibrated")))
    finally:
        if bar is not None:
            bar.stop()
    out["uncalibrated"] = {**s, "wall_s": time.time() - t0}
    rows.append(_row("uncalibrated centroids", s, time.time() - t0))
    say(f"uncalibrated centroids: {s}")
    for preset in presets:
        for scene, n_false, n_hot in SCENES:
            t0 = time.time()
            bar, step = _progress(n_preset, f"{preset} {scene}")
            try:
                s = summarize(preset_image_trials(preset, n_preset, seed=seed, false_stars=n_false,
                                                  hot_pixels=n_hot, progress=step, client=client,
                                                  output=_fresh(f"blind-{preset}-{n_false}false-{n_hot}hot")))
            finally:
                if bar is not None:
                    bar.stop()
            out[f"{preset} {scene}"] = {**s, "wall_s": time.time() - t0}
            rows.append(_row(f"{preset} {scene}", s, time.time() - t0))
            say(f"{preset} {scene}: {s}")
    print_table("blind solves: wrong attitudes and honest error bars (no camera file, no FOV hint)",
                ["set", "n", "solved", "wrong", "norm RMS x", "norm RMS y", "norm RMS roll",
                 "median bore ″", "median roll ″", "trials/s"], rows,
                note="wrong: boresight > max(60″, 1 px) or roll > 0.5°; norm RMS: error / reported σ "
                     "(0.7–1.5 is honest)")
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-blind", type=int, default=10_000)
    ap.add_argument("--n-preset", type=int, default=500)
    ap.add_argument("--presets", default=",".join(PRESETS))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=0, help="local worker processes (0: this one)")
    ap.add_argument("--scheduler", default=None, help="a Dask scheduler, tcp://HOST:PORT")
    args = ap.parse_args()
    from skyfix.errors import CampaignError

    try:
        result = run(args.n_blind, args.n_preset, tuple(args.presets.split(",")), args.seed, args.workers,
                     args.scheduler)
    except CampaignError as exc:  # a scheduler out of reach: one line, exit 2
        print(f"{Path(__file__).name}: {exc}", file=sys.stderr)
        sys.exit(2)
    from common import write_json

    say(f"wrote {write_json('blind', result)}")
