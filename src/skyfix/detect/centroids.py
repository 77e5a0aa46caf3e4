"""Centroids: the star list one extraction returns, as parallel arrays, brightest first."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from skyfix._jit import njit

__all__ = ["Centroids", "background_snr"]

_ARRAYS = ("x", "y", "flux", "area", "snr", "elongation", "peak", "sigma_x", "sigma_y")


@dataclass(frozen=True)
class Centroids:
    """Stars found in one frame, sorted by flux, brightest first.

    Pixel convention (docs/design.md#pixel-coordinates): ``(x, y)`` = (column, row), 0-based,
    ``(0, 0)`` is the centre of the top-left pixel.

    Attributes
    ----------
    x, y : (N,) float64 — centroid, pixels.
    flux : (N,) float64 — background-subtracted sum over the star's pixels, ADU.
    area : (N,) float64 — number of pixels in the star's footprint.
    snr : (N,) float64 — ``flux / (noise·sqrt(area))`` (background-limited; shot noise of the
        star itself is not included because the gain is unknown; :func:`background_snr`).
    elongation : (N,) float64 — ratio of the long to the short axis from the intensity
        second moments (1 = round).
    peak : (N,) float64 — highest background-subtracted pixel, ADU.
    sigma_x, sigma_y : (N,) float64 — 1-σ centroid uncertainty from background noise, pixels.
    saturated : (N,) bool — the star has pixels at the saturation level.
    cov_xy : (N,) float64 — x–y covariance of the centroid, px² (zero unless a fit gives it).
    angle : (N,) float64 — direction of the long axis from +x toward +y, radians in (−π/2, π/2]
        (a streak's direction; meaningless for round stars).
    image_shape : (height, width) of the frame.
    background_level : median sky level of the frame, ADU.
    noise : robust per-pixel noise (σ) of the sky, ADU.
    """

    x: np.ndarray
    y: np.ndarray
    flux: np.ndarray
    area: np.ndarray
    snr: np.ndarray
    elongation: np.ndarray
    peak: np.ndarray
    sigma_x: np.ndarray
    sigma_y: np.ndarray
    saturated: np.ndarray
    image_shape: tuple[int, int] = (0, 0)
    background_level: float = 0.0
    noise: float = 0.0
    meta: dict = field(default_factory=dict, compare=False, repr=False)
    cov_xy: np.ndarray | None = None
    angle: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = None
        for name in _ARRAYS:
            arr = np.ascontiguousarray(getattr(self, name), dtype=np.float64).reshape(-1)
            object.__setattr__(self, name, arr)
            if n is None:
                n = arr.size
            elif arr.size != n:
                raise ValueError(f"Centroids.{name} has {arr.size} entries, expected {n}")
        sat = np.ascontiguousarray(self.saturated, dtype=bool).reshape(-1)
        if sat.size != n:
            raise ValueError(f"Centroids.saturated has {sat.size} entries, expected {n}")
        object.__setattr__(self, "saturated", sat)
        cov = np.zeros(n) if self.cov_xy is None else np.ascontiguousarray(self.cov_xy, np.float64)
        cov = cov.reshape(-1)
        if cov.size != n:
            raise ValueError(f"Centroids.cov_xy has {cov.size} entries, expected {n}")
        object.__setattr__(self, "cov_xy", cov)
        ang = np.zeros(n) if self.angle is None else np.ascontiguousarray(self.angle, np.float64).reshape(-1)
        if ang.size != n:
            raise ValueError(f"Centroids.angle has {ang.size} entries, expected {n}")
        object.__setattr__(self, "angle", ang)
        object.__setattr__(self, "image_shape", (int(self.image_shape[0]), int(self.image_shape[1])))
        object.__setattr__(self, "background_level", float(self.background_level))
        object.__setattr__(self, "noise", float(self.noise))

    def __len__(self) -> int:
        return int(self.x.size)

    @property
    def xy(self) -> np.ndarray:
        """(N, 2) float64 array of ``(x, y)`` pixel positions."""
        return np.column_stack([self.x, self.y])

    @property
    def covariance(self) -> np.ndarray:
        """(N, 2, 2) centroid covariance matrices, px²."""
        cov = np.zeros((len(self), 2, 2))
        cov[:, 0, 0] = self.sigma_x**2
        cov[:, 1, 1] = self.sigma_y**2
        cov[:, 0, 1] = cov[:, 1, 0] = self.cov_xy
        return cov

    @property
    def flags(self) -> np.ndarray:
        """Alias of ``saturated`` (the only flag so far)."""
        return self.saturated

    @classmethod
    def empty(cls, image_shape: tuple[int, int] = (0, 0), background_level: float = 0.0,
              noise: float = 0.0, **meta: object) -> Centroids:
        """A list with no stars (for blank, constant or unusable frames)."""
        z = np.zeros(0)
        return cls(*(z for _ in _ARRAYS), saturated=np.zeros(0, bool), image_shape=image_shape,
                   background_level=background_level, noise=noise, meta=dict(meta))

    def subset(self, index: np.ndarray | slice) -> Centroids:
        """The stars selected by an index array, boolean mask or slice (order as given)."""
        kw = {name: getattr(self, name)[index] for name in _ARRAYS}
        return Centroids(**kw, saturated=self.saturated[index], image_shape=self.image_shape,
                         background_level=self.background_level, noise=self.noise, meta=self.meta,
                         cov_xy=self.cov_xy[index], angle=self.angle[index])

    def brightest(self, n: int) -> Centroids:
        """The ``n`` brightest stars."""
        return self.subset(slice(0, max(int(n), 0)))

    def to_records(self) -> list[dict]:
        """One dict per star, brightest first (for JSON output)."""
        cols = {name: getattr(self, name).tolist() for name in (*_ARRAYS, "cov_xy", "angle")}
        sat = self.saturated.tolist()
        return [{**{k: v[i] for k, v in cols.items()}, "saturated": sat[i]} for i in range(len(self))]


@njit(cache=True, inline="always")
def background_snr(flux, noise, area):
    """``flux / (noise·√area)``: the SNR of a star whose noise is the sky's alone.

    ``area`` (pixels) counts as at least 1 and the denominator as at least 1e-30. Scalars or
    arrays (broadcast); every detector's :attr:`Centroids.snr` is this.
    """
    return flux / np.maximum(noise * np.sqrt(np.maximum(area, 1.0)), 1e-30)
