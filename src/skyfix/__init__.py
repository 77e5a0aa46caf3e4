"""skyfix — a star tracker in Python."""

__version__ = "0.1.0"
