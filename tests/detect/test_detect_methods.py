"""The seeds' detectors, selectable by name: thesis 000's hill climb and thesis 004's region growing."""

import numpy as np
import pytest

from skyfix.detect import METHODS, extract_centroids
from skyfix.detect.hillclimb import extract_hillclimb
from skyfix.detect.region_grow import extract_region_grow
from skyfix.detect.regionprops import extract_regionprops, perona_malik
from tests.detect.test_detect import nearest, random_field, render_stars


@pytest.fixture(scope="module")
def field():
    xy, flux = random_field(n=30, seed=11)
    return xy, flux, render_stars((480, 640), xy, flux, sigma=1.5, noise=3.0)


def test_methods_by_name(field):
    xy, flux, img = field
    assert tuple(METHODS) == ("components", "threshold_hillclimb", "region_grow", "regionprops")
    # a 3×3 ROI cuts a σ = 1.5 px star's wings: thesis 000's CoM is pulled toward the peak
    # pixel (the S-curve), by up to half a pixel
    tol = {"components": 0.1, "threshold_hillclimb": 0.5, "region_grow": 0.2, "regionprops": 0.2}
    for m in METHODS:
        c = extract_centroids(img, method=m)
        d, j = nearest(c, xy)
        bright = flux > 5000
        assert np.all(d[bright] < tol[m]), (m, d[bright].max())  # every bright star found, placed
        assert np.all(np.diff(c.flux) <= 0)
        dd = np.hypot(c.x[:, None] - xy[:, 0], c.y[:, None] - xy[:, 1]).min(axis=1)
        assert np.all(dd < 1.0), m  # nothing but stars
    with pytest.raises(ValueError):
        extract_centroids(img, method="nope")


def test_hillclimb_rejects_lone_hot_pixels_and_uses_3x3_roi(field):
    xy, flux, img = field
    img = img.copy()
    img[100, 100] += 5000.0  # a hot pixel: one pixel above T, fails the 4-pixel cluster test
    c = extract_hillclimb(img)
    assert np.hypot(c.x - 100, c.y - 100).min() > 2
    assert c.area.max() <= 9  # the ROI is 3×3


def test_hillclimb_corrected_com_on_a_symmetric_star():
    # the printed equation (n subtracted once, no ROI offset) would put this star elsewhere
    img = render_stars((40, 40), [(20.0, 21.0)], [20000.0], sigma=0.9, noise=0.5)
    c = extract_hillclimb(img)
    assert len(c) == 1
    assert c.x[0] == pytest.approx(20.0, abs=0.02) and c.y[0] == pytest.approx(21.0, abs=0.02)


def test_region_grow_size_border_and_shape_tests():
    stars = [(100.0, 80.0), (200.0, 150.0), (1.0, 60.0)]  # the last touches the frame edge
    img = render_stars((240, 320), stars, [20000, 20000, 20000], sigma=1.5, noise=2.0)
    img[30, 30] += 3000.0  # one-pixel region: below the 10-pixel minimum
    # a 40-pixel streak: a − b ≥ 12 px fails the shape test
    img[120:123, 240:280] += 300.0
    c = extract_region_grow(img)
    d, _ = nearest(c, np.array(stars[:2]))
    assert len(c) == 2 and d.max() < 0.1
    assert np.all((c.area >= 10) & (c.area <= 300))


def test_region_grow_bad_frames():
    for frame in (np.zeros((50, 50)), np.full((50, 50), 7.0)):
        assert len(extract_region_grow(frame)) == 0 and len(extract_hillclimb(frame)) == 0


def test_regionprops_eccentricity_area_and_prefilters():
    stars = [(100.0, 80.0), (200.0, 150.0)]
    img = render_stars((240, 320), stars, [20000, 20000], sigma=1.5, noise=2.0)
    img[120:122, 230:290] += 200.0  # a banding streak: eccentricity ≈ 1
    img[40, 40] += 3000.0  # one pixel: below the minimum area
    for prefilter in (None, "smooth", "diffusion"):
        c = extract_regionprops(img, prefilter=prefilter)
        d, _ = nearest(c, np.array(stars))
        assert d.max() < 0.1, prefilter
        # linear smoothing spreads the hot pixel over 3×3, past the minimum area; diffusion
        # (edge-preserving) and the raw threshold do not
        assert len(c) == (3 if prefilter == "smooth" else 2), prefilter
    assert len(extract_regionprops(img, max_eccentricity=None)) == 3  # the streak is back
    with pytest.raises(ValueError):
        extract_regionprops(img, prefilter="nope")


def test_perona_malik_smooths_noise_keeps_stars():
    rng = np.random.default_rng(3)
    img = render_stars((80, 80), [(40.0, 40.0)], [30000], sigma=1.2, noise=0.0) + rng.normal(0, 5, (80, 80))
    out = perona_malik(img, iterations=10, kappa=15.0)
    assert np.std(out[:20, :20]) < 0.6 * np.std(img[:20, :20])  # sky noise down
    assert out[40, 40] > 0.8 * img[40, 40]  # the star's peak survives (an edge, not noise)
