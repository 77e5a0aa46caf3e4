"""Building the pattern database in chunks: bounded memory, the same patterns either way, progress."""

import dataclasses
import tracemalloc

import numpy as np
import pytest

import skyfix.identify.catalogue.database as database_module
from skyfix.catalog import load_hipparcos
from skyfix.identify import PatternDatabase

EPOCH = 2025.0


@pytest.fixture(scope="module")
def catalog():
    return load_hipparcos(epoch=EPOCH)


def _same(a: PatternDatabase, b: PatternDatabase) -> None:
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name == "meta":
            assert x == y
        else:
            assert x.dtype == y.dtype and np.array_equal(x, y), f.name


def test_packed_and_row_pattern_sets_build_the_same_database(catalog, monkeypatch):
    """Patterns are deduplicated as packed uint64 codes below 2^16 pattern stars, as rows above;
    forcing the rows gives the same arrays."""
    packed = PatternDatabase.build(20.0, 22.0, catalog=catalog, epoch=EPOCH)
    monkeypatch.setattr(database_module._QuadSet, "_BITS", 8)  # 2^8 < the pattern stars: rows
    rows = PatternDatabase.build(20.0, 22.0, catalog=catalog, epoch=EPOCH)
    _same(packed, rows)
    # Each pattern once, rows ascending, grouped by key code.
    p = np.asarray(packed.pattern_stars)
    assert np.all(np.diff(p, axis=1) > 0)
    assert len(np.unique(p, axis=0)) == len(p)


def test_build_memory_is_bounded(catalog):
    """One 10° band (the costliest of the default range, 0.54 M patterns): the whole build used
    307 MB of traced allocations before it was chunked; now about 110 MB."""
    tracemalloc.start()
    try:
        db = PatternDatabase.build(10.0, 10.0, catalog=catalog, epoch=EPOCH)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(db) > 500_000
    assert peak < 160e6, f"{peak / 1e6:.0f} MB"


def test_progress_callable_and_quiet_bar(catalog, capsys):
    seen = []
    PatternDatabase.build(20.0, 20.0, catalog=catalog, epoch=EPOCH,
                          progress=lambda what, fraction: seen.append((what, fraction)))
    fractions = [f for _, f in seen]
    assert fractions[0] == 0.0 and fractions[-1] == 1.0
    assert all(b >= a for a, b in zip(fractions, fractions[1:], strict=False))
    assert any(what.startswith("patterns of") for what, _ in seen)
    capsys.readouterr()
    PatternDatabase.build(20.0, 20.0, catalog=catalog, epoch=EPOCH, progress=True)
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""  # not a terminal: no bar
