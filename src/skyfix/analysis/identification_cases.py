"""The seeds' identification experiments as named cases (:data:`CASES`,
``skyfix analyze identification --case NAME``):

- ``quest-catalogue`` — thesis 000 §6.1.3: every 3-star cluster of the catalogue fed to QUEST
  as both image and reference (:func:`quest_catalogue`), and the same clusters as 3-star
  frames through identification (:func:`three_star_frames`);
- ``table-3-7`` — thesis 004 Table 3-7: 1000 attitudes per tolerance row inside the Table 3-5
  envelope, the Sunsat camera, the ≤ 8 brightest stars, van Bezooijen's match groups on a
  database of the envelope's sub-catalogue (:func:`table_3_7`);
- ``sparse-fields`` — issue 11's 3-star fields: 30° frames that detect exactly their three
  brightest stars, noise-free (:func:`sparse_fields`);
- ``perturbation`` — thesis 000 Table 6 and §6.4: one star of a catalogue cluster moved along
  x by a growing shift, the fraction still identified right (:func:`perturbation_sweep`).

Each runs as a trial of :class:`CaseStudy` on the campaign engine (a row of
``identification_cases.parquet``: the case, its time, its result as JSON), so several run on as
many workers.

docs/identification-study.md has a full run's numbers beside the theses'.
"""

from __future__ import annotations

import itertools
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from skyfix.analysis._json import strict_json
from skyfix.analysis.identification_jobs import (
    EPOCH,
    HEIGHT,
    WIDTH,
    judge_identification,
    upper_bound_95,
)
from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
from skyfix.attitude import solve_attitude
from skyfix.camera import Camera, camera_from_preset
from skyfix.catalog import load_hipparcos
from skyfix.geometry import attitude_from_radec_roll, normalize, rotation_angle_between, vector_to_radec
from skyfix.identify import Identification, PatternDatabase, default_database, identify
from skyfix.identify.common.hypothesis import chance_log_probability, frame_for, hypothesis
from skyfix.montecarlo.engine import cluster, run_rows
from skyfix.montecarlo.study import BatchedStudy

if TYPE_CHECKING:
    import pyarrow as pa

__all__ = ["CASES", "CaseStudy", "MatchingRow", "SHIFTS_PX", "TABLE_3_7_ROWS", "case_results",
           "case_study", "perturbation_sweep", "quest_catalogue", "run_cases", "sparse_fields",
           "table_3_7", "three_star_frames"]

_ARCSEC = math.pi / (180.0 * 3600.0)


def _clusters(vectors: np.ndarray, max_angle_rad: float) -> np.ndarray:
    """Every triangle (i < j < k) of ``vectors`` whose three sides are at most ``max_angle_rad``,
    from the pair table's neighbour lists."""
    from skyfix.identify.catalogue.pairs import build_pair_table

    table = build_pair_table(vectors, np.arange(len(vectors), dtype=np.int32), max_angle_rad)
    i, j = table.first.astype(np.int64), table.second.astype(np.int64)
    adj = np.zeros((len(vectors), len(vectors)), bool)
    adj[i, j] = adj[j, i] = True
    # third vertices k > j adjacent to both: one boolean row product per pair (vectorised over k)
    tri = []
    for chunk in range(0, len(i), 20000):
        a, b = i[chunk:chunk + 20000], j[chunk:chunk + 20000]
        rows, ks = np.nonzero(adj[a] & adj[b])
        keep = ks > b[rows]
        tri.append(np.stack([a[rows][keep], b[rows][keep], ks[keep]], 1))
    return np.concatenate(tri) if tri else np.zeros((0, 3), np.int64)


def quest_catalogue(n_stars: int = 513, max_angle_deg: float = 21.25) -> dict:
    """Thesis 000 §6.1.3: every 3-star cluster of the ``n_stars`` brightest stars (000 used a
    BSC cut of ~V 4: 513 stars) with all sides ≤ ``max_angle_deg`` (≈ 26,500 clusters, as
    000's 26,437), each fed to QUEST as image and reference: success when the attitude is the
    identity to 1″. 000: 25,564 of 26,437 (96.7 %)."""
    cat = load_hipparcos(epoch=EPOCH)
    v = cat.vectors[:n_stars]
    tri = _clusters(v, math.radians(max_angle_deg))
    ok = 0
    worst = 0.0
    for t in tri:
        A = solve_attitude(v[t], v[t], method="quest")
        err = rotation_angle_between(A, np.eye(3)) / _ARCSEC
        worst = max(worst, err)
        ok += err < 1.0
    return {"case": "quest-catalogue", "n_stars": n_stars, "max_angle_deg": max_angle_deg,
            "clusters": len(tri), "identity": int(ok), "success_pct": 100.0 * ok / max(len(tri), 1),
            "worst_arcsec": worst, "thesis": {"clusters": 26437, "identity": 25564, "success_pct": 96.7}}


SHIFTS_PX = (0.0, 0.0004, 0.0008, 0.01, 0.1, 0.5, 1.0, 2.0, 5.0, 10.0)
"""Thesis 000's sweep moved one star by 0.01 % steps of a pixel up to 1 % (its Table 6 means:
0.04–0.06 %); skyfix's tolerances are set by the centroid noise, so the sweep goes on to 5 px."""


def perturbation_sweep(shifts_px: tuple[float, ...] = SHIFTS_PX, n_stars: int = 513,
                       max_angle_deg: float = 21.25, n_clusters: int = 200, method: str = "triangle",
                       seed: int = 0, exactly_three: bool = False) -> dict:
    """Thesis 000 Table 6 and §6.4: the clusters of :func:`quest_catalogue` as frames — each
    seen by thesis 000's camera (preset ``mt9v022``, calibrated) at a random roll with its
    centroid on the boresight, with every other catalogue star in view (``exactly_three``: only
    the clusters with none) — one cluster star moved along x by each of ``shifts_px``,
    identified by ``method`` and judged against the truth: right, wrong, or refused. As in the
    thesis, the catalogue is identified against itself: the database is built from the same
    stars. (The thesis's frames held the cluster alone; skyfix rejects a match that leaves a
    catalogue star in view undetected, so such a frame is not a frame it can be given.)"""
    cat = load_hipparcos(epoch=EPOCH)
    v = cat.vectors[:n_stars]
    tri = _clusters(v, math.radians(max_angle_deg))
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(tri), size=min(n_clusters, len(tri)), replace=False)
    camera = camera_from_preset("mt9v022")
    # the thesis identified the catalogue against itself: a database of the same stars
    stars = cat.subset(np.arange(n_stars))
    db = PatternDatabase.build(camera.fov_deg / 1.2, camera.fov_deg * 1.2, catalog=stars, epoch=EPOCH)
    frames = []
    for t in tri[pick]:
        ra, dec = vector_to_radec(normalize(v[t].sum(0)))
        A = attitude_from_radec_roll(float(ra), float(dec), rng.uniform(0, 2 * math.pi))
        xy, front = camera.ray_to_pixel(v[t] @ A.T)
        if not (front.all() and camera.in_frame(xy).all()):
            continue
        # the frame holds every catalogue star in view (a camera sees them all), the cluster first
        near = np.setdiff1d(stars.cone(A[2], math.radians(40.0)), t)
        other, front = camera.ray_to_pixel(v[near] @ A.T)
        seen = front & camera.in_frame(other)
        if exactly_three and seen.any():
            continue
        ids = np.concatenate([stars.ids[t], stars.ids[near][seen]])
        frames.append((A, np.vstack([xy, other[seen]]), int(rng.integers(3)), ids))
    rows = []
    for shift in shifts_px:
        right = wrong = 0
        reasons: dict[str, int] = {}
        wrong_detail = []
        for A, xy, star, ids in frames:
            moved = xy.copy()
            moved[star, 0] += shift
            ident = identify(moved, camera.width, camera.height, method=method, camera=camera, database=db,
                             epoch=EPOCH)
            if not ident.success:
                key = ident.reason.split(":")[0].split("(")[0].strip()
                reasons[key] = reasons.get(key, 0) + 1
            elif (verdict := judge_identification(ident, A, camera)).wrong:
                wrong += 1
                wrong_detail.append({"boresight_arcsec": verdict.boresight_arcsec,
                                     "roll_deg": verdict.roll_deg, "matched": ident.n_matched,
                                     "matched_true": int(np.sum(ids[ident.star_index] == ident.catalog_ids)),
                                     "moved_star_matched": bool(star in set(ident.star_index.tolist()))})
            else:
                right += 1
        n = len(frames)
        rows.append({"shift_px": shift, "frames": n, "right": right, "wrong": wrong,
                     "wrong_detail": wrong_detail, "refused": n - right - wrong,
                     "right_pct": 100.0 * right / max(n, 1),
                     "wrong_upper95_pct": 100.0 * upper_bound_95(wrong, n), "refusals": reasons})
    return {"case": "perturbation", "method": method, "clusters": len(tri),
            "not_used": len(pick) - len(frames),
            "rows": rows, "thesis": {"table_6_mean_tolerance_pct_px": {"x": 0.04, "y": 0.05, "z": 0.06},
                                     "success_at_0.04pct_px": 75, "success_beyond_0.08pct_px": "< 50"}}


def three_star_frames(n_clusters: int = 10_000, method: str = "triangle", seed: int = 0) -> dict:
    """:func:`perturbation_sweep` with no shift on the clusters of the 170 brightest stars (000's
    magnitude-3 catalogue) alone in thesis 000's frame (exactly three catalogue stars in view):
    3-star fields, solved or refused as ambiguous."""
    return {**perturbation_sweep((0.0,), n_stars=170, max_angle_deg=31.8, n_clusters=n_clusters,
                                 method=method, seed=seed, exactly_three=True), "case": "three-star-frames"}


CASES: dict[str, Callable[..., dict]] = {
    "quest-catalogue": quest_catalogue,
    "three-star-frames": three_star_frames,
    "perturbation": perturbation_sweep,
}



class MatchingRow(NamedTuple):
    """One row of thesis 004's Table 3-7: the errors simulated and the tolerances matched with
    (µrad, mag), and the thesis's outcome of 1000 trials."""

    sigma_p_urad: float
    sigma_mv: float
    d_uncert_urad: float
    mv_uncert: float
    thesis_fail_lt3: int
    thesis_fail_gt3: int
    thesis_success_pct: float


TABLE_3_7_ROWS = (
    MatchingRow(50, 0.3, 50, 0.3, 4, 177, 81.9),
    MatchingRow(50, 0.3, 75, 0.45, 5, 17, 97.8),
    MatchingRow(50, 0.3, 100, 0.6, 3, 9, 98.8),
    MatchingRow(50, 0.3, 150, 0.6, 2, 4, 99.4),
    MatchingRow(100, 0.3, 200, 0.45, 4, 24, 97.2),
)


def table_3_7(trials: int = 1000, method: str = "van-bezooijen", seed: int = 0,
              rows: tuple[MatchingRow, ...] = TABLE_3_7_ROWS) -> dict:
    """Thesis 004 Table 3-7: ``trials`` attitudes drawn uniformly inside the Table 3-5 envelope,
    the Sunsat camera (preset ``sunsat``), Gaussian errors σ_p on each star's position and σ_Mv on
    its magnitude, the ≤ 8 brightest stars (thesis 004's V ≤ 6: the 5,026 brightest) identified
    by ``method`` against a pattern database of the envelope's sub-catalogue
    (:func:`skyfix.analysis.coverage.sub_catalogue`, 588 stars; thesis 540). For van Bezooijen
    the tolerances are the thesis's: the distance tolerance d_uncert (the noise stated as it is,
    ``centroid_sigma_px`` = σ_p · f / √2, and ``n_sigma`` = d_uncert / σ_p) and Mv_uncert on the
    magnitudes given. Counted as in
    the thesis: failures with < 3 stars in view, failures with more, wrong, success.

    σ_p is the error of a measured *distance* (Table 3-6 pairs it with "the uncertainty in the
    distance measured between two stars", and the uncertainties "were set equal to the 1σ
    errors"): each axis gets σ_p/√2. The method is given the ≤ 20 stars the sensor's region
    growing extracts (§3.2) and matches the 8 brightest (``max_stars``); the rest only verify.
    ``fail_thesis_found``: failures whose true stars among the 8 hold a group of ≥ 3 that passes
    (3.1) and (3.2) for every pair — a group the thesis's largest-group rule could take, refused
    here as not beyond chance (``refused_log10_p``: the verification's chance of each such true
    group proposed alone, with its first four stars as the core)."""
    from skyfix.analysis import coverage as cv

    camera = camera_from_preset("sunsat")
    f = math.sqrt(camera.fx * camera.fy)
    full = load_hipparcos(epoch=EPOCH)
    limit = cv.limit_for_count(full.brighter_than(8.0), cv.THESIS_004_CATALOG_SIZE)
    t0 = time.perf_counter()
    sub = cv.sub_catalogue(full, cv.sunsat_attitudes(cv.TABLE_3_5), 11.17, 8.32, limit)
    db = PatternDatabase.build(8.0, 12.0, catalog=sub, epoch=EPOCH)
    rng = np.random.default_rng(seed)
    env = cv.TABLE_3_5
    angles = [np.radians(rng.uniform(lo, hi, trials)) for lo, hi in env]
    attitudes = cv.sunsat_attitude_matrix(*angles)
    warm = synthetic_centroids(camera, attitudes[0], full, mag_limit=limit, rng=seed)
    identify(warm.xy[:8], camera.width, camera.height, method=method, camera=camera, database=db, epoch=EPOCH)
    build_s = time.perf_counter() - t0  # the sub-catalogue, its database and the method's tables
    star_ids, star_mag, _ = db.star_arrays()
    row_of = {int(s): i for i, s in enumerate(star_ids)}

    def thesis_group(field, row: MatchingRow) -> list[tuple[int, int]]:
        # the largest set of true (centroid, star) matches among the 8 brightest whose magnitudes
        # and pairwise distances all pass the thesis's tests (3.1), (3.2)
        rays = camera.pixel_to_ray(field.xy[:8])
        cand = [(i, row_of[int(s)]) for i, s in enumerate(field.star_id[:8])
                if int(s) in row_of and abs(field.mag[i] - star_mag[row_of[int(s)]]) <= row.mv_uncert]
        vec = db.star_index().vectors
        for size in range(len(cand), 2, -1):
            for group in itertools.combinations(cand, size):
                if all(abs(math.acos(min(1.0, rays[a] @ rays[b])) - math.acos(min(1.0, vec[ga] @ vec[gb])))
                       <= row.d_uncert_urad * 1e-6 for (a, ga), (b, gb) in itertools.combinations(group, 2)):
                    return list(group)
        return []

    def refused_log10_p(xy: np.ndarray, group: list[tuple[int, int]]) -> float:
        frame = frame_for(method, xy, camera.width, camera.height, fov_deg=None, fov_tolerance_deg=None,
                          camera=camera, database=db, epoch=EPOCH)
        stars, cat = np.array(group).T
        core = hypothesis(frame, stars[:4], cat[:4])
        return chance_log_probability(frame, core) / math.log(10.0)

    out_rows = []
    for row in rows:
        fail_lt3 = fail_gt3 = wrong = ok = 0
        refused: list[float] = []
        times = []
        reasons: dict[str, int] = {}
        for k, A in enumerate(attitudes):
            field = synthetic_centroids(camera, A, full, mag_limit=limit, mag_sigma=row.sigma_mv,
                                        sigma_px=row.sigma_p_urad * 1e-6 * f / math.sqrt(2.0),
                                        rng=np.random.default_rng([seed, k]))
            xy, mag = field.xy[:20], field.mag[:20]
            options = {}
            if method == "van-bezooijen":
                options = dict(magnitudes=mag, magnitude_tolerance=row.mv_uncert,
                               n_sigma=row.d_uncert_urad / row.sigma_p_urad,
                               centroid_sigma_px=row.sigma_p_urad * 1e-6 * f / math.sqrt(2.0), pair_stars=8)
            t1 = time.perf_counter()
            ident = identify(xy, camera.width, camera.height, method=method, camera=camera, database=db,
                             epoch=EPOCH, **options)
            times.append(1e3 * (time.perf_counter() - t1))
            if not ident.success:
                key = ident.reason.split(":")[0].split("(")[0].strip()
                reasons[key] = reasons.get(key, 0) + 1
                if len(xy) < 3:
                    fail_lt3 += 1
                else:
                    fail_gt3 += 1
                    group = thesis_group(field, row)
                    if len(group) >= 3:
                        refused.append(refused_log10_p(xy, group))
            elif judge_identification(ident, A, camera).wrong:
                wrong += 1
            else:
                ok += 1
        out_rows.append({**row._asdict(), "trials": trials, "fail_lt3": fail_lt3, "fail_gt3": fail_gt3,
                         "wrong": wrong, "wrong_upper95_pct": 100.0 * upper_bound_95(wrong, trials),
                         "success_pct": 100.0 * ok / trials, "median_ms": float(np.median(times)),
                         "max_ms": float(np.max(times)), "failures": reasons,
                         "fail_thesis_found": len(refused), "refused_log10_p": sorted(refused)})
    return {"case": "table-3-7", "method": method, "sub_catalogue_stars": len(sub), "mag_limit_hp": limit,
            "database_build_s": build_s, "rows": out_rows}


CASES["table-3-7"] = table_3_7


def sparse_fields(fov_deg: float = 30.0, n_fields: int = 200, n_bright: int = 3,
                  methods: tuple[str, ...] = ("triangle", "quad-hash"), seed: int = 0,
                  calibrated: bool = False) -> dict:
    """Issue 11's 3-star fields: ``n_fields`` random attitudes of a 1280 × 960 camera ``fov_deg``
    wide, each detecting exactly its ``n_bright`` brightest catalogue stars (the limit set between
    the ``n_bright``-th and the next), noise-free, identified by each of ``methods`` with the FOV
    told to ±10 % (``calibrated``: the camera given): right, wrong, refused (reasons counted;
    "ambiguous" when the stars are not unique enough to name)."""
    catalog = load_hipparcos(epoch=EPOCH)
    db = default_database(progress=False)
    camera = Camera.from_fov(WIDTH, HEIGHT, fov_deg)
    rng = np.random.default_rng(seed)
    tally = {m: {"right": 0, "wrong": 0, "refused": 0, "reasons": {}} for m in methods}
    used = 0
    for A in random_attitudes(n_fields, rng):
        every = synthetic_centroids(camera, A, catalog, mag_limit=9.0, sigma_px=0.0)
        mags = np.sort(every.mag)
        if len(mags) <= n_bright or mags[n_bright] - mags[n_bright - 1] < 0.05:
            continue  # too few stars, or no clean limit between the n-th and the next
        limit = 0.5 * (mags[n_bright - 1] + mags[n_bright])
        field = synthetic_centroids(camera, A, catalog, mag_limit=limit, sigma_px=0.0)
        used += 1
        for m in methods:
            try:
                told = {"camera": camera} if calibrated else {"fov_deg": fov_deg,
                                                              "fov_tolerance_deg": 0.1 * fov_deg}
                ident = identify(field.xy, WIDTH, HEIGHT, method=m, database=db, epoch=EPOCH, **told)
            except Exception as exc:  # a method's bug is its failure here
                ident = Identification(False, f"error: {type(exc).__name__}")
            t = tally[m]
            if not ident.success:
                t["refused"] += 1
                key = ident.reason.split(":")[0].split("(")[0].strip()
                t["reasons"][key] = t["reasons"].get(key, 0) + 1
            elif judge_identification(ident, A, camera).wrong:
                t["wrong"] += 1
            else:
                t["right"] += 1
    for t in tally.values():
        t["right_pct"] = 100.0 * t["right"] / max(used, 1)
        t["wrong_upper95_pct"] = 100.0 * upper_bound_95(t["wrong"], used)
    return {"case": "sparse-fields", "fov_deg": fov_deg, "stars": n_bright, "calibrated": calibrated,
            "fields": used, "methods": tally}


CASES["sparse-fields"] = sparse_fields


@dataclass(frozen=True)
class CaseStudy(BatchedStudy):
    """Named cases (``settings["cases"]``, keys of :data:`CASES`, each with its defaults) on the
    campaign engine: trial ``i`` runs case ``i``; its row holds the name, the wall time and the
    result as (strict) JSON. Use batches of one case."""

    kind = "identification-cases"
    columns = {"trial": "int64", "case": "string", "seconds": "float64", "result": "string"}

    def run_trial(self, trial: int) -> dict[str, Any]:
        name = self.settings["cases"][trial]
        t0 = time.perf_counter()
        result = CASES[name]()
        return {"trial": trial, "case": name, "seconds": time.perf_counter() - t0,
                "result": json.dumps(strict_json(result))}


def case_study(names: list[str] | tuple[str, ...]) -> CaseStudy:
    """The cases ``names`` as a study (a batch each)."""
    return CaseStudy(len(names), 1, {"cases": list(names)})


def case_results(table: pa.Table) -> dict[str, dict]:
    """A :class:`CaseStudy`'s rows as name → result."""
    return {row["case"]: json.loads(row["result"]) for row in table.to_pylist()}


def run_cases(names: list[str] | tuple[str, ...], workers: int = 0, scheduler: str | None = None, *,
              out: str | Path | None = None,
              progress: Callable[[int, int], None] | None = None) -> dict[str, dict]:
    """The cases ``names`` on the campaign engine (``workers`` local processes or ``scheduler``;
    0 and none: in this process), their rows written to ``out`` (Parquet; None: a temporary
    file): name → result."""
    with cluster(workers, scheduler) as client:
        return case_results(run_rows(case_study(names), out, client=client, fresh=True, progress=progress))
