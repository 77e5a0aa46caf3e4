"""Compiling skyfix's numba kernels before their first use: once, on every core, saying so.

skyfix's inner loops are numba kernels: compiled to machine code the first time they run, then
cached on disk (numba's cache: beside the package's sources, or numba's user cache folder for a
read-only install) and loaded in milliseconds. Compiling is the one slow step of a first run —
about a minute and a half of CPU for the kernels of one solve — so it is done here, up front,
in parallel, and announced with the time it will take:

- A **job** (:class:`Job`) runs one stage on a small synthetic input (:mod:`skyfix._warm_jobs`),
  which compiles every kernel the stage runs on real data. Jobs run in worker processes
  (``python -m skyfix._warm_worker JOB``), as many at once as there are cores, each reporting
  its progress to the process that started it.
- A **path** (:data:`PATHS`) is what one use of skyfix needs: ``"solve"`` is the extraction,
  the 4-star identification and the final fit; the attitude hint, the tracker, each
  centroider, identification method and detector have paths of their own.
- :func:`ensure` is called where a path starts (:func:`skyfix.solve`, the tracker, …): if the
  path is not warm it is compiled now, with a notice of what is happening and for how long (a
  progress bar on a terminal, a line before and after on a pipe); a warm path costs a dict
  lookup. ``skyfix warmup`` (:func:`warm`) compiles every path in one announced step.

A path is warm once its jobs have all run to the end since the package's sources last changed
(a stamp beside numba's cache, :func:`is_warm`). ``SKYFIX_WARMUP=0`` turns the up-front compile
off: kernels then compile one by one on first use, in the calling process.
"""

from __future__ import annotations

import json
import logging
import math
import os
import selectors
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import NamedTuple

from skyfix._kernels import kernel_cache_folder, kernels_digest
from skyfix.errors import unknown_name

__all__ = ["JOBS", "PATHS", "Job", "default_workers", "ensure", "estimate_s", "is_warm", "pending", "warm"]

log = logging.getLogger(__name__)


class Job(NamedTuple):
    """One worker's share of a path: a function of :mod:`skyfix._warm_jobs` that runs a stage on
    a synthetic input, and what it costs."""

    name: str
    what: str  #: what it compiles, for the notice ("the extraction")
    #: CPU seconds to compile, beyond its needs, measured on a 2-core 2026 x86 machine (a guide for
    #: the ETA; the jobs beyond the solve path with the solve path compiled)
    cpu_s: float
    needs: tuple[str, ...] = ()  #: jobs whose kernels this one's stage also runs: they compile first


#: Every job by name (:mod:`skyfix._warm_jobs` defines a function of each name, ``-`` as ``_``).
JOBS: dict[str, Job] = {job.name: job for job in (
    Job("extract", "star extraction", 41.0),
    Job("identify", "lost-in-space identification", 42.0),
    Job("final-fit", "the final fit", 50.0),
    Job("attitude", "the attitude solvers", 3.5),
    Job("hint", "identification near an attitude hint", 18.0, ("identify", "final-fit")),
    Job("centroiders", "the windowed centroiders", 13.0, ("extract",)),
    Job("detector-threshold_hillclimb", "the threshold_hillclimb detector", 3.2, ("extract",)),
    Job("detector-region_grow", "the region_grow detector", 3.2, ("extract",)),
    Job("detector-regionprops", "the regionprops detector", 1.7, ("extract",)),
    Job("method-triangle", "the triangle method", 7.7, ("identify",)),
    Job("method-liebe", "the liebe method", 16.4, ("identify",)),
    Job("method-planar", "the planar method", 15.7, ("identify",)),
    Job("method-area-moment", "the area-moment method", 17.0, ("identify",)),
    Job("method-pyramid", "the pyramid method", 15.2, ("identify",)),
    Job("method-grid", "the grid method", 20.2, ("identify",)),
    Job("method-voting", "the voting method", 8.4, ("identify",)),
    Job("method-van-bezooijen", "the van-bezooijen method", 16.2, ("identify",)),
    Job("streaks", "the streak fit", 28.0),
    Job("track", "the tracker", 46.0, ("extract", "identify", "final-fit", "centroiders", "streaks")),
    Job("simulate", "the simulator", 5.6),
)}

#: Paths by name: the jobs whose kernels one use of skyfix needs. ``solve`` is the default solve;
#: the others are what a first use of a feature adds to it.
PATHS: dict[str, tuple[str, ...]] = {
    "solve": ("extract", "identify", "final-fit"),
    "attitude": ("attitude",),
    "hint": ("hint",),
    "centroiders": ("centroiders",),
    **{f"detector-{d}": (f"detector-{d}",) for d in ("threshold_hillclimb", "region_grow", "regionprops")},
    **{f"method-{m}": (f"method-{m}",) for m in ("triangle", "liebe", "planar", "area-moment", "pyramid",
                                                   "grid", "voting", "van-bezooijen")},
    "streaks": ("streaks",),
    "track": ("track",),
    "simulate": ("simulate",),
}

_ENV = "SKYFIX_WARMUP"
_WORKER_ENV = "SKYFIX_WARM_WORKER"
_STAMP = "skyfix_warm.json"
_warm_here: set[str] = set()  # paths this process has seen warm (no second look)


def is_warm(path: str) -> bool:
    """Whether every job of ``path`` has run to the end since skyfix's sources last changed
    (with this numba and Python), or every kernel is compiled ahead of time (:mod:`skyfix.aot`)."""
    from skyfix._jit import aot_modules

    if path in _warm_here or aot_modules():
        return True
    stamp = _read_stamp()
    done = stamp.get("jobs", {}) if stamp.get("key") == _stamp_key() else {}
    if all(done.get(job) for job in _with_needs(PATHS[path])):
        _warm_here.add(path)
        return True
    return False


def estimate_s(jobs: Sequence[str], workers: int) -> float:
    """Wall seconds to compile ``jobs`` on ``workers`` cores: their measured CPU seconds
    (:attr:`Job.cpu_s`) plus a second to start each worker, scheduled as :func:`_next_job`
    picks them (longest first among those whose needs are compiled)."""
    todo = list(jobs)
    free = [0.0] * max(workers, 1)  # when each worker is next free
    finish: dict[str, float] = {}
    while todo:
        i = free.index(min(free))
        now = free[i]
        job = _next_job(todo, lambda j, now=now: finish.get(j, math.inf) <= now or j not in jobs)
        if job is None:  # wait for the running job a need is waiting on
            free[i] = min((t for t in finish.values() if t > now), default=now + 1.0)
            continue
        todo.remove(job)
        free[i] += JOBS[job].cpu_s + 1.0
        finish[job] = free[i]
    return max(finish.values(), default=0.0)


def _next_job(todo: Sequence[str], ready: Callable[[str], bool]) -> str | None:
    """Of the jobs ``todo``, the costliest whose needs are all ``ready`` (None: none is)."""
    for job in sorted(todo, key=lambda j: -JOBS[j].cpu_s):
        if all(ready(n) for n in JOBS[job].needs):
            return job
    return None


def _with_needs(jobs: Iterable[str]) -> list[str]:
    """``jobs`` and, before them, the jobs they need (transitively), each once."""
    out: list[str] = []

    def add(job: str) -> None:
        if job not in out:
            for need in JOBS[job].needs:
                add(need)
            out.append(job)

    for job in jobs:
        add(job)
    return out


def ensure(path: str | Iterable[str], *, alongside: Callable[[], object] | None = None, also: str = "",
           missing_ok: bool = False) -> None:
    """Make sure the kernels of ``path`` (:data:`PATHS`; or of several paths) are compiled
    before they are needed.

    A warm path returns at once. Otherwise its jobs compile in worker processes, with a notice
    on stderr of what is compiling and for how long, while this process runs ``alongside`` (the
    pattern database's first build, say; ``also`` says what it does, for the notice: "building
    the pattern database"). With ``SKYFIX_WARMUP=0``, inside a worker, or when workers cannot be
    started, nothing is compiled up front (the kernels compile in this process on first use) and
    ``alongside`` still runs. A path of no name in :data:`PATHS` is an error, or with
    ``missing_ok`` nothing to do (a method registered by a user has no warm-up of its own).
    """
    names = [path] if isinstance(path, str) else list(path)
    unknown = [p for p in names if p not in PATHS]
    if unknown and not missing_ok:
        raise unknown_name("warm-up path", unknown[0], PATHS)
    if not pending([p for p in names if p in PATHS]):
        if alongside is not None:
            alongside()
        return
    warm([p for p in names if p in PATHS], alongside=alongside, also=also, first_use=True)


def pending(paths: Iterable[str]) -> list[str]:
    """The jobs :func:`ensure` would compile for ``paths`` now: none when they are warm, or when
    compiling up front is off (``SKYFIX_WARMUP=0``, inside a worker), or when every kernel is
    compiled ahead of time (:mod:`skyfix.aot`)."""
    names = [p for p in paths if not is_warm(p)]
    if not names or not _enabled():
        return []
    done = _done_jobs()
    return [j for j in _with_needs(j for p in names for j in PATHS[p]) if not done.get(j)]


def warm(paths: Iterable[str] | None = None, *, workers: int | None = None,
         alongside: Callable[[], object] | None = None, also: str = "", first_use: bool = False,
         console=None) -> dict[str, float]:
    """Compile the kernels of ``paths`` (default: every path), their jobs in parallel worker
    processes, showing progress on stderr. Returns the CPU seconds each job took (jobs already
    warm are skipped; a job that failed is left out and logged: its kernels then compile on
    first use).

    ``workers``: processes at once (default: the CPUs this process may use).
    ``alongside``: run in this process while the workers compile (``also``: what it does).
    ``first_use``: the notice says this is a first use (the solve waits for it).
    """
    names = list(PATHS) if paths is None else list(paths)
    for p in names:
        if p not in PATHS:
            raise unknown_name("warm-up path", p, PATHS)
    done = _done_jobs()
    jobs = [j for j in _with_needs(j for p in names if not is_warm(p) for j in PATHS[p]) if not done.get(j)]
    if not jobs:
        if alongside is not None:
            alongside()
        return {}
    from skyfix.cache import exclusive_lock

    stamp_file = _stamp_file()
    with exclusive_lock(stamp_file, lambda: log.info("waiting for another skyfix process to compile")):
        done = _done_jobs()
        jobs = [j for j in jobs if j not in done]  # another process may have compiled them meanwhile
        if not jobs:
            if alongside is not None:
                alongside()
            return {}
        n = workers or default_workers()
        runner = _Runner(jobs, n, _describe(jobs, first_use, also), console)
        results = runner.run(alongside)
        done = _done_jobs()
        done.update({j: True for j in results})
        _write_stamp(stamp_file, done)
    for p in names:
        _warm_here.discard(p)
        is_warm(p)
    return results


# --- the workers and the notice -------------------------------------------------------------------

class _Runner:
    """Runs jobs in worker processes, ``n`` at once, longest first, and shows their progress."""

    def __init__(self, jobs: list[str], n: int, title: str, console) -> None:
        self.todo = list(jobs)
        self.finished: set[str] = set()  # succeeded or failed: the jobs that need them may start
        self.n = max(1, min(n, len(jobs)))
        self.title = title
        self.console = console
        self.cpu = dict.fromkeys(jobs, 0.0)  # CPU seconds each job has used so far
        self.results: dict[str, float] = {}
        self.failed: dict[str, str] = {}
        self.total = sum(JOBS[j].cpu_s for j in jobs)

    def run(self, alongside: Callable[[], object] | None) -> dict[str, float]:
        t0 = time.perf_counter()
        display = _Display(self.title, estimate_s(self.todo, self.n), self.console)
        reader = threading.Thread(target=self._drive, args=(display,), daemon=True)
        display.start()
        reader.start()
        try:
            if alongside is not None:
                alongside()
            reader.join()
        finally:
            display.stop(time.perf_counter() - t0, self.failed)
        for job, why in self.failed.items():
            log.warning("compiling %s ahead of use failed (%s): its kernels compile on first use",
                        JOBS[job].what, why)
        return self.results

    def _fraction(self) -> float:
        done = sum(min(self.cpu[j], JOBS[j].cpu_s) for j in self.cpu)
        return min(done / self.total, 0.99) if self.total else 0.0

    def _drive(self, display: _Display) -> None:
        sel = selectors.DefaultSelector()
        running: dict[int, tuple[str, subprocess.Popen]] = {}
        while self.todo or running:
            while self.todo and len(running) < self.n:
                job = _next_job(self.todo, lambda j: j in self.finished or j not in self.cpu)
                if job is None:
                    break  # the rest wait for what they need
                self.todo.remove(job)
                proc = _start_worker(job)
                if proc is None:
                    self.failed[job] = "could not start a worker process"
                    self.finished.add(job)
                    continue
                running[proc.stdout.fileno()] = (job, proc)
                sel.register(proc.stdout, selectors.EVENT_READ)
            if not running:
                break
            for key, _ in sel.select(timeout=0.5):
                job, proc = running[key.fd]
                line = proc.stdout.readline()
                if line:
                    self._line(job, line)
                    display.update(self._fraction())
                    continue
                sel.unregister(proc.stdout)
                del running[key.fd]
                proc.stdout.close()
                err = proc.stderr.read().strip()
                proc.stderr.close()
                if proc.wait() != 0 and job not in self.failed:
                    self.failed[job] = err.splitlines()[-1] if err else f"exit status {proc.returncode}"
                self.finished.add(job)
                display.update(self._fraction())
        sel.close()

    def _line(self, job: str, line: str) -> None:
        """A worker's report: ``cpu SECONDS`` as it compiles, ``done SECONDS`` at the end,
        ``failed MESSAGE`` on an error (:mod:`skyfix._warm_worker`)."""
        word, _, rest = line.strip().partition(" ")
        if word in ("cpu", "done"):
            try:
                self.cpu[job] = float(rest)
            except ValueError:
                return
            if word == "done":
                self.results[job] = self.cpu[job]
        elif word == "failed":
            self.failed[job] = rest


def _start_worker(job: str) -> subprocess.Popen | None:
    env = dict(os.environ, **{_WORKER_ENV: "1"})
    try:
        return subprocess.Popen([sys.executable, "-m", "skyfix._warm_worker", job], stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    except OSError as exc:
        log.info("cannot start a warm-up worker: %s", exc)
        return None


class _Display:
    """The notice of a compile: a progress bar on a terminal; on a pipe, a line when it starts
    and one when it ends (stderr either way)."""

    def __init__(self, title: str, eta_s: float, console) -> None:
        self.title, self.eta_s = title, eta_s
        self.console = console
        self.progress = None
        self.task = None

    def _console(self):
        if self.console is None:
            from rich.console import Console

            self.console = Console(stderr=True)
        return self.console

    def start(self) -> None:
        line = f"{self.title} (once; about {_duration(self.eta_s)} on {default_workers()} cores)…"
        if self.title.startswith("first use"):
            line += " (`skyfix warmup` compiles every kernel ahead of time instead, for fast starts)"
        log.info("%s", line)
        console = self._console()
        if not console.is_terminal:
            print(f"skyfix: {line}", file=sys.stderr, flush=True)
            return
        from rich.progress import BarColumn, Progress, TaskProgressColumn, TextColumn, TimeElapsedColumn

        self.progress = Progress(TextColumn("{task.description}"), BarColumn(), TaskProgressColumn(),
                                 TimeElapsedColumn(), console=console, transient=True)
        self.progress.start()
        self.task = self.progress.add_task(f"skyfix: {line}", total=1.0)

    def update(self, fraction: float) -> None:
        if self.progress is not None:
            self.progress.update(self.task, completed=fraction)

    def stop(self, elapsed_s: float, failed: dict[str, str]) -> None:
        if self.progress is not None:
            self.progress.stop()  # transient: the bar is gone before any result line
            self.progress = None
        end = f"compiled in {elapsed_s:.0f} s" + (f" ({len(failed)} job(s) failed: see -v)" if failed else "")
        log.info("%s", end)
        print(f"skyfix: {end}", file=sys.stderr, flush=True)


def _describe(jobs: list[str], first_use: bool, also: str) -> str:
    """The notice's words: what compiles (and what else happens meanwhile)."""
    what = [JOBS[j].what for j in jobs]
    listed = what[0] if len(what) == 1 else ", ".join(what[:-1]) + " and " + what[-1]
    text = f"compiling the kernels of {listed}"
    if also:
        text += f", {also}"
    return f"first use: {text}" if first_use else text


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{max(5, 5 * round(seconds / 5)):.0f} s"
    return f"{seconds / 60:.0f} min"


def default_workers() -> int:
    """Worker processes at once by default: the CPUs this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _enabled() -> bool:
    if os.environ.get(_WORKER_ENV):
        return False
    return os.environ.get(_ENV, "1").strip().lower() not in ("0", "off", "no", "false")


# --- the stamp ------------------------------------------------------------------------------------

def _stamp_key() -> str:
    """What the stamp holds for: these kernels (:func:`skyfix._kernels.kernels_digest`), these
    jobs (this file and :mod:`skyfix._warm_jobs`), this numba and its cache's format
    (:data:`skyfix._numba_cache.MARK`), this Python."""
    global _KEY
    if _KEY is None:
        import hashlib
        from importlib.metadata import version

        from skyfix._numba_cache import MARK

        here = Path(__file__)
        jobs = hashlib.sha256(here.read_bytes() + here.with_name("_warm_jobs.py").read_bytes()).hexdigest()
        _KEY = (f"{kernels_digest()} jobs {jobs[:16]} numba {version('numba')} {MARK} "
                f"python {sys.version_info[0]}.{sys.version_info[1]}")
    return _KEY


_KEY: str | None = None


def _stamp_file() -> Path:
    """Beside the package's kernel-cache stamp; in the user cache for a read-only install."""
    folder = kernel_cache_folder()
    if folder is None:
        from skyfix.cache import cache_dir

        folder = cache_dir()
    return folder / _STAMP


def _read_stamp() -> dict:
    try:
        return json.loads(_stamp_file().read_text())
    except (OSError, ValueError):
        return {}


def _done_jobs() -> dict[str, bool]:
    stamp = _read_stamp()
    return dict(stamp.get("jobs", {})) if stamp.get("key") == _stamp_key() else {}


def _write_stamp(path: Path, jobs: dict[str, bool]) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}")
    try:
        tmp.write_text(json.dumps({"key": _stamp_key(), "jobs": jobs}))
        os.replace(tmp, path)
    except OSError as exc:  # the compiled kernels are cached all the same
        log.info("cannot write %s: %s", path, exc)
