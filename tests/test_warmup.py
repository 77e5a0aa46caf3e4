"""The up-front compile (skyfix.warmup): its jobs compile what a real solve runs, one signature
per kernel whatever the frame, the stamp, the worker processes and the notice."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import skyfix
from skyfix import _warm_jobs, warmup

ROOT = Path(__file__).resolve().parents[1]
SKY = ROOT / "examples" / "sky.png"


def _kernel_signatures() -> dict[str, set[str]]:
    """Every skyfix numba kernel loaded in this process and the signatures it holds."""
    from numba.core.registry import CPUDispatcher

    out = {}
    for name, module in list(sys.modules.items()):
        if not name.startswith("skyfix") or module is None:
            continue
        for attr, value in list(vars(module).items()):
            if isinstance(value, CPUDispatcher) and value.py_func.__module__ == name:
                out[f"{name}.{attr}"] = {str(s) for s in value.signatures}
    return out


def test_the_solve_jobs_compile_every_signature_a_real_solve_uses():
    # What the jobs run in their workers, run here: every kernel signature a solve of a real
    # frame then needs must be among them, or a first solve compiles again after its warm-up.
    for job in warmup.PATHS["solve"]:
        getattr(_warm_jobs, job.replace("-", "_"))()
    before = _kernel_signatures()
    sol = skyfix.solve(SKY)
    assert sol.solved
    sol = skyfix.solve(SKY, camera=sol.camera)  # the camera-given final fit
    assert sol.solved
    after = _kernel_signatures()
    new = {k: sorted(v - before.get(k, set())) for k, v in after.items() if v - before.get(k, set())}
    assert not new, f"a real solve compiled signatures the warm-up jobs did not: {new}"


def test_extraction_kernels_have_one_signature_whatever_the_frame():
    # 8/16-bit, float64, non-contiguous frames and frames of other sizes (whose background grids
    # come out as views) all reach the kernels as C-contiguous float32 with C-contiguous grids.
    from skyfix.detect import extract_centroids

    frame = _warm_jobs.scene().frame
    rng = np.random.default_rng(3)
    frames = [frame, frame.astype(np.float64), np.clip(frame, 0, 255).astype(np.uint8),
              (frame * 10).astype(np.uint16), np.asfortranarray(frame), frame[::-1],
              np.ascontiguousarray(frame[:301, :517]),
              (200 + 4 * rng.standard_normal((1000, 130))).astype(np.float32)]
    # Kernels other tests of the session called directly (float64 arrays) may hold other
    # signatures already: what counts is that the first frame adds at most one a kernel and
    # the other frames none.
    before = _kernel_signatures()
    extract_centroids(frames[0], max_stars=50)
    first = _kernel_signatures()
    added = {k: v - before.get(k, set()) for k, v in first.items()}
    twice = {k: sorted(v) for k, v in added.items() if len(v) > 1}
    assert not twice, f"one extraction compiled two signatures of a kernel: {twice}"
    for f in frames[1:]:
        extract_centroids(f, max_stars=50)
    sigs = _kernel_signatures()
    detect = {k: v for k, v in sigs.items() if k.startswith("skyfix.detect.") and v}
    assert detect, "no detection kernel ran"
    several = {k: sorted(v - first.get(k, set())) for k, v in detect.items() if v - first.get(k, set())}
    assert not several, f"kernels compiled for more than one signature: {several}"


def test_estimate_is_the_longest_first_schedule():
    jobs = warmup.PATHS["solve"]
    costs = sorted((warmup.JOBS[j].cpu_s for j in jobs), reverse=True)
    assert warmup.estimate_s(jobs, 1) == pytest.approx(sum(costs) + len(costs))
    two = warmup.estimate_s(jobs, 2)
    assert max(costs) + 1 <= two < sum(costs) + len(costs)
    assert warmup.estimate_s(jobs, 8) == pytest.approx(max(costs) + 1)
    assert warmup.estimate_s((), 2) == 0.0


def test_unknown_path_is_refused():
    with pytest.raises(KeyError, match="unknown warm-up path 'bogus'"):
        warmup.ensure("bogus")


def test_disabled_warmup_runs_alongside_only(monkeypatch, tmp_path):
    monkeypatch.setenv("SKYFIX_WARMUP", "0")
    monkeypatch.setattr(warmup, "_stamp_file", lambda: tmp_path / "warm.json")
    monkeypatch.setattr(warmup, "_warm_here", set())
    ran = []
    warmup.ensure("solve", alongside=lambda: ran.append(1))
    assert ran == [1]
    assert not (tmp_path / "warm.json").exists()
    assert not warmup.is_warm("solve")


def test_worker_reports_a_failed_job():
    out = subprocess.run([sys.executable, "-m", "skyfix._warm_worker", "no-such-job"], capture_output=True,
                         text=True, env={**os.environ, "PYTHONPATH": str(ROOT / "src")}, timeout=120)
    assert out.returncode == 1
    assert out.stdout.strip().splitlines()[-1].startswith("failed AttributeError")


def test_warm_runs_the_jobs_in_workers_and_stamps_them(tmp_path):
    # A process with its own stamp (none yet): the solve path's jobs run in worker processes
    # (their kernels are cached by now, so they only load), the notice says so on a pipe, the
    # stamp then holds the jobs, and a second call has nothing to do.
    code = f"""
import json, sys
from pathlib import Path
from skyfix import warmup
stamp = Path({str(tmp_path / 'warm.json')!r})
warmup._stamp_file = lambda: stamp
assert not warmup.is_warm("solve")
ran = []
warmup.ensure("solve", alongside=lambda: ran.append(1), also="doing something else")
assert ran == [1], ran
assert warmup.is_warm("solve")
print(json.dumps(json.loads(stamp.read_text())["jobs"]))
assert warmup.warm(["solve"]) == {{}}
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=900,
                         env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1]) == dict.fromkeys(warmup.PATHS["solve"], True)
    lines = out.stderr.strip().splitlines()
    assert lines[0].startswith("skyfix: first use: compiling the kernels of star extraction")
    assert "doing something else (once; about" in lines[0]
    assert lines[-1].startswith("skyfix: compiled in ")
