"""The docs match the program (issue 28, part 4): every command of ``skyfix`` is in README.md's
command table (or its "Solving images" usage), every option of every command's ``-h`` appears in
README.md or a docs/ page README links, and every ``skyfix COMMAND … --option`` the README writes
is an option that command has.

Commands and options are read from the app (``typer.main.get_command``), so a new option fails
here until it is documented; the README is read as text: a command's row is the table row (or
usage line) starting with its words, and its options are the ``--names`` in that row's first
cell."""

from __future__ import annotations

import re

import typer.main

from skyfix.cli import app
from tests.conftest import ROOT

README = (ROOT / "README.md").read_text()
LINKED = sorted({m for m in re.findall(r"\]\((docs/[\w-]+\.md)", README)})
DOCS = README + "".join((ROOT / page).read_text() for page in LINKED)


def _leaves() -> dict[tuple[str, ...], object]:
    out = {}

    def walk(command, path):
        subs = getattr(command, "commands", None)
        if subs is None:
            out[path] = command
        for name, sub in (subs or {}).items():
            walk(sub, (*path, name))

    walk(typer.main.get_command(app), ())
    return out


LEAVES = _leaves()


def _usage_cells(words: tuple[str, ...]) -> list[str]:
    """The README's usage of ``skyfix WORDS``: each table row's first cell and each line of a
    code block that starts with it."""
    head = "skyfix " + " ".join(words)
    pattern = re.compile(rf"^\| `{re.escape(head)}(?![\w-])(.*?)` \|", re.M)
    cells = [m.group(1) for m in pattern.finditer(README)]
    block = re.compile(rf"^{re.escape(head)}(?![\w-])(.*(?:\n {{6,}}.*)*)", re.M)
    return cells + [m.group(1) for m in block.finditer(README)]


def _long_options(command) -> set[str]:
    return {o for p in command.params for o in (*p.opts, *p.secondary_opts) if o.startswith("--")}


def test_every_command_has_a_readme_row():
    missing = [" ".join(w) for w in LEAVES if not _usage_cells(w)]
    assert not missing, f"commands README's command table does not show: {missing}"


def test_every_option_of_every_command_is_documented():
    missing = []
    for words, command in LEAVES.items():
        for param in command.params:
            names = [o for o in (*param.opts, *param.secondary_opts) if o.startswith("-")]
            if not names or "--help" in names or "--verbose" in names:
                continue  # arguments; -h and -v are README's "skyfix -h", "-v|-vv"
            if not any(re.search(rf"(?<![\w-]){re.escape(n)}(?![\w-])", DOCS) for n in names):
                missing.append(f"skyfix {' '.join(words)} {names[0]}")
    assert not missing, f"options in -h that README.md and its linked docs/ pages never name: {missing}"


def test_every_option_the_readme_shows_exists():
    wrong = []
    for words, command in LEAVES.items():
        real = _long_options(command)
        for cell in _usage_cells(words):
            for option in re.findall(r"(?<![\w-])--[a-z][\w-]*", cell):
                if option not in real:
                    wrong.append(f"skyfix {' '.join(words)} {option}")
    assert not wrong, f"options README.md shows that the command does not have: {sorted(set(wrong))}"


def test_every_readme_command_exists():
    named = set(re.findall(r"`skyfix ((?:[a-z]+ ?){1,2})", README))
    real = {" ".join(w) for w in LEAVES} | {w[0] for w in LEAVES}
    unknown = sorted(n.strip() for n in named if n.strip() not in real
                     and n.strip().split()[0] not in {w[0] for w in LEAVES if len(w) == 1})
    assert not unknown, f"README.md names commands skyfix does not have: {unknown}"


#: Options that mean the same in every command that has them: one default, one help text.
SHARED = ("--epoch", "--calibration", "--time", "--velocity-kms", "--refraction", "--mounting", "--apparent",
          "--database")


def test_shared_options_have_one_default_and_one_help():
    """``--epoch`` defaulted to "now" in solve and to "the database's" in track (issue 28); both
    were the observation time's, else the database's. ``simulate --time`` (a simulation's time)
    and ``analyze presets --database`` (instead of the bands) are other options of the same name."""
    seen: dict[str, dict[tuple, list[str]]] = {}
    for words, command in LEAVES.items():
        if words in (("simulate",), ("analyze", "presets")):
            continue
        for param in command.params:
            if param.opts[0] in SHARED:
                key = (param.default, param.help)
                seen.setdefault(param.opts[0], {}).setdefault(key, []).append(" ".join(words))
    assert set(seen) == set(SHARED)
    differ = {name: list(v.values()) for name, v in seen.items() if len(v) > 1}
    assert not differ, f"options whose default or help differs between commands: {differ}"
