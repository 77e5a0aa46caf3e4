"""What the tracker is given, checked: frame times, frames and gyro rates, each bad one a one-line
:mod:`skyfix.errors` exception (:class:`skyfix.track.Tracker` leaves its state unchanged)."""

from __future__ import annotations

import math
import os

import numpy as np

from skyfix.errors import InputError

__all__ = ["finite_time", "frame_array", "frame_time", "gyro_rate"]


def finite_time(t_s, what: str) -> float:
    """``t_s`` as a float: a finite number of seconds (``what`` names it in the error)."""
    if t_s is None or isinstance(t_s, bool) or not isinstance(t_s, (int, float, np.integer, np.floating)):
        raise InputError(f"{what} needs its time in seconds, got {t_s!r}")
    t = float(t_s)
    if not math.isfinite(t):
        raise InputError(f"{what}: the time must be a finite number of seconds, got {t_s!r}")
    return t


def frame_time(t_s, t_last: float | None) -> float:
    """A frame's time: finite, and after the previous frame's ``t_last`` (None: the first)."""
    t = finite_time(t_s, "a frame")
    if t_last is not None and not t > t_last:
        what = "repeated" if t == t_last else "out of order"
        raise InputError(f"frame time {t:.6g} s is not after the previous frame's {t_last:.6g} s "
                         f"({what} frame)")
    return t


def frame_array(image) -> np.ndarray:
    """A frame as a C-contiguous 2-D array of numbers (a path is read; an array is not copied
    when it is contiguous already)."""
    if not isinstance(image, np.ndarray) and isinstance(image, (str, os.PathLike)):
        from skyfix.io import read_image

        image = read_image(image)
    if not isinstance(image, np.ndarray):
        raise InputError(f"a frame is a 2-D array or an image file, got {type(image).__name__}")
    if image.ndim != 2 or image.dtype.kind not in "uif":
        raise InputError(f"a frame must be a 2-D array of numbers, got shape {image.shape} "
                         f"of {image.dtype}")
    return image if image.flags.c_contiguous else np.ascontiguousarray(image)


def gyro_rate(gyro) -> np.ndarray | None:
    """Gyro rates as three finite numbers (rad/s about camera x, y, z), or None."""
    if gyro is None:
        return None
    g = np.asarray(gyro, dtype=np.float64).reshape(-1)
    if g.shape != (3,) or not np.isfinite(g).all():
        raise InputError("gyro_rate_rad_s must be three finite numbers (rad/s about camera x, y, z)")
    return g
