"""Centroid study: the Cramér–Rao bound, the stamp machinery, and the issue-4 accuracy target."""

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from skyfix.analysis import centroid_study as cs
from skyfix.detect import centroid_windows, cramer_rao_centroid


@pytest.mark.parametrize("sigma, flux, sky, read, phase", [
    (0.5, 2000.0, 10.0, 5.0, (0.0, 0.0)),
    (0.8, 500.0, 0.0, 0.0, (0.3, -0.2)),
    (1.5, 1e4, 100.0, 3.0, (0.5, 0.1)),
    (3.0, 3e3, 20.0, 10.0, (-0.25, 0.4)),
])
def test_crb_matches_numeric_fisher_sum(sigma, flux, sky, read, phase):
    """detect's analytic-derivative bound equals an independent finite-difference Fisher sum."""
    a = cramer_rao_centroid(sigma, flux, sky, read, phase=phase)
    b = cs.numeric_crb(sigma, flux, sky, read, phase=phase)
    assert a == pytest.approx(b, rel=2e-3)


def test_crb_limits():
    # photon-limited: σ_eff/√F with the pixel box in σ_eff² = σ² + 1/12 (wide PSF: exact enough)
    s, f = 3.0, 1e5
    assert cs.numeric_crb(s, f) == pytest.approx(math.sqrt(s * s + 1 / 12) / math.sqrt(f), rel=0.01)
    # background-limited, wide PSF: √(8π b)·σ²/F
    b = 1e4
    assert cs.numeric_crb(s, 1e3, b) == pytest.approx(math.sqrt(8 * math.pi * b) * s * s / 1e3, rel=0.02)


def test_flux_for_snr_inverts_the_snr_convention():
    f = cs.flux_for_snr(50.0, 1.2, 10.0, 5.0)
    area = 4 * math.pi * (1.2**2 + 1 / 12)
    assert f / math.sqrt(f + area * (10.0 + 25.0)) == pytest.approx(50.0, rel=1e-9)


def test_expected_stamps_are_exact_pixel_integrals():
    st = cs.expected_stamps(np.array([7.3]), np.array([6.8]), 1000.0, 1.0, 16)
    assert st.sum() == pytest.approx(1000.0, rel=1e-6)
    yy, xx = np.mgrid[:16, :16]
    assert (st[0] * xx).sum() / st.sum() == pytest.approx(7.3, abs=1e-4)  # wide PSF: no S-curve
    assert (st[0] * yy).sum() / st.sum() == pytest.approx(6.8, abs=1e-4)


def test_mosaic_bookkeeping_matches_single_windows():
    """centroid_stamps (one call on an (N·k, k) mosaic) equals one centroid_windows call per stamp."""
    rng = np.random.default_rng(3)
    n, hs = 6, 7
    xt, yt = hs + rng.uniform(-0.5, 0.5, n), hs + rng.uniform(-0.5, 0.5, n)
    stamps = cs.render_stamps(xt, yt, 5e4, 1.2, 2 * hs, 10.0, 5.0, rng)
    for method in ("com", "iwcog", "gaussian"):
        x, y = cs.centroid_stamps(stamps, method, 1.2)
        for i in range(n):
            c = centroid_windows(stamps[i].astype(np.float32), [[hs, hs]], half_size=hs, method=method,
                                 psf_sigma=1.2, gain=1.0)
            assert x[i] == pytest.approx(c.x[0], abs=1e-9)
            assert y[i] == pytest.approx(c.y[0], abs=1e-9)
        assert np.max(np.hypot(x - xt, y - yt)) < 0.03  # SNR ≈ 200


@pytest.mark.parametrize("sigma, snr", [(0.8, 20.0), (1.0, 50.0), (2.0, 20.0), (3.0, 200.0), (1.5, 1000.0)])
def test_gaussian_fit_reaches_the_bound(sigma, snr):
    """Issue 4: Gaussian fit RMS ≤ 1.15 × CRB for SNR ≥ 20 and σ ≥ 0.8 px (measured 0.99–1.02).

    1500 stars → 3000 coordinates: the ratio's sampling error is ~1.3 %, so 1.15 is a 10σ margin
    over the measured value, yet a fit that lost ~15 % of the information would fail.
    """
    cell = cs.run_cell("gaussian", sigma, snr, 1500, np.random.default_rng(2024))
    assert cell.fail_fraction == 0.0
    assert cell.ratio <= 1.15
    assert cell.ratio >= 0.9  # not below the bound (the bound is a bound)
    assert abs(cell.bias_px) < 3 * cell.rms_px / math.sqrt(3000) + 1e-4


def test_thresholded_com_is_well_above_the_bound_at_low_snr():
    """The k·σ-thresholded CoM throws the wings away: documented ratio ≈ 1.6 at σ = 1, SNR 20."""
    com = cs.run_cell("com", 1.0, 20.0, 1500, np.random.default_rng(7))
    fit = cs.run_cell("gaussian", 1.0, 20.0, 1500, np.random.default_rng(7))
    assert com.ratio > 1.3
    assert com.ratio > fit.ratio + 0.25


def test_s_curve_shape():
    ph = np.linspace(-0.5, 0.5, 21)
    _, b_com = cs.s_curve("com", 0.35, ph, snr=200.0)
    _, b_fit = cs.s_curve("gaussian", 0.35, ph, snr=200.0)
    # CoM on a narrow PSF: odd in phase, zero at the pixel centre and edge, a real pull to the centre
    assert np.allclose(b_com, -b_com[::-1], atol=1e-6)
    assert abs(b_com[10]) < 1e-6 and abs(b_com[0]) < 1e-6
    assert np.max(np.abs(b_com)) > 0.01
    assert np.all(b_com[ph > 0] <= 1e-9)  # measured − true < 0 for phase > 0: pulled to the centre
    # the fit of the right model has no S-curve
    assert np.max(np.abs(b_fit)) < 1e-4


def test_analyze_centroids_command_writes_tables_and_plots(tmp_path):
    from skyfix.cli.analyze import analyze_app

    out = tmp_path / "study"
    args = ["centroids", "--quick", "--trials", "40", "--methods", "com,gaussian", "--out", str(out)]
    r = CliRunner().invoke(analyze_app, args)
    assert r.exit_code == 0, r.output
    data = json.loads((out / "centroid_study.json").read_text())
    assert len(data["cells"]) == 2 * 3 * 3
    assert {c["method"] for c in data["cells"]} == {"com", "gaussian"}
    md = (out / "centroid_study.md").read_text()
    assert "skyfix analyze centroids --quick" in md and "| σ \\ SNR |" in md
    for name in ("centroid_ratio_vs_snr.png", "centroid_s_curve.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    bad = CliRunner().invoke(analyze_app, ["centroids", "--quick", "--methods", "nope", "--out", str(out)])
    assert bad.exit_code == 2 and "unknown centroider" in bad.output
