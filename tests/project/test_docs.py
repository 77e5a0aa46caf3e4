"""The project documents itself: every page and anchor the source, the README and the docs cite
exists, and the source cites files a user has (issue 8, item 6)."""

from __future__ import annotations

import re
from pathlib import Path

from tests.conftest import ROOT

DOCS = ROOT / "docs"
SRC = ROOT / "src" / "skyfix"
README = ROOT / "README.md"

# `docs/<page>.md` or `docs/<page>.md#anchor`, as the source and the pages cite them
_CITATION = re.compile(r"docs/([\w-]+\.md)(?:#([\w-]+))?")
# a Markdown link target: [text](target)
_LINK = re.compile(r"\]\(([^)\s]+)\)")
_HEADING = re.compile(r"^#{1,6}\s+(.+?)\s*#*\s*$")
_EXPLICIT_ANCHOR = re.compile(r"<a\s+(?:id|name)=\"([^\"]+)\"")
# What a user of the package does not have: the project's private design notes and readings.
_PRIVATE = re.compile(r"DESIGN\.md|SEEDS\.md|SEEDS \d{3}|\.\./shared/")


def github_anchor(heading: str) -> str:
    """The anchor GitHub gives a heading: link text only, lowercase, punctuation dropped,
    spaces to hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading).strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """Every anchor of a Markdown page: its headings' (repeats get -1, -2, … as on GitHub) and
    explicit ``<a id="…">`` ones; headings inside code blocks do not count."""
    found: set[str] = set()
    seen: dict[str, int] = {}
    in_code = False
    for line in page.read_text(encoding="utf-8").splitlines():
        if line.lstrip().startswith(("```", "~~~")):
            in_code = not in_code
            continue
        if in_code:
            continue
        m = _HEADING.match(line)
        if m:
            a = github_anchor(m.group(1))
            n = seen.get(a, 0)
            found.add(a if n == 0 else f"{a}-{n}")
            seen[a] = n + 1
        found.update(_EXPLICIT_ANCHOR.findall(line))
    return found


def _source_files() -> list[Path]:
    return sorted(p for p in SRC.rglob("*") if p.suffix in (".py", ".toml", ".md") and p.is_file())


def _pages() -> list[Path]:
    return sorted(DOCS.glob("*.md"))


def _citations(path: Path) -> list[tuple[int, str, str]]:
    """(line, page, anchor) of every ``docs/<page>.md[#anchor]`` in a file."""
    out = []
    for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        out += [(i, page, anchor) for page, anchor in _CITATION.findall(line)]
    return out


def test_github_anchor_rules():
    assert github_anchor("Boresight, RA/Dec and roll") == "boresight-radec-and-roll"
    assert github_anchor("Thesis 000: corrections") == "thesis-000-corrections"
    assert github_anchor("Camera file (TOML)") == "camera-file-toml"
    assert github_anchor("PSF (`skyfix analyze psf`)") == "psf-skyfix-analyze-psf"
    assert github_anchor("A [link](x.md) — here") == "a-link--here"


def test_every_cited_page_and_anchor_exists():
    """Every ``docs/<page>.md#anchor`` cited in ``src/``, the README or the docs, and every
    relative link of the README and the docs, points at a file and anchor that exist."""
    problems = []
    for path in _source_files() + [README] + _pages():
        for line, page, anchor in _citations(path):
            target = DOCS / page
            if not target.is_file():
                problems.append(f"{path.relative_to(ROOT)}:{line}: docs/{page} does not exist")
            elif anchor and anchor not in anchors(target):
                problems.append(f"{path.relative_to(ROOT)}:{line}: docs/{page} has no anchor #{anchor}")
    for path in [README] + _pages():
        for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            for link in _LINK.findall(line):
                if re.match(r"[a-z][a-z0-9+.-]*:", link):  # https:, mailto: …
                    continue
                file_part, _, anchor = link.partition("#")
                target = (path.parent / file_part).resolve() if file_part else path
                where = f"{path.relative_to(ROOT)}:{i}: link {link}"
                if not target.exists():
                    problems.append(f"{where}: no such file")
                elif anchor and target.suffix == ".md" and anchor not in anchors(target):
                    problems.append(f"{where}: no such anchor")
    assert not problems, "\n".join(problems)


def test_source_cites_only_files_a_user_has():
    """The source cites the docs in the repository, not the project's private DESIGN.md,
    SEEDS.md or its readings of the theses."""
    hits = [f"{p.relative_to(ROOT)}:{i}: {line.strip()}"
            for p in _source_files()
            for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
            if _PRIVATE.search(line)]
    assert not hits, "\n".join(hits)


def test_readme_links_design_and_seeds():
    text = README.read_text(encoding="utf-8")
    for page in ("docs/design.md", "docs/seeds.md"):
        assert f"]({page}" in text, f"README.md does not link {page}"


def test_docs_index_lists_every_page():
    index = DOCS / "README.md"
    linked = {link.partition("#")[0] for link in _LINK.findall(index.read_text(encoding="utf-8"))}
    missing = [p.name for p in _pages() if p != index and p.name not in linked]
    assert not missing, f"docs/README.md does not list {', '.join(missing)}"
