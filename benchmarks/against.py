"""``benchmarks/run --against REF``: the working tree and commit REF in the same run, and the ratios.

- :func:`ref_tree` makes (or reuses) a detached ``git worktree`` of REF, by default
  ``benchmarks/.cache/ref-<sha12>``; REF's numba cache lives there (the first run compiles).
- :func:`sides` starts one worker per side (``remote.Worker``: the working tree's ``src`` or
  REF's first on ``PYTHONPATH``); the suites get them as two skyfix tools, ``skyfix`` (the tree)
  and ``skyfix@<sha7>`` (REF), and hand both the same inputs, alternating.
- Each suite turns its results into :class:`Measure` rows (``against_measures``);
  :func:`print_comparison` prints tree / REF for every one and flags a regression: a median more
  than :data:`TOLERANCE` worse, or any count worse (fewer solved, more wrong). p99s are shown,
  not flagged (a few slow calls in hundreds move them).
"""

from __future__ import annotations

import math
import subprocess
from pathlib import Path
from typing import NamedTuple

from common import CACHE_DIR, REPO_ROOT
from report import print_table

TOLERANCE = 0.10  # issue 22: a median more than 10 % worse is a regression


class Measure(NamedTuple):
    """One figure on both sides. ``kind``: ``median`` (flagged beyond TOLERANCE), ``p99`` (shown),
    ``count`` (flagged if worse at all), ``info`` (shown). ``better``: ``lower`` or ``higher``."""

    suite: str
    name: str
    tree: float
    ref: float
    kind: str = "median"
    better: str = "lower"

    @property
    def ratio(self) -> float:
        t, r = float(self.tree), float(self.ref)
        if not (math.isfinite(t) and math.isfinite(r)):
            return math.nan
        if r == 0:
            return 1.0 if t == 0 else math.inf
        return t / r

    @property
    def flag(self) -> str:
        if self.kind == "count":
            worse = self.tree > self.ref if self.better == "lower" else self.tree < self.ref
            return "WORSE" if worse else ""
        q = self.ratio
        if not math.isfinite(q):
            return "" if self.tree == self.ref else "CHANGED"
        if self.kind == "median":
            limit = 1 + TOLERANCE if self.better == "lower" else 1 / (1 + TOLERANCE)
            if (q > limit) if self.better == "lower" else (q < limit):
                return f"REGRESSION {abs(q - 1):.0%}"
        return ""


def _git(*args: str, cwd: Path = REPO_ROOT) -> str:
    r = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, timeout=600)
    if r.returncode:
        raise RuntimeError(f"git {' '.join(args)}: {r.stderr.strip()}")
    return r.stdout.strip()


def resolve(ref: str) -> str:
    """The commit ``ref`` names (full sha)."""
    return _git("rev-parse", "--verify", f"{ref}^{{commit}}")


def ref_tree(sha: str, where: Path | None = None) -> Path:
    """A detached worktree of ``sha`` (reused when it is already there at that commit)."""
    path = Path(where) if where is not None else CACHE_DIR / f"ref-{sha[:12]}"
    if (path / "src" / "skyfix").is_dir():
        if _git("rev-parse", "HEAD", cwd=path) != sha:
            raise RuntimeError(f"{path} exists but is not at {sha[:12]}")
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    _git("worktree", "add", "--detach", "--quiet", str(path), sha)
    return path


def remove_ref_tree(path: Path) -> None:
    """Remove a worktree made by :func:`ref_tree` (the default ones are kept for reuse)."""
    _git("worktree", "remove", "--force", str(path))


class Side(NamedTuple):
    label: str  # the tool's name in the tables: "skyfix" (the tree) or "skyfix@<sha7>"
    src: Path
    root: Path  # the checkout (pyproject.toml, examples/)
    commit: str  # sha, or "working tree"


def tree_side() -> Side:
    return Side("skyfix", REPO_ROOT / "src", REPO_ROOT, "working tree")


def ref_side(ref: str, where: Path | None = None) -> Side:
    sha = resolve(ref)
    root = ref_tree(sha, where)
    return Side(f"skyfix@{sha[:7]}", root / "src", root, sha)


def start_tools(sides: list[Side]) -> tuple[dict, list]:
    """One worker-backed skyfix tool per side (name → tool), and the workers (to close)."""
    from remote import RemoteSkyfix, Worker

    tools, workers = {}, []
    for side in sides:
        w = Worker(side.label, side.src)
        workers.append(w)
        tools[side.label] = RemoteSkyfix(w, side.label)
    return tools, workers


def print_comparison(measures: list[Measure], tree: Side, ref: Side) -> list[dict]:
    """The tree / REF table; returns its rows (for the results file)."""
    rows = [{**m._asdict(), "ratio": m.ratio, "flag": m.flag} for m in measures]
    if not rows:
        return rows
    print_table(f"working tree / {ref.label} ({ref.commit[:12]}), same run, same inputs, interleaved",
                ["suite", "measure", "tree", "REF", "tree/REF", "flag"],
                [[r["suite"], r["name"], r["tree"], r["ref"], r["ratio"], r["flag"]] for r in rows],
                note=f"flag: a median > {TOLERANCE:.0%} worse (REGRESSION), a count worse (WORSE); "
                     "p99 rows are shown, not flagged")
    medians = [r["ratio"] for r in rows if r["kind"] == "median" and math.isfinite(r["ratio"])]
    if medians:
        from report import say

        flagged = sum(bool(r["flag"]) for r in rows)
        say(f"medians tree/REF: {len(medians)} measures, ratios {min(medians):.3f}–{max(medians):.3f}; "
            f"{flagged} flagged")
    return rows
