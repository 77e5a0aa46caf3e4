"""The image centre's RA, Dec and roll beside the boresight's (issue 26 part 1; DESIGN.md's
conventions): ``center_*`` are what a plate solver reports for the image centre
``((W − 1)/2, (H − 1)/2)``, whatever the principal point."""

import json
import math

import numpy as np
import pytest

from skyfix.camera import Camera
from skyfix.geometry import (
    angle_between,
    attitude_from_radec_roll,
    radec_roll_from_attitude,
    radec_to_vector,
    vector_to_radec,
)
from skyfix.solution import Solution


def _solved(camera: Camera, A: np.ndarray) -> Solution:
    ra, dec, roll = (math.degrees(a) for a in radec_roll_from_attitude(A))
    return Solution(image="x", status="solved", ra_deg=ra, dec_deg=dec, roll_deg=roll,
                    boresight_px=[camera.cx, camera.cy], A_icrs_to_cam=A, camera=camera)


def _sky(camera: Camera, A: np.ndarray, x: float, y: float) -> tuple[float, float]:
    ray = camera.pixel_to_ray(np.array([[x, y]], dtype=float))[0]
    ra, dec = vector_to_radec(A.T @ (ray / np.linalg.norm(ray)))
    return float(ra), float(dec)


def _position_angle(a: tuple[float, float], b: tuple[float, float]) -> float:
    """Position angle (degrees, north through east) of sky point ``b`` seen from ``a``."""
    (ra1, dec1), (ra2, dec2) = a, b
    d = ra2 - ra1
    north = math.cos(dec1) * math.sin(dec2) - math.sin(dec1) * math.cos(dec2) * math.cos(d)
    return math.degrees(math.atan2(math.sin(d) * math.cos(dec2), north))


@pytest.mark.parametrize("shift", [(0.0, 0.0), (37.0, -61.0), (-120.0, 90.0)])
def test_centre_numbers_are_the_centre_pixels_sky_position_and_up_direction(shift):
    camera = Camera.from_fov(1280, 960, 20.0)
    camera = camera.replace(cx=camera.cx + shift[0], cy=camera.cy + shift[1]) if any(shift) else camera
    A = attitude_from_radec_roll(math.radians(150.0), math.radians(-35.0), math.radians(40.0))
    sol = _solved(camera, A)
    cx, cy = 639.5, 479.5
    assert sol.center_px == [cx, cy]
    centre = _sky(camera, A, cx, cy)
    sep = math.degrees(float(angle_between(
        radec_to_vector(math.radians(sol.center_ra_deg), math.radians(sol.center_dec_deg)),
        radec_to_vector(*centre)))) * 3600
    assert sep < 1e-4
    # Roll: the position angle of image-up (−y) at the centre, from a step of 0.01 px upward.
    up = _position_angle(centre, _sky(camera, A, cx, cy - 0.01)) % 360.0
    assert abs((sol.center_roll_deg - up + 180.0) % 360.0 - 180.0) < 1e-4
    if not any(shift):
        # At the principal point the centre's numbers are the boresight's, bit for bit.
        assert (sol.center_ra_deg, sol.center_dec_deg, sol.center_roll_deg) == (
            sol.ra_deg, sol.dec_deg, sol.roll_deg)
    else:
        # A principal point 100 px off on a 20° camera: the boresight is ~0.8–2.5° away.
        assert math.degrees(math.acos(min(1.0, float(
            radec_to_vector(math.radians(sol.ra_deg), math.radians(sol.dec_deg))
            @ radec_to_vector(*centre))))) > 0.5


def test_json_carries_the_centre_after_the_boresight():
    camera = Camera.from_fov(640, 480, 15.0)
    camera = camera.replace(cx=300.0, cy=250.0)
    sol = _solved(camera, attitude_from_radec_roll(1.0, 0.3, 2.0))
    d = json.loads(sol.to_json())
    keys = list(d)
    i = keys.index("boresight_px")
    assert keys[i + 1:i + 5] == ["center_ra_deg", "center_dec_deg", "center_roll_deg", "center_px"]
    assert d["center_px"] == [319.5, 239.5]
    assert (d["center_ra_deg"], d["center_dec_deg"], d["center_roll_deg"]) == (
        sol.center_ra_deg, sol.center_dec_deg, sol.center_roll_deg)
    assert d["center_ra_deg"] != d["ra_deg"]


def test_failed_solution_has_no_centre():
    d = json.loads(Solution(image="x", reason="too few stars").to_json())
    assert d["center_ra_deg"] is None and d["center_px"] is None
