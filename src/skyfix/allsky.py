"""All-sky frames: a fisheye's whole sky identified through the stars near its centre.

A lens that sees the whole sky (up to 190° across) draws it as a disc
(:func:`skyfix.detect.sky_circle.find_image_circle`); no pinhole model can hold it, and the
lost-in-space search, which scales a gnomonic field, cannot search it whole. With no camera
file the frame is modelled as an *equidistant* fisheye (Kannala–Brandt, every ``k = 0``) about
the disc's centre, whose rim is the horizon, 90° from the boresight of a camera looking up:
``f = R / (π/2)``. Then:

1. **Rays.** The centroids become rays through that model (or through the camera file's
   Kannala–Brandt model when one is given); those within :data:`PATTERN_CONE_DEG` of the
   boresight — the zenith's stars, where the lens distorts least and no horizon hides any —
   are projected onto a virtual pinhole frame of that field (``2·PATTERN_CONE_DEG`` across,
   the fisheye's central scale), brightest first.
2. **Identification** of the virtual frame by the method asked for (the 4-star hash by
   default) with its field as the FOV hint, ± :data:`FOV_TOLERANCE` (the lens's true
   central scale and a rim lower than the horizon: an equisolid fisheye's centre is 11 % larger
   than the equidistant model's; a horizon of hills 3 % smaller), against the wide band's
   database. Its own acceptance rules decide (``prob_false``); its attitude is the fisheye's, whose
   camera axes the virtual frame shares.
3. **The final fit** (:func:`skyfix.final_fit.final_fit`): through a camera file, as given; with
   none, a Kannala–Brandt camera (focal lengths, principal point, k1..k4) fitted under the
   uncalibrated fisheye prior about the disc's centre and grown over the whole sky by
   re-matching, each step beyond chance with the camera paid for, as every solve's.

The result is an :class:`~skyfix.identify.Identification` of the frame's own centroids, its
camera the equidistant model the stars were identified through. A frame with an image circle
that is not identified so — a circular fisheye narrower than the sky, whose rim is no horizon —
is searched as any frame (:func:`identify_allsky_frame`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from skyfix.camera import Camera
from skyfix.detect.sky_circle import ImageCircle
from skyfix.identify import identify
from skyfix.identify.common.result import Identification
from skyfix.identify.lost import LostInSpace, identify_lost

__all__ = ["FOV_TOLERANCE", "PATTERN_CONE_DEG", "allsky_camera", "identify_allsky", "identify_allsky_frame"]

PATTERN_CONE_DEG = 45.0
"""The stars identified first are those within this angle of the boresight (degrees)."""
FOV_TOLERANCE = 0.15
"""The virtual frame's FOV hint is good to this share (the module text, step 2)."""


def allsky_camera(width: int, height: int, circle: ImageCircle) -> Camera:
    """The equidistant fisheye whose horizon (90° from the boresight) is the disc ``circle``."""
    f = circle.radius / (math.pi / 2.0)
    return Camera(width=int(width), height=int(height), fx=f, fy=f, cx=circle.cx, cy=circle.cy,
                  projection="kannala-brandt")


def identify_allsky(xy: np.ndarray, width: int, height: int, circle: ImageCircle, *,
                    camera: Camera | None, database, epoch: float | None, identify_method: str,
                    identify_options: dict) -> Identification:
    """The stars of an all-sky frame identified through those near its centre (the module
    text's steps 1 and 2): an Identification of ``xy``'s rows, its camera ``camera`` or the
    equidistant model of ``circle`` (:func:`allsky_camera`)."""
    model = camera if camera is not None else allsky_camera(width, height, circle)
    rays = model.pixel_to_ray(np.asarray(xy, dtype=np.float64))
    cone = math.radians(PATTERN_CONE_DEG)
    near = np.flatnonzero(np.isfinite(rays).all(axis=1) & (rays[:, 2] > math.cos(cone)))
    if len(near) < 4:
        return Identification(False, f"too few stars within {PATTERN_CONE_DEG:g}° of the all-sky frame's "
                                     f"centre ({len(near)}; need 4)")
    f = model.fx
    size = int(math.ceil(2.0 * f * math.tan(cone))) + 1
    c = (size - 1) / 2.0
    virtual = f * rays[near, :2] / rays[near, 2:3] + c
    fov = 2.0 * PATTERN_CONE_DEG
    scale = dict(camera=Camera(width=size, height=size, fx=f, fy=f, cx=c, cy=c)) if camera is not None else \
        dict(fov_deg=fov, fov_tolerance_deg=FOV_TOLERANCE * fov)
    ident = identify(virtual, size, size, method=identify_method, database=database, epoch=epoch, **scale,
                     **identify_options)
    if not ident.success:
        return dataclasses.replace(ident, reason=f"all-sky frame, the stars within {PATTERN_CONE_DEG:g}° of "
                                                 f"its centre: {ident.reason}")
    return dataclasses.replace(ident, star_index=near[np.asarray(ident.star_index)], camera=model)


def identify_allsky_frame(xy: np.ndarray, width: int, height: int, *, circle: ImageCircle,
                          fov_deg: float | None, fov_tolerance_deg: float | None, camera: Camera | None,
                          database, epoch: float | None, identify_method: str, identify_options: dict
                          ) -> LostInSpace:
    """A frame with an image circle identified as an all-sky one (:func:`identify_allsky`); failing
    that — a circular fisheye narrower than the sky, whose rim is no horizon — searched as any
    frame (:func:`skyfix.identify.lost.identify_lost`), both reasons kept when neither succeeds.
    The keywords are :func:`identify_lost`'s."""
    ident = identify_allsky(xy, width, height, circle, camera=camera, database=database, epoch=epoch,
                            identify_method=identify_method, identify_options=identify_options)
    if ident.success:
        return LostInSpace(ident, None)
    found = identify_lost(xy, width, height, fov_deg=fov_deg, fov_tolerance_deg=fov_tolerance_deg,
                          camera=camera, database=database, epoch=epoch, identify_method=identify_method,
                          identify_options=identify_options)
    if found.ident.success:
        return found
    reason = f"{ident.reason}; as any frame: {found.ident.reason}"
    return found._replace(ident=dataclasses.replace(found.ident, reason=reason))
