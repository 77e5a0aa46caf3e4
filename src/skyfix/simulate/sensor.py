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

Each temporal source draws from its own ``numpy.random.Generator`` (spawned from one
``SeedSequence``), so a frame is bit-for-bit repeatable and switching one source off does not
change the others' draws. Fixed-pattern maps (PRNU, DSNU, hot pixels) come from
``Sensor.pattern_seed``: they belong to the sensor, not to the frame.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import tomllib

from skyfix._jit import njit
from skyfix.errors import SimulationError
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


# --- Poisson sampling --------------------------------------------------------------------
@lru_cache(maxsize=64)
def _poisson_table(lam0: float) -> tuple[np.ndarray, int, np.ndarray]:
    """CDF table of Poisson(lam0) over ``lo .. lo+len-1`` (±12σ: the tails beyond hold < 1e-30),
    and a guide table for O(1) inversion."""
    from scipy.stats import poisson

    sd = math.sqrt(lam0)
    lo = max(0, int(math.floor(lam0 - 12.0 * sd - 10.0)))
    hi = int(math.ceil(lam0 + 12.0 * sd + 10.0))
    k = np.arange(lo, hi + 1)
    cdf = poisson.cdf(k, lam0)
    cdf[-1] = 1.0
    m = len(cdf)
    guide = np.searchsorted(cdf, np.arange(m) / m, side="left").astype(np.int64)
    return cdf, lo, guide


@njit(cache=True, nogil=True)
def _draw_table(u, cdf, lo, guide):
    m = cdf.size
    j = guide[int(u * m)]
    while cdf[j] < u:
        j += 1
    return lo + j


#: Below this mean a pixel's Poisson count is drawn by inverting one uniform (about mean + 1
#: steps), at or above it by ``Generator.poisson`` (PTRS).
_SEARCH_MAX = 12.0


@njit(cache=True, nogil=True, inline="always")
def _certain(u, lam):
    """Poisson(lam) of the uniform u where bounds settle it without exp: 0 or 1; else -1."""
    if u <= 1.0 - lam:  # exp(-lam) >= 1 - lam: certainly 0 (skips exp for the faint majority)
        return 0
    # 1 - lam + lam²/2 >= exp(-lam) and (1 + lam)·exp(-lam) >= 1 - lam²: certainly 1
    return 1 if 1.0 - lam + 0.5 * lam * lam < u <= 1.0 - lam * lam else -1


@njit(cache=True, nogil=True)
def _invert_small(u, lam):
    # Poisson(lam) of the uniform u by sequential search of the CDF: about lam + 1 steps.
    k = _certain(u, lam)
    if k >= 0:
        return k
    p = math.exp(-lam)
    s = p
    k = 0
    while u > s and k < 1000:
        k += 1
        p *= lam / k
        s += p
    return k


@njit(cache=True, nogil=True)
def _poisson_small(rng, lam):
    return _invert_small(rng.random(), lam)


@njit(cache=True, nogil=True)
def _lowest(lam, gain, scaled):
    """(the smallest of ``lam·gain`` — ``lam`` when not ``scaled`` —, whether all are finite),
    the products in float32 as numpy forms them, none kept."""
    flat = lam.ravel()
    g = gain.ravel()
    lo = np.float32(np.inf)
    finite = True
    for i in range(flat.size):
        m = flat[i] * g[i] if scaled else flat[i]
        if not np.isfinite(m):
            finite = False
        elif m < lo:
            lo = m
    return lo, finite


@njit(cache=True, nogil=True)
def _poisson_dim(lam, gain, scaled, u, rng, out):
    """out[i] = Poisson(lam[i]·gain[i]) (``lam[i]`` when not ``scaled``; the product in float32):
    the uniform u[i] inverted where the mean is < _SEARCH_MAX (u drawn in bulk beforehand),
    ``rng.poisson`` in pixel order elsewhere (star cores). Two passes: the pixels that bounds
    settle (0 or 1: 94 % of them at a mean of 0.2 e⁻) in one pass, then the rest."""
    flat = lam.ravel()
    g = gain.ravel()
    uu = u.ravel()
    o = out.ravel()
    for i in range(flat.size):  # a mean >= _SEARCH_MAX is never settled (1 - m² < 0 <= u)
        o[i] = _certain(uu[i], flat[i] * g[i] if scaled else flat[i])
    for i in range(flat.size):
        if o[i] >= 0.0:
            continue
        m = flat[i] * g[i] if scaled else flat[i]
        if m < _SEARCH_MAX:
            o[i] = _invert_small(uu[i], m)
        else:
            o[i] = rng.poisson(m)


@njit(cache=True, nogil=True)
def _poisson_image(lam, lam0, cdf, lo, guide, rng, out):
    """out[i] = Poisson(lam[i]) drawn as Poisson(lam0) (table) + Poisson(lam[i] - lam0)."""
    flat = lam.ravel()
    o = out.ravel()
    use_table = lam0 > 0.0
    for i in range(flat.size):
        k = 0
        if use_table:
            k = _draw_table(rng.random(), cdf, lo, guide)
        d = flat[i] - lam0
        if d > 0.0:
            if d < _SEARCH_MAX:
                k += _poisson_small(rng, d)
            else:
                k += rng.poisson(d)
        o[i] = k


def poisson_image(lam: np.ndarray, rng: np.random.Generator, gain: np.ndarray | None = None) -> np.ndarray:
    """Poisson draws (float32, same shape) with per-pixel means ``lam`` (electrons), or
    ``lam · gain`` (float32; a PRNU map, the product never stored on a dark frame).

    Exact Poisson, fast for star-tracker frames. A dark frame (the smallest mean below 1
    electron, as every star tracker's sky): one uniform per pixel drawn in bulk and inverted
    (a pixel of mean < 12, nearly always 0 in one comparison), ``Generator.poisson`` for the few
    brighter pixels. A bright background: the common floor of the means from a cached CDF table,
    the excess per pixel by inversion (small) or PTRS (``Generator.poisson``).
    """
    lam = np.ascontiguousarray(lam, dtype=np.float32)
    out = np.empty(lam.shape, dtype=np.float32)
    if lam.size == 0:
        return out
    scaled = gain is not None
    gain = np.ascontiguousarray(gain, dtype=np.float32) if scaled else np.ones((1, 1), np.float32)
    if scaled and gain.shape != lam.shape:
        raise SimulationError(f"gain map is {gain.shape}, the means {lam.shape}")
    lowest, finite = _lowest(lam, gain, scaled)
    if not finite or lowest < 0:
        raise SimulationError("expected electron counts must be finite and non-negative")
    lam0 = float(lowest)
    if lam0 < 1.0:
        _poisson_dim(lam, gain, scaled, rng.random(lam.shape), rng, out)
        return out
    if scaled:
        lam = lam * gain
    if lam0 > 1e6:  # the table would be too long; no star-tracker background is this bright
        return rng.poisson(lam).astype(np.float32)
    cdf, lo, guide = _poisson_table(lam0) if lam0 > 0 else (np.ones(1), 0, np.zeros(1, np.int64))
    _poisson_image(lam, lam0, cdf, lo, guide, rng, out)
    return out


@njit(cache=True, nogil=True)
def _fill_nonzero(out, gaps, u, p0, lam):
    """Pixels ``cumsum(gaps) - 1`` get Poisson(lam) given ≥ 1 (u[j] mapped above P(0) = p0 and
    inverted), added to them (float32, as numpy adds two float32 frames); returns how many fell
    inside ``out``."""
    o = out.ravel()
    pos = -1
    for j in range(gaps.size):
        pos += gaps[j]
        if pos >= o.size:
            return j
        o[pos] = o[pos] + np.float32(_invert_small(p0 + u[j] * (1.0 - p0), lam))
    return gaps.size


@njit(cache=True, nogil=True)
def _invert_table(u, cdf, lo, guide, out):
    o = out.ravel()
    for i in range(o.size):
        o[i] = o[i] + np.float32(_draw_table(u[i], cdf, lo, guide))


def poisson_constant(lam: float, shape: tuple[int, int], rng: np.random.Generator,
                     into: np.ndarray | None = None) -> np.ndarray:
    """Poisson draws (float32) with one mean ``lam`` for every pixel, exact; added to ``into``
    (float32, C-contiguous, in place: the same numbers as ``into + poisson_constant(…)``) and
    that returned, when given.

    A mean below 0.25 (a dark current of a fraction of an electron): the pixels that are not 0
    are found by geometric gaps between them (a pixel is not 0 with chance ``1 − e^(−lam)``,
    independently), each then drawn from the Poisson given ≥ 1 — about ``lam`` draws a pixel.
    Larger means: one uniform per pixel, in bulk, through a cached CDF table.
    """
    out = np.zeros(shape, dtype=np.float32) if into is None else into
    if into is not None and not (into.dtype == np.float32 and into.shape == tuple(shape)
                                 and into.flags.c_contiguous):
        raise SimulationError("into must be a C-contiguous float32 frame of the shape")
    if lam <= 0:
        return out
    lam = float(np.float32(lam))
    if lam < 0.25:
        p0 = math.exp(-lam)
        n, done = out.size, 0
        chunk = int(n * (1.0 - p0) * 1.05) + 64
        while True:  # the gaps in chunks: a chunk rarely falls short of the frame's end
            gaps = rng.geometric(1.0 - p0, size=chunk)
            if done:
                gaps[0] += done
            filled = _fill_nonzero(out, gaps, rng.random(chunk), p0, lam)
            if filled < chunk:
                return out
            done = int(np.sum(gaps))
            if done >= n:
                return out
    _invert_table(rng.random(out.size), *_poisson_table(lam), out)
    return out


# --- Gaussian deviates ------------------------------------------------------------------
#: The normal quantile is tabulated for uniforms in [_Q_LO, 1 − _Q_LO] (96 % of draws) on
#: _Q_STEPS equal steps and interpolated linearly; the tails use Wichura's AS241.
_Q_LO = 0.02
_Q_STEPS = 32768
# Wichura (1988), AS241 PPND16, the tail branches: |error| < 1e-15 relative (checked against
# scipy.special.ndtri in tests/simulate/test_simulate_sensor.py).
_AS241_C = np.array([1.42343711074968357734e0, 4.63033784615654529590e0, 5.76949722146069140550e0,
                     3.64784832476320460504e0, 1.27045825245236838258e0, 2.41780725177450611770e-1,
                     2.27238449892691845833e-2, 7.74545014278341407640e-4])
_AS241_D = np.array([1.0, 2.05319162663775882187e0, 1.67638483018380384940e0, 6.89767334985100004550e-1,
                     1.48103976427480074590e-1, 1.51986665636164571966e-2, 5.47593808499534494600e-4,
                     1.05075007164441684324e-9])
_AS241_E = np.array([6.65790464350110377720e0, 5.46378491116411436990e0, 1.78482653991729133580e0,
                     2.96560571828504891230e-1, 2.65321895265761230930e-2, 1.24266094738807843860e-3,
                     2.71155556874348757815e-5, 2.01033439929228813265e-7])
_AS241_F = np.array([1.0, 5.99832206555887937690e-1, 1.36929880922735805310e-1, 1.48753612908506148525e-2,
                     7.86869131145613259100e-4, 1.84631831751005468180e-5, 1.42151175831644588870e-7,
                     2.04426310338993978564e-15])


@lru_cache(maxsize=1)
def _quantile_table() -> np.ndarray:
    """The exact normal quantile at ``_Q_LO + (1 − 2·_Q_LO)·j/_Q_STEPS``, j = 0 … _Q_STEPS."""
    from scipy.special import ndtri

    return ndtri(np.linspace(_Q_LO, 1.0 - _Q_LO, _Q_STEPS + 1))


@njit(cache=True, nogil=True, inline="always")
def _horner(c, r):
    v = c[7]
    for j in range(6, -1, -1):
        v = v * r + c[j]
    return v


@njit(cache=True, nogil=True)
def _normal_tail(u):
    """AS241's quantile of ``u`` beyond ±0.425 from the middle."""
    r = math.sqrt(-math.log(max(min(u, 1.0 - u), 1e-300)))
    if r <= 5.0:
        r -= 1.6
        v = _horner(_AS241_C, r) / _horner(_AS241_D, r)
    else:
        r -= 5.0
        v = _horner(_AS241_E, r) / _horner(_AS241_F, r)
    return -v if u < 0.5 else v


@njit(cache=True, nogil=True)
def _normals_of_uniforms(u, table, out):
    # pass 1, branch-free: the table's linear interpolation (clamped at its ends) for every u;
    # pass 2: the 4 % of u in the tails again, by AS241
    scale = _Q_STEPS / (1.0 - 2.0 * _Q_LO)
    for i in range(u.size):
        t = min(max((u[i] - _Q_LO) * scale, 0.0), _Q_STEPS - 1e-9)
        j = int(t)
        out[i] = table[j] + (t - j) * (table[j + 1] - table[j])
    for i in range(u.size):
        if not (_Q_LO <= u[i] <= 1.0 - _Q_LO):
            out[i] = _normal_tail(u[i])


def standard_normals(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """float32 standard normal deviates by inversion, one float64 uniform of ``rng`` each: the
    tabulated quantile interpolated linearly in the middle 96 % (error ≤ h²/8·max|Q''| =
    9.4e-8, below a float32's resolution at |z| ≥ 1), Wichura's AS241 in the tails (1e-15).
    About half the time of numpy's ziggurat here, for the read and reset noise of every pixel."""
    out = np.empty(shape, dtype=np.float32)
    _normals_of_uniforms(rng.random(out.size), _quantile_table(), out.ravel())
    return out


# --- the chain ---------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def _readout(charge, dsnu, read_sigma, ktc_sigma, z_read, z_ktc, inv_gain, bias, max_adu,
             full_well, do_dsnu, do_read, do_ktc, do_round, out):
    # z_read, z_ktc: standard normal deviates, one a pixel (when on)
    c = charge.ravel()
    dm = dsnu.ravel()
    zr = z_read.ravel()
    zk = z_ktc.ravel()
    o = out.ravel()
    for i in range(c.size):
        e = c[i]
        if e > full_well:
            e = full_well
        if do_dsnu:
            e += dm[i]
        if do_read:
            e += read_sigma * zr[i]
        if do_ktc:
            e += ktc_sigma * zk[i]
        a = e * inv_gain + bias
        if a < 0.0:
            a = 0.0
        elif a > max_adu:
            a = max_adu
        if do_round:
            a = math.floor(a + 0.5)
        o[i] = a  # exact in uint16 after rounding


def apply_detector(photo_e: np.ndarray, sensor: Sensor, exposure_s: float,
                   streams: Mapping[str, np.random.Generator], *, noise: bool | Mapping[str, bool] = True,
                   hot_pixels: int = 0, extra_e: np.ndarray | None = None) -> np.ndarray:
    """Turn expected photo-electrons into an image in ADU.

    Parameters
    ----------
    photo_e : (H, W) array
        Expected photo-electrons per pixel (stars, sky, stray light; QE already applied).
    sensor : Sensor
    exposure_s : float
        Integration time, seconds (scales dark current).
    streams : mapping
        One ``Generator`` per temporal source: ``"shot"``, ``"dark"``, ``"read"``, ``"ktc"``.
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
    """
    on = noise_switches(noise)
    photo_e = np.asarray(photo_e, dtype=np.float32)
    shape = photo_e.shape
    need_pattern = on["prnu"] or on["dsnu"] or (on["hot_pixels"] and hot_pixels > 0)
    pattern = fixed_pattern(sensor, shape, hot_pixels if on["hot_pixels"] else 0) if need_pattern else None

    gain = pattern.prnu_gain if (on["prnu"] and sensor.prnu > 0) else None
    if on["shot"]:
        charge = poisson_image(photo_e, streams["shot"], gain)
    else:
        charge = np.array(photo_e if gain is None else photo_e * gain, dtype=np.float32)
    if on["dark"] and sensor.dark_current_e_s > 0:
        poisson_constant(sensor.dark_current_e_s * exposure_s, shape, streams["dark"], into=charge)
    if on["hot_pixels"] and pattern is not None and pattern.hot_index.size:
        hot = streams["dark"].poisson(pattern.hot_dark_e_s * exposure_s)
        charge.ravel()[pattern.hot_index] += hot.astype(np.float32)
    if extra_e is not None:
        charge += np.asarray(extra_e, dtype=np.float32)

    do_round = on["quantization"]
    out = np.empty(shape, dtype=np.uint16 if do_round else np.float32)
    dsnu_map = pattern.dsnu_e if (pattern is not None and on["dsnu"]) else np.zeros((1, 1), np.float32)
    do_read, do_ktc = bool(on["read"] and sensor.read_noise_e > 0), bool(on["ktc"] and sensor.ktc_noise_e > 0)
    _readout(charge, dsnu_map, float(sensor.read_noise_e), float(sensor.ktc_noise_e),
             standard_normals(streams["read"], shape if do_read else (1, 1)),
             standard_normals(streams["ktc"], shape if do_ktc else (1, 1)),
             1.0 / sensor.gain_e_per_adu, float(sensor.bias_adu), float(sensor.max_adu),
             float(sensor.full_well_e), bool(on["dsnu"] and sensor.dsnu_e > 0), do_read, do_ktc, do_round,
             out)
    return out
