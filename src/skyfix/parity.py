"""Mirror images: solving a frame whichever way left and right are stored (issue 26 part 2).

A frame is *mirrored* when its pixels show the sky flipped: a FITS file whose rows are stored
bottom-up (FITS puts row 1 at the bottom) read top-down, a star diagonal, any optics with an odd
number of mirrors. No proper rotation takes the catalogue onto a mirrored frame's stars, so
skyfix solves it as the frame flipped left-right about the image centre, ``x' = (W − 1) − x``
(:func:`mirror_xy`), through the camera mirrored the same way (:func:`mirror_camera`), and then
maps the answer back (:func:`unmirror_solution`).

What a mirrored Solution holds (``mirrored`` true):

- ``ra_deg``, ``dec_deg``, ``center_*`` — the sky directions of the principal point and of the
  image centre: the same whichever way the pixels are stored.
- ``roll_deg`` — the position angle of image-up (−y): rows are not flipped, so it is image-up's
  in the frame as given.
- ``boresight_px``, ``matches`` — pixels of the frame as given (x flipped back).
- ``A_icrs_to_cam``, ``quaternion_xyzw``, ``camera`` — those of the flipped frame (a right-handed
  camera whose x axis runs toward *decreasing* column): a mirror image has no proper rotation of
  its own. ``Solution.attitude_at_pixel``/``radec_of_pixel`` take pixels of the frame as given and
  flip them; the WCS (``skyfix.wcs``, ``mirrored=True``) maps pixels of the frame as given.

``parity``: ``"normal"`` (the default for arrays and for PNG, JPEG and TIFF files), ``"mirrored"``,
or ``"either"`` (the default for FITS files): the normal frame first, then the mirrored one. With
``"either"`` two hypotheses are open, so each is tried at half the false-match threshold and the
reported ``prob_false`` is doubled: the safety argument of one hypothesis holds for the pair.
"""

from __future__ import annotations

import inspect

import numpy as np

from skyfix.errors import InputError

__all__ = ["NOT_MIRRORED_NOTE", "PARITIES", "check_parity", "halved_thresholds", "mirror_camera",
           "mirror_xy", "solve_with_parity", "unmirror_solution"]

PARITIES = ("normal", "mirrored", "either")


def check_parity(parity: str) -> str:
    """``parity`` if it is one of :data:`PARITIES`, else an :class:`~skyfix.errors.InputError`."""
    if not isinstance(parity, str) or parity not in PARITIES:
        raise InputError(f"parity must be one of {', '.join(PARITIES)}, not {parity!r}")
    return parity


def mirror_xy(xy: np.ndarray, width: int) -> np.ndarray:
    """Pixel positions (N, 2) flipped left-right about the image centre: ``x' = (W − 1) − x``.
    Its own inverse."""
    out = np.array(xy, dtype=np.float64, copy=True)
    out[:, 0] = (width - 1) - out[:, 0]
    return out


def mirror_camera(camera):
    """The camera that sees a mirrored frame flipped left-right as ``camera`` sees the frame:
    principal point ``cx' = (W − 1) − cx``, skew and Brown–Conrady's ``p2`` negated (the terms
    odd in x; radial terms and ``p1`` keep their sign). Its own inverse."""
    if camera is None:
        return None
    return camera.replace(cx=(camera.width - 1) - camera.cx, skew=-camera.skew, p2=-camera.p2)


def unmirror_solution(sol, width: int) -> None:
    """Make ``sol``, solved from the frame flipped by :func:`mirror_xy`, a Solution of the frame
    as given, in place: ``mirrored`` true, ``boresight_px`` and the matches' x flipped back (the
    rest as the module's docstring says). A failed Solution only gets ``mirrored`` true."""
    sol.mirrored = True
    if not sol.solved:
        return
    if sol.boresight_px is not None:
        sol.boresight_px = [(width - 1) - float(sol.boresight_px[0]), float(sol.boresight_px[1])]
    sol.flip_match_columns(width)


def _method_parameters(identify_method: str):
    """The identification method's parameters (``inspect.signature``), by name."""
    from skyfix.identify import get_method

    return inspect.signature(get_method(identify_method)).parameters


def halved_thresholds(identify_method: str, options: dict) -> dict:
    """``options`` with the method's false-match thresholds (``prob_threshold`` and, where the
    method has it, the sparse frames' ``lone_prob_threshold``) halved — given or defaulted —
    for a search with two parity hypotheses open."""
    params = _method_parameters(identify_method)
    out = dict(options)
    for key in ("prob_threshold", "lone_prob_threshold"):
        if key in params:
            out[key] = 0.5 * float(options.get(key, params[key].default))
    return out


def solve_with_parity(parity: str, xy: np.ndarray, width: int, camera, attitude_hint, identify_method: str,
                      identify_options: dict, attempt):
    """Solve the centroids ``xy`` under ``parity`` (``"mirrored"`` or ``"either"``) with
    ``attempt(xy, camera, identify_options, attitude_hint) -> Solution`` (a normal-parity solve).

    ``"mirrored"``: the flipped frame through the flipped camera, mapped back. ``"either"``: the
    frame as given (with the hint), then, if that fails, the flipped one (lost in space: a hint
    is an attitude of the frame as given), each at half the thresholds
    (:func:`halved_thresholds`); the reported ``prob_false`` is doubled. A failure reports the
    frame as given's reason."""
    from skyfix.identify.methods.quad import MIRROR_NOTE

    flipped_camera = mirror_camera(camera)
    if parity == "mirrored":
        sol = attempt(mirror_xy(xy, width), flipped_camera, identify_options, None)
        unmirror_solution(sol, width)
        if not sol.solved and sol.reason.endswith(MIRROR_NOTE):
            sol.reason = sol.reason[: -len(MIRROR_NOTE)] + NOT_MIRRORED_NOTE
        return sol
    options = halved_thresholds(identify_method, identify_options)
    # The frame as given need not look for a mirror image on failure (the method's check_mirror,
    # up to 0.25 s): the flipped frame is tried next anyway.
    plain = dict(options)
    if "check_mirror" not in identify_options and "check_mirror" in _method_parameters(identify_method):
        plain["check_mirror"] = False
    sol = attempt(xy, camera, plain, attitude_hint)
    if not sol.solved:
        alt = attempt(mirror_xy(xy, width), flipped_camera, options, None)
        if alt.solved:
            unmirror_solution(alt, width)
            sol = alt
    if sol.solved and sol.prob_false is not None:
        sol.prob_false = min(1.0, 2.0 * float(sol.prob_false))
    return sol


#: What a failed parity="mirrored" solve adds when the frame as given matches (the opposite of
#: :data:`skyfix.identify.methods.quad.MIRROR_NOTE`).
NOT_MIRRORED_NOTE = ("; but the stars match the sky as given: not a mirror image "
                     "(solve it with --parity normal)")
