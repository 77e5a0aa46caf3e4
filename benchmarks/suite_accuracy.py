"""Suite (c): accuracy on frames from the independent renderer (benchmarks/render.py).

8°, 15° and 30° fields, 1280×960, 12-bit, Gaussian PSF (σ 1 px) integrated over pixels,
Poisson + read noise, hot pixels, 3 false stars; truth from the rendering attitude. Each tool
solves the same in-memory frames (extraction + identification + attitude) and is told the FOV;
skyfix runs a second time without it (``skyfix (no FOV)``).
Reports median / p90 boresight error (″) and median roll error (″), and the skyfix/peer ratio.
"""

from __future__ import annotations

import numpy as np

from common import boresight_error_arcsec, median, now_ms, pct, ratio, roll_error_deg
from render import RenderSpec, StarSky, random_attitudes, render
from report import print_table, say


def run(tools: dict, n_images: int = 20, fovs=(8.0, 15.0, 30.0), seed: int = 7, alternate: bool = False
        ) -> dict:
    """``alternate`` reverses the tools' order every other frame (``--against``)."""
    sky = StarSky(mag_limit=9.0)
    out = {}
    for fov in fovs:
        spec = RenderSpec(fov_deg=fov)
        rng = np.random.default_rng(seed + int(fov * 10))
        attitudes = random_attitudes(n_images, rng)
        # skyfix also runs without the FOV (its default use), as "skyfix (no FOV)".
        jobs = [(name, tool, fov) for name, tool in tools.items()]
        jobs += [(f"{name} (no FOV)", tool, None) for name, tool in tools.items()
                 if getattr(tool, "is_skyfix", False)]
        runs = {name: [] for name, _, _ in jobs}
        t0 = now_ms()
        for k, A in enumerate(attitudes):
            img = render(A, sky, spec, rng)
            for name, tool, hint in (jobs[::-1] if alternate and k % 2 else jobs):
                if name == "cedar-solve" and not (tool.min_fov <= fov <= tool.max_fov):
                    continue
                try:
                    a = tool.solve_image(img, fov_deg=hint)
                except Exception as exc:  # noqa: BLE001 - a crash counts as a failure
                    runs[name].append({"solved": False, "status": f"{type(exc).__name__}: {exc}"[:120]})
                    continue
                r = {"solved": a.solved, "status": a.status, "time_ms": a.time_ms, "n_matched": a.n_matched}
                if a.solved:
                    r.update(bore_arcsec=boresight_error_arcsec(a.A, A),
                             roll_arcsec=roll_error_deg(a.A, A) * 3600.0)
                runs[name].append(r)
        summary = {name: _summary(rs) for name, rs in runs.items() if rs}
        out[f"{fov:g}deg"] = {"spec": spec.__dict__, "summary": summary, "wall_s": (now_ms() - t0) / 1e3}
        _print(fov, spec, summary)
    return out


def against_measures(results: dict, tree: str, ref: str) -> list:
    """Tree vs REF per field, with and without the FOV (``against.Measure`` rows)."""
    from against import Measure

    out = []
    for key, v in results.items():
        summ = v["summary"]
        for suffix in ("", " (no FOV)"):
            a, b = summ.get(tree + suffix), summ.get(ref + suffix)
            if not (a and b):
                continue
            where = f"{key.replace('deg', '°')}{suffix}"
            out += [Measure("c", f"{where}: median boresight ″", a["median_bore_arcsec"],
                            b["median_bore_arcsec"]),
                    Measure("c", f"{where}: p90 boresight ″", a["p90_bore_arcsec"], b["p90_bore_arcsec"],
                            "info"),
                    Measure("c", f"{where}: median roll ″", a["median_roll_arcsec"], b["median_roll_arcsec"]),
                    Measure("c", f"{where}: solved", a["solved"], b["solved"], "count", "higher"),
                    Measure("c", f"{where}: median ms", a["median_ms"], b["median_ms"])]
    return out


def _summary(rs: list[dict]) -> dict:
    ok = [r for r in rs if r["solved"]]
    return {"n": len(rs), "solved": len(ok),
            "median_bore_arcsec": median([r["bore_arcsec"] for r in ok]),
            "p90_bore_arcsec": pct([r["bore_arcsec"] for r in ok], 90.0),
            "max_bore_arcsec": pct([r["bore_arcsec"] for r in ok], 100.0),
            "median_roll_arcsec": median([r["roll_arcsec"] for r in ok]),
            "p90_roll_arcsec": pct([r["roll_arcsec"] for r in ok], 90.0),
            "median_ms": median([r.get("time_ms", float("nan")) for r in rs]),
            "median_matched": median([r["n_matched"] for r in ok]),
            "statuses": {st: sum(r["status"] == st for r in rs if not r["solved"])
                         for st in {r["status"] for r in rs if not r["solved"]}}}


def _print(fov: float, spec: RenderSpec, summary: dict) -> None:
    sk = summary.get("skyfix", {})
    cols = ["tool", "solved", "median ″", "p90 ″", "max ″", "median roll ″", "p90 roll ″", "median ms",
            "stars matched", "skyfix/tool ″", "skyfix/tool roll"]
    rows = [[name, f"{s['solved']}/{s['n']}", s["median_bore_arcsec"], s["p90_bore_arcsec"],
             s["max_bore_arcsec"], s["median_roll_arcsec"], s["p90_roll_arcsec"], s["median_ms"],
             s["median_matched"],
             ratio(sk.get("median_bore_arcsec", np.nan), s["median_bore_arcsec"]),
             ratio(sk.get("median_roll_arcsec", np.nan), s["median_roll_arcsec"])]
            for name, s in summary.items()]
    scale = fov * 3600 / spec.width
    print_table(f"(c) rendered frames, {fov:g}° field ({scale:.1f}″/px), {spec.width}×{spec.height} 12-bit",
                cols, rows)
    for name, s in summary.items():
        if s["statuses"]:
            say(f"  {name} failures: {s['statuses']}")
