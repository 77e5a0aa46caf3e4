"""The Solution that ``solve`` returns and ``skyfix solve --json`` prints (docs/design.md#the-solution)."""

from __future__ import annotations

import functools
import json
import math
from dataclasses import asdict, dataclass, field
from typing import NamedTuple

import numpy as np

__all__ = ["Match", "MatchTable", "Solution"]


class Match(NamedTuple):
    """One image star matched to a catalogue star (a named tuple: a solve builds hundreds)."""

    x: float
    y: float
    id: int
    ra_deg: float
    dec_deg: float
    mag: float
    residual_arcsec: float


class MatchTable(NamedTuple):
    """A solve's matches as the arrays they are computed in, made into :class:`Match` tuples
    when :attr:`Solution.matches` is first read (a solve whose matches nobody reads, as in a
    tracker's or a benchmark's loop, never builds its hundreds of tuples)."""

    table: np.ndarray  #: (6, M) float: x, y (px), ra_deg, dec_deg, mag, residual_arcsec
    ids: np.ndarray  #: (M,) int: the catalogue numbers

    def matches(self) -> list[Match]:
        x, y, ra, dec, mag, resid = self.table.tolist()
        ids = np.asarray(self.ids).tolist()
        return list(map(_new_match, zip(x, y, ids, ra, dec, mag, resid, strict=True)))


_new_match = functools.partial(tuple.__new__, Match)  # Match(*row) without the per-call signature


class _Matches:
    """:attr:`Solution.matches`: a list of :class:`Match`, stored as given, or a
    :class:`MatchTable` that becomes that list when first read (a dataclass field whose
    default, ``None``, is an empty list)."""

    def __set_name__(self, owner, name: str) -> None:
        self.slot = "_" + name

    def __get__(self, obj, owner=None):
        if obj is None:
            return None  # the field's default
        value = obj.__dict__[self.slot]
        if isinstance(value, MatchTable):
            value = obj.__dict__[self.slot] = value.matches()
        return value

    def __set__(self, obj, value) -> None:
        obj.__dict__[self.slot] = [] if value is None else value


@dataclass
class Solution:
    """Result of solving one image; ``status`` is ``"solved"`` or ``"failed"`` (with ``reason``).

    ``ra_deg``, ``dec_deg`` and ``roll_deg`` are those of the boresight, the camera's +z axis,
    which meets the image at ``boresight_px`` (the principal point: the image centre unless a
    camera file says otherwise or, with no camera file, the stars pin it down elsewhere);
    :meth:`radec_of_pixel` gives any other pixel's."""

    image: str = ""
    status: str = "failed"
    reason: str = ""
    ra_deg: float | None = None
    dec_deg: float | None = None
    roll_deg: float | None = None
    boresight_px: list[float] | None = None
    fov_deg: float | None = None
    quaternion_xyzw: list[float] | None = None
    covariance_arcsec2: list[list[float]] | None = None
    n_detected: int = 0
    n_matched: int = 0
    prob_false: float | None = None
    rmse_arcsec: float | None = None
    method: str = ""
    catalog: str = ""  #: the star catalogue matched (e.g. "Hipparcos 2", "Gaia DR3 + Hipparcos 2 (G, …)")
    catalog_epoch: float | None = None  #: Julian year its positions were moved to (proper motion)
    # The observation (docs/time-and-corrections.md#in-a-solve): always in the JSON.
    time: str | None = None  #: the observation time, ISO 8601 UTC ("2026-03-01T22:00:00.000Z"); None: unknown
    time_source: str = "none"  #: where it came from: "DATE-OBS" (or the FITS keyword), "EXIF", "--time", …
    attitude_frame: str = "apparent"  #: what the attitude's numbers are against: "ICRS" or "apparent"
    corrections: list[str] = field(default_factory=list)  #: applied to the catalogue before the fit
    corrections_not_applied: dict[str, str] = field(default_factory=dict)  #: each one's reason
    warnings: list[str] = field(default_factory=list)  #: e.g. the Sun inside its exclusion angle
    # With a velocity, a site, a time, a mounting; None, and left out of the JSON, otherwise.
    observer_velocity_km_s: list[float] | None = None  #: the camera's geocentric velocity, GCRS axes
    alt_deg: float | None = None  #: the boresight's observed altitude (a site)
    az_deg: float | None = None  #: its azimuth, from north through east (a site)
    ra_jnow_deg: float | None = None  #: its apparent RA of date: true equator and equinox (a site)
    dec_jnow_deg: float | None = None  #: its apparent Dec of date (a site)
    bodies: dict[str, float | None] | None = None  #: Sun, Moon, Earth limb: angles from the boresight
    frames: dict | None = None  #: the attitude of the body (and in the orbit frame): a mounting
    # Tracking (skyfix.track.Tracker) only; None, and left out of the JSON, from solve().
    mode: str | None = None  #: "lost", "acquiring" or "tracking": the tracker state that made it
    frame_time_s: float | None = None  #: the frame's time as given to Tracker.update, seconds
    rate_dps: list[float] | None = None  #: body rate about camera x, y, z, degrees per second
    rate_covariance_dps2: list[list[float]] | None = None  #: its 3 × 3 covariance, (°/s)²
    time_ms: dict[str, float] = field(default_factory=dict)
    matches: list[Match] = _Matches()  # a MatchTable assigned is made into the list when read
    # Not part of the JSON: the full numeric results for the API.
    A_icrs_to_cam: np.ndarray | None = field(default=None, repr=False)
    camera: object | None = field(default=None, repr=False)
    #: The attitude against the catalogue places (``attitude_frame`` "apparent"): what a WCS and a
    #: plot of catalogue stars need. ``A_icrs_to_cam`` itself when no correction moved the stars.
    A_apparent_to_cam: np.ndarray | None = field(default=None, repr=False)

    @property
    def success(self) -> bool:
        """Solved: the word every result type uses (``Identification.success``,
        ``HintResult.success``, …); ``status`` is the same as text, ``solved`` an alias."""
        return self.status == "solved"

    @property
    def solved(self) -> bool:
        return self.status == "solved"

    def attitude_at_pixel(self, x: float, y: float) -> np.ndarray:
        """The attitude (3, 3) of the frame at pixel ``(x, y)``: z along its sky direction, x
        along the growing column there (:func:`skyfix.calibrate.frame_at_pixel`); at
        ``boresight_px`` it is ``A_icrs_to_cam``. The image centre's is what other solvers
        report."""
        from skyfix.calibrate import frame_at_pixel

        return frame_at_pixel(self.A_icrs_to_cam, self.camera, (x, y))

    def radec_of_pixel(self, x: float, y: float) -> tuple[float, float]:
        """RA, Dec (degrees) of the pixel ``(x, y)`` (e.g. the image centre, which is not the
        boresight when the principal point was fitted off it)."""
        from skyfix.geometry import vector_to_radec

        ra, dec = vector_to_radec(self.attitude_at_pixel(x, y)[2])
        return math.degrees(float(ra)), math.degrees(float(dec))

    def to_dict(self) -> dict:
        matches = [m._asdict() for m in self.matches]
        d = asdict(self)
        d.pop("A_icrs_to_cam")
        d.pop("camera")
        d.pop("A_apparent_to_cam")
        d["matches"] = matches
        if not self.reason:
            d.pop("reason")
        for key in _TRACKING_FIELDS + _OBSERVATION_FIELDS:
            if d[key] is None:
                del d[key]
        return _clean(d)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), separators=(", ", ": "))


_TRACKING_FIELDS = ("mode", "frame_time_s", "rate_dps", "rate_covariance_dps2")
_OBSERVATION_FIELDS = ("observer_velocity_km_s", "alt_deg", "az_deg", "ra_jnow_deg", "dec_jnow_deg", "bodies",
                       "frames")


def _clean(obj):
    """JSON-safe: numpy scalars to Python, non-finite floats to None."""
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        f = float(obj)
        return f if math.isfinite(f) else None
    return obj
