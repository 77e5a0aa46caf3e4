"""Bundled hardware presets: one TOML file per camera in this folder with a ``[camera]``, a
``[sensor]``, an ``[optics]`` and a ``[defaults]`` table (some add ``[exclusion]``). Read by the
simulator (``skyfix.simulate`` re-exports these names), :meth:`skyfix.camera.Camera.load` (a
preset name in place of a file) and the corrections' exclusion angles; it imports nothing of
skyfix but its errors, so any module may use it."""

from __future__ import annotations

from functools import lru_cache
from importlib import resources

import tomllib

from skyfix.errors import unknown_name

__all__ = ["preset_names", "load_preset"]


def preset_names() -> list[str]:
    """Names of the bundled presets (file stems), sorted."""
    folder = resources.files(__name__)
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


@lru_cache(maxsize=32)
def _read(name: str) -> dict:
    path = resources.files(__name__) / f"{name}.toml"
    return tomllib.loads(path.read_text())


def load_preset(name: str) -> dict:
    """The tables of preset ``name`` (case-insensitive) as a new dict of dicts."""
    key = str(name).lower().strip()
    if key not in preset_names():
        raise unknown_name("preset", name, preset_names())
    return {k: dict(v) for k, v in _read(key).items()}
