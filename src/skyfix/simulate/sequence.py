"""Image sequences at a frame rate under a constant body rate (for tracking tests)."""

from __future__ import annotations

from collections.abc import Iterator
from datetime import timedelta

import numpy as np

from skyfix.errors import SimulationError
from skyfix.simulate.motion import attitude_at
from skyfix.simulate.render import SimulatedFrame, render, resolve_setup
from skyfix.simulate.scene import catalog_at, parse_time

__all__ = ["render_sequence"]


def render_sequence(A_icrs_to_cam: np.ndarray, camera, *, n_frames: int, fps: float, rate_rad_s=None,
                    epoch=None, seed: int = 0, sensor=None, optics=None, exposure_s: float | None = None,
                    catalog=None, mag_limit: float | None = None, **kwargs) -> Iterator[SimulatedFrame]:
    """Frames ``k = 0 … n_frames − 1`` at times ``t_k = k / fps`` after ``epoch``.

    Frame ``k`` has attitude ``A(t_k) = R(−ω t_k) A`` (``ω`` = ``rate_rad_s`` in the camera frame),
    mid-exposure time ``epoch + t_k`` (its FITS ``DATE-OBS``) and its own noise streams
    (``frame_index = k``); fixed patterns are the sensor's and stay put. Frame 0 equals
    ``render(A, ..., seed=seed)``. Other keywords go to :func:`render`. Yields frames lazily.
    """
    if not (isinstance(n_frames, (int, np.integer)) and n_frames >= 1):
        raise SimulationError(f"n_frames must be a positive integer, got {n_frames!r}")
    if not (np.isfinite(fps) and fps > 0):
        raise SimulationError(f"fps must be a positive number, got {fps}")
    camera, sensor, optics, exposure_s = resolve_setup(camera, sensor, optics, exposure_s)
    if exposure_s > 1.0 / fps + 1e-12:
        raise SimulationError(f"exposure {exposure_s} s is longer than the frame period {1.0 / fps:.6g} s")
    jy0, iso0 = parse_time(epoch)
    from datetime import datetime

    t0 = datetime.fromisoformat(iso0.replace("Z", "+00:00"))
    if catalog is None:
        catalog = catalog_at(jy0, mag_limit)  # proper motion over a sequence is negligible
        mag_limit = None
    for k in range(int(n_frames)):
        t = k / fps
        A_k = attitude_at(A_icrs_to_cam, rate_rad_s, t)
        yield render(A_k, camera, sensor=sensor, optics=optics, exposure_s=exposure_s,
                     epoch=t0 + timedelta(seconds=t), rate_rad_s=rate_rad_s, seed=seed, catalog=catalog,
                     mag_limit=mag_limit, frame_index=k, **kwargs)
