"""Thesis 002 Tables 4-1/4-2 style: centroid error against slew rate with the HAS2 preset.

One star at a random position per run, the same rate about all three camera axes, 1/12 s
exposure, full HAS2 noise, thesis-style centroiding (the ROI is centred on the first pixel over
the signal threshold in raster order; centre of mass of ``I − η`` over pixels above the noise
threshold ``η``). The star's magnitude is set so that the error std at rest is ~0.03 px, as the
thesis calibrated it (its magnitude, FWHM, aperture and thresholds are not given).
"""


import numpy as np
import pytest

from skyfix.camera import camera_from_preset
from skyfix.catalog import Catalog
from skyfix.geometry import attitude_from_radec_roll
from skyfix.simulate import Optics, Sensor, render

CAMERA = camera_from_preset("has2")
SENSOR = Sensor.from_preset("has2")
OPTICS = Optics.from_preset("has2")
A = attitude_from_radec_roll(1.0, 0.3, 0.2)
MAG = 3.5
EXPOSURE = 1 / 12


def thesis_centroid(img, x0, y0, roi=6, k_signal=10.0, k_noise=3.0):
    """Thesis 002 §2.1.3 COM: ROI at the first pixel over the signal threshold (raster order)."""
    bg = np.median(img)
    sd = 1.4826 * np.median(np.abs(img - bg))
    eta, signal = bg + k_noise * sd, bg + k_signal * sd
    r0, c0 = int(round(y0)), int(round(x0))
    over = img[r0 - 20:r0 + 21, c0 - 20:c0 + 21] > signal
    if not over.any():
        return None  # not detected
    pr, pc = np.unravel_index(np.argmax(over), over.shape)
    pr, pc, h = pr + r0 - 20, pc + c0 - 20, roi // 2
    w = img[pr - h:pr + h, pc - h:pc + h].astype(float) - eta
    w[w < 0] = 0
    yy, xx = np.mgrid[pr - h:pr + h, pc - h:pc + h]
    return (w * xx).sum() / w.sum(), (w * yy).sum() / w.sum()


def centroid_errors(rate_dps, runs, seed=0):
    """(truth − measured) per detected run (K, 2) and the number of missed detections."""
    rng = np.random.default_rng(seed)
    errors, missed = [], 0
    for i in range(runs):
        xy = rng.uniform(100, CAMERA.width - 100, (1, 2))
        cat = Catalog(np.array([1]), CAMERA.pixel_to_ray(xy) @ A, np.array([MAG], np.float32), np.zeros(1),
                      np.zeros(1), 2025.0)
        rate = np.radians([rate_dps] * 3) if rate_dps else None
        f = render(A, CAMERA, sensor=SENSOR, optics=OPTICS, exposure_s=EXPOSURE, catalog=cat, rate_rad_s=rate,
                   seed=seed * 1000 + i, epoch=2025.0, sky_mag_arcsec2=None)
        star = f.truth["stars"][0]
        c = thesis_centroid(f.image, star["x"], star["y"])
        if c is None:
            missed += 1
            continue
        errors.append((star["x"] - c[0], star["y"] - c[1]))
    return np.array(errors), missed


def test_centroid_error_grows_with_slew_rate():
    e0, miss0 = centroid_errors(0.0, 30, seed=1)
    e4, _ = centroid_errors(0.4, 30, seed=1)
    assert miss0 == 0
    std0 = e0.std(axis=0)
    assert np.all((0.015 < std0) & (std0 < 0.05))  # thesis: 0.034, 0.031 px
    assert np.all(e4.std(axis=0) > 1.5 * std0)
    # smear skews the raster-first ROI: x biased negative, y positive, as in Table 4-1
    assert e4.mean(axis=0)[0] < e0.mean(axis=0)[0] and e4.mean(axis=0)[1] > e0.mean(axis=0)[1]


@pytest.mark.slow
def test_table_4_1_sweep(capsys):
    rows = []
    for rate in (0.0, 0.1, 0.2, 0.3, 0.4, 0.5):
        e, missed = centroid_errors(rate, 100, seed=2)
        m, s = e.mean(axis=0), e.std(axis=0)
        rows.append((rate, *m, *s, missed))
    with capsys.disabled():
        print("\nrate deg/s | x mean | x std | y mean | y std | missed (of 100)")
        for r in rows:
            print(f"{r[0]:.1f} | {r[1]:+.4f} | {r[3]:.4f} | {r[2]:+.4f} | {r[4]:.4f} | {r[5]}")
    stds = np.array([r[3] + r[4] for r in rows])
    assert np.all(np.diff(stds[:5]) > -0.01)  # grows with rate
