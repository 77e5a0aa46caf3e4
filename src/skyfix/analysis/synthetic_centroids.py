"""Synthetic star centroids with known truth, for identification tests and benchmarks.

A field is the catalogue stars (to a magnitude limit) that a camera at a given attitude sees,
projected to pixels, with Gaussian centroid noise, random dropouts (missed stars) and false
stars (hot pixels, satellites) mixed into the brightness order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from skyfix.camera import Camera
from skyfix.catalog import Catalog

__all__ = ["SyntheticField", "random_attitudes", "synthetic_centroids"]


@dataclass(frozen=True)
class SyntheticField:
    """One synthetic frame of centroids and its truth.

    Attributes
    ----------
    xy : (N, 2) float64 — centroids in pixels, brightest first (false stars included).
    star_id : (N,) int64 — Hipparcos number of each centroid, 0 for a false star.
    mag : (N,) float64 — apparent magnitude used for the brightness order (with its noise).
    A_icrs_to_cam : (3, 3) — the true attitude.
    camera : Camera — the true camera.
    """

    xy: np.ndarray
    star_id: np.ndarray
    mag: np.ndarray
    A_icrs_to_cam: np.ndarray
    camera: Camera

    @property
    def is_false(self) -> np.ndarray:
        return self.star_id == 0


def random_attitudes(n: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
    """``n`` attitude matrices (n, 3, 3) drawn uniformly from SO(3)."""
    rng = np.random.default_rng(rng)
    return Rotation.random(n, random_state=rng).as_matrix()


def synthetic_centroids(camera: Camera, A_icrs_to_cam: np.ndarray, catalog: Catalog, *,
                        mag_limit: float = 8.0, sigma_px: float = 1.0, n_false: int = 0,
                        dropout: float = 0.0, mag_sigma: float = 0.0,
                        rng: np.random.Generator | int | None = None) -> SyntheticField:
    """Centroids of the catalogue stars in view, with noise, dropouts and false stars.

    Parameters
    ----------
    camera : Camera
        Projects camera-frame rays to pixels (its distortion included).
    A_icrs_to_cam : (3, 3)
        True attitude.
    catalog : Catalog
        Star catalogue (brightest first).
    mag_limit : float
        Faintest magnitude detected.
    sigma_px : float
        Standard deviation of the Gaussian centroid noise on each axis, pixels.
    n_false : int
        False stars added at uniformly random positions, with magnitudes drawn uniformly
        between the brightest and the faintest true star (so they mix into the order).
    dropout : float
        Probability that a true star is missed.
    mag_sigma : float
        Gaussian noise on the magnitudes that set the brightness order, mag.
    rng : Generator or seed
    """
    rng = np.random.default_rng(rng)
    A = np.asarray(A_icrs_to_cam, dtype=np.float64)
    bright = catalog.mag <= mag_limit
    half_diag = np.arctan(np.hypot(camera.width, camera.height) / 2 / min(camera.fx, camera.fy))
    idx = np.flatnonzero(bright & (catalog.vectors @ A[2] > np.cos(min(half_diag * 1.3, np.pi / 2))))
    xy, front = camera.ray_to_pixel(catalog.vectors[idx] @ A.T)
    inside = front & camera.in_frame(xy)
    idx, xy = idx[inside], xy[inside]
    keep = rng.random(len(idx)) >= dropout
    idx, xy = idx[keep], xy[keep] + rng.normal(0.0, sigma_px, size=(keep.sum(), 2))
    mag = catalog.mag[idx].astype(np.float64) + rng.normal(0.0, mag_sigma, size=len(idx))
    ids = catalog.ids[idx].astype(np.int64)
    if n_false:
        lo, hi = (mag.min(), mag.max()) if len(mag) else (0.0, mag_limit)
        fxy = rng.uniform([-0.5, -0.5], [camera.width - 0.5, camera.height - 0.5], size=(n_false, 2))
        xy = np.concatenate([xy, fxy])
        mag = np.concatenate([mag, rng.uniform(lo, hi, n_false)])
        ids = np.concatenate([ids, np.zeros(n_false, np.int64)])
    order = np.argsort(mag, kind="stable")
    return SyntheticField(xy=xy[order], star_id=ids[order], mag=mag[order], A_icrs_to_cam=A,
                          camera=camera)
