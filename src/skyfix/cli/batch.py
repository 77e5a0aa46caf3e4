"""``skyfix solve --workers N`` / ``--scheduler tcp://HOST:8786``: an archive of images solved on a
Dask cluster (issue 27 part 6) — the same cluster a Monte Carlo campaign runs on
(:func:`skyfix.montecarlo.engine.connect`: a local one of ``N`` worker processes, or any scheduler).

The inputs go out in batches of a few (:data:`BATCH`), each solved by :func:`skyfix.cli.records.
solve_input` on a worker, so a failing or unreadable image is a record with its reason, never a
lost batch; the records come back and are yielded in input order, as soon as every earlier one
is in. A pattern database given by file is loaded by each worker from that file (once per
worker), not sent with every batch. The workers write the ``--wcs``, ``--plot`` and
``--save-camera`` files themselves: with a remote scheduler those paths must be on a disk the
workers share.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator, Sequence
from pathlib import Path

from skyfix.cli.records import CentroidTable, InputOutputs, Outcome, error_record, solve_input

__all__ = ["BATCH", "solve_batch", "solve_on_cluster"]

BATCH = 4
"""Inputs per task: enough to keep the scheduler's overhead (a few ms a task) small beside a
solve (~20–200 ms), few enough that two workers share a short archive."""


@functools.lru_cache(maxsize=4)
def _database(path: str):
    from skyfix.identify import PatternDatabase

    return PatternDatabase.load(path)


def solve_batch(items: Sequence[tuple[Path | CentroidTable, InputOutputs]], options: dict) -> list[Outcome]:
    """Solve ``items`` (an input and its output paths each) with ``options`` (``solve``'s keywords;
    ``database`` may be a file path, loaded here once per process): one :class:`Outcome` each."""
    database = options.get("database")
    if isinstance(database, (str, Path)):
        options = {**options, "database": _database(str(database))}
    return [solve_input(source, outputs, options) for source, outputs in items]


def solve_on_cluster(items: Sequence[tuple[Path | CentroidTable, InputOutputs]], options: dict, *,
                     workers: int, scheduler: str | None, database_file: Path | None) -> Iterator[Outcome]:
    """The :class:`Outcome` of each item, in input order, solved in batches on a Dask cluster.

    A batch whose worker dies (or that cannot be run) gives each of its inputs an ``"error"``
    record saying so; the other batches go on.
    """
    from dask.distributed import as_completed

    from skyfix.montecarlo.engine import connect

    if scheduler is None:
        from skyfix import warmup

        warmup.ensure("solve")  # compiled here once, not by every worker at its first image
    sent = {**options, "database": str(database_file)} if database_file is not None else options
    batches = [list(items[k:k + BATCH]) for k in range(0, len(items), BATCH)]
    client, cluster = connect(workers, scheduler)
    try:
        futures = {client.submit(solve_batch, batch, sent, pure=False): k for k, batch in enumerate(batches)}
        done: dict[int, list[Outcome]] = {}
        next_batch = 0
        for future in as_completed(futures, loop=client.loop):
            k = futures[future]
            try:
                done[k] = future.result()
            except Exception as exc:  # a worker killed, a task that could not be loaded
                reason = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
                done[k] = [Outcome(error_record(_name(source), f"the worker solving it failed: {reason}"),
                                   None) for source, _ in batches[k]]
            while next_batch in done:
                yield from done.pop(next_batch)
                next_batch += 1
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _name(source: Path | CentroidTable) -> Path:
    return source.path if isinstance(source, CentroidTable) else source
