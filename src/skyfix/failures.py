"""Every reason a solve can fail with, and what to try next (issue 28 part 2).

A failed :class:`~skyfix.solution.Solution` says why in ``reason`` — the identification
method's words, with what the pipeline added (the FOV hint tried both ways, a second fainter
look, the frame's own problem) — and what to try in ``next_step``
(:func:`next_step`: the step of the first kind in :data:`FAILURES` whose pattern the reason
matches; ``""`` when none applies, e.g. the tracker's reasons). The kinds are ordered from the
most to the least specific: a FOV hint that failed both ways is about the hint, whatever the
search said; a blank frame is about the frame.

docs/failures.md is the same table for a reader (a test keeps the two, and every reason the
solver's code can form, in step).
"""

from __future__ import annotations

import re
from typing import NamedTuple

__all__ = ["FAILURES", "Failure", "failure_kind", "next_step", "step_to_add"]


class Failure(NamedTuple):
    """One kind of failure: its name, the pattern its reason matches (:func:`re.search`), what
    to try, and whether the reason's own words already say it (then ``skyfix solve``'s summary
    line does not repeat it; the JSON's ``next_step`` has it all the same)."""

    kind: str
    pattern: str
    step: str
    in_reason: bool = False


_SCALE = "give the camera (--camera FILE or a preset name) or the field of view (--fov DEG)"

FAILURES: tuple[Failure, ...] = (
    Failure("frame too small", r"too small for any star field",
            "give the whole frame (at least 32×32 pixels), not a crop", in_reason=True),
    Failure("blank frame", r"blank frame: every pixel is",
            "check the lens cap, the exposure and that the file is the camera's frame"),
    Failure("saturated frame", r"saturated frame:",
            "shorten the exposure or lower the gain"),
    Failure("FOV hint failed", r"with the FOV hint \S+ too \(",
            "solve without --fov (and --fov-tolerance), or check the field of view: the search "
            "failed with it and without it", in_reason=True),
    Failure("FOV outside the databases", r"field of view \S+ is outside",
            "build a database that covers it (skyfix database build --fov-min … --fov-max … -o FILE) "
            "and solve with --database FILE, or check --fov / --camera", in_reason=True),
    Failure("mirror image", r"mirror image|mirrored left-right",
            "solve with --parity either (or mirrored); parity= in Python", in_reason=True),
    Failure("hint without a scale", r"the hint needs the image scale",
            f"{_SCALE} with --attitude-hint"),
    Failure("method needs the scale", r"needs a field of view or a camera",
            f"{_SCALE}, or use the default method (--method quad-hash)", in_reason=True),
    Failure("uncertain: no camera", r"do not pin down an uncalibrated camera",
            "give the camera: --camera FILE (skyfix calibrate, or --save-camera from a frame of the "
            "same camera that solved)", in_reason=True),
    Failure("uncertain", r"attitude too uncertain",
            "more stars: a longer exposure, better focus or a wider field; --centroid-sigma PX if "
            "the centroids' noise is known"),
    Failure("too few stars detected", r"too few stars detected \(",
            "more stars above the noise: a longer exposure, better focus, a darker sky; check the "
            "lens cap"),
    Failure("too few stars", r"too few stars \(\S+ detected, need",
            f"{_SCALE}: with the scale known, the default method identifies three stars"),
    Failure("time limit", r"time limit",
            f"{_SCALE} so the search has less to try; check the frame is of the sky and in focus; "
            "time_limit_s= in Python"),
    Failure("tolerances too wide", r"beyond max_pair_matches",
            "narrow --fov-tolerance or give the camera (--camera FILE)"),
    Failure("no match", r"no match after \S+ patterns",
            f"check the frame is of the sky and in focus; {_SCALE}, with --fov-tolerance DEG if "
            "it is only roughly known; --parity either for a mirror image"),
    Failure("attitude hint failed", r"attitude hint",
            "check --attitude-hint (RA, Dec and roll in degrees; roll: image-up's position angle) "
            "or give it a larger uncertainty (its fourth number)"),
    Failure("method found no match",
            r"no match after \S+ candidate correspondences|no catalogue triangle fits|no triangle "
            r"unique enough|ambiguous: \S+ catalogue triangles|^no match: |no agreeing grid candidates"
            r"|no match group verified|no pyramid verified|no voted set verified",
            "the default method (--method quad-hash); check --fov, or give the camera"),
)


def failure_kind(reason: str) -> Failure | None:
    """The first kind of :data:`FAILURES` whose pattern ``reason`` matches (None: none)."""
    for failure in FAILURES:
        if re.search(failure.pattern, reason):
            return failure
    return None


def next_step(reason: str) -> str:
    """What to try after a solve failed with ``reason`` (``""`` when there is nothing to say)."""
    failure = failure_kind(reason) if reason else None
    return "" if failure is None else failure.step


def step_to_add(reason: str) -> str:
    """:func:`next_step` when the reason does not already say it (``""`` otherwise): what a
    one-line summary adds after the reason."""
    failure = failure_kind(reason) if reason else None
    return "" if failure is None or failure.in_reason else failure.step
