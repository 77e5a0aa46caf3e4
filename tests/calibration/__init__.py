"""Tests of skyfix.calibration: one camera over many star fields, checkerboards."""
