"""Detector-chain statistics against the configured values (fixed seeds, z and chi-square tests)."""

import math

import numpy as np
import pytest
from scipy import stats

from skyfix.errors import SimulationError, SkyfixError, UnknownNameError
from skyfix.simulate import NOISE_SOURCES, Sensor, conversion_gain_e_per_adu, preset_names
from skyfix.simulate.sensor import (
    apply_detector,
    fixed_pattern,
    poisson_constant,
    poisson_image,
    standard_normals,
)

SHAPE = (400, 500)  # 200 000 pixels
N = SHAPE[0] * SHAPE[1]
# e⁻ in, e⁻ out (gain 1, bias well above the noise, deep ADC) so statistics read directly.
PLAIN = Sensor(qe=1.0, full_well_e=1e9, read_noise_e=5.0, dark_current_e_s=40.0, prnu=0.02, dsnu_e=3.0,
               gain_e_per_adu=1.0, bit_depth=16, bias_adu=1000.0, ktc_noise_e=4.0)


def streams(seed=0):
    ss = np.random.SeedSequence(seed).spawn(4)
    return dict(zip(("shot", "dark", "read", "ktc"), (np.random.default_rng(s) for s in ss), strict=True))


def only(*sources, quantization=False):
    sw = {k: False for k in NOISE_SOURCES}
    sw.update({k: True for k in sources})
    sw["quantization"] = quantization
    return sw


def z_mean(x, mu, var):
    return (x.mean() - mu) / math.sqrt(var / x.size)


def chi2_p(x, var):
    """Two-sided p-value of the sample variance of Gaussian data against ``var``."""
    n = x.size
    q = (n - 1) * x.var(ddof=1) / var
    cdf = stats.chi2.cdf(q, n - 1)
    return 2 * min(cdf, 1 - cdf)


def test_dark_frame_mean_and_variance_are_poisson():
    t = 0.5
    img = apply_detector(np.zeros(SHAPE), PLAIN, t, streams(1), noise=only("dark")) - PLAIN.bias_adu
    lam = PLAIN.dark_current_e_s * t  # 20 e⁻
    assert abs(z_mean(img, lam, lam)) < 4
    # Poisson: Var(s²) ≈ (λ + 2λ²)/N
    assert abs(img.var() - lam) / math.sqrt((lam + 2 * lam**2) / N) < 4
    assert np.all(img == np.round(img))  # integer electrons


def test_read_noise_frame_chi_square():
    img = apply_detector(np.zeros(SHAPE), PLAIN, 1.0, streams(2), noise=only("read"))
    assert abs(z_mean(img, PLAIN.bias_adu, PLAIN.read_noise_e**2)) < 4
    assert chi2_p(img, PLAIN.read_noise_e**2) > 1e-4
    both = apply_detector(np.zeros(SHAPE), PLAIN, 1.0, streams(2), noise=only("read", "ktc"))
    assert chi2_p(both, PLAIN.read_noise_e**2 + PLAIN.ktc_noise_e**2) > 1e-4


def test_flat_frame_shot_noise_and_prnu_spread():
    s = 5000.0
    flat = np.full(SHAPE, s)
    shot = apply_detector(flat, PLAIN, 1.0, streams(3), noise=only("shot")) - PLAIN.bias_adu
    assert abs(z_mean(shot, s, s)) < 4
    assert abs(shot.var() - s) / math.sqrt(2 * s**2 / N) < 4
    # PRNU alone: the frame's relative spread is the setting
    prnu = apply_detector(flat, PLAIN, 1.0, streams(3), noise=only("prnu")) - PLAIN.bias_adu
    rel = prnu.std() / prnu.mean()
    assert abs(rel - PLAIN.prnu) < 4 * PLAIN.prnu / math.sqrt(2 * N)
    # both: Var = S + (S·prnu)²
    both = apply_detector(flat, PLAIN, 1.0, streams(3), noise=only("shot", "prnu")) - PLAIN.bias_adu
    assert both.var() == pytest.approx(s + (s * PLAIN.prnu) ** 2, rel=0.02)
    # the map is fixed: a second frame has the same pattern
    m = fixed_pattern(PLAIN, SHAPE).prnu_gain
    assert m.std() == pytest.approx(PLAIN.prnu, rel=0.01)
    assert np.corrcoef(prnu.ravel(), m.ravel())[0, 1] > 0.999


def test_dsnu_offset_spread():
    img = apply_detector(np.zeros(SHAPE), PLAIN, 1.0, streams(4), noise=only("dsnu")) - PLAIN.bias_adu
    assert chi2_p(img, PLAIN.dsnu_e**2) > 1e-4
    again = apply_detector(np.zeros(SHAPE), PLAIN, 1.0, streams(99), noise=only("dsnu"))
    assert np.array_equal(img + PLAIN.bias_adu, again)  # fixed pattern, not temporal


def test_gain_bias_quantisation_and_clipping():
    sensor = PLAIN.replace(gain_e_per_adu=4.0, bias_adu=100.0, bit_depth=12, full_well_e=12000.0)
    flat = np.full(SHAPE, 8000.0)
    img = apply_detector(flat, sensor, 1.0, streams(5), noise=only("shot", quantization=True))
    assert img.dtype == np.uint16
    adu = img.astype(float)
    assert abs(z_mean(adu, 8000 / 4 + 100, 8000 / 16 + 1 / 12)) < 4
    full = apply_detector(np.full((10, 10), 1e6), sensor, 1.0, streams(5), noise=only())
    assert np.all(full == np.float32(12000 / 4 + 100))  # full well
    # read noise is added on readout, after the well clips the charge
    full = apply_detector(np.full((100, 100), 1e6), sensor, 1.0, streams(5), noise=only("read"))
    assert full.std() == pytest.approx(sensor.read_noise_e / 4, rel=0.05)
    sat = apply_detector(np.full((10, 10), 1e6), sensor.replace(full_well_e=1e7), 1.0, streams(5),
                         noise=only(quantization=True))
    assert np.all(sat == 4095)  # ADC ceiling
    neg = apply_detector(np.zeros((100, 100)), sensor.replace(bias_adu=0.0), 1.0, streams(5),
                         noise=only("read", quantization=True))
    assert neg.min() == 0  # no wrap-around below zero


def test_streams_are_independent_and_repeatable():
    sensor = PLAIN
    rng_img = np.random.default_rng(0).uniform(0, 200, SHAPE)
    a = apply_detector(rng_img, sensor, 0.1, streams(7))
    b = apply_detector(rng_img, sensor, 0.1, streams(7))
    assert a.dtype == np.uint16 and np.array_equal(a, b)
    c = apply_detector(rng_img, sensor, 0.1, streams(8))
    assert not np.array_equal(a, c)
    # switching read noise off leaves every other draw unchanged: the difference is read noise
    full = apply_detector(rng_img, sensor, 0.1, streams(7), noise={"quantization": False})
    no_read = apply_detector(rng_img, sensor, 0.1, streams(7), noise={"quantization": False, "read": False})
    diff = full - no_read
    assert chi2_p(diff, sensor.read_noise_e**2) > 1e-4


@pytest.mark.parametrize("lam", [0.0, 0.05, 0.7, 3.0, 11.9, 25.0, 400.0])
def test_poisson_sampler_moments(lam):
    x = poisson_image(np.full(N, lam, np.float32), np.random.default_rng(11))
    if lam == 0:
        assert np.all(x == 0)
        return
    assert abs(z_mean(x, lam, lam)) < 4
    assert abs(x.var() - lam) / math.sqrt((lam + 2 * lam**2) / N) < 4


def test_poisson_sampler_distribution_with_varying_means():
    # per-pixel means spanning table, inversion and PTRS paths: sum of (x - λ)²/λ ~ N
    lam = np.random.default_rng(1).uniform(2.0, 60.0, N).astype(np.float32)
    x = poisson_image(lam, np.random.default_rng(12))
    chi = np.sum((x - lam) ** 2 / lam)
    assert abs(chi - N) / math.sqrt(2 * N + np.sum(1 / lam)) < 4
    # the exact pmf at λ = 3 (chi-square goodness of fit)
    x3 = poisson_image(np.full(N, 3.0, np.float32), np.random.default_rng(13)).astype(int)
    k = np.arange(10)
    observed = np.array([np.sum(x3 == i) for i in k[:-1]] + [np.sum(x3 >= 9)])
    expected = np.append(stats.poisson.pmf(k[:-1], 3.0), stats.poisson.sf(8, 3.0)) * N
    assert stats.chisquare(observed, expected).pvalue > 1e-4


def _pmf_pvalue(x: np.ndarray, lam: float, top: int) -> float:
    """Chi-square goodness of fit of integer draws ``x`` to Poisson(lam), ``top`` and above pooled."""
    k = np.arange(top + 1)
    observed = np.array([np.sum(x == i) for i in k[:-1]] + [np.sum(x >= top)])
    expected = np.append(stats.poisson.pmf(k[:-1], lam), stats.poisson.sf(top - 1, lam)) * x.size
    return stats.chisquare(observed, expected).pvalue


def test_dim_frames_poisson_is_exact():
    # a star tracker's sky: means below 1 e⁻ (one inverted uniform a pixel) with bright pixels
    # among them (Generator.poisson): the exact pmf at 0.2, and the chi-square of varying means
    x = poisson_image(np.full(N, 0.2, np.float32), np.random.default_rng(21)).astype(int)
    assert _pmf_pvalue(x, 0.2, 4) > 1e-4
    lam = np.random.default_rng(2).uniform(0.0, 0.9, N).astype(np.float32)
    lam[::50] = 40.0
    x = poisson_image(lam, np.random.default_rng(22))
    chi = np.sum((x - lam) ** 2 / np.maximum(lam, 1e-9))
    assert abs(chi - N) / math.sqrt(2 * N + np.sum(1 / np.maximum(lam, 1e-3))) < 4
    assert abs(x.mean() - lam.mean()) < 4 * math.sqrt(lam.mean() / N)


@pytest.mark.parametrize("lam", [0.01, 0.2, 3.0])
def test_constant_poisson_sparse_and_table_paths_are_exact(lam):
    # below 0.25: the non-zero pixels found by geometric gaps; above: a table per pixel
    x = poisson_constant(lam, (300, 400), np.random.default_rng(23)).astype(int).ravel()
    assert _pmf_pvalue(x, lam, 3 if lam < 1 else 9) > 1e-4
    assert abs(x.mean() - lam) < 4 * math.sqrt(lam / x.size)


@pytest.mark.parametrize("floor", [0.0, 0.2, 5.0])
def test_poisson_of_a_gain_map_and_constant_into_a_frame_are_the_plain_draws(floor):
    # poisson_image(lam, rng, gain) is poisson_image(lam * gain) draw for draw (the product in
    # float32, not stored on a dark frame), and poisson_constant(…, into=frame) adds exactly its
    # own draws to the frame — on the dark path's two passes (most pixels 0 or 1 by bounds, the
    # rest inverted or PTRS) and on the bright path's table
    rng = np.random.default_rng(4)
    lam = (floor + rng.uniform(0.0, 0.6, (120, 90))).astype(np.float32)
    lam[::17, ::13] = rng.uniform(2.0, 3e3, lam[::17, ::13].shape)
    gain = (1.0 + 0.02 * rng.standard_normal(lam.shape)).astype(np.float32)
    a = poisson_image(lam, np.random.default_rng(5), gain)
    b = poisson_image(lam * gain, np.random.default_rng(5))
    assert a.dtype == np.float32 and np.array_equal(a, b) and a.sum() > 0
    for mean in (0.05, 0.7):
        frame = a.copy()
        out = poisson_constant(mean, lam.shape, np.random.default_rng(6), into=frame)
        assert out is frame
        assert np.array_equal(frame, a + poisson_constant(mean, lam.shape, np.random.default_rng(6)))
    with pytest.raises(SimulationError):
        poisson_image(lam, rng, gain[:-1])
    with pytest.raises(SimulationError):
        poisson_constant(0.1, lam.shape, rng, into=a.astype(np.float64))


def test_standard_normals_are_the_quantiles_of_their_uniforms():
    from scipy.special import ndtri

    z = standard_normals(np.random.default_rng(31), (N,))
    u = np.random.default_rng(31).random(N)  # the same stream: one uniform a deviate
    assert z.dtype == np.float32
    assert np.max(np.abs(z - ndtri(u))) < 3e-7 * max(1.0, float(np.max(np.abs(z))))  # float32 rounding
    assert stats.kstest(z, "norm").pvalue > 1e-4
    assert abs(z.mean()) < 4 / math.sqrt(N) and abs(z.std() - 1) < 4 / math.sqrt(2 * N)


def test_has2_conversion_gain_eq_3_15():
    # thesis 002 Table 3-1: 1.15 V swing, 14.8 µV/e⁻, amplifier gain 1, 12 bit
    assert conversion_gain_e_per_adu(1.15, 14.8, 12) == pytest.approx(18.975, abs=1e-3)
    has2 = Sensor.from_preset("has2")
    assert has2.gain_e_per_adu == pytest.approx(18.975, abs=1e-3)
    assert has2.qe == 0.333 and has2.read_noise_e == 75 and has2.dsnu_e == 115
    assert has2.prnu == 0.018 and has2.dark_current_e_s == 190 and has2.ktc_noise_e == 0


def test_presets_load_and_round_trip(tmp_path):
    names = preset_names()
    assert {"has2", "mt9v022", "ov5642", "mt9p031", "droid_x2", "sunsat", "generic"} <= set(names)
    for name in names:
        s = Sensor.from_preset(name)
        p = tmp_path / f"{name}.toml"
        p.write_text(s.to_toml())
        assert Sensor.load(p) == s


def test_bad_sensor_input():
    with pytest.raises(UnknownNameError, match="unknown preset"):
        Sensor.from_preset("no-such-sensor")
    with pytest.raises(SkyfixError, match="read_noise_e"):
        Sensor(read_noise_e=-1.0)
    with pytest.raises(SimulationError, match="bit_depth"):
        Sensor(bit_depth=20)
    with pytest.raises(SimulationError, match="unknown sensor keys"):
        Sensor.from_dict({"qe": 0.5, "colour": "red"})
    with pytest.raises(SimulationError, match="noise sources"):
        apply_detector(np.zeros((4, 4)), PLAIN, 1.0, streams(), noise={"shott": False})
