"""Run an analysis study on the campaign engine and hand back its rows (issue 27).

The analysis campaigns (:mod:`skyfix.analysis.preset_campaign`,
:mod:`skyfix.analysis.allsky_campaign`) are :class:`~skyfix.montecarlo.study.BatchedStudy`
subclasses; :func:`run_rows` runs one through :func:`skyfix.montecarlo.engine.run_campaign` —
``workers=0`` in this process, ``N`` local worker processes, or a Dask scheduler's workers — into
a Parquet file (a temporary one when none is named) and returns its table, one row per trial in
trial order, whatever ran it.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import pyarrow as pa

    from skyfix.montecarlo.study import BatchedStudy

__all__ = ["run_rows"]


def run_rows(study: BatchedStudy, output: str | Path | None = None, *, workers: int = 0,
             scheduler: str | None = None, progress: Callable[[int, int], None] | None = None) -> pa.Table:
    """The rows of every trial of ``study`` (a table in trial order), run on the engine into
    ``output`` (Parquet; resumable: an interrupted run's finished batches are kept beside it and
    a second run continues them; None: a temporary file, removed). ``workers=0``: in this
    process; ``scheduler``: a Dask scheduler's address (``tcp://HOST:8786``; unreachable: a
    one-line :class:`~skyfix.errors.CampaignError`). ``progress(trials done, trials)``."""
    from skyfix.montecarlo.engine import run_campaign

    def batches_done(done: int, total: int) -> None:
        if progress is not None:
            trials = sum(len(study.batch_trials(k)) for k in range(min(done, total)))
            progress(trials, study.trials)

    if output is None:
        with tempfile.TemporaryDirectory(prefix="skyfix-study-") as tmp:
            return run_rows(study, Path(tmp) / "rows.parquet", workers=workers, scheduler=scheduler,
                            progress=progress)
    result = run_campaign(study, output, workers=workers, scheduler=scheduler, progress=batches_done)
    assert result.table is not None  # every batch ran (no max_batches)
    return result.table
