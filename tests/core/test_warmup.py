"""The up-front compile (skyfix.warmup): its jobs compile what a real solve runs, one signature
per kernel whatever the frame, the stamp, the worker processes and the notice."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import skyfix
from skyfix import _warm_jobs, warmup
from skyfix.errors import UnknownNameError
from tests.conftest import EXAMPLES, ROOT

SKY = EXAMPLES / "sky.png"


def _kernel_signatures() -> dict[str, set[str]]:
    """Every skyfix numba kernel loaded in this process and the signatures it holds."""
    from skyfix._jit import Kernel

    out = {}
    for name, module in list(sys.modules.items()):
        if not name.startswith("skyfix") or module is None:
            continue
        for attr, value in list(vars(module).items()):
            if isinstance(value, Kernel) and value.n_compiled and value.py_func.__module__ == name:
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
    with pytest.raises(UnknownNameError, match="unknown warm-up path 'bogus'"):
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


def test_needs_compile_first_and_are_part_of_the_path():
    assert warmup._with_needs(["track", "hint"]) == ["extract", "identify", "final-fit", "centroiders",
                                                     "streaks", "track", "hint"]
    for job in warmup.JOBS.values():
        assert all(n in warmup.JOBS for n in job.needs)
        assert callable(getattr(_warm_jobs, job.name.replace("-", "_")))
    # with a worker for each, the tracker starts when the last of its needs is done (the
    # centroiders' job after the extraction's, which it needs), each worker taking a second to start
    cost = {name: job.cpu_s + 1.0 for name, job in warmup.JOBS.items()}
    start = max(cost["identify"], cost["final-fit"], cost["streaks"], cost["extract"] + cost["centroiders"])
    assert warmup.estimate_s(warmup._with_needs(["track"]), 8) == pytest.approx(start + cost["track"])


# What a first use of each path does, to check that its warm-up job compiled what that use needs.
_USES = {
    "attitude": "[skyfix.solve(SKY, attitude_method=m) for m in ('quest', 'esoq2', 'q-method', 'triad')]",
    "hint": "skyfix.solve(SKY, camera=CAM, attitude_hint=HINT)",
    "centroiders": "[extract_centroids(IMG, centroid=c) for c in ('iwcog', 'gaussian')]",
    "method-triangle": "skyfix.solve(SKY, fov_deg=FOV, identify_method='triangle')",
    "detector-region_grow": "extract_centroids(IMG, method='region_grow')",
}
_SLOW_USES = {
    **{f"method-{m}": f"skyfix.solve(SKY, fov_deg=FOV, identify_method='{m}')"
       for m in ("liebe", "planar", "area-moment", "pyramid", "grid", "voting", "van-bezooijen")},
    "detector-threshold_hillclimb": "extract_centroids(IMG, method='threshold_hillclimb')",
    "detector-regionprops": "extract_centroids(IMG, method='regionprops')",
    "track": "from skyfix.track import Tracker; "
             "[[tr.update(f, 0.1 * k).mode for k in range(4)] "
             "for f, tr in ((IMG, Tracker(CAM)), (IMG.astype('uint16'), Tracker(CAM)))]",
    "streaks": "from skyfix.detect.streak import centroid_streaks; "
               "centroid_streaks(IMG, [(m.x, m.y) for m in sol.matches[:30]], (5.0, -3.0))",
}


@pytest.mark.parametrize("path", [*_USES, *(pytest.param(p, marks=pytest.mark.slow) for p in _SLOW_USES)])
def test_a_path_s_jobs_compile_what_its_first_use_needs(path):
    # In a fresh process (nothing compiled in it yet): the path's jobs, then a real use of the
    # feature; the use must add no kernel signature the jobs did not (or its first use compiles).
    use = {**_USES, **_SLOW_USES}[path]
    code = f"""
import sys
sys.path.insert(0, {str(ROOT)!r})
from tests.core.test_warmup import _kernel_signatures, SKY
import skyfix
from skyfix import _warm_jobs, warmup
from skyfix.detect import extract_centroids
from skyfix.io import read_image
for job in warmup._with_needs(warmup.PATHS["solve"] + warmup.PATHS[{path!r}]):
    getattr(_warm_jobs, job.replace("-", "_"))()
IMG = read_image(SKY)
sol = skyfix.solve(SKY)  # a solve's kernels are warm before any other path's first use
CAM, FOV, HINT = sol.camera, sol.fov_deg, sol.A_icrs_to_cam
before = _kernel_signatures()
{use}
after = _kernel_signatures()
new = {{k: sorted(v - before.get(k, set())) for k, v in after.items() if v - before.get(k, set())}}
print("NEW", new)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=1800,
                         env={**os.environ, "PYTHONPATH": str(ROOT / "src"), "SKYFIX_WARMUP": "0"})
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "NEW {}", out.stdout[-3000:]


def test_warmup_command_lists_paths_and_refuses_unknown_ones():
    from typer.testing import CliRunner

    from skyfix.cli import app

    runner = CliRunner()
    listed = runner.invoke(app, ["warmup", "--list"])
    assert listed.exit_code == 0, listed.output
    lines = listed.stdout.splitlines()
    assert [ln.split()[0] for ln in lines] == list(warmup.PATHS)
    assert all(ln.split(None, 1)[1] == "compiled" or "to compile: about" in ln for ln in lines)
    assert lines[0].split(None, 1)[1] == "compiled"  # the session compiled the solve's kernels first
    bad = runner.invoke(app, ["warmup", "solve", "bogus"])
    assert bad.exit_code == 2
    assert bad.stderr.startswith("skyfix: error: unknown warm-up path 'bogus'; choose one of solve, ")
    done = runner.invoke(app, ["warmup", "solve"])
    assert done.exit_code == 0 and done.stdout == "skyfix: 1 path(s) compiled already\n"
