"""Lost-in-space identification by 4-star geometric hashing, with statistical verification: the
``"quad-hash"`` method of :data:`skyfix.identify.METHODS` (:mod:`skyfix.identify.methods`).

1. The brightest centroids form 4-star combinations in breadth-first order (every pattern
   of the first ``m`` stars before any that uses star ``m + 1``).
2. Each combination's edge-ratio key is looked up in the pattern database; candidates agree
   in all five ratios, imply a focal length in the allowed range, and (at that focal length)
   agree within the centroid-noise tolerance. Two tolerance tiers run interleaved: a tight one
   first, and a loose one (unmodelled distortion, a far-off focal-length guess) a factor of 4
   behind it in patterns and never ahead of it in modelled time (:func:`search_work`).
3. Each candidate gets its vertex correspondence (the permutation whose six edges agree best)
   and its attitude from the four stars (SVD, proper rotations only: a mirror image fits badly
   and is rejected), then verification: the brightest catalogue stars in the frame are matched
   to the brightest centroids and the binomial probability of so many chance matches, times
   the number of candidates examined, must be below ``prob_threshold``
   (:mod:`skyfix.identify.common.verify`). Steps 2–3 are one compiled kernel
   (:mod:`skyfix.identify.common.search`).
4. The accepted attitude is refitted on all matched stars — with the focal length and, where
   significant, radial distortion k1 when no camera was given (:mod:`skyfix.identify.common.refine`).

The kernels take and return the named tuples of :mod:`skyfix.identify.catalogue.kernel_data`; the rules
that accept a candidate and its refit are those of :mod:`skyfix.identify.accept` (rules 1–7).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from skyfix._kernels import lens
from skyfix.camera import Camera
from skyfix.errors import CameraError
from skyfix.identify.accept import PROB_THRESHOLD, QUAD_CENTROID_SIGMA_PX, refit_accepted, refit_focal_allowed
from skyfix.identify.catalogue.bands import (
    band_database,
    bands_for,
    log_overlap,
    served_fov_deg,
)
from skyfix.identify.catalogue.database import PatternDatabase, readonly_view
from skyfix.identify.catalogue.kernel_data import (
    FocalRange,
    ImageStars,
    PatternTable,
    RefineSettings,
    SearchResult,
    StarIndex,
    Tolerances,
    VerifySettings,
)
from skyfix.identify.common._field_notes import _outside_reason, _shallow_note
from skyfix.identify.common.hypothesis import failure
from skyfix.identify.common.refine import refine_entry
from skyfix.identify.common.result import Identification, finite_centroids
from skyfix.identify.common.search import breadth_first_combinations, centre_first_combinations, search_entry

__all__ = ["METHOD", "MIRROR_NOTE", "REFUSED_HIT_COST_S", "SEARCH_COST_S", "identify", "search_work",
           "warm_kernels"]

METHOD = "quad-hash"


def _failure(reason: str, t0: float, n_tried: int = 0, n_cand: int = 0) -> Identification:
    return failure(METHOD, reason, t0, n_tried, n_cand)


def _accepted(res: Identification | None, focal: tuple[float, float, float]) -> Identification | None:
    """``res`` if its refitted focal length is within the search's allowed range (accept rule 7),
    else None (the search goes on)."""
    return res if res is not None and refit_focal_allowed(res.camera.fx, *focal[1:]) else None


_COMPILED = False


def warm_kernels() -> None:
    """Load (or compile) the search's and the refit's kernels by running them once on a tiny
    dummy input (:mod:`skyfix.warmup` compiles them this way ahead of a first solve)."""
    global _COMPILED
    if _COMPILED:
        return
    ro = readonly_view
    image = ImageStars(np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 100.0], [70.0, 60.0]]),
                       np.array([-100.0, 100.0, -100.0, 100.0]))
    vec = ro(np.array([[0.0, 0.0, 1.0]]))
    stars = StarIndex(vec, vec, ro(np.array([0, 1], np.int64)), ro(np.zeros(1, np.int32)), 0.1)
    patterns = PatternTable(25, ro(np.full(16, -1, np.int32)), ro(np.zeros(1, np.int64)),
                            ro(np.zeros(2, np.int64)), ro(np.zeros((0, 5), np.float32)),
                            ro(np.zeros(0, np.float32)), ro(np.zeros((0, 4), np.int32)))
    focal = FocalRange(1000.0, 900.0, 1100.0, False)
    tolerances = Tolerances(0.01, 1.0, 0.01)
    search_entry(tuple(image), breadth_first_combinations(4), 0, 1, tuple(focal), tuple(tolerances),
                 tuple(patterns), tuple(stars), tuple(VerifySettings(4, 5.0, -20.0)), 0)
    settings = RefineSettings(True, 12, 4, 4, 5.0, 1.0, 1)
    refine_entry(tuple(image), np.eye(3), 1000.0, tuple(settings), tuple(stars))
    _undistorted_offsets(image.offsets_px, _Distortion(-1e-7))  # the wide searches' distortion hypotheses
    _COMPILED = True


# What a turn of the search costs, in modelled seconds: per image pattern looked up, per catalogue
# pattern whose ratios were compared, per candidate that passed the ratio checks. Fitted (least
# squares, relative error) to 4,890 search calls of 40 frames of each field case with no hint
# (the three bands, both tolerance tiers; a /tmp script timing each search_entry call): the
# model's total per band and tier is 0.73–1.11× the measured time. The bands take turns by it
# (search_work), not by the clock, so that a frame's result does not depend on the machine's
# load — with the clock, the same frame was solved in one run and not in another.
SEARCH_COST_S = (7.7e-6, 6.9e-8, 1.66e-5)
# The loose tolerance tier looks up at most one image pattern for every this many of the tight tier's
# (and takes no more modelled time than the tight tier: _Search.next_stop).
_LOOSE_LAG = 4
# A hit whose refit is refused: about a refit's time.
REFUSED_HIT_COST_S = 5e-4


def search_work(hit: SearchResult) -> float:
    """The modelled time (:data:`SEARCH_COST_S`) of the search call that returned ``hit``."""
    per_pattern, per_compared, per_candidate = SEARCH_COST_S
    return per_pattern * hit.n_done + per_compared * hit.n_compared + per_candidate * hit.n_candidates


def _focal_from_fov(width: int, fov_deg: float) -> float:
    return (width / 2.0) / math.tan(math.radians(fov_deg) / 2.0)


# Over ten parameters: the interface of every method (:mod:`skyfix.identify.methods`) and this
# method's options, all keywords with a documented default, which solve() passes through by name.
def identify(xy: np.ndarray, width: int, height: int, *, fov_deg: float | None = None,
             fov_tolerance_deg: float | None = None, camera: Camera | None = None,
             database: PatternDatabase | None = None, max_patterns: int = 4000,
             time_limit_s: float = 2.0, epoch: float | None = None, pattern_stars: int = 24,
             verify_stars: int = 60, refine_stars: int = 200, match_radius: float = 0.01,
             prob_threshold: float = PROB_THRESHOLD,
             centroid_sigma_px: float = QUAD_CENTROID_SIGMA_PX, ratio_tolerance: float | None = None,
             key_tolerance: float | None = None, check_mirror: bool = True) -> Identification:
    """Identify the stars of one frame, lost in space, by 4-star hashing, and fit the attitude.

    Parameters
    ----------
    xy : (N, 2) float
        Centroids, pixels, brightest first: ``(x, y)`` = (column, row), ``(0, 0)`` the centre of
        the top-left pixel.
    width, height : int
        Frame size, pixels.
    fov_deg : float, optional
        Horizontal field of view, degrees. Without it (and without ``camera``) the FOV is
        estimated from the matched pattern, within the database's range.
    fov_tolerance_deg : float, optional
        Allowed error of ``fov_deg`` (default 10 % of it).
    camera : Camera, optional
        Calibrated camera (intrinsics and distortion used as given; overrides ``fov_deg``).
    database : PatternDatabase, optional
        Default: the default FOV bands' databases (:mod:`skyfix.identify.catalogue.bands`): those that serve
        the FOV hint or the camera; with neither, all of them, the standard band first. Each is
        built the first time a search reaches it.
    max_patterns : int
        Work bound: image 4-star combinations looked up.
    time_limit_s : float
        Work bound: wall time of the search, seconds (loading or building a band's database the
        first time a search reaches it, and compiling or loading the search kernel for new argument
        types, are not counted: a frame must not fail for a cold cache).
    epoch : float, optional
        Julian year for the catalogue positions of the result (default: the database's).
    pattern_stars : int
        Brightest centroids used to form patterns.
    verify_stars : int
        Brightest centroids (and as many catalogue stars) used in verification.
    refine_stars : int
        Brightest centroids matched for the final fit.
    match_radius : float
        Verification match radius as a fraction of the frame's larger side.
    prob_threshold : float
        Largest accepted probability that the match is chance.
    centroid_sigma_px : float
        Expected centroid noise, pixels (sets the pattern tolerance).
    ratio_tolerance : float, optional
        Edge-ratio error allowed for the unmodelled camera (distortion), on top of the
        noise term (default 0.006 without a camera, 0.003 with one).
    key_tolerance : float, optional
        Edge-ratio tolerance of the key lookup (default 0.012 with the FOV free, else 0.008).
    check_mirror : bool
        On failure, try the frame flipped left-right briefly, so that the reason can say that
        it is a mirror image.

    Returns
    -------
    Identification
    """
    warm_kernels()  # once per process; not counted against the time limit
    t0 = time.perf_counter()
    xy, kept = finite_centroids(xy)  # kept maps back to the caller's indices
    n = len(xy)
    if n < 4:
        return _failure(f"too few stars ({n} detected, need 4)", t0)
    if fov_deg is not None and not 0.01 < fov_deg < 170.0:
        raise CameraError(f"impossible field of view {fov_deg}° (must be 0.01°–170°)")

    # The focal lengths allowed, and the databases (or default FOV bands) that serve them.
    if camera is not None:
        f0 = float(camera.fx)
        f_lo, f_hi = f0 / 1.03, f0 * 1.03
    elif fov_deg is not None:
        tol = 0.1 * fov_deg if fov_tolerance_deg is None else fov_tolerance_deg
        f0 = _focal_from_fov(width, fov_deg)
        f_lo = _focal_from_fov(width, min(fov_deg + tol, 179.0))
        f_hi = _focal_from_fov(width, max(fov_deg - tol, 1e-3))
    else:
        f0, f_lo, f_hi = math.nan, 0.0, math.inf
    if camera is not None:  # its true field (a fisheye's is wider than its fx says)
        hinted = (camera.fov_deg / 1.03, camera.fov_deg * 1.03)
    else:
        hinted = ((_fov_from_focal(width, f_hi), _fov_from_focal(width, f_lo)) if f_hi < math.inf
                  else (None, None))
    sources = [database] if database is not None else bands_for(*hinted)
    passes = []
    for source in sources:
        served = served_fov_deg(source) if isinstance(source, PatternDatabase) else source.served_fov_deg
        share = max(log_overlap(served, *hinted), 0.0)  # its share of the search's time
        if camera is not None:
            if served[0] <= hinted[1] and hinted[0] <= served[1]:
                passes.append((source, (f0, f_lo, f_hi), share))
            continue
        lo = max(f_lo, _focal_from_fov(width, min(served[1], 179.0)))
        hi = min(f_hi, _focal_from_fov(width, served[0]))
        if lo <= hi:
            passes.append((source, (f0 if math.isfinite(f0) else math.sqrt(lo * hi), lo, hi), share))
    if not passes:
        fov = camera.fov_deg if camera is not None else fov_deg
        return _failure(_outside_reason(fov, *hinted, sources), t0)
    free_fov = camera is None and fov_deg is None
    # Image stars as undistorted offsets from the principal point (scaled by each pass's f0).
    n_pat = min(n, pattern_stars)
    n_p = max(n_pat, min(n, max(verify_stars, refine_stars)))
    cx, cy = (camera.cx, camera.cy) if camera is not None else ((width - 1) / 2.0, (height - 1) / 2.0)
    combos = breadth_first_combinations(n_pat)
    n_verify = min(n, verify_stars)
    radius = match_radius * max(width, height)

    # Tolerance tiers: tight first (few false candidates), then loose (unmodelled distortion,
    # far-off focal-length guess) 4 times behind in patterns, never ahead in time (_Search.next_stop).
    if ratio_tolerance is not None or key_tolerance is not None:
        tiers = [(key_tolerance if key_tolerance is not None else (0.012 if free_fov else 0.008),
                  ratio_tolerance if ratio_tolerance is not None else 0.006)]
    else:
        tiers = [(0.008, 0.002), (0.015 if free_fov else 0.010, 0.008 if camera is None else 0.004)]
    explicit = ratio_tolerance is not None or key_tolerance is not None

    def tolerances(source) -> list[tuple]:
        """The tiers as the kernel takes them; a band whose fields barely distort (the narrow
        band: k1 = 0.1 moves a 6° frame's corner by 0.04 %) has a looser tier of its own."""
        own = getattr(source, "loose_tolerance", None)
        chosen = tiers if explicit or camera is not None or own is None else [tiers[0], own]
        return [tuple(Tolerances(float(eps_key), float(centroid_sigma_px), float(model_err)))
                for eps_key, model_err in chosen]
    # on failure the frame is tried mirrored, briefly, with these options (see check_mirror);
    # made only then
    def retry() -> dict | None:
        return dict(fov_deg=fov_deg, fov_tolerance_deg=fov_tolerance_deg, camera=camera, database=database,
                    max_patterns=min(max_patterns, 200), time_limit_s=min(time_limit_s, 0.25), epoch=epoch,
                    pattern_stars=pattern_stars, verify_stars=verify_stars, refine_stars=refine_stars,
                    match_radius=match_radius, prob_threshold=prob_threshold,
                    centroid_sigma_px=centroid_sigma_px, ratio_tolerance=ratio_tolerance,
                    key_tolerance=key_tolerance, check_mirror=False) if check_mirror else None
    log_threshold = math.log(prob_threshold)
    refit = RefineSettings(camera is None, 12, n_verify, min(n, refine_stars), float(radius),
                           float(centroid_sigma_px), 3)
    refit_plain = tuple(refit)
    verification = tuple(VerifySettings(n_verify, float(radius), log_threshold))
    geometry = (int(width), int(height), cx, cy)
    # A wide search's pattern order puts the central stars' patterns forward (_CENTRE_SHARE).
    centre_first = _CentreFirst(xy[:n_pat], geometry)
    searches = []
    for i, (source, focal, share) in enumerate(passes):
        hypotheses = _distortion_hypotheses(camera, focal, geometry)
        order = centre_first if len(hypotheses) > 1 else (lambda stop: combos)
        first_chunk = 16 if i == 0 else 4
        searches += [_Search(source, focal, camera, xy[:n_p], geometry, tolerances(source), first_chunk,
                             distortion, order, share) for distortion in hypotheses]
    total = min(len(combos), max_patterns)
    n_lookups = n_cand = 0
    loading_s = 0.0  # spent loading databases or kernels (not counted against time_limit_s)
    while True:
        # The database that has taken the least (modelled) time for its share so far goes next
        # (the first one, the common case, first) — its distortion hypotheses share its time —
        # one chunk of patterns longer than its last: a database whose wrong candidates are cheap
        # to reject gets through more patterns in the same time. A database's share is the part
        # of the fields allowed that it serves, on a log scale (bands.log_overlap): its chance of
        # holding the frame when no width is more likely than another. Time in proportion to
        # that chance is the best order when the pattern that finds a frame is about as likely
        # in each band and its place has a 1/P tail (an image's false stars decide it, whichever
        # band is searched): docs/fields.md.
        live = [s for s in searches if s.pos[0] < total]
        if not live:
            break
        spent: dict[int, float] = {}
        for s in searches:
            spent[id(s.source)] = spent.get(id(s.source), 0.0) + s.work_s
        search = min(live, key=lambda s: (spent[id(s.source)] / s.share if s.share > 0.0 else math.inf,
                                          s.work_s))
        target = min(total, search.pos[0] + search.chunk)
        search.chunk = min(2 * search.chunk, 512)
        for tier, tier_tolerances in enumerate(search.tiers):
            while True:
                start = search.pos[tier]
                stop = search.next_stop(tier, target, total)
                if stop <= start:
                    break
                if n_lookups and time.perf_counter() - t0 - loading_s > time_limit_s:
                    n_tried = max(s.pos[0] for s in searches)
                    return _failure(f"time limit {time_limit_s:g} s reached after {n_tried} patterns"
                                    + _mirror_note(xy, width, height, cx, retry()), t0, n_tried, n_cand)
                t_load = time.perf_counter()
                plain = search.plain()
                loading_s += time.perf_counter() - t_load
                known = search_entry.n_compiled
                t_call = time.perf_counter()
                hit = search_entry(plain.image, search.combos(stop), start, stop, plain.focal,
                                   tier_tolerances, plain.patterns, plain.stars, verification, n_cand)
                if search_entry.n_compiled != known:  # compiled or loaded from numba's cache just now
                    loading_s += time.perf_counter() - t_call
                search.pos[tier] = start + hit.n_done
                search.add_work(tier, search_work(hit))
                n_lookups += hit.n_done
                n_cand += hit.n_candidates
                if hit.success:
                    ctx = _Context(kept, search.geometry, camera, plain.image_stars, plain.image, refit,
                                   refit_plain, plain.stars, search.database(), epoch, log_threshold, t0,
                                   search.distortion)
                    n_tried = max(s.pos[0] for s in searches)
                    res = _accepted(_finish(ctx, hit, n_tried, n_cand), search.focal)
                    if search.distortion.equidistant_px:
                        rivals = [s for s in searches if s.source is search.source and s is not search]
                        res = _most_stars(res, ctx, hit, rivals, n_tried, n_cand)
                    if res is not None:
                        return res
                    # A refit that fails or leaves the allowed range: search on.
                    search.add_work(tier, REFUSED_HIT_COST_S)
    n_tried = max(s.pos[0] for s in searches)
    return _failure(f"no match after {n_tried} patterns ({n_cand} candidates verified)"
                    + _mirror_note(xy, width, height, cx, retry()) + _shallow_note(hinted[1]),
                    t0, n_tried, n_cand)


class _Plain(NamedTuple):
    """One search's kernel arguments, the NamedTuples as plain tuples (kernel_data says why)."""

    image_stars: ImageStars
    image: tuple
    focal: tuple
    patterns: tuple
    stars: tuple


class _Search:
    """The 4-star search of one frame in one database: where it stands (``pos``: image patterns
    looked up at each tolerance tier; ``work_s``: its modelled time so far, :func:`search_work`;
    ``chunk``: patterns in its next turn), the order of its image patterns (``combos(stop)``:
    (C, 4), at least the first ``stop``) and, loaded on first use (a default band's database is
    built then, the first time one is needed), the kernels' arguments."""

    def __init__(self, source, focal: tuple[float, float, float], camera: Camera | None, xy: np.ndarray,
                 geometry: tuple[int, int, float, float], tiers: list[tuple], first_chunk: int,
                 distortion: _Distortion, combos: Callable[[int], np.ndarray], share: float = 1.0) -> None:
        self.source, self.focal, self.camera, self.xy, self.geometry = source, focal, camera, xy, geometry
        self.share = share  # its database's share of the search's time (log_overlap of the fields allowed)
        self.distortion = distortion  # the radial distortion assumed (see _distortion_hypotheses)
        self.combos = combos
        self.tiers = tiers  # its tolerance tiers, as the kernel takes them
        self.pos = [0] * len(tiers)
        self.tier_work_s = [0.0] * len(tiers)  # modelled time of each tier
        self.work_s = 0.0
        self.chunk = first_chunk
        self._plain: _Plain | None = None

    def add_work(self, tier: int, work_s: float) -> None:
        """Count ``work_s`` (modelled seconds) against ``tier`` and the search."""
        self.tier_work_s[tier] += work_s
        self.work_s += work_s

    def next_stop(self, tier: int, target: int, total: int) -> int:
        """Where ``tier``'s next kernel call stops in a turn whose tight tier goes to ``target``
        (of ``total`` patterns): the tight tier to ``target``; a looser one, which sees every
        candidate the tight one sees and more of them (each costing a verification), only while
        its modelled time is below the tight tier's and no further than :data:`_LOOSE_LAG` times
        behind the tight tier in patterns — to ``total`` once the tight tier has finished. The
        time bound: a frame the tight tier holds then costs at most twice the tight tier's time.
        With the pattern lag alone, a frame of suite b's with 8 false stars and no FOV spent
        70–80 % of its candidates on the loose tier (a loose pattern of the standard band costs
        ~9 times a tight one there) while the tight tier held the hit; with the time bound alone,
        a FOV's cheap loose patterns (~2 tight ones) took more time than before
        (docs/identification-methods.md)."""
        start = self.pos[tier]
        if tier == 0:
            return min(target, start + 512)
        if target >= total:
            return min(total, start + 512)
        behind = self.tier_work_s[0] - self.tier_work_s[tier]
        if behind <= 0.0:
            return start
        lag = self.pos[0] // _LOOSE_LAG
        if not start:  # one pattern first: its cost is what the next calls are sized by
            return min(lag, 1)
        per_pattern = self.tier_work_s[tier] / start
        n = max(1, math.ceil(behind / per_pattern)) if per_pattern > 0.0 else 512
        return max(start, min(lag, start + n, start + 512))

    def database(self) -> PatternDatabase:
        return self.source if isinstance(self.source, PatternDatabase) else band_database(self.source)

    def plain(self) -> _Plain:
        if self._plain is None:
            self._plain = self._arguments()
        return self._plain

    def _arguments(self) -> _Plain:
        width, height, cx, cy = self.geometry
        f0 = self.focal[0]
        camera = self.camera
        if camera is not None:
            p = camera.pixel_to_normalized(self.xy) * f0
            # The frame's extent in p (undistorted at its corners: a bounding box, good enough
            # for deciding which catalogue stars to expect).
            corners = np.array([[-0.5, -0.5], [width - 0.5, -0.5], [-0.5, height - 0.5],
                                [width - 0.5, height - 0.5]])
            c_p = camera.pixel_to_normalized(corners) * f0
            if not np.isfinite(c_p).all():  # a fisheye's corners lie beyond 90°: its edges, to 80°
                c_p = _fisheye_extent(camera, f0)
            frame = np.array([c_p[:, 0].min(), c_p[:, 0].max(), c_p[:, 1].min(), c_p[:, 1].max()])
        else:
            p = _undistorted_offsets(self.xy - np.array([cx, cy]), self.distortion)
            corners = np.array([[-0.5 - cx, -0.5 - cy], [width - 0.5 - cx, height - 0.5 - cy]])
            c_p = _undistorted_offsets(corners, self.distortion)  # a barrel's corners: the extremes
            frame = np.array([c_p[0, 0], c_p[1, 0], c_p[0, 1], c_p[1, 1]])
        db = self.database()
        image = ImageStars(p, frame)
        return _Plain(image, tuple(image), tuple(FocalRange(*self.focal, camera is not None)),
                      tuple(db.pattern_table()), tuple(db.star_index()))


class _Distortion(NamedTuple):
    """A radial distortion a wide search with no camera assumes, in pixels about the principal
    point (:func:`_distortion_hypotheses`): cubic, an offset ``p`` seen at ``p (1 + kappa |p|²)``
    (``kappa`` px⁻²); or, when ``equidistant_px`` is set, an equidistant fisheye's of that focal
    length ``f``: a star ``θ`` off axis, at ``f tan θ`` in the search's offsets, seen at ``f θ``."""

    kappa: float = 0.0
    equidistant_px: float = 0.0


# Radial distortion assumed by the searches of wide fields with no camera, as the share by which
# it moves the frame's corner in (barrel, negative) or out: a lens of k1 = −0.3 squeezes the
# corner of a 45° frame by ~9 %, of a 60° frame by ~22 %, beyond what the tolerance tiers absorb
# (~6 %); each share is a search of its own. Shares beyond −1/3 fold the frame (no lens does).
_CORNER_DISTORTION = (0.0, -0.12, -0.24)
# A fisheye is none of those: an equidistant lens's corner is squeezed by −34 % at 90° (beyond
# the cubic's fold) and its stars between move unlike a cubic's. One more search assumes an
# equidistant lens whose frame corner is this far off axis (rad; a 90° fisheye on a 4:3 frame:
# 56°). Searched with the cubic shares instead, 6 of 100 90° frames were found only after
# 2000–3400 patterns or not at all; with it, none after 350 (a lens assumed 15 % wider than
# the frame's failed 4 of them: the angle is no wider than the 90° lens's).
_FISHEYE_CORNER_RAD = 0.98
_DISTORTION_MIN_FOV_DEG = 40.0  # narrower fields: the loose tier absorbs their distortion


def _distortion_hypotheses(camera: Camera | None, focal: tuple[float, float, float],
                           geometry: tuple[int, int, float, float]) -> list[_Distortion]:
    """The radial distortions a search with this focal range assumes: none with a camera or when
    every focal length allowed is narrower than :data:`_DISTORTION_MIN_FOV_DEG` (at the middle of
    the range: a wide band's search, not the standard band's, which serves up to 40°); else one
    cubic per :data:`_CORNER_DISTORTION` share ``q`` (the corner at ``c`` px is seen at ``c`` from
    ``c / (1 + q)``, so ``κ = q (1 + q)² / c²``) and the equidistant fisheye's whose corner is
    :data:`_FISHEYE_CORNER_RAD` off axis (``f = c / θ``). A pixel-space distortion needs no
    focal length: the hypothesis holds across the band."""
    width, height, cx, cy = geometry
    if camera is not None or _fov_from_focal(width, math.sqrt(focal[1] * focal[2])) < _DISTORTION_MIN_FOV_DEG:
        return [_Distortion()]
    c = _half_diagonal(geometry)
    return ([_Distortion(q * (1.0 + q) ** 2 / c**2) for q in _CORNER_DISTORTION]
            + [_Distortion(equidistant_px=c / _FISHEYE_CORNER_RAD)])


def _composed_distortion(k1: float, distortion: _Distortion, f_px: float, half_diagonal_px: float
                         ) -> tuple[float, float, float]:
    """Brown–Conrady ``k1, k2, k3`` of the refit's radial ``k1`` (of offsets a search undistorted by
    ``distortion``) followed by that distortion, at the refit's focal length ``f_px``, fitted by
    least squares over the frame's radii; without a distortion, ``(k1, 0, 0)``. Cubic
    (``k_px = κ f²``): ``r_d = r (1 + k1 r²)(1 + k_px r² (1 + k1 r²)²)`` to 1.2× the half-diagonal
    (normalised); equidistant (``e = f_e / f``): ``r_d = e atan(r (1 + k1 r²) / e)`` to 1.05× the
    corner's undistorted radius (a fisheye's corner lies far beyond its half-diagonal)."""
    if distortion.equidistant_px:
        fe = distortion.equidistant_px
        e = fe / f_px
        u_max = fe * math.tan(min(half_diagonal_px / fe, 1.5)) / f_px
        u = np.linspace(0.0, 1.05 * u_max, 64)[1:]
        r2 = u**2
        radial = e * np.arctan(u * (1.0 + k1 * r2) / e) / u - 1.0
    elif distortion.kappa:
        k_px = distortion.kappa * f_px * f_px
        r2 = np.linspace(0.0, 1.2 * (half_diagonal_px / f_px), 64)[1:] ** 2
        radial = (1.0 + k1 * r2) * (1.0 + k_px * r2 * (1.0 + k1 * r2) ** 2) - 1.0
    else:
        return k1, 0.0, 0.0
    coef = np.linalg.lstsq(np.stack([r2, r2**2, r2**3], axis=1), radial, rcond=None)[0]
    return float(coef[0]), float(coef[1]), float(coef[2])


# A wide search with no camera looks up the patterns of the stars within this share of the
# half-diagonal of the principal point as early as the brightest stars' (interleaved:
# :func:`skyfix.identify.common.search.centre_first_combinations`). In the field campaign's 45°, 60° and
# 90° frames (seed 1, 100 each), the image pattern a search found the frame at went from median
# 12 / 7 / 8 and at most 1435 / 1440 / 296 to median 3 / 3 / 3 and at most 185 / 87 / 126.
_CENTRE_SHARE = 0.5


class _CentreFirst:
    """The wide searches' image patterns (:func:`~skyfix.identify.common.search.centre_first_combinations`
    of the pattern stars ``xy`` (N, 2) within :data:`_CENTRE_SHARE` of the half-diagonal of the
    principal point), computed as far as a search asks (``self(stop)``: at least the first
    ``stop``), twice that each time: most frames are found within the first hundred."""

    def __init__(self, xy: np.ndarray, geometry: tuple[int, int, float, float]) -> None:
        self.xy, self.geometry = xy, geometry
        self.combos = np.zeros((0, 4), dtype=np.int64)

    def __call__(self, stop: int) -> np.ndarray:
        if len(self.combos) < stop:  # (the standard band's searches never ask)
            width, height, cx, cy = self.geometry
            xy = self.xy
            central = np.hypot(xy[:, 0] - cx, xy[:, 1] - cy) <= _CENTRE_SHARE * _half_diagonal(self.geometry)
            self.combos = centre_first_combinations(central, max(2 * stop, 64))
        return self.combos


def _half_diagonal(geometry: tuple[int, int, float, float]) -> float:
    """The largest distance from the principal point to a corner of the frame, pixels."""
    width, height, cx, cy = geometry
    return math.hypot(max(cx + 0.5, width - 0.5 - cx), max(cy + 0.5, height - 0.5 - cy))


def _undistorted_offsets(p: np.ndarray, distortion: _Distortion) -> np.ndarray:
    """Offsets ``p`` (N, 2) seen through the pixel-space radial ``distortion`` (see
    :func:`_distortion_hypotheses`), undistorted: a cubic's by the camera model's own inversion
    (:func:`skyfix._kernels.lens.undistort`) with a unit focal length, so it works in pixels; an
    equidistant lens's in closed form, ``f tan(|p| / f)`` (kept short of 90° off axis)."""
    if distortion.equidistant_px:
        fe = distortion.equidistant_px
        r = np.hypot(p[:, 0], p[:, 1])
        theta = np.minimum(r / fe, 1.5)
        scale = np.where(r > 0.0, fe * np.tan(theta) / np.maximum(r, 1e-300), 1.0)
        return p * scale[:, None]
    if distortion.kappa == 0.0:
        return p
    numbers = lens.camera_numbers(Camera(width=2, height=2, fx=1.0, fy=1.0, cx=0.0, cy=0.0))
    numbers[lens.K1] = distortion.kappa
    x, y = lens.undistort(np.ascontiguousarray(p[:, 0]), np.ascontiguousarray(p[:, 1]), numbers)
    return np.stack([x, y], axis=1)


def _fisheye_extent(camera: Camera, f0: float) -> np.ndarray:
    """Points (N, 2) spanning the frame of a camera whose corners look beyond 90° off axis, in the
    search's offsets ``x_n · f0``: the frame's border sampled, each point's offset capped at 80°
    off axis (no catalogue star beyond can be placed in these offsets)."""
    w, h = camera.width, camera.height
    t = np.linspace(0.0, 1.0, 65)
    zero, one = np.zeros_like(t), np.ones_like(t)
    border = np.concatenate([np.stack([t * w, zero], 1), np.stack([t * w, one * h], 1),
                             np.stack([zero, t * h], 1), np.stack([one * w, t * h], 1)]) - 0.5
    rays = camera.pixel_to_ray(border)
    theta = np.minimum(np.arccos(np.clip(rays[:, 2], -1.0, 1.0)), math.radians(80.0))
    phi = np.arctan2(rays[:, 1], rays[:, 0])
    r = np.tan(theta) * f0
    return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)


def _fov_from_focal(width: int, f: float) -> float:
    return 2.0 * math.degrees(math.atan(width / 2.0 / f))


#: What a failed solve adds when the stars match the frame flipped left-right (skyfix.parity).
MIRROR_NOTE = ("; but the stars match the sky mirrored left-right: a mirror image "
               "(solve it with --parity mirrored or either; parity= in Python)")


def _mirror_note(xy: np.ndarray, width: int, height: int, cx: float, retry: dict | None) -> str:
    """:data:`MIRROR_NOTE` if the frame flipped left-right (about the principal point) is
    identified with :func:`identify`'s options ``retry`` (a short budget: a real frame's first
    patterns match), else ``""`` (also when ``retry`` is None: no check)."""
    if retry is None:
        return ""
    flipped = xy.copy()
    flipped[:, 0] = 2.0 * cx - flipped[:, 0]
    return MIRROR_NOTE if identify(flipped, width, height, **retry).success else ""


class _Context(NamedTuple):
    """What :func:`identify` works out once per frame and :func:`_finish` needs.

    kept : the indices of the finite centroids in the caller's array (None: all were finite).
    geometry : (width, height, cx, cy) — the frame and the principal point assumed.
    camera : the calibrated camera, or None (then the focal length and k1 are fitted).
    image : the centroids as the kernels see them (``image_plain``: as a plain tuple);
    refit : the refit's settings (``refit_plain``: as a plain tuple); stars_plain : the database's
    :class:`StarIndex` as a plain tuple (kernel_data says why plain).
    """

    kept: np.ndarray | None
    geometry: tuple[int, int, float, float]
    camera: Camera | None
    image: ImageStars
    image_plain: tuple
    refit: RefineSettings
    refit_plain: tuple
    stars_plain: tuple
    database: PatternDatabase
    epoch: float | None
    log_threshold: float
    t0: float
    distortion: _Distortion = _Distortion()  # the search's assumed distortion (_distortion_hypotheses)


def _most_stars(res: Identification | None, ctx: _Context, hit: SearchResult, rivals: list[_Search],
                n_tried: int, n_cand: int) -> Identification | None:
    """Of ``res`` (the equidistant search's hit refitted, or None) and the same hit refitted
    under each rival search's distortion (the cubic ones of the same database), the one that
    matches the most stars (``res`` on a tie; each passing accept rules 6 and 7). A frame of any
    lens may show a central pattern that fits the fisheye's distortion first: a 45° frame of
    k1 −0.3 kept 78 stars through the fisheye's refit where the cubic one matches 184."""
    for other in rivals:
        plain = other.plain()
        alt = _accepted(_finish(ctx._replace(image=plain.image_stars, image_plain=plain.image,
                                             distortion=other.distortion),
                                hit, n_tried, n_cand), other.focal)
        if alt is not None and (res is None or len(alt.star_index) > len(res.star_index)):
            res = alt
    return res


def _finish(ctx: _Context, hit: SearchResult, n_tried: int, n_cand: int) -> Identification | None:
    """Refit the accepted candidate ``hit`` on all matched stars (compiled :func:`refine`) and
    package the result; None when the refit is not itself beyond chance (accept rule 6)."""
    db = ctx.database
    fit = refine_entry(ctx.image_plain, hit.A_icrs_to_cam, hit.focal_px, ctx.refit_plain, ctx.stars_plain)
    r_final, n_cat = float(fit.radius_px), int(fit.n_catalog)
    frame = ctx.image.frame_px
    area = (frame[1] - frame[0]) * (frame[3] - frame[2])
    if not refit_accepted(fit.n_pairs, n_cat, ctx.refit.n_img, r_final, area, ctx.log_threshold):
        return None
    star_index, cat_index = fit.star_index, fit.catalog_index
    order = np.argsort(star_index, kind="stable")
    star_index, cat_index = star_index[order], cat_index[order]
    camera = ctx.camera
    if camera is None:
        width, height, cx, cy = ctx.geometry
        f_fit = float(fit.focal_px)
        k1, k2, k3 = _composed_distortion(float(fit.k1), ctx.distortion, f_fit, _half_diagonal(ctx.geometry))
        try:
            camera = Camera(width=width, height=height, fx=f_fit, fy=f_fit, cx=cx, cy=cy, k1=k1, k2=k2, k3=k3)
        except CameraError:  # a polynomial that folds before the frame's edge: no camera, search on
            return None
    if ctx.kept is not None:
        star_index = ctx.kept[star_index]
    star_ids, star_mag, _ = db.star_arrays()
    return Identification(
        True, "", star_index, star_ids[cat_index], db.vectors_at(cat_index, ctx.epoch), star_mag[cat_index],
        fit.A_icrs_to_cam, camera, float(min(math.exp(hit.log_prob_false), 1.0)), n_tried, n_cand, METHOD,
        time.perf_counter() - ctx.t0, r_final, database=db)
