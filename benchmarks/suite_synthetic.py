"""Suite (b): solve from synthetic centroids (1280×960, 15°, Hipparcos to mag 8, random attitudes).

Every tool sees the same centroid sets, interleaved set by set so that the load of a shared
machine falls on all tools alike. Every tool is told the FOV (15°, no bound on its error);
skyfix is also run without a FOV (row ``skyfix (no FOV)``) when ``nofov`` is set.
Reports solved %, wrong attitudes (boresight > 60″ or roll > 0.5°), median and p99 of the
wall time of the centroids → attitude call, and the ratios skyfix / peer.
"""

from __future__ import annotations

import numpy as np

from common import boresight_error_arcsec, is_wrong, median, pct, ratio, roll_error_deg
from report import print_table, say
from synthetic import SyntheticSpec, centroid_sets


def configs(n: int, seed: int = 1) -> list[SyntheticSpec]:
    return [SyntheticSpec(sigma_px=s, n_false=f, n=n, seed=seed + 10 * i)
            for i, (s, f) in enumerate([(0.5, 3), (0.5, 8), (1.0, 3), (1.0, 8)])]


def _run_tool(tool, s, spec: SyntheticSpec, fov_deg: float | None) -> dict:
    try:
        a = tool.solve_centroids(s.xy, spec.width, spec.height, fov_deg, flux=s.flux)
    except Exception as exc:  # noqa: BLE001 - a crash counts as a failure, and is recorded
        return {"solved": False, "status": f"{type(exc).__name__}: {exc}"[:120], "time_ms": float("nan")}
    out = {"solved": a.solved, "status": a.status, "time_ms": a.time_ms}
    if a.solved:
        bore, roll = boresight_error_arcsec(a.A, s.A_true), roll_error_deg(a.A, s.A_true)
        out.update(bore_arcsec=bore, roll_deg=roll, wrong=is_wrong(bore, roll))
    return out


def run(tools: dict, n: int = 1000, n_cedar: int | None = None, nofov: bool = True) -> dict:
    results = {}
    for spec in configs(n):
        sets, generator = centroid_sets(spec)
        runs = {name: [] for name in tools}
        if nofov and "skyfix" in tools:
            runs["skyfix (no FOV)"] = []
        for i, s in enumerate(sets):
            for name, tool in tools.items():
                if name == "cedar-solve" and n_cedar is not None and i >= n_cedar:
                    continue
                runs[name].append(_run_tool(tool, s, spec, spec.fov_deg))
            if "skyfix (no FOV)" in runs:
                runs["skyfix (no FOV)"].append(_run_tool(tools["skyfix"], s, spec, None))
        summary = {name: _summary(rs) for name, rs in runs.items()}
        results[spec.label] = {"spec": spec.__dict__, "generator": generator,
                               "mean_stars": float(np.mean([len(s.xy) for s in sets])),
                               "summary": summary,
                               "failures": {k: [i for i, r in enumerate(v) if not r["solved"]][:50]
                                            for k, v in runs.items()},
                               "wrong": {k: [(i, r["bore_arcsec"], r["roll_deg"]) for i, r in enumerate(v)
                                             if r.get("wrong")] for k, v in runs.items()}}
        _print(spec, summary, generator, results[spec.label]["mean_stars"])
    return results


def _summary(rs: list[dict]) -> dict:
    solved = [r for r in rs if r["solved"]]
    times = [r["time_ms"] for r in rs]
    return {
        "n": len(rs),
        "solved": len(solved),
        "solved_pct": 100.0 * len(solved) / len(rs) if rs else float("nan"),
        "wrong": sum(bool(r.get("wrong")) for r in solved),
        "median_ms": median(times),
        "p99_ms": pct(times, 99.0),
        "max_ms": pct(times, 100.0),
        "median_ms_solved": median([r["time_ms"] for r in solved]),
        "median_bore_arcsec": median([r["bore_arcsec"] for r in solved]),
        "median_roll_arcsec": median([r["roll_deg"] * 3600 for r in solved]),
        "statuses": {st: sum(r["status"] == st for r in rs if not r["solved"])
                     for st in {r["status"] for r in rs if not r["solved"]}},
    }


def _print(spec: SyntheticSpec, summary: dict, generator: str, mean_stars: float) -> None:
    sk = summary.get("skyfix")
    cols = ["tool", "n", "solved %", "wrong", "median ms", "p99 ms", "max ms", "median ″", "median roll ″",
            "skyfix/tool median", "skyfix/tool p99"]
    rows = []
    for name, s in summary.items():
        rows.append([name, s["n"], s["solved_pct"], s["wrong"], s["median_ms"], s["p99_ms"], s["max_ms"],
                     s["median_bore_arcsec"], s["median_roll_arcsec"],
                     ratio(sk["median_ms"], s["median_ms"]) if sk else float("nan"),
                     ratio(sk["p99_ms"], s["p99_ms"]) if sk else float("nan")])
    print_table(f"(b) synthetic centroids {spec.label}, dropout {spec.dropout:.0%}, "
                f"{spec.width}×{spec.height} {spec.fov_deg:g}° mag≤{spec.mag_limit:g}",
                cols, rows, note=f"generator: {generator}; mean {mean_stars:.0f} centroids per set")
    for name, s in summary.items():
        if s["statuses"]:
            say(f"  {name} failures: {s['statuses']}")
