"""skyfix's kernels, compiled ahead of time where they can be, by numba where they cannot (issue 22).

Every kernel in skyfix is written for numba and decorated with :func:`njit` from here, not
numba's: the decorator returns a :class:`Kernel`, which imports nothing. Its first call from
Python looks for the kernel in the ahead-of-time compiled extension modules that
``skyfix warmup`` builds (:mod:`skyfix.aot`; machine code for the signatures skyfix calls, in
ordinary extension modules that need neither numba nor a compiler to load): when one is there
and its arguments have the types an export was compiled for, the call goes to the export; any
other call — no such module, a module built from other sources, arguments of other types, or
keyword arguments — goes to numba's dispatcher, created then (the first time numba is imported
in the process) and compiled or loaded from numba's cache as before. The answers are the same:
the exports are the same kernels, compiled by the same numba for this machine's CPU.

A process whose kernels are all exported never imports numba: ``skyfix solve one.png`` starts
in a fraction of the time numba's import, its target set-up and its cache loads take.

Inside numba (one kernel calling another) a :class:`Kernel` is its dispatcher: ``_numba_type_``
tells numba so, and attributes numba reads (``py_func``, ``targetoptions``, ``signatures`` …)
are the dispatcher's.

An export's arguments are checked before the call (a wrong dtype would be read as the compiled
one): a guard made from the recorded types, :func:`guard_source`.
"""

from __future__ import annotations

import functools
import importlib
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["Kernel", "aot_folder", "aot_modules", "cpu_tag", "forget_modules", "guard_source", "kernels",
           "named", "njit", "on_numba_import"]

_KERNELS: list[Kernel] = []
_NUMBA_HOOKS: list[Callable[[], None]] = []
_PACKAGE = Path(__file__).resolve().parent


def kernels() -> list[Kernel]:
    """Every kernel defined so far in this process (the modules imported so far)."""
    return list(_KERNELS)


def on_numba_import(hook: Callable[[], None]) -> Callable[[], None]:
    """Run ``hook`` when numba is first imported for a kernel in this process (now, if it was).
    Returns what cancels it (a hook not yet run)."""
    if _numba.cache_info().currsize:
        hook()
    else:
        _NUMBA_HOOKS.append(hook)
    return lambda: _NUMBA_HOOKS.remove(hook) if hook in _NUMBA_HOOKS else None


@functools.cache
def _numba() -> Any:
    import numba

    from skyfix._numba_cache import install

    install()  # the cache safe for processes compiling at once, before any kernel loads
    for hook in _NUMBA_HOOKS:
        hook()
    _NUMBA_HOOKS.clear()
    return numba


class Kernel:
    """A numba kernel that loads on demand: an ahead-of-time export when one fits the call,
    else numba's dispatcher (see the module's text)."""

    def __init__(self, py_func: Callable, options: dict[str, Any]) -> None:
        functools.update_wrapper(self, py_func)
        self.py_func = py_func
        self.options = options
        self._dispatcher: Any = None
        self._call: Callable = self._first_call
        self.from_python = False  # called from Python in this process (skyfix.aot records those)
        self.key = f"{py_func.__module__}:{py_func.__qualname__}"
        _KERNELS.append(self)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        if kwargs:
            return self.dispatcher()(*args, **kwargs)
        return self._call(*args)

    def _first_call(self, *args: Any) -> Any:
        self.from_python = True
        exports = _loaded(_exports().get(self.key, []))
        self._call = _chooser(exports, self.dispatcher) if exports else self.dispatcher()
        return self._call(*args)

    def dispatcher(self) -> Any:
        """numba's dispatcher of this kernel (created, and numba imported, on first use)."""
        if self._dispatcher is None:
            self._dispatcher = _numba().njit(**self.options)(self.py_func)
        return self._dispatcher

    @property
    def n_compiled(self) -> int:
        """Signatures numba holds for this kernel in this process: it changes when a call
        compiled or loaded one from numba's cache (0 while only exports ran)."""
        # (len of numba's overloads: its ``signatures`` builds a list, 17 µs a call, which
        # quad's search paid twice a turn)
        return 0 if self._dispatcher is None else len(self._dispatcher.overloads)

    @property
    def _numba_type_(self) -> Any:  # numba's typeof: inside a kernel this is the dispatcher
        return self.dispatcher()._numba_type_

    def __getattr__(self, name: str) -> Any:  # signatures, targetoptions, overloads, … of numba's
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.dispatcher(), name)

    def __reduce__(self) -> tuple:  # pickled by name, as a function is
        return named, (self.key,)

    def __repr__(self) -> str:
        return f"<skyfix kernel {self.key}>"


def named(path: str) -> Any:
    """The object ``"module:qualname"`` names (a kernel's :attr:`Kernel.key`, a recorded class)."""
    module, _, qualname = path.partition(":")
    obj: Any = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj


def forget_modules() -> None:
    """Look for the compiled modules again on the next first call (after a build)."""
    _index.cache_clear()
    _exports.cache_clear()


def njit(*args: Any, **options: Any) -> Any:
    """numba's ``njit``, as a :class:`Kernel` (``@njit``, ``@njit(cache=True, …)``)."""
    if args and callable(args[0]) and not options:
        return Kernel(args[0], {})
    if args:
        raise TypeError("skyfix's njit takes options only (no eager signatures)")
    return lambda func: Kernel(func, options)


# ---- the ahead-of-time exports ------------------------------------------------------------------

INDEX = "index.json"


def aot_folder() -> Path:
    """Where ``skyfix warmup`` puts the compiled modules: ``SKYFIX_AOT_DIR`` when set, beside
    the sources when they are writable (an editable or user install), else the user cache."""
    if os.environ.get("SKYFIX_AOT_DIR"):
        return Path(os.environ["SKYFIX_AOT_DIR"])
    own = _PACKAGE / "_aot"
    if os.access(_PACKAGE, os.W_OK):
        return own
    from skyfix.cache import cache_dir

    return cache_dir() / "aot"


def aot_modules() -> dict[str, Any]:
    """The index of the compiled modules that match these sources (empty when there are none,
    when they were built from other sources, or when ``SKYFIX_AOT=0``)."""
    return _index()


@functools.cache
def _index() -> dict[str, Any]:
    if os.environ.get("SKYFIX_AOT", "1") == "0":
        return {}
    path = aot_folder() / INDEX
    try:
        index = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    from skyfix._kernels import kernels_digest

    if (index.get("digest") != kernels_digest() or index.get("python") != sys.implementation.cache_tag
            or index.get("cpu") != cpu_tag()):
        return {}
    return index


def cpu_tag() -> str:
    """This machine's CPU, as the exports were compiled for it (a copied install on another CPU
    must not run them): its model and flags on Linux, else the platform's processor name."""
    import hashlib
    import platform

    text = platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.startswith(("model name", "flags", "Features", "CPU part")):
                    text += line
                if line.strip() == "":
                    break  # the first CPU's block is enough
    except OSError:  # not Linux: the processor's name (on Linux it runs `uname -p`, 5 ms)
        text += platform.processor()
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@functools.cache
def _exports() -> dict[str, list[dict[str, Any]]]:
    """Each kernel's entries in the index (its exports' modules are imported on its first call)."""
    index = _index()
    if not index:
        return {}
    folder = str(aot_folder())
    if folder not in sys.path:
        sys.path.append(folder)
    # the exports call BLAS/LAPACK through scipy's Cython modules, as numba does: `import skyfix`
    # put stand-ins for those two in sys.modules, loaded on a kernel's first BLAS or LAPACK call
    # without scipy.linalg's __init__ (skyfix._numba_lapack)
    out: dict[str, list[dict[str, Any]]] = {}
    for entry in index["exports"]:
        out.setdefault(entry["kernel"], []).append(entry)
    return out


def _loaded(entries: list[dict[str, Any]]) -> list[tuple[Callable, Callable]]:
    """A kernel's exports as (guard, compiled function) pairs (none when its module is missing)."""
    out = []
    for entry in entries:
        try:
            module = importlib.import_module(entry["module"])
        except ImportError:
            continue
        fn = getattr(module, entry["name"], None)
        if fn is None:
            continue
        guard = getattr(_guards(), f"g_{entry['module']}_{entry['name']}", None)
        out.append((guard or _make_guard(entry["args"]), fn))
    return out


def _chooser(exports: list[tuple[Callable, Callable]], dispatcher: Callable[[], Any]) -> Callable:
    """A call to the first export whose guard accepts the arguments, else to numba."""
    if len(exports) == 1:
        (guard, fn), = exports

        def call(*args: Any) -> Any:
            return fn(*args) if guard(*args) else dispatcher()(*args)
        return call

    def call_any(*args: Any) -> Any:
        for guard, fn in exports:
            if guard(*args):
                return fn(*args)
        return dispatcher()(*args)
    return call_any


# The recorded type of an argument (skyfix.aot writes them): "float64", "int64", "bool", … for a
# scalar; {"array": DTYPE, "ndim": N, "layout": "C"|"F"|"A", "readonly": B, "aligned": B} with
# DTYPE a dtype string or a record's descr; {"tuple": [TYPES]} or, for a NamedTuple,
# {"tuple": [TYPES], "class": "module:QualName"}; "none". ("aligned" is numba's: False for a packed
# record, which the dtype's equality covers; numba's typeof does not read an array's flag.)
_SCALARS = {
    "float64": "(type({v}) is float or type({v}) is _np.float64)",
    "int64": "(type({v}) is int or type({v}) is _np.int64)",
    "bool": "(type({v}) is bool or type({v}) is _np.bool_)",
}


def guard_source(types: list[Any], tag: str = "") -> tuple[str, dict[str, Any]]:
    """The source of a guard (``lambda a0, a1, …: …``) that is True exactly for arguments numba
    would type as ``types``, and the constants it names (each name ending in ``tag``)."""
    consts: dict[str, Any] = {"_np": np, "_nd": np.ndarray}
    names = [f"a{i}" for i in range(len(types))]
    tests = [_test(t, n, consts, tag) for t, n in zip(types, names, strict=True)]
    return f"lambda {', '.join(names)}: " + (" and ".join(tests) or "True"), consts


def _test(t: Any, v: str, consts: dict[str, Any], tag: str) -> str:
    if t == "none":
        return f"{v} is None"
    if isinstance(t, str):
        if t in _SCALARS:
            return _SCALARS[t].format(v=v)
        name = f"_s{len(consts)}{tag}"
        consts[name] = getattr(np, t)
        return f"type({v}) is {name}"
    if "array" in t:
        name = f"_d{len(consts)}{tag}"
        dtype = t["array"]
        consts[name] = np.dtype([tuple(f) for f in dtype] if isinstance(dtype, list) else dtype)
        layout = {"C": "_f.c_contiguous", "F": "(not _f.c_contiguous and _f.f_contiguous)",
                  "A": "not (_f.c_contiguous or _f.f_contiguous)"}[t["layout"]]
        # ``is`` first: a native dtype is numpy's one instance (0.33 → 0.21 µs an array, timeit)
        return (f"(isinstance({v}, _nd) and ({v}.dtype is {name} or {v}.dtype == {name}) and "
                f"{v}.ndim == {t['ndim']} and "
                f"(_f := {v}.flags) is not None and {layout} and _f.writeable is {not t['readonly']})")
    parts = t["tuple"]
    if "class" in t:  # by name: the class is imported already when an instance is passed
        module, _, qualname = t["class"].partition(":")
        head = f"type({v}).__qualname__ == {qualname!r} and type({v}).__module__ == {module!r}"
    else:
        head = f"type({v}) is tuple and len({v}) == {len(parts)}"
    inner = [_test(p, f"{v}[{i}]", consts, tag) for i, p in enumerate(parts)]
    return "(" + " and ".join([head, *inner]) + ")"


def _make_guard(types: list[Any]) -> Callable[..., bool]:
    source, consts = guard_source(types)
    return eval(source, consts)  # noqa: S307 - our own recorded types, never user input


GUARDS = "_skyfix_aot_guards"
"""The module of every export's guard, written by the build (imported with its bytecode cached:
a guard made by :func:`guard_source` and ``eval`` costs about half a millisecond)."""


def guards_module_source(exports: list[dict[str, Any]]) -> str:
    """The source of :data:`GUARDS`: ``g_<module>_<name>`` for each export."""
    lines = ['"""Generated by skyfix.aot: the guard of each export (skyfix._jit.guard_source)."""',
             "import numpy as _np", "_nd = _np.ndarray"]
    for entry in exports:
        tag = f"_{entry['module']}_{entry['name']}"
        source, consts = guard_source(entry["args"], tag)
        for name, value in consts.items():
            if name in ("_np", "_nd"):
                continue
            if isinstance(value, np.dtype):
                text = f"_np.dtype({[tuple(f) for f in value.descr] if value.names else value.str!r})"
            else:
                text = f"_np.{value.__name__}"
            lines.append(f"{name} = {text}")
        lines.append(f"g{tag} = {source}")
    return "\n".join(lines) + "\n"


@functools.cache
def _guards() -> Any:
    try:
        return importlib.import_module(GUARDS)
    except ImportError:
        return None
