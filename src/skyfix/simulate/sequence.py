"""Image sequences at a frame rate, the camera turning by an attitude profile (for tracking tests)."""

from __future__ import annotations

import functools
from collections.abc import Iterator, Mapping
from datetime import datetime, timedelta

import numpy as np

from skyfix.errors import SimulationError
from skyfix.geometry import rotation_angle_between
from skyfix.simulate.profiles import ConstantRate, Profile, profile_of
from skyfix.simulate.render import SimulatedFrame, render, resolve_setup
from skyfix.simulate.scene import catalog_at, simulation_time

__all__ = ["render_sequence"]


def render_sequence(A_icrs_to_cam: np.ndarray | None, camera, *, n_frames: int, fps: float, rate_rad_s=None,
                    profile: Profile | str | None = None, profile_params: Mapping | None = None, epoch=None,
                    seed: int = 0, sensor=None, optics=None, exposure_s: float | None = None, catalog=None,
                    mag_limit: float | None = None, **kwargs) -> Iterator[SimulatedFrame]:
    """Frames ``k = 0 … n_frames − 1`` at times ``t_k = k / fps`` after ``epoch``.

    The camera turns by ``profile`` (:mod:`skyfix.simulate.profiles`): a :class:`Profile`, or
    a name of :data:`~skyfix.simulate.profiles.PROFILES` with its parameters in
    ``profile_params`` (SI units), starting from ``A_icrs_to_cam`` (the profile's ``A0``; it may
    be None when a Profile is given). Without a profile, ``rate_rad_s`` is the constant profile
    ``A(t_k) = R(−ω t_k) A`` (``ω`` in the camera frame), and neither is a camera at rest.

    Frame ``k`` has attitude ``A(t_k)``, mid-exposure time ``epoch + t_k`` (its FITS
    ``DATE-OBS``) and its own noise streams (``frame_index = k``); fixed patterns are the
    sensor's and stay put. Within the exposure, the smear and the rolling shutter's row times
    follow the profile itself (not its rate at mid-exposure), so the truth holds also for
    accelerating profiles. Its truth adds ``t_s`` (``t_k``) and ``profile``
    (:meth:`Profile.to_dict`, None at rest) to :func:`render`'s, whose ``rate_rad_s`` is the
    body rate at ``t_k``. Frame 0 of a constant rate equals ``render(A, ..., rate_rad_s=ω,
    seed=seed)``. Other keywords go to :func:`render`. Yields frames lazily.
    """
    if not (isinstance(n_frames, (int, np.integer)) and n_frames >= 1):
        raise SimulationError(f"n_frames must be a positive integer, got {n_frames!r}")
    if not (isinstance(fps, (int, float, np.number)) and np.isfinite(fps) and fps > 0):
        raise SimulationError(f"fps must be a positive number, got {fps}")
    if "motion" in kwargs:
        raise SimulationError("render_sequence takes a profile, not a motion")
    prof = _sequence_profile(A_icrs_to_cam, rate_rad_s, profile, profile_params)
    A0 = prof.A0 if prof is not None else A_icrs_to_cam
    camera, sensor, optics, exposure_s = resolve_setup(camera, sensor, optics, exposure_s)
    if n_frames > 1 and exposure_s > 1.0 / fps + 1e-12:
        raise SimulationError(f"exposure {exposure_s} s is longer than the frame period {1.0 / fps:.6g} s")
    jy0, iso0 = simulation_time(epoch)
    t0 = datetime.fromisoformat(iso0.replace("Z", "+00:00"))
    if catalog is None:
        catalog = catalog_at(jy0, mag_limit)  # proper motion over a sequence is negligible
        mag_limit = None
    for k in range(int(n_frames)):
        t = k / fps
        if prof is None:
            A_k, rate_k, motion = A0, None, None
        else:
            A_k, rate_k = prof.attitude(t), prof.rate(t)
            # a constant rate is render's own motion; any other profile is followed exactly
            motion = None if isinstance(prof, ConstantRate) else functools.partial(_attitude_after, prof, t)
        frame = render(A_k, camera, sensor=sensor, optics=optics, exposure_s=exposure_s,
                       epoch=t0 + timedelta(seconds=t), rate_rad_s=rate_k, motion=motion, seed=seed,
                       catalog=catalog, mag_limit=mag_limit, frame_index=k, **kwargs)
        frame.truth["t_s"] = t
        frame.truth["profile"] = None if prof is None else prof.to_dict()
        yield frame


def _attitude_after(profile: Profile, t_frame_s: float, dt_s):
    """The profile's attitude ``dt_s`` after the frame's time (render's ``motion``)."""
    return profile.attitude(t_frame_s + np.asarray(dt_s, dtype=np.float64))


def _sequence_profile(A, rate_rad_s, profile, profile_params) -> Profile | None:
    """The sequence's profile from render_sequence's arguments (None: a camera at rest)."""
    if profile is not None and rate_rad_s is not None:
        raise SimulationError("give rate_rad_s or a profile, not both")
    if A is None and not isinstance(profile, Profile):
        raise SimulationError("the start attitude is needed (A_icrs_to_cam), unless a Profile is given")
    if isinstance(profile, Profile):
        if A is not None and rotation_angle_between(profile.A0, np.asarray(A, dtype=np.float64)) > 1e-9:
            raise SimulationError("A_icrs_to_cam differs from the profile's start attitude A0")
    if profile is None and rate_rad_s is not None:
        return ConstantRate(A, rate_rad_s)
    return profile_of(profile, A, profile_params)
