"""Import hygiene of the package: every module imports on its own, the module-level imports form
no cycle, and no module takes a private name from a public module.

- **Each module on its own.** Every module of :mod:`skyfix` is imported first thing in a process
  of its own, so a cycle that shows only with one import order (``b`` imported before ``a``)
  fails here (the idea of Skyfield's ``design/test_import_loops.py``). To keep this to seconds,
  the processes are forks of one driver that has loaded the third-party packages skyfix imports
  (numpy, numba, scipy …) and no skyfix module.
- **No cycle.** The ``import`` statements of every module, read with :mod:`ast`, make a graph of
  modules; it must have no cycle. Only module-level imports count (also those under a
  module-level ``try`` or ``if``, but not under ``if TYPE_CHECKING:``): an import inside a
  function runs when the function is called, after the modules have loaded, and is the way to
  defer an import on purpose. ``from skyfix.a import b`` depends on ``skyfix.a`` and, when ``b``
  is a module, on ``skyfix.a.b``; a package's dependency on its own submodules is not a cycle
  with them (Python sets the package up before running the submodule). Nor may a cycle run
  through imports inside functions: deferring an import keeps start-up light, but two modules
  that import each other are still one module in two files.
- **No private name from a public module.** ``from skyfix.x import _name`` only when
  ``skyfix.x`` is itself private (a part of its dotted name starts with ``_``, e.g.
  ``skyfix.detect._stats``): internals shared between files live in private modules. Imports
  inside functions count here too.
"""

from __future__ import annotations

import ast
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import skyfix

PACKAGE_DIR = Path(skyfix.__file__).resolve().parent

# issue 8: being removed — private names still imported from public modules, as
# "importing module: skyfix.module._name". The set may only shrink: an entry that no longer
# offends fails the test until it is deleted here.
KNOWN_OFFENDERS: set[str] = set()


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _module_files() -> dict[str, Path]:
    files = sorted(p for p in PACKAGE_DIR.rglob("*.py") if "__pycache__" not in p.parts)
    return {_module_name(p): p for p in files}


MODULES = _module_files()


def _is_package(name: str) -> bool:
    return MODULES.get(name, Path()).name == "__init__.py"


def _is_private(module: str) -> bool:
    return any(part.startswith("_") for part in module.split("."))


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(module: str) -> list[tuple[str, str | None, int, bool]]:
    """(imported module, name taken from it or None, line, at module level) for each import.

    Relative imports are resolved; ``import a.b`` gives ``a.b``. Imports under
    ``if TYPE_CHECKING:`` are left out (they never run).
    """
    tree = ast.parse(MODULES[module].read_text(), filename=str(MODULES[module]))
    package = module if _is_package(module) else module.rpartition(".")[0]
    found: list[tuple[str, str | None, int, bool]] = []

    def visit(node: ast.AST, top: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child.test):
                for sub in child.orelse:
                    visit_stmt(sub, top)
                continue
            visit_stmt(child, top)

    def visit_stmt(child: ast.AST, top: bool) -> None:
        if isinstance(child, ast.Import):
            found.extend((alias.name, None, child.lineno, top) for alias in child.names)
        elif isinstance(child, ast.ImportFrom):
            base = child.module or ""
            if child.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (child.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            found.extend((base, alias.name, child.lineno, top) for alias in child.names)
        else:
            inner = top and not isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            visit(child, inner)

    visit(tree, True)
    return found


def _graph(deferred: bool = False) -> dict[str, set[str]]:
    """Module-level dependencies among skyfix modules (with ``deferred``, imports inside
    functions too)."""
    graph: dict[str, set[str]] = {m: set() for m in MODULES}
    for module in MODULES:
        for target, name, _line, top in _imports(module):
            if not (top or deferred) or target.split(".")[0] != "skyfix":
                continue
            deps = [target] if target in MODULES else []
            if name is not None and f"{target}.{name}" in MODULES:
                deps.append(f"{target}.{name}")
            for dep in deps:
                # a package running its own submodules (or a submodule its package's other
                # submodules through it) is the normal order of a package's set-up
                if dep != module and not (_is_package(module) and dep.startswith(module + ".")):
                    graph[module].add(dep)
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def connect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10 * len(graph) + 100))
    for v in sorted(graph):
        if v not in index:
            connect(v)
    return out


def _private_imports() -> set[str]:
    """Every ``from <public skyfix module> import _name``, as "module: target._name"."""
    out = set()
    for module in MODULES:
        for target, name, _line, _top in _imports(module):
            if target.split(".")[0] != "skyfix" or name is None or not name.startswith("_"):
                continue
            if name.startswith("__") and name.endswith("__"):
                continue  # __version__ and the like are public
            if f"{target}.{name}" in MODULES or _is_private(target):
                continue  # a private module itself, or a name from one
            out.add(f"{module}: {target}.{name}")
    return out


def test_the_walk_sees_the_package():
    assert "skyfix.detect.extract" in MODULES and "skyfix.pipeline" in MODULES
    deps = _graph()["skyfix.detect.components"]
    assert {"skyfix.detect.labelling", "skyfix.detect._grid", "skyfix.io"} <= deps
    # an import inside a function is not a module-level dependency
    assert "skyfix.detect" not in _graph()["skyfix.pipeline"]
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_import_cycle():
    assert _cycles(_graph()) == []


def test_no_cycle_through_deferred_imports_either():
    # Deferring an import breaks no dependency: two modules that import each other, one of them
    # inside a function, are one module in two files (the tracking study and its report were,
    # issue 23). A package's own submodules are still not a cycle with it.
    assert _cycles(_graph(deferred=True)) == []


def test_nothing_but_the_command_imports_the_command():
    # the library never reaches for command-line helpers (issue 23): skyfix.cli imports the
    # library, not the other way round, not even inside a function
    def is_cli(module: str) -> bool:  # skyfix.__main__ is `python -m skyfix`: the command too
        return module in ("skyfix.cli", "skyfix.__main__") or module.startswith("skyfix.cli.")

    graph = _graph(deferred=True)
    assert sorted(m for m, deps in graph.items() if not is_cli(m) and any(map(is_cli, deps))) == []


def test_no_private_name_from_a_public_module():
    found = _private_imports()
    new = sorted(found - KNOWN_OFFENDERS)
    assert not new, "private names imported from public modules (move them to a _private module):\n" + \
        "\n".join(new)
    gone = sorted(KNOWN_OFFENDERS - found)
    assert not gone, "no longer offending, delete from KNOWN_OFFENDERS:\n" + "\n".join(gone)
    assert not any(entry.startswith("skyfix.detect") for entry in KNOWN_OFFENDERS)


def _third_party() -> list[str]:
    """The non-skyfix modules imported at module level anywhere in skyfix."""
    names = set()
    for module in MODULES:
        for target, name, _line, top in _imports(module):
            if top and target and target.split(".")[0] not in ("skyfix", "__future__"):
                names.add(target)
                if name is not None:
                    names.add(f"{target}.{name}")  # perhaps a module (from scipy import ndimage)
    return sorted(names)


_DRIVER = textwrap.dedent("""
    import importlib, os, sys, traceback
    for name in {third_party!r}:
        try:
            importlib.import_module(name)
        except Exception:
            pass  # optional: the module that needs it reports it below
    assert not any(m == "skyfix" or m.startswith("skyfix.") for m in sys.modules)
    failed = []
    for module in {modules!r}:
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:
            try:
                importlib.import_module(module)
            except BaseException:
                traceback.print_exc()
                os._exit(1)
            os._exit(0)
        _, status = os.waitpid(pid, 0)
        if status != 0:
            failed.append(module)
    print("FAILED:" + ",".join(failed))
""")


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="needs os.fork")
@pytest.mark.slow  # ~90 fresh processes, 115 s in a loaded default run; the static checks above stay
def test_every_module_imports_on_its_own():
    driver = _DRIVER.format(third_party=_third_party(), modules=sorted(MODULES))
    run = subprocess.run([sys.executable, "-c", driver], capture_output=True, text=True, timeout=600,
                         cwd=PACKAGE_DIR.parent)
    assert run.returncode == 0, run.stderr[-3000:]
    failed = run.stdout.strip().rpartition("FAILED:")[2]
    assert failed == "", f"modules that fail to import first: {failed}\n{run.stderr[-3000:]}"
