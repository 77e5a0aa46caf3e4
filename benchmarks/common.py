"""Shared pieces of the benchmarks: paths, the Attempt record, error metrics, timing statistics.

The error metrics are written here from first principles (not imported from skyfix) so that a
convention bug in skyfix.geometry cannot hide itself by being used on both sides of a comparison.
Conventions are those of docs/design.md: ``A`` takes ICRS unit vectors into the camera frame (``b = A r``),
its rows are the camera axes in ICRS; roll is the position angle of image-up (camera ``-y``)
from north through east.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

BENCH_DIR = Path(__file__).resolve().parent
REPO_ROOT = BENCH_DIR.parent
CACHE_DIR = BENCH_DIR / ".cache"
RESULTS_DIR = BENCH_DIR / "results"
# shared/data/real beside the checkout (a worktree may sit a level or two deeper, e.g. wt/<name>)
REAL_DIR = next((p / "shared" / "data" / "real" for p in REPO_ROOT.parents
                 if (p / "shared" / "data" / "real" / "solutions.jsonl").is_file()),
                REPO_ROOT.parent / "shared" / "data" / "real")

ARCSEC_PER_RAD = 180.0 / np.pi * 3600.0



@dataclass
class Attempt:
    """One tool's answer for one input.

    ``A`` is ``A_icrs_to_cam`` in skyfix's conventions (None on failure); ``time_ms`` is the
    wall-clock time of the call, measured the same way for every tool.
    """

    solved: bool
    A: np.ndarray | None = None
    time_ms: float = float("nan")
    status: str = ""
    n_matched: int = 0
    fov_deg: float | None = None
    extra: dict = field(default_factory=dict)


def now_ms() -> float:
    return time.perf_counter() * 1000.0


# --- attitude geometry (independent of skyfix.geometry) -----------------------------------------

def radec_to_vec(ra_deg: float, dec_deg: float) -> np.ndarray:
    ra, dec = np.radians(ra_deg), np.radians(dec_deg)
    return np.array([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)])


def attitude_from_radec_roll_deg(ra_deg: float, dec_deg: float, roll_deg: float) -> np.ndarray:
    """``A_icrs_to_cam`` for a boresight (ra, dec) and roll (PA of image-up, N through E), degrees."""
    ra, dec, roll = np.radians([ra_deg, dec_deg, roll_deg])
    z = radec_to_vec(ra_deg, dec_deg)
    east = np.array([-np.sin(ra), np.cos(ra), 0.0])
    north = np.cross(z, east)
    up = north * np.cos(roll) + east * np.sin(roll)
    y = -up
    x = np.cross(y, z)
    return np.vstack([x, y, z])


def radec_roll_deg(A: np.ndarray) -> tuple[float, float, float]:
    """Boresight RA, Dec and roll (degrees; roll in [0, 360)) of ``A_icrs_to_cam``."""
    z = A[2] / np.linalg.norm(A[2])
    ra = np.arctan2(z[1], z[0]) % (2 * np.pi)
    dec = np.arcsin(np.clip(z[2], -1, 1))
    east = np.array([-np.sin(ra), np.cos(ra), 0.0])
    north = np.cross(z, east)
    up = -A[1]
    roll = np.arctan2(up @ east, up @ north) % (2 * np.pi)
    return float(np.degrees(ra)), float(np.degrees(dec)), float(np.degrees(roll))


def boresight_error_arcsec(A_est: np.ndarray, A_true: np.ndarray) -> float:
    """Angle between the two boresights (third rows), arcseconds."""
    a, b = A_est[2], A_true[2]
    return float(np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b) * ARCSEC_PER_RAD)


def roll_error_deg(A_est: np.ndarray, A_true: np.ndarray) -> float:
    """Rotation about the boresight between two attitudes, degrees (absolute, ≤ 180).

    Measured as the angle between the two image-x axes after projecting them onto the plane
    normal to the true boresight, so it stays well defined near the celestial poles.
    """
    z = A_true[2]
    xa = A_est[0] - (A_est[0] @ z) * z
    xb = A_true[0]
    ang = np.arctan2(np.cross(xb, xa) @ z, xa @ xb)
    return float(abs(np.degrees(ang)))


def roll_diff_deg(a_deg: float, b_deg: float) -> float:
    """Absolute difference of two roll angles, wrapped to [0, 180]."""
    return float(abs((a_deg - b_deg + 180.0) % 360.0 - 180.0))


def is_wrong(bore_arcsec: float, roll_deg: float, plate_scale_arcsec: float = 0.0) -> bool:
    """A *wrong attitude*: skyfix's one definition (:func:`skyfix.analysis.truth.is_wrong`,
    boresight beyond max(60″, 1 px) or roll beyond 0.5°), applied to the errors measured here."""
    from skyfix.analysis.truth import is_wrong as one_definition

    return one_definition(bore_arcsec, roll_deg, plate_scale_arcsec)


# --- statistics --------------------------------------------------------------------------------

def pct(values, q: float) -> float:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], float)
    return float(np.percentile(v, q)) if len(v) else float("nan")


def median(values) -> float:
    return pct(values, 50.0)


def call_many(tool, method: str, calls: list[tuple[tuple, dict]]) -> list:
    """``getattr(tool, method)(*args, **kwargs)`` for each call, in order: the value, or the
    exception it raised. A worker-backed tool (``remote.RemoteSkyfix``) takes the whole batch in
    one round trip (``tool.many``)."""
    many = getattr(tool, "many", None)
    if many is not None:
        return many(method, calls)
    fn, out = getattr(tool, method), []
    for args, kwargs in calls:
        try:
            out.append(fn(*args, **kwargs))
        except Exception as exc:  # noqa: BLE001 - recorded in its place, as the suites report it
            out.append(exc)
    return out


def ratio(a: float, b: float) -> float:
    return a / b if (np.isfinite(a) and np.isfinite(b) and b > 0) else float("nan")


def write_json(name: str, payload: dict) -> Path:
    path = RESULTS_DIR / f"{name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_jsonable(payload), indent=1))
    return path


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        f = float(obj)
        return f if np.isfinite(f) else None
    return obj
