"""Suite (d): extraction speed, end-to-end time on 1280×960 files, database build and load times.

Every figure is a median over repeats (the machine is shared, so single timings are noisy).
- extraction: ms per megapixel on the real images and on rendered 1280×960 frames, from an
  already-decoded array (tetra3rs with its default threads and with ``threads=1``).
- end to end: 16-bit PNG files of rendered 15° 1280×960 frames, file → attitude.
- databases: build time for 10–30° and the load time of the cached file (each skyfix side
  also loads its default database from the user cache, as a solve does).
- final fit: ``skyfix.final_fit.final_fit`` of one identified frame (FOV given, no camera file):
  the centroids of rendered frames, 1280×960 at 15° and 752×480 at 30°.

With ``--against REF`` the tools are the two skyfix sides (worker processes), each figure taken
from the same inputs in alternating order; every time is measured inside the call.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from common import CACHE_DIR, REAL_DIR, median, now_ms, pct, ratio
from peers import load_gray
from render import RenderSpec, StarSky, random_attitudes, render
from report import print_table, say


def _rendered_frames(n: int, seed: int = 11) -> list[tuple[np.ndarray, np.ndarray]]:
    sky = StarSky(mag_limit=9.0)
    rng = np.random.default_rng(seed)
    spec = RenderSpec(fov_deg=15.0)
    return [(render(A, sky, spec, rng), A) for A in random_attitudes(n, rng)]


def _time(fn, repeats: int) -> float:
    ts = []
    for _ in range(repeats):
        t0 = now_ms()
        fn()
        ts.append(now_ms() - t0)
    return median(ts)


def _skyfix_tools(tools: dict) -> dict:
    return {k: v for k, v in tools.items() if getattr(v, "is_skyfix", False)}


def _call_ms(fn, repeats: int) -> float:
    """Median over ``repeats`` calls of the time each call reports (its second value)."""
    return median([fn()[1] for _ in range(repeats)])


def extraction(tools: dict, frames, repeats: int, alternate: bool = False) -> dict:
    images = [(p.relative_to(REAL_DIR).as_posix(), p) for p in sorted(REAL_DIR.glob("*/*"))
              if p.suffix.lower() in (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".fits")]
    rows = {}
    inputs = [(name, load_gray(p), p) for name, p in images]
    inputs += [(f"rendered_{i}", img, None) for i, (img, _) in enumerate(frames)]
    order = [(k, v) for k, v in tools.items() if not k.startswith("tetra3rs (")]  # variants: same extractor
    for i, (name, arr, path) in enumerate(inputs):
        mp = arr.shape[0] * arr.shape[1] / 1e6
        row = {"megapixels": mp}
        for tname, tool in (order[::-1] if alternate and i % 2 else order):
            # skyfix extracts from its own reader's array (its normal path); peers from load_gray's.
            data = tool.read(path) if (getattr(tool, "is_skyfix", False) and path is not None) else arr
            try:
                tool.extract(data)  # warm up (first-call compilation / allocation)
                row[tname] = _call_ms(lambda t=tool, a=data: t.extract(a), repeats) / mp
                if tname == "tetra3rs":
                    one = _call_ms(lambda t=tool, a=arr: t.extract(a, threads=1), repeats)
                    row["tetra3rs 1 thread"] = one / mp
            except Exception as exc:  # noqa: BLE001 - record and go on
                row[tname] = f"{type(exc).__name__}: {exc}"[:100]
        rows[name] = row
    names = [k for k in tools if any(k in r for r in rows.values())]
    names += [k for k in next(iter(rows.values())) if k not in names and k != "megapixels"]
    med = {k: median([r[k] for r in rows.values() if isinstance(r.get(k), float)]) for k in names}
    med_1280 = {k: median([r[k] for n, r in rows.items() if isinstance(r.get(k), float) and
                           (n.startswith("rendered") or "jan1_" in n or "g100" in n)]) for k in names}
    table = [[n.split("/")[-1][:34], f"{r['megapixels']:.2f}"] + [r[k] for k in names]
             for n, r in rows.items()]
    table.append(["MEDIAN (all)", ""] + [med[k] for k in names])
    table.append(["MEDIAN (1280×960 + rendered)", ""] + [med_1280[k] for k in names])
    sk = med.get("skyfix")
    table.append(["ratio skyfix/tool (all)", ""]
                 + [ratio(sk, med[k]) if sk else float("nan") for k in names])
    print_table("(d) extraction, ms per megapixel (median of repeats; decoded array in memory)",
                ["image", "MP"] + names, table)
    return {"per_image": rows, "median_ms_per_mp": med, "median_ms_per_mp_1280x960": med_1280}


def end_to_end(tools: dict, frames, repeats: int, alternate: bool = False) -> dict:
    from PIL import Image

    from common import boresight_error_arcsec

    folder = CACHE_DIR / "e2e_png"
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, (img, _) in enumerate(frames):
        p = folder / f"frame_{i:02d}.png"
        Image.fromarray(img.astype(np.uint16)).save(p)  # 16-bit greyscale PNG (12-bit data)
        paths.append(p)
    per = {name: {"times": [], "solved": 0, "errs": [], "broken": False} for name in tools}
    order = list(tools.items())
    for i, (p, (_, A)) in enumerate(zip(paths, frames, strict=True)):
        for tname, tool in (order[::-1] if alternate and i % 2 else order):
            r = per[tname]
            if r["broken"]:
                continue
            hint = None if getattr(tool, "is_skyfix", False) else 15.0
            try:
                a = tool.solve_file(p, fov_deg=hint)
                ts = [a.time_ms] + [tool.solve_file(p, fov_deg=hint).time_ms for _ in range(repeats - 1)]
            except Exception as exc:  # noqa: BLE001
                say(f"  {tname} end-to-end error: {type(exc).__name__}: {exc}")
                r["broken"] = True
                continue
            r["times"].append(median(ts))
            r["solved"] += a.solved
            if a.solved:
                r["errs"].append(boresight_error_arcsec(a.A, A))
    out = {}
    for tname, r in per.items():
        times = r["times"]
        out[tname] = {"n": len(paths), "solved": r["solved"], "median_ms": median(times),
                      "max_ms": max(times) if times else float("nan"),
                      "median_bore_arcsec": median(r["errs"])}
    sk = out.get("skyfix", {}).get("median_ms", float("nan"))
    print_table("(d) end to end, 16-bit PNG file → attitude, 1280×960 15° rendered frames "
                "(skyfix: no FOV hint)",
                ["tool", "solved", "median ms", "max ms", "median ″", "skyfix/tool"],
                [[k, f"{v['solved']}/{v['n']}", v["median_ms"], v["max_ms"], v["median_bore_arcsec"],
                  ratio(sk, v["median_ms"])] for k, v in out.items()])
    return out


def databases(tools: dict, repeats: int, build_repeats: int = 1) -> dict:
    out = {}
    tmp = Path(tempfile.mkdtemp(prefix="skyfix_bench_db_"))
    if "tetra3rs" in tools:
        t = tools["tetra3rs"]
        builds, db = [], None
        for _ in range(build_repeats):
            t0 = now_ms()
            db = t.t3.SolverDatabase.generate_from_gaia(max_fov_deg=30.0, min_fov_deg=10.0,
                                                        epoch_proper_motion_year=t.epoch)
            builds.append(now_ms() - t0)
        p = tmp / "t3rs.bin"
        db.save_to_file(str(p))
        load = _time(lambda: t.t3.SolverDatabase.load_from_file(str(p)), repeats)
        out["tetra3rs"] = {"build_ms": median(builds), "load_ms": load, "bytes": p.stat().st_size,
                           "patterns": db.num_patterns}
    sky = _skyfix_tools(tools)
    built = {}
    for name, tool in sky.items():
        try:
            folder = tmp / name.replace("@", "_")
            folder.mkdir()
            builds = [tool.database_build(folder) for _ in range(build_repeats)]
            built[name] = {"build_ms": median([b["build_ms"] for b in builds]), "path": builds[-1]["path"],
                           "bytes": builds[-1]["bytes"], "loads": [], "default_loads": []}
        except Exception as exc:  # noqa: BLE001
            out[name] = {"error": f"{type(exc).__name__}: {exc}"[:200]}
    if built:
        # A file younger than skyfix.cache.STAMP_MIN_AGE_S is hashed at every load: wait, so that the
        # loads below are the cached loads a user meets. The first load (hash, stamp) is not counted.
        from skyfix.cache import STAMP_MIN_AGE_S

        time.sleep(STAMP_MIN_AGE_S + 0.5)
        names = list(built)
        for r in range(repeats + 1):
            for name in (names[::-1] if r % 2 else names):
                b, tool = built[name], sky[name]
                load, default = tool.database_load(b["path"]), tool.default_database_load()
                if r:
                    b["loads"].append(load)
                    b["default_loads"].append(default)
                else:
                    b["first_load_ms"] = load
        for name, b in built.items():
            out[name] = {"build_ms": b["build_ms"], "load_ms": median(b["loads"]), "bytes": b["bytes"],
                         "first_load_ms": b["first_load_ms"], "default_load_ms": median(b["default_loads"])}
    if "cedar-solve" in tools:
        c = tools["cedar-solve"]
        load = _time(lambda: c.t3.load_database("default_database"), repeats)
        out["cedar-solve"] = {"build_ms": float("nan"), "load_ms": load, "note": "bundled database (10–30°)"}
    shutil.rmtree(tmp, ignore_errors=True)
    sk = out.get("skyfix", {})
    rows = [[k, v.get("build_ms", float("nan")) / 1e3 if "build_ms" in v else v.get("error", ""),
             v.get("load_ms", float("nan")), v.get("bytes", float("nan")) / 1e6 if "bytes" in v else "—",
             ratio(sk.get("build_ms", np.nan), v.get("build_ms", np.nan)),
             ratio(sk.get("load_ms", np.nan), v.get("load_ms", np.nan))] for k, v in out.items()]
    for row, v in zip(rows, out.values(), strict=True):
        row += [v.get("first_load_ms", float("nan")), v.get("default_load_ms", float("nan"))]
    print_table("(d) pattern database 10–30°: build and cached load",
                ["tool", "build s", "load ms", "MB", "skyfix/tool build", "skyfix/tool load",
                 "skyfix first load ms", "default database load ms"], rows,
                note="skyfix load: median of the loads after the first (which checks the whole file's "
                     "SHA-256 and stamps it, as the first use of a new file does); default database: "
                     "skyfix's own from the user cache")
    return out


FINAL_FIT_CASES = (("1280×960 15°", 1280, 960, 15.0), ("752×480 30°", 752, 480, 30.0))


def final_fit(tools: dict, n_frames: int = 10, repeats: int = 5, alternate: bool = False) -> dict:
    """The final fit (FOV given, no camera file) of identified frames from the independent renderer
    (``render.py``; 200 brightest centroids, extracted once by the first skyfix tool — the working
    tree — and handed to every side): the median over frames of each frame's median over
    ``repeats``, per skyfix side."""
    sky = _skyfix_tools(tools)
    if not sky:
        return {}
    extractor = next(iter(sky.values()))
    out = {}
    for label, w, h, fov in FINAL_FIT_CASES:
        rng = np.random.default_rng(29)
        spec = RenderSpec(width=w, height=h, fov_deg=fov)
        inputs = [extractor.extract(render(A, StarSky(9.0), spec, rng), max_stars=200)[0]
                  for A in random_attitudes(n_frames, rng)]
        per = {name: [] for name in sky}
        names = list(sky)
        for i, xy in enumerate(inputs):
            for name in (names[::-1] if alternate and i % 2 else names):
                try:
                    ms = sky[name].final_fit_ms(xy, w, h, fov, repeats)
                except Exception as exc:  # noqa: BLE001
                    say(f"  {name} final fit error: {type(exc).__name__}: {exc}")
                    ms = []
                if ms:
                    per[name].append(median(ms))
        out[label] = {name: {"n": len(v), "median_ms": median(v), "p90_ms": pct(v, 90.0)}
                      for name, v in per.items()}
    names = list(sky)
    print_table("(d) final fit of one identified frame (FOV given, no camera file), rendered frames",
                ["case"] + [f"{n} {k}" for n in names for k in ("frames", "median ms", "p90 ms")],
                [[label] + [x for n in names for x in (v[n]["n"], v[n]["median_ms"], v[n]["p90_ms"])]
                 for label, v in out.items()])
    return out


def run(tools: dict, repeats: int = 5, n_frames: int = 6, build_repeats: int = 1, alternate: bool = False
        ) -> dict:
    frames = _rendered_frames(n_frames)
    return {"extraction": extraction(tools, frames, repeats, alternate),
            "end_to_end_png": end_to_end(tools, frames, max(1, repeats // 2), alternate),
            "databases": databases(tools, repeats, build_repeats),
            "final_fit": final_fit(tools, repeats=repeats, alternate=alternate)}


def against_measures(results: dict, tree: str, ref: str) -> list:
    """Tree vs REF: extraction, end to end, database, final fit (``against.Measure`` rows)."""
    from against import Measure

    out = []
    ext = results.get("extraction", {})
    for key, what in (("median_ms_per_mp", "all"), ("median_ms_per_mp_1280x960", "1280×960")):
        m = ext.get(key, {})
        if tree in m and ref in m:
            out.append(Measure("d", f"extraction ms/MP ({what})", m[tree], m[ref]))
    e2e = results.get("end_to_end_png", {})
    if tree in e2e and ref in e2e:
        a, b = e2e[tree], e2e[ref]
        out += [Measure("d", "16-bit PNG → attitude, median ms", a["median_ms"], b["median_ms"]),
                Measure("d", "16-bit PNG → attitude, solved", a["solved"], b["solved"], "count", "higher")]
    db = results.get("databases", {})
    if "load_ms" in db.get(tree, {}) and "load_ms" in db.get(ref, {}):
        a, b = db[tree], db[ref]
        out += [Measure("d", "database 10–30° build s", a["build_ms"] / 1e3, b["build_ms"] / 1e3),
                Measure("d", "database 10–30° cached load ms", a["load_ms"], b["load_ms"]),
                Measure("d", "database 10–30° first load ms (checksum)", a["first_load_ms"],
                        b["first_load_ms"], "info"),
                Measure("d", "default database load ms", a["default_load_ms"], b["default_load_ms"])]
    for label, v in results.get("final_fit", {}).items():
        if tree in v and ref in v:
            out.append(Measure("d", f"final fit {label}, median ms", v[tree]["median_ms"],
                               v[ref]["median_ms"]))
    return out
