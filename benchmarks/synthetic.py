"""Synthetic centroid sets for the solve-from-centroids benchmark (suite b).

A stand-in until ``skyfix.analysis.synthetic_centroids`` exists (``centroid_sets`` prefers it).
Each set is what a perfect detector would hand to a solver: the Hipparcos stars in view of a
pinhole camera at a random attitude, with Gaussian centroid noise, dropouts and false stars,
sorted brightest first. Positions follow DESIGN.md: (x, y) = (column, row), (0, 0) the centre
of the top-left pixel.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from common import CACHE_DIR


@dataclass(frozen=True)
class SyntheticSpec:
    width: int = 1280
    height: int = 960
    fov_deg: float = 15.0
    mag_limit: float = 8.0
    sigma_px: float = 1.0
    n_false: int = 8
    dropout: float = 0.10
    mag_jitter: float = 0.2  # brightness-order noise (mag), so order is not exactly catalogue order
    n: int = 1000
    seed: int = 1

    @property
    def label(self) -> str:
        return f"σ={self.sigma_px:g}px false={self.n_false}"

    def key(self) -> str:
        return hashlib.sha1(repr(self).encode()).hexdigest()[:12]


@dataclass
class CentroidSet:
    xy: np.ndarray  # (N, 2) pixels, brightest first
    flux: np.ndarray  # (N,) arbitrary units, descending
    A_true: np.ndarray  # (3, 3) A_icrs_to_cam
    n_true: int  # how many of xy are real stars


def _hipparcos(mag_limit: float):
    from skyfix.catalog import load_hipparcos

    cat = load_hipparcos(mag_limit=mag_limit)
    return cat.vectors, np.asarray(cat.mag, float)


def generate(spec: SyntheticSpec) -> list[CentroidSet]:
    """``spec.n`` centroid sets at uniformly random attitudes (reproducible from ``spec.seed``)."""
    vectors, mags = _hipparcos(spec.mag_limit)
    tree = cKDTree(vectors)
    rng = np.random.default_rng(spec.seed)
    f = (spec.width / 2.0) / np.tan(np.radians(spec.fov_deg) / 2.0)
    cx, cy = (spec.width - 1) / 2.0, (spec.height - 1) / 2.0
    half_diag = np.arctan(np.hypot(spec.width, spec.height) / 2.0 / f)
    chord = 2.0 * np.sin(half_diag / 2.0) * 1.01
    out = []
    rotations = Rotation.random(spec.n, random_state=rng.integers(2**31))
    for rot in rotations:
        A = rot.as_matrix()  # rows: camera axes in ICRS
        idx = np.asarray(tree.query_ball_point(A[2], chord), int)
        b = vectors[idx] @ A.T
        front = b[:, 2] > 0
        idx, b = idx[front], b[front]
        x = f * b[:, 0] / b[:, 2] + cx
        y = f * b[:, 1] / b[:, 2] + cy
        x = x + rng.normal(0.0, spec.sigma_px, len(x))
        y = y + rng.normal(0.0, spec.sigma_px, len(y))
        inside = (x >= -0.5) & (x <= spec.width - 0.5) & (y >= -0.5) & (y <= spec.height - 0.5)
        keep = inside & (rng.random(len(x)) >= spec.dropout)
        m = mags[idx][keep] + rng.normal(0.0, spec.mag_jitter, keep.sum())
        xs, ys = x[keep], y[keep]
        n_true = len(xs)
        # False stars: anywhere in the frame, brightness spread over the range of real stars.
        fx = rng.uniform(-0.5, spec.width - 0.5, spec.n_false)
        fy = rng.uniform(-0.5, spec.height - 0.5, spec.n_false)
        fm = rng.uniform(3.0, spec.mag_limit, spec.n_false)
        xy = np.column_stack([np.r_[xs, fx], np.r_[ys, fy]])
        mm = np.r_[m, fm]
        order = np.argsort(mm, kind="stable")
        out.append(CentroidSet(xy[order], 10.0 ** (-0.4 * mm[order]) * 1e4, A, n_true))
    return out


def centroid_sets(spec: SyntheticSpec) -> tuple[list[CentroidSet], str]:
    """The sets for ``spec`` and the generator used; cached in benchmarks/.cache as npz."""
    shared = _shared_generator(spec)
    if shared is not None:
        return shared, "skyfix.analysis.synthetic_centroids"
    path = CACHE_DIR / f"centroids_{spec.key()}.npz"
    if path.exists():
        z = np.load(path)
        sets = [CentroidSet(z[f"xy{i}"], z[f"flux{i}"], z["A"][i], int(z["n_true"][i]))
                for i in range(spec.n)]
        return sets, "benchmarks/synthetic.py"
    sets = generate(spec)
    CACHE_DIR.mkdir(parents=True, exist_ok=True)
    arrays = {f"xy{i}": s.xy for i, s in enumerate(sets)}
    arrays.update({f"flux{i}": s.flux for i, s in enumerate(sets)})
    np.savez(path, A=np.array([s.A_true for s in sets]), n_true=np.array([s.n_true for s in sets]),
             **arrays)
    return sets, "benchmarks/synthetic.py"


def _shared_generator(spec: SyntheticSpec) -> list[CentroidSet] | None:
    """Use skyfix's shared generator when it exists (hook; adapted once its API is known)."""
    try:
        from skyfix.analysis import synthetic_centroids  # noqa: F401
    except ImportError:
        return None
    return None
