"""Exceptions skyfix raises for bad input; each carries a one-line message for the user."""

from collections.abc import Iterable


class SkyfixError(Exception):
    """Base class: a problem with the user's input, reported as one line, never a traceback."""


class ImageReadError(SkyfixError):
    """The image file is missing, empty, truncated or not an image."""


class CameraError(SkyfixError):
    """A camera model or camera file is invalid (impossible FOV, missing keys, ...)."""


class DatabaseError(SkyfixError):
    """The pattern database is missing, corrupt or was built for other settings."""


class CatalogError(SkyfixError):
    """The star catalogue cannot be read."""


class SimulationError(SkyfixError):
    """Simulator settings are invalid (unknown preset, negative exposure, bad sensor value, ...)."""


class CalibrationError(SkyfixError):
    """The images cannot calibrate the camera asked for: too few images or stars, images of
    different sizes, a degenerate set, a checkerboard not found (the message names the image or
    the parameter)."""


class InputError(SkyfixError, ValueError):
    """An argument or option is out of range or of the wrong kind (a bad FOV, epoch, threshold,
    frame size, method name, ...); raised before any work is done."""


class UnknownNameError(InputError):
    """A name that no entry of a registry has: an identification, attitude, detection or centroid
    method, a background, decoder, camera projection or preset, a motion profile, a predictor, a
    warm-up path. Every registry raises this one type, with :func:`unknown_name`'s message."""


def unknown_name(what: str, name: object, known: Iterable[str]) -> UnknownNameError:
    """The one error for a name not in a registry: ``unknown {what} {name!r}; choose one of …``
    (raise it ``from None``)."""
    return UnknownNameError(f"unknown {what} {name!r}; choose one of {', '.join(map(str, known))}")


class CampaignError(SkyfixError):
    """A Monte Carlo campaign cannot run on: its scheduler is out of reach, a batch's workers kept
    dying, or its output folder holds another campaign's batches (skyfix.montecarlo)."""
