"""numba's kernel cache made safe for processes that compile at the same time, or one after
another.

**Names.** numba names a compiled function's machine code by its module, qualified name,
argument types and a number, ``v<uid>``, that its process counts up from 1 at every compile
(``numba.core.bytecode.FunctionIdentity``): unique in one process, not across processes. A
cached kernel's code holds a copy of every function it calls (numba's own ``sort``/``argsort``
helpers, the skyfix kernels it calls) as a *weak* symbol, and when a process loads two cached
kernels whose copies have the same name, LLVM's JIT keeps the first and binds the second
kernel's calls to it — right only if the name means the same code. Across processes it need
not: numba's quicksort helpers are closures made once for ``sort`` and once for ``argsort``,
with one qualified name (``make_quicksort_impl.<locals>.run_quicksort1``) and, for a float64
array, one argument type (the return type is not in the name). Under ``pytest -n 2``,
``search._pattern_edges``'s cached code held its ``out.sort()`` as
``run_quicksort1[v24](float64[::1])``, compiled in one process, and ``grid._catalogue_cells``'s
held ``np.argsort`` under the very same name, compiled in another; a process that ran
``_pattern_edges`` first and then ``_catalogue_cells`` ran the sort for the argsort — its floats
sorted in place and handed back as indices — and crashed (numba's issue 10486). :func:`install`
starts each process's count at a random 63-bit number (again in a forked child), so no two
processes give one name to two functions.

**Numbering.** numba keeps a kernel's machine code in numbered data files (``NAME.1.nbc``,
``NAME.2.nbc``, …) beside an index (``NAME.nbi``) mapping each signature to its file. Saving an
entry reads the index, picks the first free number and writes both — with no lock. Two
processes compiling two signatures of one kernel at once (test workers, campaign workers, a
warm-up beside a solve) can both pick the same number: the index then names one signature's
file while the file holds the other's code, and the next process that loads it runs machine
code compiled for other argument types.

:func:`install` sets numba's counter (above) and changes two methods of
``numba.core.caching.IndexDataCacheFile``:

- ``save`` holds an exclusive lock (``fcntl.flock`` on ``NAME.nbi.lock``) from reading the index
  to writing the data, so no two processes pick one number;
- each data file holds :data:`MARK` and its signature's key beside the code, and ``load``
  returns the code only when both are this module's — anything else (a file of the race above,
  one saved before the counter was random, one of another skyfix) is a cache miss, and the
  kernel compiles again.

Installed by :func:`skyfix._jit` when it first imports numba, before any kernel is compiled or
loaded. ``tests/core/test_numba_cache.py`` swaps two signatures' data files, and loads a cached
``sort`` and a cached ``argsort`` compiled in two processes, and checks that each kernel
recompiles or runs its own code.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import secrets
import threading
from typing import Any

__all__ = ["MARK", "install"]

#: The first item of a data file this module wrote: ``(MARK, key, data)``. Version 2: saved by a
#: process whose compile numbers start at random (files of version 1 may share names: load as misses).
MARK = "skyfix-keyed-2"

_installed = False
#: Two threads loading their first kernels at once (the extraction's helper thread beside the
#: caller) both reach :func:`install`: the second waits, then finds it done — installed twice,
#: ``save`` would lock its index twice in one thread (two ``flock`` s on one file: a deadlock).
_install_lock = threading.Lock()


@contextlib.contextmanager
def _locked(path: str):
    try:
        import fcntl
    except ImportError:  # not POSIX: the key check alone keeps wrong code out
        yield
        return
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError:  # a read-only cache folder: numba will not save there either
        yield
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing releases the lock


def _random_uids() -> None:
    """numba's compile numbers, from a random start: its names unique across processes."""
    from numba.core.bytecode import FunctionIdentity

    FunctionIdentity._unique_ids = itertools.count(secrets.randbits(63))


def install() -> None:
    """Patch numba's compile numbering and cache file class (once per process, whichever threads
    call it; see the module text)."""
    global _installed
    with _install_lock:
        if _installed:
            return
        _install()
        _installed = True


def _install() -> None:
    from numba.core.caching import IndexDataCacheFile

    _random_uids()
    if hasattr(os, "register_at_fork"):  # a forked child would count on from its parent's number
        os.register_at_fork(after_in_child=_random_uids)

    plain_save, plain_load = IndexDataCacheFile.save, IndexDataCacheFile.load

    def save(self: Any, key: Any, data: Any) -> None:
        with _locked(self._index_path + ".lock"):
            plain_save(self, key, (MARK, key, data))

    def load(self: Any, key: Any) -> Any:
        got = plain_load(self, key)
        if isinstance(got, tuple) and len(got) == 3 and got[0] == MARK and got[1] == key:
            return got[2]
        return None  # another signature's code, or a file from before: compile again

    IndexDataCacheFile.save, IndexDataCacheFile.load = save, load
