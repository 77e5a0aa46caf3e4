"""A frame's work split between the calling thread and one helper thread (issue 22: both cores).

:func:`run_chunks` runs ``work(0) … work(n − 1)``: the calling thread and one helper thread
(started on first use, then kept) each take the next chunk nobody has taken until none is left.
The caller never waits for a chunk nobody has started: a helper that the machine has not
scheduled (on a shared 2-core machine it often is not) costs only the handing over, and the
caller then runs every chunk itself; it waits only for a chunk the helper is in the middle of.
The chunks are kernels that release the GIL (numba's ``nogil=True``; :mod:`skyfix.aot` builds
their ahead-of-time exports with the GIL released too), each writing its own part of the shared
arrays, so the result does not depend on which thread ran which chunk.

Threads compute no faster than the scheduler lets them: the split pays when the second core is
idle, and costs when it is not (Linux shares the CPU between sessions, not threads: on a 2-core
machine busy with other work the two threads take turns on the session's share, measured 5–20 %
slower than one thread). So each split call measures what it got — the chunks' CPU time over
the call's wall time — and after a call that ran less than 1.3 chunks at once the next calls run
in the calling thread, 1, 2, 4 … up to 64 of them, before the helper is tried again.

A process with one CPU, or ``SKYFIX_THREADS=1`` in the environment, runs every chunk in the
calling thread.
"""

from __future__ import annotations

import functools
import os
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

__all__ = ["bands", "run_chunks", "split", "threads_enabled"]

#: Chunks a stage is cut into at most: one for each thread (more cost a kernel call each, ~5–50 µs
#: from Python, and gain nothing when the helper is not scheduled).
MAX_CHUNKS = 2

_QUEUE: queue.SimpleQueue | None = None
_START = threading.Lock()
#: Below this many chunks at once (CPU time over wall time) a split call did not pay.
_PAYS = 1.3
_MAX_BACKOFF = 64


class _Pace:
    """How many calls to run in the caller before trying the helper again, and the next such wait."""

    skip = 0
    backoff = 0


_PACE = _Pace()


def threads_enabled() -> bool:
    """Whether :func:`run_chunks` hands chunks to the helper thread."""
    return os.environ.get("SKYFIX_THREADS", "") != "1" and _cpus() > 1


@functools.cache
def _cpus() -> int:
    """The CPUs this process may run on (as it started)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def split(n: int, least: int) -> list[int]:
    """The edges of the chunks a stage of ``n`` units (rows, tiles) is cut into: one chunk a
    thread, each of ``least`` units or more (one chunk when the helper is not used)."""
    return bands(n, min(MAX_CHUNKS, n // max(1, least)) if threads_enabled() else 1)


def bands(n: int, parts: int) -> list[int]:
    """``parts`` near-equal ranges over ``0..n`` (fewer when ``n`` is smaller): their edges."""
    parts = max(1, min(parts, n))
    return [round(i * n / parts) for i in range(parts + 1)]


class _Job:
    """One :func:`run_chunks` call: the chunks taken so far, those running in the helper."""

    def __init__(self, work: Callable[[int], Any], n: int) -> None:
        self.work = work
        self.n = n
        self.taken = 0
        self.helper_busy = 0
        self.results: list[Any] = [None] * n
        self.error: BaseException | None = None
        self.cpu = 0.0  # the chunks' CPU seconds
        self.lock = threading.Lock()
        self.helper_idle = threading.Event()


def _take(job: _Job, helper: bool) -> None:
    """Run chunks of ``job`` until none is left untaken."""
    while True:
        with job.lock:
            i = job.taken
            if i >= job.n or job.error is not None:
                return
            job.taken = i + 1
            job.helper_busy += helper
        cpu = time.thread_time()
        try:
            job.results[i] = job.work(i)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller, which raises it
            job.error = exc
        finally:
            with job.lock:
                job.cpu += time.thread_time() - cpu
                if helper:
                    job.helper_busy -= 1
                    if job.helper_busy == 0 and (job.taken >= job.n or job.error is not None):
                        job.helper_idle.set()


def _serve(jobs: queue.SimpleQueue) -> None:
    while True:
        _take(jobs.get(), helper=True)


def _helper() -> queue.SimpleQueue:
    global _QUEUE
    with _START:
        if _QUEUE is None:
            jobs: queue.SimpleQueue = queue.SimpleQueue()
            threading.Thread(target=_serve, args=(jobs,), name="skyfix-helper", daemon=True).start()
            _QUEUE = jobs
        return _QUEUE


def _forget_helper() -> None:  # a forked child has no helper thread: start its own if it needs one
    global _QUEUE
    _QUEUE = None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_helper)


def run_chunks(work: Callable[[int], Any], n: int) -> list[Any]:
    """``[work(0), …, work(n − 1)]``, the chunks shared with the helper thread (module docstring).

    Raises what a chunk raised (the chunks not yet started are then skipped).
    """
    if n <= 1 or not threads_enabled():
        return [work(i) for i in range(n)]
    if _PACE.skip > 0:
        _PACE.skip -= 1
        return [work(i) for i in range(n)]
    job = _Job(work, n)
    start = time.perf_counter()
    _helper().put(job)
    _take(job, helper=False)
    with job.lock:
        busy = job.helper_busy
    if busy:
        job.helper_idle.wait()
    if job.error is not None:
        raise job.error
    if job.cpu < _PAYS * (time.perf_counter() - start):
        _PACE.backoff = min(_MAX_BACKOFF, 2 * _PACE.backoff or 1)
        _PACE.skip = _PACE.backoff
    else:
        _PACE.backoff = 0
    return job.results
