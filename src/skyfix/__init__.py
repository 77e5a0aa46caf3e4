"""skyfix — a star tracker in Python.

>>> import skyfix
>>> sol = skyfix.solve("sky.png")          # lost in space, no FOV needed
>>> sol.ra_deg, sol.dec_deg, sol.roll_deg  # boresight and roll, degrees
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

# Before any kernel loads from numba's cache: drop the cache if a kernel source changed
# (numba itself checks only each kernel's own file; skyfix._kernels explains).
from skyfix._kernels import drop_stale_kernel_caches as _drop_stale_kernel_caches  # noqa: E402

_drop_stale_kernel_caches()

# numba's BLAS/LAPACK check and calls without importing all of scipy.linalg (~0.3 s of a solve), and
# scipy's OpenBLAS loaded only by a kernel's first BLAS/LAPACK call (a plain solve makes none)
from skyfix._numba_lapack import install as _install_numba_lapack  # noqa: E402

_install_numba_lapack()

__all__ = ["solve", "solve_centroids", "Camera", "Solution", "load_hipparcos", "load_gaia"]

_LAZY = {
    "solve": "skyfix.pipeline",
    "solve_centroids": "skyfix.pipeline",
    "Camera": "skyfix.camera",
    "Solution": "skyfix.solution",
    "load_hipparcos": "skyfix.catalog",
    "load_gaia": "skyfix.catalog",
}


def __getattr__(name: str):
    # Lazy so that `import skyfix` stays cheap for the CLI and for stage-only users.
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'skyfix' has no attribute {name!r}")
