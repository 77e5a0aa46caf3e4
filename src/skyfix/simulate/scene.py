"""Scene: which catalogue stars are in view, where they appear, and the other light in the frame
(false stars/debris, cosmic-ray hits, sky background and stray-light gradients)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from datetime import datetime, timezone

import numpy as np

from skyfix.catalog import Catalog, load_hipparcos
from skyfix.errors import InputError, SimulationError
from skyfix.geometry import radec_to_vector

__all__ = [
    "simulation_time",
    "catalog_at",
    "field_radius",
    "candidate_stars",
    "stray_light_map",
    "false_star_list",
    "cosmic_ray_hits",
]

UTC = timezone.utc


def simulation_time(epoch) -> tuple[float, str]:
    """(Julian year, ISO 8601 UTC text) of a simulation's ``epoch``: None for now, else any time
    :func:`skyfix.obstime.parse_time` reads (ISO text, ``J2026.25``, a Julian year as a number,
    a ``datetime``, an ``astropy.time.Time``); a Julian year is TT, as everywhere in skyfix.
    Raises :class:`~skyfix.errors.SimulationError` for anything else."""
    from skyfix.obstime import julian_year, parse_time

    try:
        t = parse_time(datetime.now(UTC) if epoch is None else epoch, source="epoch=")
    except InputError as exc:
        raise SimulationError(str(exc)) from None
    return julian_year(t), t.iso


_CATALOG_CACHE: dict[tuple, Catalog] = {}


def catalog_at(epoch_jyear: float, mag_limit: float | None = None) -> Catalog:
    """Hipparcos propagated to ``epoch_jyear`` (cached per ~9 h and magnitude limit)."""
    key = (round(epoch_jyear, 3), mag_limit)
    cat = _CATALOG_CACHE.get(key)
    if cat is None:
        if len(_CATALOG_CACHE) > 4:
            _CATALOG_CACHE.clear()
        cat = load_hipparcos(epoch=round(epoch_jyear, 3), mag_limit=mag_limit)
        _CATALOG_CACHE[key] = cat
    return cat


def field_radius(camera) -> float:
    """Largest angle between the boresight and a ray through the frame's edge, radians."""
    w, h = camera.width, camera.height
    xs = np.linspace(-0.5, w - 0.5, 9)
    ys = np.linspace(-0.5, h - 0.5, 9)
    border = np.concatenate([np.stack([xs, np.full(9, -0.5)], -1), np.stack([xs, np.full(9, h - 0.5)], -1),
                             np.stack([np.full(9, -0.5), ys], -1), np.stack([np.full(9, w - 0.5), ys], -1)])
    rays = camera.pixel_to_ray(border)
    if not np.isfinite(rays).all():  # a fisheye whose polynomial does not reach the edge: it sees all round
        return math.pi
    return float(np.max(np.arccos(np.clip(rays[:, 2], -1.0, 1.0))))


def candidate_stars(A_icrs_to_cam: np.ndarray, camera, catalog: Catalog, extra_rad: float) -> np.ndarray:
    """Indices of catalogue stars within the field radius + ``extra_rad`` of the boresight."""
    radius = min(field_radius(camera) + extra_rad, math.pi)
    return catalog.cone(np.asarray(A_icrs_to_cam)[2], radius)


def stray_light_map(spec: Mapping, camera, A_icrs_to_cam: np.ndarray, exposure_s: float) -> np.ndarray:
    """A smooth stray-light image (electrons per pixel) from ``spec``.

    ``spec`` keys: ``level_e_s`` (electrons s⁻¹ px⁻¹ at the frame centre, required),
    ``gradient`` (fractional increase from the centre to the frame corner toward the source,
    default 1), and the source direction as either ``angle_deg`` (in the image, 0 = +x,
    90 = +y) or ``source_ra_deg`` + ``source_dec_deg`` (a Sun/Moon/Earth-limb direction,
    projected into the image plane).
    """
    known = {"level_e_s", "gradient", "angle_deg", "source_ra_deg", "source_dec_deg"}
    unknown = set(spec) - known
    if unknown or "level_e_s" not in spec:
        raise SimulationError(f"stray_light needs level_e_s (and optionally {', '.join(sorted(known))})")
    level = float(spec["level_e_s"])
    grad = float(spec.get("gradient", 1.0))
    if "source_ra_deg" in spec:
        s = radec_to_vector(math.radians(float(spec["source_ra_deg"])),
                            math.radians(float(spec.get("source_dec_deg", 0.0))))
        b = np.asarray(A_icrs_to_cam) @ s
        angle = math.atan2(b[1], b[0]) if math.hypot(b[0], b[1]) > 1e-12 else 0.0
    else:
        angle = math.radians(float(spec.get("angle_deg", 0.0)))
    h, w = camera.height, camera.width
    half_diag = 0.5 * math.hypot(w, h)
    x = (np.arange(w) - camera.cx) * math.cos(angle) / half_diag
    y = (np.arange(h) - camera.cy) * math.sin(angle) / half_diag
    ramp = 1.0 + grad * (y[:, None] + x[None, :])
    return np.clip(ramp, 0.0, None) * (level * exposure_s)


def false_star_list(n: int, camera, rng: np.random.Generator, mag_range: tuple[float, float]
                    ) -> tuple[np.ndarray, np.ndarray]:
    """``n`` false stars/debris: pixel positions (n, 2) uniform in the frame and magnitudes
    uniform in ``mag_range``."""
    xy = np.stack([rng.uniform(-0.5, camera.width - 0.5, n), rng.uniform(-0.5, camera.height - 0.5, n)], -1)
    mag = rng.uniform(mag_range[0], mag_range[1], n)
    return xy, mag


def cosmic_ray_hits(n: int, shape: tuple[int, int], rng: np.random.Generator,
                    mean_length_px: float = 4.0, electrons_per_px: float = 1500.0
                    ) -> tuple[np.ndarray, list[dict]]:
    """Charge image (electrons) of ``n`` cosmic-ray tracks and their truth records.

    Each track is a straight segment with a random start, direction and exponential length,
    depositing charge along its path (sharp: no optics PSF).
    """
    h, w = shape
    img = np.zeros(shape, dtype=np.float32)
    records = []
    for _ in range(int(n)):  # a handful per frame
        x0, y0 = rng.uniform(-0.5, w - 0.5), rng.uniform(-0.5, h - 0.5)
        length = rng.exponential(mean_length_px)
        ang = rng.uniform(0, 2 * np.pi)
        x1, y1 = x0 + length * math.cos(ang), y0 + length * math.sin(ang)
        total = electrons_per_px * max(length, 1.0) * rng.uniform(0.5, 1.5)
        m = max(2, int(math.ceil(length * 4)))
        t = (np.arange(m) + 0.5) / m
        cols = np.rint(x0 + t * (x1 - x0)).astype(int)
        rows = np.rint(y0 + t * (y1 - y0)).astype(int)
        ok = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
        np.add.at(img, (rows[ok], cols[ok]), np.float32(total / m))
        records.append(dict(x0=float(x0), y0=float(y0), x1=float(x1), y1=float(y1), electrons=float(total)))
    return img, records
