"""Monte Carlo trials per second on one core (issue 27, throughput), this tree against another
commit in the same run, and whether the two give the same rows.

Run: ``PYTHONPATH=src .venv/bin/python benchmarks/montecarlo_throughput.py
[--campaign campaigns/quick.toml] [--trials N] [--against main] [--batch B] [--set KEY=VALUE …]``

One process, no Dask: whole batches (:func:`skyfix.montecarlo.trials.run_batch`) of the
campaign are run alternately by this tree's code and by ``--against``'s — its trial code and the
modules this work changed (:data:`_MODULES`, ``git show REF:…``) loaded as modules of their own
and swapped in for its calls, with every name other modules imported from them, so both sides
share everything else (catalogue, solver, kernels) — after one warm-up batch each. Printed per
side: trials per second (the trials over the sum of the batches' wall times), and the mean per
trial of the whole trial, the simulation and the solve, and the rest (seeding, the true
attitude, the prediction, the judgement). Then whether every row is the same on both sides
(the times, and the columns one side lacks, left out). ``--set hint=truth`` (any
``[parameters]`` value) changes the campaign first. The machine is shared: compare the two
columns of one run, not runs.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import importlib.util
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tomllib

ROOT = Path(__file__).resolve().parents[1]
#: What --against replaces: the trial code and the modules it times that this work changed.
_MODULES = ("skyfix.montecarlo.trials", "skyfix.montecarlo.budget", "skyfix.simulate.psf",
            "skyfix.simulate.render", "skyfix.simulate.sensor", "skyfix.calibrate")
_TIMES = ("simulate_ms", "time_ms")


def modules_at(ref: str) -> dict[str, object]:
    """The modules of :data:`_MODULES` as they are at commit ``ref``, as modules of their own."""
    folder = Path(tempfile.mkdtemp(prefix="skyfix-montecarlo-"))
    out = {}
    for name in _MODULES:
        text = subprocess.run(["git", "-C", str(ROOT), "show", f"{ref}:src/{name.replace('.', '/')}.py"],
                              check=True, capture_output=True, text=True).stdout
        path = folder / f"{name.replace('.', '_')}_before.py"
        path.write_text(text)
        spec = importlib.util.spec_from_file_location(path.stem, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        spec.loader.exec_module(module)
        out[name] = module
    return out


def _bindings(after: dict[str, object], before: dict[str, object]) -> list[tuple[object, str, str, str]]:
    """Every function another skyfix module imported from a module of ``after`` (``from X import
    f``) that ``before``'s has too: (that module, the name there, the module it came from, its
    name there)."""
    found = []
    origin = {id(v): (mod, k) for mod, m in after.items() for k, v in vars(m).items()
              if callable(v) and not isinstance(v, type) and getattr(v, "__module__", None) == mod
              and hasattr(before[mod], k)}
    ours = {m.__name__ for m in before.values()}  # REF's modules import from the others too
    for name, m in list(sys.modules.items()):
        if not (name.startswith("skyfix.") or name in ours) or name in after or m is None:
            continue
        for k, v in list(vars(m).items()):
            if id(v) in origin:
                found.append((m, k, *origin[id(v)]))
    return found


@contextlib.contextmanager
def swapped(side: dict[str, object], after: dict[str, object], bindings: list):
    """Inside, the modules of ``side`` are imported (the trial code imports lazily) and every name
    other modules took from them is ``side``'s."""
    sys.modules.update(side)
    for m, k, mod, name in bindings:
        setattr(m, k, getattr(side[mod], name))
    try:
        yield
    finally:
        sys.modules.update(after)
        for m, k, mod, name in bindings:
            setattr(m, k, getattr(after[mod], name))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--campaign", type=Path, default=ROOT / "campaigns" / "quick.toml")
    ap.add_argument("--trials", type=int, default=400, help="trials per side (default 400)")
    ap.add_argument("--batch", type=int, default=None, help="trials per batch (default the campaign's)")
    ap.add_argument("--against", default="main", help="the commit to compare with (default main)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a [parameters] value (TOML), e.g. hint=\"truth\"")
    args = ap.parse_args(argv)
    import importlib

    from skyfix.montecarlo.campaign import campaign_from_dict, load_campaign

    data = tomllib.loads(args.campaign.read_text())
    for item in args.set:
        data.setdefault("parameters", {}).update(tomllib.loads(item))
    campaign = campaign_from_dict(data, base=args.campaign.parent, source=str(args.campaign))
    load_campaign(args.campaign)  # the file itself is valid too
    batch = args.batch or campaign.batch_size
    campaign = dataclasses.replace(campaign, trials=args.trials + batch, batch_size=batch)
    import skyfix.analysis.truth  # noqa: F401 (imports what it binds before the bindings are listed)
    import skyfix.simulate  # noqa: F401

    after = {n: importlib.import_module(n) for n in _MODULES}
    sides = {"before": modules_at(args.against), "after": after}
    bindings = _bindings(after, sides["before"])
    for side in sides.values():  # set-up (catalogue) out of the timing
        side["skyfix.montecarlo.trials"].setup_for(campaign)
    walls: dict[str, list[float]] = {s: [] for s in sides}
    rows: dict[str, list[dict]] = {s: [] for s in sides}
    per_trial: dict[str, list[float]] = {s: [] for s in sides}
    for k in range(campaign.n_batches):
        for side in (sides if k % 2 else reversed(list(sides))):
            with swapped(sides[side], after, bindings):
                t0 = time.perf_counter()
                got = sides[side]["skyfix.montecarlo.trials"].run_batch(campaign, k)
                wall = time.perf_counter() - t0
            if k == 0:
                continue  # warm-up
            walls[side].append(wall)
            rows[side] += got
            per_trial[side].append(1e3 * wall / len(got))
    n = len(rows["after"])
    print(f"{campaign.name} ({campaign.level} level), {n} trials a side in batches of {batch}, "
          f"before = {args.against}; {' '.join(args.set)}")
    print(f"{'':8s} {'trials/s':>9s} {'ms/trial':>9s} {'simulate':>9s} {'solve':>9s} {'rest':>9s}")
    rate = {}
    for side in sides:
        rate[side] = n / sum(walls[side])
        sim, solve = (np.array([r.get(t, math.nan) for r in rows[side]]) for t in _TIMES)
        whole = 1e3 / rate[side]
        print(f"{side:8s} {rate[side]:9.1f} {whole:9.3f} {np.nanmean(sim):9.3f} {np.nanmean(solve):9.3f} "
              f"{whole - np.nanmean(sim) - np.nanmean(solve):9.3f}")
    print(f"after / before: {rate['after'] / rate['before']:.2f}× the trials per second (means per trial)")
    pairs = zip(rows["before"], rows["after"], strict=True)
    same = all(_comparable(a, b) == _comparable(b, a) for a, b in pairs)
    print(f"rows equal (times and the columns one side lacks left out): {same}")
    return 0 if same or args.set else 1


def _comparable(row: dict, other: dict) -> dict:
    """``row`` without its times and the columns ``other`` lacks, NaN as None."""
    return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()
            if k not in _TIMES and k in other}


if __name__ == "__main__":
    sys.exit(main())
