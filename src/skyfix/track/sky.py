"""The catalogue as a tracked camera sees it, kept current frame by frame
(docs/time-and-corrections.md#tracking).

With an observation time (the :class:`~skyfix.track.Tracker`'s ``time=``, the time of
``t_s = 0``, or the first frame's own FITS ``DATE-OBS`` or EXIF) the tracker applies what
:func:`skyfix.solve` does: the catalogue stars it projects into windows and fits are moved to
where the camera sees them — aberration by the Earth's and the observer's velocity, on the ground
the site's refraction per star (:meth:`skyfix.corrections.observation.Observation.seen`) — so the
attitude it tracks is the camera's physical one. :class:`TrackedSky` keeps that current:

- each frame's time is ``t_s = 0``'s plus ``t_s`` (:func:`skyfix.obstime.later`, 4 µs);
- the observation the stars are corrected for is made again for the frame's time every
  :data:`SPACE_REFRESH_S` seconds in space (aberration by a given velocity changes by 4 µas a
  second), every :data:`GROUND_REFRESH_S` on the ground (refraction follows a star's altitude:
  0.04″ a second at 20°, 0.15″ at 10°), and whenever the tracker is given an observer whose
  velocity differs by more than :data:`MOVED_KM_S` (0.01″ of aberration);
- only the local catalogue (the stars near the boresight the windows choose from,
  :func:`skyfix.track.windows.local_catalog`) is corrected, when it is made and at each refresh,
  and its rows copied into a corrected star index that the windows' fit reads (the kernels take
  the array they always did);
- the Sun's and Moon's directions are found once per refresh, their angles per frame.

A tracked frame's Solution then reports the residuals against the stars as seen, the matches'
catalogue places, the attitude in the frame asked for (``apparent``: ``A · R``, R the rotation
from the local catalogue's places to their seen directions), and the observation's fields.
"""

from __future__ import annotations

import math

import numpy as np

from skyfix._kernels.rotation import pointing
from skyfix.corrections.observation import Observation, apparent_attitude, observer_of, time_of_image
from skyfix.identify.catalogue.database import readonly_view
from skyfix.obstime import later

__all__ = ["GROUND_REFRESH_S", "MOVED_KM_S", "SPACE_REFRESH_S", "TrackedSky"]

SPACE_REFRESH_S = 60.0
GROUND_REFRESH_S = 2.0
MOVED_KM_S = 0.0145


class TrackedSky:
    """The tracker's observation and its corrected catalogue (the module's text).

    Parameters
    ----------
    observation : Observation
        At ``t_s = 0`` (:func:`skyfix.corrections.observation.observe`).
    time_from_frames : bool
        No time was given: take it from the first frame's file when it has one.
    """

    def __init__(self, observation: Observation, time_from_frames: bool) -> None:
        self.observation = observation
        self.time_from_frames = time_from_frames
        self.frame_time = observation.time
        self._frame_obs: Observation | None = None
        self._frame_obs_t = math.nan
        self.new_catalogue()

    def new_catalogue(self) -> None:
        """Forget the corrected stars (a new star index, or a new epoch)."""
        self._seen = self._seen_ro = None
        self._seen_for = self._seen_local = None
        self._places: np.ndarray | None = None
        self._to_apparent: np.ndarray | None = None

    @property
    def current(self) -> Observation:
        """The observation the catalogue is corrected for (the base one until a frame's)."""
        return self.observation if self._frame_obs is None else self._frame_obs

    def first_frame(self, got, path, t: float) -> bool:
        """Take ``t_s = 0``'s time from the first frame's file (``got``: its
        :class:`~skyfix.io.ImageFile`) when no time was given; whether the catalogue's epoch
        should move to it (no epoch was given)."""
        own = time_of_image(path, got.header, got.format)
        if not own.known:
            return False
        self.observation = self.observation.at(later(own, -t))
        self._frame_obs = None
        return self.observation.epoch_given is None

    def observe(self, t: float, observer=None) -> None:
        """The frame's time, and the observation made again when :data:`SPACE_REFRESH_S` (in
        space) or :data:`GROUND_REFRESH_S` (a site) old, or when ``observer``'s velocity moved
        (it is kept for the frames after)."""
        base = self.observation
        if observer is not None:
            given = observer_of(observer)
            old = base.observer
            if old is None or float(np.linalg.norm(given.velocity_km_s - old.velocity_km_s)) > MOVED_KM_S:
                base = self.observation = base.at(base.time, observer=given)
                self._frame_obs = None
        if not base.time.known:
            self.frame_time = base.time
            return
        self.frame_time = later(base.time, t)
        refresh = GROUND_REFRESH_S if base.site is not None else SPACE_REFRESH_S
        if self._frame_obs is None or not abs(t - self._frame_obs_t) < refresh:
            self._frame_obs = base.at(self.frame_time)
            self._frame_obs_t = t

    def vectors(self, local, stars, star_ids: np.ndarray) -> np.ndarray:
        """The star index's vectors for the windows' kernels: the local catalogue ``local``
        corrected first (its vectors moved in place) and the corrected index, or ``stars.vectors``
        when nothing moves the stars."""
        obs = self._frame_obs
        if obs is None or not obs.moves_stars:
            return stars.vectors
        if self._seen_for is not obs or self._seen_local is not local:
            if self._seen is None:
                self._seen = np.array(stars.vectors, dtype=np.float64)
                self._seen_ro = readonly_view(self._seen)
            if self._seen_local is not local:
                self._places = local.vectors.copy()
            seen = obs.seen(self._places, star_ids[local.index])
            local.vectors[:] = seen
            self._seen[local.index] = seen
            self._to_apparent = None
            if obs.apparent and len(seen) >= 2:
                self._to_apparent = apparent_attitude(np.eye(3), self._places, seen)
            self._seen_for, self._seen_local = obs, local
        return self._seen_ro

    @property
    def corrected(self) -> bool:
        """Whether the last frame's stars were corrected for the current observation."""
        obs = self._frame_obs
        return obs is not None and obs.moves_stars and self._seen_for is obs

    def solve_options(self) -> dict:
        """The observation's keywords for a lost-in-space :func:`skyfix.solve` of this frame."""
        obs = self.observation
        if obs.time.known:
            return dict(time=self.frame_time, observer=obs.observer, site=obs.site, weather=obs.weather,
                        refraction=obs.refraction, apparent=obs.apparent, mounting=obs.mounting,
                        exclusion=obs.exclusion)
        return dict(observer=obs.observer, mounting=obs.mounting, apparent=obs.apparent)

    def numbers(self, A: np.ndarray, head: np.ndarray) -> np.ndarray:
        """The attitude a tracked frame reports, in the frame asked for: ``A`` itself but for
        ``apparent``, whose RA, Dec, roll and quaternion then replace ``head``'s
        (:func:`skyfix.track.windows.solution_numbers`'s, changed in place). The matches' RA/Dec
        are their catalogue places already (the windows' ``places``)."""
        if not self.corrected or self._to_apparent is None:
            return A
        A_reported = A @ self._to_apparent
        head[:7] = pointing(A_reported)
        head[:3] = np.degrees(head[:3])
        return A_reported

    def report(self, sol, A: np.ndarray, A_reported: np.ndarray) -> None:
        """The observation's fields of a tracked frame's Solution (the frame's time)."""
        sol.A_apparent_to_cam = A_reported
        self.current.report(sol, A, A_reported, time=self.frame_time)
