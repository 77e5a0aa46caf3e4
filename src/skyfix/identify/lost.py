"""Lost in space: the strategy that names a frame's stars with no attitude hint.

:func:`identify_lost` runs the method asked for; when the default method (the 4-star hash) fails,
the strategy tries, in this order — the *fallback chain* (docs/design.md):

1. **Sparse frames** (at most :data:`SPARSE_FIELD_STARS` centroids; the hash needs more to verify
   a pattern beyond chance) go to the ``triangle`` method when the scale is known (a camera or a
   FOV) — or, with neither, through each seed camera of the frame's size (:func:`preset_cameras`),
   the chance accepted divided among them (:func:`identify_sparse`).
2. **Richer frames of a seed camera's size** with neither a camera nor a FOV are identified
   through each such preset's camera, the chance divided among them (:func:`identify_by_preset`).

After the final fit, a frame identified through a camera fitted to its few stars but too
uncertain to be solved is tried once more through the seed cameras of its size
(:func:`retry_through_preset`; :func:`skyfix.pipeline.solve_centroids` refits it). A method
named explicitly runs alone, with no fallback.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from skyfix.camera import PRESETS, Camera, camera_from_preset
from skyfix.identify import get_method, identify
from skyfix.identify.accept import PROB_THRESHOLD
from skyfix.identify.common.result import Identification
from skyfix.identify.methods import DEFAULT_METHOD

__all__ = ["LostInSpace", "SPARSE_FIELD_STARS", "identify_by_preset", "identify_lost", "identify_sparse",
           "identify_through_presets", "is_default_method", "preset_cameras", "preset_retry",
           "retry_through_preset", "sparse_fallback"]


class LostInSpace(NamedTuple):
    """What :func:`identify_lost` found: the identification, and the seed camera it was
    identified through (``assumed``: a preset's name, taken from the frame's size; None when the
    camera or FOV given, or nothing, served)."""

    ident: Identification
    assumed: str | None


def identify_lost(xy: np.ndarray, width: int, height: int, *, fov_deg: float | None,
                  fov_tolerance_deg: float | None, camera: Camera | None, database, epoch: float | None,
                  identify_method: str, identify_options: dict) -> LostInSpace:
    """The frame identified by ``identify_method``, then by the fallback chain (the module text)."""
    ident = identify(xy, width, height, method=identify_method, fov_deg=fov_deg,
                     fov_tolerance_deg=fov_tolerance_deg, camera=camera, database=database, epoch=epoch,
                     **identify_options)
    assumed = None
    if not ident.success and sparse_fallback(identify_method, len(xy), camera, fov_deg, width, height):
        ident, assumed = identify_sparse(ident, xy, width, height, fov_deg, fov_tolerance_deg, camera,
                                         database, epoch, identify_options)
    elif not ident.success and preset_retry(identify_method, camera, fov_deg, width, height):
        again, assumed = identify_by_preset(ident, xy, width, height, database, epoch, identify_method,
                                            identify_options)
        if assumed is not None:
            ident = again
    return LostInSpace(ident, assumed)


def retry_through_preset(ident: Identification, xy: np.ndarray, width: int, height: int, *,
                         fov_deg: float | None, camera: Camera | None, database, epoch: float | None,
                         identify_method: str, identify_options: dict) -> LostInSpace | None:
    """A frame identified with no camera whose attitude was too uncertain to solve, identified
    again through a seed camera of its size (None: no preset applies or none identified it)."""
    if not preset_retry(identify_method, camera, fov_deg, width, height):
        return None
    again, assumed = identify_by_preset(ident, xy, width, height, database, epoch, identify_method,
                                        identify_options)
    return None if assumed is None else LostInSpace(again, assumed)


SPARSE_FIELD_STARS = 8
"""A frame of at most this many centroids that the default method cannot identify is tried with
the ``triangle`` method (:func:`sparse_fallback`)."""

# The options of the default method that the triangle method shares (same names, same meaning).
_SPARSE_OPTIONS = ("prob_threshold", "centroid_sigma_px")


def preset_cameras(width: int, height: int) -> dict[str, Camera]:
    """The seed cameras (:data:`skyfix.camera.PRESETS`) whose image is ``width`` × ``height``."""
    return {name: camera_from_preset(name) for name, spec in PRESETS.items()
            if (spec["width"], spec["height"]) == (width, height)}


def is_default_method(identify_method: str) -> bool:
    """Whether ``identify_method`` names the default method (a method named explicitly is used
    alone, with no fallback)."""
    return get_method(identify_method) is get_method(DEFAULT_METHOD)


def sparse_fallback(identify_method: str, n_stars: int, camera: Camera | None, fov_deg: float | None,
                    width: int = 0, height: int = 0) -> bool:
    """Whether a frame the default identification failed is tried again with the ``triangle``
    method: the default method was asked for (a method named explicitly is used alone), the
    frame is sparse (at most :data:`SPARSE_FIELD_STARS` centroids: the 4-star hash needs more to
    verify a pattern beyond chance, thesis 000's camera sees three stars per frame), and the
    scale is known (a camera or a FOV: a triangle's angles need it) or the frame is the size of
    a seed camera's (:func:`preset_cameras`), whose camera is then tried."""
    return (is_default_method(identify_method) and n_stars <= SPARSE_FIELD_STARS
            and (camera is not None or fov_deg is not None or bool(preset_cameras(width, height))))


def identify_sparse(failed, xy: np.ndarray, width: int, height: int, fov_deg, fov_tolerance_deg, camera,
                     database, epoch, identify_options: dict):
    """The triangle method's identification of a sparse frame, or the default's failure with the
    triangle method's reason beside it; and the name of the preset camera it was identified
    through (None: the camera or FOV given).

    With neither a camera nor a FOV, each seed camera of the frame's size is tried as a
    calibrated camera, the chance accepted divided among them (the triangle method's
    ``lone_prob_threshold`` and ``prob_threshold`` over their number): a frame from another
    camera of that size is then a random triangle to them, and the final fit's precision rule
    still judges the attitude through the camera assumed."""
    from skyfix.identify.common.angle_match import LONE_PROB_THRESHOLD

    options = {k: identify_options[k] for k in _SPARSE_OPTIONS if k in identify_options}
    if camera is not None or fov_deg is not None:
        tries = {None: dict(camera=camera, fov_deg=fov_deg, fov_tolerance_deg=fov_tolerance_deg)}
    else:
        presets = preset_cameras(width, height)
        k = len(presets)
        options["prob_threshold"] = options.get("prob_threshold", PROB_THRESHOLD) / k
        options["lone_prob_threshold"] = LONE_PROB_THRESHOLD / k
        tries = {name: dict(camera=cam) for name, cam in presets.items()}
    reasons = []
    for name, scale in tries.items():
        sparse = identify(xy, width, height, method="triangle", database=database, epoch=epoch, **scale,
                          **options)
        if sparse.success:
            return sparse, name
        reasons.append(sparse.reason if name is None else f"{name} camera: {sparse.reason}")
    return dataclasses.replace(failed, reason=f"{failed.reason}; triangle: {'; '.join(reasons)}"), None


def preset_retry(identify_method: str, camera: Camera | None, fov_deg: float | None, width: int,
                  height: int) -> bool:
    """Whether a frame the no-hint solve could not solve is tried through the seed cameras of its
    size (:func:`preset_cameras`): the default method was asked for, and neither a camera nor a
    FOV was given."""
    return (camera is None and fov_deg is None and is_default_method(identify_method)
            and bool(preset_cameras(width, height)))


def identify_by_preset(failed, xy: np.ndarray, width: int, height: int, database, epoch,
                        identify_method: str, identify_options: dict):
    """A frame's identification through the seed cameras of its size: a sparse one (at most
    :data:`SPARSE_FIELD_STARS` centroids) by the triangle method (:func:`identify_sparse`), a
    richer one by the default method (:func:`identify_through_presets`); and the preset's name
    (None: none identified it)."""
    if len(xy) <= SPARSE_FIELD_STARS:
        return identify_sparse(failed, xy, width, height, None, None, None, database, epoch,
                                identify_options)
    return identify_through_presets(xy, width, height, database, epoch, identify_method, identify_options)


def identify_through_presets(xy: np.ndarray, width: int, height: int, database, epoch, identify_method: str,
                              identify_options: dict):
    """The default method's identification of a frame through each seed camera of its size
    (:func:`preset_cameras`) as a calibrated camera, the chance accepted divided among them; and
    the name of the preset that identified it (None: none did — the first result is returned
    failed). For a frame the default method identified with no camera but whose attitude through
    the camera fitted to its stars is too uncertain."""
    presets = preset_cameras(width, height)
    options = dict(identify_options)
    options["prob_threshold"] = options.get("prob_threshold", PROB_THRESHOLD) / len(presets)
    first = None
    for name, cam in presets.items():
        again = identify(xy, width, height, method=identify_method, camera=cam, database=database,
                         epoch=epoch, **options)
        if again.success:
            return again, name
        first = again if first is None else first
    return first, None
