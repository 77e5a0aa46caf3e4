"""skyfix.identify in layers (docs/design.md's map): accept → catalogue → common → methods →
hint → lost; each imports only from its own layer and those below, no method imports another method,
and nothing in identify imports the stages above it (pipeline, final fit, the command line)."""

from __future__ import annotations

import ast
from pathlib import Path

import skyfix.identify

PACKAGE = Path(skyfix.identify.__file__).parent
LAYERS = {"accept": 0, "catalogue": 1, "common": 2, "methods": 3, "hint": 4, "lost": 5}
ABOVE = ("skyfix.pipeline", "skyfix.final_fit", "skyfix._rematch", "skyfix.cli", "skyfix.track",
         "skyfix.analysis")  # (skyfix.warmup is not a stage: a method asks it to compile its kernels)


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported(path: Path) -> set[str]:
    """Every skyfix module ``path`` imports, at its top or inside a function."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("skyfix")}
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("skyfix"):
            out.add(node.module)
            out |= {f"{node.module}.{a.name}" for a in node.names}  # a submodule imported by name
    return out


def layer(module: str) -> tuple[int, str] | None:
    """(layer, unit) of a module of skyfix.identify: the unit is the method for methods/."""
    parts = module.split(".")
    if parts[:2] != ["skyfix", "identify"] or len(parts) < 3 or parts[2] not in LAYERS:
        return None
    return LAYERS[parts[2]], parts[3] if parts[2] == "methods" and len(parts) > 3 else parts[2]


def test_each_layer_imports_only_its_own_and_those_below():
    modules = sorted(PACKAGE.rglob("*.py"))
    assert len(modules) > 25
    bad = []
    for path in modules:
        me = module_name(path)
        mine = layer(me)
        for target in imported(path):
            if target.startswith(ABOVE):
                bad.append(f"{me} imports {target}, a stage above identify")
            theirs = layer(target)
            if mine is None or theirs is None:
                continue
            if theirs[0] > mine[0]:
                bad.append(f"{me} (layer {mine[0]}) imports {target} (layer {theirs[0]})")
            elif mine[0] == LAYERS["methods"] and theirs[0] == mine[0] and theirs[1] != mine[1] \
                    and me != "skyfix.identify.methods":
                bad.append(f"method {me} imports another method, {target}")
    assert not bad, "\n".join(bad)


def test_the_layer_rule_sees_a_violation():
    assert layer("skyfix.identify.methods.grid") == (3, "grid")
    assert layer("skyfix.identify.catalogue.pairs") == (1, "catalogue")
    assert layer("skyfix.identify") is None
    assert "skyfix.identify.common.angle_match.frame_table" in imported(PACKAGE / "methods" / "grid.py")


def test_a_moved_module_is_still_reached_by_its_old_name_with_a_warning():
    import pytest

    from skyfix.identify.methods import quad

    with pytest.warns(DeprecationWarning, match="skyfix.identify.quad is now skyfix.identify.methods.quad"):
        from skyfix.identify import quad as old
    assert old is quad
    with pytest.raises(AttributeError):
        skyfix.identify.no_such_module  # noqa: B018
