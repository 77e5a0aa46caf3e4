"""Run every benchmark suite, side by side with the peers, and write benchmarks/results/*.json.

    python benchmarks/run_all.py [--quick] [--suites abcd] [--n 1000] ...
    python benchmarks/run_all.py --against REF [--suites bd] ...   # working tree vs commit REF

(normally through ``benchmarks/run``, which makes the peers' venv first). Suites:
  a  real images (shared/data/real), end to end           suite_real.py
  b  synthetic centroids, solve from centroids            suite_synthetic.py
  c  accuracy on frames from an independent renderer      suite_accuracy.py
  d  extraction ms/MP, end-to-end time, database build/load suite_speed.py
  e  blind solves: wrong attitudes, honest error bars (skyfix) suite_blind.py  (not in the default set)
  f  tracking update vs lost in space on the same frames      suite_track.py  (not in the default set)
  g  any field 2-90 deg with no hint, band builds (skyfix)     suite_fields.py (not in the default set)
  h  start-up: --version, -h, whole-process solve, first vs later solve (skyfix)
                                                               suite_startup.py (not in the default set;
                                                               --cold, --first-use add the slow ones)

--against REF runs the chosen suites (a b c d f h) for the working tree and for commit REF in
the same run — each side's skyfix in its own worker process, fed the same inputs, alternating —
and prints tree / REF for every measure, flagging a median more than 10 % worse (against.py).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

from common import RESULTS_DIR, write_json  # noqa: E402
from report import print_table, say  # noqa: E402

AGAINST_SUITES = "abcdfh"  # the suites --against can run (e and g count results: benchmarks/same-results)


def make_tools(which: list[str], min_fov: float = 10.0, skyfix_sides: dict | None = None
               ) -> tuple[dict, dict]:
    """Adapters by name, and the reasons any of them could not be made. ``skyfix_sides``: the
    worker-backed skyfix tools of ``--against`` (they replace the in-process one)."""
    tools, missing = {}, {}
    for name in which:
        try:
            if name == "skyfix" and skyfix_sides is not None:
                tools.update(skyfix_sides)
            elif name == "skyfix":
                from skyfix_adapter import Skyfix

                tools[name] = Skyfix()
            elif name == "tetra3rs":
                from peers import Tetra3rs

                tools[name] = Tetra3rs(min_fov_deg=min_fov)
            elif name == "tetra3rs-mme":
                from peers import Tetra3rs

                t = Tetra3rs(min_fov_deg=min_fov, match_max_error=0.002)
                tools[t.name] = t
            elif name == "cedar-solve":
                from peers import Cedar

                tools[name] = Cedar()
        except Exception as exc:  # noqa: BLE001 - report which tool is unavailable and why
            missing[name] = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
            if os.environ.get("BENCH_DEBUG"):
                traceback.print_exc()
    return tools, missing


def warm_up(tools: dict) -> None:
    """One solve per tool before any timing (numba compilation, lazy imports, page faults)."""
    from synthetic import SyntheticSpec, centroid_sets

    sets, _ = centroid_sets(SyntheticSpec(n=3, seed=99, sigma_px=0.5, n_false=3))
    for tool in tools.values():
        # skyfix also without a FOV (suites b and c run it so): its first call compiles more.
        for fov in (15.0, None) if getattr(tool, "is_skyfix", False) else (15.0,):
            for s in sets:
                try:
                    tool.solve_centroids(s.xy, 1280, 960, fov, flux=s.flux)
                except Exception:  # noqa: BLE001 - the suites will report it
                    pass
    from render import RenderSpec, StarSky, random_attitudes, render

    rng = np.random.default_rng(0)
    img = render(random_attitudes(1, rng)[0], StarSky(9.0), RenderSpec(), rng)
    for tool in tools.values():
        try:
            tool.solve_image(img, fov_deg=15.0)
        except Exception:  # noqa: BLE001
            pass


def compare(results: dict, sides: list) -> list[dict]:
    """Every suite's tree / REF measures, printed as one table (against.print_comparison)."""
    import against

    measures = []
    for key, module in (("real_images", "suite_real"), ("synthetic_centroids", "suite_synthetic"),
                        ("accuracy_render", "suite_accuracy"), ("speed", "suite_speed"),
                        ("tracking", "suite_track"), ("startup", "suite_startup")):
        if key in results:
            try:
                measures += __import__(module).against_measures(results[key], sides[0].label, sides[1].label)
            except Exception:  # noqa: BLE001 - one suite's table must not hide the others
                say(f"[red]{module}: no comparison[/red]")
                traceback.print_exc()
    return against.print_comparison(measures, sides[0], sides[1])


def machine_info() -> dict:
    info = {"python": sys.version.split()[0], "platform": platform.platform(), "cpus": os.cpu_count(),
            "loadavg_start": os.getloadavg(), "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    try:
        from importlib.metadata import version

        for pkg in ("tetra3rs", "cedar-solve", "numpy", "scipy", "numba", "skyfix"):
            try:
                info[pkg] = version(pkg)
            except Exception:  # noqa: BLE001
                info[pkg] = None
    except ImportError:
        pass
    return info


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small N everywhere (~100 attitudes per config)")
    ap.add_argument("--suites", default="abcd", help="which suites to run, e.g. 'ab' (default: abcd)")
    ap.add_argument("--n", type=int, default=None, help="attitudes per synthetic config (default 1000)")
    ap.add_argument("--n-cedar", type=int, default=None,
                    help="cap cedar-solve's share of each synthetic config (it is slow); default: all")
    ap.add_argument("--images", type=int, default=None,
                    help="rendered frames per FOV in suite c (default 50)")
    ap.add_argument("--repeats", type=int, default=None, help="timing repeats (default 3; quick 1)")
    ap.add_argument("--peer-fov", choices=["hint", "mid"], default="hint",
                    help="real images: give peers the reference FOV (hint) or none/mid-range (mid)")
    ap.add_argument("--n-blind", type=int, default=None,
                    help="suite e: uncalibrated centroid trials (default 10000; quick 500)")
    ap.add_argument("--n-preset", type=int, default=None,
                    help="suite e: rendered frames per preset and scene (default 500; quick 20)")
    ap.add_argument("--workers", type=int, default=0,
                    help="suites e and g: trials on N local worker processes (campaign engine; default 0: "
                         "in this process)")
    ap.add_argument("--scheduler", metavar="ADDRESS", default=None,
                    help="suites e and g: trials on the Dask scheduler at tcp://HOST:PORT instead")
    ap.add_argument("--tools", default=None,
                    help="comma-separated subset of tools (default: skyfix,tetra3rs,tetra3rs-mme,"
                         "cedar-solve; with --against: skyfix)")
    ap.add_argument("--against", metavar="REF", default=None,
                    help="also run git commit REF (a worktree in benchmarks/.cache/ref-<sha>) in the "
                         "same run, interleaved, and print tree/REF ratios")
    ap.add_argument("--ref-tree", type=Path, default=None,
                    help="where REF's worktree goes (default benchmarks/.cache/ref-<sha12>, kept for reuse)")
    ap.add_argument("--batch", type=int, default=None,
                    help="suite b: centroid sets per turn of each tool (default 1; 10 with --against)")
    ap.add_argument("--best-of", type=int, default=None,
                    help="suite b: solve each set this many times in a row (every tool) and report the "
                         "median of the fastest too (default 1; 3 with --against, where it is flagged)")
    ap.add_argument("--startup-n", type=int, default=None,
                    help="suite h: runs per measure (default 5; quick 3)")
    ap.add_argument("--startup", default="cli,process,in-process",
                    help="suite h: which of cli,process,in-process to run (default all)")
    ap.add_argument("--cold", action="store_true",
                    help="suite h: the first solve of a fresh install on an empty cache (~2 min a side)")
    ap.add_argument("--first-use", action="store_true",
                    help="suite h: the first use of each other path, solve path compiled (minutes a side)")
    args = ap.parse_args(argv)
    n = args.n or (100 if args.quick else 1000)
    images = args.images or (6 if args.quick else 50)
    repeats = args.repeats or (1 if args.quick else 3)
    tools_arg = args.tools or ("skyfix" if args.against else "skyfix,tetra3rs,tetra3rs-mme,cedar-solve")
    wanted = [t.strip() for t in tools_arg.split(",") if t.strip()]
    alternate = args.against is not None
    batch = args.batch or (10 if alternate else 1)
    args.best_of = args.best_of or (3 if alternate else 1)

    info = machine_info()
    sides, workers, skyfix_sides = [], [], None
    if args.against:
        import against

        skipped = "".join(k for k in args.suites if k not in AGAINST_SUITES)
        if skipped:
            say(f"--against runs suites {AGAINST_SUITES}; skipping {skipped} "
                "(benchmarks/same-results compares results)")
            args.suites = "".join(k for k in args.suites if k in AGAINST_SUITES)
        sides = [against.tree_side(), against.ref_side(args.against, args.ref_tree)]
        if any(k != "h" for k in args.suites) and "skyfix" in wanted:
            skyfix_sides, workers = against.start_tools(sides)
            info["sides"] = {s.label: {"commit": s.commit, **w.info}
                             for s, w in zip(sides, workers, strict=True)}
        else:
            info["sides"] = {s.label: {"commit": s.commit, "src": str(s.src)} for s in sides}
        say(f"[bold]--against {args.against}[/bold]: working tree = skyfix, {sides[1].commit[:12]} = "
            f"{sides[1].label} (worktree {sides[1].root})")
    try:
        return _run(args, info, wanted, skyfix_sides, sides, n, images, repeats, alternate, batch)
    finally:
        for w in workers:
            w.close()


def _run(args, info: dict, wanted: list[str], skyfix_sides: dict | None, sides: list, n: int, images: int,
         repeats: int, alternate: bool, batch: int) -> int:
    prefix = f"against-{sides[1].commit[:7]}/" if args.against else ""
    tools, missing = make_tools(wanted, skyfix_sides=skyfix_sides) if set(args.suites) - {"h"} else ({}, {})
    info["missing_tools"] = missing
    say(f"[bold]skyfix benchmarks[/bold]  {info['time_utc']}  cpus={info['cpus']} "
        f"load={tuple(round(x, 1) for x in info['loadavg_start'])}")
    print_table("tools", ["tool", "version", "database load ms", "note"],
                [[k, getattr(v, "version", "?"), getattr(v, "load_ms", float("nan")), getattr(v, "note", "")]
                 for k, v in tools.items()]
                + [[k, "—", "—", f"unavailable: {why}"] for k, why in missing.items()])
    warm_up(tools)
    results = {"machine": info,
               "args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()}}
    t_start = time.time()
    for key in args.suites:
        t0 = time.time()
        try:
            if key == "a":
                import suite_real

                results["real_images"] = suite_real.run(tools, repeats=repeats, peer_fov=args.peer_fov,
                                                        alternate=alternate)
                write_json(prefix + "real_images", results["real_images"])
            elif key == "b":
                import suite_synthetic

                results["synthetic_centroids"] = suite_synthetic.run(tools, n=n, n_cedar=args.n_cedar,
                                                                     batch=batch, alternate=alternate,
                                                                     reps=args.best_of)
                write_json(prefix + "synthetic_centroids", results["synthetic_centroids"])
            elif key == "c":
                import suite_accuracy

                # tetra3rs gets a database reaching down to 8°; skyfix keeps its default one.
                acc_tools = dict(tools)
                wide = [t for t in wanted if t.startswith("tetra3rs")]
                acc_tools.update(make_tools(wide, min_fov=8.0)[0])
                results["accuracy_render"] = suite_accuracy.run(acc_tools, n_images=images,
                                                                alternate=alternate)
                write_json(prefix + "accuracy_render", results["accuracy_render"])
            elif key == "d":
                import suite_speed

                results["speed"] = suite_speed.run(tools, repeats=max(3, repeats + 2), alternate=alternate)
                write_json(prefix + "speed", results["speed"])
            elif key == "e":
                import suite_blind

                results["blind"] = suite_blind.run(
                    n_blind=args.n_blind or (500 if args.quick else 10_000),
                    n_preset=args.n_preset or (20 if args.quick else 500), workers=args.workers,
                    scheduler=args.scheduler)
                write_json("blind", results["blind"])
            elif key == "f":
                import suite_track

                results["tracking"] = suite_track.run(n_frames=10 if args.quick else 20,
                                                      repeats=2 if args.quick else 5,
                                                      tools=skyfix_sides)
                write_json(prefix + "tracking", results["tracking"])
            elif key == "g":
                import suite_fields

                results["fields"] = suite_fields.run(n=20 if args.quick else 100,
                                                     n_images=3 if args.quick else 10, workers=args.workers,
                                                     scheduler=args.scheduler)
                write_json("fields", results["fields"])
            elif key == "h":
                import against
                import suite_startup

                measures = tuple(m.strip() for m in args.startup.split(",") if m.strip())
                results["startup"] = suite_startup.run(
                    sides or [against.tree_side()], n=args.startup_n or (3 if args.quick else 5),
                    measures=measures, cold_start=args.cold, first_uses=args.first_use)
                write_json(prefix + "startup", results["startup"])
            else:
                say(f"unknown suite {key!r}")
                continue
        except Exception:  # noqa: BLE001 - one broken suite must not hide the others
            say(f"[red]suite {key} crashed[/red]")
            traceback.print_exc()
            results[f"suite_{key}_error"] = traceback.format_exc()
        say(f"suite {key}: {time.time() - t0:.0f} s")
    import targets

    results["targets"] = targets.check(results)
    targets.print_targets(results["targets"])
    write_json(prefix + "targets", {"targets": results["targets"], "machine": info})
    if args.against:
        results["against"] = compare(results, sides)
        write_json(prefix + "against", {"rows": results["against"], "machine": info,
                                        "args": results["args"]})
    info["loadavg_end"] = os.getloadavg()
    info["wall_s"] = time.time() - t_start
    write_json(prefix + "machine", info)
    say(f"results in {RESULTS_DIR}/ (wall {info['wall_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
