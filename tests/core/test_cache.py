"""Cache files: atomic writes with unique temporary names, checksums, rebuilds, concurrency.

Every test runs on its own empty cache (``SKYFIX_CACHE``), so it is cold: the catalogue is
parsed and a one-band database (FOV 20°, a few seconds) is built there.
"""

import dataclasses
import hashlib
import os
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

import skyfix.cache
import skyfix.catalog
import skyfix.identify.catalogue.bands as bands_module
import skyfix.identify.catalogue.database as database_module
from skyfix.cache import CorruptFileError, has_index, map_npz, verify, write_npz
from skyfix.catalog import load_hipparcos
from skyfix.errors import DatabaseError
from skyfix.identify import PatternDatabase, default_database, default_database_path
from tests.conftest import EXAMPLES

FOV = 20.0  # a one-band database: quick to build
EXAMPLE = EXAMPLES / "sky.png"
EPOCH = 2025.0


@pytest.fixture
def cold_cache(tmp_path, monkeypatch):
    """An empty cache, nothing loaded in this process, and a fixed epoch for default builds."""
    cache = tmp_path / "cache"
    monkeypatch.setenv("SKYFIX_CACHE", str(cache))
    monkeypatch.setattr(skyfix.catalog, "_RAW", None)
    monkeypatch.setattr(bands_module, "_LOADED", {})
    monkeypatch.setattr(database_module, "epoch_now", lambda: EPOCH)
    return cache


def _corrupt_middle(path: Path, n: int = 4096, seed: int = 0) -> None:
    """Overwrite ``n`` random bytes in the middle of ``path``, in place (size unchanged)."""
    size = path.stat().st_size
    with open(path, "r+b") as fh:
        fh.seek(size // 2 - n // 2)
        fh.write(np.random.default_rng(seed).bytes(n))


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])


def _arrays(db: PatternDatabase) -> dict[str, np.ndarray]:
    return {f.name: np.asarray(getattr(db, f.name)) for f in dataclasses.fields(db) if f.name != "meta"}


def _no_temporaries(folder: Path) -> None:
    left = [p.name for p in folder.rglob("*") if p.name.endswith(".tmp")]
    assert not left, left


# --- write_npz / verify ------------------------------------------------------------------------
def test_write_npz_is_a_plain_npz_with_a_checksum(tmp_path):
    path = tmp_path / "a.npz"
    write_npz(path, {"x": np.arange(1000), "y": np.eye(3)})
    with np.load(path) as npz:
        assert np.array_equal(npz["x"], np.arange(1000)) and np.array_equal(npz["y"], np.eye(3))
    with open(path, "rb") as fh:
        verify(fh, remember=False)
    _no_temporaries(tmp_path)


def test_a_write_into_the_user_cache_is_announced(cold_cache, tmp_path, capsys):
    """One line on stderr (a terminal or not) naming the file and its size; elsewhere, none."""
    write_npz(tmp_path / "mine.npz", {"x": np.arange(1000)})
    assert capsys.readouterr().err == ""
    path = skyfix.cache.cache_dir() / "a.npz"
    write_npz(path, {"x": np.zeros(250_000)})  # 2.0 MB
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1
    assert lines[0].startswith(f"skyfix: wrote {path} (2.0 MB) into the user cache")


@pytest.mark.parametrize("damage", ["middle", "truncate", "last byte", "no trailer"])
def test_verify_detects_damage(tmp_path, damage):
    path = tmp_path / "a.npz"
    write_npz(path, {"x": np.arange(100_000)})
    if damage == "middle":
        _corrupt_middle(path)
    elif damage == "truncate":
        _truncate(path)
    elif damage == "last byte":  # the end of the zip directory, just before the digest
        data = bytearray(path.read_bytes())
        data[-80] ^= 1
        path.write_bytes(bytes(data))
    else:
        np.savez(path, x=np.arange(100_000))  # numpy's own writer: no checksum
    with open(path, "rb") as fh, pytest.raises(CorruptFileError):
        verify(fh, remember=False)


def _legacy_npz(path: Path, arrays: dict) -> None:
    """A file as write_npz wrote it before the member index: members at no particular offset, the
    zip comment only the checksum trailer."""
    with open(path, "wb+") as fh:
        with zipfile.ZipFile(fh, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
            for name, value in arrays.items():
                with zf.open(f"{name}.npy", "w", force_zip64=True) as member:
                    np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)
            zf.comment = b"skyfix-sha256:" + b"0" * 64
        fh.seek(0)
        body = fh.read()[:-64]
        fh.seek(len(body))
        fh.write(hashlib.sha256(body).hexdigest().encode())


def test_members_are_mapped_from_the_index_aligned_without_copies(tmp_path):
    arrays = {"meta": np.array('{"a": 1}'), "x": np.arange(1001, dtype=np.int64),
              "y": np.arange(12.0).reshape(3, 4), "f": np.asfortranarray(np.arange(6.0).reshape(2, 3)),
              "odd": np.arange(7, dtype=np.int8), "empty": np.zeros((0, 3), np.float32)}
    path = tmp_path / "a.npz"
    write_npz(path, arrays)
    assert has_index(path)
    with open(path, "rb") as fh:
        verify(fh, remember=False)
        mapped = map_npz(fh)
        walked = skyfix.cache._walk_members(fh)
        assert skyfix.cache._read_index(fh, path.stat().st_size) == {
            k: [off, np.dtype(dt).str, shape, fortran] for k, (off, dt, shape, fortran) in walked.items()}
    assert list(mapped) == list(arrays)
    for name, value in arrays.items():
        got = mapped[name]
        assert got.dtype == value.dtype and got.shape == value.shape and np.array_equal(got, value), name
        assert not got.flags.writeable and got.ctypes.data % 64 == 0, name
        assert got.base is mapped["x"].base  # one memory map of the file, no copies
    assert mapped["f"].flags.f_contiguous and not mapped["f"].flags.c_contiguous
    with np.load(path) as npz:  # still an ordinary .npz
        assert all(np.array_equal(npz[k], v) for k, v in arrays.items())


def test_a_file_without_the_index_is_read_through_the_zip_directory(tmp_path):
    path = tmp_path / "old.npz"
    _legacy_npz(path, {"x": np.arange(100), "y": np.eye(3)})
    assert not has_index(path)
    with open(path, "rb") as fh:
        verify(fh, remember=False)
        mapped = map_npz(fh)
    assert np.array_equal(mapped["x"], np.arange(100)) and np.array_equal(mapped["y"], np.eye(3))


def test_temporary_names_are_unique_per_writer(tmp_path, monkeypatch):
    """Each write goes through its own temporary file beside the target, renamed over it."""
    renamed = []
    real_replace = os.replace

    def spy(src, dst):
        renamed.append((Path(src), Path(dst)))
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", spy)
    path = tmp_path / "a.npz"
    for i in range(3):
        write_npz(path, {"x": np.arange(i + 1)})
    sources = [src for src, dst in renamed if dst == path]
    assert len(sources) == 3 and len(set(sources)) == 3
    assert all(src.parent == path.parent and src.name.endswith(".tmp") for src in sources)
    _no_temporaries(tmp_path)


def test_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "a.npz"
    write_npz(path, {"x": np.arange(10)})
    with pytest.raises(ValueError):  # object arrays are refused mid-write
        write_npz(path, {"x": np.arange(5), "bad": np.array([{}, []], dtype=object)})
    with np.load(path) as npz:
        assert np.array_equal(npz["x"], np.arange(10))
    _no_temporaries(tmp_path)


def test_verified_file_is_stamped_and_a_changed_one_hashed_again(cold_cache, tmp_path, monkeypatch):
    monkeypatch.setattr(skyfix.cache, "STAMP_MIN_AGE_S", -1.0)  # stamp even a brand-new file
    path = tmp_path / "a.npz"
    write_npz(path, {"x": np.arange(100_000)})
    with open(path, "rb") as fh:
        verify(fh)
    assert len(list((cold_cache / "verified").iterdir())) == 1
    hashed = []
    real = skyfix.cache._sha256
    monkeypatch.setattr(skyfix.cache, "_sha256", lambda fh, n: hashed.append(n) or real(fh, n))
    with open(path, "rb") as fh:
        verify(fh)
    assert hashed == []  # unchanged: the stamp answers
    time.sleep(0.05)  # past the file system's timestamp granularity
    _corrupt_middle(path)
    with open(path, "rb") as fh, pytest.raises(CorruptFileError):
        verify(fh)
    assert len(hashed) == 1


def test_stamps_of_vanished_files_are_pruned(cold_cache, tmp_path, monkeypatch):
    monkeypatch.setattr(skyfix.cache, "STAMP_MIN_AGE_S", -1.0)
    files = [tmp_path / f"f{i}.npz" for i in range(70)]
    for path in files:
        write_npz(path, {"x": np.arange(3)})
        with open(path, "rb") as fh:
            verify(fh)
    stamps = cold_cache / "verified"
    assert len(list(stamps.iterdir())) == 70  # beyond 64 only stamps of vanished files go
    for path in files[:60]:
        path.unlink()
    write_npz(tmp_path / "last.npz", {"x": np.arange(3)})
    with open(tmp_path / "last.npz", "rb") as fh:
        verify(fh)
    assert len(list(stamps.iterdir())) == 11  # 10 files left + the last


# --- the catalogue cache -----------------------------------------------------------------------
def test_catalogue_is_parsed_once_then_read_from_the_cache(cold_cache, monkeypatch):
    fresh = load_hipparcos(epoch=EPOCH)
    monkeypatch.setattr(skyfix.catalog, "_RAW", None)
    monkeypatch.setattr(skyfix.catalog, "_parse_hip2", lambda path: pytest.fail("parsed again"))
    again = load_hipparcos(epoch=EPOCH)
    assert np.array_equal(again.vectors, fresh.vectors) and np.array_equal(again.ids, fresh.ids)


@pytest.mark.parametrize("damage", [_corrupt_middle, _truncate])
def test_damaged_catalogue_cache_is_rebuilt(cold_cache, monkeypatch, damage):
    fresh = load_hipparcos(epoch=EPOCH)
    cache = cold_cache / f"hip2_v{skyfix.catalog._CACHE_VERSION}.npz"
    damage(cache)
    monkeypatch.setattr(skyfix.catalog, "_RAW", None)
    again = load_hipparcos(epoch=EPOCH)
    for name in ("ids", "vectors", "mag", "pm_ra", "pm_dec"):
        assert np.array_equal(getattr(again, name), getattr(fresh, name))
    with open(cache, "rb") as fh:
        verify(fh, remember=False)  # rewritten whole
    _no_temporaries(cold_cache)


# --- database caches and files -----------------------------------------------------------------
@pytest.fixture
def cached_db(cold_cache) -> tuple[PatternDatabase, Path]:
    db = default_database(FOV, FOV, progress=False)
    return db, default_database_path(FOV, FOV)


def test_cached_database_without_the_index_is_saved_again_not_rebuilt(cached_db, monkeypatch):
    db, path = cached_db
    assert has_index(path)
    fresh = {k: v.copy() for k, v in _arrays(db).items()}
    with np.load(path) as npz:
        _legacy_npz(path, {k: npz[k] for k in npz.files})
    del db
    assert not has_index(path)
    monkeypatch.setattr(bands_module, "_LOADED", {})
    monkeypatch.setattr(bands_module, "_build", lambda *a: pytest.fail("rebuilt"))
    again = default_database(FOV, FOV, progress=False)
    assert has_index(path)
    for name, value in fresh.items():
        assert np.array_equal(np.asarray(getattr(again, name)), value), name
    _no_temporaries(path.parent)


@pytest.mark.parametrize("damage", [_corrupt_middle, _truncate])
def test_damaged_database_cache_is_rebuilt(cached_db, monkeypatch, damage):
    db, path = cached_db
    fresh = {k: v.copy() for k, v in _arrays(db).items()}
    del db
    damage(path)
    monkeypatch.setattr(bands_module, "_LOADED", {})
    again = default_database(FOV, FOV, progress=False)
    for name, value in fresh.items():
        assert np.array_equal(np.asarray(getattr(again, name)), value), name
    PatternDatabase.load(path)  # the cache holds a good file again
    _no_temporaries(path.parent)


@pytest.mark.parametrize("damage", [_corrupt_middle, _truncate])
def test_damaged_user_database_is_a_one_line_error(cached_db, tmp_path, damage):
    _, path = cached_db
    mine = tmp_path / "mine.npz"
    mine.write_bytes(path.read_bytes())
    PatternDatabase.load(mine)
    damage(mine)
    with pytest.raises(DatabaseError) as info:
        PatternDatabase.load(mine)
    message = str(info.value)
    assert "\n" not in message and str(mine) in message
    assert mine.exists()  # the user's file: reported, never removed or rebuilt


def test_damaged_user_database_in_the_cli(cached_db, tmp_path):
    from typer.testing import CliRunner

    from skyfix.cli import app

    _, path = cached_db
    mine = tmp_path / "mine.npz"
    mine.write_bytes(path.read_bytes())
    _corrupt_middle(mine)
    result = CliRunner().invoke(app, ["solve", "--database", str(mine), str(EXAMPLE)])
    assert result.exit_code == 2 and isinstance(result.exception, SystemExit)
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and "corrupt" in lines[0] and str(mine) in lines[0], result.output


# --- concurrency -------------------------------------------------------------------------------
_WORKER = """
import sys, time
from pathlib import Path
go = Path(sys.argv[1])
from skyfix.catalog import load_hipparcos
from skyfix.identify import default_database
while not go.exists():
    time.sleep(0.005)
n = len(load_hipparcos())
db = default_database({fov}, {fov}, progress=False)
print(n, len(db), db.meta["epoch"])
"""


def test_processes_on_a_cold_cache_all_succeed(tmp_path):
    """Four processes start at once on an empty cache: all load the catalogue and the database;
    one parses and builds, the others wait for its files (the same database for all four)."""
    cache = tmp_path / "cache"
    go = tmp_path / "go"
    env = {**os.environ, "SKYFIX_CACHE": str(cache)}
    procs = [subprocess.Popen([sys.executable, "-c", _WORKER.format(fov=FOV), str(go)], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(4)]
    time.sleep(0.5)
    go.touch()
    results = [p.communicate(timeout=300) for p in procs]
    for p, (_, err) in zip(procs, results, strict=True):
        assert p.returncode == 0, err[-2000:]
    lines = {out.strip() for out, _ in results}
    assert len(lines) == 1, lines  # built once: one epoch, one pattern count
    assert PatternDatabase.load(cache / default_database_path(FOV, FOV).name)
    _no_temporaries(cache)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the XDG rule is read on Linux only")
# "%" stands for the slash that begins an absolute path (no machine's path in a test's text)
@pytest.mark.parametrize("xdg, home", [(None, "%home/ann"), ("%data/cache", "%home/ann"),
                                       ("relative/cache", "%root/"), ("", "%"), (None, "relative-home"),
                                       (None, None)])
def test_the_user_cache_folder_is_platformdirs_without_importing_it(monkeypatch, xdg, home):
    import platformdirs

    for name, value in (("XDG_CACHE_HOME", xdg), ("HOME", home)):
        value = None if value is None else value.replace("%", "/")
        if value is None:
            monkeypatch.delenv(name, raising=False)
        else:
            monkeypatch.setenv(name, value)
    assert skyfix.cache._user_cache_dir() == Path(platformdirs.user_cache_dir("skyfix"))
