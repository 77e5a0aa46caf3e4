"""Text burned into a frame (issue 26 part 5): a caption's letters are found and left out, so a
processed photograph — stretched, with nebulosity, colour, JPEG, a caption — solves; a compact
cluster lined up as closely (the Pleiades) is not taken for text."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

import skyfix
from skyfix.detect import extract_centroids
from skyfix.detect.text import MIN_LETTERS, text_like
from skyfix.geometry import attitude_from_radec_roll, radec_to_vector
from skyfix.io import read_image
from skyfix.simulate import render
from skyfix.simulate.photograph import photograph

ARCSEC = math.pi / (180 * 3600)


@pytest.fixture(scope="module")
def frame():
    A = attitude_from_radec_roll(math.radians(84.0), math.radians(-2.0), math.radians(20.0))
    return render(A, "generic", seed=3, epoch=2026.9)


@pytest.mark.parametrize("caption", ["M42 & Horsehead  30x60s  ISO 1600", None])
def test_a_captioned_photograph_solves_and_its_letters_are_left_out(frame, tmp_path, caption):
    path = tmp_path / "photo.jpg"
    Image.fromarray(photograph(frame.image, caption=caption, seed=1)).save(path, quality=85)
    found = extract_centroids(read_image(path), max_stars=200)
    letters = text_like(found)
    if caption:
        assert letters.sum() >= 20  # the caption's letters and signs
        assert np.all(found.y[letters] > 0.85 * frame.image.shape[0])  # all on the caption's row
        assert letters[:24].sum() >= MIN_LETTERS  # among the brightest: they took stars' places
    else:
        assert not letters.any()
    sol = skyfix.solve(path, epoch=2026.9)
    assert sol.solved, sol.reason
    truth = radec_to_vector(math.radians(frame.truth["ra_deg"]), math.radians(frame.truth["dec_deg"]))
    seen = radec_to_vector(math.radians(sol.center_ra_deg), math.radians(sol.center_dec_deg))
    assert math.acos(min(1.0, float(truth @ seen))) / ARCSEC < 20.0  # 48″ pixels
    matched = np.array([(m.x, m.y) for m in sol.matches])
    for x, y in found.xy[letters]:  # no letter among the matched stars
        assert np.hypot(*(matched - (x, y)).T).min() > 2.0


def test_a_star_cluster_in_a_row_is_not_text(real_dir):
    """Six Pleiades in a chain on a 512-pixel wide-field frame: bright and faint, round."""
    found = extract_centroids(read_image(real_dir / "cedar-solve" / "pleiades.jpg"), max_stars=200)
    assert not text_like(found).any()
