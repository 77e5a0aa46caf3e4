"""Cache files that are written atomically and carry a checksum.

Every file skyfix keeps in its cache (the parsed catalogue, pattern databases) is an
uncompressed ``.npz`` written by :func:`write_npz`: under a temporary name unique to the
writer, in the destination's folder, then renamed over the destination, so a reader sees
either the old file or the complete new one, and concurrent writers never share a file. The
zip archive comment at the very end of the file holds an index of the members (where each
array's bytes start, dtype, shape) and the SHA-256 of every byte before the digest
(``<index JSON>skyfix-index:<8 digits: its length>skyfix-sha256:<64 hex digits>``); the
file stays an ordinary ``.npz``, and each array's bytes start at a multiple of 64 (an
alignment extra field pads the member's zip header). :func:`map_npz` memory-maps the
members from the index alone, with one map of the file and no copy: no zip directory walk,
no ``.npy`` header parsing (a few tens of microseconds). Files written before the index
existed are read through the zip directory instead.

:func:`verify` checks it. Hashing runs at 0.1–2 GB/s, so a verified file's identity (device,
inode, size, modification and change times) is remembered in a small stamp in the cache;
while the file is unchanged, later checks read only the stamp. A file modified within
:data:`STAMP_MIN_AGE_S` of its check gets no stamp (timestamps are coarse: a write right
after the check could leave them unchanged).

:func:`exclusive_lock` serialises the processes that would rebuild the same file, and
:func:`notice` tells the user about the slow first-use steps.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import mmap
import os
import sys
import time
import zipfile
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import IO, BinaryIO

import numpy as np

from skyfix.errors import SkyfixError

__all__ = ["CorruptFileError", "STAMP_MIN_AGE_S", "atomic_file", "cache_dir", "exclusive_lock", "has_index",
           "map_npz", "notice", "verify", "write_npz"]

log = logging.getLogger(__name__)

_PREFIX = b"skyfix-sha256:"
_HEX = 64  # hex digits of a SHA-256 digest
_TRAILER = len(_PREFIX) + _HEX
_READ_BLOCK = 1 << 20
STAMP_MIN_AGE_S = 2.0
_INDEX = b"skyfix-index:"
_INDEX_DIGITS = 8  # the index's length in bytes, zero-padded
_INDEX_TAIL = len(_INDEX) + _INDEX_DIGITS
_COMMENT_MAX = 0xFFFF  # a zip comment's limit: a longer index is not written
_ALIGN = 64  # array bytes start at a multiple of this (as the .npy format pads its header to)
_ALIGN_EXTRA_ID = 0xD935  # the zip extra field Android's zipalign pads with: id, size, alignment, zeros
_ZIP_LOCAL_HEADER = 30
_ZIP64_LOCAL_EXTRA = 20  # the zip64 sizes field of a member written with force_zip64


class CorruptFileError(SkyfixError):
    """A cache or database file fails its checksum (corrupt, truncated or written without one)."""


_USER_CACHE_DIRS: dict[str | None, Path] = {}


def cache_dir() -> Path:
    """skyfix's user cache directory (``$SKYFIX_CACHE`` overrides it); created on demand."""
    env = os.environ.get("SKYFIX_CACHE")
    if env:
        path = Path(env)
    else:  # asked once per $XDG_CACHE_HOME (platformdirs costs ~0.3 ms a call)
        xdg = os.environ.get("XDG_CACHE_HOME")
        path = _USER_CACHE_DIRS.get(xdg)
        if path is None:
            path = _USER_CACHE_DIRS[xdg] = _user_cache_dir()
    path.mkdir(parents=True, exist_ok=True)
    return path


def _user_cache_dir() -> Path:
    """platformdirs' user cache folder of skyfix. On Linux, where it is the XDG rule —
    ``$XDG_CACHE_HOME/skyfix`` when that is an absolute path, else ``$HOME/.cache/skyfix`` — that
    rule is read here: importing platformdirs costs a process ~10 ms (it is asked when ``$HOME`` is
    not an absolute path, and on every other system)."""
    if sys.platform.startswith("linux"):
        xdg, home = os.environ.get("XDG_CACHE_HOME", ""), os.environ.get("HOME", "")
        if os.path.isabs(xdg):
            return Path(xdg, "skyfix")
        if os.path.isabs(home):
            return Path(home, ".cache", "skyfix")
    import platformdirs

    return Path(platformdirs.user_cache_dir("skyfix"))


@contextmanager
def atomic_file(path: str | Path, mode: str = "wb") -> Iterator[IO]:
    """Open a new file to be renamed over ``path`` when the block ends without an error.

    The file is created (exclusively) next to ``path`` under a name unique to this writer
    (process id and a random token), flushed to disk, then renamed over ``path``; on any
    error it is removed and ``path`` is left as it was.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{os.urandom(6).hex()}.tmp")  # secrets.token_hex(6)
    try:
        with open(tmp, mode.replace("w", "x")) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_npz(path: str | Path, arrays: Mapping[str, np.ndarray]) -> None:
    """Write ``arrays`` as an uncompressed ``.npz`` with an index of its members and a SHA-256
    trailer, atomically (:func:`atomic_file`); each array's bytes start at a multiple of 64."""
    with atomic_file(path, "wb+") as fh:
        index, indexable = {}, True
        with zipfile.ZipFile(fh, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
            for name, value in arrays.items():
                value = np.asanyarray(value)
                info = zipfile.ZipInfo(f"{name}.npy", time.localtime()[:6])
                info.compress_type = zipfile.ZIP_STORED
                info.extra = _align_extra(fh.tell() + _ZIP_LOCAL_HEADER + len(info.filename.encode())
                                          + _ZIP64_LOCAL_EXTRA)
                with zf.open(info, "w", force_zip64=True) as member:
                    np.lib.format.write_array(member, value, allow_pickle=False)
                    # A .npy member ends with the array's bytes, in C or Fortran order.
                    index[name] = [fh.tell() - value.nbytes, value.dtype.str, list(value.shape),
                                   value.flags.f_contiguous and not value.flags.c_contiguous]
                indexable &= np.dtype(value.dtype.str) == value.dtype  # not so a structured dtype
            text = json.dumps(index, separators=(",", ":")).encode()
            comment = text + _INDEX + b"%0*d" % (_INDEX_DIGITS, len(text))
            if not indexable or len(comment) + _TRAILER > _COMMENT_MAX:
                comment = b""  # no index: readers walk the zip directory
            zf.comment = comment + _PREFIX + b"0" * _HEX  # a placeholder, outside what is hashed
        fh.flush()
        size = fh.seek(0, os.SEEK_END)
        digest = _sha256(fh, size - _HEX)
        fh.seek(size - _HEX)
        fh.write(digest.encode())
    _tell_cached(Path(path), size)


def _tell_cached(path: Path, size: int) -> None:
    """One line on stderr — a terminal or not — when a file has been written into the user cache
    (:func:`cache_dir`): its path and size, so that no command fills the cache silently."""
    try:
        inside = path.resolve().parent == cache_dir().resolve()
    except OSError:
        return
    if inside:
        message = (f"wrote {path} ({size / 1e6:.1f} MB) into the user cache "
                   "(`skyfix cache info` lists it, `skyfix cache clear` removes it)")
        log.info("%s", message)
        if sys.stderr is not None:
            print(f"skyfix: {message}", file=sys.stderr, flush=True)


def map_npz(fh: BinaryIO) -> dict[str, np.ndarray]:
    """Every member of the uncompressed ``.npz`` open as ``fh`` (written by :func:`write_npz`), as
    read-only arrays over one memory map of the file (no copies; the file may be closed after).

    The members are found from the index :func:`write_npz` puts in the zip comment; in a file
    without one, by walking the zip directory and reading each ``.npy`` header. Check the file
    first (:func:`verify`): the index is trusted as far as the checksum vouches for it.

    Raises
    ------
    ValueError
        A compressed or object-array member, or a member beyond the end of the file.
    """
    size = os.fstat(fh.fileno()).st_size
    table = _read_index(fh, size)
    if table is None:
        table = _walk_members(fh)
    buffer = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) if size else b""
    arrays = {}
    for name, (offset, dtype, shape, fortran) in table.items():
        dtype = np.dtype(dtype)
        if dtype.hasobject:
            raise ValueError(f"member {name} holds Python objects")
        shape = tuple(int(n) for n in shape)
        if offset < 0 or offset + math.prod(shape) * dtype.itemsize > size:
            raise ValueError(f"member {name} runs past the end of the file")
        arrays[name] = np.ndarray(shape, dtype, buffer=buffer, offset=offset, order="F" if fortran else "C")
    return arrays


def verify(fh: BinaryIO, *, remember: bool = True) -> None:
    """Check the SHA-256 trailer of the open file ``fh`` (as written by :func:`write_npz`); on
    success ``fh`` is left at its start.

    With ``remember``, a file that passes is stamped in the cache (see the module notes), and
    an unchanged stamped file is not hashed again.

    Raises
    ------
    CorruptFileError
        No trailer (truncated, or not written by :func:`write_npz`) or a digest mismatch.
    """
    st = os.fstat(fh.fileno())
    if st.st_size < _TRAILER:
        raise CorruptFileError(f"too short ({st.st_size} bytes) to hold a checksum")
    fh.seek(st.st_size - _TRAILER)
    trailer = fh.read(_TRAILER)
    if not trailer.startswith(_PREFIX):
        raise CorruptFileError("no checksum at its end (truncated, or written by an older skyfix)")
    stored = trailer[len(_PREFIX):].decode("ascii", "replace")
    identity = f"{st.st_dev} {st.st_ino} {st.st_size} {st.st_mtime_ns} {st.st_ctime_ns} {stored}"
    target = _real_name(fh) if remember else None
    stamp = _stamp_path(target) if target is not None else None
    if stamp is None or _read_text(stamp).split("\n")[0] != identity:
        if _sha256(fh, st.st_size - _HEX) != stored:
            raise CorruptFileError("checksum mismatch (the file is corrupt)")
        age_s = time.time() - max(st.st_mtime_ns, st.st_ctime_ns) / 1e9
        if stamp is not None and age_s > STAMP_MIN_AGE_S:
            try:
                _write_text(stamp, f"{identity}\n{target}")
                _prune_stamps(stamp.parent)
            except OSError as exc:  # a read-only cache costs a hash per load, nothing else
                log.debug("cannot write %s: %s", stamp, exc)
    fh.seek(0)


@contextmanager
def exclusive_lock(path: str | Path, on_wait: Callable[[], None] | None = None) -> Iterator[None]:
    """Hold an exclusive advisory lock on ``<path>.lock`` while rebuilding ``path``; if another
    process holds it, call ``on_wait()`` and wait for it.

    Where locks are unavailable (no ``fcntl``, read-only folder) this only yields: concurrent
    rebuilds then duplicate work but, written by :func:`write_npz`, never corrupt the file.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        yield
        return
    lock = Path(path).with_name(Path(path).name + ".lock")
    try:
        fh = open(lock, "a+b")
    except OSError:
        yield
        return
    with fh:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if on_wait is not None:
                on_wait()
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


def notice(message: str) -> None:
    """Tell the user what a long first-use step is doing: one line on stderr if it is a
    terminal (else only an INFO log record)."""
    log.info("%s", message)
    if sys.stderr is not None and sys.stderr.isatty():
        print(f"skyfix: {message}", file=sys.stderr, flush=True)


def has_index(path: str | Path) -> bool:
    """Whether the ``.npz`` at ``path`` carries the member index of :func:`write_npz` (files
    written before it existed do not)."""
    with open(path, "rb") as fh:
        return _read_index(fh, os.fstat(fh.fileno()).st_size) is not None


def _align_extra(offset: int) -> bytes:
    """A zip extra field that moves a member's data from file offset ``offset`` (where it would
    start with no extra field) to the next multiple of :data:`_ALIGN`."""
    pad = -(offset + 6) % _ALIGN
    return (_ALIGN_EXTRA_ID.to_bytes(2, "little") + (2 + pad).to_bytes(2, "little")
            + _ALIGN.to_bytes(2, "little") + bytes(pad))


def _read_index(fh: BinaryIO, size: int) -> dict[str, list] | None:
    """The member index in the zip comment of ``fh`` (see :func:`write_npz`); None without one."""
    end = size - _TRAILER
    if end < _INDEX_TAIL:
        return None
    fh.seek(end - _INDEX_TAIL)
    tail = fh.read(_INDEX_TAIL)
    if not tail.startswith(_INDEX) or not tail[len(_INDEX):].isdigit():
        return None
    length = int(tail[len(_INDEX):])
    start = end - _INDEX_TAIL - length
    if start < 0:
        return None
    fh.seek(start)
    return json.loads(fh.read(length))


def _walk_members(fh: BinaryIO) -> dict[str, list]:
    """The member index of an ``.npz`` without one: from the zip directory and the ``.npy`` headers."""
    table = {}
    with zipfile.ZipFile(fh) as zf:
        for info in zf.infolist():
            name = info.filename.removesuffix(".npy")
            if info.compress_type != zipfile.ZIP_STORED:
                raise ValueError(f"member {name} is compressed")
            fh.seek(info.header_offset)
            local = fh.read(_ZIP_LOCAL_HEADER)
            if len(local) < _ZIP_LOCAL_HEADER or local[:4] != b"PK\x03\x04":
                raise ValueError(f"bad zip member {name}")
            n_name = int.from_bytes(local[26:28], "little")
            n_extra = int.from_bytes(local[28:30], "little")
            fh.seek(info.header_offset + _ZIP_LOCAL_HEADER + n_name + n_extra)
            version = np.lib.format.read_magic(fh)
            read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                           else np.lib.format.read_array_header_2_0)
            shape, fortran, dtype = read_header(fh)
            table[name] = [fh.tell(), dtype, list(shape), fortran]
    return table


def _sha256(fh: BinaryIO, length: int) -> str:
    """Hex SHA-256 of the first ``length`` bytes of ``fh``."""
    h = hashlib.sha256()
    fh.seek(0)
    buf = bytearray(_READ_BLOCK)
    view = memoryview(buf)
    left = length
    while left > 0:
        n = fh.readinto(view[:min(left, _READ_BLOCK)])
        if not n:
            raise CorruptFileError("shorter than its own size (changed while read)")
        h.update(view[:n])
        left -= n
    return h.hexdigest()


def _real_name(fh: BinaryIO) -> str | None:
    name = getattr(fh, "name", None)
    if not isinstance(name, (str, bytes, os.PathLike)):
        return None
    return os.fsdecode(os.path.realpath(name))


def _stamp_path(target: str) -> Path | None:
    """The stamp of the file at real path ``target`` (None without a cache folder)."""
    try:
        return cache_dir() / "verified" / hashlib.sha256(os.fsencode(target)).hexdigest()[:32]
    except OSError:
        return None


def _prune_stamps(folder: Path, keep: int = 64) -> None:
    """Beyond ``keep`` stamps, remove those whose file is gone (temporary databases, old paths)."""
    stamps = [p for p in folder.iterdir() if not p.name.startswith(".")]  # not others' temporaries
    if len(stamps) <= keep:
        return
    for stamp in stamps:
        lines = _read_text(stamp).split("\n")
        if len(lines) < 2 or not os.path.exists(lines[1]):
            stamp.unlink(missing_ok=True)


def _read_text(path: Path) -> str:
    """The text of ``path``; "" if it cannot be read."""
    try:
        return path.read_text()
    except (OSError, UnicodeDecodeError):
        return ""


def _write_text(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(path, "w") as fh:
        fh.write(text)
