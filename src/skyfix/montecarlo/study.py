"""What the campaign engine runs: any seeded set of trials, batched (issue 27).

:func:`skyfix.montecarlo.engine.run_campaign` runs a :class:`Study`: ``trials`` trials in
batches of ``batch_size``, each batch one Dask task returning one row (a dict) per trial, every
row a pure function of the study and its trial index — so the rows do not depend on the worker
count or the order the batches finish in, and a run that stops can continue. A campaign file
(:class:`skyfix.montecarlo.campaign.Campaign`, simulate → solve → compare) is one kind of study;
the analysis studies (identification, tracking, the preset, blind, field and all-sky campaigns)
are others, each a :class:`BatchedStudy` with its own settings, columns and trial function.

A study must be picklable (it is sent to the workers) and importable from a module the workers
import (``skyfix…``), so define studies at module level, never in a function.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

if TYPE_CHECKING:
    import pyarrow as pa

__all__ = ["BatchedStudy", "Study", "fingerprint_of", "schema_for", "table_of"]


class Study(Protocol):
    """The engine's view of a campaign: its trials in batches, the rows of one batch, their
    schema, and what decides them (``to_dict``, hashed into ``fingerprint``)."""

    trials: int
    batch_size: int

    @property
    def n_batches(self) -> int: ...

    @property
    def fingerprint(self) -> str: ...

    def batch_trials(self, batch: int) -> range: ...

    def run_batch(self, batch: int) -> list[dict[str, Any]]: ...

    def schema(self) -> pa.Schema: ...

    def to_dict(self) -> dict: ...

    def warm(self) -> None: ...


def fingerprint_of(data: Mapping[str, Any]) -> str:
    """SHA-256 of ``data`` as sorted JSON (what a resumed run checks its finished batches against)."""
    text = json.dumps(data, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def schema_for(columns: Mapping[str, str], study: Study) -> pa.Schema:
    """An Arrow schema from ``{name: Arrow type}`` (``"float64"``, ``"list<float64>"``, …), the
    study (JSON) and its fingerprint in the metadata."""
    import pyarrow as pa

    def arrow(kind: str) -> pa.DataType:
        if kind.startswith("list<") and kind.endswith(">"):
            return pa.list_(arrow(kind[5:-1]))
        return pa.type_for_alias(kind)

    meta = {"skyfix.campaign": json.dumps(study.to_dict(), default=str),
            "skyfix.fingerprint": study.fingerprint}
    return pa.schema([pa.field(n, arrow(t)) for n, t in columns.items()], metadata=meta)


def table_of(study: Study, rows: list[Mapping[str, Any]]) -> pa.Table:
    """Rows (dicts) as a table of ``study.schema()``; a column a row lacks is null."""
    import pyarrow as pa

    return pa.Table.from_pylist([dict(r) for r in rows], schema=study.schema())


@dataclass(frozen=True)
class BatchedStudy:
    """A study defined by its settings and a trial function: subclass it at module level with
    ``kind`` (the study's name), ``columns`` (``{name: Arrow type}``, ``"trial"`` first) and
    :meth:`run_trial`; override :meth:`run_batch` when a batch shares set-up between its trials
    (a database, a catalogue) and :meth:`warm` to load kernels before the workers start.

    ``settings`` holds everything else that decides the rows (plain JSON data: numbers, strings,
    lists, tables), so two studies with equal settings give equal rows."""

    kind: ClassVar[str] = ""
    columns: ClassVar[Mapping[str, str]] = {}

    trials: int
    batch_size: int = 50
    settings: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.trials < 1 or self.batch_size < 1:
            raise ValueError(f"a {self.kind or 'study'} needs ≥ 1 trial and a batch size ≥ 1 "
                             f"(got {self.trials}, {self.batch_size})")

    @property
    def n_batches(self) -> int:
        return -(-self.trials // self.batch_size)

    def batch_trials(self, batch: int) -> range:
        """The trial indices of batch ``batch``."""
        return range(batch * self.batch_size, min((batch + 1) * self.batch_size, self.trials))

    def to_dict(self) -> dict:
        return {"study": self.kind, "trials": self.trials, "batch_size": self.batch_size,
                "settings": json.loads(json.dumps(dict(self.settings), default=str))}

    @property
    def fingerprint(self) -> str:
        return fingerprint_of(self.to_dict())

    def schema(self) -> pa.Schema:
        return schema_for(self.columns, self)

    def run_trial(self, trial: int) -> dict[str, Any]:
        raise NotImplementedError(f"{type(self).__name__}.run_trial")

    def run_batch(self, batch: int) -> list[dict[str, Any]]:
        """The rows of batch ``batch``, in trial order."""
        return [self.run_trial(i) for i in self.batch_trials(batch)]

    def warm(self) -> None:
        """Compile (or load) the kernels the trials need, once, before the workers start."""
