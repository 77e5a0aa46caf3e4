"""Every failure reason the solver can form has a next step, and docs/failures.md lists every
kind (skyfix.failures)."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from skyfix.failures import FAILURES, failure_kind, next_step, step_to_add
from skyfix.solution import Solution

ROOT = Path(__file__).resolve().parents[2]
SRC = ROOT / "src" / "skyfix"
# Where a solve's reasons are formed: identification (lost in space, the hint, every method, the
# acceptance rules), the pipeline, the parity retry, the frame checks, the final fit.
SOURCES = sorted([*(SRC / "identify").rglob("*.py"), SRC / "pipeline.py", SRC / "parity.py",
                  SRC / "detect" / "diagnose.py", SRC / "final_fit.py"])
REASON_NAMES = ("reason", "imprecise", "problem")
PART_NAMES = ("why",)  # parts of a reason (precision_failure's last words)


def _texts(node: ast.AST) -> list[str]:
    """A reason expression rendered with "1" for every value formatted into it (its leading
    string when it is a sum; both branches of a conditional; [] when it is not text)."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node.value]
    if isinstance(node, ast.JoinedStr):
        return ["".join(v.value if isinstance(v, ast.Constant) else "1" for v in node.values)]
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        return _texts(node.left)
    if isinstance(node, ast.IfExp):
        return _texts(node.body) + _texts(node.orelse)
    return []


def _reason_nodes(tree: ast.AST):
    """(expression, is a whole reason) of every reason formed in ``tree``."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            name = getattr(node.func, "id", getattr(node.func, "attr", ""))
            if name == "failure" and len(node.args) > 1:
                yield node.args[1], True
            if name == "_failure" and node.args:
                yield node.args[0], True
            if name == "Identification" and len(node.args) > 1 and getattr(node.args[0], "value", 0) is False:
                yield node.args[1], True
            yield from ((k.value, True) for k in node.keywords if k.arg == "reason")
        elif isinstance(node, (ast.Assign, ast.AugAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names = {getattr(t, "id", getattr(t, "attr", "")) for t in targets}
            if names & set(REASON_NAMES + PART_NAMES):
                yield node.value, not names & set(PART_NAMES)
        elif isinstance(node, ast.FunctionDef) and node.name in ("precision_failure", "frame_problem",
                                                                  "_solve_near", "_outside_reason"):
            yield from ((r.value, True) for r in ast.walk(node) if isinstance(r, ast.Return) and r.value)


def solver_reasons() -> list[tuple[str, str, bool]]:
    """(where, text, whole) of every reason and part of one the solver's sources form; a part
    (text appended to another reason: it starts with a value, "; " or ", ") is not whole."""
    out = []
    for path in SOURCES:
        for node, whole in _reason_nodes(ast.parse(path.read_text())):
            for text in _texts(node):
                if text:
                    part = not whole or text[0] in "1;," or text.startswith(" (")
                    out.append((f"{path.relative_to(ROOT)}:{node.lineno}", text, not part))
    return out


def test_every_reason_the_solver_forms_has_a_kind():
    reasons = solver_reasons()
    whole = [(where, text) for where, text, is_whole in reasons if is_whole]
    assert len(whole) >= 30  # the scan finds them (32, and 12 parts of reasons, when written)
    missing = [(where, text) for where, text in whole if failure_kind(text) is None]
    assert not missing, missing
    # every kind is reached by some reason, or part of one, of the code
    reached = {kind.kind for _, text, _ in reasons if (kind := failure_kind(text)) is not None}
    assert reached == {f.kind for f in FAILURES}


def test_the_docs_table_lists_every_kind_and_its_step():
    text = (ROOT / "docs" / "failures.md").read_text()
    rows = {line.split(" | ")[0].removeprefix("| "): line for line in text.splitlines()
            if line.startswith("| ") and not line.startswith("| kind")}
    assert list(rows) == [f.kind for f in FAILURES]
    for f in FAILURES:
        assert rows[f.kind].endswith(f" | {'yes' if f.in_reason else ''} | {f.step} |"), f.kind


@pytest.mark.parametrize("reason, kind", [
    ("no match after 4000 patterns (857 candidates verified)", "no match"),
    ("no match after 4000 patterns (857 candidates verified); with the FOV hint 30° too (no match after 4000 "
     "patterns (0 candidates verified)): if the field of view is known, check it; else solve without it",
     "FOV hint failed"),
    ("time limit 2 s reached after 1200 patterns", "time limit"),
    ("too few stars detected (2; need at least 3)", "too few stars detected"),
    ("too few stars detected (0; need at least 3): blank frame: every pixel is 100 (lens cap on, or no "
     "exposure?)", "blank frame"),
    ("no match after 53 candidate correspondences", "method found no match"),
    ("no match after 900 patterns (3 candidates verified); attitude hint: no two of the 8 brightest stars "
     "match catalogue stars within 40 px of where the attitude hint puts them", "no match"),
])
def test_reasons_get_their_kinds_step(reason, kind):
    assert failure_kind(reason).kind == kind
    sol = Solution(reason=reason)
    step = {f.kind: f.step for f in FAILURES}[kind]
    assert sol.next_step == next_step(reason) == step
    assert sol.to_dict()["next_step"] == step
    assert Solution(status="solved").to_dict()["next_step"] == ""


def test_a_failed_solve_names_its_next_step_in_the_cli(tmp_path):
    from PIL import Image
    from typer.testing import CliRunner

    from skyfix.cli import app

    path = tmp_path / "blank.png"
    Image.fromarray(np.full((240, 320), 100, np.uint8)).save(path)
    res = CliRunner().invoke(app, ["solve", str(path)])
    assert res.exit_code == 1
    line = [x for x in res.output.splitlines() if "failed:" in x][0]
    assert "blank frame" in line and line.endswith("— try: " + next_step(line.split(" — try: ")[0]))
    assert step_to_add(line) == next_step(line)  # not said in a blank frame's reason
    # a reason that says its next step is not followed by it again
    mirrored = ("time limit 2 s reached after 900 patterns; but the stars match the sky mirrored "
                "left-right: a mirror image")
    assert step_to_add(mirrored) == ""
    assert Solution(reason=mirrored).next_step.startswith("solve with --parity")
