"""Default star extractor on rendered frames: positions against truth, rejections, bad frames."""

import numpy as np
import pytest
from scipy.special import erf

from skyfix.detect import Centroids, estimate_background, extract_centroids


def render_stars(shape, xy, flux, sigma=1.2, sigma_y=None, background=100.0, noise=3.0, seed=0):
    """Gaussian stars integrated over pixels (the pixel convention of docs/design.md) + Gaussian noise.

    ``background`` may be a scalar or an (H, W) array. Independent of skyfix.simulate.
    """
    h, w = shape
    sy = sigma if sigma_y is None else sigma_y
    img = np.zeros(shape, np.float64) + background
    edges_x = np.arange(w + 1) - 0.5
    edges_y = np.arange(h + 1) - 0.5
    for (x0, y0), f in zip(np.asarray(xy, float).reshape(-1, 2), np.atleast_1d(flux), strict=True):
        px = np.diff(0.5 * erf((edges_x - x0) / (np.sqrt(2) * sigma)))
        py = np.diff(0.5 * erf((edges_y - y0) / (np.sqrt(2) * sy)))
        img += f * np.outer(py, px)
    if noise > 0:
        img += np.random.default_rng(seed).normal(0.0, noise, shape)
    return img.astype(np.float32)


def nearest(c: Centroids, xy):
    d = np.hypot(c.x[:, None] - xy[:, 0], c.y[:, None] - xy[:, 1])
    return d.min(axis=0), d.argmin(axis=0)


def random_field(n=40, shape=(480, 640), seed=3, margin=15):
    rng = np.random.default_rng(seed)
    xy = np.column_stack([rng.uniform(margin, shape[1] - margin, n),
                          rng.uniform(margin, shape[0] - margin, n)])
    # keep stars apart so none blend
    keep = [0]
    for i in range(1, n):
        if np.hypot(*(xy[keep] - xy[i]).T).min() > 12:
            keep.append(i)
    xy = xy[keep]
    flux = 10 ** rng.uniform(3.0, 4.5, len(xy))
    return xy, flux


@pytest.mark.parametrize("x0,y0", [(20.0, 30.0), (20.5, 30.5), (20.25, 29.8), (41.7, 12.1)])
def test_pixel_convention_single_star(x0, y0):
    img = render_stars((64, 80), [(x0, y0)], [20000.0], noise=1.0)
    c = extract_centroids(img)
    assert len(c) == 1
    assert c.x[0] == pytest.approx(x0, abs=0.03) and c.y[0] == pytest.approx(y0, abs=0.03)
    assert c.image_shape == (64, 80)
    assert c.background_level == pytest.approx(100.0, abs=0.5)
    assert c.noise == pytest.approx(1.0, rel=0.2)


def test_field_positions_and_order():
    xy, flux = random_field()
    img = render_stars((480, 640), xy, flux, noise=3.0)
    c = extract_centroids(img)
    assert len(c) == len(xy)
    d, j = nearest(c, xy)
    assert d.max() < 0.15, d.max()
    assert np.all(np.diff(c.flux) <= 0)  # brightest first
    # the brightest detection is the brightest star, and the flux order follows the truth
    assert j[np.argmax(flux)] == 0
    assert np.corrcoef(np.log(c.flux[j]), np.log(flux))[0, 1] > 0.99
    assert c.xy.shape == (len(c), 2) and c.xy.dtype == np.float64
    assert np.all(c.snr > 5) and np.all(c.area >= 3) and not c.saturated.any()


def test_max_stars_keeps_the_brightest():
    xy, flux = random_field()
    img = render_stars((480, 640), xy, flux, noise=3.0)
    c = extract_centroids(img, max_stars=5)
    assert len(c) == 5
    d, _ = nearest(c.subset(slice(None)), xy[np.argsort(-flux)[:5]])
    assert d.max() < 0.15


def test_flux_and_centroid_noise_estimate():
    """Flux close to the rendered total; sigma_x near the scatter over noise realisations."""
    xs, sig = [], []
    for seed in range(30):
        img = render_stars((48, 48), [(23.3, 24.6)], [3000.0], sigma=1.3, noise=5.0, seed=seed)
        c = extract_centroids(img)
        assert 1 <= len(c) <= 2  # a 5σ noise peak now and then in 30 frames is fair
        assert c.x[0] == pytest.approx(23.3, abs=0.5) and c.y[0] == pytest.approx(24.6, abs=0.5)
        xs.append(c.x[0])
        sig.append(c.sigma_x[0])
        assert c.flux[0] == pytest.approx(3000.0, rel=0.08)
    scatter = np.std(xs)
    assert 0.5 < np.mean(sig) / scatter < 2.0, (np.mean(sig), scatter)
    assert abs(np.mean(xs) - 23.3) < 3 * scatter / np.sqrt(30) + 0.01


def test_elongation_from_moments():
    img = render_stars((80, 80), [(40.0, 40.0)], [1e5], sigma=3.0, sigma_y=1.0, noise=1.0)
    c = extract_centroids(img)
    assert len(c) == 1
    assert 2.4 < c.elongation[0] < 3.2
    rnd = extract_centroids(render_stars((80, 80), [(40.0, 40.0)], [1e5], sigma=1.5, noise=1.0))
    assert rnd.elongation[0] < 1.1


def test_background_gradient_and_vignetting():
    """Sky glow rising 200 → 500 ADU across the frame with 30% vignetting: no false stars."""
    h, w = 480, 640
    yy, xx = np.mgrid[0:h, 0:w]
    r2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / (w / 2) ** 2
    sky = (200 + 300 * xx / w) * (1 - 0.3 * r2)
    xy, flux = random_field(shape=(h, w))
    img = render_stars((h, w), xy, flux, background=sky, noise=3.0)
    c = extract_centroids(img)
    d, _ = nearest(c, xy)
    assert len(c) == len(xy)  # every star, nothing else
    assert d.max() < 0.2
    err = np.abs(estimate_background(img).level_map(img.shape) - sky)
    assert np.median(err) < 0.5 and np.percentile(err, 99) < 3.0  # noise is 3 ADU


def test_linear_gradient_background_exact():
    h, w = 300, 400
    yy, xx = np.mgrid[0:h, 0:w]
    sky = 50 + 0.8 * xx - 0.5 * yy  # 320 ADU across the frame, corners included
    img = render_stars((h, w), [], [], background=sky, noise=2.0)
    bg = estimate_background(img)
    err = bg.level_map(img.shape) - sky
    assert np.abs(err).max() < 1.5 and abs(np.median(err)) < 0.2
    assert bg.global_noise == pytest.approx(2.0, rel=0.1)  # the gradient is not noise
    assert len(extract_centroids(img)) == 0


def test_hot_pixels_rejected():
    xy, flux = random_field(n=20)
    img = render_stars((480, 640), xy, flux, noise=3.0)
    rng = np.random.default_rng(9)
    hot = np.column_stack([rng.integers(5, 635, 30), rng.integers(5, 475, 30)])
    img[hot[:, 1], hot[:, 0]] += rng.uniform(300, 3000, 30).astype(np.float32)
    c = extract_centroids(img)
    d_hot, _ = nearest(c, hot.astype(float))
    d_star, _ = nearest(c, xy)
    assert np.all(d_hot > 1.5) or np.sum(d_hot < 1.5) <= np.sum(np.hypot(*(hot[:, None] - xy).T).min(0) < 3)
    assert d_star.max() < 0.2
    assert len(c) == len(xy)


def test_large_blob_rejected():
    """A Moon-like disk (radius 40 px) is dropped; stars away from its glare stay."""
    h, w = 480, 640
    yy, xx = np.mgrid[0:h, 0:w]
    moon = 3000.0 * (np.hypot(xx - 500, yy - 120) < 40)
    xy = np.array([[100.0, 100.0], [200.0, 350.0], [320.0, 240.0], [60.0, 420.0]])
    img = render_stars((h, w), xy, [5000, 8000, 3000, 6000], background=100 + moon, noise=3.0)
    c = extract_centroids(img)
    d, _ = nearest(c, xy)
    assert len(c) == 4 and d.max() < 0.2


def test_saturated_star_flagged():
    img = render_stars((100, 100), [(30.0, 30.0), (70.0, 60.0)], [4e6, 2e4], noise=3.0)
    img = np.clip(img, 0, 65535).round()
    c = extract_centroids(img)
    assert len(c) == 2
    i_sat = int(np.argmin(np.hypot(c.x - 30, c.y - 30)))
    assert c.saturated[i_sat] and not c.saturated[1 - i_sat]
    assert c.x[i_sat] == pytest.approx(30.0, abs=0.1)
    # a frame whose maximum is not full scale has no saturated stars
    assert not extract_centroids(img * 0.5).saturated.any()


def test_8bit_quantised_quiet_sky():
    """8-bit frame with sub-level noise: the noise estimate must not collapse to zero."""
    xy, flux = random_field(n=25, seed=5)
    img = np.clip(render_stars((480, 640), xy, flux / 20, sigma=1.3, background=12.0, noise=0.6), 0, 255)
    img = np.round(img).astype(np.uint8)
    c = extract_centroids(img)
    assert 0.2 < c.noise < 1.5
    d, _ = nearest(c, xy)
    bright = flux / 20 > 300
    assert np.all(d[bright] < 0.3)
    assert len(c) <= len(xy)


@pytest.mark.parametrize("name", ["zeros", "constant", "saturated", "noise", "1x1", "2x2", "3x3", "all_nan",
                                  "inf_noise", "bool", "int16_negative"])
def test_bad_frames_give_empty(name):
    rng = np.random.default_rng(0)
    frames = {
        "zeros": np.zeros((480, 640), np.uint8),
        "constant": np.full((480, 640), 1234.0, np.float32),
        "saturated": np.full((480, 640), 65535, np.uint16),
        "noise": rng.normal(100.0, 5.0, (480, 640)).astype(np.float32),
        "1x1": np.ones((1, 1)),
        "2x2": np.ones((2, 2)),
        "3x3": np.ones((3, 3)),
        "all_nan": np.full((50, 50), np.nan),
        "inf_noise": np.where(rng.random((64, 64)) < 0.7, np.inf, 1.0),
        "bool": np.zeros((30, 30), bool),
        "int16_negative": np.full((40, 40), -5, np.int16),
    }
    c = extract_centroids(frames[name])
    assert isinstance(c, Centroids) and len(c) == 0
    assert c.xy.shape == (0, 2)


def test_nan_pixels_ignored():
    img = render_stars((100, 120), [(40.0, 50.0), (90.0, 30.0)], [10000, 20000], noise=2.0)
    img[10:20, 10:20] = np.nan
    img[70, :] = np.nan
    c = extract_centroids(img)
    d, _ = nearest(c, np.array([[40.0, 50.0], [90.0, 30.0]]))
    assert len(c) == 2 and d.max() < 0.1


def test_centroids_container():
    c = Centroids.empty((10, 20))
    assert len(c) == 0 and c.image_shape == (10, 20)
    with pytest.raises(ValueError):
        Centroids(x=[1, 2], y=[1], flux=[1, 2], area=[1, 2], snr=[1, 2], elongation=[1, 1], peak=[1, 1],
                  sigma_x=[0, 0], sigma_y=[0, 0], saturated=[False, False])
    img = render_stars((64, 64), [(20.0, 20.0), (40.0, 44.0)], [9000, 3000], noise=1.0)
    c = extract_centroids(img)
    rec = c.to_records()
    assert rec[0]["x"] == pytest.approx(20.0, abs=0.05) and rec[0]["saturated"] is False
    assert len(c.brightest(1)) == 1 and c.flags is c.saturated


def test_background_methods_rows_and_global():
    """Per-row offsets (an AC-coupled readout's droop, thesis 004): the row model follows them."""
    h, w = 240, 320
    rng = np.random.default_rng(4)
    rows = 100 + 40 * np.sin(np.arange(h) / 3.0) + rng.normal(0, 5, h)  # varies row to row
    xy, flux = random_field(n=15, shape=(h, w), seed=8)
    img = render_stars((h, w), xy, flux, background=rows[:, None] + np.zeros((1, w)), noise=2.0)
    by_rows = estimate_background(img, method="rows")
    assert by_rows.level.shape == (h, 1)
    assert np.median(np.abs(by_rows.level_map(img.shape)[:, 0] - rows)) < 1.5  # smoothing mixes 3 rows
    flat = render_stars((h, w), xy, flux, background=100.0, noise=2.0)
    glob = estimate_background(flat, method="global")
    assert glob.level.shape == (1, 1) and glob.global_level == pytest.approx(100.0, abs=0.3)
    assert glob.global_noise == pytest.approx(2.0, rel=0.1)
    c = extract_centroids(flat, background=glob)
    d, _ = nearest(c, xy)
    assert len(c) == len(xy) and d.max() < 0.15
    with pytest.raises(ValueError):
        estimate_background(flat, method="nope")


@pytest.mark.parametrize("sep", [5.0, 7.0])
def test_deblend_touching_stars(sep):
    xy = np.array([[50.0, 50.0], [50.0 + sep, 50.7]])
    img = render_stars((100, 100), xy, [20000, 8000], sigma=1.2, noise=3.0)
    merged = extract_centroids(img, deblend=None)
    assert len(merged) == 1  # one blob whose centroid lies between the two
    c = extract_centroids(img)
    d, _ = nearest(c, xy)
    assert len(c) == 2 and d.max() < 0.3 and c.meta["n_deblended"] == 1
    # a single bright star (any noise) is never split
    single = render_stars((100, 100), [(50.3, 49.6)], [2e5], sigma=1.5, noise=3.0)
    assert len(extract_centroids(single)) == 1


@pytest.mark.parametrize("psf_sigma", [0.35, 0.5])
def test_sharp_optics_stars_are_not_hot_pixels(psf_sigma):
    """Undersampled stars (most light in one pixel) survive the hot-pixel test, even centred."""
    xy = np.array([[30.0, 30.0], [45.5, 20.2]])
    img = render_stars((64, 64), xy, [5000, 5000], sigma=psf_sigma, noise=2.0)
    c = extract_centroids(img)
    d, _ = nearest(c, xy)
    assert len(c) == 2 and d.max() < 0.25


def test_many_hot_pixels_do_not_crowd_out_stars():
    """An uncalibrated long exposure: 1000 hot pixels (0.3%), brighter than most stars."""
    xy, flux = random_field(n=25, seed=6)
    img = render_stars((480, 640), xy, flux, noise=3.0)
    rng = np.random.default_rng(12)
    hy, hx = rng.integers(0, 480, 1000), rng.integers(0, 640, 1000)
    img[hy, hx] += rng.uniform(2000, 20000, 1000).astype(np.float32)
    c = extract_centroids(img, max_stars=30)
    d, _ = nearest(c, xy)
    near_hot = np.hypot(xy[:, 0, None] - hx, xy[:, 1, None] - hy).min(axis=1) < 4
    assert np.all(d[~near_hot] < 0.2)  # every star clear of a hot pixel is found
    dd = np.hypot(c.x[:, None] - xy[:, 0], c.y[:, None] - xy[:, 1]).min(axis=1)
    assert np.sum(dd > 1.5) <= 2  # and almost nothing else (clusters of 4+ hot pixels may pass)


def test_streak_is_measured_not_dropped():
    """Motion blur: a 20-px streak at 30° is kept, with its length axis and direction."""
    t = np.linspace(-10, 10, 41)
    ang = np.radians(30.0)
    pts = np.column_stack([60 + t * np.cos(ang), 50 + t * np.sin(ang)])
    img = render_stars((100, 120), pts, np.full(len(pts), 800.0), sigma=1.2, noise=2.0)
    c = extract_centroids(img)
    assert len(c) == 1
    assert c.x[0] == pytest.approx(60.0, abs=0.1) and c.y[0] == pytest.approx(50.0, abs=0.1)
    assert c.elongation[0] > 4
    assert c.angle[0] == pytest.approx(ang, abs=0.02)


def test_particle_tracks_rejected_trailed_stars_kept():
    """Cosmic rays are one pixel wide; a trailed star keeps the PSF's width across its trail."""
    xy, flux = random_field(n=20, seed=9)
    img = render_stars((480, 640), xy, flux, sigma=1.3, noise=3.0)
    tracks = [((100, 50), (118, 58)), ((500, 400), (490, 420)), ((300, 200), (330, 201))]
    for (x0, y0), (x1, y1) in tracks:
        n = int(max(abs(x1 - x0), abs(y1 - y0))) + 1
        rows = np.round(np.linspace(y0, y1, n)).astype(int)
        img[rows, np.round(np.linspace(x0, x1, n)).astype(int)] += 800.0
    t = np.linspace(-8, 8, 33)
    trail = np.column_stack([560 + t, 60 + 0.3 * t])
    img += render_stars((480, 640), trail, np.full(33, 300.0), sigma=1.3, noise=0.0, background=0.0)
    c = extract_centroids(img)
    mid = np.array([[0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1])] for a, b in tracks])
    d_track, _ = nearest(c, mid)
    assert np.all(d_track > 5)  # no track survives
    d_trail, k = nearest(c, np.array([[560.0, 60.0]]))
    assert d_trail[0] < 0.3 and c.elongation[k[0]] > 3  # the trailed star does
    assert len(extract_centroids(img, reject_tracks=False)) >= len(c) + 2
