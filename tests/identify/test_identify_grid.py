"""The grid method (skyfix.identify.methods.grid, Padgett & Kreutz-Delgado; thesis 000 §2.6.5): patterns
that survive any rotation but not a mirror, a known field identified star by star, bad input in
one line, and the solved / wrong rates against truth."""

import math

import numpy as np
import pytest

from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
from skyfix.attitude import attitude_error
from skyfix.camera import Camera
from skyfix.errors import InputError
from skyfix.identify.common import hypothesis as hyp
from skyfix.identify.common.angle_match import frame_table
from skyfix.identify.methods import grid
from tests.identify.identify_checks import pointing_at, wrong

W, H, FOV = 1024, 1024, 15.0
ARCSEC = np.pi / 180 / 3600
ORION_BELT = (26311, 26727, 25930)  # Alnilam, Alnitak, Mintaka


@pytest.fixture(scope="module")
def camera():
    return Camera.from_fov(W, H, FOV)


@pytest.fixture(scope="module")
def orion(catalog, camera):
    A = pointing_at(catalog.vectors[np.flatnonzero(catalog.ids == ORION_BELT[0])[0]])
    return synthetic_centroids(camera, A, catalog, mag_limit=6.0, sigma_px=0.0, rng=1)


def test_a_pattern_survives_rotation_and_not_a_mirror(catalog):
    settings = grid.GridSettings(32, math.radians(7.5), math.radians(0.15), 32)
    rng = np.random.default_rng(3)
    for A in random_attitudes(20, rng=4):
        center = A[2]  # the boresight star: a catalogue star near it, its neighbours around
        near = np.flatnonzero(catalog.vectors @ center > math.cos(math.radians(8.0)))[:40]
        ref, nbrs = catalog.vectors[near[0]], catalog.vectors[near]
        out_sky, out_cam, out_mirror = (np.empty(32, np.int64) for _ in range(3))
        n_sky = grid.pattern_cells(ref, nbrs, settings, 1.0, 0, out_sky)
        R = A @ np.linalg.qr(rng.normal(size=(3, 3)))[0]  # any rotation …
        R *= np.sign(np.linalg.det(R))  # … proper
        n_cam = grid.pattern_cells(R @ ref, nbrs @ R.T, settings, 1.0, 0, out_cam)
        assert n_sky >= 5 and n_cam == n_sky
        assert sorted(out_cam[:n_cam]) == sorted(out_sky[:n_sky])  # the same cells exactly
        M = np.diag([-1.0, 1.0, 1.0]) @ R  # a mirror image
        n_m = grid.pattern_cells(M @ ref, nbrs @ M.T, settings, 1.0, 0, out_mirror)
        # a mirrored pattern shares few cells: the orienting neighbour's and those near its axis
        assert len(set(out_mirror[:n_m]) & set(out_sky[:n_sky])) <= n_sky / 4 + 1


def test_orion_belt_is_identified_star_by_star(database, camera, orion):
    ident = grid.identify(orion.xy, W, H, camera=camera, database=database)
    assert ident.success and ident.method == "grid"
    assert np.array_equal(ident.catalog_ids, orion.star_id[ident.star_index])
    assert set(ORION_BELT) <= set(ident.catalog_ids.tolist())
    e = attitude_error(orion.A_icrs_to_cam, ident.A_icrs_to_cam)
    assert np.hypot(e[0], e[1]) < 1 * ARCSEC
    # the pieces: the best scoring reference's candidate is its true star
    frame = hyp.frame_for(grid.METHOD, orion.xy, W, H, fov_deg=None, fov_tolerance_deg=None, camera=camera,
                          database=database, epoch=None)
    table, _ = frame_table(frame)
    settings = grid.GridSettings(32, math.radians(FOV / 2), math.radians(FOV / 100), 32)
    patterns = grid.catalogue_patterns(frame, table, settings)
    assert patterns.cell_start[-1] == len(patterns.cell_star) == patterns.n_cells.sum()
    refs = np.argsort(np.hypot(*frame.image.offsets_px[:20].T))[:8]  # nearest the centre, as identify
    cand = grid.image_candidates(frame, table, patterns, settings, refs, np.array([1.0]), top=1)
    ids = database.star_arrays()[0]
    hits = ids[cand.star] == orion.star_id[cand.reference]
    assert hits.sum() >= 3 and hits[np.argmax(cand.score)] and cand.score.max() >= 10


def test_a_mirrored_field_is_rejected(database, camera, catalog):
    for i, A in enumerate(random_attitudes(5, rng=21)):
        field = synthetic_centroids(camera, A, catalog, mag_limit=6.5, sigma_px=0.0, rng=i)
        mirrored = field.xy.copy()
        mirrored[:, 0] = W - 1 - mirrored[:, 0]
        assert grid.identify(field.xy, W, H, camera=camera, database=database).success
        ident = grid.identify(mirrored, W, H, camera=camera, database=database)
        assert not ident.success and "no agreeing grid candidates verified" in ident.reason


def test_bad_input_is_one_line(database, camera):
    xy = np.array([[10.0, 10.0], [500.0, 20.0], [30.0, 700.0], [600.0, 600.0]])
    r = grid.identify(xy, W, H, database=database)
    assert not r.success and "needs a field of view or a camera" in r.reason
    r = grid.identify(xy[:2], W, H, camera=camera, database=database)
    assert not r.success and r.reason == "too few stars (2 detected, need 3)"
    with pytest.raises(InputError, match="grid options out of range"):
        grid.identify(xy, W, H, camera=camera, database=database, g=1)
    with pytest.raises(InputError, match="grid radii out of range"):
        grid.identify(xy, W, H, camera=camera, database=database, buffer_deg=9.0)
    with pytest.raises(InputError):
        grid.identify(np.zeros((4, 3)), W, H, camera=camera, database=database)
    nan = np.vstack([xy, [np.nan, 3.0]])
    r = grid.identify(nan, W, H, camera=camera, database=database)  # 4 random points: no match
    assert not r.success and "no agreeing grid candidates verified" in r.reason


def test_noise_free_fields_are_solved(database, camera, catalog):
    solved = tried = 0
    for i, A in enumerate(random_attitudes(60, rng=31)):
        field = synthetic_centroids(camera, A, catalog, mag_limit=6.0, sigma_px=0.0, rng=i)
        if len(field.xy) < 5:
            continue
        tried += 1
        ident = grid.identify(field.xy, W, H, camera=camera, database=database)
        assert not (ident.success and wrong(A, ident.A_icrs_to_cam))
        solved += ident.success
    assert tried >= 50 and solved / tried >= 0.99


@pytest.mark.parametrize("calibrated", [True, False])
def test_noisy_fields_with_false_stars_are_never_wrong(database, camera, catalog, calibrated):
    n, solved, boresight = 100, 0, []
    for i, A in enumerate(random_attitudes(n, rng=41 + calibrated)):
        field = synthetic_centroids(camera, A, catalog, mag_limit=6.5, sigma_px=0.5, n_false=2, rng=1000 + i)
        known = dict(camera=camera) if calibrated else dict(fov_deg=FOV * 1.03)  # FOV 3 % off
        ident = grid.identify(field.xy, W, H, database=database, **known)
        if ident.success:
            assert not wrong(A, ident.A_icrs_to_cam), i
            e = attitude_error(A, ident.A_icrs_to_cam)
            boresight.append(np.hypot(e[0], e[1]) / ARCSEC)
            solved += 1
    assert solved >= 0.95 * n
    assert np.median(boresight) < 8.0  # 0.5 px = 26" per star, ~30 stars refitted
