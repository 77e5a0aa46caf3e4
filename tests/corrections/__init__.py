"""Tests of skyfix.corrections: aberration, apparent directions, bright bodies, refraction."""
