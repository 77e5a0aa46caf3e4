"""Issues 2 and 22's targets, checked against the numbers of this run (closing tables, PASS / FAIL / —).

Only the working tree's figures count (the tool named ``skyfix``; with ``--against`` the REF side
is there for the ratios, not for the targets). A target whose figures this run did not measure
is left out; one whose peer is missing shows ``—``.
"""

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


def _ok(value, test):
    """``test(value)``, or None when the value is missing (not a finite number)."""
    if not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    return bool(test(value))


def _tetra3rs_mme(summary: dict, key: str) -> float:
    """tetra3rs (mme 0.002)'s figure — the bar of issue 22 — or the best tetra3rs row's."""
    v = summary.get("tetra3rs (mme 0.002)", {}).get(key)
    return v if isinstance(v, (int, float)) and math.isfinite(v) else _best_tetra3rs(summary, key)


def check(results: dict) -> list[dict]:
    return check_issue2(results) + check_issue22(results)


def check_issue2(results: dict) -> list[dict]:
    rows = []

    def add(name: str, value, target: str, ok):
        rows.append({"issue": 2, "target": name, "measured": value, "goal": target,
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


def check_issue22(results: dict) -> list[dict]:
    """Issue 22's "What it must show" (start-up, the core loop against tetra3rs, accuracy, speed)."""
    rows = []

    def add(name: str, value, goal: str, ok):
        rows.append({"issue": 22, "target": name, "measured": value, "goal": goal,
                     "status": "—" if ok is None else ("PASS" if ok else "FAIL")})

    start = results.get("startup", {})
    cold = _get(start, "cold", "skyfix", "wall_s")
    if math.isfinite(cold):
        add("first solve, fresh install, empty cache, s", cold, "≤ 20", cold <= 20)
    for path, v in _get(start, "first_use", "skyfix", default={}).items():
        if not path.startswith("_"):
            x = v.get("first_use_s", float("nan"))
            add(f"first use of {path}, s", x, "≤ 10", _ok(x, lambda y: y <= 10))
    warm = _get(start, "warm", "skyfix", default={})
    for key, what, goal, test in (
            ("solve_process_s", "skyfix solve sky.png, whole process (warm), s", "≤ 1.0", lambda y: y <= 1.0),
            ("first_over_later", "first solve in a process / a later one", "≤ 3", lambda y: y <= 3),
            ("version_s", "skyfix --version, s", "≤ 0.3", lambda y: y <= 0.3),
            ("help_s", "skyfix -h, s", "≤ 0.3", lambda y: y <= 0.3)):
        x = warm.get(key, float("nan"))
        if isinstance(x, (int, float)) and math.isfinite(x):
            add(what, x, goal, x <= float(goal.split()[-1]) if test is None else test(x))

    for label, v in results.get("synthetic_centroids", {}).items():
        summ = v["summary"]
        # the median of each set's fastest of --best-of solves, when the run made them (README)
        key = "median_best_ms" if "median_best_ms" in summ.get("skyfix", {}) else "median_ms"
        t3 = _tetra3rs_mme(summ, key)
        for name in ("skyfix", "skyfix (no FOV)"):
            sk = summ.get(name)
            if not sk:
                continue
            r = sk[key] / t3 if math.isfinite(t3) and t3 > 0 else float("nan")
            best = f" (best of {sk['reps']})" if key == "median_best_ms" else ""
            add(f"synthetic {label}, {name}: median{best} / tetra3rs (mme 0.002)", r, "≤ 0.6",
                _ok(r, lambda y: y <= 0.6))
            add(f"synthetic {label}, {name}: p99 ms", sk["p99_ms"], "≤ 5",
                _ok(sk["p99_ms"], lambda y: y <= 5))
            add(f"synthetic {label}, {name}: solved %, wrong", f"{sk['solved_pct']:.1f}, {sk['wrong']}",
                "100, 0", sk["solved"] == sk["n"] and sk["wrong"] == 0)

    for key, v in results.get("accuracy_render", {}).items():
        summ = v.get("summary", {}) if isinstance(v, dict) else {}
        sk = summ.get("skyfix")
        if not sk:
            continue
        fov = key.replace("deg", "°")
        t3 = _best_tetra3rs(summ, "median_bore_arcsec")
        r = sk["median_bore_arcsec"] / t3 if math.isfinite(t3) and t3 > 0 else float("nan")
        add(f"accuracy {fov}: skyfix / tetra3rs boresight", r, "≤ 0.35", _ok(r, lambda y: y <= 0.35))
        limit = {"8°": 0.19, "15°": 0.19, "30°": 0.35}.get(fov)
        if limit is not None:
            add(f"accuracy {fov}: skyfix median boresight ″", sk["median_bore_arcsec"], f"≤ {limit:g}",
                _ok(sk["median_bore_arcsec"], lambda y, lim=limit: y <= lim))

    speed = results.get("speed", {})
    db = _get(speed, "databases", "skyfix", default={})
    if "load_ms" in db:
        add("pattern database cached load, ms", db["load_ms"], "≤ 5", _ok(db["load_ms"], lambda y: y <= 5))
    ext = _get(speed, "extraction", "median_ms_per_mp", default={})
    if "skyfix" in ext:
        r = ext["skyfix"] / ext["tetra3rs"] if isinstance(ext.get("tetra3rs"), float) else float("nan")
        add("extraction ms/MP: skyfix / tetra3rs", r, "≤ 0.5", _ok(r, lambda y: y <= 0.5))
    e2e = _get(speed, "end_to_end_png", default={})
    if "skyfix" in e2e:
        t3 = _get(e2e, "tetra3rs", "median_ms")
        r = e2e["skyfix"]["median_ms"] / t3 if math.isfinite(t3) and t3 > 0 else float("nan")
        add("16-bit PNG file → attitude: skyfix / tetra3rs", r, "≤ 0.5", _ok(r, lambda y: y <= 0.5))
    track = _get(results, "tracking", "1 deg/s", "speedup")
    if math.isfinite(track):
        add("tracking update at 1 °/s: speed-up over lost in space", track, "≥ 20", track >= 20)
    return rows


def print_targets(rows: list[dict]) -> None:
    for issue in (2, 22):
        mine = [r for r in rows if r.get("issue") == issue]
        if mine:
            print_table(f"issue {issue} targets (this run's working tree; timings on a shared machine "
                        "are noisy)",
                        ["target", "measured", "goal", "status"],
                        [[r["target"], r["measured"], r["goal"], r["status"]] for r in mine])
