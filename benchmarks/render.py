"""A small star-field renderer, independent of ``skyfix.simulate``, for the accuracy suite (c).

Only the Hipparcos star list comes from skyfix (positions at the observation epoch); projection,
PSF and sensor are written here from scratch so an error in skyfix's simulator or camera model
cannot agree with itself. Model:

- pinhole camera, square pixels, principal point at the image centre ((w-1)/2, (h-1)/2), (x, y)
  = (column, row) with (0, 0) the centre of the top-left pixel; camera +x along columns,
  +y along rows, +z the boresight; ``b = A r``.
- Gaussian PSF integrated exactly over each pixel (a product of erf differences).
- signal and sky background with Poisson noise, Gaussian read noise, a bias, 12-bit ADC
  with saturation at 4095, hot pixels, and a few false stars (same PSF, random places).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import erf


@dataclass(frozen=True)
class RenderSpec:
    width: int = 1280
    height: int = 960
    fov_deg: float = 15.0
    psf_sigma_px: float = 1.0
    mag_limit: float = 9.0
    zero_point_e: float = 2.0e6  # electrons from a magnitude-0 star in one exposure
    sky_e: float = 30.0  # sky background electrons per pixel
    read_noise_e: float = 5.0
    gain_e_per_adu: float = 1.0
    bias_adu: float = 100.0
    n_hot: int = 40
    n_false: int = 3

    @property
    def focal_px(self) -> float:
        return (self.width / 2.0) / np.tan(np.radians(self.fov_deg) / 2.0)


class StarSky:
    """Hipparcos unit vectors and magnitudes with a k-d tree for cone queries."""

    def __init__(self, mag_limit: float, epoch: float | None = None):
        from skyfix.catalog import load_hipparcos

        cat = load_hipparcos(epoch=epoch, mag_limit=mag_limit)
        self.vectors = np.asarray(cat.vectors, float)
        self.mag = np.asarray(cat.mag, float)
        self.tree = cKDTree(self.vectors)

    def in_view(self, A: np.ndarray, spec: RenderSpec) -> tuple[np.ndarray, np.ndarray]:
        """Pixel positions (N, 2) and magnitudes (N,) of the stars that land in (or near) the frame."""
        f = spec.focal_px
        half_diag = np.arctan(np.hypot(spec.width, spec.height) / 2.0 / f)
        idx = np.asarray(self.tree.query_ball_point(A[2], 2 * np.sin(half_diag / 2) * 1.02), int)
        b = self.vectors[idx] @ A.T
        front = b[:, 2] > 0
        b, mag = b[front], self.mag[idx][front]
        x = f * b[:, 0] / b[:, 2] + (spec.width - 1) / 2.0
        y = f * b[:, 1] / b[:, 2] + (spec.height - 1) / 2.0
        m = 5 * spec.psf_sigma_px
        keep = (x > -m) & (x < spec.width - 1 + m) & (y > -m) & (y < spec.height - 1 + m)
        return np.column_stack([x[keep], y[keep]]), mag[keep]


def add_gaussian_stars(img: np.ndarray, xy: np.ndarray, flux: np.ndarray, sigma: float) -> None:
    """Add pixel-integrated Gaussian spots of total ``flux`` (electrons) at ``xy``, in place."""
    if len(xy) == 0:
        return
    h, w = img.shape
    r = int(np.ceil(5 * sigma))
    offs = np.arange(-r, r + 1)
    x0 = np.round(xy[:, 0]).astype(int)
    y0 = np.round(xy[:, 1]).astype(int)
    px = x0[:, None] + offs[None, :]  # (N, K) pixel columns
    py = y0[:, None] + offs[None, :]
    s = sigma * np.sqrt(2.0)
    # Fraction of the PSF inside each pixel [p - 1/2, p + 1/2] along each axis.
    fx = 0.5 * (erf((px + 0.5 - xy[:, :1]) / s) - erf((px - 0.5 - xy[:, :1]) / s))
    fy = 0.5 * (erf((py + 0.5 - xy[:, 1:]) / s) - erf((py - 0.5 - xy[:, 1:]) / s))
    val = flux[:, None, None] * fy[:, :, None] * fx[:, None, :]  # (N, K, K) rows × cols
    PY = np.broadcast_to(py[:, :, None], val.shape)
    PX = np.broadcast_to(px[:, None, :], val.shape)
    ok = (PX >= 0) & (PX < w) & (PY >= 0) & (PY < h)
    np.add.at(img, (PY[ok], PX[ok]), val[ok])


def render(A: np.ndarray, sky: StarSky, spec: RenderSpec, rng: np.random.Generator) -> np.ndarray:
    """A 12-bit (uint16, 0–4095) frame of the sky seen at attitude ``A`` (``A_icrs_to_cam``)."""
    xy, mag = sky.in_view(A, spec)
    electrons = np.zeros((spec.height, spec.width), float)
    add_gaussian_stars(electrons, xy, spec.zero_point_e * 10.0 ** (-0.4 * mag), spec.psf_sigma_px)
    if spec.n_false:
        fxy = np.column_stack([rng.uniform(0, spec.width - 1, spec.n_false),
                               rng.uniform(0, spec.height - 1, spec.n_false)])
        fmag = rng.uniform(4.0, 7.0, spec.n_false)
        add_gaussian_stars(electrons, fxy, spec.zero_point_e * 10.0 ** (-0.4 * fmag), spec.psf_sigma_px)
    electrons = rng.poisson(electrons + spec.sky_e).astype(float)
    electrons += rng.normal(0.0, spec.read_noise_e, electrons.shape)
    adu = electrons / spec.gain_e_per_adu + spec.bias_adu
    hot = rng.integers(0, spec.width * spec.height, spec.n_hot)
    adu.flat[hot] += rng.uniform(300.0, 4000.0, spec.n_hot)
    return np.clip(np.round(adu), 0, 4095).astype(np.uint16)


def random_attitudes(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` attitudes uniformly distributed over rotations, (n, 3, 3)."""
    from scipy.spatial.transform import Rotation

    return Rotation.random(n, random_state=int(rng.integers(2**31))).as_matrix()
