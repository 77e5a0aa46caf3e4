"""The Solution that ``solve`` returns and ``skyfix solve --json`` prints (docs/design.md#the-solution)."""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any, NamedTuple

import numpy as np

from skyfix.failures import next_step

__all__ = ["Deferred", "Match", "MatchTable", "Pointing", "Solution"]


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


class Deferred(NamedTuple):
    """A Solution field's value computed when first read, ``function(*args)``: what a solve may
    not need (the apparent attitude beside the true one is read by a WCS or a plot only)."""

    function: Callable[..., Any]
    args: tuple


class _Lazy:
    """A Solution field that may be assigned a :class:`Deferred`, computed and kept when first
    read (a dataclass field whose default is ``None``)."""

    def __set_name__(self, owner, name: str) -> None:
        self.slot = "_" + name

    def __get__(self, obj, owner=None):
        if obj is None:
            return None  # the field's default
        value = obj.__dict__[self.slot]
        if isinstance(value, Deferred):
            value = obj.__dict__[self.slot] = value.function(*value.args)
        return value

    def __set__(self, obj, value) -> None:
        # field(default=_Lazy()) hands the descriptor itself to __init__ as the default
        obj.__dict__[self.slot] = None if isinstance(value, _Lazy) else value


class _OrCovariance(_Lazy):
    """:attr:`Solution.frame_covariance_arcsec2`: as assigned, or ``covariance_arcsec2`` when
    ``None`` (a camera given, a tracked frame)."""

    def __get__(self, obj, owner=None):
        if obj is None:
            return None
        value = obj.__dict__[self.slot]
        return obj.covariance_arcsec2 if value is None else value


class _Matches(_Lazy):
    """:attr:`Solution.matches`: a list of :class:`Match`, stored as given, or a
    :class:`MatchTable` that becomes that list when first read (``None`` assigned: an empty list)."""

    def __get__(self, obj, owner=None):
        if obj is None:
            return None
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
    ``center_ra_deg``, ``center_dec_deg`` and ``center_roll_deg`` (:meth:`center_pointing`) are
    those of the image centre ``center_px`` — what astrometry.net, tetra3 and cedar report;
    :meth:`radec_of_pixel` gives any other pixel's."""

    image: str = ""
    status: str = "failed"
    reason: str = ""
    ra_deg: float | None = None
    dec_deg: float | None = None
    roll_deg: float | None = None
    boresight_px: list[float] | None = None
    mirrored: bool = False  #: solved as a mirror image (skyfix.parity: parity="mirrored" or "either")
    fov_deg: float | None = None
    quaternion_xyzw: list[float] | None = None
    #: the attitude's error covariance (3 × 3, arcsec²) about the camera axes x, y, roll — with a
    #: fitted principal point its uncertainty included (the axes move with it)
    covariance_arcsec2: list[list[float]] | None = None
    #: the image centre's (``center_px``): its direction's error about the x, y axes of its frame and
    #: the roll of image-up there (``center_roll_deg``), arcsec²; ``covariance_arcsec2`` when the
    #: boresight is the centre. May be assigned as a :class:`Deferred` (computed when first read).
    center_covariance_arcsec2: list[list[float]] | None = field(default=_Lazy())
    n_detected: int = 0
    #: the detection threshold that found them, σ of the filtered frame's noise (5; 3.5 when a
    #: sparse frame solved only on a second, fainter look: skyfix.pipeline.look_fainter); None
    #: for centroids given
    detection_sigma: float | None = None
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
    zenith_px: list[float] | None = None  #: the zenith's pixel [x, y] when it is in the frame (a site)
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
    #: A solve with a time may assign it as a :class:`Deferred`: found when first read.
    A_apparent_to_cam: np.ndarray | None = field(default=_Lazy(), repr=False)
    #: The attitude's error covariance (arcsec²) relative to :attr:`camera`: the frame at
    #: ``boresight_px`` as a pixel of that camera, the principal point's own move left out (an
    #: all-sky fisheye's: the axes', as ``covariance_arcsec2``) — what the precision rule judged,
    #: the studies' errors at that pixel (:mod:`skyfix.analysis.truth`) are divided by, and a
    #: tracker that keeps the camera starts its filter from. Read as ``covariance_arcsec2`` when
    #: not assigned (the principal point at the image centre, a camera given, a tracked frame).
    frame_covariance_arcsec2: list[list[float]] | None = field(default=_OrCovariance(), repr=False)

    @property
    def success(self) -> bool:
        """Solved: the word every result type uses (``Identification.success``,
        ``HintResult.success``, …); ``status`` is the same as text, ``solved`` an alias."""
        return self.status == "solved"

    @property
    def solved(self) -> bool:
        return self.status == "solved"

    @property
    def next_step(self) -> str:
        """What to try when it failed (:func:`skyfix.failures.next_step` of ``reason``; ``""``
        when solved or when there is nothing to say)."""
        return "" if self.solved else next_step(self.reason)

    def attitude_at_pixel(self, x: float, y: float, along: str = "column") -> np.ndarray:
        """The attitude (3, 3) of the frame at pixel ``(x, y)``: z along its sky direction, x
        along the growing column there — or, with ``along="row"``, y along the growing row, so
        that its roll is image-up's position angle there, as plate solvers report it for the
        image centre (:func:`skyfix.calibrate.frame_at_pixel`); at ``boresight_px`` it is
        ``A_icrs_to_cam``."""
        from skyfix.calibrate import frame_at_pixel

        if self.mirrored:  # the camera and attitude are the flipped frame's (skyfix.parity)
            x = (self.camera.width - 1) - x
        return frame_at_pixel(self.A_icrs_to_cam, self.camera, (x, y), along)

    def radec_of_pixel(self, x: float, y: float) -> tuple[float, float]:
        """RA, Dec (degrees) of the pixel ``(x, y)`` (e.g. the image centre, which is not the
        boresight when the principal point was fitted off it), against the catalogue places: where
        the WCS of ``--wcs`` puts it, so that a matched star's pixel gives its catalogue RA/Dec
        (:meth:`radec_of_pixels`)."""
        ra, dec = self.radec_of_pixels(np.array([[x, y]], dtype=np.float64))[0]
        return float(ra), float(dec)

    def radec_of_pixels(self, xy: np.ndarray) -> np.ndarray:
        """RA, Dec (degrees, (N, 2)) of the pixels ``xy`` (N, 2) against the catalogue places —
        through ``A_apparent_to_cam``, as the WCS and the plot's grid (docs/time-and-corrections.md,
        "Which attitude"). With an observation time the reported attitude (``ra_deg``, ``dec_deg``,
        ``roll_deg``, the ``center_*``, ``attitude_frame`` "ICRS") is the true one, the camera's
        physical axes: ``radec_of_pixel(*boresight_px)`` then differs from ``(ra_deg, dec_deg)``
        by the aberration (up to ~25″) and, at a site, the refraction. Without a time the two
        attitudes are one."""
        from skyfix.geometry import vector_to_radec

        A = self.A_apparent_to_cam if self.A_apparent_to_cam is not None else self.A_icrs_to_cam
        xy = np.array(xy, dtype=np.float64).reshape(-1, 2)
        if self.mirrored:  # the camera and attitude are the flipped frame's (skyfix.parity)
            xy[:, 0] = (self.camera.width - 1) - xy[:, 0]
        ra, dec = vector_to_radec(self.camera.pixel_to_ray(xy) @ np.asarray(A, dtype=np.float64))
        return np.degrees(np.column_stack([ra, dec]))

    def flip_match_columns(self, width: int) -> None:
        """The matches' x flipped left-right, ``x' = (W − 1) − x``, in place (for
        :func:`skyfix.parity.unmirror_solution`)."""
        value = self.__dict__.get("_matches")
        if isinstance(value, MatchTable):
            table = value.table.copy()
            table[0] = (width - 1) - table[0]
            self.matches = MatchTable(table, value.ids)
        elif value:
            self.matches = [m._replace(x=(width - 1) - m.x) for m in value]

    @property
    def frame_camera(self):
        """The fitted (or given) camera of the frame as stored — what ``--camera FILE.toml`` and
        :meth:`Camera.load <skyfix.camera.Camera.load>` read, so the next frame of that camera can
        use it; for a mirror image, :attr:`camera` (the flipped frame's) mirrored back. None unless
        solved."""
        if not self.solved or self.camera is None:
            return None
        if self.mirrored:
            from skyfix.parity import mirror_camera

            return mirror_camera(self.camera)
        return self.camera

    @property
    def center_px(self) -> list[float] | None:
        """The image centre's pixel, ``[(W − 1)/2, (H − 1)/2]`` (None unless solved)."""
        if self.camera is None:
            return None
        return [(self.camera.width - 1) / 2.0, (self.camera.height - 1) / 2.0]

    @property
    def boresight_off_centre(self) -> bool:
        """The principal point ``boresight_px`` half a pixel or more from the image centre: where
        the summary line and the plot name the boresight beside the centre's numbers."""
        centre = self.center_px
        if centre is None or self.boresight_px is None:
            return False
        return math.hypot(self.boresight_px[0] - centre[0], self.boresight_px[1] - centre[1]) >= 0.5

    def center_pointing(self) -> Pointing:
        """RA, Dec and roll (degrees) of the image centre (:attr:`center_px`): its sky direction
        and the position angle of image-up there (:meth:`attitude_at_pixel` with
        ``along="row"``), as a plate solver reports them. The boresight's own numbers when the
        principal point is the centre; NaN unless solved."""
        centre = self.center_px
        if centre is None or self.A_icrs_to_cam is None or self.ra_deg is None:
            return Pointing(math.nan, math.nan, math.nan)
        if self.boresight_px is not None and list(map(float, self.boresight_px)) == centre:
            return Pointing(float(self.ra_deg), float(self.dec_deg), float(self.roll_deg))
        from skyfix.geometry import radec_roll_from_attitude

        ra, dec, roll = radec_roll_from_attitude(self.attitude_at_pixel(*centre, along="row"))
        return Pointing(math.degrees(ra), math.degrees(dec), math.degrees(roll))

    @property
    def center_sigma_arcsec(self) -> list[float] | None:
        """σ (arcsec) of the image centre's direction about its frame's x and y axes and of the roll
        there: the square roots of :attr:`center_covariance_arcsec2`'s diagonal (what the summary
        line of ``skyfix solve`` prints beside the centre's RA/Dec); None unless known."""
        c = self.center_covariance_arcsec2
        if c is None:
            return None
        return [math.sqrt(max(float(c[k][k]), 0.0)) if c[k][k] is not None else math.nan for k in range(3)]

    @property
    def center_ra_deg(self) -> float | None:
        """RA (degrees) of the image centre (:meth:`center_pointing`)."""
        return _finite_or_none(self.center_pointing().ra_deg)

    @property
    def center_dec_deg(self) -> float | None:
        """Dec (degrees) of the image centre (:meth:`center_pointing`)."""
        return _finite_or_none(self.center_pointing().dec_deg)

    @property
    def center_roll_deg(self) -> float | None:
        """Roll (degrees) of the image centre's frame (:meth:`center_pointing`)."""
        return _finite_or_none(self.center_pointing().roll_deg)

    def to_dict(self) -> dict:
        matches = [m._asdict() for m in self.matches]
        d = asdict(self)
        d.pop("A_icrs_to_cam")
        d.pop("camera")
        # The image centre's numbers beside the boresight's (computed once, here).
        centre = self.center_pointing()
        out = {}
        for key, value in d.items():
            if key == "center_covariance_arcsec2":
                continue  # beside the centre's numbers, below
            out[key] = value
            if key == "reason":
                out["next_step"] = self.next_step
            if key == "boresight_px":
                out["center_ra_deg"] = _finite_or_none(centre.ra_deg)
                out["center_dec_deg"] = _finite_or_none(centre.dec_deg)
                out["center_roll_deg"] = _finite_or_none(centre.roll_deg)
                out["center_px"] = self.center_px
                out["center_covariance_arcsec2"] = d["center_covariance_arcsec2"]
        d = out
        d.pop("A_apparent_to_cam")
        d.pop("frame_covariance_arcsec2")
        camera = self.frame_camera
        d["camera"] = camera.to_dict() if hasattr(camera, "to_dict") else None
        d["matches"] = matches
        for key in _TRACKING_FIELDS + _OBSERVATION_FIELDS:
            if d[key] is None:
                del d[key]
        return _clean(d)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), separators=(", ", ": "))


class Pointing(NamedTuple):
    """Where a pixel of a solved image points: RA, Dec and roll, degrees."""

    ra_deg: float
    dec_deg: float
    roll_deg: float


def _finite_or_none(x: float) -> float | None:
    return x if math.isfinite(x) else None


_TRACKING_FIELDS = ("mode", "frame_time_s", "rate_dps", "rate_covariance_dps2")
_OBSERVATION_FIELDS = ("observer_velocity_km_s", "alt_deg", "az_deg", "ra_jnow_deg", "dec_jnow_deg",
                       "zenith_px", "bodies", "frames")


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
