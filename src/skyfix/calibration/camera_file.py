"""The camera file a calibration writes: the ``[camera]`` table (:meth:`skyfix.camera.Camera.to_toml`,
read back by :meth:`~skyfix.camera.Camera.from_toml` bit for bit) and a ``[calibration]`` table of how
it was made, which skyfix's readers ignore (docs/calibration.md). Every ``skyfix calibrate``
method writes it here."""

from __future__ import annotations

import numbers
from collections.abc import Mapping

from skyfix.camera import Camera

__all__ = ["camera_file"]


def _value(v: object) -> str:
    """A TOML value: a string quoted, a list of strings as literal strings, a number as Python
    writes it (``repr`` of a float reads back exactly)."""
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, (list, tuple)):
        return f"[{', '.join(repr(p) if isinstance(p, str) else _value(p) for p in v)}]"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, numbers.Integral):
        return str(int(v))
    return repr(float(v))


def camera_file(camera: Camera, calibration: Mapping[str, object], sigma: Mapping[str, float] | None = None,
                tables: Mapping[str, Mapping[str, object]] | None = None) -> str:
    """The camera file's text: ``[camera]``, then ``[calibration]`` with ``calibration``'s entries in
    order, ``[calibration.sigma]`` (each fitted number's 1σ) when ``sigma`` is given, then any
    further ``[calibration.NAME]`` tables of ``tables``."""
    lines = [camera.to_toml().rstrip("\n"), "", "[calibration]"]
    lines += [f"{k} = {_value(v)}" for k, v in calibration.items()]
    if sigma:
        lines += ["", "[calibration.sigma]  # 1σ of each fitted number, from the Jacobian"]
        lines += [f"{k} = {float(v)!r}" for k, v in sigma.items()]
    for name, table in (tables or {}).items():
        lines += ["", f"[calibration.{name}]"] + [f"{k} = {_value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"
