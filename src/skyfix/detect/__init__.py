"""Star detection: frame calibration, background, extraction and centroiding."""

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
from skyfix.detect.extract import METHODS, extract_centroids, saturation_level

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
    "centroid_windows",
    "cramer_rao_centroid",
    "estimate_background",
    "extract_centroids",
    "refine_centroids",
    "saturation_level",
]
