"""Lost-in-space star identification: pattern database, 4-star hashing search, verification.

>>> from skyfix.identify import identify, default_database
>>> ident = identify(xy, width, height)             # xy: (N, 2) centroids, brightest first
>>> ident.success, ident.A_icrs_to_cam, ident.camera.fov_deg, ident.prob_false

- :class:`PatternDatabase` — ``build(fov_min_deg, fov_max_deg)``, ``save(path)``, ``load(path)``
  (memory-mapped ``.npz``); :func:`default_database` caches one in the user cache directory.
- :func:`identify` — 4-star edge-ratio hashing with or without a FOV (or a calibrated camera),
  binomial false-match probability, mirror images rejected, work bounded; returns an
  :class:`Identification`.
"""

from skyfix.identify.database import PatternDatabase, default_database, default_database_path
from skyfix.identify.quad import Identification, identify

__all__ = ["Identification", "PatternDatabase", "default_database", "default_database_path", "identify"]
