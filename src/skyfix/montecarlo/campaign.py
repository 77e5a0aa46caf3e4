"""A Monte Carlo campaign: its TOML file read into a checked, named :class:`Campaign`.

A campaign file has five tables (docs/montecarlo.md has the full reference)::

    [campaign]                  # what and how many
    name = "quick"
    level = "centroid"          # LEVELS: "centroid" (synthetic centroids) or "image" (render + solve)
    trials = 1000
    seed = 27
    batch_size = 50             # trials per Dask task (default: DEFAULT_BATCH_SIZE)
    epoch = 2025.0

    [camera]                    # one of: preset = NAME | file = "camera.toml"
    preset = "generic"

    [attitude]                  # ATTITUDES: "uniform" (the default), "scan", "profile"
    distribution = "uniform"

    [parameters]                # fixed values of PARAMETERS (the rest keep their defaults)
    sigma_px = 0.2

    [sweep]                     # swept values of PARAMETERS
    n_false = [0, 5, 10]                      # a list: grid values
    fov_deg = { start = 10, stop = 30, num = 3 }   # a range: num values, ends included
    mag_sigma = { min = 0.0, max = 0.5 }      # drawn uniformly per trial

Grid axes combine as a Cartesian product and trial ``i`` takes grid point ``i mod (points)``,
so any run of consecutive trials covers the grid evenly; a ``{min, max}`` axis is drawn per
trial from the trial's own random stream. Every name is checked: an unknown table, key,
parameter, preset, level, distribution or method is one :class:`~skyfix.errors.UnknownNameError`
line (:func:`skyfix.errors.unknown_name`), a bad value or an empty range one
:class:`~skyfix.errors.InputError` line, all before any trial runs.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import tomllib

from skyfix.errors import InputError, unknown_name

__all__ = ["ATTITUDES", "DEFAULT_BATCH_SIZE", "HINTS", "LEVELS", "PARAMETERS", "Campaign", "Parameter",
           "SweepAxis", "calibration_sigma", "campaign_from_dict", "load_campaign"]

#: The two levels a trial runs at.
LEVELS = ("centroid", "image")
#: Trials per Dask task when the file does not say: a centroid-level trial costs a few ms, an
#: image-level one tens, and a task ~1 ms of scheduler overhead.
DEFAULT_BATCH_SIZE = {"centroid": 100, "image": 10}
#: How the true attitudes are drawn (see :mod:`skyfix.montecarlo.trials`) and the options each takes.
ATTITUDES: dict[str, tuple[str, ...]] = {
    "uniform": (),  # uniform over SO(3): the whole sky, any roll
    "scan": ("pole_deg", "roll_deg"),  # the boresight steps along the great circle about pole_deg (RA, Dec)
    "profile": ("profile", "start_deg", "frame_period_s", "options"),  # skyfix.simulate.profiles over time
}


def _nonnegative(v: float) -> bool:
    return v >= 0


def _positive(v: float) -> bool:
    return v > 0


def _fraction(v: float) -> bool:
    return 0 <= v < 1


def _fov(v: float) -> bool:
    return 0.5 <= v <= 100


class Parameter(NamedTuple):
    """A quantity a campaign fixes or sweeps: its type, default, the levels it acts at, what a
    valid value is (``valid`` of the typed value, described by ``accepts``) and what it means."""

    kind: type
    default: Any
    levels: tuple[str, ...]
    valid: Callable[[Any], bool]
    accepts: str
    help: str


def _method_ok(registry: str) -> Callable[[str], bool]:
    def ok(name: str) -> bool:
        if registry == "identify":
            from skyfix.identify import get_method

            get_method(name)  # UnknownNameError with the registry's names
        else:
            from skyfix.attitude import METHODS

            if name not in METHODS:
                raise unknown_name("attitude method", name, METHODS)
        return True

    return ok


_BOTH = LEVELS
#: What the solver may be told of the attitude (the parameter ``hint``): nothing, or the truth.
HINTS = ("none", "truth")
#: Every parameter by name (the columns of the results carry these names).
PARAMETERS: dict[str, Parameter] = {
    "sigma_px": Parameter(float, 0.2, ("centroid",), _nonnegative, "≥ 0",
                          "centroid noise per axis, pixels (Gaussian)"),
    "mag_limit": Parameter(float, 6.5, ("centroid",), lambda v: 0 < v <= 12, "0–12",
                           "faintest star detected, magnitude"),
    "dropout": Parameter(float, 0.0, ("centroid",), _fraction, "0 ≤ p < 1",
                         "chance a star in view is missed"),
    "mag_sigma": Parameter(float, 0.0, ("centroid",), _nonnegative, "≥ 0",
                           "noise on the magnitudes that order the stars, mag"),
    "false_stars": Parameter(int, 0, _BOTH, _nonnegative, "≥ 0",
                             "false stars (hot pixels, satellites) among the stars"),
    "fov_deg": Parameter(float, 0.0, _BOTH, lambda v: v == 0 or _fov(v), "0 (the camera's) or 0.5–100",
                         "horizontal field of view, degrees: the camera's focal length changed to it"),
    "exposure_s": Parameter(float, 0.0, ("image",), _nonnegative, "0 (the preset's) or > 0",
                            "exposure, seconds"),
    "rate_dps": Parameter(float, 0.0, ("image",), _nonnegative, "≥ 0",
                          "body rate during the exposure, °/s, about a random axis (smear)"),
    "hot_pixels": Parameter(int, 0, ("image",), _nonnegative, "≥ 0", "hot pixels of the sensor"),
    "given": Parameter(str, "camera", _BOTH, lambda v: v in ("camera", "fov", "nothing"),
                       "camera, fov or nothing",
                       "what the solver is told: the camera model, the FOV only, or nothing (blind)"),
    "focal_error": Parameter(float, 0.0, _BOTH, lambda v: abs(v) < 0.2, "|ε| < 0.2",
                             "calibration error: relative error of the focal length of the camera given"),
    "sigma_known": Parameter(bool, False, ("centroid",), lambda v: True, "true or false",
                             "the solver is told the centroid noise (--centroid-sigma)"),
    "identify_method": Parameter(str, "quad-hash", _BOTH, _method_ok("identify"), "skyfix.identify.METHODS",
                                 "identification method"),
    "attitude_method": Parameter(str, "svd", _BOTH, _method_ok("attitude"), "skyfix.attitude.METHODS",
                                 "Wahba solver"),
    "prob_threshold": Parameter(float, 1e-9, _BOTH, lambda v: 0 < v < 1, "0 < p < 1",
                                "the largest chance of a coincidence a solution is accepted with (raise it "
                                "to see wrong solutions and check that prob_false predicts how many)"),
    "lone_prob_threshold": Parameter(float, 0.0, _BOTH, lambda v: 0 <= v < 1, "0 (the method's) or 0 < p < 1",
                                     "the largest chance a frame of a few stars is accepted with, for the "
                                     "methods that judge lone triangles (triangle, pyramid, voting, "
                                     "van-bezooijen; 1e-4 by default)"),
    "hint": Parameter(str, "none", _BOTH, lambda v: v in HINTS, "none or truth",
                      "the attitude the solver is told: none (lost in space) or the true one (the "
                      "identification near it, for accuracy studies; its wrong count is not lost "
                      "in space's)"),
    "time_limit_s": Parameter(float, 30.0, _BOTH, _positive, "> 0",
                              "identification's wall-clock limit: long, so that the search's pattern count "
                              "bounds it and a trial's result never depends on the machine's load"),
    # what real frames carry (issue 27 part 5; docs/montecarlo.md#real-error-sources)
    "calibration_error": Parameter(float, 0.0, _BOTH, lambda v: 0 <= v <= 10, "0–10",
                                   "residual calibration error: every coefficient of the camera told is off "
                                   "by this many times its [calibration.sigma] 1σ, each a Gaussian draw"),
    "distortion_error": Parameter(float, 0.0, _BOTH, lambda v: abs(v) <= 1, "|ε| ≤ 1",
                                  "residual distortion: the radial distortion (k1, k2, k3) told is (1 + ε) "
                                  "times the true one"),
    "timestamp_error_s": Parameter(float, 0.0, _BOTH, lambda v: 0 <= v <= 3600, "0–3600",
                                   "σ of a ground frame's time stamp, s: the truth a fixed mount gives is "
                                   "turned by the Earth's rotation over a Gaussian error of this σ"),
    "seeing_arcsec": Parameter(float, 0.0, ("image",), _nonnegative, "≥ 0",
                               "seeing disc FWHM, arcsec, added in quadrature to the PSF"),
    "scintillation": Parameter(bool, False, ("image",), lambda v: True, "true or false",
                               "each star's flux jittered by Young's scintillation "
                               "(aperture, exposure, airmass)"),
    "airmass": Parameter(float, 1.0, ("image",), lambda v: 1 <= v <= 40, "1–40",
                         "airmass of the field (scintillation)"),
    "altitude_m": Parameter(float, 0.0, ("image",), lambda v: -500 <= v <= 10000, "−500–10000",
                            "the site's altitude, m (scintillation)"),
    "psf_growth": Parameter(float, 0.0, ("image",), _nonnegative, "≥ 0",
                            "PSF σ growth at the field corner, (1 + g·ρ²) on both axes"),
    "max_stars": Parameter(int, 200, ("image",), lambda v: 3 <= v <= 10000, "3–10000",
                           "the brightest detections the solver uses (thesis 003's threshold kept ~16)"),
    "render_mag_limit": Parameter(float, 0.0, ("image",), lambda v: v == 0 or 0 < v <= 15, "0 (all) or 0–15",
                                  "render only the stars brighter than this (0: the whole catalogue; a "
                                  "wide field's thousands of faint stars cost seconds and add no signal)"),
    "jpeg_quality": Parameter(int, 0, ("image",), lambda v: v == 0 or 1 <= v <= 95, "0 (raw) or 1–95",
                              "the frame delivered as 8-bit JPEG of this quality (0: the sensor's ADU)"),
}

_TABLES = {
    "campaign": ("name", "level", "trials", "seed", "batch_size", "epoch"),
    "camera": ("preset", "file"),
    "attitude": ("distribution", *sorted({o for opts in ATTITUDES.values() for o in opts})),
    "parameters": tuple(PARAMETERS),
    "sweep": tuple(PARAMETERS),
}


class SweepAxis(NamedTuple):
    """One swept parameter: grid ``values``, or with ``values`` empty a uniform draw in
    [``low``, ``high``) per trial."""

    name: str
    values: tuple
    low: float = math.nan
    high: float = math.nan

    @property
    def drawn(self) -> bool:
        return not self.values


@dataclass(frozen=True)
class Campaign:
    """A checked campaign (:func:`load_campaign`). ``fixed`` holds every parameter of the level
    not swept (defaults included); ``sweep`` the swept ones, grid axes first in file order."""

    name: str
    level: str
    trials: int
    seed: int
    batch_size: int
    epoch: float
    camera: str  # a preset name or a camera file's path
    attitude: str
    attitude_options: Mapping[str, Any]
    fixed: Mapping[str, Any]
    sweep: tuple[SweepAxis, ...]
    source: str = field(default="", compare=False)  # the file it came from, for messages

    @property
    def n_batches(self) -> int:
        return -(-self.trials // self.batch_size)

    @property
    def grid(self) -> tuple[SweepAxis, ...]:
        return tuple(a for a in self.sweep if not a.drawn)

    @property
    def grid_size(self) -> int:
        return math.prod(len(a.values) for a in self.grid)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """The level's parameters in registry order (the results' input columns)."""
        return tuple(n for n, p in PARAMETERS.items() if self.level in p.levels)

    def batch_trials(self, batch: int) -> range:
        """The trial indices of batch ``batch``."""
        return range(batch * self.batch_size, min((batch + 1) * self.batch_size, self.trials))

    def grid_point(self, trial: int) -> dict[str, Any]:
        """The grid axes' values of trial ``trial`` (round robin over the Cartesian product)."""
        index, point = trial % self.grid_size, {}
        for axis in reversed(self.grid):  # the last axis varies fastest, as in itertools.product
            index, k = divmod(index, len(axis.values))
            point[axis.name] = axis.values[k]
        return {a.name: point[a.name] for a in self.grid}

    def profile(self):
        """The motion profile of a ``profile`` attitude distribution (skyfix.simulate.profiles),
        from ``start_deg``; a SimulationError for a missing or unknown profile parameter."""
        import numpy as np

        from skyfix.geometry import attitude_from_radec_roll
        from skyfix.simulate import make_profile

        opts = self.attitude_options
        A0 = attitude_from_radec_roll(*np.radians(opts["start_deg"]))
        return make_profile(opts["profile"], A0, **opts["options"])

    def to_dict(self) -> dict:
        """Everything that decides the trials' results, as plain JSON data."""
        return {"name": self.name, "level": self.level, "trials": self.trials, "seed": self.seed,
                "batch_size": self.batch_size, "epoch": self.epoch, "camera": self.camera,
                "attitude": self.attitude, "attitude_options": dict(self.attitude_options),
                "fixed": dict(self.fixed), "sweep": [a._asdict() for a in self.sweep]}

    @property
    def fingerprint(self) -> str:
        """SHA-256 of :meth:`to_dict` (what a resumed run checks its finished batches against)."""
        text = json.dumps(self.to_dict(), sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()


def load_campaign(path: str | Path) -> Campaign:
    """Read and check a campaign file (errors name the file)."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the campaign file ({exc.__class__.__name__}: {exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not a valid TOML file ({exc})") from None
    try:
        return campaign_from_dict(data, base=path.parent, source=str(path))
    except InputError as exc:
        raise type(exc)(f"{path}: {exc}") from None


def campaign_from_dict(data: Mapping[str, Any], *, base: Path | None = None, source: str = "") -> Campaign:
    """A :class:`Campaign` from the tables of a campaign file (``base``: the folder a camera
    file's relative path is taken from)."""
    for table, value in data.items():
        if table not in _TABLES:
            raise unknown_name("campaign table", table, _TABLES)
        if not isinstance(value, Mapping):
            raise InputError(f"[{table}] must be a table")
        for key in value:
            if key not in _TABLES[table]:
                raise unknown_name(f"key of [{table}]", key, _TABLES[table])
    head = data.get("campaign", {})
    level = _text(head.get("level", "centroid"), "[campaign] level")
    if level not in LEVELS:
        raise unknown_name("campaign level", level, LEVELS)
    trials = _integer(head.get("trials"), "[campaign] trials", 1)
    batch = _integer(head.get("batch_size", DEFAULT_BATCH_SIZE[level]), "[campaign] batch_size", 1)
    seed = _integer(head.get("seed", 0), "[campaign] seed", 0)
    epoch = _number(head.get("epoch", 2025.0), "[campaign] epoch")
    if not 1900 <= epoch <= 2100:
        raise InputError(f"[campaign] epoch must be a Julian year 1900–2100, got {epoch}")
    camera = _camera(data.get("camera", {}), base)
    attitude, attitude_options = _attitude(data.get("attitude", {}))
    fixed_given = dict(data.get("parameters", {}))
    sweep_given = dict(data.get("sweep", {}))
    for name in [*fixed_given, *sweep_given]:
        if level not in PARAMETERS[name].levels:
            raise InputError(f"parameter {name!r} acts at the {' and '.join(PARAMETERS[name].levels)} level, "
                             f"not the {level} level")
    if _nonzero("calibration_error", fixed_given, sweep_given) and not calibration_sigma(camera):
        raise InputError(f"calibration_error needs the camera's [calibration.sigma]; {camera!r} has none")
    both = sorted(set(fixed_given) & set(sweep_given))
    if both:
        raise InputError(f"parameter {both[0]!r} is both fixed ([parameters]) and swept ([sweep])")
    fixed = {name: _value(name, fixed_given.get(name, p.default), "[parameters]")
             for name, p in PARAMETERS.items() if level in p.levels and name not in sweep_given}
    axes = [_axis(name, spec) for name, spec in sweep_given.items()]
    sweep = tuple(sorted(axes, key=lambda a: a.drawn))
    return Campaign(name=_text(head.get("name", Path(source).stem or "campaign"), "[campaign] name"),
                    level=level, trials=trials, seed=seed, batch_size=batch, epoch=epoch, camera=camera,
                    attitude=attitude, attitude_options=attitude_options, fixed=fixed, sweep=sweep,
                    source=source)


def calibration_sigma(camera: str) -> dict[str, float]:
    """The 1σ of each calibrated coefficient of a campaign's camera (a preset name or a camera
    file's path): its ``[calibration.sigma]`` table, empty when it has none."""
    if camera.endswith(".toml") or Path(camera).is_file():
        try:
            tables = tomllib.loads(Path(camera).read_text())
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
            raise InputError(f"cannot read camera file {camera}: {exc}") from None
    else:
        from skyfix.simulate import load_preset, preset_names

        tables = load_preset(camera) if camera in preset_names() else {}
    sigma = dict(tables.get("calibration", {}).get("sigma", {}))
    return {k: float(v) for k, v in sigma.items() if isinstance(v, (int, float))}


def _nonzero(name: str, fixed: Mapping[str, Any], sweep: Mapping[str, Any]) -> bool:
    """Whether parameter ``name`` is given a non-zero value, fixed or anywhere in its sweep."""
    spec = sweep.get(name, fixed.get(name, 0))
    if isinstance(spec, Mapping):
        spec = list(spec.values())
    return any(isinstance(v, (int, float)) and v != 0 for v in (spec if isinstance(spec, list) else [spec]))


# --- checks ------------------------------------------------------------------------------------
def _text(value: Any, where: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise InputError(f"{where} must be a non-empty string, got {value!r}")
    return value.strip()


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f"{where} must be a finite number, got {value!r}")
    return float(value)


def _integer(value: Any, where: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise InputError(f"{where} must be an integer ≥ {minimum}, got {value!r}")
    return value


def _value(name: str, value: Any, where: str) -> Any:
    """``value`` of parameter ``name`` typed and checked."""
    p = PARAMETERS[name]
    label = f"{where} {name}"
    if p.kind is bool:
        if not isinstance(value, bool):
            raise InputError(f"{label} must be true or false, got {value!r}")
        typed: Any = value
    elif p.kind is str:
        typed = _text(value, label).lower()
    elif p.kind is int:
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        typed = _integer(value, label, -(2**62))
    else:
        typed = _number(value, label)
    if not p.valid(typed):
        raise InputError(f"{label} must be {p.accepts}, got {value!r}")
    return typed


def _axis(name: str, spec: Any) -> SweepAxis:
    where = f"[sweep] {name}"
    if isinstance(spec, list):
        if not spec:
            raise InputError(f"{where}: an empty list of values")
        values = tuple(_value(name, v, "[sweep]") for v in spec)
        if len(set(values)) != len(values):
            raise InputError(f"{where}: a value is listed twice")
        return SweepAxis(name, values)
    if not isinstance(spec, Mapping):
        raise InputError(f"{where} must be a list of values, {{start, stop, num}} or {{min, max}}, "
                         f"got {spec!r}")
    keys = set(spec)
    if keys == {"min", "max"}:
        if PARAMETERS[name].kind is not float:
            raise InputError(f"{where}: only a real-valued parameter can be drawn from {{min, max}}")
        low, high = _number(spec["min"], f"{where} min"), _number(spec["max"], f"{where} max")
        if not low < high:
            raise InputError(f"{where}: an empty range (min {low:g} is not below max {high:g})")
        for v in (low, high):
            _value(name, v, "[sweep]")
        return SweepAxis(name, (), low, high)
    if keys == {"start", "stop", "num"}:
        start, stop = _number(spec["start"], f"{where} start"), _number(spec["stop"], f"{where} stop")
        num = _integer(spec["num"], f"{where} num", 0)
        if num == 0 or (num > 1 and start == stop):
            raise InputError(f"{where}: an empty range ({num} values from {start:g} to {stop:g})")
        raw = [start] if num == 1 else [start + (stop - start) * k / (num - 1) for k in range(num)]
        if PARAMETERS[name].kind is int:
            raw = [round(v) for v in raw]
            if len(set(raw)) != len(raw):
                raise InputError(f"{where}: {num} integer values do not fit between {start:g} and {stop:g}")
        return SweepAxis(name, tuple(_value(name, v, "[sweep]") for v in raw))
    raise InputError(f"{where} must be a list, {{start, stop, num}} or {{min, max}}; got keys {sorted(keys)}")


def _camera(table: Mapping[str, Any], base: Path | None) -> str:
    if len(table) > 1:
        raise InputError("[camera] takes one of preset or file, not both")
    if "file" in table:
        path = Path(_text(table["file"], "[camera] file"))
        path = path if path.is_absolute() or base is None else base / path
        if not path.is_file():
            raise InputError(f"[camera] file {str(path)!r} does not exist")
        from skyfix.simulate import resolve_setup

        resolve_setup(path, None, None, None)  # a bad file fails here, before any trial
        return str(path.resolve())
    name = _text(table.get("preset", "generic"), "[camera] preset").lower()
    from skyfix.camera import PRESETS
    from skyfix.simulate import preset_names

    known = [*preset_names(), *(p for p in PRESETS if p not in preset_names())]
    if name not in known:
        raise unknown_name("camera preset", name, known)
    return name


def _attitude(table: Mapping[str, Any]) -> tuple[str, dict]:
    options = dict(table)
    name = _text(options.pop("distribution", "uniform"), "[attitude] distribution").lower()
    if name not in ATTITUDES:
        raise unknown_name("attitude distribution", name, ATTITUDES)
    for key in options:
        if key not in ATTITUDES[name]:
            raise unknown_name(f"option of the {name!r} attitude distribution", key,
                               ATTITUDES[name] or ["(none)"])
    if name == "scan":
        pole = options.setdefault("pole_deg", [0.0, 90.0])
        if not (isinstance(pole, list) and len(pole) == 2):
            raise InputError("[attitude] pole_deg must be [RA, Dec] in degrees")
        options["pole_deg"] = [_number(v, "[attitude] pole_deg") for v in pole]
        options["roll_deg"] = _number(options.get("roll_deg", 0.0), "[attitude] roll_deg")
    if name == "profile":
        from skyfix.simulate import PROFILES

        profile = _text(options.get("profile", ""), "[attitude] profile")
        if profile not in PROFILES:
            raise unknown_name("motion profile", profile, PROFILES)
        start = options.setdefault("start_deg", [0.0, 0.0, 0.0])
        if not (isinstance(start, list) and len(start) == 3):
            raise InputError("[attitude] start_deg must be [RA, Dec, roll] in degrees")
        options["start_deg"] = [_number(v, "[attitude] start_deg") for v in start]
        period = _number(options.setdefault("frame_period_s", 0.1), "[attitude] frame_period_s")
        if period <= 0:
            raise InputError(f"[attitude] frame_period_s must be > 0, got {period}")
        options["options"] = dict(options.get("options", {}))
        probe = Campaign(name="", level="centroid", trials=1, seed=0, batch_size=1, epoch=2025.0,
                         camera="generic", attitude=name, attitude_options=options, fixed={}, sweep=())
        try:
            probe.profile()  # the profile's parameters checked now
        except Exception as exc:  # SimulationError: a missing or unknown profile parameter
            raise InputError(f"[attitude] {exc}") from None
    return name, options
