"""Issue 2's targets, checked against the numbers of this run (a closing table, PASS / FAIL / —)."""

from __future__ import annotations

import math

from report import print_table


def _get(d: dict, *keys, default=float("nan")):
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return default
        d = d[k]
    return d


def _best_tetra3rs(summary: dict, key: str, lower_is_better: bool = True) -> float:
    vals = [v.get(key, float("nan")) for k, v in summary.items() if k.startswith("tetra3rs")]
    vals = [v for v in vals if isinstance(v, (int, float)) and math.isfinite(v)]
    if not vals:
        return float("nan")
    return min(vals) if lower_is_better else max(vals)


def check(results: dict) -> list[dict]:
    rows = []

    def add(name: str, value, target: str, ok):
        rows.append({"target": name, "measured": value, "goal": target,
                     "status": "—" if ok is None else ("PASS" if ok else "FAIL")})

    real = _get(results, "real_images", "summary", default={})
    if real and "skyfix" in real:
        s = real["skyfix"]
        add("real images within limits (no FOV)", f"{s['within_limits']}/{s['n']}", "21/21",
            s["within_limits"] == s["n"])
        add("end to end, 1280×960 JPEG, median ms", s["median_time_ms_1280x960"], "≤ 25",
            s["median_time_ms_1280x960"] <= 25)
    e2e = _get(results, "speed", "end_to_end_png", default={})
    if "skyfix" in e2e:
        add("end to end, 1280×960 16-bit PNG, median ms", e2e["skyfix"]["median_ms"], "≤ 25",
            e2e["skyfix"]["median_ms"] <= 25)
    syn = results.get("synthetic_centroids", {})
    if syn:
        wrong = sum(_get(v, "summary", "skyfix", "wrong", default=0) +
                    _get(v, "summary", "skyfix (no FOV)", "wrong", default=0) for v in syn.values())
        add("synthetic: wrong attitudes (all configs, ± FOV)", wrong, "0", wrong == 0)
        for label, v in syn.items():
            summ = v["summary"]
            if "skyfix" not in summ:
                continue
            sk = summ["skyfix"]
            if label.startswith("σ=1px false=8"):
                add(f"synthetic {label}: solved %", sk["solved_pct"], "≥ 99.5", sk["solved_pct"] >= 99.5)
            for stat in ("median_ms", "p99_ms"):
                t3 = _best_tetra3rs(summ, stat)
                r = sk[stat] / t3 if t3 and math.isfinite(t3) else float("nan")
                add(f"synthetic {label}: skyfix/tetra3rs {stat[:-3]} time", r, "≤ 1",
                    r <= 1 if math.isfinite(r) else None)
            if label.startswith("σ=1px") and "cedar-solve" in summ:
                r = sk["p99_ms"] / summ["cedar-solve"]["p99_ms"]
                add(f"synthetic {label}: skyfix/cedar p99 time", r, "≪ 1", r < 0.5)
    ext = _get(results, "speed", "extraction", "median_ms_per_mp_1280x960", default={})
    if "skyfix" in ext:
        add("extraction ms/MP (1280×960 frames, median)", ext["skyfix"], "≤ 10", ext["skyfix"] <= 10)
    db = _get(results, "speed", "databases", "skyfix", default={})
    if "build_ms" in db:
        add("database build 10–30°, s", db["build_ms"] / 1e3, "< 30", db["build_ms"] < 30e3)
        add("database cached load, ms", db["load_ms"], "< 300", db["load_ms"] < 300)
    acc = results.get("accuracy_render", {})
    for key, v in acc.items():
        key = key.replace("deg", "°")
        summ = v.get("summary", {}) if isinstance(v, dict) else {}
        if "skyfix" not in summ:
            continue
        sk = summ["skyfix"]
        t3b = _best_tetra3rs(summ, "median_bore_arcsec")
        t3r = _best_tetra3rs(summ, "median_roll_arcsec")
        if key == "15°":
            add("accuracy 15°: median boresight ″", sk["median_bore_arcsec"], "≤ 0.7",
                sk["median_bore_arcsec"] <= 0.7)
            add("accuracy 15°: median roll ″", sk["median_roll_arcsec"], "≤ 10",
                sk["median_roll_arcsec"] <= 10)
        add(f"accuracy {key}: skyfix/tetra3rs boresight", sk["median_bore_arcsec"] / t3b, "≤ 1",
            sk["median_bore_arcsec"] <= t3b)
        add(f"accuracy {key}: skyfix/tetra3rs roll", sk["median_roll_arcsec"] / t3r, "≤ 1",
            sk["median_roll_arcsec"] <= t3r)
        add(f"accuracy {key}: solved", f"{sk['solved']}/{sk['n']}", "all", sk["solved"] == sk["n"])
    return rows


def print_targets(rows: list[dict]) -> None:
    if not rows:
        return  # skyfix was not part of this run
    print_table("issue 2 targets (this run; timings on a shared machine are noisy)",
                ["target", "measured", "goal", "status"],
                [[r["target"], r["measured"], r["goal"], r["status"]] for r in rows])
