"""The mounting of a fixed camera on the ground from a night of solved images (thesis 003 §2.9–2.10):
each image's camera → ENU rotation, their average, and how well the average is known.

A camera fixed to the ground keeps one orientation in the local frame (east, north, up) while the
sky turns. Each solved image gives it: ``A_cam_to_enu = A_icrs_to_enu · A_icrs_to_camᵀ`` (thesis
003 Eq. 7.17, ``q(ENU←c) = q(ENU←ECI) ⊗ q(ECI←c)``), with ``A_icrs_to_enu`` the rigid rotation
of :func:`skyfix.corrections.refraction.ground_frame` at the image's time, and ``A_icrs_to_cam``
fitted to the stars' observed (refracted) directions. Their Markley average
(:func:`skyfix.frames.average_quaternions`, Eq. 7.18) is the mounting "truth", and each image's
truth attitude follows from it (Eq. 7.19, :func:`truth_attitudes`).

How well the average is known, two ways:

- the covariance of the average (``covariance_arcsec2``): the scatter of the images' rotations
  about the average, in ENU axes, divided by their number;
- thesis 003's "truth error" (§9.VI.A, Eq. 9.1): each Euler angle's deviations from the
  average's, ``S_e = σ/√n`` per angle, and their RMS (Euler 1-2-3, skyfix's sequence: the thesis
  does not name its own).

The average absorbs every error that is the same in all images (a mis-set clock, a constant
refraction error): it measures repeatability, not absolute accuracy (thesis 003 §8).

``skyfix analyze mounting IMAGES… --site …`` solves each image at the site with its own time
(:func:`image_to_enu`: refraction per star, aberration, so the attitude is the physical one) and
averages them (:func:`estimate_mounting`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from skyfix.errors import InputError
from skyfix.frames import average_quaternions, euler123_from_matrix
from skyfix.geometry import quaternion_from_attitude

__all__ = ["MountingEstimate", "camera_to_enu", "estimate_mounting", "image_to_enu", "truth_attitudes"]

RAD_TO_ARCSEC = 180.0 / np.pi * 3600.0


class MountingEstimate(NamedTuple):
    """A fixed camera's orientation in the local frame, averaged over images (:func:`estimate_mounting`).

    A_cam_to_enu : (3, 3) — the average (``v_enu = A v_cam``).
    quaternion_xyzw : (4,) — its quaternion, scalar last, ``w >= 0``.
    euler123_deg : (3,) — its Euler 1-2-3 angles (:func:`skyfix.frames.euler123_from_matrix`).
    covariance_arcsec2 : (3, 3) — covariance of the average, about the ENU axes.
    deviations_arcsec : (n, 3) — each image's rotation vector about the average (ENU axes).
    euler_deviations_arcsec : (n, 3) — each image's Euler angles minus the average's.
    euler_standard_error_arcsec : (3,) — ``σ/√n`` of each Euler angle (thesis 003 Eq. 9.1).
    standard_error_arcsec : float — the RMS of the three: thesis 003's "truth error".
    n_images : int.
    """

    A_cam_to_enu: np.ndarray
    quaternion_xyzw: np.ndarray
    euler123_deg: np.ndarray
    covariance_arcsec2: np.ndarray
    deviations_arcsec: np.ndarray
    euler_deviations_arcsec: np.ndarray
    euler_standard_error_arcsec: np.ndarray
    standard_error_arcsec: float
    n_images: int

    def to_json(self) -> dict:
        """The summary (no per-image rows), JSON-ready; each rotation says its frames."""
        return {"from": "camera", "to": "enu", "n_images": self.n_images,
                "quaternion_xyzw": [round(float(x), 10) for x in self.quaternion_xyzw],
                "euler123_deg": [round(float(x), 8) for x in self.euler123_deg],
                "covariance_arcsec2": np.round(self.covariance_arcsec2, 6).tolist(),
                "euler_standard_error_arcsec": [round(float(x), 6) for x in self.euler_standard_error_arcsec],
                "standard_error_arcsec": round(float(self.standard_error_arcsec), 6)}


def camera_to_enu(A_icrs_to_cam: np.ndarray, A_icrs_to_enu: np.ndarray) -> np.ndarray:
    """``A_cam_to_enu = A_icrs_to_enu · A_icrs_to_camᵀ`` for one image or many (..., 3, 3)."""
    A_cam = np.asarray(A_icrs_to_cam, dtype=np.float64)
    return np.asarray(A_icrs_to_enu, dtype=np.float64) @ np.swapaxes(A_cam, -1, -2)


def estimate_mounting(A_cam_to_enu: np.ndarray, weights: np.ndarray | None = None) -> MountingEstimate:
    """The mounting of a fixed camera from each image's ``A_cam_to_enu`` (n, 3, 3), n >= 2
    (:func:`camera_to_enu`); ``weights`` are relative (default equal)."""
    A = np.asarray(A_cam_to_enu, dtype=np.float64)
    if A.ndim != 3 or A.shape[1:] != (3, 3) or len(A) < 2:
        raise InputError(f"the mounting needs two or more (3, 3) rotations, not shape {A.shape}")
    avg = average_quaternions(np.array([quaternion_from_attitude(a) for a in A]), weights)
    euler = euler123_from_matrix(A)
    euler_avg = euler123_from_matrix(avg.A)
    d_euler = (euler - euler_avg + np.pi) % (2.0 * np.pi) - np.pi
    se = np.std(d_euler, axis=0, ddof=1) / np.sqrt(len(A)) * RAD_TO_ARCSEC
    return MountingEstimate(avg.A, avg.quaternion_xyzw, np.degrees(euler_avg),
                            avg.covariance_rad2 * RAD_TO_ARCSEC**2, avg.deviations_rad * RAD_TO_ARCSEC,
                            d_euler * RAD_TO_ARCSEC, se, float(np.sqrt(np.mean(se**2))), len(A))


def truth_attitudes(mounting: MountingEstimate, A_icrs_to_enu: np.ndarray) -> np.ndarray:
    """Each image's truth attitude from the averaged mounting (thesis 003 Eq. 7.19,
    ``q_T(ECI←c) = q(ENU←ECI)⁻¹ ⊗ q̃(ENU←c)``): ``A_icrs_to_cam = A_cam_to_enuᵀ · A_icrs_to_enu``."""
    return mounting.A_cam_to_enu.T @ np.asarray(A_icrs_to_enu, dtype=np.float64)


def image_to_enu(image, site, weather=None, **solve_options):
    """One image of a night solved at ``site`` (with ``weather``) at its own time (its FITS
    DATE-OBS or EXIF, or ``time=`` in ``solve_options``): the Solution and, when solved, its
    ``A_cam_to_enu`` (:func:`camera_to_enu` with the ground frame of its time), else None. An
    image without a time is an :class:`~skyfix.errors.InputError`: the local frame turns with it."""
    from skyfix.corrections.observation import observe
    from skyfix.pipeline import solve

    sol = solve(image, site=site, weather=weather, **solve_options)
    if sol.time is None:
        raise InputError("no observation time (DATE-OBS or EXIF): the mounting needs each image's")
    if not sol.solved:
        return sol, None
    frame = observe(sol.time, site=site, weather=weather,
                    refraction=solve_options.get("refraction", "erfa")).ground
    return sol, camera_to_enu(sol.A_icrs_to_cam, frame.A_icrs_to_enu)
