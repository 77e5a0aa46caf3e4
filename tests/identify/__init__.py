"""Tests of skyfix.identify: pattern databases and bands, the search, verification, acceptance,
the methods."""
