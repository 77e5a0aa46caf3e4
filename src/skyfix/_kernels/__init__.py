"""skyfix's shared numba helpers — each formula that a kernel and a readable function both need
is written here once (:mod:`.lens`: the camera model; :mod:`.rotation`: rotations, RA/Dec, roll,
quaternions, chord angles, TRIAD; :mod:`.wahba`: the attitude profile and information matrices;
:mod:`.probability`: the binomial tail; :mod:`.camera_fit`: the camera fit; :mod:`.robust`: the
outlier cut by residuals) — and the check
that keeps numba's on-disk cache honest.

numba caches a compiled kernel beside its source and checks only that file's timestamp: a
kernel in ``final_fit.py`` that inlined a helper from ``_kernels/lens.py`` would keep running
the old helper after the helper changed, and a cached kernel taking a NamedTuple defined in
another file would read its fields by their old order (numba's cache key holds the fields'
types, not their names). :func:`drop_stale_kernel_caches` (run once when :mod:`skyfix` is
imported) gives every source file that holds kernels a digest of everything its kernels can
depend on, and deletes that file's cached kernels when the digest changes:

- the file itself and every skyfix module it imports, transitively (a kernel reaches another
  file's helper or constant only through an import);
- the NamedTuple definitions its callers can pass in: every file defining a NamedTuple among
  the modules that import it and their own imports (a kernel's arguments are built by its
  callers).

Editing a file that no kernel file depends on (a command, a tracker, a report) drops nothing;
editing ``_kernels/lens.py`` drops every kernel that inlines it
(``tests/_kernels/test_kernel_cache.py`` edits a helper in a copy of the package and sees the change).
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

__all__ = ["drop_stale_kernel_caches", "kernel_cache_folder", "kernels_digest"]

_PACKAGE = Path(__file__).resolve().parent.parent
_STAMP = "skyfix_kernels.json"
_KERNEL = re.compile(rb"numba\.njit|@njit|numba\.jit|@jit\b|numba\.vectorize|numba\.guvectorize")
_NAMED_TUPLE = re.compile(rb"\(\s*(typing\.)?NamedTuple\s*\)")


def _sources(package: Path) -> list[Path]:
    out = []
    for root, dirs, files in os.walk(package):
        dirs[:] = [d for d in dirs if d != "__pycache__"]  # numba's cached kernels: hundreds of files
        out += [Path(root, f) for f in files if f.endswith(".py")]
    return sorted(out)


_DIGESTS: dict[Path, dict[str, str]] = {}  # each package's kernel digests, as this process last saw them


def kernels_digest(package: Path = _PACKAGE) -> str:
    """One digest of all the package's kernels: of their :func:`kernel_digests` as
    :func:`drop_stale_kernel_caches` last saw them (run at ``import skyfix``). It changes when a
    kernel's code, or code a kernel depends on, changes — when cached kernels are dropped — and
    not when a command or a report does (:mod:`skyfix.warmup` keys its stamp on it). For a
    read-only install, whose sources do not change, the sources' names, sizes and times."""
    import hashlib

    digests = _DIGESTS.get(package)
    text = (json.dumps(digests, sort_keys=True) if digests is not None
            else _stat_line(package, _sources(package)))
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def kernel_cache_folder(package: Path = _PACKAGE) -> Path | None:
    """The folder beside the package's sources where its kernel-cache stamps live (and numba's
    cache, for a writable install); None for a read-only install."""
    folder = package / "__pycache__"
    try:
        folder.mkdir(exist_ok=True)
    except OSError:
        return None
    return folder if os.access(folder, os.W_OK) else None


def _stat_line(package: Path, paths: list[Path]) -> str:
    parts = []
    for p in paths:
        st = p.stat()
        parts.append(f"{p.relative_to(package)}:{st.st_mtime_ns}:{st.st_size}")
    return "\n".join(parts)


def _module_file(package: Path, dotted: str) -> Path | None:
    """The source file of module ``dotted`` (``skyfix.a.b``) inside ``package``, if any."""
    parts = dotted.split(".")[1:]
    base = package.joinpath(*parts)
    for p in (base.with_suffix(".py"), base / "__init__.py"):
        if p.is_file():
            return p
    return None


def _imports(package: Path, path: Path, text: bytes) -> set[Path]:
    """The package's source files that ``path`` imports (``import skyfix.x``, ``from skyfix.x
    import y`` — ``y`` too when it is a module — and relative imports)."""
    import ast  # here, not at the top: only a changed source needs it (``import skyfix`` stays cheap)

    name = package.name
    try:
        tree = ast.parse(text)
    except SyntaxError:
        return set()
    here = path.relative_to(package).with_suffix("").parts
    if here[-1] == "__init__":
        here = here[:-1]
    mods: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            mods.update(a.name for a in node.names if a.name.split(".")[0] == name)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                pkg = here if path.name == "__init__.py" else here[:-1]
                up = pkg[: len(pkg) - (node.level - 1)]
                base = ".".join((name, *up, *((node.module,) if node.module else ())))
            elif node.module and node.module.split(".")[0] == name:
                base = node.module
            else:
                continue
            mods.add(base)
            mods.update(f"{base}.{a.name}" for a in node.names)
    found = {_module_file(package, m) for m in mods}
    found.discard(None)
    found.discard(path)
    return found  # type: ignore[return-value]


def _closure(start: Path, graph: dict[Path, set[Path]]) -> set[Path]:
    seen = {start}
    todo = [start]
    while todo:
        for q in graph.get(todo.pop(), ()):
            if q not in seen:
                seen.add(q)
                todo.append(q)
    return seen


def kernel_digests(package: Path = _PACKAGE) -> dict[str, str]:
    """For each source file holding numba kernels, the digest of what its kernels depend on
    (the module docstring says what that is)."""
    import hashlib

    # skyfix/_jit.py is the decorator every kernel file imports: numba compiles none of it
    paths = [p for p in _sources(package) if p.relative_to(package).as_posix() != "_jit.py"]
    text = {p: p.read_bytes() for p in paths}
    graph = {p: _imports(package, p, text[p]) & text.keys() for p in paths}
    named = {p for p in paths if _NAMED_TUPLE.search(text[p])}
    importers: dict[Path, set[Path]] = {p: set() for p in paths}
    for p, deps in graph.items():
        for q in deps:
            importers.setdefault(q, set()).add(p)
    out = {}
    for k in paths:
        if not _KERNEL.search(text[k]):
            continue
        deps = _closure(k, graph)
        for caller in importers.get(k, ()):
            deps |= _closure(caller, graph) & named
        h = hashlib.sha256()
        for p in sorted(deps):
            h.update(str(p.relative_to(package)).encode() + b"\0" + text[p] + b"\0")
        out[str(k.relative_to(package))] = h.hexdigest()
    return out


def _drop(files: list[Path]) -> None:
    for f in files:
        f.unlink(missing_ok=True)


def _cached_kernels_of(package: Path, rel: str) -> list[Path]:
    src = package / rel
    d = src.parent / "__pycache__"
    if not d.is_dir():
        return []
    return [f for f in d.iterdir() if f.name.startswith(src.stem + ".") and f.suffix in (".nbi", ".nbc")]


def drop_stale_kernel_caches(package: Path = _PACKAGE) -> bool:
    """Delete numba's cached kernels of every source file of ``package`` whose dependencies
    (:func:`kernel_digests`) changed since the last call. Returns whether it deleted any.

    Fast path: the files' sizes and modification times, as last seen, are unchanged (one
    ``stat`` per file). Otherwise the digests are recomputed and compared with the stamp's; a
    changed or new digest drops that file's ``*.nbi``/``*.nbc`` (and, under ``NUMBA_CACHE_DIR``
    when set, every cached kernel). A read-only install is left alone: numba then caches in its
    user-wide folder, keyed by the (unchanging) installed files."""
    cache = package / "__pycache__"
    stamp = cache / _STAMP
    try:
        stats = _stat_line(package, _sources(package))
        try:
            old = json.loads(stamp.read_text())
            old_digests, old_stats = dict(old["digests"]), str(old["stats"])
        except (OSError, ValueError, KeyError, TypeError):
            old_digests, old_stats = {}, ""
        if stats == old_stats:
            _DIGESTS[package] = old_digests
            return False
        digests = _DIGESTS[package] = kernel_digests(package)
        stale = [rel for rel, d in digests.items() if old_digests.get(rel) != d]
        for rel in stale:
            _drop(_cached_kernels_of(package, rel))
        extra = os.environ.get("NUMBA_CACHE_DIR")
        if stale and extra and Path(extra).is_dir():
            _drop(list(Path(extra).rglob("*.nbi")) + list(Path(extra).rglob("*.nbc")))
        cache.mkdir(exist_ok=True)
        (cache / "skyfix_kernels.sha256").unlink(missing_ok=True)  # the package-wide stamp before
        tmp = cache / f".{_STAMP}.{os.getpid()}"
        tmp.write_text(json.dumps({"stats": stats, "digests": digests}))
        os.replace(tmp, stamp)
        return bool(stale)
    except OSError:  # a read-only install: nothing of ours to drop
        return False
