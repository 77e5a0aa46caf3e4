"""Synthetic centroid sets for the solve-from-centroids benchmark (suite b).

``centroid_sets`` prefers skyfix's shared generator (``skyfix.analysis.synthetic_centroids``);
``generate`` here is the fallback, with the same model.
Each set is what a perfect detector would hand to a solver: the Hipparcos stars in view of a
pinhole camera at a random attitude, with Gaussian centroid noise, dropouts and false stars,
sorted brightest first. Positions follow docs/design.md: (x, y) = (column, row), (0, 0) the centre
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
        # False stars: anywhere in the frame, magnitudes uniform between the brightest and the
        # faintest true star, so they mix into the brightness order.
        fx = rng.uniform(-0.5, spec.width - 0.5, spec.n_false)
        fy = rng.uniform(-0.5, spec.height - 0.5, spec.n_false)
        lo, hi = (m.min(), m.max()) if len(m) else (0.0, spec.mag_limit)
        fm = rng.uniform(lo, hi, spec.n_false)
        xy = np.column_stack([np.r_[xs, fx], np.r_[ys, fy]])
        mm = np.r_[m, fm]
        order = np.argsort(mm, kind="stable")
        out.append(CentroidSet(xy[order], 10.0 ** (-0.4 * mm[order]) * 1e4, A, n_true))
    return out


def centroid_sets(spec: SyntheticSpec) -> tuple[list[CentroidSet], str]:
    """The sets for ``spec`` and the name of the generator used; cached in benchmarks/.cache as npz.

    skyfix's shared generator (``skyfix.analysis.synthetic_centroids``) is preferred; this
    module's own ``generate`` is the fallback when it is missing or its signature changed.
    """
    for name, make in (("skyfix.analysis.synthetic_centroids", _shared_generate),
                       ("benchmarks/synthetic.py", generate)):
        path = CACHE_DIR / f"centroids_{name.split('.')[-1].split('/')[-1]}_{spec.key()}.npz"
        if path.exists():
            z = np.load(path)
            return [CentroidSet(z[f"xy{i}"], z[f"flux{i}"], z["A"][i], int(z["n_true"][i]))
                    for i in range(spec.n)], name
        try:
            sets = make(spec)
        except (ImportError, TypeError, AttributeError):
            continue
        CACHE_DIR.mkdir(parents=True, exist_ok=True)
        arrays = {f"xy{i}": s.xy for i, s in enumerate(sets)}
        arrays.update({f"flux{i}": s.flux for i, s in enumerate(sets)})
        np.savez(path, A=np.array([s.A_true for s in sets]), n_true=np.array([s.n_true for s in sets]),
                 **arrays)
        return sets, name
    raise RuntimeError("no synthetic centroid generator worked")


def _shared_generate(spec: SyntheticSpec) -> list[CentroidSet]:
    """The sets made by skyfix's shared generator, with this spec's parameters."""
    from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
    from skyfix.camera import Camera
    from skyfix.catalog import load_hipparcos

    camera = Camera.from_fov(spec.width, spec.height, spec.fov_deg)
    catalog = load_hipparcos(mag_limit=spec.mag_limit)
    rng = np.random.default_rng(spec.seed)
    out = []
    for A in random_attitudes(spec.n, rng):
        f = synthetic_centroids(camera, A, catalog, mag_limit=spec.mag_limit, sigma_px=spec.sigma_px,
                                n_false=spec.n_false, dropout=spec.dropout, mag_sigma=spec.mag_jitter,
                                rng=rng)
        out.append(CentroidSet(np.asarray(f.xy, float), 10.0 ** (-0.4 * np.asarray(f.mag)) * 1e4,
                               np.asarray(f.A_icrs_to_cam, float), int(np.sum(f.star_id != 0))))
    return out
