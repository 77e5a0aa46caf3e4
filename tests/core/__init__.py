"""Tests of the top-level modules of src/skyfix/: geometry, camera, catalog, cache, io, attitude,
calibrate, final_fit, pipeline, warmup, wcs."""
