"""The bundled hardware presets under the simulator's names (:mod:`skyfix.presets` reads them)."""

from __future__ import annotations

from skyfix.presets import load_preset, preset_names

__all__ = ["load_preset", "preset_names"]
