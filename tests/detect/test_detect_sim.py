"""The extractor on frames from skyfix's own simulator (catalogue stars, detector noise, hot
pixels, cosmic rays) for several of the seeds' cameras, against the simulator's truth.

Thresholds are the counts measured at three attitudes per preset, lowered by two for margin.
The unmatched detections left are short cosmic-ray hits (the simulator draws 5 per frame).
"""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from skyfix.detect import extract_centroids
from skyfix.geometry import attitude_from_radec_roll

simulate = pytest.importorskip("skyfix.simulate")

# preset: (min matched among the 20 brightest, max RMS px of matched stars with SNR > 20)
CASES = {
    "generic": (18, 0.12),  # measured 20, 20, 20; 0.04–0.10 px
    "has2": (11, 0.12),  # 17, 16, 13; 0.03–0.07 px
    "sunsat": (16, 0.15),  # 19, 18, 18; 0.06–0.08 px (6-bit)
}


@pytest.mark.parametrize("preset", sorted(CASES))
@pytest.mark.parametrize("att", [(1.4, 0.3, 0.2), (2.5, 1.0, 2.0)])
def test_simulated_frames_against_truth(preset, att):
    need, max_rms = CASES[preset]
    frame = simulate.render(attitude_from_radec_roll(*att), preset, epoch=2025.0, seed=1, hot_pixels=50,
                            cosmic_rays=5)
    truth = np.array([[s["x"], s["y"]] for s in frame.truth["stars"]])
    gain = frame.truth["sensor"]["gain_e_per_adu"]
    c = extract_centroids(frame.image, max_stars=20, centroid="gaussian", gain=gain)
    d, _ = cKDTree(truth).query(c.xy)
    matched = d < 1.0
    assert matched.sum() >= need, (preset, int(matched.sum()))
    bright = matched & (c.snr > 20)
    if bright.any():
        assert math.sqrt(np.mean(d[bright] ** 2)) < max_rms
    # the simulator's hot pixels never come out as stars
    hot = np.array([[h["x"], h["y"]] for h in frame.truth["hot_pixels"]], dtype=float)
    if len(hot):
        dh, _ = cKDTree(hot).query(c.xy)
        assert np.all((dh > 1.0) | matched)
