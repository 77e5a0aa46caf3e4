"""numba's cache as processes leave it (skyfix._numba_cache), each case run in fresh processes on
small kernel modules written to a temporary folder, their cache in another:

- two signatures' data files swapped (what two processes compiling one kernel at once could
  leave): the kernel must compile again, not run the other signature's code;
- a cached ``a.sort()`` and a cached ``a.argsort()``, each compiled in a process of its own, then
  both loaded in a third: with numba's compile numbers counting from 1 in every process, both
  name their quicksort helper ``run_quicksort1[v4](float64[::1])`` (sort and argsort reach it
  after as many compiles), and the argsort loaded second ran the sort's (what crashed
  ``grid._catalogue_cells``, skyfix._numba_cache's text). Each must run its own."""

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

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


def _run(tmp_path, cache, script=SCRIPT, *args):
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": str(ROOT / "src"), "NUMBA_CACHE_DIR": str(cache),
           "SKYFIX_AOT": "0", "HOME": str(tmp_path)}
    r = subprocess.run([sys.executable, "-c", script, str(tmp_path), *args], capture_output=True, text=True,
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


SORTS = {
    "ksort": "@njit(cache=True)\ndef kernel(a):\n    a.sort()\n    return a\n",
    "kargsort": "@njit(cache=True)\ndef kernel(a):\n    return a.argsort()\n",
}

LOAD = textwrap.dedent('''
    import importlib, json, sys
    import numpy as np
    sys.path.insert(0, sys.argv[1])
    out = {}
    for name in sys.argv[2:]:
        k = importlib.import_module(name).kernel
        out[name] = k(np.array([3.0, 1.0, 2.0, 0.5])).tolist()
        out[name + " hits"] = sum(k.dispatcher().stats.cache_hits.values())
    print(json.dumps(out))
''')


@pytest.mark.slow  # three processes, each importing numba: 16 s at load 7
def test_kernels_cached_by_two_processes_run_their_own_helpers(tmp_path):
    for name, body in SORTS.items():
        (tmp_path / f"{name}.py").write_text("from skyfix._jit import njit\n\n\n" + body)
    cache = tmp_path / "cache"
    for name in SORTS:  # each compiled and cached in a process of its own
        code, _, err = _run(tmp_path, cache, LOAD, name)
        assert code == 0, err[-2000:]
    code, out, err = _run(tmp_path, cache, LOAD, "ksort", "kargsort")  # both, sort first
    assert code == 0, err[-2000:]
    got = json.loads(out)
    assert got["ksort hits"] == got["kargsort hits"] == 1  # both loaded from the cache
    a = [3.0, 1.0, 2.0, 0.5]
    assert got["ksort"] == sorted(a)
    assert got["kargsort"] == np.argsort(a).tolist()  # not the floats' bits, as sort's helper returns


THREADS = textwrap.dedent('''
    import threading, time
    from skyfix import _numba_cache as c

    slow = c._random_uids
    c._random_uids = lambda: (time.sleep(0.2), slow())  # widen the window two threads could share
    start = threading.Barrier(4)

    def first_kernel():
        start.wait()
        c.install()

    threads = [threading.Thread(target=first_kernel) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    from numba.core.caching import IndexDataCacheFile
    wrapped = [c.cell_contents.__module__ for c in IndexDataCacheFile.save.__closure__]
    print(*wrapped)
''')


def test_threads_installing_at_once_wrap_the_cache_once():
    """Four threads reaching their first kernel together (the extraction's helper thread beside
    its caller) install the cache's wrappers once: wrapped twice, ``save`` locked its index twice
    in one thread — two ``flock`` s on one file, a deadlock on the first compile."""
    out = subprocess.run([sys.executable, "-c", THREADS], capture_output=True, text=True, timeout=120,
                         cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["numba.core.caching"]  # skyfix's save around numba's, not around itself
