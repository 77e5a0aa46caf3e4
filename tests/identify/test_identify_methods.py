"""The registry of identification methods (skyfix.identify.methods) and the pipeline's choice
through it."""

import numpy as np
import pytest

from skyfix.errors import InputError, UnknownNameError
from skyfix.identify import (
    DEFAULT_METHOD,
    METHODS,
    Identification,
    get_method,
    identify,
    method_options,
)
from skyfix.identify.methods import INTERFACE_KEYWORDS, quad

W, H = 1280, 960


def test_registry_holds_the_quad_method_as_default():
    assert DEFAULT_METHOD == "quad-hash" and METHODS["quad-hash"] is quad.identify
    assert get_method("Quad-Hash") is quad.identify and METHODS["hash"] is quad.identify
    assert set(METHODS) >= {"hash", "triangle", "liebe", "planar", "area-moment", "pyramid", "grid",
                            "voting", "van-bezooijen"}
    with pytest.raises(UnknownNameError,
                       match="unknown identification method .nope.; choose one of quad-hash"):
        get_method("nope")


def test_registry_names_are_the_methods_own():
    """Each name of the registry is the ``METHOD`` of the module its function comes from (the
    registry imports a method's module when its name is first looked up)."""
    import sys

    for name in METHODS:
        method = METHODS[name]
        assert method is get_method(name) and method.__name__ == "identify"
        assert sys.modules[method.__module__].METHOD == ("quad-hash" if name == "hash" else name)
    assert len(METHODS) == len(list(METHODS)) == 10


def test_method_options_are_the_method_keywords_beyond_the_interface():
    options = method_options("quad-hash")
    assert "max_patterns" in options and "prob_threshold" in options
    assert not set(options) & set(INTERFACE_KEYWORDS)
    import inspect

    params = inspect.signature(quad.identify).parameters
    assert set(options) | set(INTERFACE_KEYWORDS) == set(params)  # the method implements the interface


def test_identify_by_name_is_the_method(database):
    from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
    from skyfix.camera import Camera
    from skyfix.catalog import load_hipparcos

    catalog = load_hipparcos(epoch=database.epoch, mag_limit=8.0)
    f = synthetic_centroids(Camera.from_fov(W, H, 15.0), random_attitudes(1, rng=5)[0], catalog, sigma_px=0.5,
                            rng=5)
    a = identify(f.xy, W, H, method="quad-hash", fov_deg=15.0, database=database)
    b = quad.identify(f.xy, W, H, fov_deg=15.0, database=database)
    assert a.success and a.method == "quad-hash"
    assert np.array_equal(a.star_index, b.star_index) and np.array_equal(a.A_icrs_to_cam, b.A_icrs_to_cam)
    failed = identify(f.xy[:2], W, H, database=database)
    assert not failed.success and failed.method == "quad-hash"


def test_pipeline_chooses_the_method_by_name(monkeypatch, database):
    from skyfix.identify import methods
    from skyfix.pipeline import solve_centroids

    seen = {}

    def fake(xy, width, height, *, fov_deg=None, fov_tolerance_deg=None, camera=None, database=None,
             epoch=None, depth=1):
        seen.update(width=width, fov_deg=fov_deg, depth=depth)
        return Identification(False, "fake says no", method="fake")

    monkeypatch.setitem(methods.METHODS, "fake", fake)
    methods.method_options.cache_clear()
    xy = np.random.default_rng(1).uniform([0, 0], [W, H], (20, 2))
    sol = solve_centroids(xy, W, H, fov_deg=12.0, database=database, identify_method="fake", depth=3)
    assert sol.status == "failed" and sol.reason == "fake says no" and sol.method == "fake"
    assert seen == dict(width=W, fov_deg=12.0, depth=3)
    with pytest.raises(InputError, match="unknown option max_patterns; known: depth"):
        solve_centroids(xy, W, H, database=database, identify_method="fake", max_patterns=10)
    methods.method_options.cache_clear()


def test_pipeline_refuses_an_unknown_method_or_option_before_any_work(database):
    from skyfix.pipeline import solve, solve_centroids

    xy = np.zeros((10, 2))
    with pytest.raises(UnknownNameError, match="unknown identification method 'kdtree'"):
        solve_centroids(xy, W, H, database=database, identify_method="kdtree")
    with pytest.raises(UnknownNameError, match="unknown identification method 'kdtree'"):
        solve(np.zeros((H, W)), database=database, identify_method="kdtree")
    with pytest.raises(InputError, match=r"unknown option max_patern; known: max_patterns, time_limit_s"):
        solve_centroids(xy, W, H, database=database, max_patern=10)


SHARED_OPTIONS = {"prob_threshold": 1e-9}  # one default for every method


def test_every_method_takes_the_shared_options_with_one_default():
    """Every registered method takes prob_threshold (default 1e-9) and centroid_sigma_px (its
    default is the 4-star hash's 1.0 px and the correspondence methods' 0.5 px — left as they
    are: changing either moves their solved counts, which needs the campaigns to judge)."""
    import inspect

    for name in METHODS:
        params = inspect.signature(METHODS[name]).parameters
        for option, default in SHARED_OPTIONS.items():
            assert option in method_options(name), (name, option)
            assert params[option].default == default, (name, option)
        assert "centroid_sigma_px" in method_options(name), name
        assert "max_stars" not in method_options(name), name  # 'max_stars' is solve's: centroids kept
