"""When an image was taken: the observation time from a FITS header, EXIF, or a string.

Every time becomes an :class:`ObservationTime`: a Julian date in TT (the scale the ephemerides
and the catalogue epoch use), the UTC instant as ISO 8601 text, where it came from (``source``:
the FITS keyword, ``"EXIF"``, ``"--time"``, or ``"none"``) and how uncertain it is. Where a
file says nothing usable the time is :data:`NO_TIME` (source ``"none"``): nothing that needs a
time is guessed from it.

- FITS (:func:`time_from_fits_header`): ``DATE-AVG``/``MJD-AVG`` (mid-exposure already), else
  ``DATE-BEG``, ``DATE-OBS`` (with ``TIME-OBS`` when it holds only a date) or ``MJD-OBS``, the
  start, moved to mid-exposure by half of ``EXPTIME`` (or ``EXPOSURE``), in seconds. ``TIMESYS``
  names the scale (UTC when absent, as the FITS standard says; TT, TAI, GPS; TDB is taken as TT,
  within 1.7 ms). A value that does not parse is a one-line warning and the next keyword is
  tried; none left gives :data:`NO_TIME`.
- EXIF (:func:`time_from_exif`, JPEG, TIFF and what else Pillow reads): ``DateTimeOriginal``
  with ``SubSecTimeOriginal`` and ``OffsetTimeOriginal``, moved to mid-exposure by half of
  ``ExposureTime``. Without ``OffsetTimeOriginal`` the camera's time zone is unknown: the local
  time is read as UTC with an uncertainty of 14 hours (:data:`UNKNOWN_ZONE_S`), and a warning
  says so.
- Text (:func:`parse_time`, the ``--time`` option): ISO 8601 (``2026-03-01T22:00:00Z``, an
  offset such as ``+02:00``, no zone = UTC), or a Julian epoch ``J2026.25`` (TT).

Times outside 1900–2100 (the span of ERFA's built-in ephemeris of the Earth, ``epv00``) are an
:class:`~skyfix.errors.InputError`. UTC becomes TT through ERFA's leap-second table
(``erfa.dat``), built into pyerfa: nothing is downloaded and no IERS table is read. After the
table's last entry a future leap second would be missed (a second, which no correction here
notices).
"""

from __future__ import annotations

import functools
import logging
import math
import numbers
import re
import warnings
from collections.abc import Mapping
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import NamedTuple

from skyfix.errors import InputError

# erfa is imported in the functions that call it: importing it takes ~150 ms.
__all__ = ["ObservationTime", "NO_TIME", "parse_time", "time_from_fits_header", "time_from_exif",
           "time_from_image", "julian_year", "jd_utc", "later", "UNKNOWN_ZONE_S", "YEAR_RANGE",
           "FITS_TIME_KEYWORDS"]

log = logging.getLogger(__name__)

YEAR_RANGE = (1900, 2100)
"""First and last calendar year accepted (ERFA ``epv00``'s span)."""

UNKNOWN_ZONE_S = 14 * 3600.0
"""Uncertainty of a local time whose zone is unknown, s: UTC offsets run from −12 h to +14 h."""

J2000_JD = 2451545.0
DAY_S = 86400.0
_GPS_MINUS_TAI_S = -19.0
_SCALES = {"UTC": "UTC", "UT": "UTC", "GMT": "UTC", "TT": "TT", "TDT": "TT", "ET": "TT",
           "TDB": "TT", "TAI": "TAI", "IAT": "TAI", "GPS": "GPS"}
"""FITS ``TIMESYS`` values read, and the scale each is converted as (TDB as TT: within 1.7 ms;
UT, GMT as UTC: within 0.9 s)."""

FITS_TIME_KEYWORDS = ("DATE-AVG", "MJD-AVG", "DATE-BEG", "DATE-OBS", "MJD-OBS")
"""FITS keywords read, in order of preference (the ``*-AVG`` ones are mid-exposure already)."""


class ObservationTime(NamedTuple):
    """An observation time and where it came from.

    Attributes
    ----------
    jd_tt : float — Julian date in TT (NaN when unknown). A float64 Julian date resolves 20 µs.
    source : str — ``"DATE-OBS"`` (or the other FITS keyword read), ``"EXIF"``, ``"--time"``,
        or ``"none"``.
    iso : str — the UTC instant, ISO 8601 to the millisecond (``2026-03-01T22:00:00.000Z``);
        "" when unknown.
    uncertainty_s : float — how far off the time can be, s: 0 for a time with its scale and
        zone, :data:`UNKNOWN_ZONE_S` for a local time of unknown zone, NaN when unknown.
    """

    jd_tt: float
    source: str
    iso: str
    uncertainty_s: float = 0.0

    @property
    def known(self) -> bool:
        """Whether there is a time (source is not ``"none"``)."""
        return math.isfinite(self.jd_tt)


NO_TIME = ObservationTime(math.nan, "none", "", math.nan)
"""No observation time: nothing that needs one may be computed."""


def julian_year(t: ObservationTime) -> float:
    """The Julian epoch (TT) of ``t``, e.g. 2026.16: the catalogue epoch of an observation.

    Raises :class:`~skyfix.errors.InputError` when ``t`` is :data:`NO_TIME`."""
    if not t.known:
        raise InputError("no observation time: the catalogue epoch cannot be taken from it")
    return 2000.0 + (t.jd_tt - J2000_JD) / 365.25


def later(t: ObservationTime, seconds: float) -> ObservationTime:
    """``t`` moved by ``seconds`` (a frame of a sequence timed from the first), same source
    (``jd_tt`` exact; the text by calendar arithmetic, a second off across a leap second).

    >>> later(parse_time("2026-03-01T22:00:00Z"), 90.5).iso
    '2026-03-01T22:01:30.500Z'
    """
    if not t.known:
        return t
    jd_tt = t.jd_tt + float(seconds) / DAY_S
    try:  # the text by calendar arithmetic: 3 µs, where ERFA's round trip takes 100 (a tracker's frames)
        utc = datetime.fromisoformat(t.iso.replace("Z", "+00:00")) + timedelta(seconds=float(seconds))
    except ValueError:  # a leap second's 60th second
        return _from_jd_tt(jd_tt, t.source, t.uncertainty_s)
    return ObservationTime(jd_tt, t.source, utc.isoformat(timespec="milliseconds").replace("+00:00", "Z"),
                           t.uncertainty_s)


def jd_utc(t: ObservationTime) -> float:
    """The UTC (quasi-)Julian date of ``t``, as ERFA's ground astrometry takes it
    (:func:`skyfix.corrections.refraction.ground_frame`). An InputError for :data:`NO_TIME`."""
    import erfa

    if not t.known:
        raise InputError("no observation time: a site's Alt/Az and refraction need one")
    jd1 = math.floor(t.jd_tt - 0.5) + 0.5
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", erfa.ErfaWarning)  # "dubious year": past the table's end
        utc1, utc2 = erfa.taiutc(*erfa.tttai(jd1, t.jd_tt - jd1))
    return float(utc1) + float(utc2)


# --- text -> time ---------------------------------------------------------------------------------
_ISO = re.compile(r"(\d{4})-(\d{1,2})-(\d{1,2})"
                  r"(?:[T ](\d{1,2}):(\d{2})(?::(\d{2}(?:\.\d*)?))?)?"
                  r"\s*(Z|[+-]\d{2}(?::?\d{2})?)?", re.IGNORECASE)
_OLD_FITS_DATE = re.compile(r"(\d{2})/(\d{2})/(\d{2})")
_JULIAN_EPOCH = re.compile(r"J(\d{4}(?:\.\d*)?)", re.IGNORECASE)
_EXIF = re.compile(r"(\d{4}):(\d{2}):(\d{2}) (\d{2}):(\d{2}):(\d{2})")


class _Fields(NamedTuple):
    """A calendar date and time of day as written, with its UTC offset in minutes."""

    year: int
    month: int
    day: int
    hour: int = 0
    minute: int = 0
    second: float = 0.0
    offset_min: float = 0.0


def _offset_minutes(text: str | None) -> float:
    if not text or text.upper() == "Z":
        return 0.0
    sign = -1.0 if text[0] == "-" else 1.0
    digits = text[1:].replace(":", "")
    return sign * (int(digits[:2]) * 60 + (int(digits[2:4]) if len(digits) > 2 else 0))


def _iso_fields(text: str) -> _Fields | None:
    """The fields of an ISO 8601 date-time (or FITS's old ``DD/MM/YY``, 19YY), None if it is not one."""
    s = text.strip()
    m = _ISO.fullmatch(s)
    if m:
        y, mo, d, h, mi, sec, zone = m.groups()
        return _Fields(int(y), int(mo), int(d), int(h or 0), int(mi or 0), float(sec or 0.0),
                       _offset_minutes(zone))
    m = _OLD_FITS_DATE.fullmatch(s)
    if m:
        d, mo, y = m.groups()
        return _Fields(1900 + int(y), int(mo), int(d))
    return None


def _check_year(year: int, text: str) -> None:
    if not YEAR_RANGE[0] <= year <= YEAR_RANGE[1]:
        raise InputError(f"the observation time {text!r} is outside {YEAR_RANGE[0]}–{YEAR_RANGE[1]}, "
                         "the span of the built-in ephemeris")


def _to_tt(f: _Fields, scale: str) -> tuple[float, float] | None:
    """(jd1, jd2) in TT of calendar fields in ``scale`` ("UTC", "TT", "TAI", "GPS"); None when a
    field is out of range (month 13, 24 h, a 61st second on a day without a leap second)."""
    import erfa

    erfa_scale = "UTC" if scale == "UTC" else "TAI"  # TT and GPS are uniform like TAI
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            jd1, jd2 = erfa.dtf2d(erfa_scale, f.year, f.month, f.day, f.hour, f.minute, f.second)
        except (erfa.ErfaError, ValueError):
            return None
        if any("end of day" in str(w.message) for w in caught):
            return None
    return _scale_to_tt(float(jd1), float(jd2) - f.offset_min / 1440.0, scale)


def _scale_to_tt(jd1: float, jd2: float, scale: str) -> tuple[float, float]:
    """A Julian date in two parts in ``scale`` (UTC's a quasi-JD, as ERFA's) as TT."""
    import erfa

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", erfa.ErfaWarning)  # "dubious year": past the table's end
        if scale == "UTC":
            jd1, jd2 = erfa.utctai(jd1, jd2)
        elif scale == "GPS":
            jd2 = jd2 - _GPS_MINUS_TAI_S / DAY_S
        if scale != "TT":
            jd1, jd2 = erfa.taitt(jd1, jd2)
    return float(jd1), float(jd2)


def _iso_utc(jd1: float, jd2: float) -> str:
    """ISO 8601 UTC text (milliseconds, ``Z``) of a TT Julian date in two parts."""
    import erfa

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", erfa.ErfaWarning)  # "dubious year": past the table's end
        tai = erfa.tttai(jd1, jd2)
        utc = erfa.taiutc(*tai)
        y, mo, d, hmsf = erfa.d2dtf("UTC", 3, *utc)
    h, mi, s, ms = (int(v) for v in hmsf)
    return f"{int(y):04d}-{int(mo):02d}-{int(d):02d}T{h:02d}:{mi:02d}:{s:02d}.{ms:03d}Z"


@functools.lru_cache(maxsize=64)
def _day_start_tt(year: int, month: int, day: int, scale: str) -> tuple[float, float] | None:
    """(jd1, jd2) in TT of 0 h of a calendar day in ``scale``, when the day is 86 400 s long in it
    (None: a UTC leap-second day, or no such date): a time of that day is then this plus its
    seconds, as ERFA's ``dtf2d`` and the scale steps would give it (they add constants within
    the day), for a few µs instead of ~100 (an image's header is read in every solve)."""
    try:
        following = datetime(year, month, day) + timedelta(days=1)
    except (ValueError, OverflowError):
        return None
    start = _to_tt(_Fields(year, month, day), scale)
    end = _to_tt(_Fields(following.year, following.month, following.day), scale)
    if start is None or end is None or abs((end[0] - start[0]) + (end[1] - start[1]) - 1.0) * DAY_S > 1e-6:
        return None
    return start


def _fast_time(f: _Fields, scale: str, source: str, shift_s: float,
               uncertainty_s: float) -> ObservationTime | None:
    """:func:`_time` by :func:`_day_start_tt` when the instant and its UTC text stay within one
    ordinary day (None: take ERFA's path)."""
    if not (0 <= f.hour < 24 and 0 <= f.minute < 60 and 0.0 <= f.second < 60.0):
        return None
    seconds = f.hour * 3600 + f.minute * 60 + f.second - f.offset_min * 60.0 + shift_s
    ms = math.floor(seconds * 1000.0 + 0.5)  # to the nearest ms, half up, as ERFA d2dtf
    if scale != "UTC" or not 0 <= ms < 86_400_000:
        return None
    start = _day_start_tt(f.year, f.month, f.day, scale)
    if start is None:
        return None
    jd2 = start[1] + seconds / DAY_S
    s, ms = divmod(ms, 1000)
    iso = (f"{f.year:04d}-{f.month:02d}-{f.day:02d}T{s // 3600:02d}:{s // 60 % 60:02d}:{s % 60:02d}"
           f".{ms:03d}Z")
    return ObservationTime(start[0] + jd2, source, iso, uncertainty_s)


def _time(f: _Fields, scale: str, source: str, shift_s: float = 0.0,
          uncertainty_s: float = 0.0) -> ObservationTime | None:
    """The ObservationTime of calendar fields, ``shift_s`` later (None if a field is out of range)."""
    fast = _fast_time(f, scale, source, shift_s, uncertainty_s)
    if fast is not None:
        return fast
    tt = _to_tt(f, scale)
    if tt is None:
        return None
    jd1, jd2 = tt[0], tt[1] + shift_s / DAY_S
    return ObservationTime(jd1 + jd2, source, _iso_utc(jd1, jd2), uncertainty_s)


def _from_jd_tt(jd_tt: float, source: str, uncertainty_s: float = 0.0) -> ObservationTime:
    jd1 = math.floor(jd_tt - 0.5) + 0.5
    return ObservationTime(jd_tt, source, _iso_utc(jd1, jd_tt - jd1), uncertainty_s)


def parse_time(text: str | datetime | float, source: str = "--time") -> ObservationTime:
    """The time ``text`` names: ISO 8601 (UTC unless it carries ``Z`` or an offset), or a Julian
    epoch ``J2026.25`` (TT); a ``datetime`` (naive = UTC), a Julian year as a number (TT, as
    ``J…``) and an ``astropy.time.Time`` too. skyfix's one reader of times (``--time``,
    ``time=``, a simulation's ``epoch``).

    Raises :class:`~skyfix.errors.InputError` for text that is not a time and for a time outside
    1900–2100.

    >>> parse_time("2026-03-01T22:00:00+02:00").iso
    '2026-03-01T20:00:00.000Z'
    >>> round(julian_year(parse_time("J2026.25")), 6)
    2026.25
    """
    if hasattr(text, "to_datetime") and not isinstance(text, datetime):  # astropy Time
        text = text.to_datetime(timezone=timezone.utc)
    if isinstance(text, numbers.Real) and not isinstance(text, bool):
        if not math.isfinite(float(text)):
            raise InputError(f"{source}: a Julian year must be finite, got {text}")
        text = f"J{float(text):.10f}"
    if isinstance(text, datetime):
        offset = text.utcoffset()
        f = _Fields(text.year, text.month, text.day, text.hour, text.minute,
                    text.second + text.microsecond * 1e-6,
                    0.0 if offset is None else offset.total_seconds() / 60.0)
        _check_year(f.year, text.isoformat())
        got = _time(f, "UTC", source)
        assert got is not None  # a datetime is always a valid date
        return got
    s = str(text).strip()
    m = _JULIAN_EPOCH.fullmatch(s)
    if m:
        jy = float(m.group(1))
        _check_year(math.floor(jy), s)
        return _from_jd_tt(J2000_JD + (jy - 2000.0) * 365.25, source)
    f = _iso_fields(s)
    got = None
    if f is not None:
        _check_year(f.year, s)
        got = _time(f, "UTC", source)
    if got is None:
        raise InputError(f"cannot read the time {s!r}; use ISO 8601 such as 2026-03-01T22:00:00Z, "
                         "or a Julian epoch such as J2026.25")
    return got


# --- FITS -----------------------------------------------------------------------------------------
def _exposure_s(value: object, what: str) -> float:
    """A positive exposure in seconds, else 0 (with a warning when it is there but unusable)."""
    if value is None:
        return 0.0
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        x = math.nan
    if not (math.isfinite(x) and x >= 0.0):
        log.warning("%s %r is not an exposure in seconds: the time is the exposure's start", what, value)
        return 0.0
    return x


def time_from_fits_header(header: Mapping[str, object]) -> ObservationTime:
    """The mid-exposure time a FITS header gives (see the module's notes), or :data:`NO_TIME`.

    ``header`` is any mapping of keyword to value: ``skyfix.io.read_image_with_header(path).header``
    or an ``astropy.io.fits.Header``. A keyword whose value is not a time is a one-line warning;
    a time outside 1900–2100 is an :class:`~skyfix.errors.InputError`.
    """
    timesys = str(header.get("TIMESYS", "UTC") or "UTC").strip().upper()
    scale = _SCALES.get(timesys)
    present = [k for k in FITS_TIME_KEYWORDS if header.get(k) not in (None, "")]
    if not present:
        return NO_TIME
    if scale is None:
        log.warning("FITS TIMESYS %r is not a time scale skyfix reads (%s): no observation time",
                    timesys, ", ".join(sorted(_SCALES)))
        return NO_TIME
    exposure = header.get("EXPTIME", header.get("EXPOSURE"))
    half = 0.5 * _exposure_s(exposure, "FITS EXPTIME" if "EXPTIME" in header else "FITS EXPOSURE")
    for i, key in enumerate(present):
        value = header[key]
        shift = 0.0 if key.endswith("-AVG") else half
        got = _fits_time(key, value, header, scale, shift)
        if got is not None:
            return got
        then = f"trying {present[i + 1]}" if i + 1 < len(present) else "no observation time"
        log.warning("FITS %s %r is not a time (ISO 8601 such as 2026-03-01T22:00:00, or an MJD): %s",
                    key, value, then)
    return NO_TIME


def _fits_time(key: str, value: object, header: Mapping[str, object], scale: str,
               shift_s: float) -> ObservationTime | None:
    """The time of one FITS keyword's value, None if it is not one."""
    import erfa

    if key.startswith("MJD"):
        try:
            mjd = float(value)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            return None
        if not math.isfinite(mjd):
            return None
        year = int(erfa.jd2cal(2400000.5, mjd)[0]) if abs(mjd) < 1e6 else -1
        _check_year(year, f"{key} = {mjd}")
        jd1, jd2 = _scale_to_tt(2400000.5, mjd, scale)
        jd2 += shift_s / DAY_S
        return ObservationTime(jd1 + jd2, key, _iso_utc(jd1, jd2))
    if not isinstance(value, str):
        return None
    text = value.strip()
    if key == "DATE-OBS" and "T" not in text.upper() and ":" not in text:
        clock = header.get("TIME-OBS", header.get("UT"))
        if isinstance(clock, str) and clock.strip():
            text = f"{text}T{clock.strip()}"
    f = _iso_fields(text)
    if f is None:
        return None
    _check_year(f.year, f"{key} = {text}")
    return _time(f, scale, key, shift_s)


def _fits_header_of(path: Path) -> dict[str, object]:
    """The header of a FITS file's first 2-D image HDU merged over its primary header (the
    image HDU's cards win), as ``skyfix.io`` reads it: astropy, headers only."""
    from astropy.io import fits

    with fits.open(path, lazy_load_hdus=True, memmap=True) as hdul:
        primary = dict(hdul[0].header.items())
        if int(primary.get("NAXIS", 0) or 0) >= 2:
            return primary
        for hdu in hdul[1:]:
            if getattr(hdu, "is_image", False) and int(hdu.header.get("NAXIS", 0) or 0) >= 2:
                return {**primary, **dict(hdu.header.items())}
    return primary


# --- EXIF -----------------------------------------------------------------------------------------
_EXIF_IFD = 0x8769
_DATE_TIME_ORIGINAL = 36867
_OFFSET_TIME_ORIGINAL = 36881
_SUBSEC_TIME_ORIGINAL = 37521
_EXPOSURE_TIME = 33434


def time_from_exif(image) -> ObservationTime:
    """The mid-exposure time of a photo's EXIF ``DateTimeOriginal`` (see the module's notes), or
    :data:`NO_TIME`.

    ``image`` is a path or an open ``PIL.Image.Image``. Without ``OffsetTimeOriginal`` the time is
    the camera's local time read as UTC, ``uncertainty_s`` :data:`UNKNOWN_ZONE_S`, with a warning.
    """
    from PIL import Image

    if isinstance(image, Image.Image):
        return _exif_time(image.getexif())
    try:
        with Image.open(image) as im:
            exif = im.getexif()
    except (OSError, ValueError) as exc:
        log.warning("cannot read EXIF from %s (%s): no observation time", image, exc)
        return NO_TIME
    return _exif_time(exif)


def _exif_time(exif) -> ObservationTime:
    ifd = exif.get_ifd(_EXIF_IFD)

    def tag(number: int):
        value = ifd.get(number, exif.get(number))
        return value.strip("\x00 ").strip() if isinstance(value, str) else value

    stamp = tag(_DATE_TIME_ORIGINAL)
    if not stamp:
        return NO_TIME
    m = _EXIF.fullmatch(stamp) if isinstance(stamp, str) else None
    if m is None:
        log.warning("EXIF DateTimeOriginal %r is not a time (YYYY:MM:DD hh:mm:ss): no observation time",
                    stamp)
        return NO_TIME
    subsec = tag(_SUBSEC_TIME_ORIGINAL)
    fraction = float(f"0.{subsec}") if isinstance(subsec, str) and subsec.isdigit() else 0.0
    zone = tag(_OFFSET_TIME_ORIGINAL)
    y, mo, d, h, mi, s = (int(v) for v in m.groups())
    uncertainty = 0.0
    if isinstance(zone, str) and re.fullmatch(r"[+-]\d{2}:\d{2}", zone):
        offset = _offset_minutes(zone)
    else:
        offset = 0.0
        uncertainty = UNKNOWN_ZONE_S
        log.warning("EXIF DateTimeOriginal %s has no OffsetTimeOriginal: the camera's time zone is "
                    "unknown, so the time is read as UTC, uncertain by up to 14 h", stamp)
    _check_year(y, f"EXIF DateTimeOriginal {stamp}")
    exposure = tag(_EXPOSURE_TIME)
    half = 0.0 if exposure is None else 0.5 * _exposure_s(exposure, "EXIF ExposureTime")
    got = _time(_Fields(y, mo, d, h, mi, s + fraction, offset), "UTC", "EXIF", half, uncertainty)
    if got is None:
        log.warning("EXIF DateTimeOriginal %r is not a time: no observation time", stamp)
        return NO_TIME
    return got


# --- any image ------------------------------------------------------------------------------------
def time_from_image(path: str | Path) -> ObservationTime:
    """The observation time an image file carries: its FITS header (a file that starts with
    ``SIMPLE  =``) or its EXIF (anything Pillow opens), else :data:`NO_TIME`."""
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            magic = fh.read(9)
    except OSError as exc:
        log.warning("cannot read %s (%s): no observation time", p, exc.strerror or exc)
        return NO_TIME
    if magic == b"SIMPLE  =":
        try:
            header = _fits_header_of(p)
        except (OSError, ValueError) as exc:
            log.warning("cannot read the FITS header of %s (%s): no observation time", p, exc)
            return NO_TIME
        return time_from_fits_header(header)
    return time_from_exif(p)

