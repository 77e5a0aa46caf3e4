"""Tests of skyfix.track: the tracker, its filter, rate, windowed measurement."""
