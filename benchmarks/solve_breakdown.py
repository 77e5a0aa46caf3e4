"""Where the time of a warm ``skyfix solve IMAGE`` process goes (issue 22, process start).

Run: ``PYTHONPATH=<tree>/src python benchmarks/solve_breakdown.py [IMAGE] [--repeat N]``

Runs ``skyfix solve IMAGE`` in this process, as the console script does, after importing its
parts one at a time, and prints wall and CPU time of each phase (from the interpreter's start;
the interpreter itself is ``python -c pass``, not counted):

- ``import skyfix.cli`` — typer, the command table, ``import skyfix`` (its kernel-cache check);
- ``import numba``, then the solve's modules (``skyfix.attitude``, ``skyfix.identify``,
  ``skyfix.pipeline``: their numba dispatchers are created, nothing compiles or loads);
- the command: option parsing (typer's coercion imports pydantic), the database load, the solve;
- inside the command, the time spent in numba dispatchers' first calls — typing the arguments
  and loading the cached machine code (or compiling, which a warm cache never does: the count of
  kernels compiled is printed) — at the outermost dispatcher only; of it, numba's one-off set-up
  of its target registries on the first dispatch (``load_additional_registries``: it imports
  numba.np.arraymath, numba.np.linalg, scipy.linalg's BLAS …);
- then the same solve ``--repeat`` more times in the process (kernels loaded): what is left is
  skyfix's own work.

Warm numba's cache first (one solve in the tree): a first run on a machine compiles.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from pathlib import Path

_T0 = (time.perf_counter(), time.process_time())


def _now() -> tuple[float, float]:
    return time.perf_counter(), time.process_time()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("image", nargs="?", default=str(Path(__file__).resolve().parents[1] / "examples/sky.png"))
    ap.add_argument("--repeat", type=int, default=3, help="solves after the first (default 3)")
    opts = ap.parse_args()
    rows: list[tuple[str, float, float]] = []

    def phase(name: str, start: tuple[float, float]) -> tuple[float, float]:
        end = _now()
        rows.append((name, end[0] - start[0], end[1] - start[1]))
        return end

    t = _now()
    import skyfix.cli as cli

    # the module whose load_database the solve command calls (skyfix.cli itself before cli/ was a package)
    command = importlib.import_module("skyfix.cli.solve") if hasattr(cli, "__path__") else cli
    t = phase("import skyfix.cli (typer, skyfix, the command table)", t)
    import numba
    from numba.core import cpu, dispatcher, event

    t = phase("import numba", t)
    import skyfix.attitude  # noqa: F401
    import skyfix.identify  # noqa: F401
    import skyfix.pipeline as pipeline

    t = phase("import the solve's modules (attitude, identify, pipeline)", t)

    first = {"wall": 0.0, "cpu": 0.0, "n": 0, "depth": 0, "compiled": 0, "reg_wall": 0.0, "reg_cpu": 0.0}
    compile_for_args = dispatcher.Dispatcher._compile_for_args

    def timed(self, *args, **kwargs):
        first["depth"] += 1
        s = _now()
        try:
            return compile_for_args(self, *args, **kwargs)
        finally:
            first["depth"] -= 1
            if first["depth"] == 0:
                e = _now()
                first["wall"] += e[0] - s[0]
                first["cpu"] += e[1] - s[1]
                first["n"] += 1

    registries = cpu.CPUContext.load_additional_registries

    def timed_registries(self):
        s = _now()
        try:
            return registries(self)
        finally:
            e = _now()
            first["reg_wall"] += e[0] - s[0]
            first["reg_cpu"] += e[1] - s[1]

    dispatcher.Dispatcher._compile_for_args = timed
    cpu.CPUContext.load_additional_registries = timed_registries

    class Compiles(event.Listener):
        def on_start(self, ev) -> None:
            first["compiled"] += 1

        def on_end(self, ev) -> None:
            pass

    event.register("numba:compile", Compiles())
    load_database, solve = command.load_database, pipeline.solve
    inner: dict[str, tuple[float, float]] = {}

    def timed_load_database(*args, **kwargs):
        s = _now()
        out = load_database(*args, **kwargs)
        e = _now()
        inner["database load"] = (e[0] - s[0], e[1] - s[1])
        return out

    def timed_solve(*args, **kwargs):
        s = _now()
        sol = solve(*args, **kwargs)
        e = _now()
        inner["the solve (first in the process)"] = (e[0] - s[0], e[1] - s[1])
        inner["  solved" if sol.solved else "  NOT SOLVED"] = (0.0, 0.0)
        return sol

    command.load_database, pipeline.solve = timed_load_database, timed_solve
    t0 = _now()
    try:
        cli.app(["solve", opts.image], prog_name="skyfix", standalone_mode=False)
    except SystemExit:
        pass
    t = phase("the command (parse, database, solve, print)", t0)
    whole = (t[0] - _T0[0], t[1] - _T0[1])
    for name, (w, c) in inner.items():
        rows.append(("  " + name, w, c))
    rows.append(("  in numba dispatchers' first calls (cache loads)", first["wall"], first["cpu"]))
    rows.append(("    of which numba's registries on the first dispatch",
                 first["reg_wall"], first["reg_cpu"]))
    command.load_database, pipeline.solve = load_database, solve
    later = []
    for _ in range(opts.repeat):
        s = _now()
        pipeline.solve(opts.image)
        e = _now()
        later.append((e[0] - s[0], e[1] - s[1]))
    print(f"{'phase':62s} {'wall ms':>8s} {'CPU ms':>8s}")
    for name, w, c in rows:
        print(f"{name:62s} {w * 1e3:8.0f} {c * 1e3:8.0f}")
    print(f"{'whole process after the interpreter started':62s} {whole[0] * 1e3:8.0f} {whole[1] * 1e3:8.0f}")
    if later:
        w = sorted(x[0] for x in later)[len(later) // 2]
        c = sorted(x[1] for x in later)[len(later) // 2]
        print(f"{'a later solve in the same process (median)':62s} {w * 1e3:8.0f} {c * 1e3:8.0f}")
    print(f"first dispatcher calls: {first['n']}; kernels compiled: {first['compiled']} (0: a warm cache)")
    print(f"numba {numba.__version__}, python {sys.version.split()[0]}")


if __name__ == "__main__":
    main()
