"""Tests of the skyfix command (the skyfix.cli package)."""
