"""Lost-in-space star identification: pattern database, identification methods by name, acceptance.

>>> from skyfix.identify import identify, default_database
>>> ident = identify(xy, width, height)             # xy: (N, 2) centroids, brightest first
>>> ident.success, ident.A_icrs_to_cam, ident.camera.fov_deg, ident.prob_false

- :class:`PatternDatabase` — ``build(fov_min_deg, fov_max_deg)``, ``save(path)``, ``load(path)``
  (memory-mapped ``.npz``); :func:`default_database` caches one in the user cache directory.
- :func:`identify` — identifies a frame with a method chosen by name from :data:`METHODS`
  (:mod:`skyfix.identify.methods` defines the interface a method implements); the default,
  ``"quad-hash"`` (:mod:`skyfix.identify.methods.quad`), is 4-star edge-ratio hashing with or without a
  FOV (or a calibrated camera), binomial false-match probability, mirror images rejected, work
  bounded. Every method returns an :class:`Identification`.
- :mod:`skyfix.identify.accept` — the rules that decide that a match is an identification.
"""

import importlib
import warnings

from skyfix.identify.catalogue.bands import (
    BANDS,
    DEEP,
    Band,
    band_database,
    default_database,
    default_database_path,
)
from skyfix.identify.catalogue.database import PatternDatabase
from skyfix.identify.common.result import Identification
from skyfix.identify.methods import DEFAULT_METHOD, METHODS, get_method, identify, method_options

__all__ = ["BANDS", "DEEP", "Band", "DEFAULT_METHOD", "METHODS", "Identification", "PatternDatabase",
           "band_database", "default_database", "default_database_path", "get_method", "identify",
           "method_options"]

# Modules that moved into the layers (issue 23): ``skyfix.identify.quad`` and the like still work
# as attributes (``from skyfix.identify import quad``), with a warning, until the next release.
_MOVED = {**dict.fromkeys(("database", "bands", "hashing", "pairs", "kernel_data", "triangles"), "catalogue"),
          **dict.fromkeys(("hypothesis", "verify", "refine", "angle_match", "result", "search"), "common"),
          **dict.fromkeys(("quad", "triangle", "liebe", "planar", "area_moment", "pyramid", "grid", "voting",
                           "match_groups"), "methods")}


def __getattr__(name: str):
    if name in _MOVED:
        new = f"skyfix.identify.{_MOVED[name]}.{name}"
        warnings.warn(f"skyfix.identify.{name} is now {new}; the old name goes in the next release",
                      DeprecationWarning, stacklevel=2)
        return importlib.import_module(new)
    raise AttributeError(f"module 'skyfix.identify' has no attribute {name!r}")
