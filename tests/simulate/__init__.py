"""Tests of skyfix.simulate: rendering, sensor, motion profiles, slews."""
