"""The benchmarks' own yardsticks: the independent renderer and the error metrics (no peers needed)."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from common import (  # noqa: E402
    attitude_from_radec_roll_deg,
    boresight_error_arcsec,
    radec_roll_deg,
    roll_error_deg,
)
from render import add_gaussian_stars  # noqa: E402


@pytest.mark.parametrize("x0, y0", [(20.0, 30.0), (20.3, 30.7), (19.5, 31.25)])
def test_rendered_spot_centroid_is_where_it_was_put(x0, y0):
    # (0, 0) is the centre of the top-left pixel: the flux-weighted mean of the pixel-integrated
    # Gaussian must land on the requested position to a few thousandths of a pixel.
    img = np.zeros((64, 64))
    add_gaussian_stars(img, np.array([[x0, y0]]), np.array([1000.0]), sigma=1.2)
    ys, xs = np.mgrid[:64, :64]
    assert img.sum() == pytest.approx(1000.0, rel=1e-4)
    assert (img * xs).sum() / img.sum() == pytest.approx(x0, abs=2e-3)
    assert (img * ys).sum() / img.sum() == pytest.approx(y0, abs=2e-3)


def test_attitude_round_trip_and_errors():
    A = attitude_from_radec_roll_deg(123.4, -56.7, 250.0)
    assert np.allclose(A @ A.T, np.eye(3), atol=1e-12)
    ra, dec, roll = radec_roll_deg(A)
    assert (ra, dec, roll) == pytest.approx((123.4, -56.7, 250.0), abs=1e-9)
    B = attitude_from_radec_roll_deg(123.4, -56.7 + 10 / 3600, 250.3)
    assert boresight_error_arcsec(B, A) == pytest.approx(10.0, rel=1e-3)
    assert roll_error_deg(B, A) == pytest.approx(0.3, abs=1e-3)


def test_north_is_up_at_roll_zero():
    # A star slightly north of the boresight projects toward row 0 (camera -y) at roll 0.
    A = attitude_from_radec_roll_deg(10.0, 20.0, 0.0)
    north = np.radians([10.0, 20.1])
    r = np.array([np.cos(north[1]) * np.cos(north[0]), np.cos(north[1]) * np.sin(north[0]), np.sin(north[1])])
    b = A @ r
    assert b[1] < 0 and abs(b[0]) < 1e-9
