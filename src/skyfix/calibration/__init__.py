"""Camera calibration over many images: from stars (a joint fit), from checkerboards, and the
seeds' own procedures."""
