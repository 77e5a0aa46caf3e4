"""Run a campaign on Dask: batches of trials as tasks, each finished batch kept on disk, so an
interrupted run continues where it stopped.

What runs is a :class:`skyfix.montecarlo.study.Study`: a campaign file
(:class:`~skyfix.montecarlo.campaign.Campaign`, wrapped as
:class:`~skyfix.montecarlo.trials.CampaignTrials`) or one of the analysis studies. Below,
"campaign" means either.

- **Cluster.** ``workers=0``: the batches run one after another in this process (no Dask; for
  small runs and tests — the same rows). Otherwise a :class:`dask.distributed.LocalCluster` of
  ``workers`` single-threaded worker processes (their ``PYTHONPATH`` gets the folder this
  skyfix is imported from), or the scheduler at ``scheduler`` (``tcp://HOST:8786``) with
  whatever workers it has. dask is imported only here, when a campaign runs.
- **Batches.** Batch ``k`` is trials ``k·B … (k+1)·B − 1`` (``[campaign] batch_size``), one task
  (the study's ``run_batch``); its key names the campaign's fingerprint and
  ``k``. A trial is a pure function of (campaign, trial index), so the rows do not depend on
  the worker count or the order the batches finish in.
- **Resume.** Each finished batch is written by this process (workers need no shared disk) to
  ``OUTPUT.parts/batch-KKKKKK.parquet``, atomically (a temporary file renamed), beside
  ``campaign.json`` (the fingerprint). A later run with the same campaign and output runs only
  the batches missing; a part whose rows are not exactly its batch's trials is run again. When
  every batch is there, the parts are joined in trial order into ``OUTPUT`` (checked: every
  trial exactly once) and the folder removed. Another campaign's parts are refused.
- **Failures.** A worker that dies has its batches run again elsewhere (Dask's
  ``allowed-failures``, 3 by default); a batch whose workers keep dying, or a scheduler out of
  reach, is a one-line :class:`~skyfix.errors.CampaignError` — the finished batches stay.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import skyfix
from skyfix.errors import CampaignError
from skyfix.montecarlo.campaign import Campaign
from skyfix.montecarlo.study import Study, table_of

if TYPE_CHECKING:
    import pyarrow as pa

__all__ = ["CONNECT_TIMEOUT_S", "RunResult", "as_study", "cluster", "connect", "parts_folder", "run_campaign",
           "run_rows", "trial_progress"]

#: How long to try reaching a scheduler before the run is refused.
CONNECT_TIMEOUT_S = 10.0
_MANIFEST = "campaign.json"


@dataclass
class RunResult:
    """What :func:`run_campaign` did: the joined table when every batch is done (else None),
    batches done before this run and by it, the wall time and the workers it had."""

    table: pa.Table | None
    n_batches: int
    batches_before: int
    batches_run: int
    trials_run: int
    wall_s: float
    workers: int

    @property
    def complete(self) -> bool:
        return self.table is not None


def as_study(campaign: Campaign | Study) -> Study:
    """What the engine runs for ``campaign``: a campaign file's :class:`CampaignTrials`, or the
    study itself."""
    if isinstance(campaign, Campaign):
        from skyfix.montecarlo.trials import CampaignTrials

        return CampaignTrials(campaign)
    return campaign


def parts_folder(output: Path) -> Path:
    """Where a run to ``output`` keeps its finished batches."""
    return output.with_name(output.name + ".parts")


def _part_path(parts: Path, batch: int) -> Path:
    return parts / f"batch-{batch:06d}.parquet"


def _finished_batches(campaign: Study, parts: Path) -> set[int]:
    """Batches already in ``parts`` (created, with the manifest, when missing); a part that does
    not hold exactly its batch's trials is deleted."""
    import pyarrow.parquet as pq

    manifest = parts / _MANIFEST
    if parts.exists() and manifest.exists():
        try:
            theirs = json.loads(manifest.read_text()).get("fingerprint")
        except (OSError, json.JSONDecodeError):
            theirs = None
        if theirs != campaign.fingerprint:
            raise CampaignError(f"{parts} holds the finished batches of another campaign (or another "
                                "version of this one): remove it, or write to another output")
    parts.mkdir(parents=True, exist_ok=True)
    text = json.dumps({"fingerprint": campaign.fingerprint, "campaign": campaign.to_dict()}, default=str)
    _write_atomic(manifest, lambda p: p.write_text(text))
    done = set()
    for k in range(campaign.n_batches):
        path = _part_path(parts, k)
        if not path.exists():
            continue
        try:
            trials = pq.read_table(path, columns=["trial"]).column("trial").to_pylist()
        except Exception:  # a torn or foreign file: run the batch again
            trials = None
        if trials == list(campaign.batch_trials(k)):
            done.add(k)
        else:
            path.unlink()
    return done


def _write_atomic(path: Path, write: Callable[[Path], Any]) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    write(tmp)
    os.replace(tmp, path)


def _join(campaign: Study, parts: Path, output: Path) -> pa.Table:
    """The parts in trial order written to ``output`` (every trial exactly once, checked)."""
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq

    schema = campaign.schema()
    table = pa.concat_tables([pq.read_table(_part_path(parts, k), schema=schema)
                              for k in range(campaign.n_batches)])
    trials = table.column("trial").to_numpy()
    if not np.array_equal(trials, np.arange(campaign.trials)):
        raise CampaignError(f"{parts}: the batches do not hold trials 0 … {campaign.trials - 1} exactly once")
    _write_atomic(output, lambda p: pq.write_table(table, p))
    shutil.rmtree(parts)
    return table


def completed_table(campaign: Campaign | Study, output: Path) -> pa.Table | None:
    """``output``'s table when it holds this campaign's finished results, else None."""
    import pyarrow.parquet as pq

    campaign = as_study(campaign)
    if not output.is_file() or parts_folder(output).exists():
        return None
    try:
        meta = pq.read_schema(output).metadata or {}
    except Exception:
        return None
    if meta.get(b"skyfix.fingerprint", b"").decode() != campaign.fingerprint:
        return None
    return pq.read_table(output)


def _worker_env() -> dict[str, str]:
    """The worker processes' environment additions: this skyfix's folder first on PYTHONPATH."""
    src = str(Path(skyfix.__file__).resolve().parents[1])
    path = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    return {"PYTHONPATH": os.pathsep.join([src, *(p for p in path if p != src)])}


def connect(workers: int, scheduler: str | None, processes: bool = True):
    """A Dask client and the LocalCluster it owns (None when ``scheduler``, an address, is given):
    ``workers`` single-threaded worker processes importing this skyfix (campaigns, and ``skyfix
    solve --workers``). An unreachable scheduler is a CampaignError naming it."""
    from dask.distributed import Client, LocalCluster

    if scheduler:
        try:
            return Client(scheduler, timeout=CONNECT_TIMEOUT_S, set_as_default=False), None
        except (OSError, TimeoutError, ValueError) as exc:
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise CampaignError(f"cannot reach the Dask scheduler at {scheduler}: {first}") from None
    import dask

    # Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, which turns off glibc's
    # adaptive mmap threshold: every large array is then mapped and unmapped anew, and a solve on
    # a worker took twice as long as in this process (the tracking study's lost-in-space median,
    # 16 → 11 ms without it). Dask lets a config override unset it (None).
    with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=processes,
                               dashboard_address=None, silence_logs=logging.CRITICAL,
                               **({"env": _worker_env()} if processes else {}))
    return Client(cluster, set_as_default=False), cluster


def run_campaign(campaign: Campaign | Study, output: str | Path, *, workers: int = 2,
                 scheduler: str | None = None, client=None, processes: bool = True,
                 max_batches: int | None = None,
                 progress: Callable[[int, int], None] | None = None) -> RunResult:
    """Run the batches of ``campaign`` not yet finished and, when all are, join them into
    ``output`` (Parquet). ``workers=0`` (and no ``scheduler`` or ``client``): in this process,
    without Dask. ``client``: an existing Dask client to use (then ``workers``, ``scheduler``
    and ``processes`` are ignored and it is left open). ``max_batches``: stop once this many
    batches have finished in this run (what an interrupt does, for tests).
    ``progress(done, total)`` is called with the batches finished."""
    campaign = as_study(campaign)
    output = Path(output)
    t0 = time.perf_counter()
    done_table = completed_table(campaign, output)
    if done_table is not None:
        return RunResult(done_table, campaign.n_batches, campaign.n_batches, 0, 0, 0.0, 0)
    parts = parts_folder(output)
    done = _finished_batches(campaign, parts)
    before, todo = len(done), [k for k in range(campaign.n_batches) if k not in done]
    if progress is not None:
        progress(len(done), campaign.n_batches)
    n_workers, ran = 0, []
    if todo and client is None and scheduler is None and workers == 0:
        ran = _run_here(campaign, todo, parts, max_batches, progress, len(done))
    elif todo:
        if client is None and scheduler is None:
            campaign.warm()
        owned = client is None
        if owned:
            client, cluster = connect(workers, scheduler, processes)
        try:
            n_workers = len(client.scheduler_info().get("workers", {}))
            ran = _run_batches(client, campaign, todo, parts, max_batches, progress, len(done))
        finally:
            if owned:
                client.close()
                if cluster is not None:
                    cluster.close()
    complete = len(done) + len(ran) == campaign.n_batches
    table = _join(campaign, parts, output) if complete else None
    return RunResult(table, campaign.n_batches, before, len(ran),
                     sum(len(campaign.batch_trials(k)) for k in ran), time.perf_counter() - t0, n_workers)


def _keep(campaign: Study, parts: Path, k: int, rows: list) -> None:
    """Write batch ``k``'s rows as its part, atomically."""
    import pyarrow.parquet as pq

    table = table_of(campaign, rows)
    _write_atomic(_part_path(parts, k), lambda p: pq.write_table(table, p))


def _run_here(campaign: Study, todo: list[int], parts: Path, max_batches: int | None,
              progress: Callable[[int, int], None] | None, done: int) -> list[int]:
    """``todo`` run one after another in this process, each written as it finishes."""
    ran: list[int] = []
    for k in todo:
        _keep(campaign, parts, k, campaign.run_batch(k))
        ran.append(k)
        if progress is not None:
            progress(done + len(ran), campaign.n_batches)
        if max_batches is not None and len(ran) >= max_batches:
            break
    return ran


def _run_batch(campaign: Study, batch: int) -> list[dict[str, Any]]:
    """One task: the rows of ``batch``."""
    return campaign.run_batch(batch)


def _run_batches(client, campaign: Study, todo: list[int], parts: Path, max_batches: int | None,
                 progress: Callable[[int, int], None] | None, done: int) -> list[int]:
    """Submit ``todo``, write each batch as it finishes; the batches written."""
    from dask.distributed import KilledWorker, as_completed

    tag = campaign.fingerprint[:12]
    futures = {client.submit(_run_batch, campaign, k, key=f"skyfix-montecarlo-{tag}-{k}"): k for k in todo}
    ran: list[int] = []
    try:
        for fut in as_completed(futures, loop=client.loop):
            k = futures[fut]
            try:
                rows = fut.result()
            except KilledWorker:
                raise CampaignError(f"batch {k}: the workers running it died again and again; the "
                                    f"{done + len(ran)} finished batches are kept in {parts} — run again to "
                                    "continue") from None
            except RuntimeError as exc:
                if "deserializ" not in str(exc):
                    raise
                raise CampaignError("the scheduler could not load the campaign's tasks: the scheduler and "
                                    "every worker must import the same skyfix as this command (its "
                                    "PYTHONPATH, or the same install)") from None
            _keep(campaign, parts, k, rows)
            ran.append(k)
            if progress is not None:
                progress(done + len(ran), campaign.n_batches)
            if max_batches is not None and len(ran) >= max_batches:
                break
    finally:
        client.cancel(list(futures))
    return ran


@contextlib.contextmanager
def cluster(workers: int, scheduler: str | None = None) -> Iterator[Any]:
    """A Dask client for the studies of one run (:func:`connect`: ``workers`` local worker
    processes, or the scheduler at ``scheduler``), closed at the end; None with ``workers=0``
    and no scheduler (the studies then run in this process)."""
    if not workers and not scheduler:
        yield None
        return
    client, local = connect(workers, scheduler)
    try:
        yield client
    finally:
        client.close()
        if local is not None:
            local.close()


def run_rows(study: Study, output: str | Path | None = None, *, workers: int = 0,
             scheduler: str | None = None, client=None, fresh: bool = False,
             progress: Callable[[int, int], None] | None = None) -> pa.Table:
    """Every trial's row of ``study`` (a table in trial order), run by :func:`run_campaign` into
    ``output`` (Parquet; its folder made; None: a temporary file, removed) on ``workers`` local
    processes (0: this one), the scheduler at ``scheduler`` or an open ``client`` (several studies
    on one :func:`cluster`). A stopped run's finished batches beside ``output`` are kept and the run
    continues; a finished ``output`` of the same study is read back, or run again when ``fresh``.
    ``progress(done, total)``: batches finished (:func:`trial_progress` counts trials)."""
    if output is None:
        with tempfile.TemporaryDirectory(prefix="skyfix-study-") as tmp:
            return run_rows(study, Path(tmp) / "rows.parquet", workers=workers, scheduler=scheduler,
                            client=client, progress=progress)
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    if fresh:
        output.unlink(missing_ok=True)
    result = run_campaign(study, output, workers=workers, scheduler=scheduler, client=client,
                          progress=progress)
    assert result.table is not None  # every batch ran (no max_batches)
    return result.table


def trial_progress(study: Study, progress: Callable[[int, int], None] | None
                   ) -> Callable[[int, int], None] | None:
    """The engine's ``progress(batches done, batches)`` as ``progress(trials done, trials)``."""
    if progress is None:
        return None

    def batches_done(done: int, total: int) -> None:
        progress(min(done * study.batch_size, study.trials), study.trials)

    return batches_done
