"""Inter-star angles of a frame as the pair-table methods match them (``pyramid``, ``voting``).

A centroid's ray at focal length ``f`` is its undistorted offset from the principal point
``p = (x, y)`` (pixels, :attr:`~skyfix.identify.catalogue.kernel_data.ImageStars.offsets_px`) over it:
``(x, y, f) / |(x, y, f)|`` — the ray of :func:`skyfix.identify.common.hypothesis.rays_at`. The angle
between two rays (:func:`ray_angle`) shrinks as ``f`` grows, so over the focal range a frame
allows ``[f_lo, f_hi]`` a measured angle spans ``[θ(f_hi), θ(f_lo)]``, widened by the centroid
noise (:func:`angle_range`). The noise term of one angle is ``n_sigma · σ_px · √2 / f`` rad (two
centroids, each ``σ_px`` per axis): :attr:`AngleSettings.noise_px` ``/ f``.

With only a FOV known, a method that has matched one image pair to a catalogue pair knows the
focal length (:func:`focal_for_angle`); the other angles at that focal length then carry the
noise of the pair that fixed it in proportion, ``noise / f · (1 + θ / θ_pair)``
(:func:`angle_tolerance`). A calibrated camera has one focal length and the noise term alone.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from typing import NamedTuple

import numpy as np

from skyfix._jit import njit
from skyfix._kernels.rotation import chord_angle
from skyfix.attitude import attitude_covariance
from skyfix.geometry import rotation_angle_between
from skyfix.identify.accept import noise_posterior, precision_failure
from skyfix.identify.catalogue.pairs import PairTable, pair_table
from skyfix.identify.common.hypothesis import Frame, finish, first_accepted, fits, hypothesis, rays_at
from skyfix.identify.common.lone import AMBIGUITY_RATIO, LONE_MAX_STARS, judge_lone
from skyfix.identify.common.result import Identification

__all__ = ["LONE_PROB_THRESHOLD", "AngleSettings", "TableRows", "angle_range", "angle_settings",
           "angle_tolerance", "consistent_set", "focal_for_angle", "frame_diagonal_rad", "frame_pair_table",
           "frame_table", "longest_side_first", "ray_angle", "recorded", "sparse_identification",
           "star_angle", "star_chord2", "triple_product"]

_MAX_ANGLE_MARGIN = 1.02  # the pair table holds pairs a little wider than the frame's diagonal
LONE_PROB_THRESHOLD = 1e-4
"""The largest chance of a wrong match accepted for a sparse frame's proposal (as the
``triangle`` method's ``lone_prob_threshold``: a frame of a few stars cannot reach the 1e-9 of a
rich one, whose other stars verify it)."""


class AngleSettings(NamedTuple):
    """What the angle-matching kernels need of a frame (:func:`angle_settings`).

    offsets_px : (N, 2) float64 — the centroids' undistorted offsets from the principal point.
    rays : (N, 3) float64 — their unit rays at ``f0`` (:attr:`~skyfix.identify.common.hypothesis.Frame.rays`).
    f0 : float — the nominal focal length, pixels.
    f_lo, f_hi : float — the focal lengths allowed (equal to ``f0`` for a calibrated camera).
    calibrated : bool — the focal length is known (else it is fitted per correspondence).
    noise_px : float — ``n_sigma · σ_px · √2``: an angle's noise tolerance times the focal length.
    """

    offsets_px: np.ndarray
    rays: np.ndarray
    f0: float
    f_lo: float
    f_hi: float
    calibrated: bool
    noise_px: float


def angle_settings(frame: Frame, centroid_sigma_px: float, n_sigma: float) -> AngleSettings:
    """The :class:`AngleSettings` of ``frame`` for centroids of noise ``centroid_sigma_px`` (per
    axis, pixels) matched within ``n_sigma`` standard deviations."""
    lo, hi = frame.focal_range_px
    return AngleSettings(np.ascontiguousarray(frame.image.offsets_px, np.float64),
                         np.ascontiguousarray(frame.rays, np.float64), float(frame.camera.fx),
                         float(lo), float(hi), bool(frame.calibrated),
                         float(n_sigma) * float(centroid_sigma_px) * math.sqrt(2.0))


@njit(cache=True, inline="always")
def ray_angle(p, i, j, f):
    """The angle (rad) between the rays of offsets ``p[i]`` and ``p[j]`` (pixels) at focal
    length ``f``."""
    ni = math.sqrt(p[i, 0] ** 2 + p[i, 1] ** 2 + f * f)
    nj = math.sqrt(p[j, 0] ** 2 + p[j, 1] ** 2 + f * f)
    dx = p[i, 0] / ni - p[j, 0] / nj
    dy = p[i, 1] / ni - p[j, 1] / nj
    dz = f / ni - f / nj
    return chord_angle(math.sqrt(dx * dx + dy * dy + dz * dz))


@njit(cache=True, inline="always")
def angle_range(p, i, j, f_lo, f_hi, noise_px):
    """The catalogue angles (lo, hi) rad that the image pair ``(i, j)`` can be at a focal
    length in ``[f_lo, f_hi]``, its noise tolerance included."""
    return ray_angle(p, i, j, f_hi) - noise_px / f_hi, ray_angle(p, i, j, f_lo) + noise_px / f_lo


@njit(cache=True)
def focal_for_angle(p, i, j, target, f, f_lo, f_hi):
    """The focal length in ``[f_lo, f_hi]`` (from ``f``) at which the pair ``(i, j)`` is
    ``target`` rad apart (secant steps on ``θ ∝ 1/f``; clipped to the range)."""
    for _ in range(3):
        seen = ray_angle(p, i, j, f)
        if seen <= 0.0 or target <= 0.0:
            return f
        f = f * seen / target
    return min(max(f, f_lo), f_hi)


@njit(cache=True, inline="always")
def angle_tolerance(theta, theta_pair, f, noise_px, calibrated):
    """The tolerance (rad) of an angle ``theta`` measured at focal length ``f`` — fixed by a pair
    ``theta_pair`` apart when not ``calibrated``."""
    tol = noise_px / f
    if not calibrated:
        tol *= 1.0 + theta / theta_pair
    return tol


def frame_diagonal_rad(frame: Frame, focal_px: float) -> float:
    """The larger of the angles between the frame's opposite corners (its diagonals) at the
    focal length ``focal_px``: the widest angle two of its stars can be apart."""
    p = frame.image.frame_px
    corners = np.array([[p[0], p[2]], [p[1], p[3]], [p[0], p[3]], [p[1], p[2]]])
    return max(ray_angle(corners, 0, 1, focal_px), ray_angle(corners, 2, 3, focal_px))


def frame_pair_table(frame: Frame, per_field: int = 12) -> PairTable:
    """The pair table (:func:`skyfix.identify.catalogue.pairs.pair_table`) of ``frame``'s database that
    holds every angle the frame can measure: fields of the camera's FOV, pairs up to the frame's
    diagonal at the shortest focal length allowed."""
    diagonal = frame_diagonal_rad(frame, float(frame.focal_range_px[0]))
    return pair_table(frame.database, frame.camera.fov_deg, math.degrees(diagonal) * _MAX_ANGLE_MARGIN,
                      per_field=per_field)


@njit(cache=True, inline="always")
def star_chord2(vectors, a, b):
    """The squared chord ``|v_a − v_b|²`` between catalogue stars ``a`` and ``b`` (rows of
    ``vectors``): it grows with their angle θ as ``(2 sin(θ/2))²``."""
    dx = vectors[a, 0] - vectors[b, 0]
    dy = vectors[a, 1] - vectors[b, 1]
    dz = vectors[a, 2] - vectors[b, 2]
    return dx * dx + dy * dy + dz * dz


@njit(cache=True, inline="always")
def star_angle(vectors, a, b):
    """The angle (rad) between catalogue stars ``a`` and ``b`` (rows of ``vectors``)."""
    return chord_angle(math.sqrt(star_chord2(vectors, a, b)))


@njit(cache=True, inline="always")
def triple_product(vectors, a, b, c):
    """``(v_a × v_b) · v_c`` of rows ``a``, ``b``, ``c`` of ``vectors``: its sign is the
    handedness of the triangle (a proper rotation keeps it; a mirror image flips it)."""
    return (vectors[c, 0] * (vectors[a, 1] * vectors[b, 2] - vectors[a, 2] * vectors[b, 1])
            + vectors[c, 1] * (vectors[a, 2] * vectors[b, 0] - vectors[a, 0] * vectors[b, 2])
            + vectors[c, 2] * (vectors[a, 0] * vectors[b, 1] - vectors[a, 1] * vectors[b, 0]))


def recorded(proposals: Iterator[tuple[np.ndarray, np.ndarray]],
             into: list[tuple[np.ndarray, np.ndarray]]) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """``proposals`` passed on unchanged, each one also appended to ``into`` (for
    :func:`sparse_identification` once the common rules have judged them all)."""
    for stars, catalog in proposals:
        into.append((stars, catalog))
        yield stars, catalog


def judged(frame: Frame, table: PairTable, proposals: Iterator[tuple[np.ndarray, np.ndarray]], *,
           max_candidates: int, n_stars: int, tolerance_rad: float, centroid_sigma_px: float,
           work: Callable[[], int], threshold: float = LONE_PROB_THRESHOLD) -> tuple[Identification, str]:
    """A correspondence method's ``proposals`` judged: by the common rules
    (:func:`skyfix.identify.common.hypothesis.first_accepted`, at most ``max_candidates``) and, on a
    sparse frame (at most :data:`~skyfix.identify.common.lone.LONE_MAX_STARS` centroids) that they
    refuse, by :func:`sparse_identification` over the same proposals (``work()``: the method's
    count of what it searched, read once the proposals are spent). Returns the identification —
    successful from either, else the common rules' failure — and the sparse rules' reason to
    append to the method's own ("; ..." or "")."""
    proposed: list[tuple[np.ndarray, np.ndarray]] = []
    result = first_accepted(frame, recorded(proposals, proposed), max_candidates=max_candidates)
    if result.success or len(frame.xy) > LONE_MAX_STARS:
        return result, ""
    sparse = sparse_identification(frame, table, proposed[:result.n_candidates], n_stars=n_stars,
                                   tolerance_rad=tolerance_rad, centroid_sigma_px=centroid_sigma_px,
                                   n_tried=work(), threshold=threshold)
    if isinstance(sparse, Identification):
        return sparse, ""
    return result, f"; {sparse}"


def longest_side_first(frame: Frame, stars: np.ndarray, catalog: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Three matched centroid rows ``stars`` (and their ``catalog`` rows) in the vertex order of
    :func:`skyfix.identify.common.lone.judge_lone` — the longest image side θ01 first — and the
    image sides (θ01, θ02, θ12) at the nominal focal length."""
    v = frame.rays[stars]
    sides = chord_angle(np.linalg.norm(v[[0, 0, 1]] - v[[1, 2, 2]], axis=1))  # 01, 02, 12
    order = ((0, 1, 2), (0, 2, 1), (1, 2, 0))[int(np.argmax(sides))]
    stars, catalog = stars[list(order)], catalog[list(order)]
    v = frame.rays[stars]
    return stars, catalog, chord_angle(np.linalg.norm(v[[0, 0, 1]] - v[[1, 2, 2]], axis=1))


def sparse_identification(frame: Frame, table: PairTable, proposals: list[tuple[np.ndarray, np.ndarray]], *,
                          n_stars: int, tolerance_rad: float, centroid_sigma_px: float, n_tried: int,
                          threshold: float = LONE_PROB_THRESHOLD, mag_margin: float = 1.0,
                          missing_margin: float = 0.75, min_error_px: float = 0.05) -> Identification | str:
    """A sparse frame's identification from proposals the common rules refused, or why not.

    A frame of at most :data:`~skyfix.identify.common.lone.LONE_MAX_STARS` centroids has too few
    stars beyond a 4-star proposal to verify it at 1e-9. Each proposal's first three stars are
    judged as the ``triangle`` method judges a sparse frame's triangle
    (:func:`skyfix.identify.common.lone.judge_lone`: how unusual a catalogue triangle this close is,
    every one of the ``C(n_stars, 3)`` image triangles counted as a look, every other star —
    the proposal's fourth included — verifying it as a binomial tail, a bright catalogue star in
    view on no centroid refuting it). The best is accepted when its chance is at most
    ``threshold`` and no proposal that puts the camera elsewhere comes within
    :data:`~skyfix.identify.common.lone.AMBIGUITY_RATIO` of it; the refit on every matched star
    (:func:`skyfix.identify.common.hypothesis.finish`) must then pass as always, and the attitude of so
    few stars be precise enough to be right (:func:`skyfix.identify.accept.precision_failure`,
    the solve's rule, with the stated ``centroid_sigma_px`` and the matched stars' residuals:
    a few stars at σ 1 px leave the boresight tens of arcseconds uncertain).

    Returns
    -------
    Identification or str
        The identification, or the reason none was accepted.
    """
    if len(frame.xy) > LONE_MAX_STARS:
        return f"a frame of more than {LONE_MAX_STARS} stars is not judged as sparse"
    _, star_mag, _ = frame.database.star_arrays()
    n_triangles = math.comb(max(int(n_stars), 3), 3)
    judged = []
    seen: set[bytes] = set()
    for stars, catalog in proposals:
        tri, cat, sides = longest_side_first(frame, np.asarray(stars[:3], np.int64),
                                             np.asarray(catalog[:3], np.int64))
        key = np.concatenate([tri, cat]).tobytes()
        if key in seen:
            continue
        seen.add(key)
        h = hypothesis(frame, tri, cat)
        if not fits(frame, h):
            continue
        j = judge_lone(frame, h, table, star_mag, sides_img=sides, tolerance_rad=tolerance_rad,
                       n_triangles=n_triangles, mag_margin=mag_margin, missing_margin=missing_margin,
                       min_error_px=min_error_px)
        if j.n_missing == 0:
            judged.append((j.log_chance, h, j))
    if not proposals:
        return "nothing proposed"
    if not judged:
        return "no proposal passes the sparse-frame rules"
    judged.sort(key=lambda e: e[0])
    best_log, best_h, best_j = judged[0]
    if best_log > math.log(threshold):
        return f"sparse frame: best chance of a wrong match {math.exp(best_log):.1e} > {threshold:g}"
    apart = 3.0 * frame.radius_px / float(best_h.focal_px)
    rivals = {tuple(j.catalog[:3]) for lp, h, j in judged[1:]
              if lp <= best_log + math.log(AMBIGUITY_RATIO)
              and rotation_angle_between(h.A_icrs_to_cam, best_h.A_icrs_to_cam) > apart}
    if rivals:
        return f"ambiguous: {len(rivals) + 1} proposals fit these stars about equally well"
    full = hypothesis(frame, best_j.stars, best_j.catalog)
    if not fits(frame, full):
        return "sparse frame: the matched stars fit no one rotation"
    b = rays_at(frame, full.stars, full.focal_px)
    r = frame.stars.vectors[full.catalog] @ full.A_icrs_to_cam.T
    residuals = chord_angle(np.linalg.norm(b - r, axis=1))
    noise = noise_posterior(residuals, 2 * len(b) - 3, float(centroid_sigma_px) / full.focal_px)
    covariance = attitude_covariance(full.A_icrs_to_cam, b, noise.sigma_rad)
    plate_scale = float(frame.camera.plate_scale_rad)
    imprecise = precision_failure(covariance, plate_scale, noise.dof, frame.calibrated)
    if imprecise:
        return f"sparse frame: {imprecise}"
    result = finish(frame, full, best_log, n_tried, len(proposals))
    return result if result is not None else "sparse frame: the refit is not beyond chance"


class TableRows(NamedTuple):
    """The pair table in its own rows (kept with the database): what step 1 reads in order.

    local : (S,) int64 — star-index row -> table row (-1: not in the table).
    first, second : (P,) int32 — each pair's stars as table rows.
    magnitude : (T,) float64 — the table stars' catalogue magnitudes.
    """

    local: np.ndarray
    first: np.ndarray
    second: np.ndarray
    magnitude: np.ndarray


def frame_table(frame: Frame) -> tuple[PairTable, TableRows]:
    """The pair table for ``frame`` (pairs up to its diagonal at the widest focal range) and its
    :class:`TableRows`, both kept with the database."""
    diag = frame_diagonal_rad(frame, float(frame.camera.fx))
    max_deg = math.degrees(diag) * (1.0 + frame.scale_tolerance) * 1.01
    db = frame.database
    table = pair_table(db, float(frame.camera.fov_deg), max_deg)

    def make() -> TableRows:
        local = np.full(len(frame.stars.vectors), -1, np.int64)
        local[table.stars] = np.arange(len(table.stars))
        mag = np.asarray(db.star_arrays()[1], np.float64)[table.stars]
        first, second = local[table.first].astype(np.int32), local[table.second].astype(np.int32)
        return TableRows(local, first, second, mag)

    # A table lives as long as its database, so its id names it there.
    return table, db.derived(("table-rows", id(table)), make)


@njit(cache=True)
def consistent_set(agree, order, seed, out):
    """Grow a set from centroid ``seed``: each centroid of ``order`` (best-validated first) whose
    row of ``agree`` (n, n) bool is true for every member joins. The members, in joining
    order, go to ``out``; returns their number."""
    out[0] = seed
    m = 1
    for b in order:
        if b == seed:
            continue
        ok = True
        for e in range(m):
            if not agree[b, out[e]]:
                ok = False
                break
        if ok:
            out[m] = b
            m += 1
    return m
