"""Tracking mode: follow the sky from frame to frame (issue 9; docs/tracking.md).

>>> from skyfix.track import Tracker                                   # doctest: +SKIP
>>> tracker = Tracker(camera)                                          # doctest: +SKIP
>>> for image, t in frames:                                            # doctest: +SKIP
...     sol = tracker.update(image, t)   # sol.mode: "lost", "acquiring" or "tracking"

- :mod:`skyfix.track.tracker` — :class:`Tracker`, the state machine lost → acquiring → tracking.
- :mod:`skyfix.track.windows` — the catalogue-predicted windows of one tracking update.
- :mod:`skyfix.track.predictors` — the attitude predictors by name (:data:`PREDICTORS`: the
  MEKF of :mod:`skyfix.track.filter` by default, thesis 002's small-angle rate, the three-point
  extrapolators of thesis 004).
- :mod:`skyfix.track.rate`, :mod:`skyfix.track.relative` — rates from star motion, and
  frame-to-frame star IDs without a catalogue (thesis 002 §2.4–2.5).

The names below load their modules on first use: ``import skyfix.track`` costs nothing until a
name is asked for (the ``skyfix track`` command is :mod:`skyfix.cli.track`).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from skyfix.track.predictors import PREDICTORS, Prediction, make_predictor
    from skyfix.track.tracker import MODES, Tracker, TrackSettings

__all__ = ["MODES", "PREDICTORS", "Prediction", "TrackSettings", "Tracker", "make_predictor"]

_LAZY = {
    "MODES": "skyfix.track.tracker",
    "PREDICTORS": "skyfix.track.predictors",
    "Prediction": "skyfix.track.predictors",
    "TrackSettings": "skyfix.track.tracker",
    "Tracker": "skyfix.track.tracker",
    "make_predictor": "skyfix.track.predictors",
}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'skyfix.track' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
