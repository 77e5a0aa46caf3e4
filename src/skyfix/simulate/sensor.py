"""Detector model: electrons in a pixel -> ADU, with every noise source switchable.

Order of the chain (physical; each step names the thesis 002 equation it corrects):

1. PRNU: the expected photo-electrons of each pixel are scaled by a fixed gain map
   ``1 + prnu·R`` (Eq. 3-10; applied to the *expected* signal so that shot noise follows the
   pixel's real response).
2. Shot noise: Poisson draw of the photo-electrons (Eq. 3-8 used a Gaussian; Poisson here).
3. Dark current: mean ``dark_current_e_s · t`` (plus hot pixels) with its own Poisson noise
   from its own stream (Eq. 3-9); switching ``dark`` off removes both.
4. Full-well clipping of the collected charge (absent in the thesis).
5. DSNU / fixed-pattern offset: fixed map ``dsnu_e·R`` (Eq. 3-11).
6. Read noise and 7. kTC reset noise: Gaussian (Eqs. 3-12, 3-13).
8. Gain to ADU (Eq. 3-15: ``gain_e_per_adu = V_swing / ((2^bits - 1)·A_g·I2V)``), bias,
   clipping to ``[0, 2^bits - 1]`` and rounding.

Each temporal source draws from its own stream: a xoshiro256** generator run inside the
kernel, seeded from that source's ``numpy.random.Generator`` (spawned from one
``SeedSequence``), so a frame is bit-for-bit repeatable and switching one source off does not
change the others' draws. The whole chain is one pass over the frame (``apply_detector``), every
draw exact in distribution (Poisson by inversion or PTRS, normals by the ziggurat).
Fixed-pattern maps (PRNU, DSNU, hot pixels) come from ``Sensor.pattern_seed``: they belong to
the sensor, not to the frame.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import tomllib

from skyfix._jit import njit
from skyfix.errors import SimulationError
from skyfix.simulate._streams import (
    _CHUNK,
    _SPARSE_MAX,
    _gap,
    _load,
    _means,
    _nonzero,
    _normals_chunk,
    _poisson,
    _poisson_chunk,
    _store,
    poisson_constant,
    poisson_image,
    standard_normals,
    stream_state,
    stream_uniforms,
)
from skyfix.simulate.presets import load_preset

__all__ = [
    "Sensor",
    "NOISE_SOURCES",
    "noise_switches",
    "conversion_gain_e_per_adu",
    "fixed_pattern",
    "FixedPattern",
    "apply_detector",
    "poisson_constant",
    "poisson_image",
    "standard_normals",
    "stream_state",
    "stream_uniforms",
]

#: The switchable detector effects, in the order they are applied.
NOISE_SOURCES = ("prnu", "shot", "dark", "hot_pixels", "dsnu", "read", "ktc", "quantization")


def conversion_gain_e_per_adu(adc_swing_v: float, charge_to_voltage_uv_per_e: float,
                              bit_depth: int, amp_gain: float = 1.0) -> float:
    """Electrons per ADU of the readout chain (thesis 002 Eq. 3-15, inverted).

    ``I_ADU = (2^bits - 1) / V_s · A_g · I2V · I_e``, so one ADU is
    ``V_s / ((2^bits - 1) · A_g · I2V)`` electrons. HAS2: 1.15 V, 14.8 µV/e⁻, 12 bit -> 18.98 e⁻/ADU.
    """
    return adc_swing_v / ((2**bit_depth - 1) * amp_gain * charge_to_voltage_uv_per_e * 1e-6)


@dataclass(frozen=True)
class Sensor:
    """Radiometric and noise parameters of an image sensor.

    Attributes
    ----------
    qe : float
        Quantum efficiency × fill factor averaged over the band, electrons per photon.
    full_well_e : float
        Pixel charge capacity, electrons.
    read_noise_e : float
        Temporal read noise σ, electrons.
    dark_current_e_s : float
        Mean dark current, electrons per second per pixel.
    prnu : float
        Photo-response non-uniformity σ, as a fraction of the mean response.
    dsnu_e : float
        Fixed-pattern (dark signal non-uniformity) offset σ, electrons.
    gain_e_per_adu : float
        Conversion gain, electrons per ADU.
    bit_depth : int
        ADC resolution, bits; output is clipped to ``[0, 2^bit_depth - 1]``.
    bias_adu : float
        Constant offset added after the gain, ADU.
    ktc_noise_e : float
        Reset (kTC) noise σ, electrons (0 with correlated double sampling).
    line_time_s : float
        Rolling-shutter row delay, seconds per row (0: global shutter).
    hot_pixel_dark_e_s : float
        Median extra dark current of a hot pixel, electrons per second.
    hot_pixel_log_sigma : float
        Spread of the hot pixels' (log-normal) dark currents, σ of the natural log.
    pattern_seed : int
        Seed of this sensor's fixed-pattern maps (PRNU, DSNU, hot pixel positions).
    pixel_pitch_um : float or None
        Pixel pitch, µm (informational).
    name : str
        Human-readable name.
    """

    qe: float = 0.6
    full_well_e: float = 15000.0
    read_noise_e: float = 3.0
    dark_current_e_s: float = 1.0
    prnu: float = 0.01
    dsnu_e: float = 1.0
    gain_e_per_adu: float = 4.0
    bit_depth: int = 12
    bias_adu: float = 64.0
    ktc_noise_e: float = 0.0
    line_time_s: float = 0.0
    hot_pixel_dark_e_s: float = 2000.0
    hot_pixel_log_sigma: float = 1.0
    pattern_seed: int = 0
    pixel_pitch_um: float | None = None
    name: str = ""

    def __post_init__(self) -> None:
        for key in ("qe", "full_well_e", "gain_e_per_adu"):
            v = float(getattr(self, key))
            if not (math.isfinite(v) and v > 0):
                raise SimulationError(f"sensor {key} must be a positive number, got {v}")
        for key in ("read_noise_e", "dark_current_e_s", "prnu", "dsnu_e", "ktc_noise_e", "line_time_s",
                    "hot_pixel_dark_e_s", "hot_pixel_log_sigma"):
            v = float(getattr(self, key))
            if not (math.isfinite(v) and v >= 0):
                raise SimulationError(f"sensor {key} must be a non-negative number, got {v}")
        if self.qe > 1.0:
            raise SimulationError(f"sensor qe must be at most 1, got {self.qe}")
        if not (isinstance(self.bit_depth, int) and 1 <= self.bit_depth <= 16):
            raise SimulationError(f"sensor bit_depth must be an integer 1–16, got {self.bit_depth}")

    @property
    def max_adu(self) -> int:
        """Largest output value, ``2^bit_depth - 1``."""
        return 2**self.bit_depth - 1

    def replace(self, **changes) -> Sensor:
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)

    # --- I/O ------------------------------------------------------------------------------
    @classmethod
    def from_dict(cls, table: Mapping) -> Sensor:
        """Sensor from a ``[sensor]`` table. ``gain_e_per_adu`` may be replaced by the chain
        ``adc_swing_v`` + ``charge_to_voltage_uv_per_e`` (+ ``amp_gain``), thesis 002 Eq. 3-15."""
        table = dict(table)
        chain = {k: table.pop(k) for k in ("adc_swing_v", "charge_to_voltage_uv_per_e", "amp_gain")
                 if k in table}
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(table) - known
        if unknown:
            raise SimulationError(f"unknown sensor keys: {', '.join(sorted(unknown))}")
        try:
            if "gain_e_per_adu" not in table and {"adc_swing_v", "charge_to_voltage_uv_per_e"} <= set(chain):
                table["gain_e_per_adu"] = conversion_gain_e_per_adu(
                    float(chain["adc_swing_v"]), float(chain["charge_to_voltage_uv_per_e"]),
                    int(table.get("bit_depth", 12)), float(chain.get("amp_gain", 1.0)))
            kw = {}
            for f in dataclasses.fields(cls):
                if f.name not in table:
                    continue
                v = table[f.name]
                if f.name in ("bit_depth", "pattern_seed"):
                    kw[f.name] = int(v)
                elif f.name == "name":
                    kw[f.name] = str(v)
                else:
                    kw[f.name] = float(v)
        except (TypeError, ValueError) as exc:
            raise SimulationError(f"bad sensor value: {exc}") from None
        return cls(**kw)

    @classmethod
    def from_toml(cls, text: str) -> Sensor:
        try:
            table = tomllib.loads(text)["sensor"]
        except (tomllib.TOMLDecodeError, KeyError, TypeError) as exc:
            raise SimulationError(f"not a sensor file ({exc.__class__.__name__}: {exc})") from None
        return cls.from_dict(table)

    @classmethod
    def load(cls, path: str | Path) -> Sensor:
        """Sensor from the ``[sensor]`` table of a TOML file."""
        p = Path(path)
        try:
            text = p.read_text()
        except (OSError, UnicodeDecodeError) as exc:
            raise SimulationError(f"cannot read sensor file {p}: {exc}") from None
        return cls.from_toml(text)

    @classmethod
    def from_preset(cls, name: str) -> Sensor:
        """Sensor of a bundled preset (``skyfix/presets/<name>.toml``)."""
        return cls.from_dict(load_preset(name)["sensor"])

    def to_dict(self) -> dict:
        """The ``[sensor]`` table (None fields left out)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if getattr(self, f.name) is not None}

    def to_toml(self) -> str:
        """The ``[sensor]`` table as TOML text."""
        lines = ["[sensor]"]
        for key, value in self.to_dict().items():
            if isinstance(value, str):
                lines.append(f"{key} = {json.dumps(value)}")
            elif isinstance(value, int):
                lines.append(f"{key} = {value}")
            else:
                lines.append(f"{key} = {float(value)!r}")
        return "\n".join(lines) + "\n"

    def save(self, path: str | Path) -> None:
        Path(path).write_text(self.to_toml())


def noise_switches(noise: bool | Mapping[str, bool]) -> dict[str, bool]:
    """Normalise ``noise`` (True/False, or a mapping of source -> bool) to all sources.

    A mapping switches the named sources; unnamed ones stay on.
    """
    if isinstance(noise, bool):
        return {k: noise for k in NOISE_SOURCES}
    if not isinstance(noise, Mapping):
        raise SimulationError("noise must be True, False or a mapping of source names to booleans")
    unknown = set(noise) - set(NOISE_SOURCES)
    if unknown:
        raise SimulationError(f"unknown noise sources: {', '.join(sorted(unknown))};"
                              f" known: {', '.join(NOISE_SOURCES)}")
    return {k: bool(noise.get(k, True)) for k in NOISE_SOURCES}


# --- fixed pattern -----------------------------------------------------------------------
@dataclass(frozen=True)
class FixedPattern:
    """A sensor's fixed-pattern maps for one frame size.

    ``prnu_gain`` (H, W) float32 = ``1 + prnu·R``; ``dsnu_e`` (H, W) float32 offsets, electrons;
    ``hot_index`` (K,) flat indices of hot pixels; ``hot_dark_e_s`` (K,) their extra dark current.
    """

    prnu_gain: np.ndarray
    dsnu_e: np.ndarray
    hot_index: np.ndarray
    hot_dark_e_s: np.ndarray


_PATTERN_CACHE: dict[tuple, FixedPattern] = {}


def fixed_pattern(sensor: Sensor, shape: tuple[int, int], hot_pixels: int = 0) -> FixedPattern:
    """The fixed-pattern maps of ``sensor`` for a ``shape`` frame (cached; drawn from
    ``sensor.pattern_seed`` with one stream per map, so they never change between frames)."""
    key = (sensor.pattern_seed, float(sensor.prnu), float(sensor.dsnu_e), float(sensor.hot_pixel_dark_e_s),
           float(sensor.hot_pixel_log_sigma), tuple(shape), int(hot_pixels))
    hit = _PATTERN_CACHE.get(key)
    if hit is not None:
        return hit
    s_prnu, s_dsnu, s_hot = np.random.SeedSequence([int(sensor.pattern_seed), 0x5EED]).spawn(3)
    h, w = shape
    prnu = np.random.default_rng(s_prnu).standard_normal((h, w), dtype=np.float32)
    prnu *= np.float32(sensor.prnu)
    prnu += np.float32(1.0)
    np.maximum(prnu, 0.0, out=prnu)
    dsnu = np.random.default_rng(s_dsnu).standard_normal((h, w), dtype=np.float32)
    dsnu *= np.float32(sensor.dsnu_e)
    rng_hot = np.random.default_rng(s_hot)
    n_hot = min(int(hot_pixels), h * w)
    hot_index = np.sort(rng_hot.choice(h * w, size=n_hot, replace=False)) if n_hot else np.zeros(0, np.int64)
    hot_dark = sensor.hot_pixel_dark_e_s * np.exp(rng_hot.normal(0.0, sensor.hot_pixel_log_sigma, n_hot))
    pattern = FixedPattern(prnu, dsnu, hot_index.astype(np.int64), hot_dark)
    if len(_PATTERN_CACHE) > 8:
        _PATTERN_CACHE.clear()
    _PATTERN_CACHE[key] = pattern
    return pattern


# --- the chain ---------------------------------------------------------------------------
class _Switches(NamedTuple):
    """What the detector kernel does (the sources on, the hot pixels and extra charge given)."""

    prnu: bool
    shot: bool
    dark: bool
    hot: bool
    extra: bool
    dsnu: bool
    read: bool
    ktc: bool
    round: bool


class _Levels(NamedTuple):
    """The detector kernel's numbers: means and σ in electrons, the ADC's conversion."""

    dark_e: float
    read_sigma: float
    ktc_sigma: float
    full_well: float
    inv_gain: float
    bias: float
    max_adu: float


@njit(cache=True, nogil=True)
def _detect(photo, gain, dsnu, hot_index, hot_e, extra, on, lv, states, out):
    """One pass over the frame, a chunk of _CHUNK pixels at a time (kept in the L1 cache), in
    order: the expected photo-electrons (× the PRNU gain), their Poisson draw, the dark
    current's Poisson draw (its own stream), the hot pixels' and the extra charge, the full
    well, the DSNU offset, read and reset noise (a normal each, their own streams), gain, bias,
    the ADC's range and rounding. Each source is a tight loop of its own over the chunk (one
    stream in registers). Returns how many means were negative or not finite (drawn as 0)."""
    p = photo.ravel()
    g = gain.ravel()
    dm = dsnu.ravel()
    x = extra.ravel()
    o = out.ravel()
    n = p.size
    dark_e = lv.dark_e  # float64, of the float32 value (apply_detector)
    shot, dark, read, ktc = _load(states[0]), _load(states[1]), _load(states[2]), _load(states[3])
    sparse = on.dark and dark_e < _SPARSE_MAX  # the dark current's non-zero pixels by their gaps
    p0 = math.exp(-dark_e)
    next_dark = np.int64(-1)
    if sparse:
        next_dark, dark = _gap(dark, dark_e)
    e = np.empty(_CHUNK, np.float32)  # the charge, electrons
    u = np.empty(_CHUNK, np.float64)  # the shot noise's uniforms
    a = np.empty(_CHUNK, np.float64)  # the signal read out, electrons
    z = np.empty(_CHUNK, np.float32)  # read or reset noise's normal deviates
    bad = 0
    j = 0
    for start in range(0, n, _CHUNK):
        size = min(_CHUNK, n - start)
        bad += _means(p, g, on.prnu, start, size, e)
        if on.shot:
            shot = _poisson_chunk(e, u, size, shot)
        if sparse:
            while next_dark < start + size:
                k, dark = _nonzero(dark, dark_e, p0)
                e[next_dark - start] += np.float32(k)
                gap, dark = _gap(dark, dark_e)
                next_dark += gap + 1
        elif on.dark:
            for c in range(size):
                k, dark = _poisson(dark, dark_e)
                e[c] += np.float32(k)
        if on.hot:
            while j < hot_index.size and hot_index[j] < start + size:
                e[hot_index[j] - start] += np.float32(hot_e[j])
                j += 1
        if on.extra:
            for c in range(size):
                e[c] += x[start + c]
        for c in range(size):
            a[c] = min(np.float64(e[c]), lv.full_well)
        if on.dsnu:
            for c in range(size):
                a[c] += dm[start + c]
        if on.read:
            read = _normals_chunk(z, size, read)
            for c in range(size):
                a[c] += lv.read_sigma * z[c]
        if on.ktc:
            ktc = _normals_chunk(z, size, ktc)
            for c in range(size):
                a[c] += lv.ktc_sigma * z[c]
        oo = o[start:start + size]
        if on.round:
            for c in range(size):
                oo[c] = math.floor(min(max(a[c] * lv.inv_gain + lv.bias, 0.0), lv.max_adu) + 0.5)
        else:
            for c in range(size):
                oo[c] = min(max(a[c] * lv.inv_gain + lv.bias, 0.0), lv.max_adu)
    _store(states[0], shot)
    _store(states[1], dark)
    _store(states[2], read)
    _store(states[3], ktc)
    return bad


def apply_detector(photo_e: np.ndarray, sensor: Sensor, exposure_s: float,
                   streams: Mapping[str, np.random.Generator], *, noise: bool | Mapping[str, bool] = True,
                   hot_pixels: int = 0, extra_e: np.ndarray | None = None) -> np.ndarray:
    """Turn expected photo-electrons into an image in ADU, in one pass over the pixels.

    Parameters
    ----------
    photo_e : (H, W) array
        Expected photo-electrons per pixel (stars, sky, stray light; QE already applied).
    sensor : Sensor
    exposure_s : float
        Integration time, seconds (scales dark current).
    streams : mapping
        One ``Generator`` per temporal source: ``"shot"``, ``"dark"``, ``"read"``, ``"ktc"``; each
        seeds its source's xoshiro256** stream (:func:`stream_state`).
    noise : bool or mapping
        Which sources are on (see :data:`NOISE_SOURCES`); switched-off sources are absent,
        not just noiseless (``dark`` off removes the dark mean as well).
    hot_pixels : int
        Number of hot pixels (positions fixed by ``sensor.pattern_seed``).
    extra_e : (H, W) array, optional
        Charge added after shot noise (cosmic-ray hits), electrons.

    Returns
    -------
    (H, W) ndarray
        ``uint16`` ADU when ``quantization`` is on (rounded), else ``float32`` ADU.

    Notes
    -----
    Every draw is exact in distribution: Poisson by inversion (mean < 12) or PTRS, normals by
    the ziggurat (:func:`_normal`); no normal approximation of a Poisson anywhere.
    A pixel's noise comes from the four streams in pixel order, so a frame is a pure function of
    its seed. The arithmetic is float32 up to the charge and float64 from the full well on.
    """
    on = noise_switches(noise)
    photo_e = np.ascontiguousarray(photo_e, dtype=np.float32)
    shape = photo_e.shape
    need_pattern = on["prnu"] or on["dsnu"] or (on["hot_pixels"] and hot_pixels > 0)
    pattern = fixed_pattern(sensor, shape, hot_pixels if on["hot_pixels"] else 0) if need_pattern else None
    none = np.zeros((1, 1), np.float32)

    switches = _Switches(
        prnu=bool(on["prnu"] and sensor.prnu > 0), shot=bool(on["shot"]),
        dark=bool(on["dark"] and sensor.dark_current_e_s > 0),
        hot=bool(on["hot_pixels"] and pattern is not None and pattern.hot_index.size > 0),
        extra=extra_e is not None, dsnu=bool(on["dsnu"] and sensor.dsnu_e > 0),
        read=bool(on["read"] and sensor.read_noise_e > 0), ktc=bool(on["ktc"] and sensor.ktc_noise_e > 0),
        round=bool(on["quantization"]))
    levels = _Levels(float(np.float32(sensor.dark_current_e_s * exposure_s)), float(sensor.read_noise_e),
                     float(sensor.ktc_noise_e), float(sensor.full_well_e), 1.0 / sensor.gain_e_per_adu,
                     float(sensor.bias_adu), float(sensor.max_adu))
    states = np.stack([stream_state(streams[k]) if getattr(switches, k) else np.ones(4, np.uint64)
                       for k in ("shot", "dark", "read", "ktc")])
    hot_index, hot_e = np.zeros(0, np.int64), np.zeros(0, np.float64)
    if switches.hot:  # drawn from the dark source's numpy Generator, after its stream's state
        hot_index = pattern.hot_index
        hot_e = streams["dark"].poisson(pattern.hot_dark_e_s * exposure_s).astype(np.float64)
    extra = np.ascontiguousarray(extra_e, dtype=np.float32) if switches.extra else none
    if switches.extra and extra.shape != shape:
        raise SimulationError(f"extra_e is {extra.shape}, the frame {shape}")
    out = np.empty(shape, dtype=np.uint16 if switches.round else np.float32)
    bad = _detect(photo_e, pattern.prnu_gain if switches.prnu else none,
                  pattern.dsnu_e if switches.dsnu else none, hot_index, hot_e, extra, switches, levels,
                  states, out)
    if bad:
        raise SimulationError("expected electron counts must be finite and non-negative")
    return out
