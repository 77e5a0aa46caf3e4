"""numba's cache with two signatures' data files swapped (what two processes compiling one
kernel at once could leave): the kernel must compile again, not run the other signature's code.
Run in a subprocess on a copy of a small kernel module, its cache in a temporary folder."""

import subprocess
import sys
import textwrap

from tests.conftest import ROOT

KERNEL = textwrap.dedent('''
    import numpy as np
    from skyfix._jit import njit

    @njit(cache=True)
    def pick(a, i):
        return a[i] * 2
''')

SCRIPT = textwrap.dedent('''
    import sys, numpy as np
    sys.path.insert(0, sys.argv[1])
    import kmod
    ints = np.arange(5, dtype=np.int64)
    floats = np.arange(5, dtype=np.float64) + 0.5
    print(kmod.pick.dispatcher()(ints, 3), kmod.pick.dispatcher()(floats, 3))
''')


def _run(tmp_path, cache):
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": str(ROOT / "src"), "NUMBA_CACHE_DIR": str(cache),
           "SKYFIX_AOT": "0", "HOME": str(tmp_path)}
    r = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path)], capture_output=True, text=True,
                       env=env, timeout=600)
    return r.returncode, r.stdout.strip(), r.stderr


def test_swapped_data_files_recompile_instead_of_crashing(tmp_path):
    (tmp_path / "kmod.py").write_text(KERNEL)
    cache = tmp_path / "cache"
    assert _run(tmp_path, cache)[:2] == (0, "6 7.0")
    files = sorted(cache.rglob("*pick*.nbc"))
    assert len(files) == 2, files  # one a signature
    a, b = (f.read_bytes() for f in files)
    files[0].write_bytes(b)
    files[1].write_bytes(a)  # the index now names the other signature's code for each
    code, out, err = _run(tmp_path, cache)
    assert (code, out) == (0, "6 7.0"), err[-2000:]
