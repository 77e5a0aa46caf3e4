"""Tests of the skyfix command (cli.py, cli_analyze.py, cli_support.py)."""
