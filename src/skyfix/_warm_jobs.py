"""The warm-up jobs of :mod:`skyfix.warmup`: each runs one stage on a small synthetic sky, so
that numba compiles (into its on-disk cache) every kernel the stage runs on real data, with the
same argument types.

The sky (:func:`scene`) is 600 stars scattered over a 30° cap, seen by a 640 × 480 camera with a
15° field: a float32 frame with Gaussian stars on a noisy sky, the stars' true centroids, and a
pattern database built from those stars alone (:func:`database`, a second or two). Every job is
a function of no arguments named as the job (``final-fit`` → :func:`final_fit`).
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

__all__ = ["Scene", "attitude", "centroiders", "database", "extract", "final_fit", "hint", "identify",
           "loaded_database", "scene", "simulate", "streaks", "track"]


class Scene(NamedTuple):
    """A synthetic sky and one frame of it."""

    catalog: object  #: :class:`skyfix.catalog.Catalog` of the cap's stars
    camera: object  #: :class:`skyfix.camera.Camera`, pinhole, 640 × 480, 15°
    A_icrs_to_cam: np.ndarray  #: the frame's attitude
    xy: np.ndarray  #: (N, 2) true centroids in the frame, brightest first
    rows: np.ndarray  #: (N,) their catalogue rows
    frame: np.ndarray  #: (480, 640) float32, ADU


@functools.cache
def scene() -> Scene:
    from skyfix.camera import Camera
    from skyfix.catalog import Catalog
    from skyfix.geometry import attitude_from_radec_roll, radec_to_vector

    rng = np.random.default_rng(2026)
    n = 600
    ra0, dec0 = math.radians(80.0), math.radians(20.0)
    axis = radec_to_vector(ra0, dec0)
    # uniform over the cap: cos(angle from the axis) uniform in [cos 30°, 1]
    cos_t = rng.uniform(math.cos(math.radians(30.0)), 1.0, n)
    phi = rng.uniform(0.0, 2.0 * math.pi, n)
    e1 = np.cross([0.0, 0.0, 1.0], axis)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    sin_t = np.sqrt(1.0 - cos_t**2)
    v = cos_t[:, None] * axis + sin_t[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    mag = np.sort(rng.uniform(1.0, 7.5, n)).astype(np.float32)
    catalog = Catalog(np.arange(1, n + 1, dtype=np.int64), v, mag, np.zeros(n), np.zeros(n), 2026.0)
    camera = Camera.from_fov(640, 480, 15.0)
    A = attitude_from_radec_roll(ra0, dec0, math.radians(30.0))
    xy, front = camera.ray_to_pixel(v @ A.T)
    inside = front & (xy[:, 0] > 2) & (xy[:, 0] < 637) & (xy[:, 1] > 2) & (xy[:, 1] < 477)
    rows = np.flatnonzero(inside)  # brightest first, as the catalogue
    xy = xy[rows]
    frame = _render(xy, mag[rows], camera.height, camera.width, rng)
    return Scene(catalog, camera, A, xy, rows, frame)


def _render(xy: np.ndarray, mag: np.ndarray, h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """Gaussian stars (σ 1.1 px) on a sky of 200 ADU with noise of 4 ADU, float32."""
    frame = 200.0 + rng.normal(0.0, 4.0, (h, w))
    yy, xx = np.mgrid[-5:6, -5:6]
    for (x, y), m in zip(xy, mag, strict=True):
        ix, iy = int(round(x)), int(round(y))
        stamp = np.exp(-((xx + ix - x) ** 2 + (yy + iy - y) ** 2) / (2 * 1.1**2))
        y0, x0 = max(iy - 5, 0), max(ix - 5, 0)
        y1, x1 = min(iy + 6, h), min(ix + 6, w)
        frame[y0:y1, x0:x1] += (4e4 * 10 ** (-0.4 * (m - 1.0)) / (2 * math.pi * 1.1**2)) * stamp[
            y0 - iy + 5:y1 - iy + 5, x0 - ix + 5:x1 - ix + 5]
    return frame.astype(np.float32)


@functools.cache
def database():
    """A pattern database (10–30°) of the scene's stars alone."""
    from skyfix.identify.catalogue.database import PatternDatabase

    return PatternDatabase.build(10.0, 30.0, catalog=scene().catalog)


@functools.cache
def loaded_database():
    """:func:`database` saved and loaded again, as a cached database reaches the kernels: its
    arrays read-only views of the file's mmap (:func:`skyfix.cache.map_npz`)."""
    import tempfile

    from skyfix.identify.catalogue.database import PatternDatabase

    path = Path(tempfile.mkdtemp(prefix="skyfix-warm-")) / "database.npz"
    database().save(path)
    loaded = PatternDatabase.load(path)
    for f in path.parent.iterdir():  # the mmap keeps the data; nothing is left behind
        f.unlink()
    path.parent.rmdir()
    return loaded


def extract() -> None:
    """Reading a PNG file (its row filters are undone by a kernel) and the default extraction of
    a float32 frame (every image reaches the kernels as float32)."""
    import tempfile

    from PIL import Image

    from skyfix.detect import extract_centroids
    from skyfix.io import read_image

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "frame.png"
        Image.fromarray(np.clip(scene().frame, 0, 65535).astype(np.uint16)).save(path)
        read_image(path)
    for _ in range(2):  # the second call of a frame size reuses (and clears) the first's buffers
        extract_centroids(scene().frame, max_stars=200)


def identify() -> None:
    """The 4-star search and its refit (:func:`skyfix.identify.methods.quad.warm_kernels`), and the
    undistortion a search through a given camera starts with."""
    from skyfix.identify.methods.quad import warm_kernels

    warm_kernels()
    scene().camera.pixel_to_normalized(scene().xy)


def final_fit() -> None:
    """The final fit of an identification, with the camera fitted and given, the default attitude
    solver (SVD), and the Solution's numbers."""
    from skyfix.attitude import svd_attitude
    from skyfix.final_fit import final_fit as fit
    from skyfix.identify.accept import chance_log_probability
    from skyfix.identify.common.result import Identification
    from skyfix.pipeline import solution_numbers

    s = scene()
    db = database()
    cat = s.catalog
    ident = Identification(True, star_index=np.arange(len(s.rows)), catalog_ids=cat.ids[s.rows],
                           catalog_vectors=cat.vectors[s.rows],
                           catalog_mag=cat.mag[s.rows].astype(np.float64), A_icrs_to_cam=s.A_icrs_to_cam,
                           camera=s.camera, prob_false=1e-30, method="quad-hash", match_radius_px=3.0,
                           database=db)
    for given in (False, True):
        result = fit(s.xy, ident, camera_given=given, database=db)
        solution_numbers(result.A_icrs_to_cam, s.xy, result.star_index, result.catalog_vectors,
                         result.catalog_mag, result.residuals_rad)
    n = len(s.rows)
    chance_log_probability(n, 2 * n, n, 3.0, 640.0 * 480.0, 2.0)  # a re-match's test
    # two stars: the SVD solver's own branch (a sparse or degenerate field)
    svd_attitude(s.camera.pixel_to_ray(s.xy[:2]), cat.vectors[s.rows[:2]])


def attitude() -> None:
    """The attitude solvers but the default (``quest``, ``esoq2``, ``q-method``, ``triad``)."""
    from skyfix.attitude import METHODS, attitude_covariance, solve_attitude

    s = scene()
    b = s.camera.pixel_to_ray(s.xy)
    r = s.catalog.vectors[s.rows]
    for method in METHODS:
        attitude_covariance(solve_attitude(b, r, method=method), b, 1e-5)


def hint() -> None:
    """A solve near an attitude hint (:func:`skyfix.identify.hint.identify_near`), camera given."""
    from skyfix.pipeline import solve_centroids

    s = scene()
    solve_centroids(s.xy, s.camera.width, s.camera.height, camera=s.camera, attitude_hint=s.A_icrs_to_cam,
                    database=database())


def centroiders() -> None:
    """The windowed centroiders (``iwcog``, ``gaussian``) after an extraction."""
    from skyfix.detect import CENTROIDERS, extract_centroids

    for name in CENTROIDERS:
        if name != "com":
            extract_centroids(scene().frame, centroid=name, max_stars=50)


def streaks() -> None:
    """The streak fit (:func:`skyfix.detect.streak.fit_streaks`) of stars smeared by a turn, which
    the tracker runs after a lost frame and on a fast turn."""
    from skyfix.detect.streak import centroid_streaks

    s = scene()
    centroid_streaks(s.frame, s.xy[:20], np.array([6.0, 2.0]), prediction_sigma=2.0)


def _detector(name: str) -> None:
    from skyfix.detect import extract_centroids

    extract_centroids(scene().frame, method=name, max_stars=50)


def detector_threshold_hillclimb() -> None:
    """Thesis 000's detector."""
    _detector("threshold_hillclimb")


def detector_region_grow() -> None:
    """Thesis 004's detector."""
    _detector("region_grow")


def detector_regionprops() -> None:
    """Thesis 003's detector."""
    _detector("regionprops")


def _method(name: str) -> None:
    """Identification method ``name`` with a FOV and with a camera (sparse frames: the brightest 6
    stars, which some methods judge by rules of their own)."""
    from skyfix.identify import identify

    s = scene()
    w, h = s.camera.width, s.camera.height
    for xy in (s.xy, s.xy[:6]):
        identify(xy, w, h, method=name, fov_deg=s.camera.fov_deg, database=database())
        identify(xy, w, h, method=name, camera=s.camera, database=database())


def method_triangle() -> None:
    _method("triangle")


def method_liebe() -> None:
    _method("liebe")


def method_planar() -> None:
    _method("planar")


def method_area_moment() -> None:
    _method("area-moment")


def method_pyramid() -> None:
    _method("pyramid")


def method_grid() -> None:
    _method("grid")


def method_voting() -> None:
    _method("voting")


def method_van_bezooijen() -> None:
    _method("van-bezooijen")


def track() -> None:
    """The tracker over a few frames turning at 0.5°/s (lost in space, acquiring, tracking): float32
    frames (what :func:`skyfix.io.read_image` gives) with a database built in memory, and 16-bit
    frames (a camera's, the simulator's) with one loaded from a file, at another epoch."""
    from scipy.spatial.transform import Rotation

    from skyfix.track import Tracker

    s = scene()
    axis = np.array([0.3, -0.2, 0.93])
    axis /= np.linalg.norm(axis)
    # (a loaded database's star vectors moved to another epoch are a fresh array beside its
    # read-only ones: a tracker's catalogue at the frames' time)
    for db, dtype, epoch in ((database(), np.float32, None), (loaded_database(), np.uint16, 2030.0)):
        tracker = Tracker(s.camera, database=db, epoch=epoch)
        rng = np.random.default_rng(5)
        for k in range(6):
            t = 0.1 * k
            A = Rotation.from_rotvec(axis * math.radians(0.5) * t).as_matrix() @ s.A_icrs_to_cam
            xy, front = s.camera.ray_to_pixel(s.catalog.vectors @ A.T)
            inside = front & (xy[:, 0] > 2) & (xy[:, 0] < 637) & (xy[:, 1] > 2) & (xy[:, 1] < 477)
            rows = np.flatnonzero(inside)
            frame = _render(xy[rows], s.catalog.mag[rows], s.camera.height, s.camera.width, rng)
            tracker.update(np.clip(frame, 0, 65535).astype(dtype), t)


def simulate() -> None:
    """The simulator: a frame at rest and one turning (smear, rolling shutter), of the scene's
    stars; and one aberrated by an observer's velocity (what ``skyfix simulate`` renders)."""
    from skyfix.simulate import render

    s = scene()
    for rate in (None, (0.002, -0.001, 0.003)):
        render(s.A_icrs_to_cam, "generic", exposure_s=0.1, epoch=2026.0, seed=1, catalog=s.catalog,
               rate_rad_s=rate)
    render(s.A_icrs_to_cam, "generic", exposure_s=0.1, epoch="2026-06-01T00:00:00", seed=1, catalog=s.catalog,
           observer_velocity_km_s=(20.0, -15.0, 5.0))
