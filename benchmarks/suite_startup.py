"""Suite (h): start-up — what a user meets before the first answer (issue 22). skyfix alone.

Every figure is the wall time of a whole process, started the way the ``skyfix`` console script
starts (``[project.scripts]`` of the side's own ``pyproject.toml``), with the side's ``src``
first on ``PYTHONPATH``; medians over ``n`` runs (≥ 5), the sides alternating run by run:

- ``cli``: ``skyfix --version`` and ``skyfix -h``;
- ``process``: ``skyfix solve examples/sky.png`` with the kernels and the database cached (one
  untimed run first compiles what is missing);
- ``in-process``: one process importing skyfix and solving the same image six times: the import,
  the first solve, the second, and a later one (median of the 3rd–6th), and first / later;
- ``cold`` (opt-in, ``--cold``; minutes a side): the first ``skyfix solve`` after an install — a
  copy of the side's sources with no compiled kernels (``.pyc`` compiled, as pip does) and an
  empty ``SKYFIX_CACHE`` (catalogue, pattern database, kernels all from scratch); for a side with
  ``skyfix.aot`` the README's setup runs ``skyfix warmup`` first, timed on its own row;
- ``first-use`` (opt-in, ``--first-use``; a few minutes a side): the first use of each other
  path (a JPEG, a uint16 array, an attitude hint, the tracker, each centroider, each
  identification method) in a process whose solve path is already compiled: a copy of the
  sources with only the solve path's kernels cached, one copy per path (so no path inherits
  another's kernels); the first call's wall time less a later call's (``startup_probe.py``).

With ``--against REF`` each measure is taken for both sides in the same run.
"""

from __future__ import annotations

import compileall
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from common import BENCH_DIR, REPO_ROOT, median
from report import print_table, say

PROBE = BENCH_DIR / "startup_probe.py"
IMAGE = REPO_ROOT / "examples" / "sky.png"
MEASURES = ("cli", "process", "in-process")
IN_PROCESS_SOLVES = 6


def _entry(root: Path) -> str:
    """``module:attr`` of the side's ``skyfix`` console script."""
    try:
        text = (root / "pyproject.toml").read_text()
    except OSError:
        return "skyfix.cli:app"
    section = text.split("[project.scripts]", 1)[-1].split("\n[", 1)[0]
    m = re.search(r'^\s*skyfix\s*=\s*"([^"]+)"', section, re.M)
    return m.group(1) if m else "skyfix.cli:app"


def cli_command(root: Path, *args: str) -> list[str]:
    """The command line the console script amounts to (the same interpreter as this run)."""
    module, _, attr = _entry(root).partition(":")
    code = (f"import sys\nfrom {module} import {attr.split('.')[0]} as _entry\n"
            f"sys.argv[0] = 'skyfix'\nsys.exit(_entry{''.join('.' + a for a in attr.split('.')[1:])}())")
    return [sys.executable, "-c", code, *args]


def _env(src: Path, **extra: str) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(src), *filter(None, [os.environ.get("PYTHONPATH")])])
    env.pop("NUMBA_CACHE_DIR", None)  # kernels beside the sources, as after an install
    env.update(extra)
    return env


def timed_run(cmd: list[str], env: dict, timeout: float = 1800) -> dict:
    t0 = time.perf_counter()
    r = subprocess.run(cmd, env=env, cwd=str(REPO_ROOT), capture_output=True, text=True, timeout=timeout)
    wall = time.perf_counter() - t0
    return {"wall_s": wall, "rc": r.returncode, "stdout": r.stdout[-2000:], "stderr": r.stderr[-2000:]}


def probe(src: Path, *args: str, env_extra: dict | None = None, timeout: float = 1800) -> dict:
    r = timed_run([sys.executable, str(PROBE), *args], _env(src, **(env_extra or {})), timeout)
    for line in r["stdout"].splitlines()[::-1]:
        if line.startswith("PROBE-RESULT "):
            return {**json.loads(line[len("PROBE-RESULT "):]), "wall_s": r["wall_s"]}
    raise RuntimeError(f"probe {args[0]} failed (rc {r['rc']}): {r['stderr'][-600:]}")


def _order(sides: list, i: int) -> list:
    return sides[::-1] if i % 2 else sides


def warm_runs(sides: list, measures: tuple[str, ...], n: int) -> dict:
    """cli / process / in-process, ``n`` rounds, the sides alternating."""
    out = {s.label: {"version_s": [], "help_s": [], "solve_process_s": [], "solve_rc": [], "import_ms": [],
                     "first_ms": [], "second_ms": [], "later_ms": [], "in_process_solved": []} for s in sides}
    if "process" in measures or "in-process" in measures:
        for s in sides:  # compile whatever this side's cache lacks, untimed
            r = timed_run(cli_command(s.root, "solve", str(IMAGE)), _env(s.src))
            say(f"  {s.label}: warm-up solve {r['wall_s']:.1f} s (rc {r['rc']})")
    for i in range(n):
        for s in _order(sides, i):
            o = out[s.label]
            if "cli" in measures:
                o["version_s"].append(timed_run(cli_command(s.root, "--version"), _env(s.src))["wall_s"])
                o["help_s"].append(timed_run(cli_command(s.root, "-h"), _env(s.src))["wall_s"])
            if "process" in measures:
                r = timed_run(cli_command(s.root, "solve", str(IMAGE)), _env(s.src))
                o["solve_process_s"].append(r["wall_s"])
                o["solve_rc"].append(r["rc"])
            if "in-process" in measures:
                p = probe(s.src, "in-process", str(IMAGE), str(IN_PROCESS_SOLVES))
                o["import_ms"].append(p["import_ms"])
                o["first_ms"].append(p["solve_ms"][0])
                o["second_ms"].append(p["solve_ms"][1])
                o["later_ms"].append(median(p["solve_ms"][2:]))
                o["in_process_solved"].append(all(p["solved"]))
    summary = {}
    for label, o in out.items():
        first, later = median(o["first_ms"]), median(o["later_ms"])
        summary[label] = {"version_s": median(o["version_s"]), "help_s": median(o["help_s"]),
                          "solve_process_s": median(o["solve_process_s"]),
                          "solve_rc": sorted(set(o["solve_rc"])),
                          "import_ms": median(o["import_ms"]), "first_solve_ms": first,
                          "second_solve_ms": median(o["second_ms"]), "later_solve_ms": later,
                          "first_over_later": first / later if later > 0 else float("nan"),
                          "in_process_solved": (all(o["in_process_solved"]) if o["in_process_solved"]
                                                else None),
                          "runs": o}
    return summary


def fresh_copy(src: Path, dest: Path) -> Path:
    """``src`` (the package's parent folder) copied without compiled kernels or bytecode, then
    byte-compiled as ``pip install`` does: what a new install holds."""
    shutil.copytree(src, dest / "src", ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc", "*.pyc",
                                                                     "*.egg-info", "_aot"))
    compileall.compile_dir(str(dest / "src"), quiet=1)
    return dest / "src"


def cold(sides: list, n: int = 1) -> dict:
    """The first ``skyfix solve examples/sky.png`` on a fresh copy and an empty cache."""
    out = {s.label: [] for s in sides}
    for i in range(n):
        for s in _order(sides, i):
            tmp = Path(tempfile.mkdtemp(prefix="skyfix-cold-"))
            try:
                src = fresh_copy(s.src, tmp)
                (tmp / "cache").mkdir()
                env = _env(src, SKYFIX_CACHE=str(tmp / "cache"))
                install = None
                if (src / "skyfix" / "aot.py").exists():  # the README's setup runs `skyfix warmup`
                    install = timed_run(cli_command(s.root, "warmup"), env)
                    say(f"  {s.label}: setup's skyfix warmup {install['wall_s']:.1f} s (rc {install['rc']})")
                r = timed_run(cli_command(s.root, "solve", str(IMAGE)), env)
                r["warmup_s"] = install["wall_s"] if install else None
                say(f"  {s.label}: cold first solve {r['wall_s']:.1f} s (rc {r['rc']})")
                out[s.label].append(r)
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
    return {label: {"wall_s": median([r["wall_s"] for r in rs]), "rc": [r["rc"] for r in rs],
                    "warmup_s": rs[-1]["warmup_s"] if rs else None,
                    "messages": rs[-1]["stderr"][-1000:] if rs else ""} for label, rs in out.items()}


def make_jpeg(folder: Path) -> Path:
    """examples/sky.png as an 8-bit JPEG (the same file for every side)."""
    from PIL import Image

    with Image.open(IMAGE) as im:
        a = np.asarray(im).astype(np.float64)
    top = np.percentile(a, 99.95)
    lo = np.median(a)
    img = np.clip((a - lo) / max(top - lo, 1.0) * 230 + 20, 0, 255).astype(np.uint8)
    path = folder / "sky.jpg"
    Image.fromarray(img).save(path, quality=92)
    return path


def first_use(sides: list, paths: list[str] | None = None) -> dict:
    """Each path's first use on a copy whose cache holds only the solve path's kernels."""
    tmp = Path(tempfile.mkdtemp(prefix="skyfix-first-use-"))
    out: dict[str, dict] = {s.label: {} for s in sides}
    try:
        jpeg = make_jpeg(tmp)
        bases = {}
        for s in sides:
            base = tmp / s.label.replace("@", "_") / "base"
            src = fresh_copy(s.src, base)
            r = probe(src, "warm", str(IMAGE))
            say(f"  {s.label}: solve path compiled in a fresh copy: {r['wall_s']:.1f} s")
            bases[s.label] = (src, r["wall_s"])
        if paths is None:
            paths = probe(sides[0].src, "paths")["paths"]
        for i, path in enumerate(paths):
            for s in _order(sides, i):
                dest = tmp / s.label.replace("@", "_") / path
                shutil.copytree(bases[s.label][0], dest / "src")  # copy2: mtimes kept, so the cache is valid
                try:
                    r = probe(dest / "src", "first-use", path, str(IMAGE), str(jpeg))
                    r["first_use_s"] = (r["first_ms"] - r["later_ms"]) / 1e3
                except Exception as exc:  # noqa: BLE001 - a path missing on a side, a crash: recorded
                    r = {"error": f"{type(exc).__name__}: {exc}"[:400], "first_use_s": float("nan")}
                out[s.label][path] = r
                say(f"  {s.label} {path}: first use {r['first_use_s']:.1f} s"
                    + (f" ({r['error'][:120]})" if "error" in r else
                       f" (first {r['first_ms'] / 1e3:.2f} s, later {r['later_ms'] / 1e3:.3f} s, "
                       f"solve path loaded in {r['warm_solve_ms'] / 1e3:.1f} s)"))
                shutil.rmtree(dest, ignore_errors=True)
        for s in sides:
            out[s.label]["_solve_path_compile_s"] = bases[s.label][1]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def run(sides: list, n: int = 5, measures: tuple[str, ...] = MEASURES, cold_start: bool = False,
        first_uses: bool = False) -> dict:
    results: dict = {"n": n, "measures": list(measures), "image": str(IMAGE.relative_to(REPO_ROOT)),
                     "sides": {s.label: {"src": str(s.src), "commit": s.commit} for s in sides}}
    results["warm"] = warm_runs(sides, measures, n)
    if cold_start:
        results["cold"] = cold(sides)
    if first_uses:
        results["first_use"] = first_use(sides)
    _print(results, sides)
    return results


def _print(results: dict, sides: list) -> None:
    labels = [s.label for s in sides]
    w = results["warm"]
    rows = []
    for key, what in (("version_s", "skyfix --version, s"), ("help_s", "skyfix -h, s"),
                      ("solve_process_s", "skyfix solve sky.png (whole process, warm), s"),
                      ("import_ms", "import skyfix, ms"), ("first_solve_ms", "first solve in process, ms"),
                      ("second_solve_ms", "second solve, ms"),
                      ("later_solve_ms", "later solve (3rd–6th), ms"),
                      ("first_over_later", "first / later")):
        rows.append([what] + [w[label][key] for label in labels])
    if "cold" in results:
        rows.append(["cold: the setup's skyfix warmup (compile ahead of time + database), s"]
                    + [results["cold"][label].get("warmup_s") or "—" for label in labels])
        rows.append(["cold: first solve, fresh install, empty cache, s"]
                    + [results["cold"][label]["wall_s"] for label in labels])
    if "first_use" in results:
        fu = results["first_use"]
        rows.append(["first use: solve path compile (fresh copy), s"]
                    + [fu[label].get("_solve_path_compile_s", float("nan")) for label in labels])
        for path in [p for p in fu[labels[0]] if not p.startswith("_")]:
            rows.append([f"first use: {path}, s (first − later)"]
                        + [fu[label].get(path, {}).get("first_use_s", float("nan")) for label in labels])
    print_table(f"(h) start-up: whole processes, median of {results['n']} (examples/sky.png)",
                ["measure"] + labels, rows,
                note="targets (issue 22): --version/-h ≤ 0.3 s; warm whole-process solve ≤ 1 s; "
                     "first solve ≤ 3× a later one; cold first solve ≤ 20 s; each path's first use ≤ 10 s")


def against_measures(results: dict, tree: str, ref: str) -> list:
    """Tree vs REF (``against.Measure`` rows)."""
    from against import Measure

    w = results.get("warm", {})
    a, b = w.get(tree), w.get(ref)
    out = []
    if a and b:
        for key, what in (("version_s", "skyfix --version s"), ("help_s", "skyfix -h s"),
                          ("solve_process_s", "skyfix solve sky.png, whole process s"),
                          ("import_ms", "import skyfix ms"), ("first_solve_ms", "first solve in process ms"),
                          ("second_solve_ms", "second solve in process ms"),
                          ("later_solve_ms", "later solve in process ms")):
            if np.isfinite(a[key]) and np.isfinite(b[key]):
                out.append(Measure("h", what, a[key], b[key]))
    if "cold" in results:
        out.append(Measure("h", "cold first solve s", results["cold"][tree]["wall_s"],
                           results["cold"][ref]["wall_s"], "info"))
    if "first_use" in results:
        fa, fb = results["first_use"][tree], results["first_use"][ref]
        for path in [p for p in fa if not p.startswith("_")]:
            out.append(Measure("h", f"first use {path} s", fa[path].get("first_use_s", float("nan")),
                               fb.get(path, {}).get("first_use_s", float("nan")), "info"))
    return out
