"""What starting ``skyfix`` imports (issue 22, process start).

``skyfix --version``, ``skyfix -h`` and every command's ``-h`` import no heavy package (numpy,
numba, scipy, astropy, matplotlib …) and no command's implementation: the commands are
registered with their signatures, their bodies import what they run. ``skyfix solve`` imports
what a solve runs and nothing else (not the tracker, the analyses, the simulator, plotting,
FITS, scipy.stats, scipy.linalg …). Each check runs the command in a fresh process and reads ``sys.modules``
at its end.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import skyfix
from tests.conftest import EXAMPLES

SRC = Path(skyfix.__file__).resolve().parents[1]
EXAMPLE = EXAMPLES / "sky.png"

#: Packages no version or help output needs.
HEAVY = ("numpy", "numba", "llvmlite", "scipy", "astropy", "matplotlib", "dask", "PIL", "cv2", "pandas")

#: The skyfix modules that define the command table; everything else is a command's implementation.
COMMAND_TABLE = {"skyfix", "skyfix._kernels", "skyfix._numba_lapack", "skyfix.errors", "skyfix.validate",
                 *(f"skyfix.cli{m}" for m in ("", ".common", ".solve", ".detect", ".simulate", ".warmup",
                                             ".track", ".montecarlo", ".database", ".analyze", ".calibrate",
                                             ".observation", ".records", ".inputs", ".cache"))}

_DRIVER = textwrap.dedent("""
    import json, sys
    from skyfix.cli import app
    for args in json.loads(sys.argv[1]):
        try:
            app(args, prog_name="skyfix")
        except SystemExit as exc:
            if exc.code not in (0, None):
                raise
    # the modules loaded: not the stand-ins of scipy's BLAS/LAPACK modules (skyfix._numba_lapack)
    loaded = sorted(m for m, v in sys.modules.items() if type(v).__name__ != "_StandIn")
    print("\\nMODULES " + json.dumps(loaded))
""")


def _modules_after(*invocations: list[str]) -> set[str]:
    """``sys.modules`` of a fresh process that ran ``skyfix ARGS`` for each invocation."""
    return _run(*invocations)[0]


def _run(*invocations: list[str]) -> tuple[set[str], str]:
    """:func:`_modules_after`, and what the process printed before the modules."""
    run = subprocess.run([sys.executable, "-c", _DRIVER, json.dumps(list(invocations))], cwd=SRC,
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    printed, _, last = run.stdout.rstrip().rpartition("\n")
    assert last.startswith("MODULES "), run.stdout[-2000:]
    return set(json.loads(last.removeprefix("MODULES "))), printed


def _heavy(modules: set[str]) -> list[str]:
    return sorted(m for m in modules if m.split(".")[0] in HEAVY)


def _implementation(modules: set[str]) -> list[str]:
    return sorted(m for m in modules if m.split(".")[0] == "skyfix" and m not in COMMAND_TABLE)


def _command_paths() -> list[list[str]]:
    """Every command and command group of ``skyfix``, as the words that name it."""
    import typer.main

    from skyfix.cli import app

    out: list[list[str]] = []

    def walk(command, path: list[str]) -> None:
        out.append(path)
        for name, sub in getattr(command, "commands", {}).items():
            walk(sub, [*path, name])

    walk(typer.main.get_command(app), [])
    return out


def test_the_walk_sees_every_command():
    paths = _command_paths()
    assert {("solve",), ("detect",), ("track",), ("simulate",), ("database", "build"),
            ("calibrate", "frames"), ("analyze", "psf")} <= {tuple(p) for p in paths}


def test_version_imports_nothing_heavy():
    modules = _modules_after(["--version"])
    assert "skyfix.cli" in modules  # the driver did run the command
    assert _heavy(modules) == []
    assert _implementation(modules) == []
    # nor the help renderer (rich) nor typer's value coercion (pydantic): neither is needed
    assert not any(m.split(".")[0] in ("rich", "pydantic") for m in modules)


def test_help_of_every_command_imports_nothing_heavy():
    paths = _command_paths()
    modules, printed = _run(*([*path, "-h"] for path in paths))
    assert printed.count("Usage: skyfix") == len(paths)  # every help was rendered...
    assert not any(m.split(".")[0] == "rich" for m in modules)  # ...as plain text
    assert _heavy(modules) == []
    assert _implementation(modules) == []


#: What a plain solve of a PNG (no time, site, mounting, camera file or hint) has no use for.
SOLVE_UNNEEDED = ("skyfix.track.tracker", "skyfix.analysis", "skyfix.simulate", "skyfix.plot", "skyfix.wcs",
                  "matplotlib", "astropy", "dask", "scipy.stats", "scipy.optimize",
                  # numba's BLAS/LAPACK come from the two Cython modules alone (skyfix._numba_lapack):
                  # not from scipy.linalg's __init__, nor what it drags in
                  "scipy.linalg._", "scipy._lib._array_api", "numpy.f2py", "numpy.testing",
                  # a plain solve skips typer's value coercion (skyfix.cli.solve.plain_solve)
                  "pydantic",
                  # the streak fit (30 kernels to set up) is for the tracker and --smear
                  "skyfix.detect.streak",
                  # issue 22, the first solve in a process: the other detectors, the apparent places
                  # (a time), a site's refraction and ERFA, the body frames (a mounting), TOML (a
                  # camera file), platformdirs (the XDG rule is read on Linux)
                  "skyfix.detect.hillclimb", "skyfix.detect.region_grow", "skyfix.detect.regionprops",
                  "skyfix.corrections.apparent", "skyfix.corrections.refraction", "erfa", "skyfix.frames",
                  "tomllib", "platformdirs",
                  # the solve's kernels call no BLAS or LAPACK (3 × 3 products, Wahba's rotation and
                  # a 3 × 3 eigen-decomposition are written out): scipy's OpenBLAS is not loaded
                  "scipy.linalg")


def test_solve_imports_only_what_it_runs(database):
    modules = _modules_after(["solve", str(EXAMPLE)])
    assert {"skyfix.pipeline", "numba"} <= modules  # it did solve
    assert sorted(m for m in modules if m.startswith(SOLVE_UNNEEDED)) == []


def test_a_python_solve_imports_only_what_it_runs(database):
    code = ("import json, sys, skyfix\n"
            f"assert skyfix.solve({str(EXAMPLE)!r}).status == 'solved'\n"
            "print(json.dumps([m for m, v in sys.modules.items() if type(v).__name__ != '_StandIn']))")
    run = subprocess.run([sys.executable, "-c", code], cwd=SRC, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    modules = set(json.loads(run.stdout.strip().splitlines()[-1]))
    assert "skyfix.final_fit" in modules
    assert sorted(m for m in modules if m.startswith(SOLVE_UNNEEDED)) == []


def test_track_names_load_on_first_use():
    """skyfix.track's names load their modules when first asked for, and are the same objects."""
    import skyfix.track
    from skyfix.track import predictors, tracker

    for name in skyfix.track.__all__:
        assert getattr(skyfix.track, name) is getattr(tracker, name, getattr(predictors, name, None))
    assert skyfix.track.Tracker is tracker.Tracker
    with pytest.raises(AttributeError):
        skyfix.track.NoSuchName  # noqa: B018
