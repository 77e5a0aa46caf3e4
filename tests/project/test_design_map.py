"""docs/design.md is the map of the code: every module and package under src/skyfix is named in
its "Package layout" tree, and the tree names nothing that does not exist."""

from __future__ import annotations

import re

from tests.conftest import ROOT

SRC = ROOT / "src" / "skyfix"


def map_entries(text: str) -> set[str]:
    """The paths (``identify/methods/quad.py``, ``identify/``) the layout tree of design.md names."""
    section = text.split("## Package layout", 1)[1]
    block = section.split("```", 2)[1]
    entries: set[str] = set()
    stack: list[str] = []
    inside = False
    for line in block.splitlines():
        if line.strip() == "src/skyfix/":
            inside = True
            continue
        if not inside or not line.strip():
            continue
        indent = len(line) - len(line.lstrip(" "))
        if indent == 0:  # tests/, benchmarks/ …: the tree of src/skyfix ends
            break
        token = line.split()[0]
        if not re.fullmatch(r"[\w.]+(/|\.py)", token) or indent % 2:
            continue  # a description's continuation line
        depth = indent // 2 - 1
        del stack[depth:]
        path = "".join(stack) + token
        entries.add(path)
        if token.endswith("/"):
            stack.append(token)
    return entries


def code_entries() -> set[str]:
    skip = {"__pycache__", "_aot"}  # numba's cache; the modules `skyfix warmup` generates (git-ignored)
    modules = {p.relative_to(SRC).as_posix() for p in SRC.rglob("*.py") if not skip & set(p.parts)}
    packages = {p.relative_to(SRC).as_posix() + "/" for p in SRC.rglob("*")
                if p.is_dir() and not skip & set(p.relative_to(SRC).parts)
                and (any(p.glob("*.py")) or any(p.glob("*.toml")))}
    return modules | packages


def test_every_module_is_on_the_map_and_nothing_else():
    named = map_entries((ROOT / "docs" / "design.md").read_text())
    actual = code_entries()
    assert len(actual) > 100
    assert not actual - named, f"modules docs/design.md's map does not name: {sorted(actual - named)}"
    assert not named - actual, f"docs/design.md names what does not exist: {sorted(named - actual)}"


def test_the_parser_reads_nesting_and_skips_descriptions():
    text = ("## Package layout\n\n```\nsrc/skyfix/\n  a.py          one\n  pkg/          two\n"
            "    b.py        three, continued\n                b.py is not an entry here\n"
            "  c.py          four\ntests/          x\n```\n")
    assert map_entries(text) == {"a.py", "pkg/", "pkg/b.py", "c.py"}
