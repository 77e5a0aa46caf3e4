"""Tests of skyfix.montecarlo: campaigns, the Dask engine, results."""
