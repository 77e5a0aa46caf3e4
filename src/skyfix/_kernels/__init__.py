"""skyfix's shared numba helpers — each formula that a kernel and a readable function both need
is written here once (:mod:`.lens`: the camera model; :mod:`.rotation`: rotations, RA/Dec, roll,
quaternions) — and the package-wide check that keeps numba's on-disk cache honest.

numba caches a compiled kernel beside its source and checks only that file's timestamp: a
kernel in ``final_fit.py`` that inlined a helper from ``_kernels/lens.py`` would keep running
the old helper after the helper changed, and a cached kernel taking a NamedTuple defined in
another file would read its fields by their old order (numba's cache key holds the fields'
types, not their names). :func:`drop_stale_kernel_caches` (run once when :mod:`skyfix` is
imported) keeps a digest of every source file of the package — any file may define what a
kernel inlines or takes — and deletes all of the package's cached kernels when it changes
(``tests/test_kernel_cache.py`` edits a helper in a copy of the package and sees the change).
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

__all__ = ["drop_stale_kernel_caches"]

_PACKAGE = Path(__file__).resolve().parent.parent
_STAMP = "skyfix_kernels.sha256"


def _kernel_sources(package: Path) -> list[Path]:
    return sorted(p for p in package.rglob("*.py") if "__pycache__" not in p.parts)


def _stat_line(package: Path, paths: list[Path]) -> str:
    parts = []
    for p in paths:
        st = p.stat()
        parts.append(f"{p.relative_to(package)}:{st.st_mtime_ns}:{st.st_size}")
    return "\n".join(parts)


def drop_stale_kernel_caches(package: Path = _PACKAGE) -> bool:
    """Delete numba's cached kernels of ``package`` if any of its source files changed since
    the last call. Returns whether it deleted them.

    Fast path: the files' sizes and modification times, as last seen, are unchanged (one
    ``stat`` per file). Otherwise every source file is hashed; a new digest drops every
    ``*.nbi``/``*.nbc`` under the package's ``__pycache__`` folders (and under
    ``NUMBA_CACHE_DIR`` when set). A read-only install is left alone: numba then caches in
    its user-wide folder, keyed by the (unchanging) installed files."""
    cache = package / "__pycache__"
    stamp = cache / _STAMP
    try:
        paths = _kernel_sources(package)
        stats = _stat_line(package, paths)
        try:
            old_digest, old_stats = stamp.read_text().split("\n", 1)
        except (OSError, ValueError):
            old_digest, old_stats = "", ""
        if stats == old_stats:
            return False
        h = hashlib.sha256()
        for p in paths:
            h.update(str(p.relative_to(package)).encode() + b"\0" + p.read_bytes() + b"\0")
        digest = h.hexdigest()
        dropped = digest != old_digest
        if dropped:
            folders = [d for d in package.rglob("__pycache__")]
            extra = os.environ.get("NUMBA_CACHE_DIR")
            if extra and Path(extra).is_dir():
                folders.append(Path(extra))
            for d in folders:
                for f in list(d.rglob("*.nbi")) + list(d.rglob("*.nbc")):
                    f.unlink(missing_ok=True)
        cache.mkdir(exist_ok=True)
        tmp = cache / f".{_STAMP}.{os.getpid()}"
        tmp.write_text(digest + "\n" + stats)
        os.replace(tmp, stamp)
        return dropped
    except OSError:  # a read-only install: nothing of ours to drop
        return False
