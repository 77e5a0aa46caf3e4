"""The shared judge of correspondence hypotheses (skyfix.identify.common.hypothesis): a true
correspondence verifies and refits to the true attitude; a wrong or mirrored one does not."""

import numpy as np
import pytest

from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
from skyfix.attitude import attitude_error
from skyfix.camera import Camera
from skyfix.errors import CameraError
from skyfix.identify.accept import is_verified, log_prob_false
from skyfix.identify.common import hypothesis as hyp

W, H, FOV = 1024, 1024, 15.0
ARCSEC = np.pi / 180 / 3600


def _truth(frame, field, database):
    """Catalogue rows (into the star index) of the frame's true stars, -1 for false ones."""
    ids, _, _ = database.star_arrays()
    row = {int(h): i for i, h in enumerate(ids)}
    return np.array([row.get(int(s), -1) for s in field.star_id])


@pytest.mark.parametrize("calibrated", [True, False])
def test_a_true_correspondence_is_verified_and_refitted(database, catalog, calibrated):
    cam = Camera.from_fov(W, H, FOV)
    for i, A in enumerate(random_attitudes(5, rng=3)):
        field = synthetic_centroids(cam, A, catalog, mag_limit=6.5, sigma_px=0.5, n_false=3, rng=i)
        frame = hyp.frame_for("test", field.xy, W, H, fov_deg=None if calibrated else FOV * 1.04,
                              fov_tolerance_deg=None, camera=cam if calibrated else None, database=database,
                              epoch=None)
        truth = _truth(frame, field, database)
        own = np.flatnonzero(truth >= 0)[:3]
        h = hyp.hypothesis(frame, own, truth[own])
        assert hyp.fits(frame, h)
        assert h.focal_px == pytest.approx(cam.fx, rel=3e-3)  # found from the angles with a FOV only
        logp = hyp.chance_log_probability(frame, h)
        assert is_verified(log_prob_false(logp, 100), frame.log_threshold)
        ident = hyp.finish(frame, h, logp, 1, 100)
        assert ident is not None and ident.success and ident.method == "test"
        err = attitude_error(A, ident.A_icrs_to_cam)
        assert np.hypot(err[0], err[1]) < 10 * ARCSEC
        matched = field.star_id[ident.star_index]
        assert np.array_equal(matched, ident.catalog_ids)  # every matched star is the true one
        if not calibrated:
            assert ident.camera.fx == pytest.approx(cam.fx, rel=2e-3)


def test_wrong_and_mirrored_correspondences_are_rejected(database, catalog):
    cam = Camera.from_fov(W, H, FOV)
    rng = np.random.default_rng(4)
    A = random_attitudes(1, rng=5)[0]
    field = synthetic_centroids(cam, A, catalog, mag_limit=6.5, sigma_px=0.5, rng=6)
    frame = hyp.frame_for("test", field.xy, W, H, fov_deg=None, fov_tolerance_deg=None, camera=cam,
                          database=database, epoch=None)
    truth = _truth(frame, field, database)
    own = np.arange(3)
    # three random catalogue stars: their rotation (fitted or not) verifies nothing
    wrong = rng.choice(len(frame.stars.vectors), 3, replace=False)
    h = hyp.hypothesis(frame, own, wrong)
    assert not is_verified(log_prob_false(hyp.chance_log_probability(frame, h), 1), frame.log_threshold)
    # the frame mirrored left-right: its true stars fit no proper rotation
    mirrored = field.xy.copy()
    mirrored[:, 0] = cam.cx * 2 - mirrored[:, 0]
    frame_m = hyp.frame_for("test", mirrored, W, H, fov_deg=None, fov_tolerance_deg=None, camera=cam,
                            database=database, epoch=None)
    spread = np.argsort(-np.linalg.norm(mirrored - [cam.cx, cam.cy], axis=1))[:4]  # far apart: a clear mirror
    h = hyp.hypothesis(frame_m, spread, truth[spread])
    assert not hyp.fits(frame_m, h) and h.max_residual_rad * h.focal_px > frame_m.radius_px


def test_a_frame_needs_a_scale_and_stars(database):
    xy = np.array([[10.0, 10.0], [500.0, 20.0], [30.0, 700.0], [np.nan, 1.0]])
    no_scale = hyp.frame_for("test", xy, W, H, fov_deg=None, fov_tolerance_deg=None, camera=None,
                             database=database, epoch=None)
    assert not no_scale.success and "needs a field of view or a camera" in no_scale.reason
    few = hyp.frame_for("test", xy, W, H, fov_deg=15.0, fov_tolerance_deg=None, camera=None,
                        database=database, epoch=None, min_stars=4)
    assert not few.success and few.reason == "too few stars (3 detected, need 4)"
    with pytest.raises(CameraError, match="impossible field of view"):
        hyp.frame_for("test", xy, W, H, fov_deg=200.0, fov_tolerance_deg=None, camera=None, database=database,
                      epoch=None)
    frame = hyp.frame_for("test", xy, W, H, fov_deg=15.0, fov_tolerance_deg=1.5, camera=None,
                          database=database, epoch=None)
    assert list(frame.kept) == [0, 1, 2] and frame.scale_tolerance == pytest.approx(0.11, abs=0.01)
