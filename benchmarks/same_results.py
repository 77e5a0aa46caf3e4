#!/usr/bin/env python3
"""Same results across a refactor: record what skyfix computes on a fixed set, compare two records.

    benchmarks/same_results.py record OUT.npz [--quick]
    benchmarks/same_results.py compare BASE.npz NEW.npz [--all]
    benchmarks/same_results.py against REF [--quick] [--keep DIR]

``record`` runs skyfix on a fixed, deterministic set and writes every number that comes out:

- ``real``: the 21 real images of shared/data/real, solved end to end with no FOV hint and
  default options (as ``benchmarks/suite_real.py``); the extracted centroids (every column of
  :class:`skyfix.detect.Centroids`) and the solution.
- ``synthetic``: the centroid sets of the solve-from-centroids benchmark (``suite_synthetic.configs``:
  σ 0.5/1 px, 3/8 false stars, 10 % dropouts; plus σ 1 px with 30 % dropouts), each solved with
  the true FOV (``fov.*``) and with none (``nofov.*``).
- ``rendered``: frames of skyfix's simulator (seven presets, seeds, false stars, hot pixels, cosmic
  rays, smear, a second frame index, noise off) and of ``benchmarks/render.py`` (8°, 15°, 30°):
  the SHA-256 of the pixels (and of the simulator's expected electrons and truth), the centroids
  and the solutions (the benchmark's frames with and without their FOV).
- ``blind``: ``skyfix.analysis.blind_campaign.uncalibrated_centroid_trials`` (random uncalibrated
  cameras: the final camera fit), the trials and each trial's full solution.
- ``database``: a pattern database built from scratch, the SHA-256 of each of its arrays.

A solution is recorded as: status, reason, method, ``A`` (ICRS → camera), quaternion, RA/Dec/roll,
FOV, boresight pixel, covariance, P(false), RMS, the matches (centroid index ↔ Hipparcos id,
residual) and the fitted camera's twelve numbers. Every solve uses epoch 2025.0: the default,
"now", moves the catalogue between two runs.

``compare`` prints one table row per section and lists each difference; it exits 0 only when the
two records are the same: rotation matrices and quaternions within 1e-12, centroid and input
positions within 1e-12 px, the same status, reasons, matches, image hashes and counts, and every
other number within 1e-9 relative. ``against REF`` records REF (a ``git worktree`` in a temporary
directory, its ``src`` first on ``PYTHONPATH``) and the working tree, each in its own process,
then compares them. The harness (this file and the benchmark modules it uses) is the working
tree's on both sides: only skyfix changes between the two runs.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

BENCH_DIR = Path(__file__).resolve().parent
if str(BENCH_DIR) not in sys.path:  # the benchmark modules (common, render, suite_synthetic)
    sys.path.insert(0, str(BENCH_DIR))

from common import REAL_DIR, REPO_ROOT, attitude_from_radec_roll_deg  # noqa: E402

EPOCH = 2025.0
# The search's wall-clock bound set far beyond its work bound (4000 patterns): a record is then
# the same on an idle and on a loaded machine (two records of one tree differed when a loaded
# machine stopped a search at the default 2 s).
WORK = {"time_limit_s": 120.0}
SECTIONS = ("real", "synthetic", "rendered", "blind", "database")
FORMAT = 1  # version of the record's layout

ATTITUDE_TOL = 1e-12  # rotation matrix / quaternion entries
POSITION_TOL = 1e-12  # pixels
RTOL, ATOL = 1e-9, 1e-12  # every other number
_ATTITUDE_FIELDS = ("A", "q")
_POSITION_FIELDS = ("x", "y", "xy")
_ARCSEC = 180.0 / math.pi * 3600.0

Fields = dict[str, np.ndarray]
Records = dict[str, dict[str, Fields]]  # section -> record name -> field -> array


class UsageError(Exception):
    """Bad input from the user: one line on stderr, exit status 2."""


# --- what to record -----------------------------------------------------------------------------

@dataclass(frozen=True)
class Plan:
    """How much of each section to record (``None``: all of it)."""

    real: int | None = None
    synthetic_per_config: int = 120
    sim_frames: int | None = None
    bench_frames_per_fov: int = 2
    blind: int = 500
    blind_seed: int = 2025
    database_fov: tuple[float, float] | None = (10.0, 30.0)


FULL = Plan()
QUICK = Plan(synthetic_per_config=20, sim_frames=9, bench_frames_per_fov=1, blind=50,
             database_fov=(20.0, 30.0))

# (name, preset, (RA, Dec, roll) degrees, render() keywords); the cheap frames first (--quick
# takes the first ones). Pointings at bright constellations so that most frames solve.
SIM_FRAMES: list[tuple[str, str, tuple[float, float, float], dict]] = [
    ("generic s1 Orion", "generic", (83.8, -5.4, 0.0), dict(seed=1)),
    ("generic s2 Pleiades false+hot", "generic", (56.9, 24.1, 30.0),
     dict(seed=2, false_stars=5, hot_pixels=30)),
    ("generic s3 Lyra smear", "generic", (279.2, 38.8, 120.0),
     dict(seed=3, rate_rad_s=(0.003, -0.002, 0.01))),
    ("generic s4 Virgo frame1", "generic", (201.3, -11.2, 200.0), dict(seed=4, frame_index=1)),
    ("generic s5 CMa shot+read only", "generic", (101.3, -16.7, 45.0),
     dict(seed=5, noise={"prnu": False, "dark": False, "hot_pixels": False, "dsnu": False, "ktc": False})),
    ("has2 s1 Orion", "has2", (88.8, 7.4, 10.0), dict(seed=1)),
    ("has2 s2 Cygnus false+hot+cosmic", "has2", (310.4, 45.3, 300.0),
     dict(seed=2, false_stars=3, hot_pixels=20, cosmic_rays=5)),
    ("mt9v022 s1 Bootes", "mt9v022", (213.9, 19.2, 0.0), dict(seed=1)),
    ("sunsat s1 Crux", "sunsat", (186.6, -63.1, 90.0), dict(seed=1)),
    ("mt9v022 s2 Scorpius hot", "mt9v022", (247.4, -26.4, 270.0), dict(seed=2, hot_pixels=20)),
    ("sunsat s2 UMa false", "sunsat", (165.9, 61.8, 180.0), dict(seed=2, false_stars=4)),
    ("mt9p031 s1 Orion", "mt9p031", (83.8, -1.2, 15.0), dict(seed=1)),
    ("ov5642 s1 Taurus", "ov5642", (68.98, 16.51, 0.0), dict(seed=1)),
    ("droid_x2 s1 Cassiopeia", "droid_x2", (10.1, 59.1, 60.0), dict(seed=1)),
    ("generic s6 noiseless (float32: a flat frame to the extractor)", "generic", (37.9, 89.3, 0.0),
     dict(seed=6, noise=False)),
]
BENCH_FOVS = (8.0, 15.0, 30.0)


# --- fields of one record -----------------------------------------------------------------------

def _f(value: float | None) -> float:
    return float("nan") if value is None else float(value)


def _sha256(array: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(array)
    h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())
    return np.array(h.hexdigest())


def centroid_fields(c: object, prefix: str = "c") -> Fields:
    """Every column of a :class:`skyfix.detect.Centroids` (and its frame-wide numbers)."""
    out: Fields = {}
    for name in ("x", "y", "flux", "area", "snr", "elongation", "peak", "sigma_x", "sigma_y", "saturated",
                 "cov_xy", "angle"):
        value = getattr(c, name, None)
        if value is not None:
            out[f"{prefix}.{name}"] = np.asarray(value)
    for name in ("background_level", "noise"):
        if hasattr(c, name):
            out[f"{prefix}.{name}"] = np.array(float(getattr(c, name)))
    out[f"{prefix}.n"] = np.array(len(c))
    return out


def solution_fields(sol: object, xy: np.ndarray, prefix: str) -> Fields:
    """Everything a :class:`skyfix.solution.Solution` holds but timings, under ``prefix.``; each match
    as the index of its centroid in ``xy`` (-1 when not found) and its catalogue id."""
    nan3 = np.full((3, 3), np.nan)
    A = getattr(sol, "A_icrs_to_cam", None)
    q = getattr(sol, "quaternion_xyzw", None)
    cov = getattr(sol, "covariance_arcsec2", None)
    bore = getattr(sol, "boresight_px", None) or [None, None]
    out: Fields = {
        "status": np.array(str(sol.status)),
        "reason": np.array(str(sol.reason or "")),
        "method": np.array(str(getattr(sol, "method", ""))),
        "n_detected": np.array(int(sol.n_detected)),
        "n_matched": np.array(int(sol.n_matched)),
        "A": nan3 if A is None else np.asarray(A, float),
        "q": np.full(4, np.nan) if q is None else np.asarray(q, float),
        "pointing_deg": np.array([_f(sol.ra_deg), _f(sol.dec_deg), _f(sol.roll_deg), _f(sol.fov_deg)]),
        "boresight_px": np.array([_f(bore[0]), _f(bore[1])]),
        "covariance_arcsec2": nan3 if cov is None else np.asarray(cov, float),
        "prob_false": np.array(_f(sol.prob_false)),
        "rmse_arcsec": np.array(_f(sol.rmse_arcsec)),
    }
    where = {}
    for i, (x, y) in enumerate(np.asarray(xy, float).reshape(-1, 2).tolist()):
        where.setdefault((x, y), i)
    matches = list(getattr(sol, "matches", []) or [])
    out["match_index"] = np.array([where.get((float(m.x), float(m.y)), -1) for m in matches], np.int64)
    out["match_id"] = np.array([int(m.id) for m in matches], np.int64)
    out["match_xy"] = np.array([[float(m.x), float(m.y)] for m in matches]).reshape(-1, 2)
    out["match_radec_mag_deg"] = np.array([[float(m.ra_deg), float(m.dec_deg), float(m.mag)]
                                           for m in matches]).reshape(-1, 3)
    out["match_residual_arcsec"] = np.array([float(m.residual_arcsec) for m in matches])
    cam = getattr(sol, "camera", None)
    names = ("width", "height", "fx", "fy", "cx", "cy", "skew", "k1", "k2", "k3", "p1", "p2")
    out["camera"] = np.array([_f(getattr(cam, n, None)) if cam is not None else np.nan for n in names])
    return {f"{prefix}.{k}": v for k, v in out.items()}


def _error(exc: BaseException) -> Fields:
    text = str(exc).splitlines()[0] if str(exc) else ""
    return {"error": np.array(f"{type(exc).__name__}: {text}")}


def _guarded(make: Callable[[], Fields]) -> Fields:
    """The fields ``make`` returns, or the error it raised (recorded, so that it is compared)."""
    try:
        return make()
    except Exception as exc:  # noqa: BLE001 - a crash is a result too (e.g. an API that changed)
        return _error(exc)


# --- the sections -------------------------------------------------------------------------------

Section = Iterator[tuple[str, Fields]]


def _real_images(limit: int | None) -> list[str]:
    path = REAL_DIR / "solutions.jsonl"
    if not path.is_file():
        raise UsageError(f"real images not found: no {path}")
    names = [json.loads(line)["image"] for line in path.read_text().splitlines() if line.strip()]
    return names if limit is None else names[:limit]


def real_section(plan: Plan) -> Section:
    from skyfix.detect import extract_centroids
    from skyfix.io import read_image
    from skyfix.pipeline import solve

    for name in _real_images(plan.real):
        def one(name: str = name) -> Fields:
            path = REAL_DIR / name
            c = extract_centroids(read_image(path), max_stars=200)  # as solve() extracts
            sol = solve(path, epoch=EPOCH, **WORK)
            return {**centroid_fields(c), **solution_fields(sol, c.xy, "sol")}

        yield name, _guarded(one)


def synthetic_specs(per_config: int) -> list:
    """The benchmark's configurations (``suite_synthetic.configs``) plus one with 30 % dropouts."""
    from suite_synthetic import configs

    specs = configs(per_config)
    return [*specs, replace(specs[-1], n_false=0, dropout=0.3, seed=specs[-1].seed + 10)]


def _synthetic_label(spec) -> str:
    return f"σ={spec.sigma_px:g}px false={spec.n_false} dropout={spec.dropout:g}"


def _synthetic_sets(spec) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``benchmarks/synthetic.py``'s sets from skyfix's shared generator, with the catalogue at
    :data:`EPOCH` (the benchmark's own sets use "now"): (xy, flux, A_true) per set."""
    from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
    from skyfix.camera import Camera
    from skyfix.catalog import load_hipparcos

    camera = Camera.from_fov(spec.width, spec.height, spec.fov_deg)
    catalog = load_hipparcos(epoch=EPOCH, mag_limit=spec.mag_limit)
    rng = np.random.default_rng(spec.seed)
    for A in random_attitudes(spec.n, rng):
        f = synthetic_centroids(camera, A, catalog, mag_limit=spec.mag_limit, sigma_px=spec.sigma_px,
                                n_false=spec.n_false, dropout=spec.dropout, mag_sigma=spec.mag_jitter,
                                rng=rng)
        yield (np.asarray(f.xy, float), 10.0 ** (-0.4 * np.asarray(f.mag, float)) * 1e4,
               np.asarray(f.A_icrs_to_cam, float))


def synthetic_section(plan: Plan) -> Section:
    from skyfix.pipeline import solve_centroids

    for spec in synthetic_specs(plan.synthetic_per_config):
        label = _synthetic_label(spec)
        sets = _synthetic_sets(spec)
        for k in range(spec.n):
            try:
                xy, flux, A_true = next(sets)
            except Exception as exc:  # noqa: BLE001 - the generator broke: the rest of this config too
                error = _error(exc)
                for j in range(k, spec.n):
                    yield f"{label} #{j:03d}", error
                break

            def one(xy: np.ndarray = xy, flux: np.ndarray = flux, A_true: np.ndarray = A_true,
                    spec=spec) -> Fields:
                out = {"in.xy": xy, "in.flux": flux, "in.A_true": A_true}
                for prefix, fov in (("fov", spec.fov_deg), ("nofov", None)):
                    sol = solve_centroids(xy, spec.width, spec.height, fov_deg=fov, epoch=EPOCH, **WORK)
                    out.update(solution_fields(sol, xy, prefix))
                return out

            yield f"{label} #{k:03d}", _guarded(one)


def rendered_names(plan: Plan) -> list[str]:
    sim = SIM_FRAMES if plan.sim_frames is None else SIM_FRAMES[:plan.sim_frames]
    bench = [f"bench-render {fov:g}° #{k}" for fov in BENCH_FOVS for k in range(plan.bench_frames_per_fov)]
    return [f"simulate {name}" for name, *_ in sim] + bench


def rendered_section(plan: Plan) -> Section:
    from skyfix.detect import extract_centroids
    from skyfix.pipeline import solve

    sim = SIM_FRAMES if plan.sim_frames is None else SIM_FRAMES[:plan.sim_frames]
    for name, preset, (ra, dec, roll), kw in sim:
        def one(preset: str = preset, ra: float = ra, dec: float = dec, roll: float = roll, kw: dict = kw
                ) -> Fields:
            from skyfix.simulate import render

            A = attitude_from_radec_roll_deg(ra, dec, roll)
            kw = dict(kw)
            if "rate_rad_s" in kw:
                kw["rate_rad_s"] = np.asarray(kw["rate_rad_s"], float)
            frame = render(A, preset, epoch=EPOCH, **kw)
            truth = json.dumps(frame.truth, sort_keys=True, default=str)
            out = {"hash.image": _sha256(frame.image), "hash.expected_e": _sha256(frame.expected_e),
                   "hash.truth": np.array(hashlib.sha256(truth.encode()).hexdigest())}
            c = extract_centroids(frame.image, max_stars=200)
            sol = solve(frame.image, epoch=EPOCH, **WORK)
            return {**out, **centroid_fields(c), **solution_fields(sol, c.xy, "sol")}

        yield f"simulate {name}", _guarded(one)

    if plan.bench_frames_per_fov <= 0:
        return
    from render import RenderSpec, StarSky, random_attitudes, render

    sky = StarSky(mag_limit=9.0, epoch=EPOCH)
    for fov in BENCH_FOVS:  # as suite_accuracy.py: one stream per FOV draws attitudes, then frames
        spec = RenderSpec(fov_deg=fov)
        rng = np.random.default_rng(7 + int(fov * 10))
        for k, A in enumerate(random_attitudes(plan.bench_frames_per_fov, rng)):
            img = render(A, sky, spec, rng)

            def one(img: np.ndarray = img, fov: float = fov) -> Fields:
                out = {"hash.image": _sha256(img)}
                c = extract_centroids(img, max_stars=200)
                out.update(centroid_fields(c))
                for prefix, hint in (("fov", fov), ("nofov", None)):
                    out.update(solution_fields(solve(img, fov_deg=hint, epoch=EPOCH, **WORK), c.xy, prefix))
                return out

            yield f"bench-render {fov:g}° #{k}", _guarded(one)


@contextlib.contextmanager
def _capture_solve_centroids() -> Iterator[list]:
    """Every ``solve_centroids`` call made meanwhile, as (xy, Solution) (the campaign keeps only a
    summary of each solution)."""
    import skyfix.analysis.blind_campaign as campaign
    import skyfix.pipeline as pipeline

    calls: list = []
    original = pipeline.solve_centroids

    def recording(xy, *args, **kw):
        sol = original(xy, *args, **kw)
        calls.append((np.array(xy, float), sol))
        return sol

    patched = [m for m in (pipeline, campaign) if getattr(m, "solve_centroids", None) is original]
    for m in patched:
        m.solve_centroids = recording
    try:
        yield calls
    finally:
        for m in patched:
            m.solve_centroids = original


def blind_section(plan: Plan, advance: Callable[[int], None]) -> Section:
    """The uncalibrated campaign runs in one call (its random stream is one sequence); its trials
    are yielded after it, ``advance`` moves the progress bar meanwhile."""
    if plan.blind <= 0:
        return
    from skyfix.analysis.blind_campaign import uncalibrated_centroid_trials

    with _capture_solve_centroids() as calls:  # an exception: every trial's error (record())
        trials = uncalibrated_centroid_trials(plan.blind, seed=plan.blind_seed, epoch=EPOCH, progress=advance)
    for k, t in enumerate(trials):
        out: Fields = {"trial.solved": np.array(bool(t.solved)), "trial.reason": np.array(str(t.reason)),
                       "trial.n_stars": np.array(int(t.n_stars)), "trial.fov_deg": np.array(float(t.fov_deg)),
                       "trial.error_rad": np.asarray(t.error_rad, float),
                       "trial.sigma_rad": np.asarray(t.sigma_rad, float),
                       "trial.plate_scale_arcsec": np.array(float(t.plate_scale_arcsec))}
        if len(calls) == len(trials):
            xy, sol = calls[k]
            out["in.xy"] = xy
            out.update(solution_fields(sol, xy, "sol"))
        else:
            out["note"] = np.array(f"{len(calls)} solve_centroids calls seen for {len(trials)} trials")
        yield f"trial #{k:03d}", out


def database_section(plan: Plan) -> Section:
    if plan.database_fov is None:
        return
    lo, hi = plan.database_fov

    def one() -> Fields:
        from skyfix.identify import PatternDatabase

        db = PatternDatabase.build(lo, hi, epoch=EPOCH)
        out: Fields = {"meta": np.array(json.dumps(db.meta, sort_keys=True, default=str))}
        for name, value in sorted(vars(db).items()):
            if isinstance(value, np.ndarray):
                out[f"hash.{name}"] = _sha256(value)
        return out

    yield f"patterns {lo:g}-{hi:g}°", _guarded(one)


def planned_names(plan: Plan) -> dict[str, list[str]]:
    """The names of the records each section makes."""
    lo, hi = plan.database_fov or (0.0, 0.0)
    return {"real": _real_images(plan.real),
            "synthetic": [f"{_synthetic_label(spec)} #{k:03d}"
                          for spec in synthetic_specs(plan.synthetic_per_config) for k in range(spec.n)],
            "rendered": rendered_names(plan),
            "blind": [f"trial #{k:03d}" for k in range(max(plan.blind, 0))],
            "database": [] if plan.database_fov is None else [f"patterns {lo:g}-{hi:g}°"]}


def record(plan: Plan = FULL, *, progress: bool = True) -> tuple[Records, dict]:
    """Run every section of ``plan``; the records and the metadata (where skyfix came from, times)."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    import skyfix

    planned = planned_names(plan)
    counts = {s: len(planned[s]) for s in SECTIONS}
    records: Records = {s: {} for s in SECTIONS}
    seconds: dict[str, float] = {}
    t_all = time.perf_counter()
    columns = (TextColumn("{task.description:<10}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=Console(stderr=True), disable=not progress) as bar:
        tasks = {s: bar.add_task(s, total=counts[s], start=False) for s in SECTIONS if counts[s]}
        for section in SECTIONS:
            if not counts[section]:
                continue
            task = tasks[section]
            bar.start_task(task)
            t0 = time.perf_counter()
            if section == "blind":
                items = blind_section(plan, lambda k, task=task: bar.advance(task, k))
            else:
                items = {"real": real_section, "synthetic": synthetic_section, "rendered": rendered_section,
                         "database": database_section}[section](plan)
            try:
                for name, fields in items:
                    records[section][name] = fields
                    if section != "blind":
                        bar.advance(task)
            except Exception as exc:  # noqa: BLE001 - e.g. an import broken by an edit: recorded as
                for name in planned[section]:  # the error of every record the section did not make
                    records[section].setdefault(name, _error(exc))
            bar.update(task, completed=counts[section])
            bar.stop_task(task)
            seconds[section] = round(time.perf_counter() - t0, 2)
    meta = {"format": FORMAT, "skyfix_file": str(Path(skyfix.__file__).resolve()),
            "skyfix_version": getattr(skyfix, "__version__", "?"), "git": _git_state(Path(skyfix.__file__)),
            "plan": plan.__dict__, "epoch": EPOCH, "python": platform.python_version(),
            "numpy": np.__version__, "seconds": seconds, "total_s": round(time.perf_counter() - t_all, 2),
            "made": time.strftime("%Y-%m-%d %H:%M:%S")}
    return records, meta


def _git_state(skyfix_file: Path) -> str:
    """``<commit>`` of the tree skyfix was imported from, ``+dirty`` with uncommitted changes in src."""
    src = skyfix_file.resolve().parent.parent
    try:
        def git(*args: str) -> str:
            return subprocess.run(["git", "-C", str(src), *args], capture_output=True, text=True, check=True,
                                  timeout=30).stdout.strip()

        head, dirty = git("rev-parse", "HEAD"), git("status", "--porcelain", "--", ".")
    except (OSError, subprocess.SubprocessError):
        return "?"
    return head[:12] + ("+dirty" if dirty else "")


# --- the npz file -------------------------------------------------------------------------------

_SEP = "|"


def save_record(path: str | Path, records: Records, meta: dict) -> None:
    arrays = {"__meta__": np.array(json.dumps(meta))}
    for section, recs in records.items():
        for name, fields in recs.items():
            for key, value in fields.items():
                arrays[_SEP.join((section, name, key))] = np.asarray(value)
    path = Path(path)
    tmp = path.with_name(path.name + ".part.npz")
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)


def load_record(path: str | Path) -> tuple[Records, dict]:
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"{path}: no such file")
    try:
        with np.load(path, allow_pickle=False) as z:
            if "__meta__" not in z.files:
                raise UsageError(f"{path}: not a record of same_results.py (no __meta__)")
            meta = json.loads(str(z["__meta__"]))
            records: Records = {s: {} for s in SECTIONS}
            for key in z.files:
                if key == "__meta__":
                    continue
                section, name, fname = key.split(_SEP, 2)
                records.setdefault(section, {}).setdefault(name, {})[fname] = z[key]
    except UsageError:
        raise
    except (OSError, ValueError, KeyError) as exc:
        raise UsageError(f"{path}: not a readable record ({type(exc).__name__}: {exc})") from None
    return records, meta


# --- comparison ---------------------------------------------------------------------------------

@dataclass
class SectionResult:
    n_base: int = 0
    n_new: int = 0
    identical: int = 0
    bit_exact: int = 0
    solved_base: int = 0
    solved_new: int = 0
    solves: int = 0
    max_attitude_arcsec: float = 0.0
    max_position_px: float = 0.0
    differences: list[tuple[str, list[str]]] = field(default_factory=list)


def _kind(key: str, a: np.ndarray) -> str:
    last = key.rsplit(".", 1)[-1]
    if a.dtype.kind not in "fc":
        return "exact"
    if last in _ATTITUDE_FIELDS:
        return "attitude"
    if last in _POSITION_FIELDS:
        return "position"
    return "number"


def _show(a: np.ndarray) -> str:
    if a.ndim == 0:
        s = repr(a.item())
    else:
        s = np.array2string(a, threshold=6, precision=6, separator=",").replace("\n", "")
    return s if len(s) <= 60 else s[:57] + "..."


def rotation_angle_arcsec(A: np.ndarray, B: np.ndarray) -> float:
    """Angle of the rotation between two attitude matrices (chord formula: exact when small)."""
    d = np.linalg.norm(np.asarray(A, float) - np.asarray(B, float))
    return float(2.0 * math.asin(min(d / (2.0 * math.sqrt(2.0)), 1.0)) * _ARCSEC)


def quaternion_angle_arcsec(p: np.ndarray, q: np.ndarray) -> float:
    d = min(np.linalg.norm(p - q), np.linalg.norm(p + q))
    return float(4.0 * math.asin(min(d / 2.0, 1.0)) * _ARCSEC)


def compare_fields(a: Fields, b: Fields) -> tuple[list[str], float, float, bool]:
    """Differences between two records' fields, the largest attitude difference (″), the largest
    position difference (px), and whether every field is bit for bit the same."""
    found: dict[str, str] = {}
    att = pos = 0.0
    exact = set(a) == set(b)
    for key in sorted(set(a) | set(b)):
        if key not in b:
            found[key] = f"{key}: only in BASE ({_show(a[key])})"
            continue
        if key not in a:
            found[key] = f"{key}: only in NEW ({_show(b[key])})"
            continue
        x, y = a[key], b[key]
        if x.shape != y.shape or x.dtype.kind != y.dtype.kind:
            exact = False
            found[key] = (f"{key}: shape {x.shape} → {y.shape}" if x.shape != y.shape
                          else f"{key}: type {x.dtype} → {y.dtype}")
            continue
        kind = _kind(key, x)
        if kind == "exact":
            if not np.array_equal(x, y):
                exact = False
                n = int(np.sum(x != y)) if x.ndim else 1
                found[key] = (_show_change(key, x, y) if x.ndim == 0 or x.size <= 4
                              else f"{key}: {n} of {x.size} differ")
            continue
        if not np.array_equal(x, y, equal_nan=True):
            exact = False
        both = np.isfinite(x) & np.isfinite(y)
        if not np.array_equal(x[~both], y[~both], equal_nan=True) or not np.array_equal(both, np.isfinite(y)):
            found[key] = f"{key}: finite/NaN pattern differs ({_show(x)} → {_show(y)})"
            continue
        diff = np.abs(x[both] - y[both])
        dmax = float(diff.max()) if diff.size else 0.0
        if kind == "attitude":
            angle = None
            if both.all() and x.shape in ((3, 3), (4,)):
                angle = rotation_angle_arcsec(x, y) if x.shape == (3, 3) else quaternion_angle_arcsec(x, y)
                att = max(att, angle)
            if dmax > ATTITUDE_TOL:
                found[key] = f"{key}: max |Δ| {dmax:.3g}" + (f" ({angle:.3g}″)" if angle is not None else "")
        elif kind == "position":
            pos = max(pos, dmax)
            if dmax > POSITION_TOL:
                found[key] = f"{key}: max |Δ| {dmax:.3g} px"
        else:
            scale = np.maximum(np.abs(x[both]), np.abs(y[both]))
            bad = diff > ATOL + RTOL * scale
            if bad.any():
                rel = float(np.max(diff / np.where(scale > 0, scale, 1.0)))
                found[key] = (f"{key}: max |Δ| {dmax:.3g} (relative {rel:.3g})"
                              + (f" {_show(x)} → {_show(y)}" if x.size == 1 else ""))
    return _summarise_notes(found, a, b), att, pos, exact


def _show_change(key: str, x: np.ndarray, y: np.ndarray) -> str:
    """``key: old → new``; two long strings from where they start to differ."""
    if x.ndim == 0 and x.dtype.kind == "U" and y.dtype.kind == "U":
        s, t = str(x), str(y)
        start = next((i for i, (c, d) in enumerate(zip(s, t, strict=False)) if c != d), min(len(s), len(t)))
        start = max(0, start - 12)

        def cut(u: str) -> str:
            return ("…" if start else "") + u[start:start + 70] + ("…" if len(u) > start + 70 else "")

        return f"{key}: {cut(s)!r} → {cut(t)!r}"
    return f"{key}: {_show(x)} → {_show(y)}"


def _order(key: str) -> int:
    """Rank of a field in the list of differences: errors, status, inputs, matches, attitude, rest."""
    last = key.rsplit(".", 1)[-1]
    ranks = (key == "error", last in ("status", "reason", "method", "solved"),
             key.startswith(("hash.", "in.")), last.startswith(("match_", "n_")), last in _ATTITUDE_FIELDS)
    return next((rank for rank, hit in enumerate(ranks) if hit), len(ranks))


def _summarise_notes(found: dict[str, str], a: Fields, b: Fields) -> list[str]:
    """The notes, most telling first; a solve whose status changed is one note (with the reason)
    instead of one per field that follows from it."""
    notes = []
    for key in [k for k in found if k.endswith(".status") and k in a and k in b]:
        prefix = key[:-len("status")]
        reasons = [str(f.get(prefix + "reason", "")) for f in (a, b)]
        why = next((f" ({r[:90]})" for r in reasons if r), "")
        consequent = [k for k in found if k.startswith(prefix) and k != key]
        for k in consequent:
            del found[k]
        notes.append(f"{_show_change(key, a[key], b[key])}{why}"
                     + (f" [+{len(consequent)} fields]" if consequent else ""))
        del found[key]
    return notes + [found[k] for k in sorted(found, key=lambda k: (_order(k), k))]


def compare_records(base: Records, new: Records) -> dict[str, SectionResult]:
    out: dict[str, SectionResult] = {}
    for section in [*SECTIONS, *sorted((set(base) | set(new)) - set(SECTIONS))]:
        a, b = base.get(section, {}), new.get(section, {})
        if not a and not b:
            continue
        r = SectionResult(n_base=len(a), n_new=len(b))
        for name in [*a, *(n for n in b if n not in a)]:
            if name not in b:
                r.differences.append((name, ["missing in NEW"]))
                continue
            if name not in a:
                r.differences.append((name, ["missing in BASE"]))
                continue
            for fields, attr in ((a[name], "solved_base"), (b[name], "solved_new")):
                statuses = [str(v) for k, v in fields.items() if k.endswith(".status")]
                setattr(r, attr, getattr(r, attr) + sum(s == "solved" for s in statuses))
            r.solves += sum(k.endswith(".status") for k in a[name])
            notes, att, pos, exact = compare_fields(a[name], b[name])
            r.max_attitude_arcsec = max(r.max_attitude_arcsec, att)
            r.max_position_px = max(r.max_position_px, pos)
            r.bit_exact += exact
            if notes:
                r.differences.append((name, notes))
            else:
                r.identical += 1
        out[section] = r
    return out


def print_comparison(results: dict[str, SectionResult], base_meta: dict, new_meta: dict,
                     show_all: bool = False) -> bool:
    """The table and the list of differences; True when the records are the same."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    console = Console(width=max(Console().width, 140), highlight=False)
    for label, meta in (("BASE", base_meta), ("NEW", new_meta)):
        console.print(f"{label}: skyfix {escape(meta.get('skyfix_file', '?'))} (git {meta.get('git', '?')}), "
                      f"recorded {meta.get('made', '?')} in {meta.get('total_s', float('nan')):.0f} s")
    if base_meta.get("plan") != new_meta.get("plan"):
        console.print("[yellow]the two records were made with different plans (e.g. one with --quick): "
                      "records missing on one side count as differences[/yellow]")
    table = Table(title="same results? (BASE → NEW)", title_justify="left")
    for i, col in enumerate(("section", "records", "identical", "bit-exact", "different", "solved",
                             "max attitude Δ (″)", "max position Δ (px)")):
        table.add_column(col, justify="left" if i == 0 else "right")
    same = True
    for section, r in results.items():
        n = max(r.n_base, r.n_new)
        differ = len(r.differences)
        same &= differ == 0
        style = "green" if differ == 0 else "red"
        records = str(n) if r.n_base == r.n_new else f"{r.n_base} → {r.n_new}"
        solved = (f"{r.solved_base}/{r.solves}" if r.solved_base == r.solved_new
                  else f"{r.solved_base} → {r.solved_new}/{r.solves}")
        table.add_row(section, records, f"[{style}]{r.identical}[/{style}]", str(r.bit_exact),
                      f"[{style}]{differ}[/{style}]", solved, f"{r.max_attitude_arcsec:.3g}",
                      f"{r.max_position_px:.3g}")
    console.print(table)
    for section, r in results.items():
        shown = r.differences if show_all else r.differences[:40]
        for name, notes in shown:
            more = f"; (+{len(notes) - 6} more)" if len(notes) > 6 else ""
            console.print(f"[red]≠[/red] {section} {escape(name)}: {escape('; '.join(notes[:6]))}{more}")
        if len(shown) < len(r.differences):
            console.print(f"  … and {len(r.differences) - len(shown)} more {section} differences "
                          "(--all lists them)")
    console.print("[green]SAME: every result identical[/green]" if same
                  else "[red]DIFFERENT: see the list above[/red]")
    return same


def compare(base_path: str | Path, new_path: str | Path, show_all: bool = False) -> int:
    """Compare two record files and print the result: 0 when the same, 1 when not."""
    base, base_meta = load_record(base_path)
    new, new_meta = load_record(new_path)
    return 0 if print_comparison(compare_records(base, new), base_meta, new_meta, show_all) else 1


# --- against a git ref ---------------------------------------------------------------------------

def _git(*args: str, cwd: Path = REPO_ROOT) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, timeout=300)


def _record_in_subprocess(src: Path, out: Path, quick: bool) -> dict:
    """``record`` in a fresh interpreter importing skyfix from ``src``; its metadata."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(src), *filter(None, [env.get("PYTHONPATH")])])
    cmd = [sys.executable, str(Path(__file__).resolve()), "record", str(out), "--expect-src", str(src)]
    if quick:
        cmd.append("--quick")
    print(f"\n$ PYTHONPATH={src} {' '.join(cmd[1:])}", flush=True)
    rc = subprocess.run(cmd, env=env, cwd=out.parent).returncode
    if rc != 0:
        raise UsageError(f"record with skyfix from {src} failed (exit {rc})")
    return load_record(out)[1]


def against(ref: str, quick: bool = False, keep: Path | None = None, show_all: bool = False) -> int:
    """Record ``ref`` (a git worktree) and the working tree, then compare them."""
    sha = _git("rev-parse", "--verify", "--quiet", f"{ref}^{{commit}}").stdout.strip()
    if not sha:
        raise UsageError(f"{ref!r} is not a commit of {REPO_ROOT}")
    if keep is not None and not keep.is_dir():
        raise UsageError(f"--keep {keep}: no such directory")
    tmp = Path(tempfile.mkdtemp(prefix="skyfix-same-results-"))
    tree = tmp / "tree"
    try:
        added = _git("worktree", "add", "--detach", "--quiet", str(tree), sha)
        if added.returncode != 0:
            raise UsageError(f"git worktree add failed: {added.stderr.strip().splitlines()[-1:]}")
        print(f"{ref} = {sha[:12]} checked out in {tree} (its kernels compile in a warm-up record first)")
        base_path, new_path = tmp / "base.npz", tmp / "new.npz"
        # A quick record first, thrown away, on each side: a tree's kernels compile on first use,
        # and a solve that waits for a compile can meet identification's 2 s wall-clock limit
        # and fail where a warm one solves (04ada99's synthetic #009 did, twice).
        for src in (tree / "src", REPO_ROOT / "src"):
            _record_in_subprocess(src, tmp / "warm-up.npz", True)
        base_meta = _record_in_subprocess(tree / "src", base_path, quick)
        new_meta = _record_in_subprocess(REPO_ROOT / "src", new_path, quick)
        print(f"\nskyfix of {ref}: {base_meta['skyfix_file']} (git {base_meta['git']})")
        print(f"skyfix of the working tree: {new_meta['skyfix_file']} (git {new_meta['git']})")
        if base_meta["skyfix_file"] == new_meta["skyfix_file"]:
            raise UsageError("both runs imported the same skyfix file: the comparison would prove nothing")
        if keep is not None:
            for p, label in ((base_path, sha[:12]), (new_path, "worktree")):
                shutil.copy2(p, keep / f"same-results-{label}.npz")
            print(f"records kept in {keep}")
        print()
        return compare(base_path, new_path, show_all)
    finally:
        if tree.exists():
            _git("worktree", "remove", "--force", str(tree))
        shutil.rmtree(tmp, ignore_errors=True)
        _git("worktree", "prune")


# --- command line --------------------------------------------------------------------------------

class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2 (argparse prints the usage too)
        raise UsageError(message)


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="same_results.py", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    r = sub.add_parser("record", help="run skyfix on the fixed set and write OUT.npz")
    r.add_argument("out", type=Path)
    r.add_argument("--quick", action="store_true", help="a subset (about a minute)")
    r.add_argument("--expect-src", type=Path, help="fail unless skyfix is imported from this directory")
    c = sub.add_parser("compare", help="compare two records; exit 0 only if the same")
    c.add_argument("base", type=Path)
    c.add_argument("new", type=Path)
    c.add_argument("--all", action="store_true", help="list every difference (default: 40 per section)")
    a = sub.add_parser("against", help="record git REF (a worktree) and the working tree, compare")
    a.add_argument("ref")
    a.add_argument("--quick", action="store_true", help="a subset (about a minute per record)")
    a.add_argument("--keep", type=Path, help="copy both records into this directory")
    a.add_argument("--all", action="store_true", help="list every difference")
    return p


def _record_command(out: Path, quick: bool, expect_src: Path | None) -> int:
    if out.suffix != ".npz":
        raise UsageError(f"{out}: the record is an .npz file")
    if not out.parent.resolve().is_dir():
        raise UsageError(f"{out.parent}: no such directory")
    _real_images(None)  # the real images are there
    try:
        import skyfix
    except Exception as exc:  # noqa: BLE001 - nothing to record without it
        raise UsageError(f"cannot import skyfix: {type(exc).__name__}: {exc}") from None

    where = Path(skyfix.__file__).resolve()
    print(f"skyfix imported from {where}", flush=True)
    if expect_src is not None and not where.is_relative_to(expect_src.resolve()):
        raise UsageError(f"skyfix was imported from {where}, not from {expect_src} (PYTHONPATH shadowed?)")
    records, meta = record(QUICK if quick else FULL)
    save_record(out, records, meta)
    per = ", ".join(f"{s} {t:.0f} s" for s, t in meta["seconds"].items())
    print(f"wrote {out}: {sum(map(len, records.values()))} records in {meta['total_s']:.0f} s ({per})")
    return 0


def main(argv: list[str] | None = None) -> int:
    try:
        args = _parser().parse_args(argv)
        if args.command == "record":
            return _record_command(args.out, args.quick, args.expect_src)
        if args.command == "compare":
            return compare(args.base, args.new, args.all)
        return against(args.ref, args.quick, args.keep, args.all)
    except UsageError as exc:
        print(f"same_results.py: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("same_results.py: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
