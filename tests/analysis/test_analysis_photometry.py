"""Photometry: zero point, aperture flux, and catalogue consistency on the 8 ESA frames."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from skyfix.analysis import photometry as ph
from skyfix.simulate.psf import add_gaussians
from tests.conftest import REAL_DIR

ESA = sorted(str(p) for p in (REAL_DIR / "esa-tetra3").glob("*.tiff"))  # beside the repository
EPOCH = 2019.58  # capture 2019-07-29


def test_instrumental_magnitude():
    m = ph.instrumental_magnitude(np.array([1.0, 100.0, 0.0, -5.0]))
    assert m[0] == 0.0 and m[1] == pytest.approx(-5.0)
    assert np.isnan(m[2]) and np.isnan(m[3])


def test_zero_point_is_robust_to_outliers():
    rng = np.random.default_rng(0)
    inst = rng.uniform(-12, -8, 60)
    cat = inst + 17.3 + rng.normal(0, 0.1, 60)
    cat[:4] += np.array([2.0, -1.5, 3.0, 1.0])  # blends, wrong matches
    zp = ph.fit_zero_point(inst, cat)
    assert zp.zp == pytest.approx(17.3, abs=0.03)
    assert not zp.inliers[:4].any() and zp.inliers[4:].mean() > 0.95
    assert zp.rms_clipped_mag == pytest.approx(0.1, abs=0.03)
    assert zp.rms_mag > 0.3


def test_aperture_flux_recovers_simulated_stars():
    rng = np.random.default_rng(1)
    img = np.full((200, 300), 50.0)
    x, y = rng.uniform(20, 280, 20), rng.uniform(20, 180, 20)
    flux = rng.uniform(2e3, 2e4, 20)
    s2 = np.full(20, 1.3**2)
    add_gaussians(img, x, y, flux, s2, s2, np.zeros(20))
    img = rng.poisson(img).astype(np.float64)
    f, sky = ph.aperture_flux(img, x, y, radius=6.0)  # 4.6 σ
    assert np.allclose(sky, 50.0, atol=2.0)
    assert np.median(np.abs(f / flux - 1)) < 0.02
    f_out, _ = ph.aperture_flux(img, np.array([2.0]), np.array([100.0]), 3.0)
    assert np.isnan(f_out[0])  # aperture off the frame


@pytest.fixture(scope="module")
def esa_results():
    return [ph.frame_photometry(p, epoch=EPOCH) for p in ESA]


@pytest.mark.skipif(len(ESA) != 8, reason="ESA frames not available")
def test_esa_photometry_per_frame_zero_point(esa_results):
    """Per-frame zero point alone: pooled RMS 0.244 mag over 372 stars (Hp 3–7.7), median frame 0.23.

    Above the issue's 0.2: Hp is a blue-visual band, the IMX265 is red-extended (a B−V colour term
    of ≈ +0.28 mag/mag), and the lens vignettes (≈ −0.44 mag at the corner); see the next test.
    """
    assert all(r.solved for r in esa_results)
    s = ph.summarize(esa_results)
    assert s["n_stars"] >= 300
    assert s["rms_mag"] < 0.28
    assert s["median_frame_rms_mag"] < 0.27
    # one camera, one exposure setting: the zero points agree to ~0.1 mag (the Alt60 set is brighter)
    assert np.ptp(s["zero_points_mag"]) < 0.25
    assert sum(r.saturated.sum() for r in esa_results) >= 5  # the brightest stars are left out


@pytest.mark.skipif(len(ESA) != 8, reason="ESA frames not available")
def test_esa_photometry_with_colour_and_vignetting_reaches_0p2(esa_results):
    """Issue 4: consistent to 0.2 mag RMS. With a shared B−V term and ρ² vignetting: 0.156 (all
    372 stars, no clipping); cross-checked by fitting the two terms on the Alt40 frames and
    applying them to the Alt60 frames (0.17) and the reverse (0.14)."""
    cal = ph.fit_field_calibration(esa_results)
    assert cal.rms_mag < 0.18
    assert cal.rms_brighter_than(6.0) < 0.13
    assert 0.15 < cal.colour_slope < 0.45  # red stars brighter in the sensor band than in Hp
    assert -0.65 < cal.vignetting < -0.25  # fainter at the corners
    a = [r for r in esa_results if "Alt40" in r.image]
    b = [r for r in esa_results if "Alt60" in r.image]
    for train, test in ((a, b), (b, a)):
        c = ph.fit_field_calibration(train)
        held_out = ph.fit_field_calibration(test, fixed=(c.colour_slope, c.vignetting))
        assert held_out.rms_mag < 0.2


@pytest.mark.skipif(len(ESA) != 8, reason="ESA frames not available")
def test_analyze_photometry_command():
    from skyfix.cli.analyze import analyze_app

    r = CliRunner().invoke(analyze_app, ["photometry", *ESA[:2], "--epoch", str(EPOCH), "--json"])
    assert r.exit_code == 0, r.output
    lines = [json.loads(x) for x in r.output.strip().splitlines() if x.startswith("{")]
    assert len(lines) == 3
    assert all(x["solved"] for x in lines[:2])
    assert lines[2]["n_frames_solved"] == 2 and lines[2]["rms_mag"] < 0.35
    bad = CliRunner().invoke(analyze_app, ["photometry", ESA[0], "--flux", "nope"])
    assert bad.exit_code == 2
