"""A frame the size of a seed camera's image, solved with no hint through that camera.

With no camera and no FOV, a frame whose size is a seed camera's (``skyfix.identify.lost.preset_cameras``)
that the default method cannot identify, or identifies only too uncertainly through a camera
fitted to its stars, is tried through the preset's camera, the chance accepted divided among the
presets of that size. The sparse (≤ 8 centroid) case is pinned in ``test_identify_triangle.py``;
these are frames of 9–13 stars.
"""

from __future__ import annotations

import math

import numpy as np

from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
from skyfix.analysis.truth import judge_error
from skyfix.attitude import attitude_error
from skyfix.camera import Camera, camera_from_preset
from skyfix.pipeline import solve_centroids


def _wrong(A_true: np.ndarray, A: np.ndarray, camera: Camera) -> bool:
    return judge_error(attitude_error(A_true, A), math.degrees(camera.plate_scale_rad) * 3600).wrong


def test_rich_frames_of_a_preset_size_solve_through_its_camera(catalog):
    """9–13 stars of a 752×480 frame, σ 0.3 px, one false star, no hint. Through the MT9V022's own
    lens every frame solves (before the preset retry of rich frames: 69 of 100 such frames — the
    rest identified but too uncertain through a camera fitted to them); through a 25° lens on the
    same sensor the preset's camera is never taken and nothing is wrong."""
    preset = camera_from_preset("mt9v022")
    cameras = {"mt9v022": preset, "25°": Camera.from_fov(752, 480, 25.0)}
    solved = dict.fromkeys(cameras, 0)
    through_preset = dict.fromkeys(cameras, 0)
    n = 40
    for i, A in enumerate(random_attitudes(n, 7)):
        k = 9 + i % 5
        for key, cam in cameras.items():
            f = synthetic_centroids(cam, A, catalog, mag_limit=6.5, sigma_px=0.3, rng=i, n_false=1)
            assert len(f.xy) >= k
            sol = solve_centroids(f.xy[:k], 752, 480)
            if sol.solved:
                solved[key] += 1
                through_preset[key] += sol.camera == preset
                assert not _wrong(A, sol.A_icrs_to_cam, cam), (key, i)
    assert solved["mt9v022"] >= 39, solved  # 100 of 100 measured over 100 such frames
    assert through_preset["mt9v022"] >= 5, through_preset  # 31 of 100 measured
    assert through_preset["25°"] == 0, through_preset
