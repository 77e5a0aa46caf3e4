"""Tests of skyfix.analysis: the studies and campaigns."""
