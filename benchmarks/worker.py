"""The worker process of ``benchmarks/run --against``: serves one side's skyfix over a pipe.

Started by :class:`remote.Worker` with that side's ``src`` first on ``PYTHONPATH``; the protocol
is described in ``remote.py``. Not meant to be run by hand.
"""

from __future__ import annotations

import importlib
import os
import sys
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from remote import RemoteError, Stored, receive, send  # noqa: E402


def main() -> int:
    # The protocol owns the original stdout; anything printed (by skyfix, numba, C code) goes to stderr.
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    inp = sys.stdin.buffer
    store: dict[str, object] = {}
    adapter = None

    def resolve(obj):
        if isinstance(obj, Stored):
            return store[obj.key]
        if isinstance(obj, (list, tuple)) and not hasattr(obj, "_fields"):
            return type(obj)(resolve(x) for x in obj)
        if isinstance(obj, dict):
            return {k: resolve(v) for k, v in obj.items()}
        return obj

    def target(name: str):
        nonlocal adapter
        if name.startswith("adapter."):
            if adapter is None:
                from skyfix_adapter import Skyfix

                adapter = Skyfix()
            return getattr(adapter, name.split(".", 1)[1])
        module, _, func = name.partition(":")
        return getattr(importlib.import_module(module), func)

    while True:
        try:
            op, payload = receive(inp)
        except EOFError:
            return 0
        try:
            if op == "exit":
                send(out, ("ok", None))
                return 0
            if op == "hello":
                import numba
                import numpy

                import skyfix

                value = {"skyfix_file": skyfix.__file__, "version": skyfix.__version__,
                         "python": sys.version.split()[0], "numpy": numpy.__version__,
                         "numba": numba.__version__, "pid": os.getpid()}
            elif op == "put":
                key, obj, evict = payload
                for k in evict:
                    store.pop(k, None)
                store[key] = obj
                value = None
            elif op == "call":
                name, args, kwargs = payload
                value = target(name)(*resolve(args), **resolve(kwargs))
            elif op == "many":
                name, calls = payload
                fn = target(name)
                value = []
                for args, kwargs in calls:
                    try:
                        value.append(fn(*resolve(args), **resolve(kwargs)))
                    except Exception as exc:  # noqa: BLE001 - one failed call, reported in its place
                        value.append(RemoteError(f"{type(exc).__name__}: {exc}"[:300]))
            else:
                raise ValueError(f"unknown op {op!r}")
            send(out, ("ok", value))
        except Exception:  # noqa: BLE001 - the driver shows it
            send(out, ("err", traceback.format_exc()))


if __name__ == "__main__":
    sys.exit(main())
