"""One error style for every option (issue 28): each option of each command, given a bad value,
prints one line ``skyfix: error: …`` on stderr naming the option (or the bad file), nothing on
stdout, exit status 2, no traceback — and it is said before any work.

The commands and their options are read from the app itself (``typer.main.get_command``), so an
option added tomorrow is tested the day it exists; what a bad value is comes from the option's
type alone:

- a number: ``abc``;
- a flag (or the counted ``-v``): a value after ``=`` (``--json=yes``);
- a file or folder: a path under ``/proc`` that can be neither read nor created;
- any other text (a name, a list, a pair of numbers, an address, a time): ``nosuch``.

Each is added to a valid command line of its command (:data:`BASE`: the required arguments and
options, nothing more), so what fails is the option, not a missing argument.
"""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import pytest
import typer.main
from typer.testing import CliRunner

from skyfix.cli import app
from skyfix.identify.catalogue.bands import STANDARD
from tests.conftest import EXAMPLES, ROOT

IMAGE = str(EXAMPLES / "sky.png")
CAMERA = str(EXAMPLES / "sky.camera.toml")
CAMPAIGN = str(ROOT / "campaigns" / "smoke.toml")
NOWHERE = "/proc/skyfix-nowhere/x.png"  # cannot be read, nor written, nor its folder made

#: A valid command line of each command (its words first), every bad option appended to it. The
#: root's goes after the option (``skyfix --verbose=1 warmup --list``). Outputs land in the test's
#: folder (it is the working directory).
BASE: dict[tuple[str, ...], list[str]] = {
    (): ["warmup", "--list"],
    ("solve",): [IMAGE],
    ("detect",): [IMAGE],
    ("simulate",): ["--ra", "84", "--dec", "-2", "-o", "sim.fits"],
    ("warmup",): ["--list"],
    ("track",): [IMAGE, "--camera", CAMERA, "--fps", "1"],
    ("montecarlo",): [CAMPAIGN, "-o", "mc.parquet"],
    ("database", "build"): ["-o", "db.npz"],
    ("analyze", "centroids"): ["--quick"],
    ("analyze", "tracking"): ["--quick"],
    ("analyze", "presets"): ["--n", "1", "--presets", "generic"],
    ("analyze", "psf"): [IMAGE],
    ("analyze", "photometry"): [IMAGE],
    ("analyze", "budget"): ["--camera", "generic", "--pointings", "5"],
    ("analyze", "mounting"): [IMAGE, "--site", "40,20,100"],
    ("analyze", "coverage"): ["--fov", "10", "--mag", "4", "--n", "10"],
    ("analyze", "identification"): ["--quick"],
    ("analyze", "seeds"): ["--only", "003-bennett"],
    ("calibrate", "stars"): [IMAGE, IMAGE, IMAGE, "-o", "cam.toml"],
    ("calibrate", "checkerboard"): [IMAGE, IMAGE, IMAGE, "-o", "cam.toml"],
    ("calibrate", "frames"): ["--darks", IMAGE, "-o", "maps.fits"],
    ("database", "info"): [str(STANDARD.path)],
    ("cache", "info"): [],
    ("cache", "clear"): ["--dry-run"],  # a bad option must stop it before it removes anything
}


def _commands() -> dict[tuple[str, ...], object]:
    """Every command and group of ``skyfix`` by its words (the root: ``()``)."""
    out = {}

    def walk(command, path: tuple[str, ...]) -> None:
        out[path] = command
        for name, sub in getattr(command, "commands", {}).items():
            walk(sub, (*path, name))

    walk(typer.main.get_command(app), ())
    return out


COMMANDS = _commands()


def _kind(command, param) -> str:
    """``flag``, ``int``, ``float``, ``path`` or ``text``: from the option and its annotation."""
    if param.is_flag or param.count:
        return "flag"
    annotation = str(inspect.signature(command.callback).parameters[param.name].annotation)
    for kind, pattern in (("int", r"\bint\b"), ("float", r"\bfloat\b"), ("path", r"\bPath\b")):
        if re.search(pattern, annotation):
            return kind
    return "text"


def _bad(option: str, kind: str) -> list[str]:
    return {"flag": [f"{option}=yes"], "int": [option, "abc"], "float": [option, "abc"],
            "path": [option, NOWHERE]}.get(kind, [option, "nosuch"])


def _cases() -> list[tuple[tuple[str, ...], str, str]]:
    """(command words, option, kind) for every option of every command (help aside)."""
    cases = []
    for path, command in COMMANDS.items():
        for param in command.params:
            if param.param_type_name == "option":
                cases.append((path, param.opts[0], _kind(command, param)))
    return cases


CASES = _cases()


def test_every_command_has_a_valid_command_line_to_spoil():
    leaves = {path for path, command in COMMANDS.items() if not hasattr(command, "commands")}
    assert leaves | {()} == set(BASE), "a command without a BASE line, or a BASE line of no command"
    assert len(CASES) > 100 and {kind for *_, kind in CASES} == {"flag", "int", "float", "path", "text"}


@pytest.mark.parametrize(("path", "option", "kind"), CASES, ids=[" ".join((*p, o)) for p, o, _ in CASES])
def test_a_bad_value_is_one_line_naming_the_option(path, option, kind, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    bad = _bad(option, kind)
    args = [*bad, *BASE[()]] if path == () else [*path, *BASE[path], *bad]
    result = CliRunner().invoke(app, args)
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    lines = result.stderr.splitlines()
    assert (result.exit_code, len(lines), result.stdout) == (2, 1, ""), (args, result.output)
    line = lines[0]
    assert line.startswith("skyfix: error: ") and "Traceback" not in line, line
    names = [o for o in COMMANDS[path].params if option in o.opts][0].opts
    assert any(re.search(rf"(?<![\w-]){re.escape(n)}\b", line) for n in names) or (
        kind == "path" and NOWHERE.rpartition("/")[0] in line), line


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc")
@pytest.mark.parametrize("args", [
    ["simulate", "--ra", "84", "--dec", "-2", "-o", "/proc/x.fits"],
    ["solve", IMAGE, "--wcs", "/proc/x.wcs"],
    ["database", "build", "-o", "/proc/x.npz"],
    ["calibrate", "frames", "--darks", IMAGE, "-o", "/proc/x.fits"],
], ids=lambda args: " ".join(args[:2]))
def test_an_unwritable_output_is_one_plain_line(args):
    """/proc exists and takes no new file, even from root (whom permission bits never stop): the
    output is tried before any work, and refused in one line — not an internal error."""
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2 and result.stdout == "", result.output
    line = r"skyfix: error: --(output|wcs): cannot write /proc/x\.\w+ \(.+\)\n"
    assert re.fullmatch(line, result.stderr), result.stderr


def test_flags_show_as_flags_in_help():
    """A flag takes no value, and -h shows none (no ``<bool>``, no ``--json BOOLEAN``)."""
    runner = CliRunner()
    for path, command in COMMANDS.items():
        flags = [p for p in command.params
                 if p.param_type_name == "option" and "bool" in str(
                     inspect.signature(command.callback).parameters[p.name].annotation)]
        assert all(p.is_flag for p in flags), (path, [p.name for p in flags if not p.is_flag])
        text = runner.invoke(app, [*path, "-h"]).stdout
        # each option's declaration: the first column of its line ("  -o, --output <path>  Where …")
        first_columns = re.findall(r"^  (-\S.*?)(?:\s{2,}|$)", text, re.M)
        declared = {d.split(", ")[-1].split()[0]: d for d in first_columns}
        for p in flags:
            assert re.fullmatch(r"(-\w, )?--[\w-]+", declared[p.opts[0]]), (path, declared[p.opts[0]])


def test_options_show_a_readable_metavar_in_help():
    """An option that takes a value shows what it takes in capitals (``--fov DEG``, ``--camera
    FILE|NAME``, ``--workers N``), not a Python type (``<float>``, ``<str>``, ``<path>``)."""
    runner = CliRunner()
    for path in COMMANDS:
        text = runner.invoke(app, [*path, "-h"], terminal_width=250).stdout
        arguments = text.split("Arguments:")[1].split("Options:")[0] if "Arguments:" in text else ""
        assert not re.search(r"<\w", arguments), (path, arguments)  # not "images... <list[Path]>"
        first_columns = re.findall(r"^  (-\S.*?)(?:\s{2,}|$)", text, re.M)
        for declared in first_columns:
            words = declared.split(", ")[-1].split(" ", 1)
            if len(words) == 2:
                # DEG, FILE.csv, RA,DEC,ROLL[,UNCERTAINTY_DEG], data|kernels
                shown = r"[A-Z][A-Za-z0-9_,.|/²x\[\]]*|[a-z]+(\|[a-z]+)+"
                assert re.fullmatch(shown, words[1]), (path, declared)
