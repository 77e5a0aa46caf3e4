"""The tests' own layout (issue 23): every test file sits in an area folder that mirrors
``src/skyfix/`` (none at the top of ``tests/``), every folder of tests is a package (so two areas
may hold files of the same name), no test reads its data through a machine's absolute path (the
repository, ``examples/``, ``tests/data/`` and the real images are found through
``tests/conftest.py``), and every test file the source, the README, the docs and the benchmarks
cite exists, with the test named after ``::``."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from tests.conftest import ROOT

TESTS = ROOT / "tests"
SRC = ROOT / "src" / "skyfix"
# an area folder per package of src/skyfix/ (cli/: the command); and two more: core/ (the
# top-level modules of src/skyfix/), project/ (the repository as a whole: docs, import graph,
# benchmarks, this layout)
NOT_PACKAGES = {"core", "project"}
# where a test keeps what is not a test: shared data, caches
NOT_TESTS = {"data", "__pycache__"}
# an absolute path of one machine: a home, a scratch or a work folder
_MACHINE_PATH = re.compile(r"(?<![\w.~-])/(?:work|home|tmp|Users|root|mnt|scratch)/")
# a test file cited as tests/<folders>/<file>.py, optionally ::test_name
_CITED = re.compile(r"\btests/((?:[\w-]+/)*[\w-]+\.py)(?:::(\w+))?")


def _test_files() -> list[Path]:
    return sorted(p for p in TESTS.rglob("*.py")
                  if p.name.startswith("test_") and not NOT_TESTS & set(p.relative_to(TESTS).parts))


def _areas() -> set[str]:
    packages = {p.name for p in SRC.iterdir() if (p / "__init__.py").is_file()}
    return packages | NOT_PACKAGES


def test_no_test_file_at_the_top_of_tests():
    top = sorted(p.name for p in TESTS.glob("*.py") if p.name not in ("conftest.py", "__init__.py"))
    assert not top, f"move into an area folder (tests/<package>/, tests/core/ …): {', '.join(top)}"


def test_every_test_sits_in_an_area_folder():
    areas = _areas()
    assert {"detect", "identify", "track", "simulate", "analysis", "_kernels"} <= areas
    stray = [str(p.relative_to(ROOT)) for p in _test_files() if p.relative_to(TESTS).parts[0] not in areas]
    assert not stray, f"not in an area folder ({', '.join(sorted(areas))}): {', '.join(stray)}"


def test_every_folder_of_tests_is_a_package():
    """With an ``__init__.py`` in each folder a test module's name is its path
    (``tests.core.test_io``): two areas may hold a ``test_io.py`` each, and helper modules are
    imported by that name from any folder."""
    folders = {p.parent for p in TESTS.rglob("*.py") if not NOT_TESTS & set(p.relative_to(TESTS).parts)}
    missing = sorted(str(d.relative_to(ROOT)) for d in folders if not (d / "__init__.py").is_file())
    assert not missing, f"no __init__.py in {', '.join(missing)}"


def machine_paths(source: str) -> list[tuple[int, str]]:
    """(line, text) of each string literal (f-strings' parts included, docstrings not) that holds
    a machine's absolute path."""
    tree = ast.parse(source)
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                docstrings.add(id(body[0].value))
    return [(node.lineno, node.value) for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str)
            and id(node) not in docstrings and _MACHINE_PATH.search(node.value)]


def test_machine_paths_are_found():
    # "%" stands for the slash that begins an absolute path (this file must pass its own check)
    source = ('"""Reads %work/x in its docstring, which is prose."""\n'
              'A = "%work/shared/data/real"\nB = f"{A}%home/x"\nC = "~%tmp/x"\nD = "a%tmp/b"\n'
              'E = Path("%tmp/run") / "out.json"\n').replace("%", "/")
    assert [line for line, _ in machine_paths(source)] == [2, 3, 6]


def test_no_test_uses_a_machine_path():
    hits = [f"{p.relative_to(ROOT)}:{line}: {text!r}"
            for p in sorted(TESTS.rglob("*.py")) if "__pycache__" not in p.parts
            for line, text in machine_paths(p.read_text(encoding="utf-8"))]
    assert not hits, ("absolute paths of one machine (find data through tests/conftest.py):\n"
                      + "\n".join(hits))


def test_cited_tests_exist():
    """``tests/…/test_x.py[::test_name]`` in the source, README, docs or benchmarks names a file
    (and a test in it) that exists: a moved or renamed test leaves no stale citation."""
    cited_in = ([ROOT / "README.md"] + sorted((ROOT / "docs").glob("*.md"))
                + sorted(p for p in SRC.rglob("*") if p.suffix in (".py", ".md", ".toml"))
                + sorted(p for p in (ROOT / "benchmarks").rglob("*") if p.suffix in (".py", ".md")
                         # not the benchmarks' own venvs and reference checkouts (.venv-peers, .cache)
                         and not any(part.startswith(".") for part in p.relative_to(ROOT).parts)))
    problems = []
    for path in cited_in:
        for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            for file, name in _CITED.findall(line):
                target = TESTS / file
                where = f"{path.relative_to(ROOT)}:{i}: tests/{file}"
                if not target.is_file():
                    problems.append(f"{where}: no such file")
                elif name and not re.search(rf"^\s*def {name}\(", target.read_text(encoding="utf-8"), re.M):
                    problems.append(f"{where}: no test {name}")
    assert not problems, "\n".join(problems)
