"""A camera on the ground: its site, the weather, and the directions it sees the catalogue's stars
in — light deflection, aberration, Earth rotation and refraction applied per star
(docs/frames-and-refraction.md).

The engine is ERFA's astrometry (``erfa.apco13``, set up once per time and site): the
catalogue's ICRS directions are bent by the Sun (``erfa.ldsun``) and aberrated (``erfa.ab``, the
Earth's and the site's velocity), rotated into the local frame, then refracted. Step by step:

1. **Set up** (:func:`ground_frame`, cached per time, site and weather, ~0.2 ms): ERFA's
   star-independent astrometry parameters for the UTC Julian date, UT1 − UTC and polar motion
   (defaults 0: no IERS tables are read, nothing is downloaded), and from them the rigid
   rotations ``A_cirs_to_enu = A_z(90°)·A_y(90° − φ)·A_x(−y_p)·A_y(−x_p)·A_z(ERA + λ)`` (the
   steps of ``eraAtioq``, polar motion as an exact rotation) and
   ``A_icrs_to_enu = A_cirs_to_enu · BPN``. The local frame ENU is (east, north, up); azimuth
   runs from north through east, as in ERFA and astropy.
2. **Per star** (:func:`observed_enu`, vectorised): ``p = ab(ldsun(r))``, ``u = A_icrs_to_enu p``
   — ERFA's ``atciqz`` and ``atioq`` without their spherical round trips — then refraction
   lifts ``u`` toward the zenith by ``Δ(altitude)`` in its vertical plane (:func:`refract_enu`).
3. **Refraction models** (:data:`REFRACTION_MODELS`): ``"erfa"`` (the default) is ERFA's
   ``A tan z + B tan³ z`` with the constants of ``erfa.refco`` for the weather, applied to the
   true zenith distance with ``eraAtioq``'s Newton correction; ``"bennett"`` is thesis 003's
   Eq. 5.1, Bennett's formula, ``R = cot(h_a + 7.31/(h_a + 4.4))′ · (P/1010 hPa)·(283/(273 + T))``
   of the *apparent* altitude ``h_a``: a star at true altitude ``h`` is seen at the ``h_a`` that
   solves ``h_a = h + R(h_a)``, higher (the sign thesis 003's Eq. 5.5 gets wrong: the seed text
   corrects it — an observed direction is *lowered* by ``R(h_a)`` to its true place, a catalogue
   direction raised); ``"none"`` applies none.

**The frame the attitude comes out in.** :func:`observed_directions` returns the observed
directions in ICRS *axes*: ``A_icrs_to_enuᵀ u``. Fitted to them, ``A_icrs_to_cam`` is the
camera's physical orientation against the ICRS axes — refraction and aberration are in the
stars, not in the attitude — so ``A_enu_to_cam = A_icrs_to_cam · A_icrs_to_enuᵀ`` exactly (the
mounting of thesis 003 §2.10), and :func:`altaz_of` of the boresight ``A[2]`` is where the
camera points, refracted. The boresight's catalogue (astrometric ICRS) place — the star that
would sit on it — and its apparent place of date (JNow, unrefracted, what a telescope mount or a
push-to finder uses) are :func:`boresight_places`: the transform inverted (refraction by
iteration, aberration and deflection by ``erfa.aticq``).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import erfa
import numpy as np

from skyfix.errors import InputError
from skyfix.frames import elementary_rotation
from skyfix.validate import EPOCH_RANGE

__all__ = [
    "AltAz", "BoresightPlaces", "GroundFrame", "REFRACTION_MODELS", "Refraction", "Site", "Weather",
    "altaz_of", "apparent_enu", "bennett_refraction_arcmin", "boresight_places", "check_site_weather",
    "ground_frame", "observed_directions", "observed_enu", "refract_enu", "unrefract_enu",
]

#: Refraction models by name: ERFA's (default), thesis 003's Bennett formula, none.
REFRACTION_MODELS = ("erfa", "bennett", "none")

#: ERFA's floors in ``eraAtioq``: the sine of the altitude (2.87°) and the cosine used in tan z.
ERFA_SIN_ALT_MIN = 0.05
ERFA_COS_ALT_MIN = 1e-6
#: Bennett's formula is evaluated no lower than this apparent altitude (degrees; it diverges at −4.4°).
BENNETT_MIN_ALT_DEG = -1.0
#: Thesis 003's reference weather for Bennett's formula: 1010 hPa (101 kPa), 283 K.
BENNETT_PRESSURE_HPA = 1010.0
BENNETT_TEMPERATURE_K = 283.0
#: A standard atmosphere when no weather is given: 10 °C, relative humidity 0.5, and the pressure
#: of the site's height by ERFA's rule ``1013.25 exp(−h / (29.3 · 288.15 K))`` hPa.
STANDARD_TEMPERATURE_C = 10.0
STANDARD_RELATIVE_HUMIDITY = 0.5
STANDARD_WAVELENGTH_UM = 0.55
_SCALE_HEIGHT_M = 29.3 * 288.15

_LIMITS = {  # name: (low, high, unit)
    "site latitude": (-90.0, 90.0, "degrees"),
    "site longitude": (-180.0, 360.0, "degrees"),
    "site height": (-1000.0, 20000.0, "m"),
    "temperature": (-100.0, 60.0, "°C"),
    "pressure": (0.0, 1200.0, "hPa"),
    "relative humidity": (0.0, 1.0, "(a fraction: 0.5 for 50 %)"),
    "wavelength": (0.3, 2.0, "µm"),
}
_ITERATIONS = 30  # iterations at most (Newton's take 3–4; refraction's slope is below 0.25)


def _checked(value: object, name: str) -> float:
    lo, hi, unit = _LIMITS[name]
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"{name} {value!r} is not a number") from None
    if not lo <= v <= hi:  # NaN fails too
        raise InputError(f"{name} {value} is not in {lo:g}..{hi:g} {unit}")
    return v


def _split(text: str, name: str, counts: tuple[int, ...], form: str) -> list[float]:
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) not in counts:
        raise InputError(f"{name} {text!r} is not {form}")
    try:
        return [float(p) for p in parts]
    except ValueError:
        raise InputError(f"{name} {text!r} is not {form}") from None


@dataclass(frozen=True)
class Site:
    """Where the camera is: geodetic latitude and east longitude (degrees, WGS84) and height above
    the ellipsoid (m). Checked when made: a latitude outside ±90° is an InputError."""

    lat_deg: float
    lon_deg: float
    height_m: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "lat_deg", _checked(self.lat_deg, "site latitude"))
        object.__setattr__(self, "lon_deg", _checked(self.lon_deg, "site longitude"))
        object.__setattr__(self, "height_m", _checked(self.height_m, "site height"))

    @classmethod
    def parse(cls, text: str, name: str = "site") -> Site:
        """From ``"LAT,LON[,HEIGHT_M]"`` (degrees, degrees east, metres)."""
        return cls(*_split(text, name, (2, 3), "LAT,LON,HEIGHT_M (degrees, degrees east, metres)"))


@dataclass(frozen=True)
class Weather:
    """The air at the site: temperature (°C), pressure (hPa, at the site, not reduced to sea
    level), relative humidity (a fraction 0–1) and the effective wavelength (µm)."""

    temperature_c: float = STANDARD_TEMPERATURE_C
    pressure_hpa: float = 1013.25
    relative_humidity: float = STANDARD_RELATIVE_HUMIDITY
    wavelength_um: float = STANDARD_WAVELENGTH_UM

    def __post_init__(self) -> None:
        for field, name in (("temperature_c", "temperature"), ("pressure_hpa", "pressure"),
                            ("relative_humidity", "relative humidity"), ("wavelength_um", "wavelength")):
            object.__setattr__(self, field, _checked(getattr(self, field), name))

    @classmethod
    def parse(cls, text: str, name: str = "weather") -> Weather:
        """From ``"T_C,P_HPA[,RH]"`` (°C, hPa at the site, relative humidity 0–1)."""
        return cls(*_split(text, name, (2, 3), "T_C,P_HPA,RH (°C, hPa, relative humidity 0-1)"))

    @classmethod
    def standard(cls, height_m: float = 0.0) -> Weather:
        """10 °C, RH 0.5 and the pressure of a standard atmosphere at ``height_m``."""
        return cls(pressure_hpa=1013.25 * math.exp(-float(height_m) / _SCALE_HEIGHT_M))


def check_site_weather(site: Site | str | None, weather: Weather | str | None,
                       names: tuple[str, str] = ("site", "weather")) -> tuple[Site | None, Weather | None]:
    """A site and weather (parsed from their strings), checked together: weather needs a site."""
    if weather is not None and site is None:
        raise InputError(f"{names[1]} needs a {names[0]}: refraction depends on where the camera is")
    s = Site.parse(site, names[0]) if isinstance(site, str) else site
    w = Weather.parse(weather, names[1]) if isinstance(weather, str) else weather
    return s, w


# --- refraction -----------------------------------------------------------------------------------
def bennett_refraction_arcmin(apparent_alt_deg: float | np.ndarray,
                              pressure_hpa: float = BENNETT_PRESSURE_HPA,
                              temperature_c: float = 10.0) -> np.ndarray:
    """Bennett's refraction (thesis 003 Eq. 5.1), arcminutes, at apparent altitude ``h_a``:
    ``cot(h_a + 7.31/(h_a + 4.4))·(P/1010 hPa)·(283/(273 + T))``, ``h_a`` in degrees (evaluated
    no lower than :data:`BENNETT_MIN_ALT_DEG`). 9.883′ at 5°, 1.1848′ at 40° for 1010 hPa, 10 °C.
    """
    return _bennett(apparent_alt_deg, pressure_hpa, temperature_c)[0]


def _bennett(apparent_alt_deg: float | np.ndarray, pressure_hpa: float, temperature_c: float,
             ) -> tuple[np.ndarray, np.ndarray]:
    """Bennett's formula (arcmin) and its slope d/dh_a (arcmin per degree; 0 below the floor)."""
    h_raw = np.asarray(apparent_alt_deg, dtype=np.float64)
    h = np.maximum(h_raw, BENNETT_MIN_ALT_DEG)
    scale = pressure_hpa / BENNETT_PRESSURE_HPA * BENNETT_TEMPERATURE_K / (273.0 + temperature_c)
    x = np.radians(h + 7.31 / (h + 4.4))
    value = scale / np.tan(x)
    slope = -scale / np.sin(x) ** 2 * (1.0 - 7.31 / (h + 4.4) ** 2) * (math.pi / 180.0)
    return value, np.where(h_raw >= BENNETT_MIN_ALT_DEG, slope, 0.0)


class Refraction(NamedTuple):
    """A refraction model with its constants (:meth:`for_weather`).

    model : one of :data:`REFRACTION_MODELS`.
    refa_rad, refb_rad : ERFA's A and B (``erfa.refco``), radians (model ``"erfa"``).
    pressure_hpa, temperature_c : the weather Bennett's formula scales by (model ``"bennett"``).
    """

    model: str
    refa_rad: float
    refb_rad: float
    pressure_hpa: float
    temperature_c: float

    @classmethod
    def for_weather(cls, weather: Weather, model: str = "erfa") -> Refraction:
        refa, refb = erfa.refco(weather.pressure_hpa, weather.temperature_c, weather.relative_humidity,
                                weather.wavelength_um)
        return cls(model, float(refa), float(refb), weather.pressure_hpa, weather.temperature_c)

    def _bennett_rad(self, apparent_alt_rad: np.ndarray) -> np.ndarray:
        return np.radians(bennett_refraction_arcmin(np.degrees(apparent_alt_rad), self.pressure_hpa,
                                                    self.temperature_c) / 60.0)

    def lift_rad(self, sin_alt: np.ndarray, cos_alt: np.ndarray) -> np.ndarray:
        """How far refraction raises a star at the geometric altitude of sine ``sin_alt`` and
        cosine ``cos_alt``, radians."""
        if self.model == "erfa":  # eraAtioq: A tan z + B tan³ z with its Newton correction
            z = np.maximum(sin_alt, ERFA_SIN_ALT_MIN)
            tz = np.maximum(cos_alt, ERFA_COS_ALT_MIN) / z
            w = self.refb_rad * tz * tz
            return (self.refa_rad + w) * tz / (1.0 + (self.refa_rad + 3.0 * w) / (z * z))
        if self.model == "bennett":  # h_a = h + R(h_a) by Newton's method, from h_a = h + R(h)
            h = np.degrees(np.arctan2(sin_alt, cos_alt))
            h_a = h + bennett_refraction_arcmin(h, self.pressure_hpa, self.temperature_c) / 60.0
            for _ in range(_ITERATIONS):
                value, slope = _bennett(h_a, self.pressure_hpa, self.temperature_c)
                step = (h_a - h - value / 60.0) / (1.0 - slope / 60.0)
                h_a = h_a - step
                if np.all(np.abs(step) < 1e-13):
                    break
            return np.radians(h_a - h)
        return np.zeros_like(sin_alt)

    def drop_rad(self, sin_alt: np.ndarray, cos_alt: np.ndarray) -> np.ndarray:
        """How far an observed star at the apparent altitude of sine ``sin_alt`` and cosine
        ``cos_alt`` lies above its true place, radians (Bennett's formula directly, thesis 003's
        correction; ERFA's model inverted)."""
        h = np.arctan2(sin_alt, cos_alt)
        if self.model == "bennett":
            return self._bennett_rad(h)
        if self.model == "erfa":  # h_a = h + lift(h), from h = h_a − lift(h_a)
            return _fixed_point(lambda d: self.lift_rad(np.sin(h - d), np.cos(h - d)),
                                self.lift_rad(sin_alt, cos_alt))
        return np.zeros_like(h)


def _fixed_point(f: Callable[[np.ndarray], np.ndarray], x0: np.ndarray) -> np.ndarray:
    """``x = f(x)`` by iteration from ``x0`` (a contraction: refraction's slope is below 0.25)."""
    x = x0
    for _ in range(_ITERATIONS):
        x_new = f(x)
        if np.all(np.abs(x_new - x) < 1e-15):
            return x_new
        x = x_new
    return x


def _tilt(u_rows: np.ndarray, delta_rad: np.ndarray) -> np.ndarray:
    """Unit vectors in ENU as rows (3, n) — east, north, up components — turned toward the
    zenith by ``delta_rad`` in their vertical planes; returns rows (3, n). (Rows, not (n, 3):
    each component contiguous, the fast layout for a few hundred stars.)"""
    sin_alt, cos_alt = _sin_cos_alt(u_rows)
    c, s = np.cos(delta_rad), np.sin(delta_rad)
    f = c - s * sin_alt / np.maximum(cos_alt, 1e-300)
    out = np.empty_like(u_rows)
    np.multiply(u_rows[0], f, out=out[0])
    np.multiply(u_rows[1], f, out=out[1])
    out[2] = sin_alt * c + cos_alt * s
    return out


def _sin_cos_alt(u_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The sine and cosine of the altitudes of unit vectors in ENU given as rows (3, ...)."""
    return u_rows[2], np.sqrt(u_rows[0] * u_rows[0] + u_rows[1] * u_rows[1])


def _refract_rows(u_rows: np.ndarray, refraction: Refraction) -> np.ndarray:
    return _tilt(u_rows, refraction.lift_rad(*_sin_cos_alt(u_rows)))


def refract_enu(u_enu: np.ndarray, refraction: Refraction) -> np.ndarray:
    """Geometric (unrefracted) unit vectors in ENU (n, 3) to where they are seen: raised by the
    refraction at their altitude."""
    return _refract_rows(np.asarray(u_enu, dtype=np.float64).T, refraction).T


def unrefract_enu(u_enu: np.ndarray, refraction: Refraction) -> np.ndarray:
    """Observed unit vectors in ENU (n, 3) to their geometric ones: lowered by the refraction at
    their apparent altitude (thesis 003 §5's correction, with Eq. 5.5's sign corrected)."""
    u = np.asarray(u_enu, dtype=np.float64).T
    return _tilt(u, -refraction.drop_rad(*_sin_cos_alt(u))).T


# --- the ground frame -------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class GroundFrame:
    """ERFA's astrometry for one time and site (:func:`ground_frame`), with the rigid rotations
    and the refraction model; the arrays are read-only.

    site, weather, refraction : where, the air, the model.
    jd_utc, dut1_s : the time (UTC Julian date) and UT1 − UTC (s).
    astrom : ERFA's ``ASTROM`` record (refraction-free: skyfix refracts itself).
    sun_eh, sun_em, velocity_c, bm1 : its fields the stars need, as plain arrays (a field of a
        structured record costs ~10 µs to read): the Sun → observer unit vector and distance
        (au), the observer's barycentric velocity (units of c) and sqrt(1 − |v|²).
    eo_rad : the equation of the origins (ERA − GST), radians.
    A_cirs_to_enu, A_icrs_to_enu : rigid rotations (3 × 3) into the local frame (east, north,
        up); ``A_icrs_to_enu = A_cirs_to_enu · BPN``.
    """

    site: Site
    weather: Weather
    refraction: Refraction
    jd_utc: float
    dut1_s: float
    astrom: np.ndarray
    sun_eh: np.ndarray
    sun_em: float
    velocity_c: np.ndarray
    bm1: float
    eo_rad: float
    A_cirs_to_enu: np.ndarray
    A_icrs_to_enu: np.ndarray


@lru_cache(maxsize=32)
def _ground_frame(site: Site, jd_utc: float, weather: Weather, model: str, dut1_s: float,
                  polar_motion_arcsec: tuple[float, float]) -> GroundFrame:
    xp, yp = (math.radians(a / 3600.0) for a in polar_motion_arcsec)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*dubious year.*", category=erfa.ErfaWarning)
        astrom, eo = erfa.apco13(2400000.5, jd_utc - 2400000.5, dut1_s, math.radians(site.lon_deg),
                                 math.radians(site.lat_deg), site.height_m, xp, yp, 0.0, 0.0, 0.0, 0.0)
    a = astrom[()] if astrom.shape == () else astrom  # its "phi" is left unset by eraApco: use sphi, cphi
    A_cirs_to_enu = (elementary_rotation(2, math.pi / 2)
                     @ elementary_rotation(1, math.atan2(float(a["cphi"]), float(a["sphi"])))
                     @ elementary_rotation(0, -float(a["ypl"])) @ elementary_rotation(1, -float(a["xpl"]))
                     @ elementary_rotation(2, float(a["eral"])))
    A_icrs_to_enu = A_cirs_to_enu @ np.asarray(a["bpn"])
    eh, v = np.array(a["eh"]), np.array(a["v"])
    for arr in (astrom, A_cirs_to_enu, A_icrs_to_enu, eh, v):
        arr.setflags(write=False)
    return GroundFrame(site, weather, Refraction.for_weather(weather, model), jd_utc, dut1_s, astrom,
                       eh, float(a["em"]), v, float(a["bm1"]), float(eo), A_cirs_to_enu, A_icrs_to_enu)


def ground_frame(site: Site, jd_utc: float, weather: Weather | None = None, *, model: str = "erfa",
                 dut1_s: float = 0.0, polar_motion_arcsec: tuple[float, float] = (0.0, 0.0)) -> GroundFrame:
    """Set up (and cache, per argument set) ERFA's astrometry for a camera at ``site`` at the UTC
    Julian date ``jd_utc``.

    Parameters
    ----------
    site : Site
    jd_utc : float — UTC as a Julian date (ERFA's quasi-JD on a leap-second day).
    weather : Weather, optional — default :meth:`Weather.standard` for the site's height.
    model : ``"erfa"`` (default), ``"bennett"`` or ``"none"`` (:data:`REFRACTION_MODELS`).
    dut1_s : float — UT1 − UTC, seconds (|·| < 0.9). Left at 0 the Earth's rotation angle is off by
        up to 13″ (15″ per second of UT1 − UTC): give it (IERS Bulletin A, or astropy's
        ``Time.delta_ut1_utc``) for Alt/Az to better than that.
    polar_motion_arcsec : (x_p, y_p), arcseconds (|·| < 1″; default 0).
    """
    if not isinstance(site, Site):
        raise InputError(f"site must be a Site, not {type(site).__name__}")
    jd = float(jd_utc)
    lo, hi = (2451545.0 + (year - 2000.0) * 365.25 for year in EPOCH_RANGE)
    if not lo <= jd <= hi:
        raise InputError(f"UTC Julian date {jd_utc} is not within the years "
                         f"{EPOCH_RANGE[0]:g}–{EPOCH_RANGE[1]:g}")
    if not (math.isfinite(dut1_s) and abs(dut1_s) < 1.0):
        raise InputError(f"UT1 - UTC {dut1_s} s is not within ±1 s")
    pm = tuple(float(p) for p in polar_motion_arcsec)
    if len(pm) != 2 or not all(math.isfinite(p) and abs(p) < 2.0 for p in pm):
        raise InputError(f"polar motion {polar_motion_arcsec} is not two numbers within ±2 arcsec")
    if model not in REFRACTION_MODELS:
        raise InputError(f"refraction model {model!r} is not one of {', '.join(REFRACTION_MODELS)}")
    w = Weather.standard(site.height_m) if weather is None else weather
    return _ground_frame(site, jd, w, model, float(dut1_s), pm)


def _apparent_rows(vectors_icrs: np.ndarray, frame: GroundFrame) -> np.ndarray:
    r = np.asarray(vectors_icrs, dtype=np.float64)
    p = erfa.ab(erfa.ldsun(r, frame.sun_eh, frame.sun_em), frame.velocity_c, frame.sun_em, frame.bm1)
    return frame.A_icrs_to_enu @ p.T


def apparent_enu(vectors_icrs: np.ndarray, frame: GroundFrame) -> np.ndarray:
    """Catalogue (astrometric ICRS) unit vectors (n, 3) to their geometric topocentric directions
    in ENU: deflected by the Sun, aberrated, rotated — everything but refraction."""
    return _apparent_rows(vectors_icrs, frame).T


def observed_enu(vectors_icrs: np.ndarray, frame: GroundFrame) -> np.ndarray:
    """Catalogue unit vectors (n, 3) to where the camera sees them, in ENU (east, north, up)."""
    return _refract_rows(_apparent_rows(vectors_icrs, frame), frame.refraction).T


def observed_directions(vectors_icrs: np.ndarray, frame: GroundFrame) -> np.ndarray:
    """Catalogue unit vectors (n, 3) to where the camera sees them, in ICRS axes — the directions
    to fit the attitude to (the module's docstring: the attitude is then the camera's physical
    orientation, ``A_enu_to_cam = A_icrs_to_cam · frame.A_icrs_to_enuᵀ``)."""
    return (frame.A_icrs_to_enu.T @ _refract_rows(_apparent_rows(vectors_icrs, frame), frame.refraction)).T


class AltAz(NamedTuple):
    """Observed (refracted) altitude and azimuth (from north through east), degrees."""

    alt_deg: np.ndarray | float
    az_deg: np.ndarray | float


def altaz_of(directions: np.ndarray, frame: GroundFrame) -> AltAz:
    """Altitude and azimuth of physical directions in ICRS axes (n, 3) or (3,) — e.g. a camera
    axis, ``A_icrs_to_cam[2]``, of an attitude fitted to :func:`observed_directions`."""
    d = np.asarray(directions, dtype=np.float64)
    u = frame.A_icrs_to_enu @ d.T
    alt = np.degrees(np.arctan2(u[2], np.hypot(u[0], u[1])))
    az = np.degrees(np.arctan2(u[0], u[1])) % 360.0
    return AltAz(alt, az) if d.ndim > 1 else AltAz(float(alt), float(az))


class BoresightPlaces(NamedTuple):
    """Where a camera on the ground points (:func:`boresight_places`), degrees.

    alt_deg, az_deg : observed (refracted) altitude, azimuth from north through east.
    ra_deg, dec_deg : the astrometric ICRS place seen on the boresight (catalogue coordinates).
    ra_jnow_deg, dec_jnow_deg : its apparent place of date (JNow: true equator and equinox,
        aberration and light deflection in, refraction out) — what mounts and push-to finders use.
    """

    alt_deg: float
    az_deg: float
    ra_deg: float
    dec_deg: float
    ra_jnow_deg: float
    dec_jnow_deg: float


def boresight_places(A_icrs_to_cam: np.ndarray, frame: GroundFrame) -> BoresightPlaces:
    """The boresight ``A[2]`` of an attitude fitted to :func:`observed_directions`: its Alt/Az,
    its catalogue place and its place of date (JNow)."""
    b = np.asarray(A_icrs_to_cam, dtype=np.float64)[2]
    alt, az = altaz_of(b, frame)
    u_geom = unrefract_enu((frame.A_icrs_to_enu @ b)[None], frame.refraction)[0]
    ri, di = erfa.c2s(frame.A_cirs_to_enu.T @ u_geom)
    rc, dc = erfa.aticq(ri, di, frame.astrom)
    return BoresightPlaces(float(alt), float(az), math.degrees(erfa.anp(rc)), math.degrees(dc),
                           math.degrees(erfa.anp(ri - frame.eo_rad)), math.degrees(di))
