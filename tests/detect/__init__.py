"""Tests of skyfix.detect: frame calibration, background, extraction, centroiders, streaks, smear."""
