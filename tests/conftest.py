"""Shared fixtures: the real images beside the repository and the cached pattern database; and the
paths every test finds its data by (the repository, examples/, tests/data/, the real images), so
no test depends on its own depth in tests/ or on where the repository sits."""

import contextlib
import json
import os
import time
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


def _whole_suite(config: pytest.Config) -> bool:
    """Whether this run is the default run of every test (CI's: no paths, or the tests folder)."""
    if config.args_source == pytest.Config.ArgsSource.TESTPATHS:
        return True
    return bool(config.args) and all(Path(a).resolve() == ROOT / "tests" for a in config.args)


def _build_default_databases() -> None:
    from skyfix.identify import BANDS, band_database

    for band in BANDS:
        band_database(band, progress=False)


@pytest.hookimpl(optionalhook=True)  # xdist's hook: in the starting process, before the workers
def pytest_xdist_setupnodes(config: pytest.Config, specs) -> None:
    _first_use(config)


def _first_use(config: pytest.Config) -> None:
    """A fresh cache's first-use work done once, announced, inside the run's timed session: with
    xdist, before its workers start (:func:`pytest_xdist_setupnodes`); with ``-n 0``, before the
    first test. In a whole run, every warm-up path's kernels compiled on every core
    (skyfix.warmup) while this process builds the four default bands' pattern databases (and the
    Hipparcos and Gaia caches they are built from); in a run of some tests, the solve path's
    kernels. So no two workers compile or build the same thing, no worker waits on a lock while
    the other compiles alone, and no test pays the first use of what it happens to run first (a
    compile notice would land in a checked stderr)."""
    if config.option.collectonly:
        return
    from skyfix import warmup
    from skyfix.identify import BANDS

    whole = _whole_suite(config)
    paths = list(warmup.PATHS) if whole else ["solve"]
    missing = whole and any(not band.path.exists() for band in BANDS)
    todo = warmup.pending(paths)
    if not todo and not missing:
        return
    reporter = config.pluginmanager.get_plugin("terminalreporter")
    what = [f"compiling {len(todo)} warm-up jobs"] if todo else []
    what += ["building the default pattern databases"] if missing else []
    if reporter is not None:
        reporter.write_line(f"skyfix, first use in this cache: {' and '.join(what)} before the tests")
    start = time.perf_counter()
    capture = config.pluginmanager.get_plugin("capturemanager")
    with capture.global_and_fixture_disabled() if capture is not None else contextlib.nullcontext():
        warmup.ensure(paths, alongside=_build_default_databases if missing else None,
                      also="building the pattern databases")
    if reporter is not None:
        reporter.write_line(f"skyfix, first use in this cache: done in {time.perf_counter() - start:.0f} s")


@pytest.fixture(scope="session", autouse=True)
def _kernels_compiled_up_front(request):
    """The first-use work before any test (:func:`_first_use`; in an xdist worker its starting
    process did it): a fresh checkout's first solve would otherwise print its compile notice into
    whichever test solves first (and that test's stderr is checked)."""
    if not hasattr(request.config, "workerinput"):
        _first_use(request.config)


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
