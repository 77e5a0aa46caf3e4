"""Whole-process time of the ``skyfix`` command against another tree, in the same run (issue 22).

Run: ``python benchmarks/process_start.py --against /path/to/other/worktree [--n 7] [--pyc both]``

Each command (``--version``, ``-h``, ``solve -h``, ``solve examples/sky.png``, ``detect
examples/sky.png``) runs as a fresh process the way the ``skyfix`` console script runs it
(``from skyfix.cli import app; app()``), with ``PYTHONPATH=<tree>/src``, alternating between the
two trees (the order flips every round, so the machine's load falls on both alike). Printed per
command and tree: the median wall time and the median CPU time (user + system) of the process,
and the ratio this tree / the other. CPU time moves less than wall time on a shared machine.

``--pyc``: ``yes`` — the trees' ``.pyc`` files are written first and used (what a user has);
``no`` — none for the trees' sources (``PYTHONDONTWRITEBYTECODE=1`` with every skyfix ``.pyc``
deleted before each run: each run compiles the sources it imports); ``both`` (default).

Warm numba's cache in both trees first (one solve and one detect each): a run that compiled
kernels is reported as such and is not a process-start figure.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
ENTRY = "import sys; from skyfix.cli import app; sys.exit(app())"
COMMANDS = [["--version"], ["-h"], ["solve", "-h"], ["solve", "examples/sky.png"],
            ["detect", "examples/sky.png"]]


def _drop_pyc(tree: Path) -> None:
    for p in (tree / "src" / "skyfix").rglob("*.pyc"):
        p.unlink(missing_ok=True)


def _env(tree: Path, pyc: bool) -> dict[str, str]:
    env = dict(os.environ, PYTHONPATH=str(tree / "src"))
    if pyc:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
    else:
        env["PYTHONDONTWRITEBYTECODE"] = "1"
    return env


def run_once(tree: Path, args: list[str], pyc: bool) -> tuple[float, float, int]:
    """(wall s, CPU s, exit status) of one ``skyfix ARGS`` process in ``tree``."""
    if not pyc:
        _drop_pyc(tree)
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", ENTRY, *args], cwd=tree, env=_env(tree, pyc),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    return wall, usage.ru_utime + usage.ru_stime, os.waitstatus_to_exitcode(status)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", type=Path, required=True,
                    help="the other tree (e.g. a worktree of the base commit)")
    ap.add_argument("--n", type=int, default=7, help="runs per command, tree and mode (default 7)")
    ap.add_argument("--pyc", choices=("yes", "no", "both"), default="both")
    ap.add_argument("--commands", default="", help="only these commands, ';'-separated (e.g. '--version;-h')")
    opts = ap.parse_args()
    trees = {"this": HERE, "other": opts.against.resolve()}
    commands = [c.split() for c in opts.commands.split(";")] if opts.commands else COMMANDS
    modes = {"yes": [True], "no": [False], "both": [True, False]}[opts.pyc]
    print(f"this: {trees['this']}  other: {trees['other']}  n={opts.n}  python {sys.executable}")
    for pyc in modes:
        if pyc:  # write the .pyc files once (and warm the OS file cache)
            for tree in trees.values():
                run_once(tree, ["--version"], True)
                run_once(tree, ["solve", "-h"], True)
        print(f"\n.pyc files: {'yes' if pyc else 'no'}")
        print(f"{'command':28s} {'this wall':>10s} {'other wall':>11s} {'ratio':>6s}   "
              f"{'this CPU':>9s} {'other CPU':>10s} {'ratio':>6s}")
        for args in commands:
            res: dict[str, list[tuple[float, float, int]]] = {k: [] for k in trees}
            for i in range(opts.n):
                for name in (("this", "other") if i % 2 == 0 else ("other", "this")):
                    res[name].append(run_once(trees[name], args, pyc))
            wall = {k: statistics.median(r[0] for r in v) for k, v in res.items()}
            cpu = {k: statistics.median(r[1] for r in v) for k, v in res.items()}
            codes = {k: sorted({r[2] for r in v}) for k, v in res.items()}
            flag = "" if all(c == [0] for c in codes.values()) else f"  exit codes {codes}"
            print(f"skyfix {' '.join(args):21s} {wall['this']:9.3f}s {wall['other']:10.3f}s "
                  f"{wall['this'] / wall['other']:6.2f}   {cpu['this']:8.3f}s {cpu['other']:9.3f}s "
                  f"{cpu['this'] / cpu['other']:6.2f}{flag}")


if __name__ == "__main__":
    main()
