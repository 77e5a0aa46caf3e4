"""What real frames carry (issue 27 part 5): JPEG / 8-bit output, seeing, scintillation, a PSF
that grows toward the field's edge — each switchable in ``render``, each pinned by a number
measured on a known frame (docs/simulating.md#what-real-frames-carry)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from skyfix.analysis.psf_field import measure_psf_field
from skyfix.camera import Camera
from skyfix.detect import extract_centroids
from skyfix.errors import SimulationError
from skyfix.geometry import attitude_from_radec_roll
from skyfix.simulate import Sensor, render, resolve_setup
from skyfix.simulate.atmosphere import Atmosphere, scintillate, seeing_sigma_px, young_scintillation
from skyfix.simulate.compression import jpeg_roundtrip

A = attitude_from_radec_roll(1.4, 0.1, 0.3)
#: The generic camera with an 8-bit output whose noise is ~1.5 counts, as the Droid X2's was.
SENSOR_8BIT = Sensor.from_preset("generic").replace(bit_depth=8, gain_e_per_adu=2.0, bias_adu=10.0)


def _centroid_errors(frame) -> tuple[np.ndarray, np.ndarray]:
    """Detected minus true position (px) of each detection within 1 px of a true star, and
    that star's index."""
    c = extract_centroids(frame.image, max_stars=200)
    truth = np.array([[s["x"], s["y"]] for s in frame.truth["stars"]])
    d, j = cKDTree(truth).query(c.xy)
    ok = d < 1.0
    return c.xy[ok] - truth[j[ok]], j[ok]


def _rms_on(errors: np.ndarray, index: np.ndarray, common: np.ndarray) -> float:
    return float(np.sqrt(np.mean(errors[np.isin(index, common)] ** 2)))


def test_jpeg_quality_75_moves_centroids_and_loses_faint_stars():
    raw = render(A, "generic", sensor=SENSOR_8BIT, epoch=2025.0, seed=3)
    jpeg = render(A, "generic", sensor=SENSOR_8BIT, epoch=2025.0, seed=3, jpeg_quality=75)
    assert jpeg.image.dtype == np.uint8 and jpeg.truth["jpeg_quality"] == 75
    e0, j0 = _centroid_errors(raw)
    e1, j1 = _centroid_errors(jpeg)
    common = np.intersect1d(j0, j1)
    # measured: 176 stars found raw, 99 after JPEG q75; on the 90 found in both the centroid
    # error RMS (per axis) is 0.112 px raw and 0.305 px after JPEG
    assert len(j0) == 176 and 90 <= len(j1) <= 110 and len(common) >= 80
    assert _rms_on(e0, j0, common) == pytest.approx(0.112, abs=0.01)
    assert _rms_on(e1, j1, common) == pytest.approx(0.305, abs=0.03)


def test_jpeg_of_a_12_bit_frame_is_first_cut_to_8_bits():
    image = np.array([[0, 16, 4095], [2048, 8, 24]], dtype=np.uint16)
    out = jpeg_roundtrip(np.tile(image, (8, 8)), 95, 4095)
    assert out.dtype == np.uint8
    assert abs(int(out[0, 2]) - 255) <= 2 and abs(int(out[1, 0]) - 128) <= 2
    with pytest.raises(SimulationError, match="1 to 95"):
        jpeg_roundtrip(image, 99, 4095)


@pytest.mark.slow  # ~8 s: two frames' PSF fits
def test_seeing_3_arcsec_widens_the_measured_fwhm_as_predicted():
    cam = Camera.from_fov(1280, 960, 1.0)  # 2.81″ a pixel
    kw = dict(epoch=2025.0, seed=3, false_stars=60, false_star_mags=(4.0, 7.0))
    still = measure_psf_field(render(A, cam, **kw).image).summary()["median_fwhm_px"]
    seen = measure_psf_field(render(A, cam, atmosphere=Atmosphere(3.0), **kw).image
                             ).summary()["median_fwhm_px"]
    seeing_fwhm_px = 3.0 / (cam.plate_scale_rad * 206264.806)
    assert seeing_sigma_px(3.0, cam.plate_scale_rad) == pytest.approx(seeing_fwhm_px / 2.3548, rel=1e-4)
    predicted = math.hypot(1.8, seeing_fwhm_px)  # the generic PSF's 1.8 px in quadrature: 2.09 px
    assert still == pytest.approx(1.8, rel=0.05)  # measured 1.79
    assert seen == pytest.approx(predicted, rel=0.10)  # measured 2.07


def test_young_scintillation_and_its_flux_draws():
    # D = 10 mm, 0.1 s, zenith, sea level: 0.09 · 1^(-2/3) · (0.2)^(-1/2) = 0.2012
    assert young_scintillation(10.0, 0.1) == pytest.approx(0.09 / math.sqrt(0.2), rel=1e-12)
    # airmass 2 (× 2^1.75 = 3.364), 1400 m (× e^(-0.175) = 0.8395)
    assert young_scintillation(10.0, 0.1, 2.0, 1400.0) == pytest.approx(0.2012 * 3.3636 * 0.83946, rel=1e-3)
    f = scintillate(np.full(40000, 1000.0), 0.3, np.random.default_rng(1))
    assert f.min() > 0
    assert np.mean(f) == pytest.approx(1000.0, rel=0.01)
    assert np.std(f) / np.mean(f) == pytest.approx(0.3, rel=0.03)


def test_scintillation_in_a_frame_jitters_each_star_by_youngs_sigma():
    kw = dict(epoch=2025.0, seed=5, noise=False, sky_mag_arcsec2=None, exposure_s=0.1)
    calm = render(A, "generic", **kw)
    twinkling = render(A, "generic", atmosphere=Atmosphere(0.0, True, 1.2, 0.0), **kw)
    sigma = young_scintillation(11.43, 0.1, 1.2)  # 0.254
    # each star's light in a 7 × 7 box around it, twinkling over calm, isolated bright stars
    xy = np.array([[s["x"], s["y"]] for s in calm.truth["stars"]])
    near, _ = cKDTree(xy).query(xy, k=2)
    ratios = []
    for (x, y), d in zip(xy, near[:, 1], strict=True):
        c, r = round(x), round(y)
        if d > 12 and 5 <= c < 1275 and 5 <= r < 955:
            box = (slice(r - 3, r + 4), slice(c - 3, c + 4))
            ratios.append(twinkling.expected_e[box].sum() / calm.expected_e[box].sum())
    ratios = np.array(ratios)
    assert len(ratios) > 300
    assert np.std(ratios) == pytest.approx(sigma, rel=0.1)
    assert np.mean(ratios) == pytest.approx(1.0, abs=0.06)
    # the other streams are untouched: the same frame without it draws the same noise
    assert render(A, "generic", epoch=2025.0, seed=5).image.tobytes() == render(
        A, "generic", epoch=2025.0, seed=5, atmosphere=Atmosphere()).image.tobytes()


def test_psf_growth_widens_the_edge_as_one_plus_g_rho_squared():
    optics = resolve_setup("generic", None, None, None)[2].replace(psf_growth_edge=0.5)
    cam = resolve_setup("generic", None, None, None)[0]
    corner = np.array([[cam.cx + cam.width / 2, cam.cy + cam.height / 2]])
    sxx, syy, sxy = optics.covariance(corner, cam)
    assert math.sqrt(sxx[0]) == pytest.approx(optics.psf_sigma_px * 1.5, rel=1e-9)
    assert math.sqrt(syy[0]) == pytest.approx(optics.psf_sigma_px * 1.5, rel=1e-9)
    field = measure_psf_field(render(A, "generic", optics=optics, epoch=2025.0, seed=3).image)
    rho = np.hypot(field.x - cam.cx, field.y - cam.cy) / (0.5 * math.hypot(cam.width, cam.height))
    ratio = field.fwhm_px / (1.8 * (1 + 0.5 * rho**2))
    assert len(ratio) >= 40
    assert np.median(ratio) == pytest.approx(1.0, abs=0.05)  # measured: 1.00 on 46 stars
    edge = rho > 2 / 3
    assert np.median(field.fwhm_px[edge]) > 1.15 * np.median(field.fwhm_px[rho < 1 / 3])


def test_atmosphere_values_are_checked():
    with pytest.raises(SimulationError, match="airmass"):
        render(A, "generic", epoch=2025.0, atmosphere=Atmosphere(1.0, True, 0.5))
    with pytest.raises(SimulationError, match="seeing"):
        render(A, "generic", epoch=2025.0, atmosphere=Atmosphere(-1.0))
