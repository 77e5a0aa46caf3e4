"""skyfix in a worker process: one per side of ``benchmarks/run --against REF``.

The driver (``run_all.py``) makes the inputs once and hands the same ones to both sides; each
side's skyfix runs in its own process (``benchmarks/worker.py`` with that side's ``src`` first on
``PYTHONPATH``), which times every call itself, so the pipe costs nothing in the figures. The
harness (this file, ``worker.py``, ``skyfix_adapter.py`` and the suites) is the working tree's on
both sides: only skyfix changes.

Protocol: length-prefixed pickles over the worker's stdin / stdout (the worker points its own
stdout at stderr, so nothing skyfix prints can corrupt a frame). A request is ``(op, payload)``;
the answer ``("ok", value)`` or ``("err", traceback text)``. Ops:

- ``hello`` → where skyfix was imported from, its version, python, numba;
- ``put`` ``(key, value, evict)`` → stores an input (a large array) under ``key`` and drops the
  ``evict`` keys, so an image sent once serves several calls (:class:`Stored` refers to it);
- ``call`` ``(target, args, kwargs)`` → ``target(*args, **kwargs)``; ``target`` is
  ``"adapter.<method>"`` (the worker's :class:`skyfix_adapter.Skyfix`, made on first use) or
  ``"<module>:<function>"`` (a benchmark module's function, e.g. ``suite_track:one_round``);
- ``many`` ``(target, calls)`` → one answer per ``(args, kwargs)``: the value, or a
  :class:`RemoteError` for a call that raised (the others still run);
- ``exit``.
"""

from __future__ import annotations

import os
import pickle
import struct
import subprocess
import sys
from collections import OrderedDict
from pathlib import Path
from typing import Any, BinaryIO, NamedTuple

import numpy as np

BENCH_DIR = Path(__file__).resolve().parent
_HEADER = struct.Struct("<Q")
_BIG = 256 * 1024  # arrays at least this large are sent once (put) and referred to by key
_KEEP = 32  # how many such arrays each side keeps (suite f's 20 frames serve several rounds) ...
_KEEP_BYTES = 512 << 20  # ... and how many bytes


class Stored(NamedTuple):
    """An argument already sent to the worker (``put``) under ``key``."""

    key: str


class RemoteError(Exception):
    """A call that raised in the worker: the exception's type and message (and traceback)."""


def send(fh: BinaryIO, obj: Any) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    fh.write(_HEADER.pack(len(data)))
    fh.write(data)
    fh.flush()


def receive(fh: BinaryIO) -> Any:
    head = fh.read(_HEADER.size)
    if len(head) < _HEADER.size:
        raise EOFError("the worker closed its pipe")
    (n,) = _HEADER.unpack(head)
    data = fh.read(n)
    if len(data) < n:
        raise EOFError("the worker closed its pipe mid-message")
    return pickle.loads(data)


def side_env(src: Path, extra: dict[str, str] | None = None) -> dict[str, str]:
    """The environment of a process that must import skyfix from ``src`` (first on PYTHONPATH)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(src), *filter(None, [os.environ.get("PYTHONPATH")])])
    env.update(extra or {})
    return env


class Worker:
    """A worker process importing skyfix from ``src``."""

    def __init__(self, label: str, src: Path):
        self.label, self.src = label, Path(src)
        self.proc = subprocess.Popen([sys.executable, str(BENCH_DIR / "worker.py")],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=side_env(self.src),
                                     cwd=str(BENCH_DIR.parent))
        self._sent: OrderedDict[int, tuple[np.ndarray, str]] = OrderedDict()
        self._n_keys = 0
        self.info = self.request("hello", None)
        where = Path(self.info["skyfix_file"]).resolve()
        if self.src.resolve() not in where.parents:
            self.close()
            raise RuntimeError(f"{label}: skyfix was imported from {where}, not from {self.src} "
                               "(PYTHONPATH shadowed?)")

    def request(self, op: str, payload: Any) -> Any:
        send(self.proc.stdin, (op, payload))
        status, value = receive(self.proc.stdout)
        if status != "ok":
            raise RemoteError(f"{self.label}: {value}")
        return value

    def _encode(self, obj: Any) -> Any:
        """``obj`` with every large array replaced by a :class:`Stored` key (sent once per side)."""
        if isinstance(obj, np.ndarray) and obj.nbytes >= _BIG:
            hit = self._sent.get(id(obj))
            if hit is not None and hit[0] is obj:
                self._sent.move_to_end(id(obj))
                return Stored(hit[1])
            self._n_keys += 1
            key = f"a{self._n_keys}"
            evict = []
            while self._sent and (len(self._sent) >= _KEEP or
                                  sum(a.nbytes for a, _ in self._sent.values()) + obj.nbytes > _KEEP_BYTES):
                evict.append(self._sent.popitem(last=False)[1][1])
            self.request("put", (key, obj, evict))
            self._sent[id(obj)] = (obj, key)
            return Stored(key)
        if isinstance(obj, (list, tuple)) and not hasattr(obj, "_fields"):
            return type(obj)(self._encode(x) for x in obj)
        if isinstance(obj, dict):
            return {k: self._encode(v) for k, v in obj.items()}
        return obj

    def call(self, target: str, *args, **kwargs) -> Any:
        return self.request("call", (target, self._encode(args), self._encode(kwargs)))

    def many(self, target: str, calls: list[tuple[tuple, dict]]) -> list:
        """One value (or :class:`RemoteError`) per ``(args, kwargs)``, in one round trip."""
        return self.request("many", (target, [(self._encode(a), self._encode(k)) for a, k in calls]))

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                send(self.proc.stdin, ("exit", None))
                self.proc.stdin.close()
                self.proc.wait(timeout=30)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait()


class RemoteSkyfix:
    """The :class:`skyfix_adapter.Skyfix` adapter of a worker, called like the local one."""

    is_skyfix = True

    def __init__(self, worker: Worker, name: str):
        self.worker, self.name = worker, name
        info = worker.call("adapter.describe")
        self.version, self.load_ms = info["version"], info["load_ms"]
        self.build_ms, self.note = info["build_ms"], info["note"]
        self.skyfix_file = worker.info["skyfix_file"]

    def many(self, method: str, calls: list[tuple[tuple, dict]]) -> list:
        return self.worker.many(f"adapter.{method}", calls)

    def _call(self, method: str, *args, **kwargs):
        return self.worker.call(f"adapter.{method}", *args, **kwargs)

    def solve_centroids(self, *args, **kwargs):
        return self._call("solve_centroids", *args, **kwargs)

    def solve_file(self, *args, **kwargs):
        return self._call("solve_file", *args, **kwargs)

    def solve_image(self, *args, **kwargs):
        return self._call("solve_image", *args, **kwargs)

    def extract(self, *args, **kwargs):
        return self._call("extract", *args, **kwargs)

    def read(self, *args, **kwargs):
        return self._call("read", *args, **kwargs)

    def database_build(self, *args, **kwargs):
        return self._call("database_build", *args, **kwargs)

    def database_load(self, *args, **kwargs):
        return self._call("database_load", *args, **kwargs)

    def default_database_load(self, *args, **kwargs):
        return self._call("default_database_load", *args, **kwargs)

    def final_fit_ms(self, *args, **kwargs):
        return self._call("final_fit_ms", *args, **kwargs)
