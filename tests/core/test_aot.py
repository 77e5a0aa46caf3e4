"""Kernels compiled ahead of time (skyfix.aot, skyfix._jit): the guards accept exactly what numba
would type as the export's signature, the recorded signatures cover a real solve, and a built
module answers as numba does, without importing numba."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from typing import NamedTuple

import numpy as np
import pytest

from skyfix import _jit, aot
from tests.conftest import EXAMPLES, ROOT


class Pair(NamedTuple):
    a: np.ndarray
    n: int


def _samples() -> list[object]:
    x = np.arange(12.0).reshape(3, 4)
    ro = np.arange(3.0)
    ro.setflags(write=False)
    rec = np.zeros(3, dtype=[("id", np.int32), ("v", np.float64), ("ok", np.bool_)])
    return [
        1, 1.5, True, None, np.float32(2), np.int32(3), np.float64(1), np.int64(1), np.bool_(False),
        np.arange(3.0), x, np.asfortranarray(x), x[:, ::2], ro, np.arange(3, dtype=np.float32),
        np.arange(3, dtype=np.int32), np.zeros((2, 2), np.uint8), rec, rec[::2],
        (1.0, 2.0), (1.0, 2), (np.arange(3.0), 1), Pair(np.arange(3.0), 1), Pair(np.arange(3.0), 2.5),
    ]


def test_a_guard_accepts_exactly_what_numba_types_the_same():
    from numba import typeof

    values = _samples()
    for a in values:
        recorded = aot.encode(typeof(a))
        assert aot.decode(recorded) == typeof(a), a  # the recorded text round-trips
        source, consts = _jit.guard_source([recorded])
        guard = eval(source, consts)
        for b in values:
            assert guard(b) == (typeof(b) == typeof(a)), (a, b)


def test_recorded_signatures_decode_and_encode_back():
    recorded = json.loads(aot.SIGNATURES.read_text())
    assert len(recorded) > 50
    for key, sigs in recorded.items():
        for sig in sigs:
            args = [aot.decode(a) for a in sig["args"]]
            assert [aot.encode(t) for t in args] == sig["args"], key
            assert aot.encode(aot.decode(sig["returns"])) == sig["returns"], key


@pytest.mark.slow  # a fresh process compiles the solve's kernels with numba (minutes on a cold cache)
def test_a_real_solve_calls_only_recorded_signatures():
    # A solve of the bundled frame, with numba (no exports), records what it calls from Python:
    # each must be in the recorded list, or a `skyfix solve` after `skyfix warmup` compiles again.
    code = ("import json, skyfix; from skyfix import aot; s = skyfix.solve('examples/sky.png'); "
            "skyfix.solve('examples/sky.png', camera=s.camera); print(json.dumps(aot.recorded_here()))")
    env = {**os.environ, "SKYFIX_AOT": "0", "PYTHONPATH": str(ROOT / "src")}
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
                         check=True, timeout=600)
    called = json.loads(out.stdout.strip().splitlines()[-1])
    recorded = json.loads(aot.SIGNATURES.read_text())
    assert len(called) >= 15
    missing = [(k, s["args"]) for k, sigs in called.items() for s in sigs if s not in recorded.get(k, [])]
    assert not missing, f"run `python -m skyfix.aot record`: {missing[:3]}"


@pytest.mark.slow
def test_a_built_module_answers_as_numba_does_without_numba(tmp_path):
    assert (EXAMPLES / "sky.png").exists()
    keys = ["skyfix._kernels.probability:log_binom_sf", "skyfix._kernels.rotation:angles"]
    cpu = aot.build(only=keys, folder=tmp_path, workers=1)
    assert set(cpu) == {"core"}
    index = json.loads((tmp_path / _jit.INDEX).read_text())
    assert {e["kernel"] for e in index["exports"]} == set(keys)
    code = """
import json, sys
import numpy as np
from skyfix._kernels.probability import log_binom_sf
from skyfix._kernels.rotation import angles
rng = np.random.default_rng(1)
a, b, c = (rng.normal(size=(5, 3)) for _ in range(3))
out = {"p": log_binom_sf(12, 40, 0.01), "angles": angles(a, b, c).tolist(),
       "numba_after_exports": "numba" in sys.modules}
out["f32"] = angles(a.astype(np.float32), b.astype(np.float32), c.astype(np.float32)).tolist()
out["numba_after_other_dtype"] = "numba" in sys.modules
print(json.dumps(out))
"""
    env = {**os.environ, "SKYFIX_AOT": "1", "SKYFIX_AOT_DIR": str(tmp_path), "PYTHONPATH": str(ROOT / "src")}
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    got = json.loads(res.stdout)
    assert got["numba_after_exports"] is False
    assert got["numba_after_other_dtype"] is True  # float32 is no export's: numba's dispatcher took it

    from skyfix._kernels.probability import log_binom_sf
    from skyfix._kernels.rotation import angles

    rng = np.random.default_rng(1)
    a, b, c = (rng.normal(size=(5, 3)) for _ in range(3))
    assert got["p"] == log_binom_sf.dispatcher()(12, 40, 0.01)
    assert got["angles"] == angles.dispatcher()(a, b, c).tolist()


def test_every_kernel_is_decorated_by_skyfix_jit():
    # A kernel decorated with numba's own njit would not be compiled ahead of time, and a module
    # importing numba at its top would import it in every process that imports the module.
    import re

    src = ROOT / "src" / "skyfix"
    offenders = []
    for path in sorted(src.rglob("*.py")):
        if "_aot" in path.parts:
            continue
        text = path.read_text()
        if re.search(r"^(import numba|from numba\b)", text, re.M) or re.search(r"@numba\.(njit|jit)\b", text):
            offenders.append(str(path.relative_to(src)))
    assert not offenders


@pytest.mark.filterwarnings("ignore:The 'pycc' module is pending deprecation")
def test_the_exports_of_nogil_kernels_release_the_gil(monkeypatch):
    """numba.pycc compiles every export with numba's default flags, whose CPython wrapper holds
    the GIL: the build turns ``release_gil`` on for the exports of ``nogil=True`` kernels (the
    extraction's chunks, which run on a helper thread), and leaves the others as they were."""
    from numba.core.compiler import Flags
    from numba.pycc import compiler

    from skyfix.detect.labelling import _smooth_threshold_rows, select_candidates

    seen = []

    def record(typingctx, targetctx, func, args, return_type, flags, *rest, **kw):
        seen.append((func.__name__, flags.release_gil))

    monkeypatch.setattr(compiler, "compile_extra", record)

    def held():
        pass

    def free():
        pass

    free.release_gil = True
    flags = Flags()
    with aot._gil_released_for_nogil_kernels():
        compiler.compile_extra(None, None, held, (), None, flags)
        compiler.compile_extra(None, None, free, (), None, flags)
    assert seen == [("held", False), ("free", True)] and not flags.release_gil
    assert compiler.compile_extra is record
    assert _smooth_threshold_rows.options.get("nogil") and not select_candidates.options.get("nogil")
