"""Thesis 004's own calibration procedures (its ch. 6 and App. F), as functions: the optical
centre from a rotating camera, the focal length from a known star pair, the tilted-CCD model with
its radial lens polynomial, and §6.3's calibration statistics (docs/calibration.md#thesis-004s-procedures).

Thesis 004 had no precision target, so it solved the parameters one at a time, largest error
first, on an optical bench and on the sky:

1. **Optical centre** (§6.2.1, App. F.2): a back-lit dot imaged while the camera turns about
   its optical axis in a V-clamp; any fixed object turns about the optical centre, so the
   centre is the centre of the dot's circle (:func:`optical_centre_from_rotation`). The thesis
   took "the centre of the scatter" of 36 images at 10° steps (a 70 × 70 µm, 12 × 12 px cloud);
   with the dot off the axis the centroids draw a circle, whose centre is fitted here (for a
   dot on the axis, the fit is the cloud's mean).
2. **Focal length** (§6.2.2, ``Estf.mod``): two catalogue stars near the centre, their
   separation θ known, their positions ``(u, v)`` measured from the optical centre; squaring
   the angle between their rays gives ``a f⁴ + b f² + c = 0`` (6.4) with
   ``a = 1/cos²θ − 1``, ``b = 2(u₁u₂ + v₁v₂)/cos²θ − u₁² − v₁² − u₂² − v₂²``,
   ``c = (u₁u₂ + v₁v₂)²/cos²θ − (u₁² + v₁²)(u₂² + v₂²)``, of which only the ``+`` root is
   positive: ``f = √((−b + √(b² − 4ac)) / 2a)`` (6.5–6.6; :func:`focal_length_from_star_pair`),
   averaged over images (:func:`focal_length_from_star_pairs`). (The thesis says the other root
   is never positive; it is when ``c > 0``, e.g. for two stars on opposite sides of the centre —
   ``f₋`` is then far shorter than the stars' distances from the centre, a camera whose rays lie
   nearly in the image plane — and ``f₊`` is the focal length; ``test_calibration_bench.py`` pins
   both.)
3. **Tilt and lens** (§6.2.3, App. F.1; :class:`TiltedSensor`): a CCD tilted by ``θ_max``
   toward the azimuth ``φ_max`` (from +u toward +v) meets a ray of true radius ``r_a`` at the
   local tilt ``θ = asin(sin θ_max · cos(φ − φ_max))`` (6.14), and the lens adds
   ``Δr = k₁r + k₂r² + k₃r³`` (6.16) of the measured radius ``r``: the measured radius is
   ``r = (r_a/cos θ + Δr)/(1 − (r_a/f)·tan θ)`` (6.12; solved by iteration, as Δr depends on r)
   and the correction ``r_a = cos θ·(r − Δr)/(1 + (r/f)·sin θ)`` (6.13), applied to centroids
   along their own azimuth (6.18–6.20). Along ``φ_max`` the tilt is exact (a ray meeting a
   tilted plane); elsewhere (6.14) is the local slope, and the radius departs from a tilted
   plane's by 0.0001 µm at most at thesis 004's 0.733° over its 4.9 × 3.6 mm CCD, where the tilt
   itself moves a point by up to 4.8 µm (0.7 px; ``tests/calibration/test_calibration_bench.py``).
   The tilt is fitted on the bench (:func:`fit_tilt`: the separation ``r₁₂`` of a centre and an
   edge dot over the rotation, (6.15), least squares in ``θ_max``, ``φ_max`` and ``r_a``); the
   polynomial from star images (:func:`lens_errors`: the distances from a star near the centre
   to the others, measured against the catalogue's, (6.17); :func:`fit_lens_polynomial`).
4. **Statistics** (§6.3; :func:`distance_statistics`, :func:`magnitude_statistics`,
   :func:`calibration_statistics`): every star pair of every image, its measured angular
   distance less the catalogue's, ``σ_dist`` (thesis: 4385 pairs of 354 stars in 20 images,
   78.2 µrad = 0.34 px) and the position error ``σ_pos = σ_dist/√2`` (55.3 µrad, 11.4″); each
   star's instrumental magnitude against the catalogue's with one zero point for the camera
   (the thesis's ``k_illum``), errors beyond 1 magnitude left out as the thesis left out its two,
   ``σ_mag`` (thesis: 0.2 Mv).

Units: positions and radii in any one unit (mm as the thesis, or pixels) with ``f`` in the same;
the polynomial's ``k₂``, ``k₃`` in its inverse powers (the thesis's mm: ``k = (1e-3, −8e-5,
−4.4e-4)`` gives ``Δr = −9.6 µm`` at ``r = 3 mm``). ``(u, v)`` are measured from the optical
centre, ``v`` down the image as skyfix's ``y`` (docs/design.md#pixel-coordinates).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from skyfix.geometry import angle_between

__all__ = ["CalibrationStatistics", "DistanceStatistics", "MagnitudeStatistics", "OpticalCentre",
           "THESIS_004", "TiltedSensor", "calibration_statistics", "distance_errors", "distance_statistics",
           "fit_lens_polynomial", "fit_tilt", "focal_length_from_star_pair", "focal_length_from_star_pairs",
           "lens_errors", "magnitude_statistics", "optical_centre_from_rotation"]


class Thesis004(NamedTuple):
    """Thesis 004's calibration results (§6.2–6.3, App. F.2), to print beside skyfix's."""

    theta_max_deg: float = 0.733
    phi_max_deg: float = 306.0
    k_mm: tuple[float, float, float] = (1e-3, -8e-5, -4.4e-4)
    focal_length_mm: float = 25.0
    pixel_um: float = 6.5
    rad_per_px: float = 230e-6
    images: int = 20
    stars: int = 354
    pairs: int = 4385
    sigma_dist_rad: float = 78.2e-6
    sigma_pos_rad: float = 55.3e-6
    sigma_mag: float = 0.2


THESIS_004 = Thesis004()


# --- 1. the optical centre ------------------------------------------------------------------
class OpticalCentre(NamedTuple):
    """The optical centre ``(x, y)`` and its 1σ per axis, and the dot's circle radius, in the
    centroids' units."""

    x: float
    y: float
    sigma: float
    radius: float


def optical_centre_from_rotation(xy: np.ndarray) -> OpticalCentre:
    """The optical centre from a dot's centroids ``xy`` (N, 2) while the camera turns about its
    optical axis (module text, item 1): the centre of the least-squares circle through them
    (Kåsa's algebraic fit, then Gauss–Newton on the distances), or, when no circle explains them
    (their scatter about it over a quarter of their RMS distance from their mean: a cloud, the
    dot on the axis), their mean — the thesis's "centre of the scatter". ``sigma`` is the
    centre's 1σ per axis from the scatter about the circle, or the cloud's."""
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(p) < 3:
        raise ValueError(f"the optical centre needs at least 3 centroids, got {len(p)}")
    mean = p.mean(axis=0)
    q = p - mean
    A = np.column_stack([2 * q, np.ones(len(q))])
    (a, b, c), *_ = np.linalg.lstsq(A, (q ** 2).sum(axis=1), rcond=None)
    centre = np.array([a, b])
    radius = math.sqrt(max(c + a * a + b * b, 0.0))
    for _ in range(20):  # geometric fit: distances to the circle
        d = q - centre
        rho = np.hypot(d[:, 0], d[:, 1])
        J = np.column_stack([-d / rho[:, None], -np.ones(len(q))])
        step, *_ = np.linalg.lstsq(J, -(rho - radius), rcond=None)
        centre, radius = centre + step[:2], radius + step[2]
        if np.abs(step).max() < 1e-12:
            break
    rho = np.hypot(*(q - centre).T)
    scatter = math.sqrt(float(np.sum((rho - radius) ** 2)) / max(len(q) - 3, 1))
    spread = math.sqrt(float(np.mean(np.sum(q ** 2, axis=1))))
    if scatter > 0.25 * spread:  # no circle to speak of: the cloud's centre
        return OpticalCentre(float(mean[0]), float(mean[1]), spread / math.sqrt(2.0 * len(q)), 0.0)
    return OpticalCentre(float(mean[0] + centre[0]), float(mean[1] + centre[1]),
                         scatter * math.sqrt(2.0 / len(q)), abs(float(radius)))


# --- 2. the focal length --------------------------------------------------------------------
def focal_length_from_star_pair(uv1, uv2, theta_rad: float) -> float:
    """The focal length (the positions' unit) from two stars at ``uv1``, ``uv2`` (from the optical
    centre) whose catalogue separation is ``theta_rad``: (6.4)–(6.6). NaN when the pair admits no
    positive root (a separation the positions cannot make at any focal length)."""
    u1, v1 = (float(t) for t in uv1)
    u2, v2 = (float(t) for t in uv2)
    c2 = math.cos(theta_rad) ** 2
    dot = u1 * u2 + v1 * v2
    a = 1.0 / c2 - 1.0
    b = 2.0 * dot / c2 - u1 * u1 - v1 * v1 - u2 * u2 - v2 * v2
    c = dot * dot / c2 - u1 * u1 * u2 * u2 - u1 * u1 * v2 * v2 - v1 * v1 * u2 * u2 - v1 * v1 * v2 * v2
    disc = b * b - 4.0 * a * c
    if a <= 0 or disc < 0:
        return math.nan
    f2 = (-b + math.sqrt(disc)) / (2.0 * a)
    return math.sqrt(f2) if f2 > 0 else math.nan


def focal_length_from_star_pairs(uv1: np.ndarray, uv2: np.ndarray, theta_rad: np.ndarray
                                 ) -> tuple[float, float]:
    """The mean focal length over several images' pairs (``Estf.mod`` averages them) and its 1σ
    (the pairs' scatter over √n)."""
    f = np.array([focal_length_from_star_pair(a, b, t) for a, b, t in
                  zip(np.reshape(uv1, (-1, 2)), np.reshape(uv2, (-1, 2)), np.ravel(theta_rad), strict=True)])
    f = f[np.isfinite(f)]
    if len(f) == 0:
        return math.nan, math.nan
    return float(f.mean()), float(f.std(ddof=1) / math.sqrt(len(f))) if len(f) > 1 else math.nan


# --- 3. the tilted CCD and the lens ---------------------------------------------------------
@dataclass(frozen=True)
class TiltedSensor:
    """Thesis 004's camera model (module text, item 3): focal length ``f``, the CCD's tilt
    ``theta_max_rad`` toward ``phi_max_rad`` (from +u toward +v), and the lens polynomial
    ``k = (k₁, k₂, k₃, …)`` of ``Δr = Σ kᵢ rⁱ`` (the measured radius)."""

    f: float
    theta_max_rad: float = 0.0
    phi_max_rad: float = 0.0
    k: tuple[float, ...] = ()

    def tilt(self, phi: np.ndarray) -> np.ndarray:
        """The local tilt θ at azimuth ``phi`` (6.14)."""
        return np.arcsin(math.sin(self.theta_max_rad) * np.cos(np.asarray(phi) - self.phi_max_rad))

    def lens(self, r: np.ndarray) -> np.ndarray:
        """Δr_lens at the measured radius ``r`` (6.16)."""
        r = np.asarray(r, dtype=np.float64)
        return sum((ki * r ** (i + 1) for i, ki in enumerate(self.k)), np.zeros_like(r))

    def measured_radius(self, r_a: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """The measured radius of a point of true radius ``r_a`` at azimuth ``phi`` (6.12), by
        fixed-point iteration on Δr(r) (at most 50 steps; 1e-12 of the radius)."""
        r_a = np.asarray(r_a, dtype=np.float64)
        th = self.tilt(phi)
        base, div = r_a / np.cos(th), 1.0 - r_a / self.f * np.tan(th)
        r = base / div
        tolerance = 1e-12 * max(float(np.max(np.abs(r), initial=0.0)), 1.0)
        for _ in range(50):
            r_new = (base + self.lens(r)) / div
            done = np.max(np.abs(r_new - r), initial=0.0) <= tolerance
            r = r_new
            if done:
                break
        return r

    def true_radius(self, r: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """The true radius of a point measured at radius ``r``, azimuth ``phi`` (6.13)."""
        r = np.asarray(r, dtype=np.float64)
        th = self.tilt(phi)
        return np.cos(th) * (r - self.lens(r)) / (1.0 + r / self.f * np.sin(th))

    def correct(self, uv: np.ndarray) -> np.ndarray:
        """Measured centroids ``uv`` (N, 2, from the optical centre) to true ones (6.18–6.20)."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        phi = np.arctan2(uv[:, 1], uv[:, 0])
        r_a = self.true_radius(np.hypot(uv[:, 0], uv[:, 1]), phi)
        return np.column_stack([r_a * np.cos(phi), r_a * np.sin(phi)])

    def distort(self, uv_a: np.ndarray) -> np.ndarray:
        """True positions ``uv_a`` (N, 2) to measured ones (6.12), for simulation."""
        uv_a = np.asarray(uv_a, dtype=np.float64).reshape(-1, 2)
        phi = np.arctan2(uv_a[:, 1], uv_a[:, 0])
        r = self.measured_radius(np.hypot(uv_a[:, 0], uv_a[:, 1]), phi)
        return np.column_stack([r * np.cos(phi), r * np.sin(phi)])


def fit_tilt(phi: np.ndarray, r12: np.ndarray, f: float) -> tuple[float, float, float]:
    """The tilt ``(θ_max, φ_max, r_a)`` (rad, rad, the radii's unit) that fits the separations
    ``r12`` of a centre and an edge dot measured at the edge dot's azimuths ``phi`` over a turn
    of the camera (6.15), by least squares (``scipy.optimize.least_squares``), started from the
    separations' first harmonic (a tilt stretches the radius most toward ``φ_max``)."""
    from scipy.optimize import least_squares

    phi = np.asarray(phi, dtype=np.float64)
    r12 = np.asarray(r12, dtype=np.float64)
    mean = float(r12.mean())
    c1 = 2.0 * float(np.mean(r12 * np.cos(phi)))
    s1 = 2.0 * float(np.mean(r12 * np.sin(phi)))
    # (6.15) to first order in θ: r₁₂ ≈ r_a (1 + (r_a/f) θ_max cos(φ − φ_max))
    theta0 = max(math.hypot(c1, s1) * f / mean ** 2, 1e-6)
    start = np.array([theta0, math.atan2(s1, c1), mean])

    def residuals(p):
        return TiltedSensor(f, p[0], p[1]).measured_radius(np.full_like(phi, p[2]), phi) - r12

    fit = least_squares(residuals, start, x_scale=[1e-3, 0.1, mean], xtol=1e-14, ftol=1e-14, gtol=1e-14)
    theta, phi_max, r_a = fit.x
    if theta < 0:
        theta, phi_max = -theta, phi_max + math.pi
    return float(theta), float(phi_max % (2 * math.pi)), float(r_a)


def lens_errors(uv_centre, uv: np.ndarray, r_centre: np.ndarray, r_icrs: np.ndarray, f: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """Thesis 004's lens data (6.17) from one image: the star nearest the optical centre at
    ``uv_centre`` (catalogue direction ``r_centre``) and the others at ``uv`` (N, 2; ``r_icrs``
    (N, 3)), positions from the optical centre after the tilt's correction. Each measured
    distance from the centre star, and the catalogue's, are angles turned into radii on the CCD
    (``f·tan``): returns ``(r, Δr = r − r_a)``."""
    rays = np.column_stack([np.asarray(uv, dtype=np.float64).reshape(-1, 2), np.full(len(uv), float(f))])
    centre = np.array([float(uv_centre[0]), float(uv_centre[1]), float(f)])
    measured = angle_between(rays, centre[None, :])
    catalogue = angle_between(np.asarray(r_icrs, dtype=np.float64).reshape(-1, 3),
                              np.asarray(r_centre, dtype=np.float64)[None, :])
    r = f * np.tan(measured)
    return r, r - f * np.tan(catalogue)


def fit_lens_polynomial(r: np.ndarray, dr: np.ndarray, order: int = 3) -> np.ndarray:
    """The lens polynomial's ``(k₁ … k_order)`` of ``Δr = Σ kᵢ rⁱ`` (6.16) by least squares
    (no constant: the centre is not moved)."""
    r = np.asarray(r, dtype=np.float64)
    M = np.column_stack([r ** (i + 1) for i in range(order)])
    k, *_ = np.linalg.lstsq(M, np.asarray(dr, dtype=np.float64), rcond=None)
    return k


# --- 4. the statistics ----------------------------------------------------------------------
class DistanceStatistics(NamedTuple):
    """§6.3's distance statistics: ``sigma_dist_rad`` of the pairs' errors, ``sigma_pos_rad`` =
    σ_dist/√2, and the counts."""

    sigma_dist_rad: float
    sigma_pos_rad: float
    mean_rad: float
    images: int
    stars: int
    pairs: int


class MagnitudeStatistics(NamedTuple):
    """§6.3's magnitude statistics: ``sigma_mag`` of the stars' errors within ``clip`` of the
    zero point (``left_out`` beyond), the zero point, the counts."""

    sigma_mag: float
    zero_point: float
    stars: int
    left_out: int


class CalibrationStatistics(NamedTuple):
    distances: DistanceStatistics
    magnitudes: MagnitudeStatistics | None


def distance_errors(b_measured: np.ndarray, b_catalogue: np.ndarray) -> np.ndarray:
    """Every pair's measured angular distance less its catalogue distance (6.21), rad, for one
    image's stars: measured rays (N, 3) and the catalogue's unit vectors (N, 3, any frame)."""
    bm = np.asarray(b_measured, dtype=np.float64).reshape(-1, 3)
    bc = np.asarray(b_catalogue, dtype=np.float64).reshape(-1, 3)
    i, j = np.triu_indices(len(bm), k=1)
    return angle_between(bm[i], bm[j]) - angle_between(bc[i], bc[j])


def distance_statistics(images: list[tuple[np.ndarray, np.ndarray]]) -> DistanceStatistics:
    """:func:`distance_errors` over images ``[(b_measured, b_catalogue), …]``: σ_dist (6.22),
    σ_pos = σ_dist/√2 (6.23), the mean, and the counts."""
    errors = [distance_errors(bm, bc) for bm, bc in images]
    e = np.concatenate(errors) if errors else np.empty(0)
    s = float(np.std(e, ddof=1)) if len(e) > 1 else math.nan
    return DistanceStatistics(s, s / math.sqrt(2.0), float(np.mean(e)) if len(e) else math.nan, len(images),
                              int(sum(len(bm) for bm, _ in images)), len(e))


def magnitude_statistics(flux: np.ndarray, mag: np.ndarray, clip: float = 1.0) -> MagnitudeStatistics:
    """Instrumental magnitudes ``−2.5 log₁₀ flux`` against catalogue magnitudes ``mag`` with one
    zero point (the median difference, then the mean of those within ``clip``), errors beyond
    ``clip`` magnitudes left out (6.25–6.26)."""
    from skyfix.analysis.photometry import instrumental_magnitude

    m = instrumental_magnitude(np.asarray(flux, dtype=np.float64))
    cat = np.asarray(mag, dtype=np.float64)
    ok = np.isfinite(m) & np.isfinite(cat)
    d = cat[ok] - m[ok]
    if len(d) < 2:
        return MagnitudeStatistics(math.nan, math.nan, int(len(d)), 0)
    zp = float(np.median(d))
    keep = np.abs(d - zp) <= clip
    zp = float(np.mean(d[keep]))
    err = d[keep] - zp
    return MagnitudeStatistics(float(np.std(err, ddof=1)), zp, int(keep.sum()), int((~keep).sum()))


def calibration_statistics(fit) -> CalibrationStatistics:
    """§6.3's statistics of a joint fit's stars (a :class:`~skyfix.calibration.joint.JointFit`,
    e.g. ``calibrate_stars(...).fit``; its inliers): the measured rays through its camera, the
    catalogue's where the camera and attitude put them (the measured pixel plus its residual),
    and the magnitudes when the fit carries the stars' fluxes and catalogue magnitudes."""
    cam = fit.camera
    images = []
    fluxes, mags = [], []
    for i, (xy, res, keep) in enumerate(zip(fit.xy, fit.residuals_px, fit.inliers, strict=True)):
        images.append((cam.pixel_to_ray(xy[keep]), cam.pixel_to_ray(xy[keep] + res[keep])))
        if i < len(fit.flux) and fit.flux[i] is not None and fit.mag[i] is not None:
            fluxes.append(np.asarray(fit.flux[i])[keep])
            mags.append(np.asarray(fit.mag[i])[keep])
    magnitudes = magnitude_statistics(np.concatenate(fluxes), np.concatenate(mags)) if fluxes else None
    return CalibrationStatistics(distance_statistics(images), magnitudes)
