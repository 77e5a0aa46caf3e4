"""Verification of a candidate attitude, and the refit of attitude and camera on all matches.

A candidate from a 4-star pattern is checked by projecting the brightest catalogue stars in
the field into the frame and matching them to the centroids within a radius. The chance that a
*wrong* attitude matches ``k`` of ``n`` catalogue stars is binomial: each lands within the
radius of some centroid with probability ``p`` = (area of the match circles) / (frame area).
The four pattern stars are matched by construction, so they are left out of both counts.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import bdtrc

from skyfix.attitude import svd_attitude
from skyfix.camera import Camera

__all__ = ["stars_in_view", "match_to_centroids", "prob_false_match", "refit_camera_attitude"]


def stars_in_view(star_vectors: np.ndarray, A_icrs_to_cam: np.ndarray, camera: Camera,
                  n_max: int, margin_px: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The ``n_max`` brightest catalogue stars whose projection falls inside the frame.

    Parameters
    ----------
    star_vectors : (S, 3) ICRS unit vectors, brightest first.
    A_icrs_to_cam : (3, 3) attitude.
    camera : Camera
    n_max : int
    margin_px : float
        Keep only stars at least this far inside the frame edge.

    Returns
    -------
    index : (n,) indices into ``star_vectors``, brightest first.
    xy : (n, 2) their pixel positions.
    """
    half_diag = math.atan(math.hypot(camera.width, camera.height) / 2.0 / min(camera.fx, camera.fy))
    cos_cone = math.cos(min(half_diag * 1.1 + 0.01, math.pi / 2))
    near = np.flatnonzero(star_vectors @ A_icrs_to_cam[2] > cos_cone)
    xy, front = camera.ray_to_pixel(star_vectors[near] @ A_icrs_to_cam.T)
    inside = np.flatnonzero(front & camera.in_frame(xy, margin=margin_px))[:n_max]
    return near[inside], xy[inside]


def match_to_centroids(xy_catalog: np.ndarray, image_tree: cKDTree,
                       radius_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One-to-one nearest matches of projected catalogue stars to centroids within a radius.

    Returns
    -------
    cat_index, image_index : (k,) matched pairs (indices into ``xy_catalog`` and the tree's data).
    distance : (k,) pixels.
    """
    if len(xy_catalog) == 0:
        empty = np.zeros(0, np.int64)
        return empty, empty, np.zeros(0)
    dist, img = image_tree.query(xy_catalog, k=1, distance_upper_bound=radius_px)
    ok = np.flatnonzero(np.isfinite(dist))
    # Where several catalogue stars claim one centroid, the nearest keeps it.
    order = ok[np.lexsort((dist[ok], img[ok]))]
    first = np.ones(len(order), bool)
    first[1:] = img[order][1:] != img[order][:-1]
    cat = np.sort(order[first])
    return cat, img[cat].astype(np.int64), dist[cat]


def prob_false_match(n_matched: int, n_catalog: int, n_image: int, radius_px: float,
                     width: int, height: int, n_forced: int = 4) -> float:
    """Probability that a wrong attitude matches at least ``n_matched`` of ``n_catalog`` stars.

    Parameters
    ----------
    n_matched, n_catalog : int
        Matched and projected catalogue stars.
    n_image : int
        Centroids they were matched against.
    radius_px : float
        Match radius, pixels.
    width, height : int
        Frame size, pixels.
    n_forced : int
        Stars matched by construction (the pattern), left out of both counts.
    """
    p = min(1.0, n_image * math.pi * radius_px**2 / (width * height))
    k = n_matched - n_forced
    n = n_catalog - n_forced
    if k <= 0 or n <= 0:
        return 1.0
    return float(bdtrc(k - 1, n, p))  # P(X >= k), X ~ Binomial(n, p)


def refit_camera_attitude(xy: np.ndarray, r_icrs: np.ndarray, camera: Camera, *,
                          fit_focal: bool, fit_k1: bool, iterations: int = 4,
                          ) -> tuple[np.ndarray, Camera]:
    """Attitude (SVD) and, optionally, focal length and radial distortion k1 on matched stars.

    Alternates a Wahba fit at fixed camera with a linear least-squares fit of ``f`` and
    ``f·k1`` at fixed attitude (``u − cx = f·x_n·(1 + k1·r²)``, same for ``v``; principal
    point and the other coefficients kept).

    Parameters
    ----------
    xy : (M, 2) centroids, pixels.
    r_icrs : (M, 3) matched catalogue unit vectors.
    camera : Camera — starting camera.
    fit_focal, fit_k1 : bool — which parameters to free.

    Returns
    -------
    A_icrs_to_cam : (3, 3), camera : Camera (refitted).
    """
    xy = np.asarray(xy, np.float64)
    A = svd_attitude(camera.pixel_to_ray(xy), r_icrs)
    if not fit_focal:
        return A, camera
    du, dv = xy[:, 0] - camera.cx, xy[:, 1] - camera.cy
    rhs = np.concatenate([du, dv])
    for _ in range(iterations):
        b = r_icrs @ A.T
        xn, yn = b[:, 0] / b[:, 2], b[:, 1] / b[:, 2]
        r2 = xn * xn + yn * yn
        cols = [np.concatenate([xn, yn])]
        if fit_k1:
            cols.append(np.concatenate([xn * r2, yn * r2]))
        sol, *_ = np.linalg.lstsq(np.stack(cols, axis=1), rhs, rcond=None)
        f = float(sol[0])
        k1 = float(np.clip(sol[1] / f, -1.0, 1.0)) if fit_k1 else camera.k1
        if not (f > 0 and math.isfinite(f)):
            break
        camera = camera.replace(fx=f, fy=f, k1=k1)
        A = svd_attitude(camera.pixel_to_ray(xy), r_icrs)
    return A, camera
