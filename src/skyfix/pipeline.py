"""``solve()``: image → centroids → identification → attitude → :class:`Solution`.

The same path serves the Python API and ``skyfix solve``. Each stage is a plain function
of its own module; this one only composes them, times them and fills in the Solution.

The observation — its time (given, or read from the image's FITS header or EXIF), the
observer's velocity, a ground site — is made once per image
(:func:`skyfix.corrections.observation.observe`); the final fit then compares the stars with the
catalogue as the camera sees it (:meth:`~skyfix.corrections.observation.Observation.seen`) and
the Solution reports the time, the corrections and what follows from them
(docs/time-and-corrections.md#in-a-solve).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import os
import time
from pathlib import Path

import numpy as np

from skyfix._jit import aot_modules
from skyfix._kernels.numbers import solution_numbers
from skyfix.camera import Camera
from skyfix.corrections.observation import Observation, apparent_attitude, observe, time_of_image
from skyfix.errors import CameraError, InputError
from skyfix.final_fit import covariance_at_pixel, final_fit
from skyfix.identify import PatternDatabase, get_method, method_options
from skyfix.identify.accept import PROB_THRESHOLD, error_covariance, noise_posterior, precision_failure
from skyfix.identify.catalogue import bands
from skyfix.identify.catalogue.bands import database_for_fov
from skyfix.identify.lost import identify_lost, retry_through_preset
from skyfix.parity import check_parity, solve_with_parity
from skyfix.solution import Deferred, MatchTable, Solution
from skyfix.validate import (
    check_count,
    check_frame_size,
    check_solve_options,
    check_xy,
)

__all__ = ["DETECT_SIGMA", "FAINT_LOOK_BELOW", "FAINT_LOOK_FROM", "FAINT_SIGMA", "look_fainter",
           "solution_numbers", "solve", "solve_centroids"]

log = logging.getLogger("skyfix")

_ARCSEC = math.pi / (180 * 3600)


def solve(
    image: str | Path | np.ndarray,
    *,
    fov_deg: float | None = None,
    fov_tolerance_deg: float | None = None,
    camera: Camera | None = None,
    database=None,
    epoch: float | None = None,
    attitude_method: str = "svd",
    identify_method: str = "quad-hash",
    max_stars: int = 200,
    name: str | None = None,
    dark: np.ndarray | None = None,
    flat: np.ndarray | None = None,
    bad_pixels: np.ndarray | None = None,
    mask=None,
    attitude_hint=None,
    smear_px=None,
    parity: str | None = None,
    time=None,
    observer=None,
    site=None,
    weather=None,
    refraction: str = "erfa",
    apparent: bool = False,
    mounting=None,
    exclusion=None,
    **identify_options,
) -> Solution:
    """Solve one sky image, lost in space or near a known attitude.

    Parameters
    ----------
    image : path or (H, W) array
        FITS, PNG, TIFF or JPEG file, or image data.
    fov_deg : float, optional
        Horizontal field of view, degrees. Unknown when omitted (it is then fitted).
    fov_tolerance_deg : float, optional
        How far the true FOV may be from ``fov_deg``, degrees.
    camera : Camera, optional
        Full camera model (intrinsics + distortion); overrides ``fov_deg``.
    database : PatternDatabase, optional
        Pattern database (default: the cached default one).
    epoch : float, optional
        Observation epoch, Julian year, for proper motion (default: now).
    attitude_method : str
        Wahba solver for the final fit: ``svd``, ``quest``, ``esoq2``, ``q-method``, ``triad``.
    identify_method : str
        Identification method, by name (:data:`skyfix.identify.METHODS`); the other keywords
        (``identify_options``) are that method's own (:func:`skyfix.identify.method_options`).
    dark, flat, bad_pixels : (H, W) arrays, optional
        Frame calibration applied before extraction, in this order (master dark in ADU,
        normalised flat, hot/dead pixel mask): see :mod:`skyfix.detect.calibrate_frames`.
    mask : (H, W) array or image file, optional
        The pixels that show sky: non-zero (white) = use, zero (black) = ignore (a horizon, trees,
        a caption, the corners outside an all-sky lens). Stars within 3 px of an ignored pixel
        are dropped (:mod:`skyfix.detect.mask`). A mask of another size is an InputError.
    max_stars : int
        Brightest centroids kept: identification tries patterns among the brightest and
        verifies against all of them, and every verified star enters the attitude fit.
    attitude_hint : optional
        A rough attitude: ``"RA,DEC,ROLL[,UNCERTAINTY_DEG]"`` or a sequence of those numbers
        (degrees), a 3×3 ``A_icrs_to_cam``, or a :class:`skyfix.identify.hint.AttitudeHint`
        (the uncertainty, the largest rotation from the truth, defaults to 1°). The stars are
        then first identified near it (:func:`skyfix.identify.hint.identify_near`, no pattern
        search; the Solution's ``method`` is ``"attitude-hint"``) and the same acceptance rules
        decide; when that fails, or when neither ``camera`` nor ``fov_deg`` gives the scale the
        hint needs, the frame is solved lost in space (``method`` says which path solved it).
    parity : str, optional
        ``"normal"``, ``"mirrored"`` (a mirror image: a star diagonal, a FITS file stored
        bottom-up) or ``"either"`` (:mod:`skyfix.parity`; the Solution's ``mirrored`` says which
        solved). Default: ``"either"`` for FITS files, whose rows may be stored either way up,
        ``"normal"`` for everything else.
    time : ObservationTime, str or datetime, optional
        The observation time (ISO 8601 text, UTC unless it says otherwise). Default: the image
        file's own — FITS ``DATE-OBS`` (mid-exposure with ``EXPTIME``), a JPEG's or TIFF's EXIF —
        and none for an array. With a time the catalogue is moved to it and aberrated (the
        Earth's and ``observer``'s velocity), so the attitude is the camera's true one against
        the ICRS axes; with none, nothing that needs one is applied and the Solution's
        ``corrections_not_applied`` says so (docs/time-and-corrections.md#in-a-solve).
    observer : str, (3,) numbers or Observer, optional
        The camera's velocity relative to the Earth's centre, km/s, GCRS axes (``"vx,vy,vz"``:
        ``--velocity-kms``), or an :class:`skyfix.corrections.Observer` (with a position, the
        Earth's limb and the orbit frame are known too).
    site, weather : str, Site, Weather, optional
        A camera on the ground: ``"LAT,LON[,HEIGHT_M]"`` and ``"T_C,P_HPA[,RH]"``; refraction is
        applied per star and the Solution adds the boresight's Alt/Az and place of date.
    refraction : str
        The refraction model at a site: ``"erfa"`` (default), ``"bennett"`` (thesis 003), ``"none"``.
    apparent : bool
        Report the apparent attitude (against the catalogue places, as plate solvers do)
        instead of the true one; ``attitude_frame`` says which.
    mounting : Mounting or str, optional
        Camera → body rotation (``"x,y,z,w"``, or Euler 1-2-3 ``"φ,θ,ψ"`` degrees): the Solution
        adds the body's attitude (``frames``).
    exclusion : Exclusion or str, optional
        The Sun's, Moon's and Earth limb's exclusion angles, or a camera preset whose to use
        (default 28.1° each, thesis 004's baffle); a body inside its angle is a warning.

    Returns
    -------
    Solution
        ``status == "solved"`` with attitude and error bars, or ``"failed"`` with a reason.

    Raises
    ------
    skyfix.errors.ImageReadError
        The file cannot be read as an image.
    skyfix.errors.InputError
        An argument is out of range or of the wrong kind (checked before any work).
    """
    from skyfix.detect import frame_problem
    from skyfix.detect.mask import as_mask
    from skyfix.io import read_image_with_header

    if not isinstance(image, (str, os.PathLike, np.ndarray)):
        raise InputError(f"solve() takes one image (a file path or a 2-D array), got a "
                         f"{type(image).__name__}" + ("; call it once per image"
                                                      if isinstance(image, (list, tuple)) else ""))
    max_stars = check_count(max_stars, "max_stars")
    _check_options(fov_deg, fov_tolerance_deg, camera, database, epoch, attitude_method, identify_method,
                   identify_options)
    hint = _checked_hint(attitude_hint)
    if parity is None:
        from skyfix.io import file_format

        fits_file = isinstance(image, (str, os.PathLike)) and file_format(image) == "fits"
        parity = "either" if fits_file else "normal"
    parity = check_parity(parity)
    if smear_px is not None:
        from skyfix.detect.smear import smear_offsets

        smear_offsets(smear_px)  # checked before any work
    obs = observe(time, observer=observer, site=site, weather=weather, refraction=refraction,
                  apparent=apparent, epoch=epoch, mounting=mounting, exclusion=exclusion)  # checked now
    _warm(database, fov_deg, camera)
    t0 = _clock()
    label = name if name is not None else (str(image) if isinstance(image, (str, Path)) else "<array>")
    got = read_image_with_header(image)
    data = raw = got.data
    if time is None and got.format != "array":
        own = time_of_image(image, got.header, got.format)
        if own.known:
            obs = obs.at(own)
    if dark is not None or flat is not None or bad_pixels is not None:
        from skyfix.detect import calibrate_frame

        data = calibrate_frame(data, dark=dark, flat=flat, bad_pixels=bad_pixels)
    t_read = _clock()
    if smear_px is not None:  # a part of the extraction
        from skyfix.detect.smear import smear_filter

        data = smear_filter(data, smear_px)
    usable = None if mask is None else as_mask(mask, data.shape[:2])
    circle = _sky_circle(data, camera, fov_deg)
    if circle is not None and usable is None:  # an explicit mask wins
        from skyfix.detect.sky_circle import sky_mask

        usable = as_mask(sky_mask(data, circle))
    centroids = _extract(data, DETECT_SIGMA, max_stars, usable)
    t_extract = _clock()
    log.info("%s: %d×%d image, %d centroids (noise %.3g)", label, data.shape[1], data.shape[0],
             len(centroids), getattr(centroids, "noise", float("nan")))
    solve_stars = functools.partial(
        solve_centroids, width=data.shape[1], height=data.shape[0], fov_deg=fov_deg,
        fov_tolerance_deg=fov_tolerance_deg, camera=camera, database=database, epoch=epoch,
        attitude_method=attitude_method, identify_method=identify_method, name=label, parity=parity,
        observation=obs, image_circle=circle, **identify_options)
    sol = solve_stars(centroids.xy, attitude_hint=hint)
    if not sol.solved and camera is not None and camera.projection == "pinhole":
        _check_not_allsky(data, camera)
    problem = frame_problem(raw) if not sol.solved else ""
    if not sol.solved and not problem and look_fainter(len(centroids), hint):
        # A sparse frame that failed: the stars a solve needs may lie between the fainter
        # threshold and the default one. A second extraction and solve; kept only if it solves.
        faint = _extract(data, FAINT_SIGMA, max_stars, usable)
        if len(faint) > len(centroids):
            again = solve_stars(faint.xy)  # no hint: look_fainter is for lost in space
            if again.solved:
                log.info("%s: solved from %d stars above %g σ (%d above %g σ did not)", label, len(faint),
                         FAINT_SIGMA, len(centroids), DETECT_SIGMA)
                sol = again
                sol.detection_sigma = FAINT_SIGMA
            else:
                sol.reason = (f"{sol.reason}; with the {len(faint)} stars above {FAINT_SIGMA:g} σ: "
                              f"{again.reason}")
    if sol.detection_sigma is None:
        sol.detection_sigma = DETECT_SIGMA
    if not sol.solved and problem:  # blank, saturated, too small: say which
        sol.reason = f"{sol.reason}: {problem}"
    t_end = _clock()
    sol.time_ms = {
        "read": 1e3 * (t_read - t0),
        "extract": 1e3 * (t_extract - t_read),
        "identify": sol.time_ms.get("identify", 0.0),
        "attitude": sol.time_ms.get("attitude", 0.0),
        "total": 1e3 * (t_end - t0),
    }
    return sol


def solve_centroids(
    xy: np.ndarray,
    width: int,
    height: int,
    *,
    fov_deg: float | None = None,
    fov_tolerance_deg: float | None = None,
    camera: Camera | None = None,
    database=None,
    epoch: float | None = None,
    attitude_method: str = "svd",
    identify_method: str = "quad-hash",
    name: str = "",
    attitude_hint=None,
    parity: str = "normal",
    time=None,
    observer=None,
    site=None,
    weather=None,
    refraction: str = "erfa",
    apparent: bool = False,
    mounting=None,
    exclusion=None,
    observation: Observation | None = None,
    image_circle=None,
    **identify_options,
) -> Solution:
    """Identify centroids (N, 2) (pixels, brightest first) and fit the attitude.

    The keywords are those of :func:`solve` (``parity`` defaults to ``"normal"``; with no
    image, no time is read: ``time`` or none);
    ``width`` and ``height`` are the frame's size in pixels. ``observation`` (an
    :class:`~skyfix.corrections.observation.Observation`, :func:`~skyfix.corrections.observation.observe`'s)
    gives the time and the rest at once instead, and then they must be left out. ``image_circle``
    (an :class:`~skyfix.detect.sky_circle.ImageCircle`) makes the frame an all-sky one, identified
    through the stars near the circle's centre (:mod:`skyfix.allsky`). Raises
    :class:`~skyfix.errors.InputError` for a bad argument, before any work.
    """
    xy = check_xy(xy)
    width, height = check_frame_size(width, height)
    _check_options(fov_deg, fov_tolerance_deg, camera, database, epoch, attitude_method, identify_method,
                   identify_options)
    hint = _checked_hint(attitude_hint)
    obs = _observation(observation, epoch, time=time, observer=observer, site=site, weather=weather,
                       refraction=refraction, apparent=apparent, mounting=mounting, exclusion=exclusion)
    epoch = obs.epoch
    if check_parity(parity) != "normal":
        def attempt(points: np.ndarray, cam: Camera | None, options: dict, hint_) -> Solution:
            return solve_centroids(points, width, height, fov_deg=fov_deg,
                                   fov_tolerance_deg=fov_tolerance_deg, camera=cam, database=database,
                                   epoch=epoch, attitude_method=attitude_method,
                                   identify_method=identify_method, name=name, attitude_hint=hint_,
                                   observation=obs, image_circle=image_circle if image_circle is None or
                                   points is xy else image_circle.mirrored(width), **options)

        return solve_with_parity(parity, xy, width, camera, hint, identify_method, identify_options, attempt)
    _warm(database, fov_deg, camera)
    sol = _new_solution(name, len(xy), obs)
    if camera is not None and (camera.width, camera.height) != (width, height):
        raise CameraError(f"camera is {camera.width}×{camera.height} but the image is {width}×{height}")
    if len(xy) < 3:
        sol.reason = f"too few stars detected ({len(xy)}; need at least 3)"
        return sol
    fit_options = dict(camera_given=camera is not None, database=database, epoch=epoch,
                       prob_threshold=identify_options.get("prob_threshold", PROB_THRESHOLD),
                       n_img=identify_options.get("refine_stars", 200),
                       centroid_sigma_px=identify_options.get("centroid_sigma_px"), observation=obs)
    t0 = _clock()
    hint_failure = ""
    if hint is not None:
        hint_failure = _solve_near(sol, xy, width, height, hint, fov_deg, fov_tolerance_deg, camera, database,
                                   epoch, attitude_method, identify_options, fit_options)
        if not hint_failure:
            sol.time_ms["total"] = 1e3 * (_clock() - t0)
            log.info("%s: solved near the attitude hint with %d stars, P(false) %.2g, rmse %.2f″", name,
                     sol.n_matched, sol.prob_false, sol.rmse_arcsec)
            return sol
        log.info("%s: not solved near the attitude hint (%s): solving lost in space", name, hint_failure)
        sol = _new_solution(name, len(xy), obs)
    search = identify_lost
    if image_circle is not None:
        from skyfix.allsky import identify_allsky_frame

        search = functools.partial(identify_allsky_frame, circle=image_circle)
    ident, assumed = search(xy, width, height, fov_deg=fov_deg, fov_tolerance_deg=fov_tolerance_deg,
                            camera=camera, database=database, epoch=epoch, identify_method=identify_method,
                            identify_options=identify_options)
    fov_failure = ""
    if (not ident.success and fov_deg is not None and camera is None
            and identify_method.lower() in _BLIND_METHODS and _searched(database, fov_deg)):
        # A FOV hint that matched nothing may be wrong: the frame is searched without it, and the
        # Solution says the hint was not used (warnings) — or, failing too, what both said.
        fov_failure = ident.reason
        log.info("%s: nothing matched at the FOV hint %g° (%s): solving without it", name, fov_deg,
                 fov_failure)
        ident, assumed = identify_lost(xy, width, height, fov_deg=None, fov_tolerance_deg=None, camera=None,
                                       database=database, epoch=epoch, identify_method=identify_method,
                                       identify_options=identify_options)
    if assumed is not None:
        fit_options["camera_given"] = True
        log.info("%s: identified through the %s preset's camera (its %d×%d size)", name, assumed, width,
                 height)
    t1 = _clock()
    sol.time_ms = {"identify": 1e3 * (t1 - t0)}
    sol.method = ident.method
    if not ident.success:
        sol.reason = ident.reason + (f"; attitude hint: {hint_failure}" if hint_failure else "")
        if fov_failure:
            sol.reason += (f"; with the FOV hint {fov_deg:g}° too ({fov_failure}): if the field of view "
                           "is known, check it; else solve without it")
        log.info("%s: identification failed: %s", name, ident.reason)
        return sol
    _fill_attitude(sol, xy, ident, attitude_method, **fit_options)
    if not sol.solved and assumed is None and ident.camera.projection == "pinhole":
        # Identified, but too uncertain through a camera fitted to a few stars: a seed camera of
        # the frame's size, if the stars confirm it, pins the attitude down.
        again = retry_through_preset(ident, xy, width, height, fov_deg=fov_deg, camera=camera,
                                     database=database, epoch=epoch, identify_method=identify_method,
                                     identify_options=identify_options)
        if again is not None:
            retry = _new_solution(name, len(xy), obs)
            retry.method = again.ident.method
            _fill_attitude(retry, xy, again.ident, attitude_method, **{**fit_options, "camera_given": True})
            if retry.solved:
                log.info("%s: solved through the %s preset's camera (its %d×%d size)", name, again.assumed,
                         width, height)
                retry.time_ms = sol.time_ms
                sol = retry
    sol.time_ms["attitude"] = 1e3 * (_clock() - t1)
    sol.time_ms["total"] = 1e3 * (_clock() - t0)
    if sol.solved:
        log.info("%s: solved with %d stars, P(false) %.2g, rmse %.2f″", name, sol.n_matched,
                 sol.prob_false, sol.rmse_arcsec)
        if fov_failure:
            sol.warnings.append(f"the FOV hint {fov_deg:g}° was not used: nothing matched at it "
                                f"({fov_failure}); solved without it, the stars give {sol.fov_deg:.3f}°")
        if hint_failure:
            sol.warnings.append(f"the attitude hint was not used ({hint_failure}): solved lost in space")
    elif hint_failure:
        sol.reason += f"; attitude hint: {hint_failure}"
    return sol


def _sky_circle(data: np.ndarray, camera: Camera | None, fov_deg: float | None):
    """The image circle of an all-sky frame (:func:`skyfix.detect.sky_circle.find_image_circle`)
    when the scale is not given otherwise — no FOV, and no camera or a fisheye's — else None
    (tens of µs on an ordinary frame)."""
    if fov_deg is not None or (camera is not None and camera.projection == "pinhole"):
        return None
    from skyfix.detect.sky_circle import find_image_circle

    return find_image_circle(data)


def _check_not_allsky(data: np.ndarray, camera: Camera) -> None:
    """Raise CameraError when a frame that failed through the pinhole ``camera`` is an all-sky
    fisheye's: no pinhole model holds it."""
    from skyfix.detect.sky_circle import find_image_circle

    circle = find_image_circle(data)
    if circle is not None:
        raise CameraError(f"this is an all-sky fisheye frame (an image circle of radius {circle.radius:.0f} "
                          f"px about ({circle.cx:.0f}, {circle.cy:.0f})) but the camera is a pinhole's "
                          f"({camera.fov_deg:.3g}° across): give a kannala-brandt camera file, or none")


#: The identification methods that search without a FOV (the others need the scale), so that a
#: FOV hint that matched nothing can be left out.
_BLIND_METHODS = ("quad-hash", "hash")


def _searched(database, fov_deg: float) -> bool:
    """Whether a search at ``fov_deg`` ran: a database (given, or the default bands) that does not
    serve it refuses it — its reason says how to build one that does — and then the hint is not
    what failed."""
    from skyfix.identify.catalogue.bands import bands_for, served_fov_deg

    if database is None:
        return bool(bands_for(fov_deg, fov_deg))
    lo, hi = served_fov_deg(database)
    return lo <= fov_deg <= hi


_WARM = False  # this process has seen the solve path warm (it stays so: skyfix.warmup.is_warm)


def _warm(database, fov_deg: float | None, camera: Camera | None) -> None:
    """A first solve's kernels compiled up front, in parallel (:func:`skyfix.warmup.ensure`),
    while the pattern database it will search first is built, if that is not cached yet."""
    global _WARM
    if _WARM or aot_modules():  # every kernel compiled ahead of time: skyfix.warmup (~12 ms) not imported
        return
    from skyfix import warmup

    if warmup.is_warm("solve"):
        _WARM = True
        return
    alongside, also = None, ""
    if database is None:
        fov = camera.fov_deg if camera is not None else fov_deg
        band = (bands.bands_for(fov, fov) or bands.BANDS)[0] if fov is not None else bands.STANDARD
        if not band.path.exists():
            alongside = functools.partial(bands.band_database, band, progress=False)
            also = "building the pattern database"
    warmup.ensure("solve", alongside=alongside, also=also)


_clock = time.perf_counter  # the module's `time` is solve()'s keyword inside it

DETECT_SIGMA = 5.0
"""The detection threshold of a solve, in σ of the matched-filtered frame's noise."""
FAINT_SIGMA = 3.5
"""The threshold of the second look at a sparse frame that failed (:func:`look_fainter`)."""
FAINT_LOOK_BELOW = 20
"""A frame with fewer stars than this above :data:`DETECT_SIGMA` is sparse."""
FAINT_LOOK_FROM = 3
"""... and one with fewer than this shows no star at all (noise, cloud, a lens cap): no second look."""


def _extract(data: np.ndarray, sigma: float, max_stars: int, usable: np.ndarray | None):
    """The frame's stars above ``sigma``, the brightest ``max_stars`` of those on the sky of the
    mask (``usable``, :func:`skyfix.detect.mask.as_mask`; None: every pixel) that are not letters
    of a caption or time stamp (:func:`skyfix.detect.text.text_like`)."""
    from skyfix.detect import extract_centroids
    from skyfix.detect.text import text_like

    found = extract_centroids(data, sigma=sigma, max_stars=max_stars if usable is None else 4 * max_stars)
    text = text_like(found)
    if usable is None and not text.any():
        return found  # the common case, as extracted
    if text.any():  # the letters took stars' places: look deeper, then leave the text out
        found = extract_centroids(data, sigma=sigma, max_stars=4 * max_stars)
        found = found.subset(np.flatnonzero(~text_like(found)))
    if usable is not None:
        from skyfix.detect.mask import sky_only

        found = sky_only(found, usable)
    return found.brightest(max_stars)


def look_fainter(n_detected: int, hint) -> bool:
    """Whether a frame that failed to solve is extracted again at :data:`FAINT_SIGMA`: when it is
    sparse (:data:`FAINT_LOOK_FROM` to :data:`FAINT_LOOK_BELOW` stars above :data:`DETECT_SIGMA`:
    a short exposure, a small aperture or a narrow field, whose stars a solve needs may lie just
    below the threshold; fewer: nothing but noise, whose peaks above 3.5 σ — 24–49 on a 1280 × 960
    frame of pure noise — would cost a 2 s search to refuse) and no attitude hint was given (a
    hint's failure is about the hint). The
    fainter extraction holds more false detections (~0.02 % of noise peaks pass 3.5 σ), which
    identification counts against chance as any other; a second solve that does not solve
    changes nothing but the reason."""
    return hint is None and FAINT_LOOK_FROM <= n_detected < FAINT_LOOK_BELOW


def _observation(observation: Observation | None, epoch: float | None, **given) -> Observation:
    """The solve's Observation: ``observation`` as made by :func:`solve` (or a caller), else one
    made from the keywords (:func:`~skyfix.corrections.observation.observe`)."""
    if observation is None:
        return observe(epoch=epoch, **given)
    if not isinstance(observation, Observation):
        raise InputError(f"observation must be an Observation (observe(...)), not "
                         f"{type(observation).__name__}")
    both = [k for k, v in given.items()
            if not (v is None or (k == "refraction" and v == "erfa") or (k == "apparent" and v is False))]
    if both:
        raise InputError(f"give {', '.join(both)} in the observation, not beside it")
    return observation


def _new_solution(name: str, n_detected: int, obs: Observation) -> Solution:
    """An unsolved Solution with the observation's time and corrections."""
    sol = Solution(image=name, n_detected=n_detected)
    obs.report(sol, None)
    return sol


# The options of identify_near that lost in space's default method shares (same names, same meaning).
_HINT_OPTIONS = ("prob_threshold", "verify_stars", "refine_stars", "match_radius", "centroid_sigma_px")


def _checked_hint(attitude_hint):
    """The attitude hint as an :class:`~skyfix.identify.hint.AttitudeHint` (None: no hint)."""
    if attitude_hint is None:
        return None
    from skyfix.identify.hint import check_attitude_hint

    return check_attitude_hint(attitude_hint)


def _solve_near(sol: Solution, xy: np.ndarray, width: int, height: int, hint, fov_deg, fov_tolerance_deg,
                camera, database, epoch, attitude_method: str, identify_options: dict,
                fit_options: dict) -> str:
    """Solve near the attitude ``hint`` into ``sol`` (:func:`skyfix.identify.hint.identify_near`,
    then the final fit and the precision rule as lost in space's); returns why not ("" when solved)."""
    from skyfix.identify.hint import identify_near

    if camera is None and fov_deg is None:
        return "no camera or FOV given: the hint needs the image scale"
    t0 = _clock()
    cam = camera if camera is not None else Camera.from_fov(width, height, fov_deg)
    if database is None:
        database = database_for_fov(cam.fov_deg)
    near = identify_near(xy, cam, hint.A_icrs_to_cam, hint.uncertainty_rad, database=database, epoch=epoch,
                         fit_camera=camera is None, fov_tolerance_deg=fov_tolerance_deg,
                         **{k: identify_options[k] for k in _HINT_OPTIONS if k in identify_options})
    t1 = _clock()
    sol.time_ms = {"identify": 1e3 * (t1 - t0)}
    if not near.success:
        return near.reason
    ident = dataclasses.replace(near.identification(), database=database)
    sol.method = ident.method
    _fill_attitude(sol, xy, ident, attitude_method, **fit_options)
    sol.time_ms["attitude"] = 1e3 * (_clock() - t1)
    return "" if sol.solved else sol.reason


def _check_options(fov_deg, fov_tolerance_deg, camera, database, epoch, attitude_method, identify_method,
                   identify_options: dict) -> None:
    """The checks :func:`solve` and :func:`solve_centroids` share (:mod:`skyfix.validate`; the
    identification method and its options: :mod:`skyfix.identify.methods`)."""
    check_solve_options(fov_deg, fov_tolerance_deg, epoch, attitude_method)
    if camera is not None and not isinstance(camera, Camera):
        raise InputError(f"camera must be a Camera (Camera.load(path)), got {type(camera).__name__}")
    if database is not None and not isinstance(database, PatternDatabase):
        raise InputError(f"database must be a PatternDatabase (PatternDatabase.load(path)), "
                         f"got {type(database).__name__}")
    get_method(identify_method)  # an unknown name: InputError listing the known ones
    if not identify_options:
        return
    known = method_options(identify_method)
    unknown = [k for k in identify_options if k not in known]
    if unknown:
        raise InputError(f"unknown option {', '.join(unknown)}; known: {', '.join(known)}")


def _fill_attitude(sol: Solution, xy: np.ndarray, ident, attitude_method: str, *, camera_given: bool,
                   database, epoch: float | None, prob_threshold: float, n_img: int,
                   centroid_sigma_px: float | None = None, observation: Observation) -> None:
    seen = _Places(observation.seen) if observation.moves_stars else None
    try:
        fit = final_fit(xy, ident, camera_given=camera_given, database=database, epoch=epoch,
                        method=attitude_method, prob_threshold=prob_threshold, n_img=n_img, seen=seen)
    except CameraError as exc:  # no camera model fits the stars identified
        sol.reason = str(exc)
        return
    A, camera, idx = fit.A_icrs_to_cam, fit.camera, fit.star_index
    # The σ behind the covariance was estimated from the residuals: 2 per star, less the
    # attitude's 3 and the camera's effective share (Student's tails for a few stars). A centroid
    # noise stated beside a given camera is combined with it (accept.noise_posterior).
    dof = fit.residual_dof
    scale = 1.0
    if centroid_sigma_px is not None and math.isfinite(fit.noise_sigma_rad):
        noise = noise_posterior(fit.residuals_rad, dof, centroid_sigma_px * camera.plate_scale_rad)
        scale = (noise.sigma_rad / fit.noise_sigma_rad) ** 2
        dof = noise.dof
    covariance = fit.covariance_rad2 * scale
    judged = covariance if fit.precision_covariance_rad2 is None else fit.precision_covariance_rad2 * scale
    imprecise = precision_failure(judged, camera.plate_scale_rad, dof, camera_given)
    if imprecise:
        sol.reason = imprecise
        log.info("%s: %s", sol.image, imprecise)
        return
    db = ident.database if ident.database is not None else database
    places = fit.catalog_vectors  # the catalogue places the matches report (seen: corrected, not those)
    A_apparent = A_reported = A
    if seen is not None:
        places = seen.places(fit.catalog_ids)
        A_apparent = Deferred(apparent_attitude, (A, places, fit.catalog_vectors))  # a WCS or plot reads it
        if observation.apparent:  # the attitude reported: found now
            A_apparent = A_reported = apparent_attitude(*A_apparent.args)
    pointing, table, rmse = solution_numbers(A_reported, xy, idx, places, fit.catalog_mag, fit.residuals_rad)
    pointing = pointing.tolist()
    sol.status = "solved"
    sol.reason = ""
    sol.ra_deg, sol.dec_deg, sol.roll_deg = pointing[:3]
    sol.boresight_px = [float(camera.cx), float(camera.cy)]
    sol.fov_deg = camera.fov_deg
    sol.quaternion_xyzw = pointing[3:]
    # Student's variance for a σ from dof residual degrees of freedom (the rule above took the scale).
    sol.covariance_arcsec2 = (error_covariance(covariance, dof) / _ARCSEC**2).tolist()
    if judged is not covariance:  # else it reads as covariance_arcsec2
        sol.frame_covariance_arcsec2 = (error_covariance(judged, dof) / _ARCSEC**2).tolist()
    sol.n_matched = len(idx)
    sol.prob_false = max(float(ident.prob_false), math.exp(fit.log_prob_chance))
    sol.rmse_arcsec = rmse / _ARCSEC
    sol.A_icrs_to_cam = A
    sol.A_apparent_to_cam = A_apparent
    sol.camera = camera
    # the image centre's, when first read (a JSON line, the summary): the same when it is the boresight
    sol.center_covariance_arcsec2 = Deferred(_pixel_covariance_arcsec2, (fit, sol.center_px, scale, dof))
    observation.report(sol, A, A_reported, camera=camera)
    for line in sol.warnings:  # a bright body inside its exclusion angle
        log.warning("%s: %s", sol.image, line)
    if db is not None:
        sol.catalog = str(db.meta.get("catalog", ""))
        sol.catalog_epoch = float(epoch if epoch is not None else db.epoch)
    sol.matches = MatchTable(table, fit.catalog_ids)  # made into Match tuples when first read


def _pixel_covariance_arcsec2(fit, pixel: list[float], scale: float, dof: float) -> list[list[float]]:
    """The covariance (3 × 3, arcsec², Student-scaled as ``covariance_arcsec2``) of the frame at
    ``pixel`` (:func:`skyfix.final_fit.covariance_at_pixel`), ``scale`` the centroid noise's (σ²
    stated over σ² fitted)."""
    return (error_covariance(covariance_at_pixel(fit, pixel) * scale, dof) / _ARCSEC**2).tolist()


class _Places:
    """:meth:`Observation.seen <skyfix.corrections.observation.Observation.seen>` for the final fit,
    remembering the catalogue places it is given, by catalogue number: the matches report those."""

    def __init__(self, seen) -> None:
        self._seen, self._ids, self._vectors = seen, [], []

    def __call__(self, vectors: np.ndarray, ids: np.ndarray) -> np.ndarray:
        self._ids.append(np.asarray(ids))
        self._vectors.append(np.asarray(vectors, dtype=np.float64))
        return self._seen(vectors, ids)

    def places(self, ids: np.ndarray) -> np.ndarray:
        """The catalogue places (K, 3) of the stars numbered ``ids``, each one seen before."""
        ids = np.asarray(ids)
        if len(self._ids) == 1 and np.array_equal(self._ids[0], ids):  # one call, those very stars
            return self._vectors[0]
        numbers, vectors = np.concatenate(self._ids), np.concatenate(self._vectors)
        order = np.argsort(numbers, kind="stable")
        return vectors[order[np.searchsorted(numbers, ids, sorter=order)]]
