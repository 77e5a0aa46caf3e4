"""One warm-up job in a process of its own: ``python -m skyfix._warm_worker JOB``
(:mod:`skyfix.warmup` starts these).

Runs the job's function of :mod:`skyfix._warm_jobs`, which compiles its stage's kernels into
numba's on-disk cache, and reports on stdout, one line each: ``cpu SECONDS`` (the CPU time so
far) as kernels finish compiling, at most a few times a second; ``done SECONDS`` at the end; or
``failed MESSAGE`` (then exit status 1).
"""

from __future__ import annotations

import sys
import time


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("failed usage: python -m skyfix._warm_worker JOB", flush=True)
        return 2
    from numba.core import event

    last = [0.0]

    class Progress(event.Listener):
        def on_start(self, ev) -> None:
            pass

        def on_end(self, ev) -> None:
            now = time.perf_counter()
            if now - last[0] > 0.2:
                last[0] = now
                print(f"cpu {time.process_time():.2f}", flush=True)

    event.register("numba:compile", Progress())
    from skyfix import _warm_jobs

    try:
        getattr(_warm_jobs, argv[0].replace("-", "_"))()
    except Exception as exc:  # reported to the parent, which logs it: the kernels compile on first use
        text = str(exc).strip().splitlines()
        print(f"failed {type(exc).__name__}: {text[0] if text else ''}", flush=True)
        return 1
    print(f"done {time.process_time():.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
