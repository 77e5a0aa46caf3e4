"""Star detection: frame calibration, background, extraction and centroiding.

Typical use::

    from skyfix.io import read_image
    from skyfix.detect import extract_centroids

    stars = extract_centroids(read_image("frame.fits"))      # Centroids, brightest first
    stars.xy, stars.flux, stars.snr, stars.covariance         # (N, 2), (N,), (N,), (N, 2, 2)

- :func:`extract_centroids` — full-frame detection; ``method=`` "components" (default),
  "threshold_hillclimb" (thesis 000), "region_grow" (thesis 004), "regionprops" (thesis 003);
  ``centroid=`` "com" (default), "iwcog", "gaussian".
- :func:`centroid_windows` — tracking: one star per predicted position, O(N·window²).
- :func:`centroid_streaks` — tracking at high rates: a PSF swept along each star's predicted
  motion (:func:`streak_motion`), centred on its mid-exposure position; :func:`star_times` —
  each star's time on a rolling-shutter sensor.
- :func:`estimate_background` — tiled (default), global or per-row sky and noise.
- :func:`frame_problem` — why a frame holds no usable stars (blank, saturated, too small).
- :func:`cramer_rao_centroid`, :func:`measure_psf` — bounds and PSF shape (the study of every
  centroider against the bound is :mod:`skyfix.analysis.centroid_study`).
- Frame calibration: :func:`master_dark`, :func:`master_flat`, :func:`hot_pixel_map`,
  :func:`dead_pixel_map`, :func:`calibrate_frame` (dark → flat → repair), :func:`dark_report`,
  :func:`save_calibration` / :func:`load_calibration`.
"""

import importlib
from typing import TYPE_CHECKING

from skyfix.detect.background import Background, estimate_background
from skyfix.detect.calibrate_frames import (
    calibrate_frame,
    dark_report,
    dead_pixel_map,
    hot_pixel_map,
    load_calibration,
    master_dark,
    master_flat,
    save_calibration,
)
from skyfix.detect.centroid import (
    CENTROIDERS,
    centroid_windows,
    cramer_rao_centroid,
    measure_psf,
    refine_centroids,
)
from skyfix.detect.centroids import Centroids
from skyfix.detect.diagnose import frame_problem
from skyfix.detect.extract import METHODS, extract_centroids
from skyfix.detect.saturation import saturation_level

if TYPE_CHECKING:
    from skyfix.detect.streak import centroid_streaks, star_times, streak_motion

__all__ = [
    "CENTROIDERS",
    "METHODS",
    "Background",
    "Centroids",
    "calibrate_frame",
    "dark_report",
    "dead_pixel_map",
    "hot_pixel_map",
    "load_calibration",
    "measure_psf",
    "master_dark",
    "master_flat",
    "save_calibration",
    "centroid_streaks",
    "centroid_windows",
    "cramer_rao_centroid",
    "estimate_background",
    "extract_centroids",
    "frame_problem",
    "refine_centroids",
    "saturation_level",
    "star_times",
    "streak_motion",
]

# The streak fit's names load skyfix.detect.streak (30 kernels) when first asked for: a solve
# does not use it (issue 22: what `skyfix solve` imports).
_LAZY = {"centroid_streaks": "skyfix.detect.streak", "star_times": "skyfix.detect.streak",
         "streak_motion": "skyfix.detect.streak"}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'skyfix.detect' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
