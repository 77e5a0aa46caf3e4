"""Bad arguments to the Python API: a :class:`~skyfix.errors.InputError` (a SkyfixError and a
ValueError) with a one-line message, raised before any work — never a TypeError,
ZeroDivisionError or a silently wrong result. Featureless frames fail with a reason that says
which kind of frame it is."""


import numpy as np
import pytest

from skyfix.errors import InputError, SkyfixError
from skyfix.pipeline import solve, solve_centroids
from tests.conftest import EXAMPLES

EXAMPLE = EXAMPLES / "sky.png"
XY = np.random.default_rng(0).uniform(0, 500, (30, 2))


def _one_line(exc_info) -> str:
    msg = str(exc_info.value)
    assert msg and "\n" not in msg
    assert isinstance(exc_info.value, SkyfixError) and isinstance(exc_info.value, ValueError)
    return msg


def test_solve_rejects_a_list_of_images():
    with pytest.raises(InputError) as info:
        solve([str(EXAMPLE), str(EXAMPLE)])
    assert _one_line(info) == ("solve() takes one image (a file path or a 2-D array), got a list; "
                               "call it once per image")


@pytest.mark.parametrize("size", [(0, 0), (-5, 100), (640.5, 480), (float("nan"), 480), ("640", 480)])
def test_solve_centroids_rejects_bad_frame_size(size):
    with pytest.raises(InputError) as info:
        solve_centroids(XY, *size)
    assert _one_line(info).startswith("width and height must be whole numbers of pixels >= 1, got ")


@pytest.mark.parametrize("xy", [np.zeros((5, 3)), "abc", np.zeros((2, 2, 2))])
def test_solve_centroids_rejects_bad_centroid_array(xy):
    with pytest.raises(InputError) as info:
        solve_centroids(xy, 640, 480)
    assert _one_line(info).startswith("xy must be an (N, 2) array of pixel positions")


def test_unknown_attitude_method_rejected_before_any_work():
    # A 4x4 blank frame would otherwise "fail" with too few stars: the option is checked first.
    with pytest.raises(InputError) as info:
        solve(np.zeros((4, 4)), attitude_method="bogus")
    assert _one_line(info) == ("attitude_method 'bogus' is not a Wahba solver; choose one of "
                               "svd, quest, esoq2, q-method, triad")


@pytest.mark.parametrize("epoch", [float("nan"), float("inf"), -5000.0])
def test_bad_epoch(epoch):
    with pytest.raises(InputError) as info:
        solve_centroids(XY, 640, 480, epoch=epoch)
    assert _one_line(info) == f"epoch {epoch:g} is not a Julian year in 1000–3000 (e.g. 2024.5)"


@pytest.mark.parametrize("tol", [-1.0, 0.0, float("nan")])
def test_bad_fov_tolerance(tol):
    with pytest.raises(InputError) as info:
        solve_centroids(XY, 640, 480, fov_deg=20.0, fov_tolerance_deg=tol)
    assert _one_line(info) == f"fov_tolerance_deg {tol:g} must be a positive number"


@pytest.mark.parametrize("max_stars", [-5, 0, 2.5])
def test_bad_max_stars(max_stars):
    with pytest.raises(InputError) as info:
        solve(np.zeros((4, 4)), max_stars=max_stars)
    assert _one_line(info) == f"max_stars {max_stars:g} must be a whole number >= 1"


def test_unknown_keyword_is_named():
    with pytest.raises(InputError) as info:
        solve_centroids(XY, 640, 480, bogus=3)
    assert _one_line(info).startswith("unknown option bogus; known: ")


def test_database_of_the_wrong_kind():
    with pytest.raises(InputError) as info:
        solve_centroids(XY, 640, 480, database="db.npz")
    assert _one_line(info) == ("database must be a PatternDatabase (PatternDatabase.load(path)), "
                               "got str")


def test_one_fov_validation_for_solve_and_database_build():
    """The same range and the same words for a FOV hint and a database's FOV range."""
    from skyfix.identify import PatternDatabase

    with pytest.raises(InputError) as info:
        solve_centroids(XY, 640, 480, fov_deg=120.0)
    assert _one_line(info) == "fov_deg 120 is not a plausible field of view (0.5–100 degrees)"
    with pytest.raises(InputError) as info:
        solve_centroids(XY, 640, 480, fov_deg=float("nan"))
    assert _one_line(info) == "fov_deg nan is not a plausible field of view (0.5–100 degrees)"
    # Rejected at once: no catalogue load, no minutes of building.
    with pytest.raises(InputError) as info:
        PatternDatabase.build(fov_min_deg=0.2, fov_max_deg=10.0)
    assert _one_line(info) == "fov_min_deg 0.2 is not a plausible field of view (0.5–100 degrees)"
    with pytest.raises(InputError) as info:
        PatternDatabase.build(fov_min_deg=30.0, fov_max_deg=10.0)
    assert _one_line(info) == "fov_min_deg 30 is larger than fov_max_deg 10"


@pytest.mark.parametrize("kw", [{"sigma": -3.0}, {"sigma": float("nan")}, {"max_stars": -5}])
def test_extract_centroids_rejects_bad_arguments(kw):
    from skyfix.detect import extract_centroids

    with pytest.raises(InputError) as info:
        extract_centroids(np.zeros((50, 50)), **kw)
    name, value = next(iter(kw.items()))
    expected = "a positive number" if name == "sigma" else "a whole number >= 1"
    assert _one_line(info) == f"{name} {value:g} must be {expected}"


@pytest.mark.parametrize(("image", "reason"), [
    (np.zeros((480, 640)), "blank frame: every pixel is 0 (lens cap on, or no exposure?)"),
    (np.full((480, 640), 1234.0), "blank frame: every pixel is 1234 (lens cap on, or no exposure?)"),
    (np.full((480, 640), 255.0), "saturated frame: 100% of the pixels at full scale 255 (overexposed?)"),
    (np.zeros((1, 1)), "the image is 1×1 pixels, too small for any star field (a solve needs three or "
     "more stars, a few pixels apart: give the whole frame, at least 32×32)"),
])
def test_featureless_frames_say_which(image, reason, database):
    sol = solve(image, database=database)
    assert sol.status == "failed"
    assert sol.reason == f"too few stars detected (0; need at least 3): {reason}"


def test_a_tiny_frame_says_it_is_too_small_for_any_star(database):
    """A 10×10 frame of noise (issue 28: it said only "too few stars")."""
    sol = solve(np.random.default_rng(0).normal(40.0, 3.0, (10, 10)), database=database)
    assert sol.status == "failed" and sol.reason.endswith(
        "the image is 10×10 pixels, too small for any star field (a solve needs three or more stars, a few "
        "pixels apart: give the whole frame, at least 32×32)")


def test_mostly_saturated_frame_says_so(database):
    image = np.random.default_rng(3).normal(40.0, 3.0, (480, 640))
    image[:, 160:] = 255.0  # three quarters blown out
    sol = solve(image, database=database)
    assert sol.status == "failed"
    assert sol.reason.endswith("saturated frame: 75% of the pixels at full scale 255 (overexposed?)")


def test_fov_outside_database_says_how_to_build_one(database):
    sol = solve_centroids(XY, 640, 480, fov_deg=50.0, database=database)
    assert sol.status == "failed"
    assert sol.reason == (
        "field of view 50° is outside the pattern database's range 10–30° (it serves 7.41–40.5°); "
        "build one that covers it: `skyfix database build --fov-min 45 --fov-max 55 -o patterns-45-55deg.npz`"
        ", then `skyfix solve --database patterns-45-55deg.npz ...`")


def test_mirror_image_is_named(database):
    from skyfix.io import read_image

    mirrored = np.ascontiguousarray(read_image(EXAMPLE)[:, ::-1])
    # the search must run out of patterns, not out of time: the 2 s default is wall time, which
    # a loaded machine reaches first (then the reason is "time limit … reached", and no mirror)
    sol = solve(mirrored, database=database, time_limit_s=120.0)
    assert sol.status == "failed"
    assert "mirror image" in sol.reason
    assert sol.reason.startswith("no match after ")
    assert sol.reason.endswith("; but the stars match the sky mirrored left-right: a mirror image "
                               "(solve it with --parity mirrored or either; parity= in Python)")
