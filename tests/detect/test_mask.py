"""A sky mask (issue 26: horizons, trees, captions, all-sky corners): stars on or within 3 px of
a masked pixel are dropped, the frame solves from the rest, and a mask that cannot be the frame's
is a one-line error."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

import skyfix
from skyfix.cli import app
from skyfix.detect import extract_centroids
from skyfix.detect.mask import MASK_MARGIN_PX, as_mask, sky_only
from skyfix.errors import InputError
from skyfix.geometry import radec_to_vector
from skyfix.io import read_image
from tests.conftest import EXAMPLES

SKY = EXAMPLES / "sky.png"


def test_stars_on_or_next_to_masked_pixels_are_dropped():
    image = read_image(SKY)
    h, w = image.shape
    mask = np.ones((h, w), np.uint8)
    mask[:, : w // 2] = 0  # the left half is "foreground"
    found = extract_centroids(image)
    kept = sky_only(found, as_mask(mask, (h, w)))
    edge = w // 2 + MASK_MARGIN_PX - 0.5
    assert len(kept) > 10 and np.all(kept.x > edge)
    assert len(kept) == np.count_nonzero(np.rint(found.x) >= w // 2 + MASK_MARGIN_PX)
    assert np.all(np.diff(kept.flux) <= 0)  # brightest first, as found


def test_a_masked_frame_solves_from_the_sky_half(tmp_path):
    full = skyfix.solve(SKY)
    h, w = read_image(SKY).shape
    mask = np.full((h, w), 255, np.uint8)
    mask[:, : w // 2] = 0
    half = skyfix.solve(SKY, mask=mask)
    assert half.solved and full.solved
    assert min(m.x for m in half.matches) > w // 2 and half.n_matched < full.n_matched
    a, b = (radec_to_vector(*np.radians([s.ra_deg, s.dec_deg])) for s in (half, full))
    sep = np.degrees(np.arccos(min(1.0, float(a @ b)))) * 3600
    assert sep < 5.0  # the same attitude (15° frame, 40″ pixels)
    path = tmp_path / "mask.png"
    Image.fromarray(mask).save(path)
    result = CliRunner().invoke(app, ["solve", str(SKY), "--mask", str(path), "--json"])
    assert result.exit_code == 0, result.output
    assert '"status": "solved"' in result.stdout


@pytest.mark.parametrize(("mask", "message"), [
    (np.ones((10, 10)), "the mask is 10×10 pixels, the image 1280×960: a mask must be the image's size"),
    (np.zeros((960, 1280)), "the mask hides every pixel (white = sky to use, black = ignore)"),
])
def test_a_mask_that_cannot_be_the_frames_is_one_line(mask, message):
    with pytest.raises(InputError) as info:
        skyfix.solve(SKY, mask=mask)
    assert str(info.value) == message


def test_cli_mask_of_another_size_or_unreadable_is_one_line(tmp_path):
    small = tmp_path / "small.png"
    Image.fromarray(np.full((10, 10), 255, np.uint8)).save(small)
    result = CliRunner().invoke(app, ["solve", str(SKY), "--mask", str(small)])
    assert result.exit_code != 0 and "Traceback" not in result.output
    assert "the mask is 10×10 pixels, the image 1280×960" in result.output
    assert len(result.output.strip().splitlines()) == 1
    missing = CliRunner().invoke(app, ["solve", str(SKY), "--mask", str(tmp_path / "none.png")])
    assert missing.exit_code == 2 and len(missing.output.strip().splitlines()) == 1
    assert missing.output.startswith("skyfix: error: --mask")
