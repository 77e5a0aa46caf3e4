"""What every ``skyfix`` command shares: one-line errors, the guard that turns any exception into
one, ``-v``/``-vv``, output files (folders created, names never colliding), the inputs several
commands read (``--camera``, ``--calibration``/``--dark``/``--flat``, the pattern database) and
the notice shown while numba compiles kernels (the first run on a machine).

Errors: ``skyfix: error: MESSAGE`` on stderr and exit status 2; an interrupt prints
``skyfix: interrupted`` and exits 130 (the shell's convention for Ctrl-C); an unexpected
exception (a bug) is one line too, and ``-vv`` adds its traceback.

The camera, image, database and numba imports sit inside the functions that need them: every
``skyfix`` start loads this module, ``--version`` and ``-h`` included, which must stay light.
"""

from __future__ import annotations

import functools
import inspect
import logging
import os
import re
import sys
import time
import traceback
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NoReturn

import typer

from skyfix.errors import DatabaseError, ImageReadError, InputError, SkyfixError

__all__ = [
    "EPOCH_HELP", "VERBOSE", "LineProgress", "OneLineErrors", "add_verbosity", "calibration_maps",
    "check_cluster", "checking", "compile_notice", "counter_bar", "error_line", "fail", "guarded",
    "input_error_line", "load_camera", "load_database", "output_names", "output_paths", "prepare_outputs",
    "reset_verbosity",
]

#: ``-v`` / ``-vv``: a counted flag (it takes no value), on ``skyfix`` itself and on commands.
VERBOSE = typer.Option(0, "--verbose", "-v", count=True, metavar="", show_default=False,
                       help="-v: say what each stage decided; -vv: debug detail and tracebacks "
                            "(a counted flag: it takes no value).")

#: ``--epoch``, the same in every command that solves (solve, track, analyze photometry).
EPOCH_HELP = ("Catalogue epoch, Julian year: where proper motion moves the stars to (default: the "
              "observation time's, from --time, DATE-OBS or EXIF, else the pattern database's).")

_state = {"verbosity": 0}


class _StderrHandler(logging.StreamHandler):
    """A handler that writes to whatever ``sys.stderr`` is at the time (test runners swap it)."""

    @property
    def stream(self):  # noqa: D401
        return sys.stderr

    @stream.setter
    def stream(self, value) -> None:
        pass


_HANDLER = _StderrHandler()
_HANDLER.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))


def add_verbosity(count: int) -> int:
    """Add a command's ``-v`` count to the one given before the command; set skyfix's log level
    (only skyfix's own loggers: numba's and Pillow's debug output stays off). Returns the total."""
    _state["verbosity"] += int(count)
    total = _state["verbosity"]
    log = logging.getLogger("skyfix")
    log.setLevel(logging.WARNING if total == 0 else logging.INFO if total == 1 else logging.DEBUG)
    if _HANDLER not in log.handlers:
        log.addHandler(_HANDLER)
        log.propagate = False
    return total


def reset_verbosity() -> None:
    """Back to no ``-v`` (the start of each invocation)."""
    _state["verbosity"] = 0
    logging.getLogger("skyfix").setLevel(logging.WARNING)


def fail(message: str, code: int = 2) -> NoReturn:
    """Print ``skyfix: error: MESSAGE`` on stderr and exit with ``code``."""
    typer.echo(f"skyfix: error: {message}", err=True)
    raise typer.Exit(code)


@contextmanager
def checking(option: str, value: object = None) -> Iterator[None]:
    """Inside, a SkyfixError — a name no registry has, a file that cannot be read, a value out of
    range — fails as one line said of ``option`` and its ``value``: ``OPTION VALUE: message``, or
    ``OPTION: message`` when the message names the value itself (or the option)."""
    try:
        yield
    except SkyfixError as exc:
        text = str(exc)
        if text.startswith(option):
            fail(text)
        named = value is None or str(value) in text
        fail(f"{option}: {text}" if named else f"{option} {value}: {text}")


def error_line(exc: BaseException, where: str | Path | None = None) -> str:
    """One line for an exception: a SkyfixError's own message, a file system's refusal as the file
    and the reason, anything else as an internal error. With ``-vv`` the traceback goes to stderr
    first. ``where`` (a file) goes in front unless the message already starts with it."""
    debug = _state["verbosity"] >= 2
    if debug:
        typer.echo("".join(traceback.format_exception(exc)).rstrip(), err=True)
    if isinstance(exc, SkyfixError):
        text = str(exc)
    elif isinstance(exc, OSError) and exc.filename is not None:  # the file system said no: not a bug
        text = f"{exc.filename}: {exc.strerror or type(exc).__name__}"
    else:
        first = (str(exc).strip().splitlines() or [""])[0]
        text = f"internal error: {type(exc).__name__}{': ' + first if first else ''}"
        if not debug:
            text += " (run with -vv for the traceback)"
    if where is not None and not text.startswith(str(where)):
        text = f"{where}: {text}"
    return text


def input_error_line(exc: BaseException, path: Path) -> str:
    """:func:`error_line` for an input file of a batch, with a hint when the "file" is a value
    given to an option that takes none (``-v 1 x.png``, ``--json true x.png``)."""
    text = error_line(exc, path)
    word = str(path)
    if isinstance(exc, ImageReadError) and not Path(path).exists():
        if word.isdigit():
            return f"{text} (-v takes no value: write -v or -vv)"
        if word.lower() in ("true", "false", "yes", "no", "on", "off"):
            return f"{text} (a flag takes no value: write --json, not --json {word})"
    return text


def guarded(func: Callable[..., Any]) -> Callable[..., Any]:
    """Decorate a command: whatever it raises becomes one ``skyfix: error:`` line (exit 2), an
    interrupt ``skyfix: interrupted`` (exit 130); ``typer.Exit`` passes through."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except (typer.Exit, typer.Abort):
            raise
        except KeyboardInterrupt:
            typer.echo("skyfix: interrupted", err=True)
            raise typer.Exit(130) from None
        except BrokenPipeError:  # the reader went away (`skyfix … | head`): stop quietly, as cat does
            try:
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            except (OSError, ValueError):
                pass
            raise typer.Exit(141) from None
        except Exception as exc:  # a SkyfixError (bad input) or a bug: one line either way
            fail(error_line(exc))
        finally:
            reset_verbosity()

    return wrapper


# --- usage errors: click's parser, one line ---------------------------------------------------------
#: click's usage errors — an option's value of the wrong type or out of range, an option without its
#: value or a flag with one, a missing argument, an unknown option or command. typer ≥ 0.20 runs on
#: a click of its own (private); its UsageError is the base of the public ``typer.BadParameter``.
_USAGE_ERROR = next(k for k in typer.BadParameter.__mro__ if k.__name__ == "UsageError")
_ARGV = "skyfix.argv"  # the command line, kept in the contexts' shared meta to quote a bad value


class OneLineErrors(typer.core.TyperGroup):
    """A command group whose usage errors are one line, ``skyfix: error: …`` naming the option and
    what it takes, exit status 2 — not click's usage, hint and message (the one error style of
    every command: tests/cli/test_bad_values.py). Help for a group called alone passes through."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        for command in self.commands.values():
            for param in getattr(command, "params", ()):
                readable_metavar(param)

    def make_context(self, info_name, args, parent=None, **extra):
        argv = list(args)
        try:
            ctx = super().make_context(info_name, args, parent=parent, **extra)
        except _USAGE_ERROR as exc:
            words = [*_words(parent), info_name] if parent is not None else ["skyfix"]
            _usage_failure(exc, self, words, argv)
        ctx.meta.setdefault(_ARGV, argv)
        return ctx

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except _USAGE_ERROR as exc:  # a subcommand's (its own context, when it has one, says which)
            name = ctx.invoked_subcommand
            command = self.get_command(ctx, name) if name else None
            words = _words(ctx) + ([name] if command is not None else [])
            _usage_failure(exc, command or self, words, ctx.meta.get(_ARGV, []))


# What -h shows after an option that takes a value, when the option names none itself: the first
# unit its help names (a float), else what its type is ("--fov DEG", not "--fov <float>").
_UNITS = (("julian year", "YEAR"), ("mag/arcsec", "MAG/ARCSEC²"), ("deg/s²", "DEG/S²"), ("deg/s", "DEG/S"),
          ("°/s", "DEG/S"), ("arcsec", "ARCSEC"), ("degrees", "DEG"), ("°", "DEG"), ("pixels", "PX"),
          ("frames per second", "FPS"), ("hz", "HZ"), ("seconds", "S"), (", s ", "S"), (", m ", "M"),
          (", mm", "MM"), ("µm", "UM"), ("σ above", "SIGMA"), ("snr", "SNR"), ("magnitude", "MAG"))


def readable_metavar(param: Any) -> None:
    """Give an option that takes a value, and names no metavar, a readable one: ``FILE`` or
    ``DIR`` for a path, ``N`` for an integer, a float's unit from its help (``DEG``, ``S``,
    ``YEAR``, ``PX``, …; else ``X``), ``FILE|NAME`` for a file or preset name, ``NAME,...`` for
    a comma-separated list, ``ISO8601`` for a time, ``NAME`` for a name, ``TEXT`` otherwise.
    Flags stay bare, and an argument shows its name alone (typer would add its Python type)."""
    if param.param_type_name == "argument":  # its name says what it is: no "<list[Path]>" after it
        param.display_type_rich = _no_type
        return
    if param.param_type_name != "option" or param.metavar or param.is_flag or param.count:
        return
    desc = getattr(param, "type_descriptor", None)  # typer's (its click type is made lazily)
    kind = getattr(desc, "annotation", None)
    words = (param.help or "").lower()
    if getattr(desc, "is_path", False):
        info = desc.parameter_info
        folder = getattr(info, "dir_okay", True) and not getattr(info, "file_okay", True)
        meta = "DIR" if folder or param.name.endswith("dir") or "directory" in words else "FILE"
    elif kind is int:
        meta = "N"
    elif kind is float:
        meta = next((unit for word, unit in _UNITS if word in words), "X")
    elif "file" in words and "name" in words:
        meta = "FILE|NAME"
    elif "comma-separated" in words:
        meta = "NAME,..."
    elif "iso 8601" in words:
        meta = "ISO8601"
    elif re.search(r"name|method|^[\w-]+(, [\w-]+)+|: \w[\w-]*, \w", words):
        meta = "NAME"
    else:
        meta = "TEXT"
    param.metavar = meta


def _no_type(ctx: Any = None) -> str:
    return ""


def _words(ctx: Any) -> list[str]:
    """The command's words, ``skyfix`` first (whatever the program was called: ``python -m …``)."""
    names = []
    while ctx is not None and ctx.parent is not None:
        names.append(ctx.info_name)
        ctx = ctx.parent
    return ["skyfix", *reversed(names)] if ctx is not None else []


def _usage_failure(exc: Exception, command: Any, words: list[str], argv: list[str]) -> NoReturn:
    if type(exc).__name__ == "NoArgsIsHelpError":
        raise exc  # a group called alone: its help, as before
    ctx = getattr(exc, "ctx", None)
    if ctx is not None:
        command, words = ctx.command, _words(ctx)
    fail(_usage_line(exc, command, " ".join(words) or "skyfix", argv))


def _usage_line(exc: Exception, command: Any, where: str, argv: Sequence[str] = ()) -> str:
    """The one line (without ``skyfix: error:``) for click's usage error ``exc`` raised while
    parsing ``command`` (called ``where``, e.g. ``skyfix solve``) from the words ``argv``."""
    kind = type(exc).__name__
    message = str(getattr(exc, "message", exc)).strip()
    param = getattr(exc, "param", None)
    if param is None and getattr(exc, "option_name", None):
        param = next((p for p in getattr(command, "params", ()) if exc.option_name in _opts(p)), None)
    if kind == "NoSuchOption" and exc.option_name == "-=":  # -v=2: a short option's value after "="
        word = next((w for w in reversed(argv) if re.fullmatch(r"-\w=.*", w)), "")
        param = next((p for p in getattr(command, "params", ()) if word[:2] in _opts(p)), None)
        if param is not None:
            return (f"{word[:2]} is a flag: it takes no value" if param.is_flag or param.count
                    else f"{word[:2]} takes its value after a space: {word[:2]} {word[3:]}")
    if kind == "NoSuchOption":
        near = sorted(exc.possibilities or ())
        guess = f" (did you mean {' or '.join(near)}?)" if near else ""
        return f"{where} has no option {exc.option_name}{guess}; see {where} -h"
    if kind == "BadOptionUsage" and param is not None:
        if param.is_flag or param.count:
            return f"{exc.option_name} is a flag: it takes no value"
        shape = f" {param.metavar}" if param.metavar else ""  # RA,DEC,ROLL[,UNCERTAINTY_DEG], NAME …
        return f"{exc.option_name} needs a value{shape}: {_accepts(command, param)}"
    if kind == "MissingParameter" and param is not None:
        if param.param_type_name == "argument":
            return f"{where} needs {_metavar(param)}: {_accepts(command, param)}"
        return f"{where} needs {_opts(param)[0]}: {_accepts(command, param)}"
    if param is not None and param.param_type_name == "option":  # a value of the wrong type or range
        typed, value = _given(param, argv)
        return f"{typed} takes {_accepts(command, param)}" + ("" if value is None else f", not {value!r}")
    if message.startswith("No such command"):
        name = message.split(" ", 3)[-1].rstrip(".")
        return f"{where} has no command {name}; choose one of {', '.join(getattr(command, 'commands', {}))}"
    return f"{where}: {message[:1].lower()}{message[1:].rstrip('.')}"


def _opts(param: Any) -> list[str]:
    return [*param.opts, *param.secondary_opts]


def _metavar(param: Any) -> str:
    meta = param.metavar or param.name.upper()
    return f"{meta}…" if param.nargs == -1 else meta


def _given(param: Any, argv: Sequence[str]) -> tuple[str, str | None]:
    """(the option as written, its value) from the last mention of ``param`` in ``argv``."""
    names = _opts(param)
    for i in range(len(argv) - 1, -1, -1):
        word = argv[i]
        if word in names:
            return word, argv[i + 1] if i + 1 < len(argv) else None
        head, eq, value = word.partition("=")
        if eq and head in names:
            return head, value
    return names[0], None


def _accepts(command: Any, param: Any) -> str:
    """What ``param`` takes, in a few words: a number (in its range), or its help's first sentence."""
    callback = getattr(command, "callback", None)
    annotation = inspect.signature(callback).parameters[param.name].annotation if callback else ""
    text = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", str(annotation))
    kind = next((k for k in ("int", "float") if re.search(rf"\b{k}\b", text)), None)
    if kind is not None:
        low, high = getattr(param, "min", None), getattr(param, "max", None)
        what = "a whole number" if kind == "int" else "a number"
        if low is not None and high is not None:
            return f"{what} from {low:g} to {high:g}"
        return what + (f" ≥ {low:g}" if low is not None else f" ≤ {high:g}" if high is not None else "")
    first = re.split(r"(?<=[a-z)])\. ", (param.help or "").strip(), maxsplit=1)[0].rstrip(".")
    word = first.split(" ", 1)[0]
    acronym = len(word) > 1 and word.isupper()  # FITS, CSV: as written
    return (first if acronym else first[:1].lower() + first[1:]) or "a value"


# --- output files ----------------------------------------------------------------------------------
def output_names(images: Sequence[Path]) -> list[str]:
    """A name per input for its output files, distinct whenever the inputs are.

    The file's stem. Inputs that share a stem get their folder's name in front if their folders
    differ (``a/sky.png`` → ``a-sky``, ``b/sky.png`` → ``b-sky``) and their extension behind if
    their extensions differ (``sky.png`` → ``sky-png``, ``sky.fits`` → ``sky-fits``); anything
    still the same (a file given twice) gets ``-2``, ``-3``...
    """
    paths = [Path(p) for p in images]
    names = [p.stem for p in paths]
    groups: dict[str, list[int]] = {}
    for i, n in enumerate(names):
        groups.setdefault(n, []).append(i)
    for stem, idx in groups.items():
        if len(idx) == 1:
            continue
        folders = [paths[i].parent.name for i in idx]
        exts = [paths[i].suffix.lstrip(".") for i in idx]
        by_folder, by_ext = len(set(folders)) > 1, len(set(exts)) > 1
        for i, folder, ext in zip(idx, folders, exts, strict=True):
            parts = (folder if by_folder else "", stem, ext if by_ext else "")
            names[i] = "-".join(part for part in parts if part)
    seen: Counter[str] = Counter()
    out = []
    for n in names:
        seen[n] += 1
        out.append(n if seen[n] == 1 else f"{n}-{seen[n]}")
    return out


def output_paths(template: Path | None, images: Sequence[Path], suffix: str) -> list[Path | None]:
    """The output file of each image for an option like ``--plot TEMPLATE``.

    ``{stem}`` in the template is replaced by the image's name from :func:`output_names`; an
    existing folder receives ``NAME{suffix}`` files; without either, one image writes the
    template itself and several write ``TEMPLATE-NAME.ext``.
    """
    if template is None:
        return [None] * len(images)
    names = output_names(images)
    text = str(template)
    if "{stem}" in text:
        return [Path(text.replace("{stem}", n)) for n in names]
    if template.is_dir():
        return [template / f"{n}{suffix}" for n in names]
    if len(images) == 1:
        return [template]
    return [template.with_name(f"{template.stem}-{n}{template.suffix or suffix}") for n in names]


def prepare_outputs(outputs: dict[str, Sequence[Path | None]], inputs: Sequence[Path] = ()) -> None:
    """Before any work: create the folders of the output files and check they can be written;
    refuse outputs that would overwrite an input or each other. ``outputs`` maps an option name
    (``"--plot"``) to its paths. Fails with a one-line error."""
    written: dict[Path, str] = {}
    sources = {Path(p).resolve(): Path(p) for p in inputs}
    for option, paths in outputs.items():
        for path in paths:
            if path is None:
                continue
            key = path.resolve()
            if key in sources:
                fail(f"{option} {path} would overwrite the input image {sources[key]}")
            if key in written:
                if written[key] != option:
                    fail(f"{written[key]} and {option} both write {path}")
                fail(f"{option} writes {path} more than once (put {{stem}} in its name)")
            written[key] = option
            if path.is_dir():
                fail(f"{option} {path} is a folder; give a file name")
            folder = path.parent
            try:
                folder.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                fail(f"{option}: cannot create the folder {folder} ({exc.strerror or type(exc).__name__})")
            why = _cannot_write(path)
            if why is not None:
                fail(f"{option}: cannot write {path} ({why})")


def _cannot_write(path: Path) -> str | None:
    """Why ``path`` cannot be written, or None when it can: tried, not judged from permission bits
    (root passes every access check, and /proc or a read-only mount refuse it anyway). An existing
    file is opened for appending and left as it was; a new one is created and removed."""
    try:
        if path.exists():
            with open(path, "ab"):
                pass
        else:
            with open(path, "xb"):
                pass
            path.unlink()
    except OSError as exc:
        return exc.strerror or type(exc).__name__
    return None


# --- inputs several commands read ------------------------------------------------------------------
def load_camera(value: str) -> Any:
    """A Camera from ``--camera``'s value: a TOML file or a preset name (simulator presets
    included)."""
    from skyfix.camera import Camera

    if value.endswith(".toml") and not Path(value).is_file():
        raise InputError(f"no such file {value}")
    return Camera.load(value)  # a file, or a preset name (Camera.load says which names it knows)


#: A scheduler's address as Dask takes it: an optional protocol, a host, a port.
_ADDRESS = re.compile(r"(?:[a-z][a-z0-9+.-]*://)?(?:\[[0-9a-fA-F:]+\]|[^\s/:\[\]]+):\d+/?")


def check_cluster(workers: int | None, scheduler: str | None, minimum: int = 1) -> None:
    """``--workers N`` (≥ ``minimum``: 0 where the command can run in its own process) or
    ``--scheduler [PROTOCOL://]HOST:PORT``, not both (InputError)."""
    if workers is not None and scheduler is not None:
        raise InputError("give --workers or --scheduler, not both")
    if workers is not None and workers < minimum:
        raise InputError(f"--workers must be ≥ {minimum}, got {workers}")
    if scheduler is not None and not _ADDRESS.fullmatch(scheduler):
        raise InputError(f"--scheduler {scheduler!r} is not a Dask scheduler's address: give "
                         "[PROTOCOL://]HOST:PORT (tcp://10.0.0.5:8786)")


def calibration_maps(calibration: Path | None, dark: Path | None, flat: Path | None) -> dict:
    """``dark``, ``flat`` and ``bad_pixels`` for :func:`skyfix.pipeline.solve`; files given
    one by one override those in the calibration file."""
    from skyfix.io import read_image

    maps: dict = {}
    if calibration is not None:
        from skyfix.detect import load_calibration

        maps.update(load_calibration(calibration))
    if dark is not None:
        maps["dark"] = read_image(dark)
    if flat is not None:
        maps["flat"] = read_image(flat)
    return maps


# --- progress bars -------------------------------------------------------------------------------------
def counter_bar(label: str, total: int) -> Any:
    """A transient progress bar on stderr, started: ``LABEL ━━━━━━ 3/20 0:00:05`` (the caller
    advances task 0 and stops it; whether to show one at all is the caller's choice); off a
    terminal, a :class:`LineProgress`: ``skyfix: LABEL 3/20 (5 s)``, a line per step."""
    if not sys.stderr.isatty():
        progress = LineProgress()
        progress.add_task(label, total=total)
        return progress
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    progress = Progress(TextColumn(label), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                        console=Console(stderr=True), transient=True)
    progress.add_task(label, total=total)
    progress.start()
    return progress


class LineProgress:
    """Progress as lines on stderr, for when it is not a terminal (a pipe, a log file): one line
    when a task starts, and one each time it advances — ``skyfix: TITLE 3/20: STEP (12 s)``, the
    title the task's first description, the step its latest. It takes the calls a
    :class:`rich.progress.Progress` takes here (``add_task``, ``update``, ``advance``,
    ``remove_task``, ``start``, ``stop``, a ``with`` block), so a command drives either the same
    way; a task with no total (a spinner: the compile notice, which logs its own line) prints
    nothing."""

    def __init__(self) -> None:
        self._tasks: dict[int, dict[str, Any]] = {}
        self._t0 = time.perf_counter()

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> None:
        pass

    def stop(self) -> None:
        pass

    def add_task(self, description: str, total: float | None = None, **_: Any) -> int:
        task = len(self._tasks)
        self._tasks[task] = {"title": description, "step": description, "total": total, "completed": 0}
        self._line(task)
        return task

    def remove_task(self, task: int) -> None:
        self._tasks.pop(task, None)

    def advance(self, task: int, advance: float = 1) -> None:
        self.update(task, advance=advance)

    def update(self, task: int, *, advance: float | None = None, description: str | None = None,
               **_: Any) -> None:
        t = self._tasks.get(task)
        if t is None:
            return
        if description is not None:
            t["step"] = description
        if advance:
            t["completed"] += advance
            self._line(task)

    def _line(self, task: int) -> None:
        t = self._tasks[task]
        if t["total"] is None:
            return
        step = f": {t['step']}" if t["step"] != t["title"] else ""
        typer.echo(f"skyfix: {t['title']} {t['completed']:g}/{t['total']:g}{step} "
                   f"({time.perf_counter() - self._t0:.0f} s)", err=True)


# --- the first run: building the database, numba compiling kernels ---------------------------------
def load_database(path: Path | None, warm: Sequence[str] = ("solve",)) -> Any:
    """The pattern database in ``path``; with none, None (the solver then picks the default FOV
    bands, :mod:`skyfix.identify.catalogue.bands`) after loading the standard band.

    Meanwhile the kernels of the paths ``warm`` (:mod:`skyfix.warmup`) are compiled if they are
    not yet. The first run on a machine does both — builds the standard band's database and
    compiles — and says so first, with how long it will take (:data:`DATABASE_BUILD_S`)."""
    from skyfix import warmup
    from skyfix.identify import PatternDatabase, default_database, default_database_path

    if path is not None:
        if not Path(path).is_file():
            raise DatabaseError(f"{path}: no such pattern database (build one with "
                                f"`skyfix database build --fov-min … --fov-max … -o {path}`)")
        database = PatternDatabase.load(path)
        warmup.ensure(warm)
        return database
    if default_database_path().exists():
        warmup.ensure(warm, alongside=default_database)
        return None
    if not warmup.pending(warm):
        typer.echo(f"skyfix: first run: building the pattern database (once; about {DATABASE_BUILD_S} s)…",
                   err=True)
    warmup.ensure(warm, alongside=functools.partial(default_database, progress=False),
                  also="building the pattern database")
    return None


#: About how long the standard band's pattern database takes to build, seconds (measured: 5 s quiet,
#: 9 s on a loaded 2-core machine, benchmarks suite d).
DATABASE_BUILD_S = 10

_COMPILE_TEXT = "compiling numba kernels (first use)"


@contextmanager
def compile_notice(progress: Any = None, console: Any = None) -> Iterator[None]:
    """While active, numba compiling anything (it does on the first run on a machine, or after an
    upgrade; a warm cache loads without compiling) shows a transient spinner on stderr, with the
    number of kernels compiled and the time so far. Nothing shows otherwise, nor when stderr is
    not a terminal (then ``-v`` logs one line).

    ``progress``: a running :class:`rich.progress.Progress` to add the line to (one display);
    ``console``: the :class:`rich.console.Console` for a display of its own (default: stderr).
    """
    from skyfix._jit import on_numba_import

    notice = _CompileNotice(progress, console)
    registered: list[Any] = []

    def listen() -> None:  # numba is imported only when a kernel is not compiled ahead of time
        from numba.core import event

        class Listener(event.Listener):
            def on_start(self, ev: Any) -> None:
                notice.start()

            def on_end(self, ev: Any) -> None:
                notice.end()

        registered.append((event, Listener()))
        event.register("numba:compile", registered[0][1])

    cancel = on_numba_import(listen)
    try:
        yield
    finally:
        cancel()
        for event, listener in registered:
            event.unregister("numba:compile", listener)
        notice.close()


class _CompileNotice:
    """The display of :func:`compile_notice`, driven by numba's ``numba:compile`` events (nested:
    a kernel's callees compile inside it)."""

    def __init__(self, progress: Any, console: Any) -> None:
        self._progress = progress
        self._own = None
        self._console = console
        self._task = None
        self._depth = 0
        self._done = 0
        self._t0 = 0.0

    def start(self) -> None:
        self._depth += 1
        if self._depth == 1:
            self._show()

    def end(self) -> None:
        self._depth = max(self._depth - 1, 0)
        self._done += 1
        self._update()

    def _show(self) -> None:
        if self._t0 == 0.0:
            self._t0 = time.perf_counter()
            logging.getLogger("skyfix").info("%s…", _COMPILE_TEXT)
        if self._task is not None:
            return
        bar = self._progress
        if bar is None:
            if self._own is None:
                from rich.console import Console
                from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

                console = self._console if self._console is not None else Console(stderr=True)
                if not console.is_terminal:
                    return
                self._own = Progress(SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn(),
                                     console=console, transient=True)
                self._own.start()
            bar = self._own
        self._task = bar.add_task(f"{_COMPILE_TEXT}…", total=None)

    def _update(self) -> None:
        bar = self._progress if self._progress is not None else self._own
        if bar is not None and self._task is not None:
            bar.update(self._task, description=f"{_COMPILE_TEXT}… {self._done} compiled")

    def close(self) -> None:
        if self._progress is not None and self._task is not None:
            self._progress.remove_task(self._task)
        if self._own is not None:
            self._own.stop()
        self._task = self._own = None
