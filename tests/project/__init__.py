"""Tests of the repository as a whole: docs, import graph, benchmarks, the tests' own layout."""
