"""The default extractor on the 21 real images: its brightest centroids are catalogue stars.

For each image the Hipparcos stars (Hp ≤ 9) are projected with the reference solution in
``solutions.jsonl`` (pinhole camera from its pixel scale). The projection is then refined
by an affine and a cubic map fitted to nearest-neighbour pairs (the reference is not truth,
and ``virgo.jpg``'s lens distorts by several pixels at the edges); a centroid counts as a star
when it lies within 3 px of a refined catalogue position.

The minimum counts below were measured (top 20 / top 30) and lowered by about two for margin;
``tree.jpg`` (half covered by lit foliage, masked as clutter) and ``virgo.jpg`` (galaxies of
the Virgo cluster are real but not in Hipparcos) are the hard ones.
"""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from skyfix.camera import Camera
from skyfix.catalog import load_hipparcos
from skyfix.detect import extract_centroids
from skyfix.geometry import attitude_from_radec_roll
from skyfix.io import read_image

# image: (min matched among the 20 brightest; measured)
MIN_MATCHED_TOP20 = {
    "cedar-solve/crappy.jpg": 18,  # 20
    "cedar-solve/hale_bopp.jpg": 17,  # 20 (the comet is masked as clutter)
    "cedar-solve/jan1_g90_e100ms.jpg": 18,  # 20
    "cedar-solve/jan1_g90_e50ms.jpg": 18,  # 20
    "cedar-solve/orion2.jpg": 18,  # 20
    "cedar-solve/orion_belt.jpg": 18,  # 20
    "cedar-solve/orion_trees.jpg": 18,  # 20
    "cedar-solve/pleiades.jpg": 18,  # 20
    "cedar-solve/roof.jpg": 17,  # 20
    "cedar-solve/test2_g100_e50ms.jpg": 18,  # 20
    "cedar-solve/test_5mp_g100_e50ms.jpg": 18,  # 20
    "cedar-solve/tree.jpg": 14,  # 18 (lit foliage masked as clutter)
    "cedar-solve/virgo.jpg": 13,  # 16
}
ESA_MIN_MATCHED_TOP30 = 28  # measured 30 on 7 frames, 29 on one (≥ 95%: issue 4)

MAG_LIMIT = 9.0
TOL_PX = 3.0


@pytest.fixture(scope="module")
def catalog():
    return load_hipparcos(epoch=2019.6, mag_limit=MAG_LIMIT)


def _design(xy, deg):
    x, y = xy[:, 0] / 1000.0, xy[:, 1] / 1000.0
    cols = [np.ones_like(x), x, y]
    if deg >= 2:
        cols += [x * x, x * y, y * y]
    if deg >= 3:
        cols += [x**3, x * x * y, x * y * y, y**3]
    return np.column_stack(cols)


def matched(cxy, sol, shape, catalog):
    """Boolean per centroid: within TOL_PX of a (refined) projected catalogue star."""
    h, w = shape
    cam = Camera.from_fov(w, h, w * sol["pixscale_arcsec"] / 3600.0)
    A = attitude_from_radec_roll(math.radians(sol["ra_deg"]), math.radians(sol["dec_deg"]),
                                 math.radians(sol["roll_deg"]))
    pxy, ok = cam.ray_to_pixel(catalog.vectors @ A.T)
    pxy = pxy[ok & cam.in_frame(pxy, margin=-10)]
    if len(pxy) == 0 or len(cxy) == 0:
        return np.zeros(len(cxy), bool)
    mapped = pxy
    for radius, deg, need in ((15, 1, 6), (8, 1, 6), (5, 2, 12), (4, 3, 20)):
        d, j = cKDTree(mapped).query(cxy)
        m = d < radius
        if m.sum() < need:
            continue
        coef, *_ = np.linalg.lstsq(_design(pxy[j[m]], deg), cxy[m], rcond=None)
        mapped = _design(pxy, deg) @ coef
    d, _ = cKDTree(mapped).query(cxy)
    return d < TOL_PX


def test_cedar_images_brightest_are_stars(real_dir, real_solutions, catalog):
    short = []
    for name, need in MIN_MATCHED_TOP20.items():
        img = read_image(real_dir / name)
        c = extract_centroids(img)
        assert len(c) >= 20, name
        n = int(matched(c.xy[:20], real_solutions[name], img.shape, catalog).sum())
        if n < need:
            short.append(f"{name}: {n}/20 < {need}")
    assert not short, short


def test_esa_frames_top30_are_stars(real_dir, real_solutions, catalog):
    names = sorted(k for k in real_solutions if k.startswith("esa-tetra3/"))
    assert len(names) == 8
    for name in names:
        img = read_image(real_dir / name)
        c = extract_centroids(img)
        assert len(c) >= 30, name
        n = int(matched(c.xy[:30], real_solutions[name], img.shape, catalog).sum())
        assert n >= ESA_MIN_MATCHED_TOP30, f"{name}: {n}/30"
        # a saturated star (frame at 65535) is flagged, and only at full scale
        if img.max() < 65000:
            assert not c.saturated.any()


def test_real_noise_and_background_are_sane(real_dir):
    img = read_image(real_dir / "esa-tetra3" / "2019-07-29T204726_Alt40_Azi45_Try1.tiff")
    c = extract_centroids(img)
    assert 2500 < c.background_level < 4000  # sky ~3180 ADU in 16-bit units
    assert 80 < c.noise < 250
    assert np.all(np.diff(c.flux) <= 0)
