"""Centroiders (CoM, IWCoG, Gaussian fit), windowed centroiding and the Cramér–Rao bound."""

import math

import numpy as np
import pytest

from skyfix.detect import centroid_windows, cramer_rao_centroid, extract_centroids
from tests.detect.test_detect import nearest, random_field, render_stars


def test_cramer_rao_limits():
    # background-limited, wide PSF: √(8π b)·σ²/F
    s, f, b = 3.0, 1e4, 1e4
    assert cramer_rao_centroid(s, f, b) == pytest.approx(math.sqrt(8 * math.pi * b) * s**2 / f, rel=0.03)
    # photon-limited, wide PSF: σ/√F (pixelation adds ~1/12 px² to σ²)
    s, f = 4.0, 1e6
    assert cramer_rao_centroid(s, f, 0.0) == pytest.approx(math.sqrt(s**2 + 1 / 12) / math.sqrt(f), rel=0.02)
    # read noise adds like sky; more flux, tighter bound
    assert cramer_rao_centroid(1.0, 1e4, 0.0, 10.0) == pytest.approx(cramer_rao_centroid(1.0, 1e4, 100.0))
    assert cramer_rao_centroid(1.0, 4e4, 10.0) < cramer_rao_centroid(1.0, 1e4, 10.0)
    with pytest.raises(ValueError):
        cramer_rao_centroid(0.0, 1e4)


def _trials(method, s_psf, flux, n=120, sky=50.0, read=3.0, gain=1.0, seed=7):
    rng = np.random.default_rng(seed)
    err, sig = [], []
    for _ in range(n):
        x0, y0 = 20 + rng.random(), 20 + rng.random()
        mu = render_stars((40, 40), [(x0, y0)], [flux], sigma=s_psf, background=sky, noise=0.0)
        img = (rng.poisson(mu) + rng.normal(0.0, read, mu.shape)).astype(np.float32)
        guess = [(x0 + rng.normal(0, 0.4), y0 + rng.normal(0, 0.4))]
        c = centroid_windows(img, guess, 8, method=method, gain=gain)
        err.append(c.x[0] - x0)
        sig.append(c.sigma_x[0])
    err = np.asarray(err)
    crb = cramer_rao_centroid(s_psf, flux, sky, read)
    return np.sqrt(np.mean(err**2)) / crb, np.mean(sig) / np.sqrt(np.mean(err**2)), np.mean(err)


@pytest.mark.parametrize("s_psf,flux", [(0.8, 1500.0), (1.2, 3000.0), (2.0, 20000.0)])
def test_gaussian_fit_reaches_the_bound(s_psf, flux):
    """Issue 4: RMS ≤ 1.15 × CRB for SNR ≥ 20, σ ≥ 0.8 px; its own σ is honest."""
    ratio, sig_ratio, bias = _trials("gaussian", s_psf, flux)
    assert ratio < 1.15 + 0.1, ratio  # 120 trials: ~7% sampling error on an RMS
    assert 0.8 < sig_ratio < 1.25, sig_ratio
    assert abs(bias) < 0.02


def test_iwcog_near_bound_and_com_worse():
    r_iw, s_iw, _ = _trials("iwcog", 1.2, 3000.0)
    r_com, _, _ = _trials("com", 1.2, 3000.0)
    assert r_iw < 1.3 and 0.75 < s_iw < 1.3
    assert r_com > r_iw  # the thresholded CoM throws the wings away


def test_windows_keep_order_and_flag_misses():
    xy = np.array([[30.2, 40.7], [100.5, 20.1], [70.0, 90.0]])
    img = render_stars((120, 140), xy[:2], [8000, 3000], noise=2.0)
    pred = np.array([[100.0, 20.5], [30.0, 41.0], [70.0, 90.0], [-50.0, 10.0], [np.nan, 3.0]])
    for method in ("com", "iwcog", "gaussian"):
        c = centroid_windows(img, pred, half_size=6, method=method)
        assert len(c) == 5
        assert c.x[0] == pytest.approx(100.5, abs=0.05) and c.y[1] == pytest.approx(40.7, abs=0.05)
        assert c.flux[1] > c.flux[0]  # input order kept, not sorted
        assert np.isnan(c.x[2:]).all() and np.all(c.flux[2:] == 0)  # empty sky, off frame, NaN


def test_windowed_cost_is_independent_of_frame_size():
    """O(N·window²): a big frame gives the same answers (and touches only the windows)."""
    xy = np.array([[30.3, 40.6], [60.8, 25.2]])
    small = render_stars((80, 100), xy, [5000, 7000], noise=2.0, seed=3)
    big = np.zeros((3000, 4000), np.float32)
    big[:80, :100] = small
    a = centroid_windows(small, xy + 0.3, half_size=8, method="gaussian")
    b = centroid_windows(big, xy + 0.3, half_size=8, method="gaussian")
    np.testing.assert_allclose(a.xy, b.xy, atol=1e-9)


def test_extractor_centroid_choice():
    xy, flux = random_field()
    img = render_stars((480, 640), xy, flux, noise=3.0)
    rms = {}
    for m in ("com", "iwcog", "gaussian"):
        c = extract_centroids(img, centroid=m)
        d, j = nearest(c, xy)
        assert len(c) == len(xy)
        rms[m] = float(np.sqrt(np.mean(d**2)))
        assert np.all(np.diff(c.flux) <= 0)
        if m == "gaussian":
            assert np.median(np.abs(c.flux[j] / flux - 1)) < 0.01  # photometry within 1%
            assert np.all(c.sigma_x > 0) and np.all(np.isfinite(c.covariance))
    assert rms["gaussian"] < 0.6 * rms["com"] and rms["iwcog"] < 0.6 * rms["com"]
    with pytest.raises(ValueError):
        extract_centroids(img, centroid="nope")


def test_measure_psf_width_and_ellipticity():
    from skyfix.detect import measure_psf

    xy = np.array([[30.2, 30.7], [80.6, 60.1]])
    img = render_stars((100, 120), xy[:1], [30000], sigma=1.5, noise=2.0)
    img += render_stars((100, 120), xy[1:], [30000], sigma=2.0, sigma_y=1.0, noise=0.0, background=0.0)
    psf = measure_psf(img, xy + 0.4)
    assert psf["ok"].all()
    assert psf["fwhm"][0] == pytest.approx(2.3548 * 1.5, rel=0.03)
    assert psf["ellipticity"][0] < 0.03
    assert psf["sigma_x"][1] == pytest.approx(2.0, rel=0.03)
    assert psf["sigma_y"][1] == pytest.approx(1.0, rel=0.05)
    assert psf["ellipticity"][1] == pytest.approx(0.5, abs=0.03)

