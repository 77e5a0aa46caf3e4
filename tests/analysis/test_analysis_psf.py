"""PSF over the field: FWHM and ellipticity against simulated truth, and on a real ESA frame."""

import math

import numpy as np
import pytest
from typer.testing import CliRunner

from skyfix.analysis.psf_field import adaptive_moments, fit_elliptical_gaussians, measure_psf_field
from skyfix.camera import Camera
from skyfix.catalog import Catalog
from skyfix.geometry import attitude_from_radec_roll
from skyfix.simulate import Optics, Sensor, render
from skyfix.simulate.psf import pixel_integrated_stamps
from tests.conftest import REAL_DIR

A0 = attitude_from_radec_roll(math.radians(40.0), math.radians(20.0), math.radians(30.0))
CAM = Camera.from_fov(800, 600, 10.0)
SENSOR = Sensor(qe=0.6, full_well_e=1e6, gain_e_per_adu=1.0, bit_depth=16, bias_adu=100.0, read_noise_e=5.0)
ESA = sorted(str(p) for p in (REAL_DIR / "esa-tetra3").glob("*.tiff"))  # beside the repository


def _grid_catalog(mag: float) -> tuple[Catalog, np.ndarray]:
    xs, ys = np.meshgrid(np.linspace(25, 775, 16), np.linspace(25, 575, 12))
    xy = np.column_stack([xs.ravel(), ys.ravel()]) + np.random.default_rng(0).uniform(-0.5, 0.5, (192, 2))
    vec = CAM.pixel_to_ray(xy) @ A0
    n = len(xy)
    cat = Catalog(np.arange(1, n + 1), vec, np.full(n, mag, np.float32), np.zeros(n), np.zeros(n), 2025.0)
    return cat, xy


def _frame(fwhm: float, ell: float, mag: float = 4.5):
    cat, _ = _grid_catalog(mag)
    f = render(A0, CAM, sensor=SENSOR, optics=Optics(psf_fwhm_px=fwhm, ellipticity_edge=ell), exposure_s=0.5,
               catalog=cat, epoch=2025.0, seed=1)
    return f.image.astype(np.float32)


def _model_ellipticity(x, y, ell):
    """Optics.covariance: radial σ·(1 + e·ρ²), tangential σ → 1 − b/a = 1 − 1/(1 + e·ρ²)."""
    rho2 = ((x - CAM.cx) ** 2 + (y - CAM.cy) ** 2) / (0.5 * math.hypot(CAM.width, CAM.height)) ** 2
    return 1.0 - 1.0 / (1.0 + ell * rho2), rho2


@pytest.mark.parametrize("method", ["fit", "moments"])
def test_shape_estimators_on_exact_stamps(method):
    """Noise-free elliptical, rotated stamps: covariance back to 1 % (moments: well sampled only)."""
    n = 5
    sxx, syy, sxy = np.full(n, 2.0), np.full(n, 1.2), np.linspace(-0.6, 0.6, n)
    x = 9 + np.linspace(-0.4, 0.4, n)
    y = 9 + np.linspace(0.3, -0.3, n)
    st, r0, c0 = pixel_integrated_stamps(x, y, sxx, syy, sxy, 9, strips=16)
    st = 1e4 * st
    fn = fit_elliptical_gaussians if method == "fit" else adaptive_moments
    xf, yf, cov = fn(st, np.full(n, 9.0), np.full(n, 9.0), 1.2)
    if method == "moments":
        cov = cov - np.eye(2) / 12
    assert np.allclose(xf + c0, x, atol=0.01) and np.allclose(yf + r0, y, atol=0.01)
    assert np.allclose(cov[:, 0, 0], sxx, rtol=0.01)
    assert np.allclose(cov[:, 1, 1], syy, rtol=0.01)
    assert np.allclose(cov[:, 0, 1], sxy, atol=0.02)


def test_round_psf_fwhm_recovered():
    field = measure_psf_field(_frame(3.0, 0.0))
    s = field.summary()
    assert field.n >= 150  # 192 stars on the grid, all isolated; a few cut by the border
    assert s["median_fwhm_px"] == pytest.approx(3.0, rel=0.05)  # issue: within 5 % (measured 0.1 %)
    assert s["median_ellipticity"] < 0.06  # noise bias only
    for zone in s["zones"].values():
        assert zone["median_fwhm_px"] == pytest.approx(3.0, rel=0.05)


def test_undersampled_psf_fwhm_recovered():
    """FWHM 1.4 px, like the ESA frames: the pixel-integrated fit stays unbiased."""
    field = measure_psf_field(_frame(1.4, 0.0, mag=5.0))
    assert field.summary()["median_fwhm_px"] == pytest.approx(1.4, rel=0.05)  # measured 0.3 %


def test_elliptical_field_follows_the_optics_model():
    ell = 0.4
    field = measure_psf_field(_frame(2.0, ell))
    s = field.summary()
    truth_e, rho2 = _model_ellipticity(field.x, field.y, ell)
    truth_fwhm = 2.0 * np.sqrt(1 + ell * rho2)  # geometric mean of radial and tangential FWHM
    assert np.median(field.fwhm_px / truth_fwhm - 1) == pytest.approx(0.0, abs=0.05)
    assert abs(np.median(field.ellipticity - truth_e)) < 0.03  # noise bias ~0.01 at this SNR
    assert s["zones"]["edge"]["median_ellipticity"] > s["zones"]["centre"]["median_ellipticity"] + 0.1
    # the major axis is radial where the PSF is clearly elongated
    edge = truth_e > 0.15
    phi = np.arctan2(field.y - CAM.cy, field.x - CAM.cx)
    d = np.angle(np.exp(2j * (field.angle_rad - phi))) / 2
    assert edge.sum() > 20
    assert np.median(np.abs(d[edge])) < math.radians(8)


def test_blank_frame_gives_empty_field():
    img = np.random.default_rng(0).normal(100, 5, (200, 300)).astype(np.float32)
    field = measure_psf_field(img)
    assert field.n == 0
    assert math.isnan(field.summary()["median_fwhm_px"])


@pytest.mark.skipif(not ESA, reason="ESA frames not available")
def test_real_esa_frame_plausible(tmp_path):
    from skyfix.cli.analyze import analyze_app

    out = tmp_path / "psf.png"
    r = CliRunner().invoke(analyze_app, ["psf", ESA[2], "--out", str(out), "--json"])
    assert r.exit_code == 0, r.output
    import json

    s = json.loads(r.output.strip().splitlines()[-1])
    # Blackfly S + 35 mm f/1.9, 40″ px: sharply focused stars, FWHM 1.36–1.43 px on all 8 frames
    assert s["n_stars"] >= 30
    assert 1.1 < s["median_fwhm_px"] < 1.8
    assert 0.05 < s["median_ellipticity"] < 0.35
    assert out.read_bytes()[:4] == b"\x89PNG"


@pytest.mark.skipif(not ESA, reason="ESA frames not available")
def test_fwhm_agrees_with_detect_measure_psf():
    """Independent fits agree: this module's rotated fit and detect's axis-aligned windowed fit
    (same stars) give the same median FWHM to 1 % on a simulated and a real frame (measured 0.2 %)."""
    from skyfix.detect import measure_psf
    from skyfix.io import read_image

    for img in (_frame(1.4, 0.0, mag=5.0), read_image(ESA[2])):
        f = measure_psf_field(img)
        d = measure_psf(img, np.column_stack([f.x, f.y]))
        assert np.nanmedian(d["fwhm"]) == pytest.approx(np.median(f.fwhm_px), rel=0.01)
