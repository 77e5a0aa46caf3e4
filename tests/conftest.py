"""Shared fixtures: the real images beside the repository and the cached pattern database; and the
paths every test finds its data by (the repository, examples/, tests/data/, the real images), so
no test depends on its own depth in tests/ or on where the repository sits."""

import json
import os
from pathlib import Path

import pytest

# The tests run the kernels through numba, as a fresh checkout (CI) does, whether or not
# `skyfix warmup` compiled them ahead of time here: the same results either way, and tests of the
# warm-up and of start-up assume numba's path. tests/core/test_aot.py runs the exports in
# processes of their own.
os.environ.setdefault("SKYFIX_AOT", "0")

ROOT = Path(__file__).resolve().parents[1]  # the repository
EXAMPLES = ROOT / "examples"
DATA_DIR = ROOT / "tests" / "data"
REAL_DIR = ROOT.parent / "shared" / "data" / "real"  # beside the repository


@pytest.hookimpl(optionalhook=True)  # xdist's hook
def pytest_xdist_auto_num_workers(config) -> int:
    """``-n auto``: a worker a core, at most 4 (each worker loads its own catalogue, databases and
    kernels)."""
    return max(1, min(os.cpu_count() or 1, 4))


@pytest.fixture(scope="session", autouse=True)
def _kernels_compiled_up_front():
    """The solve path's kernels compiled once, in parallel, before any test (skyfix.warmup): a
    fresh checkout's first solve would otherwise print its compile notice into whichever test
    solves first (and that test's stderr is checked)."""
    from skyfix import warmup

    warmup.ensure("solve")


@pytest.fixture(scope="session")
def real_dir() -> Path:
    if not REAL_DIR.is_dir():
        if os.environ.get("CI"):
            pytest.fail(f"real images not found at {REAL_DIR}")
        pytest.skip("real images (../shared/data/real) not present")
    return REAL_DIR


@pytest.fixture(scope="session")
def real_solutions(real_dir) -> dict[str, dict]:
    lines = (real_dir / "solutions.jsonl").read_text().splitlines()
    return {d["image"]: d for d in map(json.loads, lines)}


@pytest.fixture(scope="session")
def database():
    from skyfix.identify import default_database

    return default_database()


@pytest.fixture(scope="session")
def catalog(database):
    """Hipparcos at the default database's epoch: the catalogue whose stars it identifies."""
    from skyfix.catalog import load_hipparcos

    return load_hipparcos(epoch=database.epoch)
