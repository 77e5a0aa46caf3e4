"""Argument checks shared by the Python API and the ``skyfix`` command.

Each check returns the value (converted) or raises :class:`~skyfix.errors.InputError` with a
one-line message naming the argument as the caller calls it (``fov_deg`` from Python, ``--fov``
from the command line). They run before any work, so a bad option costs nothing.

The plausible field of view, :data:`FOV_RANGE_DEG`, is one range for all: a FOV hint to
``solve``, ``skyfix solve --fov`` and the range of ``PatternDatabase.build`` /
``skyfix database build``.
"""

from __future__ import annotations

import math
import numbers
from typing import TYPE_CHECKING

from skyfix.errors import InputError

if TYPE_CHECKING:
    import numpy as np

__all__ = [
    "check_solve_options",
    "EPOCH_RANGE", "FOV_RANGE_DEG", "check_attitude_method", "check_count", "check_epoch", "check_fov",
    "check_fov_range", "check_frame_size", "check_positive", "check_xy",
]

#: Horizontal fields of view, degrees, that a star camera with a pinhole model can have and the
#: Hipparcos pattern database can serve (below 0.5° a field holds about one catalogue star).
FOV_RANGE_DEG = (0.5, 100.0)
#: Julian years for which the catalogue's linear proper motion is meaningful.
EPOCH_RANGE = (1000.0, 3000.0)


def _real(value: object) -> float | None:
    """``value`` as a float if it is a real number (bool excluded), else None."""
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        return float(value)
    return None


def _text(value: object) -> str:
    v = _real(value)
    return f"{v:g}" if v is not None else repr(value)


def check_fov(value: object, name: str = "fov_deg") -> float:
    """A horizontal field of view in :data:`FOV_RANGE_DEG`, degrees."""
    lo, hi = FOV_RANGE_DEG
    v = _real(value)
    if v is None or not lo <= v <= hi:  # NaN fails the comparison
        raise InputError(f"{name} {_text(value)} is not a plausible field of view ({lo:g}–{hi:g} degrees)")
    return v


def check_fov_range(fov_min: object, fov_max: object, names: tuple[str, str] = ("fov_min_deg", "fov_max_deg"),
                    ) -> tuple[float, float]:
    """A FOV range ``fov_min <= fov_max``, both in :data:`FOV_RANGE_DEG`."""
    lo, hi = check_fov(fov_min, names[0]), check_fov(fov_max, names[1])
    if lo > hi:
        raise InputError(f"{names[0]} {lo:g} is larger than {names[1]} {hi:g}")
    return lo, hi


def check_positive(value: object, name: str) -> float:
    """A finite number > 0."""
    v = _real(value)
    if v is None or not (math.isfinite(v) and v > 0):
        raise InputError(f"{name} {_text(value)} must be a positive number")
    return v


def check_count(value: object, name: str, minimum: int = 1) -> int:
    """A whole number >= ``minimum`` (an integral float such as ``200.0`` is accepted)."""
    v = _real(value)
    if v is None or not (math.isfinite(v) and v == int(v) and v >= minimum):
        raise InputError(f"{name} {_text(value)} must be a whole number >= {minimum}")
    return int(v)


def check_epoch(value: object, name: str = "epoch") -> float | None:
    """A Julian year in :data:`EPOCH_RANGE`, or None (now)."""
    if value is None:
        return None
    lo, hi = EPOCH_RANGE
    v = _real(value)
    if v is None or not lo <= v <= hi:
        raise InputError(f"{name} {_text(value)} is not a Julian year in {lo:g}–{hi:g} (e.g. 2024.5)")
    return v


def check_attitude_method(value: object, name: str = "attitude_method") -> str:
    """The name of a Wahba solver of :data:`skyfix.attitude.METHODS` (any case)."""
    from skyfix.attitude import METHODS

    if not isinstance(value, str) or value.lower() not in METHODS:
        raise InputError(f"{name} {value!r} is not a Wahba solver; choose one of {', '.join(METHODS)}")
    return value


def check_solve_options(fov: object, fov_tolerance: object, epoch: object, attitude_method: object,
                        names: tuple[str, str, str, str] = ("fov_deg", "fov_tolerance_deg", "epoch",
                                                            "attitude_method")) -> None:
    """The options ``solve`` takes from the API and the CLI alike (``names``: how the caller
    spells them, e.g. ``--fov``)."""
    if fov is not None:
        check_fov(fov, names[0])
    if fov_tolerance is not None:
        check_positive(fov_tolerance, names[1])
    check_epoch(epoch, names[2])
    check_attitude_method(attitude_method, names[3])


def check_frame_size(width: object, height: object) -> tuple[int, int]:
    """Frame width and height: whole numbers of pixels >= 1."""
    w, h = _real(width), _real(height)
    if w is None or h is None or not all(math.isfinite(v) and v == int(v) and v >= 1 for v in (w, h)):
        raise InputError(f"width and height must be whole numbers of pixels >= 1, got "
                         f"{_text(width)}×{_text(height)}")
    return int(w), int(h)


def check_xy(xy: object) -> np.ndarray:
    """Centroids as a float64 (N, 2) array (a flat array of pairs is accepted)."""
    import numpy as np

    try:
        a = np.asarray(xy, dtype=np.float64)
    except (TypeError, ValueError):
        a = None
    if a is None or a.ndim > 2 or (a.ndim == 2 and a.shape[1] != 2) or (a.ndim < 2 and a.size % 2):
        shape = "non-numeric data" if a is None else f"shape {a.shape}"
        raise InputError(f"xy must be an (N, 2) array of pixel positions, got {shape}")
    return a.reshape(-1, 2)
