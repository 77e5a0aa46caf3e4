"""numba's BLAS and LAPACK from scipy, without importing ``scipy.linalg`` (issue 22: start-up).

numba calls BLAS and LAPACK (``np.linalg.svd``, ``eigh``, ``pinv``, ``np.dot`` … in a kernel)
through the two Cython modules ``scipy.linalg.cython_blas`` and ``scipy.linalg.cython_lapack``:
when its CPU target starts (the first kernel a process loads or compiles) it imports
``scipy.linalg.cython_blas`` to check that BLAS is there, and a kernel's first LAPACK call
imports ``scipy.linalg.cython_lapack``. Importing either runs ``scipy.linalg``'s ``__init__``
first — all of ``scipy.linalg``, scipy's array-API layer and, through it, ``numpy.f2py`` and
``numpy.testing``: about 0.3 s of CPU of a ``skyfix solve`` process, for two modules that are
plain extension modules of their own.

:func:`install` (run by ``import skyfix``) adds an import hook that, the moment numba's CPU
target starts (the import of ``numba.np.arraymath``, which makes that check as it is imported), loads the
two extension modules from their files under their own names into ``sys.modules``, so
numba's ``import scipy.linalg.cython_blas`` and its C helpers' imports find them there and
``scipy.linalg``'s ``__init__`` never runs on their account. They are the very modules scipy
would load (the same files, the same LAPACK), so results are bit-for-bit those of a plain
import. A later ``import scipy.linalg`` works as usual and finds them loaded (``from
scipy.linalg import cython_blas`` gives the same module; the attribute
``scipy.linalg.cython_blas`` is not set on the package by that import, as it is not before
anything imports the submodule). Nothing is done when ``scipy.linalg`` is imported already,
or when the files cannot be found or loaded (numba then imports ``scipy.linalg`` as it always
did).
"""

from __future__ import annotations

import sys

__all__ = ["install", "preload"]

_MODULES = ("cython_blas", "cython_lapack")
_TRIGGER = "numba.np.arraymath"  # numba's CPU target imports it first; it checks for BLAS on import


def preload() -> bool:
    """Load ``scipy.linalg.cython_blas`` and ``cython_lapack`` into ``sys.modules`` without
    ``scipy.linalg``'s ``__init__``. Returns whether both are there now."""
    names = [f"scipy.linalg.{m}" for m in _MODULES]
    if all(n in sys.modules for n in names):
        return True
    if "scipy.linalg" in sys.modules:  # imported already: the normal way costs nothing more
        return False
    try:
        import importlib.machinery
        import importlib.util

        import scipy  # light: numba has imported it already (its version check)

        folder = [p + "/linalg" for p in scipy.__path__]
        for name in names:
            if name in sys.modules:
                continue
            spec = importlib.machinery.PathFinder.find_spec(name.rpartition(".")[2], folder)
            if spec is None or not isinstance(spec.loader, importlib.machinery.ExtensionFileLoader):
                return False
            spec.name = name
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
            sys.modules[name] = module
    except Exception:  # any surprise: leave it to numba's own import
        return False
    return True


class _Finder:
    """A meta-path entry that finds nothing itself: it preloads the two modules just before
    ``numba.np.arraymath`` is imported. (It stays in ``sys.meta_path``, idle: removing it
    while the import system walks that list would skip the next finder.)"""

    done = False

    def find_spec(self, name, path=None, target=None):
        if name == _TRIGGER and not self.done:
            self.done = True
            preload()
        return None


_FINDER = _Finder()


def install() -> None:
    """Add the hook (once), unless numba's CPU target or ``scipy.linalg`` is loaded already."""
    if _FINDER in sys.meta_path or _TRIGGER in sys.modules or "scipy.linalg" in sys.modules:
        return
    sys.meta_path.insert(0, _FINDER)
