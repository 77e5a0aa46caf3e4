"""Wahba's problem: the attitude that best rotates catalogue vectors onto observed ones."""

from __future__ import annotations

import numpy as np

__all__ = ["svd_attitude"]


def svd_attitude(b_cam: np.ndarray, r_icrs: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Markley's SVD solution: ``A_icrs_to_cam`` minimising Σ w |b − A r|².

    Parameters
    ----------
    b_cam : (N, 3) unit vectors observed in the camera frame.
    r_icrs : (N, 3) matching catalogue unit vectors (ICRS).
    weights : (N,) optional non-negative weights (default 1).
    """
    w = np.ones(len(b_cam)) if weights is None else np.asarray(weights, float)
    B = (np.asarray(b_cam, float) * w[:, None]).T @ np.asarray(r_icrs, float)
    U, _, Vt = np.linalg.svd(B)
    d = np.linalg.det(U) * np.linalg.det(Vt)
    return U @ np.diag([1.0, 1.0, d]) @ Vt
