"""Star detection: frame calibration, background, extraction and centroiding."""

from skyfix.detect.background import Background, estimate_background
from skyfix.detect.centroids import Centroids
from skyfix.detect.extract import extract_centroids, saturation_level

__all__ = ["Background", "Centroids", "estimate_background", "extract_centroids", "saturation_level"]
