"""render(): attitude → stars in view → camera model → PSF → sensor → image, with the truth.

Random streams: ``SeedSequence(seed, spawn_key=(frame_index,))`` is split into one stream per
source (:data:`STREAMS`), so a frame is bit-for-bit repeatable, frames of a sequence are
independent, and switching one source off leaves every other source's draws unchanged.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
import tomllib

from skyfix.camera import PRESETS as CAMERA_PRESETS
from skyfix.camera import Camera, camera_from_preset
from skyfix.catalog import Catalog
from skyfix.corrections.aberration import aberrate
from skyfix.errors import SimulationError, UnknownNameError, unknown_name
from skyfix.geometry import quaternion_from_attitude, radec_roll_from_attitude, rotation_angle_between
from skyfix.simulate.atmosphere import Atmosphere, scintillate, seeing_sigma_px, young_scintillation
from skyfix.simulate.compression import jpeg_roundtrip
from skyfix.simulate.motion import star_tracks
from skyfix.simulate.optics import Optics
from skyfix.simulate.photometry import sky_electrons_per_pixel, star_electrons
from skyfix.simulate.presets import load_preset, preset_names
from skyfix.simulate.psf import add_gaussians
from skyfix.simulate.scene import (
    candidate_stars,
    catalog_at,
    cosmic_ray_hits,
    false_star_list,
    simulation_time,
    stray_light_map,
)
from skyfix.simulate.sensor import Sensor, apply_detector, fixed_pattern, noise_switches

__all__ = ["SimulatedFrame", "render", "resolve_setup", "STREAMS"]

#: Independent random streams of one frame, in spawn order (never reorder: it changes every draw).
STREAMS = ("shot", "dark", "read", "ktc", "false_stars", "cosmic_rays", "scintillation")


@dataclass
class SimulatedFrame:
    """A rendered frame.

    Attributes
    ----------
    image : (H, W) ndarray
        ``uint16`` ADU (``float32`` ADU when quantisation is switched off).
    truth : dict
        ``ra_deg``, ``dec_deg``, ``roll_deg``, ``quaternion_xyzw``, ``time`` (ISO UTC, mid-exposure),
        ``epoch_jyear``, ``exposure_s``, ``rate_rad_s``, ``seed``, ``frame_index``, ``camera``
        (the ``[camera]`` table), ``sensor``, ``optics``, ``noise``, ``stars``
        (``[{id, x, y, mag, electrons}]``, x/y at the star's mid-exposure in docs/design.md#pixel-coordinates
        convention, electrons = expected photo-electrons before noise), ``false_stars``,
        ``cosmic_rays``, ``hot_pixels``, ``background_e``.
    expected_e : (H, W) float32 ndarray
        Expected photo-electrons per pixel before the detector (no noise, no PRNU).
    """

    image: np.ndarray
    truth: dict
    expected_e: np.ndarray = field(repr=False)


def _camera_table(camera: Camera) -> dict:
    """The truth's ``camera``: the camera file's ``[camera]`` table (a copy of the one kept for
    the last few cameras: its TOML, written and read, costs ~0.4 ms a frame)."""
    return dict(_camera_toml_table(camera))


@lru_cache(maxsize=8)
def _camera_toml_table(camera: Camera) -> dict:
    return tomllib.loads(camera.to_toml())["camera"]


def resolve_setup(camera: Camera | str | Path, sensor: Sensor | str | None, optics: Optics | str | None,
                  exposure_s: float | None) -> tuple[Camera, Sensor, Optics, float]:
    """Camera, sensor, optics and exposure from objects or preset names.

    A preset name for the camera also supplies the sensor, optics and exposure left as None;
    so does a camera TOML file (``.toml`` path) holding ``[sensor]``, ``[optics]`` or
    ``[defaults]`` tables beside ``[camera]``; otherwise the ``generic`` preset does.
    """
    preset = None
    file_tables: dict = {}
    if isinstance(camera, Path) or (isinstance(camera, str) and (camera.endswith(".toml")
                                                                 or Path(camera).is_file())):
        file_tables = _read_setup_file(Path(camera))
        camera = Camera.from_dict(file_tables["camera"])
    if isinstance(camera, str):
        preset = camera.lower()
        try:
            tables = load_preset(preset)
            camera = Camera.from_dict(tables["camera"])
        except UnknownNameError:
            try:
                camera = camera_from_preset(preset)  # a camera.py preset without sensor data
            except UnknownNameError:
                known = dict.fromkeys([*preset_names(), *CAMERA_PRESETS])  # each name once
                raise unknown_name("camera preset", preset, known) from None
            preset = "generic"
    elif not isinstance(camera, Camera):
        raise SimulationError(f"camera must be a Camera or a preset name, got {type(camera).__name__}")
    base = load_preset(preset or "generic")
    for key in ("sensor", "optics", "defaults"):  # a camera file's own tables win over the preset's
        if key in file_tables:
            base[key] = file_tables[key]
    if sensor is None:
        sensor = Sensor.from_dict(base["sensor"])
    elif isinstance(sensor, str):
        sensor = Sensor.from_preset(sensor)
    elif not isinstance(sensor, Sensor):
        raise SimulationError(f"sensor must be a Sensor or a preset name, got {type(sensor).__name__}")
    if optics is None:
        optics = Optics.from_dict(base.get("optics", {}))
    elif isinstance(optics, str):
        optics = Optics.from_preset(optics)
    elif not isinstance(optics, Optics):
        raise SimulationError(f"optics must be an Optics or a preset name, got {type(optics).__name__}")
    if exposure_s is None:
        exposure_s = float(base.get("defaults", {}).get("exposure_s", 0.1))
    try:
        exposure_s = float(exposure_s)
    except (TypeError, ValueError):
        raise SimulationError(f"exposure must be a number of seconds, got {exposure_s!r}") from None
    if not (math.isfinite(exposure_s) and exposure_s > 0):
        raise SimulationError(f"exposure must be a positive number of seconds, got {exposure_s}")
    return camera, sensor, optics, exposure_s


def _read_setup_file(path: Path) -> dict:
    """Tables of a camera TOML file: ``[camera]`` and optionally ``[sensor]``, ``[optics]``,
    ``[defaults]``."""
    try:
        tables = tomllib.loads(path.read_text())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise SimulationError(f"cannot read camera file {path}: {exc}") from None
    if "camera" not in tables:
        raise SimulationError(f"{path} has no [camera] table")
    return tables


def _check_attitude(A: np.ndarray) -> np.ndarray:
    A = np.asarray(A, dtype=np.float64)
    if A.shape != (3, 3) or not np.all(np.isfinite(A)):
        raise SimulationError("attitude must be a finite 3x3 matrix")
    if np.max(np.abs(A @ A.T - np.eye(3))) > 1e-6 or np.linalg.det(A) < 0:
        raise SimulationError("attitude must be a rotation matrix (orthonormal, determinant +1)")
    return A


def render(A_icrs_to_cam: np.ndarray, camera: Camera | str, *, sensor: Sensor | str | None = None,
           optics: Optics | str | None = None, exposure_s: float | None = None, epoch=None,
           rate_rad_s=None, seed: int = 0, catalog: Catalog | None = None, mag_limit: float | None = None,
           false_stars: int = 0, false_star_mags: tuple[float, float] = (3.0, 8.0), hot_pixels: int = 0,
           cosmic_rays: int = 0, stray_light: Mapping | None = None, sky_mag_arcsec2: float | None = 22.0,
           observer_velocity_km_s=None, noise: bool | Mapping[str, bool] = True, frame_index: int = 0,
           motion=None, atmosphere: Atmosphere | None = None, jpeg_quality: int | None = None,
           foreground=None) -> SimulatedFrame:
    """Render a star-camera frame and its truth.

    Parameters
    ----------
    A_icrs_to_cam : (3, 3) array
        Attitude at mid-exposure (of the centre row), ``b = A r``.
    camera : Camera, str or Path
        Camera model, a preset name, or a TOML file; a preset or a file with ``[sensor]`` /
        ``[optics]`` / ``[defaults]`` tables also supplies those.
    sensor, optics : Sensor / Optics / preset name, optional
    exposure_s : float, optional
        Integration time, seconds (> 0).
    epoch : None, float, str, datetime
        Mid-exposure time: Julian year, ISO-8601 text or datetime (default: now). Pass it for
        bit-for-bit repeatable frames (proper motion is applied to this epoch).
    rate_rad_s : (3,) array, optional
        Body rate about the camera x, y, z axes, rad/s: smear during the exposure (and rolling
        shutter skew when ``sensor.line_time_s > 0``), and the truth's ``rate_rad_s``.
    motion : callable, optional
        The attitude at times relative to this frame's reference time, ``motion(t_s) ->
        (..., 3, 3)`` with ``motion(0) = A`` (an attitude profile seen from the frame, as
        :func:`~skyfix.simulate.render_sequence` passes it): the smear and the rolling shutter
        follow it instead of the constant ``rate_rad_s``, which then only goes into the truth.
    seed : int
        Seed of the temporal noise streams.
    catalog : Catalog, optional
        Stars to render (default: Hipparcos); the stars near the field are moved by proper
        motion to ``epoch``.
    mag_limit : float, optional
        Render only stars brighter than this.
    false_stars : int
        Number of false stars/debris (uniform positions, magnitudes in ``false_star_mags``).
    hot_pixels : int
        Number of hot pixels (fixed positions for the sensor).
    cosmic_rays : int
        Number of cosmic-ray tracks.
    stray_light : mapping, optional
        Smooth gradient, see :func:`skyfix.simulate.scene.stray_light_map`.
    sky_mag_arcsec2 : float or None
        Sky background surface brightness, mag arcsec⁻² (None: dark sky).
    observer_velocity_km_s : (3,) array, optional
        Observer velocity in ICRS for stellar aberration, km/s (the relativistic form,
        :func:`skyfix.corrections.aberrate`).
    noise : bool or mapping
        Detector sources on/off (see :data:`skyfix.simulate.sensor.NOISE_SOURCES`).
    frame_index : int
        Index in a sequence; selects independent noise streams for the same seed.
    atmosphere : Atmosphere, optional
        Seeing (the PSF broadened by the seeing disc) and scintillation (each star's flux times a
        log-normal factor, Young's formula) over a ground camera
        (:mod:`skyfix.simulate.atmosphere`); None: no air.
    jpeg_quality : int, optional
        The frame as a camera delivering 8-bit JPEG gives it: scaled to 8 bits, JPEG-encoded at
        this quality (1–95) and decoded (:mod:`skyfix.simulate.compression`); the image is then
        ``uint8``. None: the sensor's own ADU.
    foreground : callable, optional
        What stands in front of the sky: ``foreground(expected_e (H, W), camera, A, exposure_s)
        -> (H, W)`` takes the expected photo-electrons of the sky and its stars and returns the
        frame's (an all-sky lens's image circle, horizon, trees and light dome:
        :func:`skyfix.simulate.allsky.render_allsky`), before the detector.
    """
    A = _check_attitude(A_icrs_to_cam)
    camera, sensor, optics, exposure_s = resolve_setup(camera, sensor, optics, exposure_s)
    from skyfix import warmup

    warmup.ensure("simulate")  # its kernels, compiled up front on first use
    switches = noise_switches(noise)
    epoch_jy, time_iso = simulation_time(epoch)
    rate = None if rate_rad_s is None else np.asarray(rate_rad_s, dtype=np.float64).reshape(3)
    if rate is not None and not np.all(np.isfinite(rate)):
        raise SimulationError("rate_rad_s must be three finite numbers")
    if motion is not None and not (callable(motion) and rotation_angle_between(A, motion(0.0)) < 1e-9):
        raise SimulationError("motion must be a function of time whose attitude at 0 is A")
    counts = (("false_stars", false_stars), ("hot_pixels", hot_pixels), ("cosmic_rays", cosmic_rays))
    for name, value in counts:
        if int(value) < 0:
            raise SimulationError(f"{name} must be >= 0, got {value}")
    if not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise SimulationError(f"seed must be a non-negative integer, got {seed!r}")
    ss = np.random.SeedSequence(int(seed), spawn_key=(int(frame_index),))
    streams = dict(zip(STREAMS, (np.random.default_rng(s) for s in ss.spawn(len(STREAMS))), strict=True))

    # --- stars in view ---------------------------------------------------------------
    if catalog is None:
        catalog = catalog_at(epoch_jy, mag_limit)  # cached near the epoch; exact epoch below
    elif mag_limit is not None:
        catalog = catalog.brighter_than(mag_limit)
    h, w = camera.height, camera.width
    atmosphere = Atmosphere() if atmosphere is None else Atmosphere(*atmosphere).checked()
    seeing_px = seeing_sigma_px(atmosphere.seeing_fwhm_arcsec, camera.plate_scale_rad)
    span_s = exposure_s / 2 + abs(sensor.line_time_s) * h
    sigma_max = math.hypot(optics.psf_sigma_max_px, seeing_px) + optics.defocus_px
    extra = ((np.linalg.norm(rate) * span_s if rate is not None else 0.0)
             + (8 * sigma_max + 2) * camera.plate_scale_rad)
    if motion is not None:  # how far the profile turns within the rows' exposures
        extra += max(rotation_angle_between(A, motion(s)) for s in (-span_s, span_s))
    pm_margin = 1e-4 * (1.0 + abs(catalog.epoch - epoch_jy))  # > 20″/yr: no star moves farther
    idx = candidate_stars(A, camera, catalog, extra + pm_margin)
    catalog = catalog.subset(idx)  # only the stars near the field are moved to the exact epoch
    if catalog.epoch != epoch_jy:
        catalog = catalog.at_epoch(epoch_jy)
    idx = np.arange(len(catalog))
    vectors = (catalog.vectors if observer_velocity_km_s is None
               else aberrate(catalog.vectors, observer_velocity_km_s))
    xy_mid, front, tracks, b_mid = star_tracks(A, rate if motion is None else motion, vectors, camera,
                                               exposure_s, sensor.line_time_s)
    margin = -(6 * sigma_max + 1)  # stars just outside still spill light in
    near = front & camera.in_frame(xy_mid, margin=margin) & np.all(np.isfinite(tracks), axis=(0, 2))
    idx, xy_mid, tracks, b_mid = idx[near], xy_mid[near], tracks[:, near], b_mid[near]
    beta = np.arccos(np.clip(b_mid[:, 2], -1.0, 1.0))
    electrons = star_electrons(catalog.mag[idx], optics, sensor, exposure_s, optics.transmission(beta))
    flux_e = electrons
    if atmosphere.scintillation:
        sigma_rel = young_scintillation(optics.aperture_mm, exposure_s, *atmosphere[2:])
        flux_e = scintillate(electrons, sigma_rel, streams["scintillation"])

    # --- expected photo-electrons ------------------------------------------------------
    expected = np.zeros((h, w), dtype=np.float32)
    background = 0.0
    if sky_mag_arcsec2 is not None:
        background = sky_electrons_per_pixel(sky_mag_arcsec2, optics, sensor, exposure_s,
                                             camera.plate_scale_rad)
        expected += background
    if stray_light is not None:
        expected += stray_light_map(stray_light, camera, A, exposure_s)
    _add_sources(expected, tracks, flux_e, optics, camera, seeing_px)
    fs_records = []
    if false_stars:
        fxy, fmag = false_star_list(int(false_stars), camera, streams["false_stars"], false_star_mags)
        fe = star_electrons(fmag, optics, sensor, exposure_s)
        _add_sources(expected, fxy[None], fe, optics, camera, seeing_px)
        fs_records = [dict(x=float(x), y=float(y), mag=float(m), electrons=float(e))
                      for (x, y), m, e in zip(fxy, fmag, fe, strict=True)]
    extra_e, cr_records = None, []
    if cosmic_rays:
        extra_e, cr_records = cosmic_ray_hits(int(cosmic_rays), (h, w), streams["cosmic_rays"])

    if foreground is not None:
        expected = np.asarray(foreground(expected, camera, A, exposure_s), dtype=np.float32)
    image = apply_detector(expected, sensor, exposure_s, streams, noise=switches,
                           hot_pixels=int(hot_pixels), extra_e=extra_e)
    if jpeg_quality is not None:
        image = jpeg_roundtrip(image, jpeg_quality, sensor.max_adu)

    # --- truth ------------------------------------------------------------------------
    inside = camera.in_frame(xy_mid)
    ra, dec, roll = radec_roll_from_attitude(A)
    hot_records = []
    if hot_pixels and switches["hot_pixels"]:
        pat = fixed_pattern(sensor, (h, w), int(hot_pixels))
        hot_records = [dict(x=int(i % w), y=int(i // w), dark_e_s=float(d))
                       for i, d in zip(pat.hot_index, pat.hot_dark_e_s, strict=True)]
    truth = dict(
        ra_deg=math.degrees(ra), dec_deg=math.degrees(dec), roll_deg=math.degrees(roll),
        quaternion_xyzw=[float(q) for q in quaternion_from_attitude(A)],
        time=time_iso, epoch_jyear=epoch_jy, exposure_s=exposure_s,
        rate_rad_s=None if rate is None else [float(r) for r in rate],
        observer_velocity_km_s=None if observer_velocity_km_s is None
        else [float(v) for v in np.asarray(observer_velocity_km_s).reshape(3)],
        seed=int(seed), frame_index=int(frame_index),
        camera=_camera_table(camera), sensor=sensor.to_dict(), optics=optics.to_dict(), noise=switches,
        sky_mag_arcsec2=sky_mag_arcsec2, background_e=float(background),
        atmosphere=atmosphere._asdict(), jpeg_quality=jpeg_quality,
        stars=[dict(id=i, x=x, y=y, mag=m, electrons=e)  # Python numbers by tolist (float64's: the same)
               for i, (x, y), m, e in zip(catalog.ids[idx][inside].astype(np.int64).tolist(),
                                          xy_mid[inside].astype(np.float64).tolist(),
                                          catalog.mag[idx][inside].astype(np.float64).tolist(),
                                          electrons[inside].astype(np.float64).tolist(), strict=True)],
        false_stars=fs_records, cosmic_rays=cr_records, hot_pixels=hot_records,
    )
    return SimulatedFrame(image=image, truth=truth, expected_e=expected)


def _add_sources(image: np.ndarray, tracks: np.ndarray, electrons: np.ndarray, optics: Optics,
                 camera: Camera, seeing_px: float = 0.0) -> None:
    """Add stars along their tracks (K sub-steps × defocus points), electrons split evenly; the
    seeing disc's σ ``seeing_px`` adds in quadrature to the optics' PSF."""
    k, n, _ = tracks.shape
    if n == 0:
        return
    offsets, weights = optics.defocus_offsets()
    pos = tracks[:, :, None, :] + offsets[None, None, :, :]  # (K, N, D, 2)
    flux = (electrons[None, :, None] / k) * weights[None, None, :]
    flux = np.broadcast_to(flux, pos.shape[:3])
    pos = pos.reshape(-1, 2)
    sxx, syy, sxy = optics.covariance(np.broadcast_to(tracks[:, :, None, :], pos.reshape(k, n, -1, 2).shape
                                                      ).reshape(-1, 2), camera)
    if seeing_px > 0:
        sxx, syy = sxx + seeing_px**2, syy + seeing_px**2
    add_gaussians(image, pos[:, 0], pos[:, 1], flux.reshape(-1), sxx, syy, sxy)
