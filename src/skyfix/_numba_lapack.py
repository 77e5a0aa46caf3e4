"""numba's BLAS and LAPACK from scipy, loaded when a kernel first calls them and without importing
``scipy.linalg`` (issue 22: start-up).

numba calls BLAS and LAPACK (``np.linalg.svd``, ``eigh``, ``pinv``, ``np.dot``, ``@`` … in a
kernel) through the two Cython modules ``scipy.linalg.cython_blas`` and
``scipy.linalg.cython_lapack``: when its CPU target starts (the first kernel a process loads or
compiles) it imports ``scipy.linalg.cython_blas`` to check that BLAS is there, and a kernel's
first BLAS or LAPACK call — compiled by numba or ahead of time (:mod:`skyfix.aot`) alike — imports
the module and reads its ``__pyx_capi__`` (the functions' addresses). Two costs come with that:

- importing either module the ordinary way runs ``scipy.linalg``'s ``__init__`` first — all of
  ``scipy.linalg``, scipy's array-API layer and, through it, ``numpy.f2py`` and ``numpy.testing``:
  about 0.3 s of CPU of a ``skyfix solve`` process, for two modules that are plain extension
  modules of their own;
- loading the two modules loads scipy's own OpenBLAS (a library apart from numpy's) and starts its
  threads: ~30 ms, which a solve whose kernels call no BLAS or LAPACK does not need.

:func:`install` (run by ``import skyfix``) puts a stand-in for each of the two modules into
``sys.modules``: numba's import finds it there (so ``scipy.linalg``'s ``__init__`` never runs on
its account), and the first read of any of its attributes — the ``__pyx_capi__`` a kernel's first
BLAS or LAPACK call reads — loads the real extension module from its file under its own name
(:func:`load`), puts it in the stand-in's place in ``sys.modules`` and answers from it. They are
the very modules scipy would load (the same files, the same LAPACK), so results are bit-for-bit
those of a plain import. A later ``import scipy.linalg`` works as usual (its own Cython modules
read the stand-in's ``__pyx_capi__`` as numba does). Nothing is done when ``scipy.linalg`` or the
modules are imported already; when the files cannot be found or loaded the stand-in imports the
module the ordinary way (``scipy.linalg`` and all).
"""

from __future__ import annotations

import sys
import types

__all__ = ["install", "load", "loaded"]

_MODULES = ("scipy.linalg.cython_blas", "scipy.linalg.cython_lapack")


def loaded() -> tuple[str, ...]:
    """Which of scipy's two modules (BLAS's, LAPACK's) are loaded in this process (not stand-ins)."""
    return tuple(name for name in _MODULES
                 if name in sys.modules and not isinstance(sys.modules[name], _StandIn))


def load(name: str) -> types.ModuleType:
    """The extension module ``name`` (one of the two), loaded from its file under its own name and
    put into ``sys.modules`` without ``scipy.linalg``'s ``__init__`` (imported the ordinary way
    when that fails)."""
    module = sys.modules.get(name)
    if module is not None and not isinstance(module, _StandIn):
        return module
    try:
        import importlib.machinery
        import importlib.util

        import scipy  # light: numpy is imported already

        folder = [p + "/linalg" for p in scipy.__path__]
        spec = importlib.machinery.PathFinder.find_spec(name.rpartition(".")[2], folder)
        if spec is None or not isinstance(spec.loader, importlib.machinery.ExtensionFileLoader):
            raise ImportError(name)
        spec.name = name
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    except Exception:  # any surprise: the ordinary import (scipy.linalg's __init__ too)
        import importlib

        sys.modules.pop(name, None)
        return importlib.import_module(name)
    sys.modules[name] = module
    return module


class _StandIn(types.ModuleType):
    """``sys.modules``' entry for one of the two modules until an attribute of it is read."""

    def __getattr__(self, attr: str):
        return getattr(load(self.__name__), attr)


def install() -> None:
    """Put the stand-ins into ``sys.modules`` (once), unless ``scipy.linalg`` or the modules are
    there already."""
    if "scipy.linalg" in sys.modules or any(name in sys.modules for name in _MODULES):
        return
    for name in _MODULES:
        sys.modules[name] = _StandIn(name, "scipy's module, loaded on first use (skyfix._numba_lapack)")
