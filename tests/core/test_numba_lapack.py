"""numba's BLAS and LAPACK without ``scipy.linalg``'s ``__init__`` (:mod:`skyfix._numba_lapack`).

Each check runs in a fresh process: the hook acts when numba's CPU target starts, once a process.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import skyfix

SRC = Path(skyfix.__file__).resolve().parents[1]

# a kernel that calls LAPACK (np.linalg.svd) and one that calls BLAS through numba (np.dot)
_DRIVER = textwrap.dedent("""
    import json, sys
    if sys.argv[1] == "scipy-first":
        import scipy.linalg  # the plain way: numba finds scipy.linalg imported
    import numpy as np
    import skyfix
    from skyfix._kernels.rotation import proper_rotation

    B = np.random.default_rng(7).normal(size=(20, 3, 3))
    out = [proper_rotation(b).tobytes().hex() for b in B]
    print(json.dumps({"rotations": out, "scipy.linalg": "scipy.linalg" in sys.modules,
                      "cython_lapack": "scipy.linalg.cython_lapack" in sys.modules}))
    import scipy.linalg
    from scipy.linalg import cython_blas, cython_lapack
    assert cython_lapack is sys.modules["scipy.linalg.cython_lapack"]
    assert cython_blas is sys.modules["scipy.linalg.cython_blas"]
    U, s, Vt = scipy.linalg.svd(B[0])  # scipy.linalg itself still works after the preload
    assert np.allclose(U * s @ Vt, B[0])
""")


def _run(mode: str) -> dict:
    run = subprocess.run([sys.executable, "-c", _DRIVER, mode], cwd=SRC, capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


def test_kernels_call_lapack_without_scipy_linalg_and_bit_for_bit():
    hooked, plain = _run("hook"), _run("scipy-first")
    assert hooked["cython_lapack"] and not hooked["scipy.linalg"]  # LAPACK came, scipy.linalg did not
    assert plain["scipy.linalg"]
    assert hooked["rotations"] == plain["rotations"]  # the same LAPACK: the same bits
