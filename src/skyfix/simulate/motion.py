"""Motion during and between exposures: attitude after a turn or under a constant body rate,
smear sub-steps, rolling-shutter row timing.

The body rate ``ω`` (rad/s) is expressed in the camera frame (about camera x, y, z). A direction
fixed in ICRS then moves in the camera frame as ``ḃ = −ω × b``, so
``A(t) = R(−ω t) · A(0)`` with ``R`` the rotation by the vector ``−ω t``. More generally a camera
that has turned by the rotation vector ``φ`` (camera axes) has the attitude ``R(−φ) · A``
(:func:`turn`); the profiles of :mod:`skyfix.simulate.profiles` are ``φ(t)``.

Where a function takes a ``motion``, it is what the camera does around the frame's reference
time (mid-exposure of the centre row, where ``A`` holds): ``None`` (still), a (3,) body rate
(constant over the exposure), or a callable ``motion(t_s) -> (..., 3, 3)`` giving the attitude
at times ``t_s`` relative to that reference (an attitude profile seen from the frame).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from skyfix.detect.streak import star_times

__all__ = ["turn", "attitude_at", "attitude_function", "project_at", "star_tracks", "smear_steps",
           "MEAN_ERROR_PX"]

#: A profile's smear is sampled finely enough that a star's mean position over the exposure is
#: this close to the continuous motion's, pixels (:func:`smear_steps`).
MEAN_ERROR_PX = 1e-3

#: The attitude at times ``t_s`` (s) relative to a frame's reference time: (3, 3) for a scalar,
#: (..., 3, 3) for an array of times.
AttitudeFunction = Callable[[np.ndarray | float], np.ndarray]


def turn(A_icrs_to_cam: np.ndarray, rotvec_rad: np.ndarray) -> np.ndarray:
    """The attitude after the camera turned by the rotation vector ``φ`` (radians, camera axes):
    ``R(−φ) · A``. ``φ`` of shape (3,) gives (3, 3); (..., 3) gives (..., 3, 3)."""
    A = np.asarray(A_icrs_to_cam, dtype=np.float64)
    phi = np.asarray(rotvec_rad, dtype=np.float64)
    R = Rotation.from_rotvec(-phi.reshape(-1, 3)).as_matrix()
    return (R @ A).reshape(phi.shape[:-1] + (3, 3))


def attitude_at(A_icrs_to_cam: np.ndarray, rate_rad_s: np.ndarray | None, t_s: np.ndarray | float
                ) -> np.ndarray:
    """Attitude matrices at times ``t_s`` (s, relative to the reference attitude ``A``) under the
    constant body rate ``rate_rad_s``: ``R(−ω t) · A``; (3, 3) for a scalar time, (K, 3, 3) for an
    array."""
    A = np.asarray(A_icrs_to_cam, dtype=np.float64)
    t = np.asarray(t_s, dtype=np.float64)
    if rate_rad_s is None:
        return np.broadcast_to(A, t.shape + (3, 3)).copy()
    w = np.asarray(rate_rad_s, dtype=np.float64).reshape(3)
    return turn(A, t[..., None] * w)


def attitude_function(A_icrs_to_cam: np.ndarray, motion) -> AttitudeFunction | None:
    """The attitude as a function of time around ``A``'s time for a ``motion`` (module
    docstring), or None when the camera is still (no motion, or a zero rate)."""
    if motion is None:
        return None
    if callable(motion):
        return motion
    rate = np.asarray(motion, dtype=np.float64).reshape(3)
    if not np.any(rate):
        return None
    return functools.partial(attitude_at, np.asarray(A_icrs_to_cam, dtype=np.float64), rate)


def project_at(A_icrs_to_cam: np.ndarray, motion, t_s: np.ndarray, vectors: np.ndarray, camera
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel positions of ICRS ``vectors`` (N, 3), each at its own time ``t_s`` (N,) relative to
    ``A``'s time, under ``motion`` (module docstring).

    Returns ``xy`` (N, 2), the in-front mask (N,), and camera-frame unit vectors (N, 3).
    """
    t = np.broadcast_to(np.asarray(t_s, dtype=np.float64), (len(vectors),))
    attitude = attitude_function(A_icrs_to_cam, motion)
    if attitude is None:
        b = vectors @ np.asarray(A_icrs_to_cam).T
    elif len(t) == 0 or np.all(t == t[0]):  # one attitude for all (global shutter)
        b = vectors @ attitude(t[0] if len(t) else 0.0).T
    else:
        As = attitude(t)  # (N, 3, 3)
        b = np.einsum("nij,nj->ni", As, vectors)
    xy, front = camera.ray_to_pixel(b)
    return xy, front, b


def star_tracks(A_icrs_to_cam: np.ndarray, motion, vectors: np.ndarray, camera, exposure_s: float,
                line_time_s: float = 0.0, max_step_px: float = 0.2, max_steps: int = 4096
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where each star is during the exposure, under ``motion`` (module docstring).

    Each row of a rolling-shutter sensor is exposed over ``[t_r − τ/2, t_r + τ/2]`` with
    ``t_r = (row − (H − 1)/2)·line_time_s`` (0 for a global shutter); time 0 is the frame's
    mid-exposure at the centre row, where ``A`` holds. A star's reference time is that of the row
    it is imaged on (:func:`skyfix.detect.streak.star_times`, the same formula a tracker applies
    to a measured centroid), found by fixed-point iteration.

    Returns
    -------
    xy_mid : (N, 2) — the star's position at its row's mid-exposure (its truth position).
    front : (N,) bool — in front of the camera.
    tracks : (K, N, 2) — positions at ``K`` equally spaced sub-step times covering the exposure
        (midpoints of ``K`` equal intervals; ``K`` chosen so no step exceeds ``max_step_px``).
    b_mid : (N, 3) — camera-frame unit vectors at ``xy_mid``'s time.
    """
    n = len(vectors)
    moving = attitude_function(A_icrs_to_cam, motion) is not None
    t_ref = np.zeros(n)
    xy, front, b = project_at(A_icrs_to_cam, motion, t_ref, vectors, camera)
    if moving and line_time_s > 0:
        for _ in range(4):
            rows = np.clip(xy[:, 1], -0.5, camera.height - 0.5)
            t_ref = star_times(np.column_stack([xy[:, 0], rows]), 0.0, line_time_s, camera.height)
            xy, front, b = project_at(A_icrs_to_cam, motion, t_ref, vectors, camera)
    if not moving or exposure_s <= 0:
        return xy, front, xy[None], b
    k = smear_steps(A_icrs_to_cam, motion, vectors, camera, exposure_s, t_ref, max_step_px, max_steps)
    offsets = ((np.arange(k) + 0.5) / k - 0.5) * exposure_s
    tracks = np.empty((k, n, 2))
    for i, dt in enumerate(offsets):  # K sub-steps, each vectorised over stars
        tracks[i] = project_at(A_icrs_to_cam, motion, t_ref + dt, vectors, camera)[0]
    return xy, front, tracks, b


def smear_steps(A_icrs_to_cam, motion, vectors, camera, exposure_s, t_ref, max_step_px=0.2,
                max_steps=4096) -> int:
    """Number of sub-steps so that no star moves more than ``max_step_px`` between steps: from
    the exposure's end points, and for a profile (a callable ``motion``, which may turn back
    within the exposure) the path through its middle too. A profile that accelerates also
    needs enough steps for the star's mean position over the exposure (the centroid of its
    light): ``K`` midpoints miss it by ``bend/(3K²)`` for a path whose middle is ``bend`` off
    its chord (``α·τ²/8`` for an acceleration ``α``), kept below ``MEAN_ERROR_PX``."""
    if len(vectors) == 0:
        return 1
    a = project_at(A_icrs_to_cam, motion, t_ref - exposure_s / 2, vectors, camera)[0]
    z = project_at(A_icrs_to_cam, motion, t_ref + exposure_s / 2, vectors, camera)[0]
    span = np.hypot(*(z - a).T)
    bend = np.zeros(len(vectors))
    if callable(motion):
        m = project_at(A_icrs_to_cam, motion, t_ref, vectors, camera)[0]
        span = np.maximum(span, np.hypot(*(m - a).T) + np.hypot(*(z - m).T))
        bend = np.hypot(*(m - 0.5 * (a + z)).T)
    ok = np.isfinite(span) & (span < 10 * (camera.width + camera.height))
    longest = float(span[ok].max()) if ok.any() else 0.0
    most_bent = float(bend[ok].max()) if ok.any() else 0.0
    k = max(math.ceil(longest / max_step_px), math.ceil(math.sqrt(most_bent / (3 * MEAN_ERROR_PX))))
    return int(min(max(1, k), max_steps))
