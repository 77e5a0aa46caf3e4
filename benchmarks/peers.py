"""Thin adapters for the peer solvers: tetra3rs (Rust, PyPI) and cedar-solve (Python, PyPI ``tetra3``).

Benchmark-only: the skyfix package never imports these. Each adapter takes and returns skyfix's
conventions (pixels: (x, y) = (column, row), (0, 0) the centre of the top-left pixel; attitude
``A_icrs_to_cam``), and converts at its own edge. The conversions were checked on noise-free
synthetic centroids (see ``check_conventions`` in run_all.py): each gives < 0.1″ boresight error.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from common import CACHE_DIR, Attempt, attitude_from_radec_roll_deg, now_ms


def load_gray(path: str | Path) -> np.ndarray:
    """An image file as a 2-D array (luminance for colour), in its native integer type."""
    from PIL import Image

    path = str(path)
    if path.lower().endswith((".tif", ".tiff")):
        try:
            import tifffile

            arr = tifffile.imread(path)
        except ImportError:
            arr = np.asarray(Image.open(path))
    else:
        img = Image.open(path)
        if img.mode not in ("L", "I;16", "I", "F"):
            img = img.convert("L")
        arr = np.asarray(img)
    if arr.ndim == 3:
        arr = arr[..., :3].mean(axis=2)
    return arr


# --- tetra3rs -------------------------------------------------------------------------------------

class Tetra3rs:
    """tetra3rs: database generated from the bundled Gaia catalogue and cached in benchmarks/.cache."""

    name = "tetra3rs"

    def __init__(self, min_fov_deg: float = 10.0, max_fov_deg: float = 30.0, epoch: float = 2026.0,
                 match_max_error: float | None = None):
        import tetra3rs

        # None = the database's pattern_max_error (0.001, tetra3rs' default); 0.002 is cedar-solve's
        # default and makes tetra3rs solve σ = 1 px centroids far more often (see README).
        self.match_max_error = match_max_error
        if match_max_error is not None:
            self.name = f"tetra3rs (mme {match_max_error:g})"

        self.t3 = tetra3rs
        self.version = tetra3rs.__version__
        self.min_fov, self.max_fov, self.epoch = min_fov_deg, max_fov_deg, epoch
        self.path = CACHE_DIR / f"tetra3rs_{min_fov_deg:g}-{max_fov_deg:g}_{epoch:g}.bin"
        self.build_ms = None
        if not self.path.exists():
            self.build_ms, db = self.build()
            CACHE_DIR.mkdir(parents=True, exist_ok=True)
            db.save_to_file(str(self.path))
        self.db, self.load_ms = self.load()

    def build(self):
        t0 = now_ms()
        db = self.t3.SolverDatabase.generate_from_gaia(
            max_fov_deg=self.max_fov, min_fov_deg=self.min_fov, epoch_proper_motion_year=self.epoch)
        return now_ms() - t0, db

    def load(self):
        t0 = now_ms()
        db = self.t3.SolverDatabase.load_from_file(str(self.path))
        return db, now_ms() - t0

    def _to_t3(self, xy: np.ndarray, width: int, height: int) -> np.ndarray:
        # tetra3rs: origin at the image centre (width/2, height/2 in corner-origin pixels),
        # i.e. ((width-1)/2, (height-1)/2) in skyfix's pixel-centre convention.
        return np.column_stack([xy[:, 0] - (width - 1) / 2.0, xy[:, 1] - (height - 1) / 2.0])

    def solve_centroids(self, xy: np.ndarray, width: int, height: int, fov_deg: float,
                        fov_max_error_deg: float | None = None, flux: np.ndarray | None = None,
                        timeout_ms: int = 5000) -> Attempt:
        c = self._to_t3(np.asarray(xy, float), width, height)
        if flux is not None:
            c = np.column_stack([c, flux])
        t0 = now_ms()
        r = self.db.solve_from_centroids(c, fov_estimate_deg=fov_deg, image_width=width,
                                         image_height=height, fov_max_error_deg=fov_max_error_deg,
                                         solve_timeout_ms=timeout_ms, match_max_error=self.match_max_error)
        dt = now_ms() - t0
        if not r:
            return Attempt(False, None, dt, r.status)
        A = np.asarray(r.rotation_matrix_icrs_to_camera, float)
        return Attempt(True, A, dt, "solved", int(r.num_matches), float(r.fov_deg),
                       {"self_ms": float(r.solve_time_ms), "parity_flip": bool(r.parity_flip)})

    def extract(self, image: np.ndarray, threads: int | None = None) -> tuple[np.ndarray, float]:
        """Centroids (skyfix pixel convention, brightest first) and the wall time in ms."""
        t0 = now_ms()
        res = self.t3.extract_centroids(image, threads=threads)
        dt = now_ms() - t0
        return self._centroids_xy(res, image.shape), dt

    def _centroids_xy(self, res, shape) -> np.ndarray:
        cs = res.centroids
        xy = np.array([[c.x, c.y] for c in cs], float).reshape(-1, 2)
        h, w = shape[:2]
        return xy + [(w - 1) / 2.0, (h - 1) / 2.0]

    def solve_image(self, image: np.ndarray, fov_deg: float, fov_max_error_deg: float | None = None,
                    ) -> Attempt:
        """Extraction + solve on an in-memory image (time covers both)."""
        t0 = now_ms()
        res = self.t3.extract_centroids(image)
        h, w = image.shape[:2]
        r = self.db.solve_from_centroids(res.centroids, fov_estimate_deg=fov_deg, image_width=w,
                                         image_height=h, fov_max_error_deg=fov_max_error_deg,
                                         match_max_error=self.match_max_error)
        dt = now_ms() - t0
        if not r:
            return Attempt(False, None, dt, r.status, extra={"n_detected": len(res.centroids)})
        return Attempt(True, np.asarray(r.rotation_matrix_icrs_to_camera, float), dt, "solved",
                       int(r.num_matches), float(r.fov_deg), {"n_detected": len(res.centroids)})

    def solve_file(self, path: str | Path, fov_deg: float, fov_max_error_deg: float | None = None,
                   ) -> Attempt:
        """End to end: read the file, extract, solve."""
        t0 = now_ms()
        img = load_gray(path)
        a = self.solve_image(img, fov_deg, fov_max_error_deg)
        a.time_ms = now_ms() - t0
        return a


# --- cedar-solve ----------------------------------------------------------------------------------

class Cedar:
    """cedar-solve (``tetra3`` module) with its bundled default database (10–30° FOV, Hipparcos)."""

    name = "cedar-solve"

    def __init__(self):
        logging.getLogger("tetra3.Tetra3").setLevel(logging.WARNING)
        if not hasattr(np, "math"):
            # cedar-solve 0.5 calls np.math.factorial, removed in numpy 2; the stdlib is the same.
            import math

            np.math = math
        import tetra3

        self.mod = tetra3
        from importlib.metadata import version

        self.version = version("cedar-solve")
        t0 = now_ms()
        self.t3 = tetra3.Tetra3()
        self.load_ms = now_ms() - t0
        for h in self.t3._logger.handlers:
            h.setLevel(logging.WARNING)
        props = self.t3.database_properties
        self.min_fov, self.max_fov = float(props["min_fov"]), float(props["max_fov"])

    @staticmethod
    def _to_cedar(xy: np.ndarray) -> np.ndarray:
        # cedar-solve: (y, x) rows with the image centre at (height/2, width/2): corner origin,
        # so pixel centres sit at +0.5.
        return np.column_stack([xy[:, 1] + 0.5, xy[:, 0] + 0.5])

    @staticmethod
    def _attitude(sol: dict) -> np.ndarray:
        # cedar's 'Roll' is the angle of north counter-clockwise from image-up; skyfix's roll is
        # the position angle of image-up from north through east: the negative of cedar's.
        return attitude_from_radec_roll_deg(sol["RA"], sol["Dec"], -sol["Roll"])

    def _attempt(self, sol: dict, dt: float, extra: dict | None = None) -> Attempt:
        if sol.get("status") != 1 or sol.get("RA") is None:
            status = {2: "no_match", 3: "timeout", 4: "cancelled", 5: "too_few"}.get(sol.get("status"),
                                                                                  str(sol.get("status")))
            return Attempt(False, None, dt, status, extra=extra or {})
        return Attempt(True, self._attitude(sol), dt, "solved", int(sol["Matches"]), float(sol["FOV"]),
                       {"self_ms": float(sol["T_solve"]), **(extra or {})})

    def solve_centroids(self, xy: np.ndarray, width: int, height: int, fov_deg: float | None,
                        fov_max_error_deg: float | None = None, flux: np.ndarray | None = None,
                        timeout_ms: int = 5000) -> Attempt:
        c = self._to_cedar(np.asarray(xy, float))
        t0 = now_ms()
        sol = self.t3.solve_from_centroids(c, (height, width), fov_estimate=fov_deg,
                                           fov_max_error=fov_max_error_deg, solve_timeout=timeout_ms)
        return self._attempt(sol, now_ms() - t0)

    def extract(self, image: np.ndarray) -> tuple[np.ndarray, float]:
        t0 = now_ms()
        yx = self.mod.get_centroids_from_image(image)
        dt = now_ms() - t0
        yx = np.asarray(yx, float).reshape(-1, 2) - 0.5  # corner origin -> pixel-centre origin
        return np.column_stack([yx[:, 1], yx[:, 0]]), dt

    def solve_image(self, image: np.ndarray, fov_deg: float | None = None,
                    fov_max_error_deg: float | None = None) -> Attempt:
        """Extraction + solve on an in-memory image (time covers both)."""
        t0 = now_ms()
        yx = self.mod.get_centroids_from_image(image)
        h, w = image.shape[:2]
        sol = self.t3.solve_from_centroids(yx, (h, w), fov_estimate=fov_deg, fov_max_error=fov_max_error_deg)
        return self._attempt(sol, now_ms() - t0, {"n_detected": len(yx)})

    def solve_file(self, path: str | Path, fov_deg: float | None = None,
                   fov_max_error_deg: float | None = None) -> Attempt:
        """End to end as cedar-solve's README does it: PIL image → solve_from_image."""
        from PIL import Image

        t0 = now_ms()
        with Image.open(str(path)) as img:
            img.load()
            sol = self.t3.solve_from_image(img, fov_estimate=fov_deg, fov_max_error=fov_max_error_deg)
        return self._attempt(sol, now_ms() - t0, {"extract_ms": sol.get("T_extract")})


def available_peers() -> dict[str, str]:
    """Which peers import in this interpreter, with their versions (or the import error)."""
    out = {}
    for mod in ("tetra3rs", "tetra3"):
        try:
            __import__(mod)
            out[mod] = "ok"
        except Exception as exc:  # noqa: BLE001 - report any import failure
            out[mod] = f"{type(exc).__name__}: {exc}"
    return out

