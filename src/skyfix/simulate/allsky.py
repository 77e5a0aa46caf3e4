"""All-sky frames: a fisheye camera looking up from a site, its image circle, the horizon with a
ragged skyline of hills and trees (dark, or lit and textured) and a town's light dome.

:func:`render_allsky` renders one through :func:`skyfix.simulate.render` (its ``foreground``
step) and adds to the truth what an all-sky solve is judged on: the zenith's pixel and the image
circle. The scene:

- the camera (:func:`all_sky_camera`): a Kannala–Brandt fisheye (all ``k = 0``: equidistant)
  whose image circle, ``θ ≤ θ_max`` off the boresight, is centred near the frame's centre and
  fills most of its short side; outside the circle the lens passes no light (black corners);
- the attitude (:func:`zenith_attitude`): the boresight a few degrees from the site's zenith, any
  roll;
- the landscape (:class:`Landscape`, :func:`random_landscape`): below the skyline's altitude at
  each azimuth the sky is hidden (no star, no sky light); an obstruction is dark (a share of the
  zenith's sky brightness) or lit (brighter than the sky, with a blotchy texture of a few pixels,
  as floodlit trees and buildings); the light dome brightens the sky toward one azimuth,
  falling off with altitude.

Refraction and extinction are not rendered: stars are where the catalogue puts them (solve such a
frame with ``refraction="none"`` at its site).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skyfix._kernels import lens
from skyfix.camera import Camera
from skyfix.corrections.observation import observe
from skyfix.simulate.optics import Optics
from skyfix.simulate.render import SimulatedFrame, render

__all__ = ["ALLSKY_OPTICS", "Landscape", "all_sky_camera", "random_landscape", "render_allsky",
           "zenith_attitude"]

#: The optics of a small all-sky camera: a 1.6 mm f/2 fisheye (0.8 mm pupil), stars ~2 px wide.
ALLSKY_OPTICS = Optics(aperture_mm=0.8, throughput=0.8, psf_fwhm_px=2.2)


class Landscape(NamedTuple):
    """What surrounds the sky of an all-sky frame.

    skyline_deg : (360,) the altitude of the skyline at each whole degree of azimuth (north 0,
        east 90), degrees: the horizon's hills and the trees and buildings on them.
    lit : (360,) bool — the obstruction at that azimuth is lit (brighter than the sky, textured);
        else dark.
    dome_az_deg : the azimuth of a town's light dome.
    dome_gain : the sky's brightness at the horizon below the dome, as a multiple of the zenith's
        (1 + gain; falling off as exp(−alt / 15°) and with azimuth as cos²).
    dark_share : a dark obstruction's brightness, a share of the zenith sky's.
    lit_gain : a lit obstruction's mean brightness, a multiple of the zenith sky's.
    """

    skyline_deg: np.ndarray
    lit: np.ndarray
    dome_az_deg: float
    dome_gain: float
    dark_share: float = 0.05
    lit_gain: float = 4.0


def random_landscape(rng: np.random.Generator) -> Landscape:
    """A random landscape: hills 0–4° high, one to three groups of trees or buildings 10–60°
    wide and 8–30° high (half of the frames have one of them lit), and a light dome of 1–6 times
    the zenith's sky brightness at the horizon."""
    az = np.arange(360.0)
    phases = rng.uniform(0, 2 * np.pi, 3)
    hills = sum(np.cos(np.radians(az) * n + p) for n, p in zip((2, 5, 11), phases, strict=True))
    skyline = rng.uniform(0.0, 2.0) * (1.0 + hills / 3.0)
    lit = np.zeros(360, dtype=bool)
    n_groups = int(rng.integers(1, 4))
    lit_group = int(rng.integers(0, n_groups)) if rng.random() < 0.5 else -1
    for g in range(n_groups):
        centre, width, height = rng.uniform(0, 360), rng.uniform(10, 60), rng.uniform(8, 30)
        off = (az - centre + 180.0) % 360.0 - 180.0
        inside = np.abs(off) < width / 2
        crowns = height * (0.7 + 0.3 * rng.random(360))  # ragged crowns, 1° apart
        skyline = np.where(inside, np.maximum(skyline, crowns), skyline)
        if g == lit_group:
            lit |= inside
    return Landscape(np.clip(skyline, 0.0, None), lit, float(rng.uniform(0, 360)), float(rng.uniform(1, 6)))


def all_sky_camera(width: int, height: int, fov_deg: float = 180.0, *, fill: float = 0.96,
                   offset_px: tuple[float, float] = (0.0, 0.0), k: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0),
                   ) -> Camera:
    """A Kannala–Brandt fisheye (``k``: k1..k4; all 0, equidistant) whose image circle — the
    lens's ``fov_deg`` across — is ``fill`` of the frame's short side wide, centred ``offset_px``
    from the frame's centre."""
    numbers = np.zeros(len(lens.CAMERA_NUMBERS))
    numbers[[lens.K1, lens.K2, lens.K3, lens.K4]] = (tuple(k) + (0.0,) * 4)[:4]
    radius = fill * min(width, height) / 2.0
    f = radius / lens.kb_theta_d(math.radians(fov_deg) / 2.0, numbers)[0]
    ks = dict(zip(("k1", "k2", "k3", "k4"), numbers[[lens.K1, lens.K2, lens.K3, lens.K4]], strict=True))
    return Camera(width=int(width), height=int(height), fx=f, fy=f, cx=(width - 1) / 2.0 + offset_px[0],
                  cy=(height - 1) / 2.0 + offset_px[1], projection="kannala-brandt",
                  **{key: float(v) for key, v in ks.items()})


def zenith_attitude(A_icrs_to_enu: np.ndarray, tilt_deg: float, tilt_az_deg: float, roll_deg: float
                    ) -> np.ndarray:
    """``A_icrs_to_cam`` of a camera whose boresight is ``tilt_deg`` from the zenith toward the
    azimuth ``tilt_az_deg``, turned by ``roll_deg`` about it."""
    t, a = math.radians(tilt_deg), math.radians(tilt_az_deg)
    z = np.array([math.sin(t) * math.sin(a), math.sin(t) * math.cos(a), math.cos(t)])  # ENU
    north = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x0 = np.cross(north, z)
    x0 /= np.linalg.norm(x0)
    y0 = np.cross(z, x0)
    r = math.radians(roll_deg)
    x = math.cos(r) * x0 + math.sin(r) * y0
    y = np.cross(z, x)
    return np.array([x, y, z]) @ np.asarray(A_icrs_to_enu)


def _foreground(landscape: Landscape, A_icrs_to_enu: np.ndarray, theta_max: float, seed: int):
    """The ``foreground`` step of :func:`skyfix.simulate.render` for ``landscape``."""

    def apply(expected: np.ndarray, camera: Camera, A: np.ndarray, exposure_s: float) -> np.ndarray:
        h, w = expected.shape
        yy, xx = np.mgrid[0:h, 0:w]
        rays = camera.pixel_to_ray(np.stack([xx.ravel(), yy.ravel()], axis=1).astype(np.float64))
        theta = np.arccos(np.clip(rays[:, 2], -1.0, 1.0)).reshape(h, w)
        enu = rays @ (A @ np.asarray(A_icrs_to_enu).T)  # camera ray → ENU: (A_enu_to_cam)ᵀ
        alt = np.degrees(np.arcsin(np.clip(enu[:, 2], -1.0, 1.0))).reshape(h, w)
        az = (np.degrees(np.arctan2(enu[:, 0], enu[:, 1])) % 360.0).reshape(h, w)
        circle = np.isfinite(theta) & (theta <= theta_max)
        cell = np.nan_to_num(az).astype(np.int64) % 360
        hidden = circle & (alt < landscape.skyline_deg[cell])
        sky = circle & ~hidden
        level = float(np.median(expected[sky]))  # the zenith's sky (stars are a few pixels)
        off = np.radians(az - landscape.dome_az_deg)
        dome = landscape.dome_gain * np.exp(-np.clip(alt, 0, None) / 15.0) * np.maximum(np.cos(off), 0.0) ** 2
        out = np.where(sky, expected + level * dome, 0.0)
        rng = np.random.default_rng(seed)
        texture = rng.lognormal(0.0, 0.6, ((h + 3) // 4, (w + 3) // 4)).repeat(4, 0).repeat(4, 1)[:h, :w]
        lit = hidden & landscape.lit[cell]
        out = np.where(lit, level * landscape.lit_gain * texture, out)
        out = np.where(hidden & ~lit, level * landscape.dark_share, out)
        return out.astype(np.float32)

    return apply


def render_allsky(camera: Camera, *, site: tuple[float, float], time: str, landscape: Landscape,
                  fov_deg: float = 180.0, tilt_deg: float = 0.0, tilt_az_deg: float = 0.0,
                  roll_deg: float = 0.0, seed: int = 0, exposure_s: float = 10.0,
                  sky_mag_arcsec2: float = 20.5, optics: Optics = ALLSKY_OPTICS, **render_options
                  ) -> SimulatedFrame:
    """An all-sky frame of ``camera`` (:func:`all_sky_camera`, its lens ``fov_deg`` across) at
    ``site`` (latitude, longitude, degrees) and ``time`` (ISO UTC) looking up
    (:func:`zenith_attitude`), with ``landscape``; the other keywords are
    :func:`skyfix.simulate.render`'s. The truth adds ``zenith_px`` (the zenith's pixel),
    ``image_circle`` (``[cx, cy, radius]`` px), ``site`` and ``lens_fov_deg``."""
    obs = observe(time, site=f"{site[0]},{site[1]}")
    enu = obs.ground.A_icrs_to_enu
    A = zenith_attitude(enu, tilt_deg, tilt_az_deg, roll_deg)
    theta_max = math.radians(fov_deg) / 2.0
    frame = render(A, camera, optics=optics, exposure_s=exposure_s, epoch=time, seed=seed,
                   sky_mag_arcsec2=sky_mag_arcsec2, foreground=_foreground(landscape, enu, theta_max, seed),
                   **render_options)
    zenith, _ = camera.ray_to_pixel((A @ enu[2])[None])
    radius = camera.fx * lens.kb_theta_d(theta_max, camera.numbers())[0]
    frame.truth.update(zenith_px=[float(v) for v in zenith[0]], image_circle=[camera.cx, camera.cy, radius],
                       site=[float(site[0]), float(site[1])], lens_fov_deg=float(fov_deg))
    return frame
