"""numba's on-disk cache of the detection kernels, dropped whenever any detect source changes.

Private to :mod:`skyfix.detect`. numba checks a cached kernel against its own file only, so a
cached :func:`~skyfix.detect.measure.measure` would keep running an old copy of a changed
:func:`~skyfix.detect._grid.grid_at` (kernels here call kernels in other files of the package:
the sky grid, the statistics, the smoothing). A digest of every ``.py`` file of the package,
kept next to the cache, catches that: when it differs, the whole cache is deleted and rebuilt
on first use. (:mod:`skyfix.identify.quad` guards its four kernel files the same way.)

With ``NUMBA_CACHE_DIR`` set, numba keeps its cache elsewhere and this check does not see it.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

__all__ = ["drop_stale_cache"]

_STAMP = "skyfix_detect_kernels.sha1"


def drop_stale_cache(package: Path = Path(__file__).parent) -> bool:
    """Delete ``package/__pycache__/*.nbi|nbc`` if any ``package/*.py`` changed since the last check.

    Returns whether the cache was dropped. A read-only install is left alone (numba then uses
    its user-wide cache directory).
    """
    digest = hashlib.sha1()
    for path in sorted(package.glob("*.py")):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    cache = package / "__pycache__"
    stamp = cache / _STAMP
    try:
        if stamp.read_text() == digest.hexdigest():
            return False
    except OSError:
        pass
    try:
        cache.mkdir(exist_ok=True)
        for f in cache.glob("*.nb[ic]"):
            f.unlink(missing_ok=True)
        stamp.write_text(digest.hexdigest())
    except OSError:
        return False
    return True
