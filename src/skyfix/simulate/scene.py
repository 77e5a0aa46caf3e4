"""Scene: which catalogue stars are in view, where they appear, and the other light in the frame
(false stars/debris, cosmic-ray hits, sky background and stray-light gradients)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from datetime import datetime, timedelta, timezone

import numpy as np

from skyfix.catalog import Catalog, load_hipparcos
from skyfix.errors import SimulationError
from skyfix.geometry import radec_to_vector

__all__ = [
    "parse_time",
    "catalog_at",
    "field_radius",
    "candidate_stars",
    "stray_light_map",
    "false_star_list",
    "cosmic_ray_hits",
]

UTC = timezone.utc
_J2000 = datetime(2000, 1, 1, 12, 0, 0, tzinfo=UTC)


def parse_time(epoch) -> tuple[float, str]:
    """(Julian year, ISO-8601 UTC text) of ``epoch``: None (now), a Julian year (float), an ISO
    string, a ``datetime`` (naive = UTC) or an ``astropy.time.Time``."""
    if epoch is None:
        when = datetime.now(UTC)
    elif isinstance(epoch, datetime):
        when = epoch if epoch.tzinfo else epoch.replace(tzinfo=UTC)
    elif isinstance(epoch, (int, float, np.floating, np.integer)):
        jy = float(epoch)
        if not (math.isfinite(jy) and 0.0 < jy < 10000.0):
            raise SimulationError(f"epoch must be a Julian year such as 2025.5, got {epoch}")
        days = (jy - 2000.0) * 365.25
        when = _J2000 + _timedelta_days(days)
        return jy, when.isoformat(timespec="milliseconds").replace("+00:00", "Z")
    elif isinstance(epoch, str):
        try:
            when = datetime.fromisoformat(epoch.strip().replace("Z", "+00:00"))
        except ValueError:
            raise SimulationError(f"cannot read the time {epoch!r}; use ISO 8601, e.g. 2025-03-01T22:00:00Z"
                                  ) from None
        when = when if when.tzinfo else when.replace(tzinfo=UTC)
    elif hasattr(epoch, "to_datetime"):  # astropy Time
        when = epoch.to_datetime(timezone=UTC)
    else:
        raise SimulationError(f"cannot use {type(epoch).__name__} as a time")
    when = when.astimezone(UTC)
    jy = 2000.0 + (when - _J2000).total_seconds() / (365.25 * 86400.0)
    return jy, when.isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _timedelta_days(days: float) -> timedelta:
    return timedelta(days=days)


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
