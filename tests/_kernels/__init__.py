"""Tests of skyfix._kernels: the shared numba kernels and their cache check."""
