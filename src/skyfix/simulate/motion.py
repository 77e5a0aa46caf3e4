"""Motion during and between exposures: attitude under a constant body rate, smear sub-steps,
rolling-shutter row timing.

The body rate ``ω`` (rad/s) is expressed in the camera frame (about camera x, y, z). A direction
fixed in ICRS then moves in the camera frame as ``ḃ = −ω × b``, so
``A(t) = R(−ω t) · A(0)`` with ``R`` the rotation by the vector ``−ω t``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["attitude_at", "project_at", "star_tracks", "smear_steps"]


def attitude_at(A_icrs_to_cam: np.ndarray, rate_rad_s: np.ndarray | None, t_s: np.ndarray | float
                ) -> np.ndarray:
    """Attitude matrices at times ``t_s`` (s, relative to the reference attitude ``A``):
    (3, 3) for a scalar time, (K, 3, 3) for an array."""
    A = np.asarray(A_icrs_to_cam, dtype=np.float64)
    t = np.asarray(t_s, dtype=np.float64)
    if rate_rad_s is None:
        return np.broadcast_to(A, t.shape + (3, 3)).copy()
    w = np.asarray(rate_rad_s, dtype=np.float64).reshape(3)
    R = Rotation.from_rotvec(-t.reshape(-1, 1) * w[None, :]).as_matrix()
    out = R @ A
    return out.reshape(t.shape + (3, 3))


def project_at(A_icrs_to_cam: np.ndarray, rate_rad_s, t_s: np.ndarray, vectors: np.ndarray, camera
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel positions of ICRS ``vectors`` (N, 3), each at its own time ``t_s`` (N,).

    Returns ``xy`` (N, 2), the in-front mask (N,), and camera-frame unit vectors (N, 3).
    """
    t = np.broadcast_to(np.asarray(t_s, dtype=np.float64), (len(vectors),))
    if rate_rad_s is None or not np.any(np.asarray(rate_rad_s)):
        b = vectors @ np.asarray(A_icrs_to_cam).T
    elif len(t) == 0 or np.all(t == t[0]):  # one attitude for all (global shutter)
        b = vectors @ attitude_at(A_icrs_to_cam, rate_rad_s, t[0] if len(t) else 0.0).T
    else:
        As = attitude_at(A_icrs_to_cam, rate_rad_s, t)  # (N, 3, 3)
        b = np.einsum("nij,nj->ni", As, vectors)
    xy, front = camera.ray_to_pixel(b)
    return xy, front, b


def star_tracks(A_icrs_to_cam: np.ndarray, rate_rad_s, vectors: np.ndarray, camera, exposure_s: float,
                line_time_s: float = 0.0, max_step_px: float = 0.2, max_steps: int = 4096
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where each star is during the exposure.

    Each row of a rolling-shutter sensor is exposed over ``[t_r − τ/2, t_r + τ/2]`` with
    ``t_r = (row − (H − 1)/2)·line_time_s`` (0 for a global shutter); time 0 is the frame's
    mid-exposure at the centre row, where ``A`` holds. A star's reference time is that of the row
    it is imaged on, found by fixed-point iteration.

    Returns
    -------
    xy_mid : (N, 2) — the star's position at its row's mid-exposure (its truth position).
    front : (N,) bool — in front of the camera.
    tracks : (K, N, 2) — positions at ``K`` equally spaced sub-step times covering the exposure
        (midpoints of ``K`` equal intervals; ``K`` chosen so no step exceeds ``max_step_px``).
    b_mid : (N, 3) — camera-frame unit vectors at ``xy_mid``'s time.
    """
    n = len(vectors)
    moving = rate_rad_s is not None and np.any(np.asarray(rate_rad_s))
    t_ref = np.zeros(n)
    xy, front, b = project_at(A_icrs_to_cam, rate_rad_s, t_ref, vectors, camera)
    if moving and line_time_s > 0:
        centre_row = (camera.height - 1) / 2.0
        for _ in range(4):
            t_ref = (np.clip(xy[:, 1], -0.5, camera.height - 0.5) - centre_row) * line_time_s
            xy, front, b = project_at(A_icrs_to_cam, rate_rad_s, t_ref, vectors, camera)
    if not moving or exposure_s <= 0:
        return xy, front, xy[None], b
    k = smear_steps(A_icrs_to_cam, rate_rad_s, vectors, camera, exposure_s, t_ref, max_step_px, max_steps)
    offsets = ((np.arange(k) + 0.5) / k - 0.5) * exposure_s
    tracks = np.empty((k, n, 2))
    for i, dt in enumerate(offsets):  # K sub-steps, each vectorised over stars
        tracks[i] = project_at(A_icrs_to_cam, rate_rad_s, t_ref + dt, vectors, camera)[0]
    return xy, front, tracks, b


def smear_steps(A_icrs_to_cam, rate_rad_s, vectors, camera, exposure_s, t_ref, max_step_px=0.2,
                max_steps=4096) -> int:
    """Number of sub-steps so that no star moves more than ``max_step_px`` between steps."""
    if len(vectors) == 0:
        return 1
    a = project_at(A_icrs_to_cam, rate_rad_s, t_ref - exposure_s / 2, vectors, camera)[0]
    z = project_at(A_icrs_to_cam, rate_rad_s, t_ref + exposure_s / 2, vectors, camera)[0]
    span = np.hypot(*(z - a).T)
    span = span[np.isfinite(span) & (span < 10 * (camera.width + camera.height))]
    longest = float(span.max()) if span.size else 0.0
    return int(min(max(1, math.ceil(longest / max_step_px)), max_steps))
