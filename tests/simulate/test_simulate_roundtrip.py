"""Round trip: simulated frames at random attitudes solve back to the truth with the core solver."""

import math

import numpy as np
import pytest
from scipy.special import erf

from skyfix.camera import Camera, camera_from_preset
from skyfix.geometry import angle_between, attitude_from_radec_roll, radec_to_vector
from skyfix.simulate import Optics, Sensor, render, resolve_setup

pipeline = pytest.importorskip("skyfix.pipeline")


def visible_stars(frame, sensor: Sensor, optics: Optics, exposure_s: float, snr: float = 5.0) -> int:
    """Stars whose central pixel stands ``snr`` × the per-pixel noise above the background."""
    noise = math.sqrt(sensor.read_noise_e**2 + sensor.dsnu_e**2 + sensor.dark_current_e_s * exposure_s
                      + (sensor.gain_e_per_adu**2 / 12))
    peak = erf(0.5 / (math.sqrt(2) * optics.psf_sigma_px)) ** 2
    return sum(s["electrons"] * peak > snr * noise for s in frame.truth["stars"])


def boresight_errors(camera, setup, database, n=10, seed=7, min_visible=5):
    """Boresight errors (arcsec) of solved frames and the number of failures, over frames that
    show at least 5 clearly visible stars (the others are counted in ``skipped``)."""
    rng = np.random.default_rng(seed)
    _, sensor, optics, exposure_s = resolve_setup(setup, None, None, None)
    errors, failed, skipped = [], 0, 0
    for i in range(n):
        A = attitude_from_radec_roll(rng.uniform(0, 2 * np.pi), np.arcsin(rng.uniform(-1, 1)),
                                     rng.uniform(0, 2 * np.pi))
        frame = render(A, setup, epoch=2025.0, seed=i)
        if visible_stars(frame, sensor, optics, exposure_s) < min_visible:
            skipped += 1
            continue
        sol = pipeline.solve(frame.image, camera=camera, epoch=2025.0, database=database)
        if sol.status != "solved":
            failed += 1
            continue
        b = radec_to_vector(math.radians(sol.ra_deg), math.radians(sol.dec_deg))
        errors.append(math.degrees(float(angle_between(b, A[2]))) * 3600)
    assert skipped <= n // 2
    return np.array(errors), failed


@pytest.mark.parametrize("name", ["fov15", "generic"])
def test_round_trip_arcseconds_at_15_degrees(name, database):
    # a 15° 1024² camera with the generic CMOS sensor, and the generic preset (17°)
    camera = Camera.from_fov(1024, 1024, 15.0) if name == "fov15" else camera_from_preset(name)
    errors, failed = boresight_errors(camera, camera if name == "fov15" else name, database)
    assert failed <= 1
    assert np.median(errors) < 2.0  # arcsec (measured: 1.2″ and 0.8″, ~0.02 px)


def test_round_trip_has2(database):
    # HAS2: 75 e⁻ read noise and an uncalibrated 115 e⁻ fixed pattern; 43.7″ pixels
    camera = camera_from_preset("has2")
    errors, failed = boresight_errors(camera, "has2", database)
    assert failed <= 2
    assert np.median(errors) < 0.1 * math.degrees(camera.plate_scale_rad) * 3600  # measured ~2–2.6″


def test_round_trip_sunsat_6_bit(database):
    # Sunsat digitised to 64 levels: quantisation limits centroids to ~0.1 px (53″ pixels)
    camera = camera_from_preset("sunsat")
    errors, failed = boresight_errors(camera, "sunsat", database)
    assert failed <= 1
    assert np.median(errors) < 0.15 * math.degrees(camera.plate_scale_rad) * 3600  # measured 4.8″



def test_round_trip_mt9v022_30_degrees(database):
    # Thesis 000's camera: 29.7° × 19.2°, 6 µm pixels behind 8.5 mm, at the wide end of the
    # default database (10–30°, which serves fields up to ~40°). Its frames often show only
    # 3–5 stars, too few to beat the 1e-9 false-match bound: those fail (by design) and are
    # left out here. Of the 9 frames with 8 or more visible stars, 7 solve (measured): the other
    # two yield only 5–6 detections.
    camera = camera_from_preset("mt9v022")
    errors, failed = boresight_errors(camera, "mt9v022", database, n=16, min_visible=8)
    assert len(errors) >= 6
    assert failed <= 3
    assert np.median(errors) < 0.25 * math.degrees(camera.plate_scale_rad) * 3600
