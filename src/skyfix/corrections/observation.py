"""One image's circumstances — when, from where, moving how fast, through what air — and what
they change in a solve: which corrections apply, the directions the camera sees catalogue stars
in, and what the Solution reports beside the attitude (docs/time-and-corrections.md#in-a-solve).

:func:`observe` checks the options and makes an :class:`Observation` once per image (a tracker:
once per few seconds of its frames):

- the **catalogue epoch** (proper motion): ``epoch`` when given, else the observation time's
  Julian year, else none (the pattern database's own epoch);
- in space (no site), the **aberration frame** (:func:`skyfix.corrections.apparent_frame`: the
  Earth's barycentric velocity at the time plus the observer's own);
- on the ground (a site), **ERFA's astrometry** for the time and site
  (:func:`skyfix.corrections.refraction.ground_frame`), which holds the site's velocity as well:
  the aberration is applied there, once, never on top of the space path's.

:meth:`Observation.seen` then turns catalogue vectors (at the epoch) into the directions the
camera sees: parallax, the Sun's light deflection and aberration
(:func:`~skyfix.corrections.apparent_directions`), and on the ground the Earth's rotation into
the local frame and refraction per star (:func:`~skyfix.corrections.refraction.observed_directions`).
The attitude fitted to those is the camera's physical orientation against the ICRS axes (the
Solution's ``attitude_frame`` ``"ICRS"``); :func:`apparent_attitude` turns it into the
``"apparent"`` one, the rotation that best maps the stars' catalogue places onto the image (what
a plate solver reports, and every skyfix solve before issue 24). With no time nothing that needs
one is applied, and :attr:`Observation.not_applied` says so and why.

Identification's own pattern search and its verification stay on the catalogue's places: the
hash's and the verification's tolerances cover the 20.5″ + 5″ of aberration (a pixel of an 8°
frame) and refraction's 0.2 % squeeze of vertical separations at 20° altitude. The corrections
enter where stars are compared with the catalogue after identification: the final fit, its
re-matching and re-verification (:func:`skyfix.final_fit.final_fit`'s ``seen``), and the
tracker's windows and fit.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
from dataclasses import dataclass
from datetime import datetime
from typing import TYPE_CHECKING

import numpy as np

from skyfix.catalog import hipparcos_parallax
from skyfix.corrections.bodies import (
    EXCLUSION_DEG,
    BodyDirections,
    Exclusion,
    angles_from_directions,
    body_directions,
    exclusion_for,
    exclusion_warnings,
)
from skyfix.corrections.observer import GEOCENTRE, Observer, observer_from_state, parse_velocity
from skyfix.errors import InputError
from skyfix.obstime import (
    NO_TIME,
    ObservationTime,
    jd_utc,
    julian_year,
    parse_time,
    time_from_exif,
    time_from_fits_header,
)

if TYPE_CHECKING:
    from skyfix.corrections.apparent import ApparentFrame
    from skyfix.corrections.refraction import GroundFrame, Site, Weather
    from skyfix.frames import Mounting

# A site's refraction (ERFA's astrometry) and the body frames are imported when a site or a mounting
# is given, the apparent places when a time is: a plain solve's process does without them (erfa,
# skyfix.frames: ~30 ms at start).

__all__ = ["ALL_SKY_FOV_DEG", "CORRECTIONS", "NO_TIME_REASON", "Observation", "apparent_attitude", "observe",
           "observer_of", "time_of_image"]

#: A camera this wide or wider (an all-sky lens) has no baffle and sees the Moon whenever it is up:
#: its Solution gives the bright bodies' angles (``bodies``) but no exclusion-angle warnings.
ALL_SKY_FOV_DEG = 120.0

#: The corrections a solve can apply to the catalogue, by the names the Solution lists them by.
CORRECTIONS = ("proper_motion", "parallax", "light_deflection", "aberration", "refraction")

NO_TIME_REASON = "no observation time (give --time, or an image with DATE-OBS or EXIF)"


@dataclass(frozen=True, eq=False)
class Observation:
    """What is known about how one image was taken, and the frames made from it (:func:`observe`).

    Attributes
    ----------
    time : ObservationTime — :data:`skyfix.obstime.NO_TIME` when unknown.
    observer : Observer or None — the camera's geocentric velocity (and position), GCRS axes.
    site, weather : Site, Weather or None — a camera on the ground.
    refraction : str — the refraction model (:data:`~skyfix.corrections.refraction.REFRACTION_MODELS`).
    apparent : bool — report the apparent attitude instead of the true ICRS one.
    epoch : float or None — the catalogue epoch (Julian year) of the solve: ``epoch_given``, else
        the time's; None: the pattern database's own.
    epoch_given : float or None — the epoch asked for (``epoch=``, ``--epoch``).
    mounting : Mounting or None — the camera → body rotation, for the body frame's attitude.
    exclusion : Exclusion — the bright bodies' exclusion angles, degrees.
    dut1_s : float — UT1 − UTC for a site's Earth rotation, seconds (0 unless given).
    applied : tuple of str — the corrections applied (:data:`CORRECTIONS`' names, in order).
    not_applied : dict — each correction not applied: why.
    space : ApparentFrame or None — the aberration frame (a time, no site).
    ground : GroundFrame or None — ERFA's astrometry for the time and site.
    """

    time: ObservationTime = NO_TIME
    observer: Observer | None = None
    site: Site | None = None
    weather: Weather | None = None
    refraction: str = "erfa"
    apparent: bool = False
    epoch: float | None = None
    epoch_given: float | None = None
    mounting: Mounting | None = None
    exclusion: Exclusion = EXCLUSION_DEG
    dut1_s: float = 0.0
    applied: tuple[str, ...] = ()
    not_applied: dict = dataclasses.field(default_factory=dict)
    space: ApparentFrame | None = dataclasses.field(default=None, repr=False)
    ground: GroundFrame | None = dataclasses.field(default=None, repr=False)

    @property
    def moves_stars(self) -> bool:
        """Whether :meth:`seen` changes catalogue directions (a time is known)."""
        return self.space is not None or self.ground is not None

    @property
    def attitude_frame(self) -> str:
        """``"ICRS"``: the attitude is the camera's physical one (the stars were aberrated before
        the fit); ``"apparent"``: against the catalogue places (asked for, or no time)."""
        return "ICRS" if self.moves_stars and not self.apparent else "apparent"

    def at(self, time: ObservationTime, observer: Observer | None = None) -> Observation:
        """The same camera, site and options at another time (a tracker's frame), and with
        another ``observer`` when given."""
        return observe(time, observer=self.observer if observer is None else observer, site=self.site,
                       weather=self.weather, refraction=self.refraction, apparent=self.apparent,
                       epoch=self.epoch_given, mounting=self.mounting, exclusion=self.exclusion,
                       dut1_s=self.dut1_s)

    def seen(self, vectors: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Catalogue unit vectors (K, 3) at the epoch, of the stars numbered ``ids`` (K,) (their
        Hipparcos parallaxes are looked up), as the camera sees them — ICRS axes, the module's
        steps. ``vectors`` themselves when nothing moves them."""
        if not self.moves_stars:
            return vectors
        p = np.asarray(vectors, dtype=np.float64)
        parallax = hipparcos_parallax(ids)
        if self.ground is None:
            from skyfix.corrections.apparent import apparent_directions

            return apparent_directions(p, self.space, parallax if parallax.any() else None)
        if parallax.any():  # seen from the site's barycentric place (ERFA's astrometry holds it)
            p = p - parallax[:, None] * _barycentric_au(self.ground)
            p = p / np.linalg.norm(p, axis=1, keepdims=True)
        from skyfix.corrections.refraction import observed_directions

        return observed_directions(p, self.ground)

    @functools.cached_property
    def body_directions(self) -> BodyDirections | None:
        """The Sun, the Moon and the Earth from the observer at the time (None: no time); found
        once per Observation."""
        if not self.time.known:
            return None
        return body_directions(self.time, self.observer if self.observer is not None else GEOCENTRE)

    def report(self, sol, A_icrs_to_cam: np.ndarray | None, A_reported: np.ndarray | None = None,
               time: ObservationTime | None = None, camera=None) -> None:
        """Fill the Solution's observation fields (docs/time-and-corrections.md#in-a-solve): the
        time (``time``, default the Observation's: a tracker's frame passes its own), the
        corrections, the attitude's frame, the observer's velocity; with an attitude
        (``A_icrs_to_cam``, the physical one fitted) also a site's Alt/Az and place of date, the
        bright bodies' angles with a warning inside their exclusion angles (not for an all-sky
        camera's, :data:`ALL_SKY_FOV_DEG`), and with a mounting
        the body frame's attitude (of ``A_reported``, the attitude in the Solution's frame), and
        with a site and the ``camera`` the zenith's pixel when it lies in the frame."""
        t = self.time if time is None else time
        sol.time = t.iso or None
        sol.time_source = t.source
        sol.corrections = list(self.applied)
        sol.corrections_not_applied = dict(self.not_applied)
        sol.attitude_frame = self.attitude_frame
        if self.observer is not None:
            sol.observer_velocity_km_s = np.asarray(self.observer.velocity_km_s, dtype=np.float64).tolist()
        if A_icrs_to_cam is None:
            return
        A = np.asarray(A_icrs_to_cam, dtype=np.float64)
        if self.ground is not None:
            from skyfix.corrections.refraction import boresight_places

            places = boresight_places(A, self.ground)
            sol.alt_deg, sol.az_deg = places.alt_deg, places.az_deg
            sol.ra_jnow_deg, sol.dec_jnow_deg = places.ra_jnow_deg, places.dec_jnow_deg
            if camera is not None:  # the zenith: the local frame's up, in ICRS axes
                uv, front = camera.ray_to_pixel((A @ self.ground.A_icrs_to_enu[2])[None])
                if front[0] and camera.in_frame(uv)[0]:
                    sol.zenith_px = [float(uv[0, 0]), float(uv[0, 1])]
        bodies = self.body_directions
        if bodies is not None:
            angles = angles_from_directions(A[2], bodies)
            sol.bodies = {"sun_deg": angles.sun_deg, "moon_deg": angles.moon_deg,
                          "earth_limb_deg": angles.earth_limb_deg}
            if camera is None or camera.fov_deg < ALL_SKY_FOV_DEG:
                sol.warnings = sol.warnings + exclusion_warnings(angles, self.exclusion)
        if self.mounting is not None:
            sol.frames = self._frames(A if A_reported is None else A_reported)

    def _frames(self, A: np.ndarray) -> dict:
        """The attitude of the camera and the body (and the body in the orbit frame when the
        observer's position is known), in the Solution's frame."""
        from skyfix.frames import attitude_frames, orbit_frame

        orbit = None
        if self.observer is not None and self.observer.position_km is not None:
            orbit = orbit_frame(self.observer.position_km, self.observer.velocity_km_s)
        out = attitude_frames(A, mounting=self.mounting, A_icrs_to_orbit=orbit).to_json()
        if self.attitude_frame != "ICRS":  # attitude_frames names the reference "icrs"
            out["reference_frame"] = self.attitude_frame
            for part in out.values():
                if isinstance(part, dict) and part.get("from") == "icrs":
                    part["from"] = self.attitude_frame
        return out


def _barycentric_au(ground: GroundFrame) -> np.ndarray:
    return np.asarray(ground.astrom["eb"], dtype=np.float64).reshape(3)


def time_of_image(image, header: dict | None = None, image_format: str = "") -> ObservationTime:
    """The time an image carries: a FITS ``header`` (as :func:`skyfix.io.read_image_with_header`
    read it), else the EXIF of a JPEG or TIFF file; :data:`NO_TIME` for an array, a PNG, or a
    file that says nothing (a malformed value: one warning line, never an exception but for a
    time outside 1900–2100)."""
    if image_format == "fits" and header is not None:
        return time_from_fits_header(header)
    if isinstance(image, (str, os.PathLike)) and image_format in ("jpeg", "tiff", "image"):
        return time_from_exif(image)
    return NO_TIME


def _time(time) -> ObservationTime | None:
    """``time=`` as an ObservationTime (None: not given)."""
    if time is None or isinstance(time, ObservationTime):
        return time
    if isinstance(time, (str, datetime)):
        return parse_time(time, source="time=")
    raise InputError(f"time must be an ISO 8601 text, a datetime or an ObservationTime, "
                     f"not {type(time).__name__}")


def observer_of(observer) -> Observer | None:
    """``observer=`` as an :class:`~skyfix.corrections.Observer`: one already, ``"vx,vy,vz"``
    (``--velocity-kms``, km/s) or three numbers (None: not given)."""
    if observer is None or isinstance(observer, Observer):
        return observer
    if isinstance(observer, str):
        return parse_velocity(observer)
    return observer_from_state(None, observer, "observer=")


def observe(time=None, *, observer=None, site=None, weather=None, refraction: str = "erfa",
            apparent: bool = False, epoch: float | None = None, mounting=None, exclusion=None,
            dut1_s: float = 0.0) -> Observation:
    """Check one image's circumstances and make its :class:`Observation` (the module's text).

    Parameters
    ----------
    time : ObservationTime, str or datetime, optional
        The observation time (ISO 8601 text: :func:`skyfix.obstime.parse_time`); None: unknown.
    observer : Observer, str or (3,) numbers, optional
        The camera's velocity relative to the Earth's centre, km/s, GCRS axes (``"vx,vy,vz"``,
        ``--velocity-kms``), or an :class:`~skyfix.corrections.Observer` with a position.
    site, weather : Site / Weather or their text, optional
        ``"LAT,LON[,HEIGHT_M]"`` and ``"T_C,P_HPA[,RH]"``: a camera on the ground.
    refraction : str
        The refraction model at a site: ``"erfa"`` (default), ``"bennett"``, ``"none"``.
    apparent : bool
        Report the apparent attitude (against the catalogue places) instead of the true one.
    epoch : float, optional
        Catalogue epoch, Julian year (default: the time's).
    mounting : Mounting or str, optional
        Camera → body rotation (``"x,y,z,w"`` or Euler 1-2-3 degrees ``"φ,θ,ψ"``).
    exclusion : Exclusion or str, optional
        Exclusion angles, or a camera preset's name whose ``[exclusion]`` to use (default 28.1°).
    dut1_s : float
        UT1 − UTC, seconds, for a site's Alt/Az (default 0: 13″ at most off in azimuth).

    Raises
    ------
    skyfix.errors.InputError
        A time outside 1900–2100 or not a time, a speed of c or more, a latitude beyond ±90°,
        weather without a site, a velocity with a site, a malformed mounting, an unknown
        refraction model or preset.
    """
    from skyfix.validate import check_epoch

    t = _time(time)
    t = NO_TIME if t is None else t
    obs = observer_of(observer)
    if site is not None or weather is not None or refraction != "erfa":
        from skyfix.corrections.refraction import REFRACTION_MODELS, check_site_weather

        site, weather = check_site_weather(site, weather, names=("site", "weather"))
        if refraction not in REFRACTION_MODELS:
            raise InputError(f"refraction model {refraction!r} is not one of {', '.join(REFRACTION_MODELS)}")
    if site is not None and obs is not None:
        raise InputError("an observer velocity and a site: a camera on the ground moves with the Earth "
                         "(its site's velocity is computed); give one or the other")
    if mounting is not None:
        from skyfix.frames import Mounting

        if isinstance(mounting, str):
            mounting = Mounting.parse(mounting)
        elif not isinstance(mounting, Mounting):
            raise InputError(f"mounting must be a Mounting or its text, not {type(mounting).__name__}")
    if exclusion is None or isinstance(exclusion, str):
        exclusion = exclusion_for(exclusion)
    elif not isinstance(exclusion, Exclusion):
        raise InputError(f"exclusion must be an Exclusion or a preset's name, not {type(exclusion).__name__}")
    given = epoch = check_epoch(epoch)
    if not (isinstance(dut1_s, (int, float)) and math.isfinite(dut1_s) and abs(dut1_s) < 1.0):
        raise InputError(f"UT1 - UTC {dut1_s!r} s is not within ±1 s")
    applied: list[str] = []
    missing: dict[str, str] = {}
    if epoch is None and t.known:
        epoch = julian_year(t)
    if epoch is not None:
        applied.append("proper_motion")
    else:
        missing["proper_motion"] = NO_TIME_REASON + ": the catalogue at the pattern database's epoch"
    space = ground = None
    if t.known:
        applied += ["parallax", "light_deflection", "aberration"]
        if site is None:
            from skyfix.corrections.apparent import apparent_frame

            space = apparent_frame(t, obs if obs is not None else GEOCENTRE)  # speed ≥ c: InputError
        else:
            from skyfix.corrections.refraction import ground_frame

            ground = ground_frame(site, jd_utc(t), weather, model=refraction, dut1_s=float(dut1_s))
            if refraction == "none":
                missing["refraction"] = "refraction model 'none'"
            else:
                applied.append("refraction")
    else:
        for name in ("parallax", "light_deflection", "aberration"):
            missing[name] = NO_TIME_REASON
        if site is not None:
            missing["refraction"] = NO_TIME_REASON
    return Observation(t, obs, site, weather, refraction, bool(apparent), epoch, given, mounting, exclusion,
                       float(dut1_s), tuple(applied), missing, space, ground)


def apparent_attitude(A_icrs_to_cam: np.ndarray, catalog_vectors: np.ndarray,
                      seen_vectors: np.ndarray) -> np.ndarray:
    """The apparent attitude of a physical one: ``A · R``, with ``R`` the rotation that best
    takes the matched stars' catalogue places (K, 3) to the directions they were seen in (K, 3)
    (Wahba's problem, :func:`skyfix.attitude.solve_attitude`): it maps the catalogue places onto
    the image as the fitted attitude maps the seen directions — what a fit to the catalogue
    places themselves gives, less the field's small differential part."""
    from skyfix.attitude import solve_attitude

    R = solve_attitude(np.ascontiguousarray(seen_vectors, dtype=np.float64),
                       np.ascontiguousarray(catalog_vectors, dtype=np.float64), method="svd")
    return np.asarray(A_icrs_to_cam, dtype=np.float64) @ R
