"""Run every benchmark suite, side by side with the peers, and write benchmarks/results/*.json.

    python benchmarks/run_all.py [--quick] [--suites abcd] [--n 1000] ...

(normally through ``benchmarks/run``, which makes the peers' venv first). Suites:
  a  real images (shared/data/real), end to end           suite_real.py
  b  synthetic centroids, solve from centroids            suite_synthetic.py
  c  accuracy on frames from an independent renderer      suite_accuracy.py
  d  extraction ms/MP, end-to-end time, database build/load suite_speed.py
  e  blind solves: wrong attitudes, honest error bars (skyfix) suite_blind.py  (not in the default set)
  f  tracking update vs lost in space on the same frames      suite_track.py  (not in the default set)
  g  any field 2-90 deg with no hint, band builds (skyfix)     suite_fields.py (not in the default set)
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


def make_tools(which: list[str], min_fov: float = 10.0) -> tuple[dict, dict]:
    """Adapters by name, and the reasons any of them could not be made."""
    tools, missing = {}, {}
    for name in which:
        try:
            if name == "skyfix":
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
        for s in sets:
            try:
                tool.solve_centroids(s.xy, 1280, 960, 15.0, flux=s.flux)
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
    ap.add_argument("--tools", default="skyfix,tetra3rs,tetra3rs-mme,cedar-solve",
                    help="comma-separated subset of tools")
    args = ap.parse_args(argv)
    n = args.n or (100 if args.quick else 1000)
    images = args.images or (6 if args.quick else 50)
    repeats = args.repeats or (1 if args.quick else 3)
    wanted = [t.strip() for t in args.tools.split(",") if t.strip()]

    info = machine_info()
    tools, missing = make_tools(wanted)
    info["missing_tools"] = missing
    say(f"[bold]skyfix benchmarks[/bold]  {info['time_utc']}  cpus={info['cpus']} "
        f"load={tuple(round(x, 1) for x in info['loadavg_start'])}")
    print_table("tools", ["tool", "version", "database load ms", "note"],
                [[k, getattr(v, "version", "?"), getattr(v, "load_ms", float("nan")), getattr(v, "note", "")]
                 for k, v in tools.items()]
                + [[k, "—", "—", f"unavailable: {why}"] for k, why in missing.items()])
    warm_up(tools)
    results = {"machine": info, "args": vars(args)}
    t_start = time.time()
    for key in args.suites:
        t0 = time.time()
        try:
            if key == "a":
                import suite_real

                results["real_images"] = suite_real.run(tools, repeats=repeats, peer_fov=args.peer_fov)
                write_json("real_images", results["real_images"])
            elif key == "b":
                import suite_synthetic

                results["synthetic_centroids"] = suite_synthetic.run(tools, n=n, n_cedar=args.n_cedar)
                write_json("synthetic_centroids", results["synthetic_centroids"])
            elif key == "c":
                import suite_accuracy

                # tetra3rs gets a database reaching down to 8°; skyfix keeps its default one.
                acc_tools = dict(tools)
                wide = [t for t in wanted if t.startswith("tetra3rs")]
                acc_tools.update(make_tools(wide, min_fov=8.0)[0])
                results["accuracy_render"] = suite_accuracy.run(acc_tools, n_images=images)
                write_json("accuracy_render", results["accuracy_render"])
            elif key == "d":
                import suite_speed

                results["speed"] = suite_speed.run(tools, repeats=max(3, repeats + 2))
                write_json("speed", results["speed"])
            elif key == "e":
                import suite_blind

                results["blind"] = suite_blind.run(
                    n_blind=args.n_blind or (500 if args.quick else 10_000),
                    n_preset=args.n_preset or (20 if args.quick else 500))
                write_json("blind", results["blind"])
            elif key == "f":
                import suite_track

                results["tracking"] = suite_track.run(n_frames=10 if args.quick else 20,
                                                      repeats=2 if args.quick else 5)
                write_json("tracking", results["tracking"])
            elif key == "g":
                import suite_fields

                results["fields"] = suite_fields.run(n=20 if args.quick else 100,
                                                     n_images=3 if args.quick else 10)
                write_json("fields", results["fields"])
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
    write_json("targets", {"targets": results["targets"], "machine": info})
    info["loadavg_end"] = os.getloadavg()
    info["wall_s"] = time.time() - t_start
    write_json("machine", info)
    say(f"results in {RESULTS_DIR}/ (wall {info['wall_s']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
