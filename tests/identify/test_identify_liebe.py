"""The ``liebe`` identification method (skyfix.identify.methods.liebe): a known field named right,
mirrored fields refused, bad input one-line, noise-free and noisy 15° fields solved and never
wrong (the checks of tests/identify/identify_checks.py)."""

from skyfix.identify.methods import liebe
from tests.identify import identify_checks as checks


def test_known_field_and_its_mirror(database):
    checks.check_known_field(liebe.identify, database)


def test_mirrored_fields_are_refused(database):
    checks.check_mirrored_fields(liebe.identify, database)


def test_bad_input(database):
    checks.check_bad_input(liebe.identify, database)


def test_noise_free_fields(database):
    checks.check_noise_free_fields(liebe.identify, database)


def test_noisy_fields_with_false_stars(database):
    checks.check_noisy_fields(liebe.identify, database)
