"""numba's kernel cache made safe for processes that compile at the same time.

numba keeps a kernel's machine code in numbered data files (``NAME.1.nbc``, ``NAME.2.nbc``, …)
beside an index (``NAME.nbi``) mapping each signature to its file. Saving an entry reads the
index, picks the first free number and writes both — with no lock. Two processes compiling two
signatures of one kernel at once (test workers, campaign workers, a warm-up beside a solve) can
both pick the same number: the index then names one signature's file while the file holds the
other's code, and the next process that loads it runs machine code compiled for other argument
types — it crashed (a segmentation fault in ``grid.pattern_cells``, whose two signatures differ
in one argument's type, after a test run beside two other processes).

:func:`install` changes two methods of ``numba.core.caching.IndexDataCacheFile``:

- ``save`` holds an exclusive lock (``fcntl.flock`` on ``NAME.nbi.lock``) from reading the index
  to writing the data, so no two processes pick one number;
- each data file holds its signature's key beside the code, and ``load`` returns the code only
  when that key is the one asked for — anything else (a file of the race above, one from before
  this change) is a cache miss, and the kernel compiles again.

Installed by :func:`skyfix._jit` when it first imports numba, before any kernel is compiled or
loaded. ``tests/core/test_numba_cache.py`` swaps two signatures' data files and checks that the
kernel recompiles instead of running the wrong code.
"""

from __future__ import annotations

import contextlib
import os
from typing import Any

__all__ = ["MARK", "install"]

#: The first item of a data file this module wrote: ``(MARK, key, data)``.
MARK = "skyfix-keyed-1"

_installed = False


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


def install() -> None:
    """Patch numba's cache file class (once per process; see the module text)."""
    global _installed
    if _installed:
        return
    from numba.core.caching import IndexDataCacheFile

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
    _installed = True
