"""Study results as strict JSON: the one conversion the studies' files share."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["strict_json"]


def strict_json(v):
    """``v`` with what :func:`json.dumps` would refuse or write as non-standard JSON replaced:
    non-finite floats → None, NamedTuples → dicts, other tuples and arrays → lists, numpy scalars
    → Python numbers, dict keys → strings."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, tuple) and hasattr(v, "_asdict"):
        return strict_json(v._asdict())
    if isinstance(v, dict):
        return {str(k): strict_json(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [strict_json(x) for x in v]
    if isinstance(v, np.ndarray):
        return strict_json(v.tolist())
    if isinstance(v, (np.floating, np.integer, np.bool_)):
        return strict_json(v.item())
    return v
