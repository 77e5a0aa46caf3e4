"""Mirror images (issue 26 part 2, skyfix.parity): a frame flipped left-right, a FITS file stored
bottom-up, and parity="either" over random synthetic frames with no wrong attitude."""

import math

import numpy as np
import pytest
from astropy.io import fits

from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
from skyfix.analysis.truth import judge
from skyfix.camera import Camera
from skyfix.errors import InputError
from skyfix.geometry import angle_between, radec_to_vector
from skyfix.io import read_image
from skyfix.parity import check_parity, halved_thresholds, mirror_camera, mirror_xy
from skyfix.pipeline import solve, solve_centroids
from skyfix.wcs import solution_wcs
from tests.conftest import EXAMPLES

EXAMPLE = EXAMPLES / "sky.png"


def _sep_arcsec(ra1, dec1, ra2, dec2) -> float:
    return math.degrees(float(angle_between(radec_to_vector(math.radians(ra1), math.radians(dec1)),
                                            radec_to_vector(math.radians(ra2), math.radians(dec2))))) * 3600


@pytest.fixture(scope="module")
def normal(database):
    sol = solve(EXAMPLE, database=database)
    assert sol.solved and not sol.mirrored
    return sol


def test_mirror_image_solves_as_mirrored_or_either_and_fails_with_advice_as_normal(normal, database):
    mirrored = np.ascontiguousarray(read_image(EXAMPLE)[:, ::-1])
    failed = solve(mirrored, database=database)
    assert not failed.solved and "--parity mirrored" in failed.reason
    by_id = {m.id: m for m in normal.matches}
    for parity in ("mirrored", "either"):
        sol = solve(mirrored, database=database, parity=parity)
        assert sol.solved and sol.mirrored, sol.reason
        # The same sky: centre and boresight within 1″, roll (image-up, rows not flipped) within 0.01°.
        centre = (normal.center_ra_deg, normal.center_dec_deg)
        assert _sep_arcsec(sol.center_ra_deg, sol.center_dec_deg, *centre) < 1.0
        assert abs((sol.roll_deg - normal.roll_deg + 180.0) % 360.0 - 180.0) < 0.01
        # Pixels are the frame's as given: each star's x is the flipped one of the normal frame
        # (to 0.1 px: the extraction's background tiles do not flip with the frame).
        shared = [m for m in sol.matches if m.id in by_id]
        assert len(shared) > 0.9 * len(normal.matches)
        assert max(abs(m.x - (1279 - by_id[m.id].x)) for m in shared) < 0.1
        # Any pixel's sky position, and the WCS, take the frame's own pixels.
        ra, dec = sol.radec_of_pixel(1279 - 100.0, 200.0)
        assert _sep_arcsec(ra, dec, *normal.radec_of_pixel(100.0, 200.0)) < 1.0
        w = solution_wcs(sol.A_icrs_to_cam, sol.camera, mirrored=True)
        m = shared[0]
        sky = w.pixel_to_world_values(m.x, m.y)
        tolerance = 3 * max(1.0, abs(m.residual_arcsec))
        assert _sep_arcsec(float(sky[0]), float(sky[1]), m.ra_deg, m.dec_deg) < tolerance
    either = solve(mirrored, database=database, parity="either")
    alone = solve(mirrored, database=database, parity="mirrored")
    assert either.prob_false == pytest.approx(2 * alone.prob_false, rel=1e-6)


def test_a_normal_frame_under_mirrored_says_it_is_not_a_mirror_image(database):
    sol = solve(EXAMPLE, database=database, parity="mirrored")
    assert not sol.solved and sol.mirrored
    assert sol.reason.endswith("not a mirror image (solve it with --parity normal)")


def test_fits_bottom_up_and_top_down_give_the_same_sky_with_no_option(tmp_path, normal, database):
    image = read_image(EXAMPLE).astype(np.float32)
    top_down, bottom_up = tmp_path / "top.fits", tmp_path / "bottom.fits"
    fits.PrimaryHDU(image).writeto(top_down)
    fits.PrimaryHDU(np.ascontiguousarray(image[::-1])).writeto(bottom_up)
    a = solve(top_down, database=database)
    b = solve(bottom_up, database=database)
    assert a.solved and b.solved and not a.mirrored and b.mirrored
    assert _sep_arcsec(a.center_ra_deg, a.center_dec_deg, b.center_ra_deg, b.center_dec_deg) < 1.0
    # b's rows run the other way: its image-up is a's image-down.
    assert abs((b.roll_deg - a.roll_deg) % 360.0 - 180.0) < 0.01
    # Each WCS maps its own file's pixel of a star to the same sky position.
    wa, wb = (solution_wcs(s.A_icrs_to_cam, s.camera, mirrored=s.mirrored) for s in (a, b))
    for m in a.matches[:20]:
        pa = wa.pixel_to_world_values(m.x, m.y)
        pb = wb.pixel_to_world_values(m.x, 959 - m.y)
        assert _sep_arcsec(float(pa[0]), float(pa[1]), float(pb[0]), float(pb[1])) < 1.0


def test_either_over_random_normal_and_mirrored_frames_has_no_wrong_attitude(catalog, database):
    """60 synthetic 15° frames, half mirrored, each solved with parity="either": every one solved
    with the right parity and none wrong (docs/design.md's definition of a wrong attitude)."""
    camera = Camera.from_fov(1280, 960, 15.0)
    attitudes = random_attitudes(60, rng=26)
    wrong = solved = right_parity = 0
    for i, A in enumerate(attitudes):
        field = synthetic_centroids(camera, A, catalog, sigma_px=0.5, n_false=3, dropout=0.1, rng=i)
        flip = i % 2 == 1
        xy = mirror_xy(field.xy, 1280) if flip else field.xy
        sol = solve_centroids(xy, 1280, 960, fov_deg=15.0, database=database, parity="either")
        if not sol.solved:
            continue
        solved += 1
        right_parity += sol.mirrored == flip
        # A mirrored solution's attitude and camera are the flipped frame's: the frame as rendered.
        wrong += sol.mirrored != flip or judge(sol.A_icrs_to_cam, sol.camera, A, camera).wrong
    assert wrong == 0
    assert solved >= 58 and right_parity == solved


def test_parity_helpers():
    cam = Camera.from_fov(640, 480, 20.0).replace(cx=300.0, skew=0.5, p2=1e-3, k1=-0.1)
    back = mirror_camera(mirror_camera(cam))
    assert (back.cx, back.skew, back.p2, back.k1) == (cam.cx, cam.skew, cam.p2, cam.k1)
    flipped = mirror_camera(cam)
    assert (flipped.cx, flipped.skew, flipped.p2, flipped.k1) == (339.0, -0.5, -1e-3, -0.1)
    # The mirrored camera sees the flipped pixel of every ray mirrored in x.
    rays = np.array([[0.1, -0.05, 1.0], [-0.12, 0.08, 1.0], [0.02, 0.15, 1.0]])
    xy, _ = cam.ray_to_pixel(rays)
    xy_m, _ = flipped.ray_to_pixel(rays * [-1.0, 1.0, 1.0])
    assert np.abs(mirror_xy(xy, 640) - xy_m).max() < 1e-9
    assert halved_thresholds("quad-hash", {}) == {"prob_threshold": 5e-10}
    assert halved_thresholds("pyramid", {"prob_threshold": 1e-6})["prob_threshold"] == 5e-7
    assert "lone_prob_threshold" in halved_thresholds("pyramid", {})
    assert check_parity("either") == "either"
    with pytest.raises(InputError, match="parity must be one of normal, mirrored, either, not 'sideways'"):
        check_parity("sideways")
    with pytest.raises(InputError, match="parity"):
        solve_centroids(np.zeros((5, 2)), 640, 480, parity="sideways")
