"""Unit vectors, RA/Dec, attitude matrices, quaternions and roll: the conventions of
``docs/design.md#conventions`` (the arithmetic shared with the kernels is in
:mod:`skyfix._kernels.rotation`).

- ``A`` (``A_icrs_to_cam``) takes ICRS unit vectors into the camera frame, ``b = A @ r``;
  its rows are the camera axes expressed in ICRS.
- Camera frame: ``+z`` boresight, ``+x`` toward increasing column, ``+y`` toward increasing row.
- Roll: position angle of image-up (the ``-y`` axis) from celestial north through east.
  At roll 0 north is up and east is left.

All angles are radians unless a name says otherwise.
"""

from __future__ import annotations

import numpy as np

from skyfix._kernels import rotation

__all__ = [
    "radec_to_vector",
    "vector_to_radec",
    "attitude_from_radec_roll",
    "radec_roll_from_attitude",
    "quaternion_from_attitude",
    "attitude_from_quaternion",
    "angle_between",
    "normalize",
    "rotation_angle_between",
]


def normalize(v: np.ndarray) -> np.ndarray:
    """Return ``v`` scaled to unit length along its last axis."""
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def radec_to_vector(ra: np.ndarray | float, dec: np.ndarray | float) -> np.ndarray:
    """Unit vectors (..., 3) for right ascension and declination in radians."""
    ra = np.asarray(ra, dtype=np.float64)
    dec = np.asarray(dec, dtype=np.float64)
    cd = np.cos(dec)
    return np.stack([cd * np.cos(ra), cd * np.sin(ra), np.sin(dec)], axis=-1)


def vector_to_radec(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Right ascension in [0, 2π) and declination in [-π/2, π/2] (radians) of vectors (..., 3)."""
    v = np.asarray(v, dtype=np.float64)
    ra, dec = rotation.radec_of_vectors(np.ascontiguousarray(v.reshape(-1, 3)))
    if v.ndim == 1:
        return ra[0], dec[0]
    return ra.reshape(v.shape[:-1]), dec.reshape(v.shape[:-1])


def _east_north(ra: float, dec: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local east, north and outward unit vectors at (ra, dec); east × north = outward."""
    b = radec_to_vector(ra, dec)
    east = np.array([-np.sin(ra), np.cos(ra), 0.0])
    north = np.array([-np.sin(dec) * np.cos(ra), -np.sin(dec) * np.sin(ra), np.cos(dec)])
    return east, north, b


def attitude_from_radec_roll(ra: float, dec: float, roll: float) -> np.ndarray:
    """Attitude matrix ``A_icrs_to_cam`` (3×3) for a boresight at (ra, dec) and a roll.

    Parameters
    ----------
    ra, dec : float
        Boresight right ascension and declination, radians (ICRS).
    roll : float
        Position angle of image-up (camera ``-y``) from north through east, radians.
    """
    east, north, z = _east_north(ra, dec)
    up = north * np.cos(roll) + east * np.sin(roll)
    y = -up
    x = np.cross(y, z)
    return np.vstack([x, y, z])


def radec_roll_from_attitude(A_icrs_to_cam: np.ndarray) -> tuple[float, float, float]:
    """Boresight (ra, dec) and roll, radians, of an attitude matrix; roll in [0, 2π)."""
    ra, dec, roll = rotation.pointing(np.ascontiguousarray(A_icrs_to_cam, dtype=np.float64))[:3].tolist()
    return ra, dec, roll


def quaternion_from_attitude(A_icrs_to_cam: np.ndarray) -> np.ndarray:
    """Scalar-last quaternion ``[x, y, z, w]`` of ``A`` (scipy's convention), with ``w >= 0``.

    Shepperd's method (the largest of the four squared components first, for accuracy);
    equal to ``Rotation.from_matrix(A).as_quat(canonical=True)``, at a tenth of its cost.
    """
    return rotation.pointing(np.ascontiguousarray(A_icrs_to_cam, dtype=np.float64))[3:]


def attitude_from_quaternion(quaternion_xyzw: np.ndarray) -> np.ndarray:
    """Attitude matrix of a scalar-last quaternion (inverse of :func:`quaternion_from_attitude`)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(np.asarray(quaternion_xyzw, dtype=np.float64)).as_matrix()


def angle_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle between unit vectors along the last axis, radians; accurate at small angles."""
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    cross = np.linalg.norm(np.cross(u, v), axis=-1)
    dot = np.sum(u * v, axis=-1)
    return np.arctan2(cross, dot)


def rotation_angle_between(A1: np.ndarray, A2: np.ndarray) -> float:
    """Angle of the rotation that takes attitude ``A1`` to ``A2``, radians."""
    from scipy.spatial.transform import Rotation

    dA = np.asarray(A2) @ np.asarray(A1).T
    return float(np.linalg.norm(Rotation.from_matrix(dA).as_rotvec()))
