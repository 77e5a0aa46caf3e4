"""The one place where the benchmarks call skyfix (so an API change is a change here only).

Calls: ``skyfix.pipeline.solve`` (image file or array → Solution), ``skyfix.pipeline.solve_centroids``
(centroids → Solution), ``skyfix.detect.extract_centroids``, ``skyfix.io.read_image``,
``skyfix.identify``'s ``PatternDatabase`` / ``default_database`` / ``default_database_path`` /
``identify`` and ``skyfix.final_fit.final_fit`` — all of them as they are at 1a5d56b, since
``benchmarks/run --against REF`` runs this adapter on an older skyfix too (in a worker process,
``worker.py``). Timings are wall clock around each call, measured exactly as for the peers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from common import CACHE_DIR, Attempt, now_ms


class Skyfix:
    name = "skyfix"
    is_skyfix = True  # a side of --against, and the tool suite b also runs with no FOV

    def __init__(self, min_fov_deg: float | None = None, max_fov_deg: float | None = None):
        import skyfix
        import skyfix.pipeline

        self.version = skyfix.__version__
        self.pipeline = skyfix.pipeline
        self.build_ms = None
        self.note = ""
        self.db, self.load_ms = self._database(min_fov_deg, max_fov_deg)

    # --- database --------------------------------------------------------------------------------
    def _database(self, min_fov: float | None, max_fov: float | None):
        """The default cached database (or, if it cannot be loaded, one built into benchmarks/.cache),
        or one for a custom FOV range cached in benchmarks/.cache."""
        from skyfix import identify
        from skyfix.errors import DatabaseError

        if min_fov is None:
            try:
                t0 = now_ms()
                db = identify.default_database()
                return db, now_ms() - t0
            except DatabaseError as exc:
                self.note = f"default database unusable ({exc}); built one in benchmarks/.cache"
                min_fov, max_fov = 10.0, 30.0
        path = CACHE_DIR / f"skyfix_{min_fov:g}-{max_fov:g}.npz"
        if path.exists():
            try:
                return self.load(path)
            except DatabaseError:
                pass  # stale format: rebuild
        self.build_ms, db = self.build(min_fov, max_fov)
        CACHE_DIR.mkdir(parents=True, exist_ok=True)
        db.save(path)
        return self.load(path)

    @staticmethod
    def build(min_fov: float, max_fov: float):
        from skyfix.identify import PatternDatabase

        t0 = now_ms()
        db = PatternDatabase.build(fov_min_deg=min_fov, fov_max_deg=max_fov)
        return now_ms() - t0, db

    @staticmethod
    def load(path: str | Path):
        from skyfix.identify import PatternDatabase

        t0 = now_ms()
        db = PatternDatabase.load(path)
        return db, now_ms() - t0

    def describe(self) -> dict:
        return {"version": self.version, "load_ms": self.load_ms, "build_ms": self.build_ms,
                "note": self.note}

    @staticmethod
    def database_build(folder: str | Path, min_fov: float = 10.0, max_fov: float = 30.0) -> dict:
        """Build a database from scratch and save it in ``folder``: build ms, its path and bytes."""
        ms, db = Skyfix.build(min_fov, max_fov)
        path = Path(folder) / "skyfix_db.npz"
        db.save(path)
        size = sum(f.stat().st_size for f in Path(folder).glob("skyfix_db*"))
        return {"build_ms": ms, "path": str(path), "bytes": size}

    @staticmethod
    def database_load(path: str | Path) -> float:
        """One load of a saved database, ms."""
        return Skyfix.load(path)[1]

    @staticmethod
    def default_database_load() -> float:
        """One load of the default (10–30°) database from the user cache, ms: what a solve loads."""
        from skyfix.identify import default_database_path

        return Skyfix.load(default_database_path())[1]

    def final_fit_ms(self, xy: np.ndarray, width: int, height: int, fov_deg: float, repeats: int = 5
                     ) -> list[float]:
        """The final fit of one identified frame (FOV given, no camera file), ms per repeat;
        empty when the frame is not identified."""
        from skyfix.final_fit import final_fit
        from skyfix.identify import identify

        ident = identify(xy, width, height, fov_deg=fov_deg, database=self.db)
        if not ident.success:
            return []
        out = []
        for _ in range(repeats):
            t0 = now_ms()
            final_fit(xy, ident, camera_given=False, database=self.db)
            out.append(now_ms() - t0)
        return out

    # --- solving ---------------------------------------------------------------------------------
    @staticmethod
    def _attempt(sol, dt: float) -> Attempt:
        if sol.status != "solved":
            return Attempt(False, None, dt, sol.reason or sol.status,
                           extra={"n_detected": sol.n_detected, "self_ms": dict(sol.time_ms)})
        # The frame at the image centre, as the peers and the references report it (skyfix's
        # boresight is the principal point, which it may fit elsewhere with no camera file).
        A = sol.attitude_at_pixel((sol.camera.width - 1) / 2.0, (sol.camera.height - 1) / 2.0)
        return Attempt(True, np.asarray(A, float), dt, "solved", int(sol.n_matched),
                       sol.fov_deg, {"n_detected": sol.n_detected, "self_ms": dict(sol.time_ms),
                                     "prob_false": sol.prob_false})

    def solve_centroids(self, xy: np.ndarray, width: int, height: int, fov_deg: float | None,
                        fov_max_error_deg: float | None = None, flux: np.ndarray | None = None,
                        timeout_ms: int = 5000) -> Attempt:
        t0 = now_ms()
        sol = self.pipeline.solve_centroids(xy, width, height, fov_deg=fov_deg,
                                            fov_tolerance_deg=fov_max_error_deg, database=self.db)
        return self._attempt(sol, now_ms() - t0)

    def solve_file(self, path: str | Path | np.ndarray, fov_deg: float | None = None,
                   fov_max_error_deg: float | None = None) -> Attempt:
        """End to end: file (or array) → Solution."""
        t0 = now_ms()
        sol = self.pipeline.solve(path, fov_deg=fov_deg, fov_tolerance_deg=fov_max_error_deg,
                                  database=self.db)
        return self._attempt(sol, now_ms() - t0)

    solve_image = solve_file

    @staticmethod
    def extract(image: np.ndarray, max_stars: int | None = None) -> tuple[np.ndarray, float]:
        from skyfix.detect import extract_centroids

        t0 = now_ms()
        c = extract_centroids(image) if max_stars is None else extract_centroids(image, max_stars=max_stars)
        dt = now_ms() - t0
        return np.asarray(c.xy, float).reshape(-1, 2), dt

    @staticmethod
    def read(path: str | Path) -> np.ndarray:
        from skyfix.io import read_image

        return read_image(path)
