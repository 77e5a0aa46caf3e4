"""Compile skyfix's kernels ahead of time into extension modules (issue 22: start-up).

``skyfix warmup`` calls :func:`build`: every kernel skyfix calls from Python, for every
signature it calls it with (the list :data:`SIGNATURES`, recorded by :func:`record`), is
compiled by numba's ahead-of-time compiler (``numba.pycc``) into a few ordinary extension
modules, one an area (detection, identification, tracking, simulation, the rest), built in
parallel processes. :mod:`skyfix._jit` calls them from then on: a process whose kernels are all
there never imports numba, so a ``skyfix solve`` starts in a fraction of a second and no
feature's first use compiles.

The exports are the kernels themselves: each is a one-line function that calls the kernel, so
numba compiles the kernel with its own options (``fastmath``, ``error_model``, ``inline``) for
this machine's CPU, as its just-in-time compiler would. The modules hold the digest of the
sources they were built from (:func:`skyfix._kernels.kernels_digest`): after any change to a
kernel they are not used until the next ``skyfix warmup``.

Needs a C compiler (``cc``) to link; without one :func:`build` fails with that reason and
numba compiles each kernel on first use as before.

Recording: ``python -m skyfix.aot record`` runs every warm-up job (:mod:`skyfix._warm_jobs`)
and a solve of the bundled frames with numba, and writes the signatures each kernel was called
with from Python to :data:`SIGNATURES` (a file in the repository, reviewed like code).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

from skyfix import _jit

__all__ = ["AREAS", "CPU_S", "SIGNATURES", "area_of", "build", "decode", "encode", "estimate_s",
           "folder_text", "is_built", "record"]

SIGNATURES = Path(__file__).resolve().parent / "data" / "aot_signatures.json"

AREAS = ("detect", "identify", "track", "simulate", "core")


def area_of(kernel_key: str) -> str:
    """The module (of :data:`AREAS`) a kernel is compiled into: by its package."""
    parts = kernel_key.split(":")[0].split(".")
    return parts[1] if len(parts) > 2 and parts[1] in AREAS else "core"


# ---- numba types <-> the recorded text (the grammar is in skyfix._jit) ---------------------------

class Unsupported(Exception):
    """A type the exports cannot take (such a signature stays with numba's dispatcher)."""


def encode(t: Any) -> Any:
    """numba type → the recorded form (:func:`skyfix._jit.guard_source` reads it)."""
    from numba.core import types
    from numba.np.numpy_support import as_dtype

    if isinstance(t, types.Array):
        dt = as_dtype(t.dtype)
        return {"array": [list(f) for f in dt.descr] if dt.names else dt.str, "ndim": t.ndim,
                "layout": t.layout, "readonly": not t.mutable, "aligned": bool(t.aligned)}
    if isinstance(t, types.BaseNamedTuple):
        cls = t.instance_class
        return {"tuple": [encode(x) for x in t.types], "class": f"{cls.__module__}:{cls.__qualname__}"}
    if isinstance(t, types.BaseTuple):
        return {"tuple": [encode(x) for x in t.types]}
    if t == types.none:
        return "none"
    if isinstance(t, (types.Integer, types.Float, types.Boolean)) and not isinstance(t, types.Literal):
        return str(t)
    raise Unsupported(str(t))


def decode(d: Any) -> Any:
    """The recorded form → numba type."""
    import numba
    import numpy as np
    from numba.core import types

    if d == "none":
        return types.none
    if isinstance(d, str):
        return types.boolean if d == "bool" else getattr(types, d)
    if "array" in d:
        raw = d["array"]
        dtype = np.dtype([tuple(f) for f in raw] if isinstance(raw, list) else raw)
        return types.Array(numba.from_dtype(dtype), d["ndim"], d["layout"], readonly=d["readonly"],
                           aligned=d["aligned"])
    parts = [decode(x) for x in d["tuple"]]
    if "class" in d:
        cls = _jit.named(d["class"])
        if parts and all(p == parts[0] for p in parts):
            return types.NamedUniTuple(parts[0], len(parts), cls)
        return types.NamedTuple(parts, cls)
    return types.Tuple(parts)


# ---- recording --------------------------------------------------------------------------------

def recorded_here() -> dict[str, list[dict[str, Any]]]:
    """The signatures each kernel was called with from Python in this process (numba's)."""
    out: dict[str, list[dict[str, Any]]] = {}
    for kernel in _jit.kernels():
        if not kernel.from_python or kernel.n_compiled == 0:
            continue
        for sig in kernel.signatures:
            try:
                entry = {"args": [encode(a) for a in sig],
                         "returns": encode(kernel.overloads[sig].signature.return_type)}
            except Unsupported:
                continue
            out.setdefault(kernel.key, []).append(entry)
    return out


def record(jobs: Iterable[str] | None = None, path: Path = SIGNATURES) -> int:
    """Run the warm-up jobs (default: all) and a solve of the bundled frame with numba in this
    process (no exports), and write the signatures recorded to ``path``. Returns their count."""
    os.environ["SKYFIX_AOT"] = "0"
    _jit.forget_modules()
    from skyfix import _warm_jobs, warmup

    names = list(jobs) if jobs is not None else sorted({j for p in warmup.PATHS.values() for j in p})
    for job in names:
        getattr(_warm_jobs, job.replace("-", "_"))()
    _solve_examples()
    _wide_search_order()
    _all_sky()
    found = recorded_here()
    old = json.loads(path.read_text()) if path.exists() and jobs is not None else {}
    for key, sigs in found.items():
        have = old.setdefault(key, [])
        have += [s for s in sigs if s not in have]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(dict(sorted(old.items())), indent=0, sort_keys=True) + "\n")
    return sum(len(v) for v in old.values())


def _solve_examples() -> None:
    """The bundled frames as the README solves them, with and without a camera; the first also
    as an 8-bit JPEG (a photograph's path: no camera, a distorted-frame search order), as a
    colour PNG, and with a time and an observer's velocity (the corrections' path)."""
    import numpy as np
    from PIL import Image

    import skyfix
    from skyfix.io import read_image

    examples = Path(__file__).resolve().parents[2] / "examples"
    frames = [p for p in sorted(examples.glob("*"))
              if p.suffix.lower() in {".png", ".fits", ".fit", ".jpg", ".jpeg", ".tif", ".tiff"}]
    with tempfile.TemporaryDirectory(prefix="skyfix-record-") as tmp:
        if frames:
            a = read_image(frames[0]).astype(np.float64)
            lo, top = np.median(a), np.percentile(a, 99.9)
            jpeg = Path(tmp) / "frame.jpg"
            grey = Image.fromarray(np.clip((a - lo) / max(top - lo, 1.0) * 230 + 20, 0, 255).astype(np.uint8))
            grey.save(jpeg, quality=92)
            colour = Path(tmp) / "frame-rgb.png"  # a colour PNG: the reader's RGB rows
            grey.convert("RGB").save(colour)
            frames += [jpeg, colour]
        for path in frames:
            try:
                sol = skyfix.solve(path)
            except Exception:  # noqa: BLE001 - recording only: a frame that cannot be read adds nothing
                continue
            if sol.solved:
                skyfix.solve(path, camera=sol.camera)
        if frames:  # a time and a velocity: proper motion and the per-star corrections' kernels
            skyfix.solve(frames[0], time="2026-06-01T00:00:00", observer="7.0,0.5,-1.0")


def _all_sky() -> None:
    """Frames of the all-sky campaign (each of its lenses), solved with no camera and with the
    true one."""
    import skyfix
    from skyfix.analysis.allsky_campaign import LENSES, allsky_frame

    lenses: set[str] = set()
    for seed in range(40):
        if len(lenses) == len(LENSES):
            break
        frame, camera, lens = allsky_frame(seed)
        if lens in lenses and seed >= 3:
            continue
        lenses.add(lens)
        skyfix.solve(frame.image)
        skyfix.solve(frame.image, camera=camera)


def _wide_search_order() -> None:
    """The wide searches' pattern order (a 45–90° frame's, or a photograph's whose first band
    failed): its kernel, called as the search calls it."""
    import numpy as np

    from skyfix.identify.common.search import centre_first_combinations

    centre_first_combinations(np.arange(12) % 3 == 0, 64)


# ---- building ---------------------------------------------------------------------------------

#: CPU seconds each area's module took to compile here (2-core machine, skyfix warmup), for the
#: notice's estimate
CPU_S = {"identify": 100.0, "detect": 95.0, "track": 75.0, "core": 55.0, "simulate": 10.0}


def estimate_s(workers: int) -> float:
    """Wall seconds :func:`build` takes on ``workers`` cores: the areas, longest first, each on
    the first core free."""
    free = [0.0] * max(1, workers)
    for cpu in sorted(CPU_S.values(), reverse=True):
        free[free.index(min(free))] += cpu
    return max(free)


def folder_text() -> str:
    """Where the modules are, for a message."""
    return str(_jit.aot_folder())


def is_built() -> bool:
    """Whether compiled modules that match these sources are in place."""
    return bool(_jit.aot_modules())


def build(*, workers: int | None = None, on_area: Callable[[str, float], None] | None = None,
          alongside: Callable[[], object] | None = None, folder: Path | None = None,
          only: Iterable[str] | None = None) -> dict[str, float]:
    """Compile every recorded signature (``only``: of these kernels, ``module:qualname``) into one
    module an area, ``workers`` processes at once (default: every CPU), and write the index
    :mod:`skyfix._jit` reads (into ``folder``, default :func:`skyfix._jit.aot_folder`).
    ``on_area(area, cpu_s)`` is called as each module is done; ``alongside`` runs in this process
    while they compile. Returns each area's CPU seconds. Raises RuntimeError with the reason when
    a module cannot be built (no C compiler, a compile error)."""
    from skyfix._kernels import kernels_digest
    from skyfix.warmup import default_workers

    compiler = (sysconfig.get_config_var("CC") or "cc").split()[0]
    if shutil.which(compiler) is None:
        raise RuntimeError(f"no C compiler ({compiler}) to link the compiled kernels; "
                           "numba compiles them on first use")
    signatures = json.loads(SIGNATURES.read_text())
    if only is not None:
        keep = set(only)
        signatures = {k: v for k, v in signatures.items() if k in keep}
    folder = folder or _jit.aot_folder()
    folder.mkdir(parents=True, exist_ok=True)
    digest = kernels_digest()
    areas = sorted({area_of(k) for k in signatures}, key=lambda a: -sum(
        len(v) for k, v in signatures.items() if area_of(k) == a))
    n = max(1, min(workers or default_workers(), len(areas)))
    running: dict[str, tuple[subprocess.Popen, Path]] = {}
    todo = list(areas)
    exports: list[dict[str, Any]] = []
    cpu: dict[str, float] = {}
    (folder / _jit.INDEX).unlink(missing_ok=True)
    with tempfile.TemporaryDirectory(prefix="skyfix-aot-") as tmp:
        selected = Path(tmp) / "signatures.json"
        selected.write_text(json.dumps(signatures))
        while todo or running:
            while todo and len(running) < n:
                area = todo.pop(0)
                out = Path(tmp) / f"{area}.json"
                env = {**os.environ, "NUMBA_CACHE_DIR": str(Path(tmp) / f"numba-{area}"), "SKYFIX_AOT": "0"}
                proc = subprocess.Popen([sys.executable, "-m", "skyfix.aot", "build-area", area, str(folder),
                                         str(out), str(selected)],
                                        env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                        stderr=subprocess.STDOUT, text=True)
                running[area] = (proc, out)
            if alongside is not None:
                alongside()
                alongside = None
            time.sleep(0.2)
            for area, (proc, out) in list(running.items()):
                if proc.poll() is None:
                    continue
                del running[area]
                log = proc.stdout.read() if proc.stdout else ""
                if proc.returncode != 0:
                    for other, _ in running.values():
                        other.kill()
                    last = [line for line in log.strip().splitlines() if line.strip()][-1:] or ["no output"]
                    raise RuntimeError(f"compiling the {area} kernels failed: {last[0]}")
                done = json.loads(out.read_text())
                exports += done["exports"]
                cpu[area] = done["cpu_s"]
                if on_area:
                    on_area(area, cpu[area])
    if kernels_digest() != digest:
        raise RuntimeError("the sources changed while compiling; run it again")
    (folder / f"{_jit.GUARDS}.py").write_text(_jit.guards_module_source(exports))
    index = {"digest": digest, "python": sys.implementation.cache_tag, "cpu": _jit.cpu_tag(),
             "exports": exports}
    tmp_index = folder / (_jit.INDEX + ".tmp")
    tmp_index.write_text(json.dumps(index))
    tmp_index.replace(folder / _jit.INDEX)
    _jit.forget_modules()
    return cpu


UNPICKLE_SOURCE = Path(__file__).resolve().parent / "_aot_unpickle.c"


def _memoise_unpickling(cc: Any) -> None:
    """Link ``_aot_unpickle.c`` into the module ``cc`` builds and point its compiled code's
    unpickling at it (this build process only): an array a kernel returns then costs what it
    costs under numba's JIT, not ~1 µs more (the C file says why). The JIT compilations of this
    process keep numba's own function."""
    from llvmlite import ir
    from numba.core import pythonapi

    def unserialize(self: Any, structptr: Any) -> Any:  # numba's PythonAPI.unserialize, renamed
        fnty = ir.FunctionType(self.pyobj, (self.voidptr, ir.IntType(32), self.voidptr))
        name = "skyfix_unpickle" if self.context.aot_mode else "numba_unpickle"
        fn = self._get_function(fnty, name=name)
        struct = self.builder.load(structptr)
        ptr, n, hashed = (self.builder.extract_value(struct, k) for k in range(3))
        return self.builder.call(fn, (ptr, n, hashed))

    pythonapi.PythonAPI.unserialize = unserialize
    cc._mixin_sources = [*cc._mixin_sources, str(UNPICKLE_SOURCE)]  # joined to pycc's folder: absolute stays


def _build_area(area: str, folder: Path, out: Path, signature_file: Path) -> None:
    """In a process of its own: compile one area's module of the signatures in
    ``signature_file`` into ``folder``, and list its exports and CPU seconds in ``out``."""
    import importlib

    from numba.core import types  # noqa: F401 - numba's types before the signatures are decoded
    from numba.pycc import CC

    import skyfix  # noqa: F401 - the kernel-cache check, as at any start

    signatures = json.loads(signature_file.read_text())
    module_name = f"_skyfix_aot_{area}"
    cc = CC(module_name)
    _memoise_unpickling(cc)
    cc.output_dir = str(folder)
    cc.target_cpu = "host"
    cc.verbose = False
    exports = []
    for key, sigs in sorted(signatures.items()):
        if area_of(key) != area:
            continue
        kernel = _jit.named(key)
        if not isinstance(kernel, _jit.Kernel):
            continue
        importlib.import_module(kernel.py_func.__module__)
        for i, sig in enumerate(sigs):
            try:
                args = [decode(a) for a in sig["args"]]
                returns = decode(sig["returns"])
            except (AttributeError, ImportError, TypeError, ValueError):
                continue  # a type that no longer exists: that call stays with numba
            name = f"k{len(exports)}"
            arg_names = ", ".join(f"a{j}" for j in range(len(args)))
            namespace = {"K": kernel}
            exec(f"def {name}({arg_names}):\n    return K({arg_names})\n", namespace)  # noqa: S102
            namespace[name].release_gil = bool(kernel.options.get("nogil"))
            cc.export(name, returns(*args))(namespace[name])
            exports.append({"kernel": key, "module": module_name, "name": name, "args": sig["args"],
                            "n": i})
    with _gil_released_for_nogil_kernels():
        cc.compile()
    out.write_text(json.dumps({"exports": exports, "cpu_s": time.process_time()}))


@contextlib.contextmanager
def _gil_released_for_nogil_kernels() -> Iterator[None]:
    """While it lasts, ``numba.pycc`` builds the CPython wrapper of an export whose function has
    ``release_gil`` set (a ``nogil=True`` kernel's, :func:`_build_area`) with the GIL released
    around the call, as numba's own dispatcher does for such a kernel; pycc compiles every
    export with numba's default flags, which hold it (so a kernel run on a helper thread,
    :mod:`skyfix.detect._threads`, would run one thread at a time)."""
    from numba.pycc import compiler

    plain = compiler.compile_extra

    def compile_extra(typingctx: Any, targetctx: Any, func: Any, args: Any, return_type: Any, flags: Any,
                      *rest: Any, **kw: Any) -> Any:
        if getattr(func, "release_gil", False):
            flags = flags.copy()
            flags.release_gil = True
        return plain(typingctx, targetctx, func, args, return_type, flags, *rest, **kw)

    compiler.compile_extra = compile_extra
    try:
        yield
    finally:
        compiler.compile_extra = plain


def main(argv: list[str]) -> int:
    if argv[:1] == ["record"]:
        n = record()
        print(f"{n} signatures recorded in {SIGNATURES}")
        return 0
    if argv[:1] == ["build-area"] and len(argv) == 5:
        _build_area(argv[1], Path(argv[2]), Path(argv[3]), Path(argv[4]))
        return 0
    if argv[:1] == ["build"]:
        t0 = time.perf_counter()
        build(on_area=lambda a, s: print(f"{a}: {s:.0f} s CPU", flush=True))
        print(f"built in {time.perf_counter() - t0:.0f} s: {_jit.aot_folder()}")
        return 0
    print("usage: python -m skyfix.aot record | build", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
