"""What the identification study's grid (:mod:`skyfix.analysis.identification_study`), its seed
experiments (:mod:`skyfix.analysis.identification_cases`) and its safety case
(:mod:`skyfix.analysis.identification_safety`) share: the simulated frames' settings and
conditions, the methods run, a solve judged against its truth
(:func:`skyfix.analysis.truth.judge`, the one definition of a wrong attitude), the 95 % bound on a
rate, the methods warmed once per process, and how they run on the campaign engine
(:func:`skyfix.montecarlo.engine.run_campaign`): :class:`MethodTrials`, a study whose trial is one
method on one frame, run by :func:`skyfix.montecarlo.engine.run_rows`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple, get_type_hints

import numpy as np

from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
from skyfix.analysis.truth import Judgement, judge, upper_bound_95
from skyfix.camera import Camera
from skyfix.catalog import load_hipparcos
from skyfix.identify import METHODS, default_database, get_method, identify
from skyfix.montecarlo.study import BatchedStudy

if TYPE_CHECKING:
    import pyarrow as pa

__all__ = ["CONDITIONS", "Condition", "EPOCH", "HEIGHT", "MAG_LIMIT", "WIDTH", "MethodTrials",
           "condition_key", "judge_identification", "method_names", "record_columns",
           "study_field", "table_nbytes", "upper_bound_95", "warm_methods", "warm_once"]

EPOCH = 2025.0
WIDTH, HEIGHT = 1280, 960
MAG_LIMIT = 6.5

class Condition(NamedTuple):
    """How a simulated frame departs from the truth."""

    name: str
    sigma_px: float = 0.0
    n_false: int = 0
    dropout: float = 0.0
    mag_sigma: float = 0.0


CONDITIONS = (
    Condition("noise-free"),
    Condition("σ 0.5 px", sigma_px=0.5),
    Condition("σ 1 px", sigma_px=1.0),
    Condition("σ 2 px", sigma_px=2.0),
    Condition("3 false stars", n_false=3),
    Condition("10 false stars", n_false=10),
    Condition("20 % dropped", dropout=0.2),
    Condition("0.5 mag noise", mag_sigma=0.5),
    Condition("all: σ 1 px, 5 false, 10 % dropped, 0.3 mag", 1.0, 5, 0.1, 0.3),
)


def method_names(methods: tuple[str, ...] | list[str] = ()) -> list[str]:
    """The methods to run: those named (checked), or every registered one; a name that is an
    alias of an earlier one's function (``hash`` of ``quad-hash``) is run once."""
    names = [m.strip().lower() for m in methods if m.strip()] or list(METHODS)
    seen: dict[int, str] = {}
    out = []
    for m in names:
        fn = get_method(m)  # InputError for an unknown name
        if id(fn) not in seen:
            seen[id(fn)] = m
            out.append(m)
    return out


def study_field(fov: float, cond: Condition, trial: int, seed: int, catalog):
    rng = np.random.default_rng([seed, int(round(fov * 100)), condition_key(cond), trial])
    camera = Camera.from_fov(WIDTH, HEIGHT, fov)
    A = random_attitudes(1, rng)[0]
    f = synthetic_centroids(camera, A, catalog, mag_limit=MAG_LIMIT, sigma_px=cond.sigma_px,
                            n_false=cond.n_false, dropout=cond.dropout, mag_sigma=cond.mag_sigma, rng=rng)
    return camera, f


def condition_key(cond: Condition) -> int:
    return int(round(cond.sigma_px * 100)) * 10**7 + cond.n_false * 10**5 + int(round(
        cond.dropout * 100)) * 10**3 + int(round(cond.mag_sigma * 100))


def judge_identification(ident, A_true: np.ndarray, camera: Camera) -> Judgement:
    """A solved identification against the truth of a frame seen by ``camera``
    (:func:`skyfix.analysis.truth.judge`)."""
    return judge(ident.A_icrs_to_cam, ident.camera, A_true, camera)


def warm_methods(methods: list[str], fovs_deg: tuple[float, ...] = (8.0, 15.0, 30.0), cameras: bool = False
          ) -> dict[str, dict]:
    """Two calls per method and FOV outside the clock (the first builds the method's tables
    beside the shared database and loads its compiled kernels). Returns per method the bytes of
    the tables it added to the database (:meth:`~skyfix.identify.PatternDatabase.derived`) and
    its first calls' time beyond the second's (the build). With ``cameras``, then one call per
    method and FOV with the camera given (the tables a calibrated camera's search builds), not
    counted."""
    catalog = load_hipparcos(epoch=EPOCH, mag_limit=MAG_LIMIT + 1.0)
    db = default_database(progress=False)
    fields = [(fov, study_field(fov, CONDITIONS[0], 10**6 + 1, 12345, catalog)[1]) for fov in fovs_deg]
    out = {}
    for m in methods:
        before = set(db.__dict__.get("_derived", {}))
        build = 0.0
        for fov, f in fields:
            for k in range(2):
                t0 = time.perf_counter()
                identify(f.xy, WIDTH, HEIGHT, method=m, fov_deg=fov, fov_tolerance_deg=0.1 * fov, database=db,
                         epoch=EPOCH)
                build += (1 if k == 0 else -1) * (time.perf_counter() - t0)
        derived = db.__dict__.get("_derived", {})
        added = [v for key, v in derived.items() if key not in before]
        out[m] = {"bytes": table_nbytes(added), "tables": len(added), "build_s": max(build, 0.0)}
    for m in methods if cameras else ():
        for fov, f in fields:
            identify(f.xy, WIDTH, HEIGHT, method=m, camera=Camera.from_fov(WIDTH, HEIGHT, fov), database=db,
                     epoch=EPOCH)
    _WARMED.update(_warm_keys(methods, fovs_deg, cameras))
    return out


_WARMED: set[tuple[str, float, bool]] = set()
"""(method, FOV, camera given) warmed in this process (:func:`warm_methods`)."""


def _warm_keys(methods, fovs_deg, cameras: bool) -> set[tuple[str, float, bool]]:
    given = (False, True) if cameras else (False,)
    return {(m, float(f), c) for m in methods for f in fovs_deg for c in given}


def warm_once(methods, fovs_deg, cameras: bool = False) -> None:
    """:func:`warm_methods` unless this process has warmed these methods and FOVs (and cameras)
    already: what every engine worker does before its first batch (what the study's own pool did
    in its initializer), so that no trial's time holds the build of a method's tables."""
    if not _warm_keys(methods, fovs_deg, cameras) <= _WARMED:
        warm_methods(list(methods), tuple(fovs_deg), cameras=cameras)


def table_nbytes(value, seen: set | None = None) -> int:
    """Bytes of the numpy arrays in a (nested) table."""
    seen = set() if seen is None else seen
    if id(value) in seen:
        return 0
    seen.add(id(value))
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if isinstance(value, dict):
        return sum(table_nbytes(v, seen) for v in value.values())
    if isinstance(value, (list, tuple)):
        return sum(table_nbytes(v, seen) for v in value)
    if hasattr(value, "__dict__"):
        return sum(table_nbytes(v, seen) for v in vars(value).values())
    return 0


_ARROW = {"int": "int64", "float": "float64", "bool": "bool", "str": "string"}


def record_columns(record: type, number: str) -> dict[str, str]:
    """A study's Parquet columns for rows of ``record`` (a NamedTuple of ints, floats, bools and
    strings): the engine's ``trial`` first, then the record's fields, its own ``trial`` (the
    frame's number) renamed ``number``."""
    return {"trial": "int64", **{(number if f == "trial" else f): _ARROW[t.__name__]
                                 for f, t in get_type_hints(record).items()}}


@dataclass(frozen=True)
class MethodTrials(BatchedStudy):
    """A study of the methods ``settings["methods"]`` (M of them) on numbered frames: trial ``i``
    is method ``i % M`` on frame ``i // M`` — one row per solve, the frame's methods interleaved as
    the study always ran them — and a batch of whole frames (``batch_size`` a multiple of M)
    simulates each frame once for its methods. A subclass names its ``record`` (a NamedTuple whose
    ``trial`` field is the frame's number, the column ``number``), the set-up a batch shares
    (:meth:`context`), what a frame's solves are (:meth:`solve_frame`) and the warm-up
    (:meth:`warm_args`: :func:`warm_once`'s methods, FOVs and cameras)."""

    record: ClassVar[type]
    number: ClassVar[str] = "frame"

    @property
    def methods(self) -> list[str]:
        return list(self.settings["methods"])

    def context(self) -> Any:
        """What a batch's frames share (a catalogue, a database)."""

    def solve_frame(self, context: Any, frame: int, methods: list[str]) -> list:
        """The records of ``methods`` on frame ``frame`` (0, 1, … in the study)."""
        raise NotImplementedError(f"{type(self).__name__}.solve_frame")

    def warm_args(self) -> tuple[list[str], tuple[float, ...], bool]:
        return self.methods, (), False

    def warm(self) -> None:
        warm_once(*self.warm_args())

    def run_trial(self, trial: int) -> dict[str, Any]:
        return self._rows(range(trial, trial + 1))[0]

    def run_batch(self, batch: int) -> list[dict[str, Any]]:
        return self._rows(self.batch_trials(batch))

    def _rows(self, trials: range) -> list[dict[str, Any]]:
        self.warm()
        context, methods, rows = self.context(), self.methods, []
        m = len(methods)
        for frame in range(trials.start // m, (trials.stop - 1) // m + 1):
            mine = [i for i in trials if i // m == frame]
            records = self.solve_frame(context, frame, [methods[i % m] for i in mine])
            for i, r in zip(mine, records, strict=True):
                row = r._asdict()
                row[self.number] = row.pop("trial")
                rows.append({"trial": i, **row})
        return rows

    @classmethod
    def records(cls, table: pa.Table) -> list:
        """The rows of ``table`` (this study's Parquet) as records, in trial order."""
        return [cls.record(**{f: row[cls.number if f == "trial" else f] for f in cls.record._fields})
                for row in table.to_pylist()]
