"""numba's BLAS and LAPACK loaded on a kernel's first call and without ``scipy.linalg``'s
``__init__`` (:mod:`skyfix._numba_lapack`).

Each check runs in a fresh process: the stand-ins are put in place once a process, by ``import skyfix``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import skyfix

SRC = Path(skyfix.__file__).resolve().parents[1]

# a kernel that calls LAPACK (np.linalg.svd: proper_rotation of a rank-one profile, which the
# Jacobi rotations leave to LAPACK) and, before it, one that calls none (a full-rank profile)
_DRIVER = textwrap.dedent("""
    import json, sys
    if sys.argv[1] == "scipy-first":
        import scipy.linalg  # the plain way: numba finds scipy.linalg imported
    import numpy as np
    import skyfix
    from skyfix import _numba_lapack
    from skyfix._kernels.rotation import proper_rotation

    rng = np.random.default_rng(7)
    full = [proper_rotation(b).tobytes().hex() for b in rng.normal(size=(5, 3, 3))]
    before = _numba_lapack.loaded()  # numba has started (or the exports loaded): no LAPACK yet
    rank_one = [proper_rotation(np.outer(a, b)).tobytes().hex() for a, b in rng.normal(size=(20, 2, 3))]
    print(json.dumps({"full": full, "rank_one": rank_one, "loaded_before": before,
                      "loaded_after": _numba_lapack.loaded(), "scipy.linalg": "scipy.linalg" in sys.modules}))
    import scipy.linalg
    from scipy.linalg import cython_blas, cython_lapack
    assert cython_lapack is sys.modules["scipy.linalg.cython_lapack"]
    assert hasattr(cython_blas, "__pyx_capi__")
    U, s, Vt = scipy.linalg.svd(np.eye(3) + 0.1)  # scipy.linalg itself still works afterwards
    assert np.allclose(U * s @ Vt, np.eye(3) + 0.1)
""")


def _run(mode: str) -> dict:
    run = subprocess.run([sys.executable, "-c", _DRIVER, mode], cwd=SRC, capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


def test_lapack_loads_on_its_first_call_without_scipy_linalg_and_bit_for_bit():
    deferred, plain = _run("stand-in"), _run("scipy-first")
    assert deferred["loaded_before"] == []  # kernels that call no LAPACK: nothing loaded
    assert deferred["loaded_after"] == ["scipy.linalg.cython_lapack"]  # LAPACK came (BLAS not needed) ...
    assert not deferred["scipy.linalg"]  # ... and scipy.linalg did not
    assert plain["scipy.linalg"] and len(plain["loaded_before"]) == 2
    assert deferred["full"] == plain["full"]
    assert deferred["rank_one"] == plain["rank_one"]  # the same LAPACK: the same bits
