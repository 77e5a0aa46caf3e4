"""numba's on-disk cache checks only a kernel's own file: a cached kernel that inlined a helper
from another file (``@njit(inline="always")``) keeps the old helper after it changes — with
numba 0.68, editing ``lens.distort_jacobian`` left ``camera_jacobian.jacobian_rows`` loading its
stale compiled code from the cache. skyfix's dependency digests
(:func:`skyfix._kernels.drop_stale_kernel_caches`, run when skyfix is imported) drops the
cached kernels of every file that depends on a changed source, and only those.

A copy of the package is run in fresh processes; between runs the helper is edited (its
distorted x doubled). The second run must see the edit although ``camera_jacobian.py`` is unchanged
and its compiled kernel is on disk.
"""

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

import skyfix

SCRIPT = """
import numpy as np
from skyfix._kernels import camera_jacobian, lens
from skyfix.camera import Camera
cam = Camera.from_fov(640, 480, 20.0)
rays = cam.pixel_to_ray(np.array([[100.0, 200.0], [500.0, 50.0]]))
J, res = camera_jacobian.jacobian_rows(np.zeros((2, 2)), rays, lens.camera_numbers(cam), 1.0,
                                       np.array([camera_jacobian.F], dtype=np.int64))
print(repr((res[:, 0] - cam.cx).tolist()))
"""


def _run(pkg: Path) -> list[float]:
    out = subprocess.run([sys.executable, "-c", SCRIPT], cwd=pkg.parent, capture_output=True, text=True,
                         env={"PYTHONPATH": str(pkg.parent), "PATH": "/usr/bin:/bin", "SKYFIX_AOT": "0"},
                         timeout=600)  # numba's cache is what is tested, not the ahead-of-time exports
    assert out.returncode == 0, out.stderr[-2000:]
    return eval(out.stdout.strip().splitlines()[-1])


def test_an_edited_inlined_helper_is_seen_by_a_cached_kernel_in_another_file(tmp_path):
    pkg = tmp_path / "skyfix"
    shutil.copytree(Path(skyfix.__file__).parent, pkg, ignore=shutil.ignore_patterns("__pycache__", "_aot"))
    before = _run(pkg)
    cached = sorted(pkg.rglob("camera_jacobian.jacobian_rows*.nb[ic]"))
    assert cached, "the kernel was not cached"
    stamps = [f.stat().st_mtime_ns for f in cached]
    # An edit to a file no kernel depends on (a command) keeps the compiled kernel.
    command = pkg / "cli" / "solve.py"
    command.write_text(command.read_text() + "\n# edited\n")
    assert _run(pkg) == before
    assert [f.stat().st_mtime_ns for f in cached] == stamps
    lens_py = pkg / "_kernels" / "lens.py"
    text = lens_py.read_text()
    old = "    return xd, yd, dxx, dxy, dxy, dyy, r2"
    assert old in text
    lens_py.write_text(text.replace(old, "    return 2.0 * xd, yd, dxx, dxy, dxy, dyy, r2"))
    after = _run(pkg)
    np.testing.assert_allclose(after, 2.0 * np.array(before), rtol=1e-12)
    assert _run(pkg) == after  # and the fresh cache serves the next run
