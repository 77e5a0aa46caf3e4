"""Every registered identification method (skyfix.identify.METHODS) on the issue's small
hand-made cases, side by side: a known field named right, the same field mirrored refused, and a
three-star field whose shape alone is ambiguous refused — never a guess. The methods' own test
files pin what is particular to each; this file is where a new method's first failure shows.
"""

import numpy as np
import pytest

from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
from skyfix.camera import Camera
from skyfix.geometry import attitude_from_radec_roll
from skyfix.identify import METHODS, identify
from tests.identify.identify_checks import FOV, ORION_HIP, ORION_XY, H, W, catalog_for, wrong

ORION_ATTITUDE = attitude_from_radec_roll(np.radians(83.0), np.radians(-2.0), 0.0)

NAMES = [name for name in METHODS if name != "hash"]  # "hash" is the default's other name


def test_the_list_is_every_method():
    assert METHODS["hash"] is METHODS["quad-hash"]
    assert len(NAMES) == len(set(METHODS.values())) >= 9


@pytest.mark.parametrize("method", NAMES)
def test_known_field_is_named_right(method, database):
    """Orion (RA 83°, Dec −2°, roll 0) through a 15° camera, its stars to V 5 without noise:
    every method names at least five, each one right. (Its seven brightest alone are too few
    for the grid method's neighbourhood patterns: it refuses them.)"""
    cam = Camera.from_fov(W, H, FOV)
    field = synthetic_centroids(cam, ORION_ATTITUDE, catalog_for(database), mag_limit=5.0, sigma_px=0.0)
    assert 15 <= len(field.xy) <= 40 and set(ORION_HIP) <= set(field.star_id.tolist())
    ident = identify(field.xy, W, H, method=method, camera=cam, database=database)
    assert ident.success, ident.reason
    assert len(ident.star_index) >= 5
    assert np.array_equal(field.star_id[ident.star_index], ident.catalog_ids)
    assert not wrong(ORION_ATTITUDE, ident.A_icrs_to_cam)


@pytest.mark.parametrize("method", NAMES)
def test_mirrored_field_is_refused(method, database):
    """Orion's seven brightest stars (to V 3.5) mirrored left-right: no rotation maps them onto
    the sky, yet Rigel and the belt, nearly symmetric, fit it mirrored within the tolerance (the
    triangle method named four of them, chance 8e-5, before its mirror rule). Refused by every
    method, with the camera and with a FOV only."""
    mirrored = ORION_XY.copy()
    mirrored[:, 0] = W - 1 - mirrored[:, 0]
    for kw in ({"camera": Camera.from_fov(W, H, FOV)}, {"fov_deg": FOV}):
        ident = identify(mirrored, W, H, method=method, database=database, **kw)
        assert not ident.success and ident.reason, (kw, ident.catalog_ids)


@pytest.mark.parametrize("method", NAMES)
def test_ambiguous_three_star_field_fails(method, database):
    """Three noise-free stars of a 30° field with the FOV known to 10 % and a 1 px tolerance:
    only their shape counts, and many catalogue triangles share it (the triangle method's own
    test shows over a hundred within 1 px). Every method says "failed" with a reason; with the
    calibrated camera the triangle method, which judges lone triangles, names them right."""
    w, h = 1280, 960
    cam = Camera.from_fov(w, h, 30.0)
    A = random_attitudes(10, 3)[2]
    field = synthetic_centroids(cam, A, catalog_for(database), mag_limit=8.0, sigma_px=0.0, rng=2)
    xy = field.xy[:3]
    ident = identify(xy, w, h, method=method, fov_deg=30.0, database=database, centroid_sigma_px=1.0)
    assert not ident.success and ident.reason, ident.catalog_ids
    if method == "triangle":
        known = identify(xy, w, h, method=method, camera=cam, database=database)
        assert known.success and not wrong(A, known.A_icrs_to_cam)
        assert np.array_equal(field.star_id[known.star_index], known.catalog_ids)
