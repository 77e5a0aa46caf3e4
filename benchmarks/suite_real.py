"""Suite (a): the 21 real images in shared/data/real, end to end (file → attitude), every tool.

skyfix gets no FOV hint. tetra3rs needs a FOV estimate: by default the reference FOV
(``--peer-fov hint``; no bound on its error), or the middle of its database range with
``--peer-fov mid``. cedar-solve gets the same hint, or none with ``--peer-fov mid``.
Pass mark per image (issue 2): boresight within 60″ (20″ for the ESA frames), roll within 0.5°.
"""

from __future__ import annotations

import json

import numpy as np

from common import (
    REAL_DIR,
    boresight_error_arcsec,
    median,
    radec_roll_deg,
    radec_to_vec,
    ratio,
    roll_diff_deg,
)
from report import print_table, say


def references() -> list[dict]:
    return [json.loads(line) for line in (REAL_DIR / "solutions.jsonl").read_text().splitlines() if line]


def _fov_hint(tool_name: str, ref: dict, mode: str, is_skyfix: bool = False) -> float | None:
    if is_skyfix or tool_name == "skyfix":
        return None
    if mode == "hint":
        return float(ref["fov_w_deg"])
    return 20.0 if tool_name.startswith("tetra3rs") else None


def _errors(A: np.ndarray, ref: dict) -> tuple[float, float]:
    ref_axes = np.vstack([A[0], A[1], radec_to_vec(ref["ra_deg"], ref["dec_deg"])])
    bore = boresight_error_arcsec(A, ref_axes)
    roll = roll_diff_deg(radec_roll_deg(A)[2], ref["roll_deg"]) if "roll_deg" in ref else float("nan")
    return bore, roll


def run(tools: dict, repeats: int = 3, peer_fov: str = "hint", alternate: bool = False) -> dict:
    """``alternate`` reverses the tools' order every other image (``--against``)."""
    refs = references()
    per_image = []
    order = list(tools.items())
    for k, ref in enumerate(refs):
        path = REAL_DIR / ref["image"]
        limit = 20.0 if ref["image"].startswith("esa-tetra3/") else 60.0
        row = {"image": ref["image"], "limit_arcsec": limit, "tools": {}}
        for name, tool in (order[::-1] if alternate and k % 2 else order):
            hint = _fov_hint(name, ref, peer_fov, getattr(tool, "is_skyfix", False))
            times, first = [], None
            for _ in range(repeats):
                try:
                    a = tool.solve_file(path, fov_deg=hint)
                except Exception as exc:  # noqa: BLE001 - a crash is a failure, recorded
                    a = None
                    err = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
                if a is None:
                    first = first or {"solved": False, "status": err}
                    break
                times.append(a.time_ms)
                if first is None:
                    first = {"solved": a.solved, "status": a.status, "n_matched": a.n_matched,
                             "fov_deg": a.fov_deg}
                    if a.solved:
                        bore, roll = _errors(a.A, ref)
                        first.update(bore_arcsec=bore, roll_deg=roll,
                                     ok=bool(bore <= limit and not roll > 0.5))
            first["time_ms"] = median(times) if times else float("nan")
            first["fov_hint_deg"] = hint
            row["tools"][name] = first
        per_image.append(row)
    summary = _summarise(per_image, list(tools))
    _print(per_image, summary, list(tools))
    return {"peer_fov": peer_fov, "repeats": repeats, "images": per_image, "summary": summary}


def against_measures(results: dict, tree: str, ref: str) -> list:
    """Tree vs REF on the real images (``against.Measure`` rows)."""
    from against import Measure

    a, b = results["summary"].get(tree), results["summary"].get(ref)
    if not (a and b):
        return []
    return [Measure("a", "median ms (all)", a["median_time_ms"], b["median_time_ms"]),
            Measure("a", "median ms (1280×960)", a["median_time_ms_1280x960"], b["median_time_ms_1280x960"]),
            Measure("a", "median boresight ″", a["median_bore_arcsec"], b["median_bore_arcsec"]),
            Measure("a", "within limits", a["within_limits"], b["within_limits"], "count", "higher")]


def _summarise(per_image: list[dict], names: list[str]) -> dict:
    out = {}
    for name in names:
        rs = [r["tools"][name] for r in per_image]
        solved = [x for x in rs if x.get("solved")]
        out[name] = {
            "solved": len(solved),
            "within_limits": sum(bool(x.get("ok")) for x in rs),
            "n": len(rs),
            "failed": [r["image"] for r in per_image if not r["tools"][name].get("solved")],
            "out_of_limits": [r["image"] for r in per_image
                              if r["tools"][name].get("solved") and not r["tools"][name].get("ok")],
            "median_bore_arcsec": median([x["bore_arcsec"] for x in solved]),
            "median_roll_arcsec": median([x["roll_deg"] * 3600 for x in solved]),
            "median_time_ms": median([x["time_ms"] for x in rs]),
            "median_time_ms_1280x960": median([r["tools"][name]["time_ms"] for r in per_image
                                               if "jan1_" in r["image"] or "test2_g100" in r["image"]]),
        }
    return out


def _print(per_image: list[dict], summary: dict, names: list[str]) -> None:
    cols = ["image"] + [f"{n} {k}" for n in names for k in ("″ / roll°", "ms")]
    rows = []
    for r in per_image:
        row = [r["image"].split("/")[-1][:30]]
        for n in names:
            x = r["tools"][n]
            if x.get("solved"):
                mark = "" if x.get("ok") else " ✗"
                row += [f"{x['bore_arcsec']:.1f} / {x['roll_deg']:.3f}{mark}", x["time_ms"]]
            else:
                row += [f"FAIL {str(x.get('status', ''))[:12]}", x["time_ms"]]
        rows.append(row)
    print_table("(a) real images: boresight error vs reference (″) / roll error (°), end-to-end time (ms)",
                cols, rows)
    cols = ["tool", "solved", "within limits", "median ″", "median roll ″", "median ms", "ms 1280×960",
            "ratio skyfix/tool (ms)"]
    rows = []
    sk = summary.get("skyfix", {})
    for n in names:
        s = summary[n]
        rows.append([n, f"{s['solved']}/{s['n']}", f"{s['within_limits']}/{s['n']}", s["median_bore_arcsec"],
                     s["median_roll_arcsec"], s["median_time_ms"], s["median_time_ms_1280x960"],
                     ratio(sk.get("median_time_ms", float("nan")), s["median_time_ms"])])
    print_table("(a) real images: summary", cols, rows)
    for n in names:
        if summary[n]["failed"] or summary[n]["out_of_limits"]:
            say(f"  {n}: failed {summary[n]['failed']}; out of limits {summary[n]['out_of_limits']}")
