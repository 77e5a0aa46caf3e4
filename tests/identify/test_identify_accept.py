"""The acceptance rules of identification (skyfix.identify.accept): their definitions, and that
identify applies the ones it runs in Python."""

import math

import numpy as np
import pytest

from skyfix.identify import accept

W, H = 1280, 960


def test_rule_helpers_are_the_kernel_arithmetic():
    # rule 1: 4·√2·σ over the largest edge in pixels, plus the tier's model allowance
    assert accept.ratio_tolerance(1.0, 0.1, 2000.0, 0.002) == 4.0 * 1.4142 * 1.0 / (0.1 * 2000.0) + 0.002
    # rule 2: inclusive range; NaN passes (rule 3 rejects it)
    assert accept.focal_allowed(1000.0, 1000.0, 1100.0) and accept.focal_allowed(1100.0, 1000.0, 1100.0)
    assert not accept.focal_allowed(999.9, 1000.0, 1100.0)
    assert not accept.focal_allowed(1100.1, 1000.0, 1100.0)
    assert accept.focal_allowed(math.nan, 1000.0, 1100.0)
    # rule 3: every star within the radius (in pixels at the candidate's focal length)
    assert accept.pattern_fits(0.005, 2000.0, 10.0) and not accept.pattern_fits(0.0051, 2000.0, 10.0)
    # rule 5: look-elsewhere multiplies by the candidates examined
    assert accept.log_prob_false(-30.0, 1000) == pytest.approx(-30.0 + math.log(1000.0), abs=0)
    assert accept.is_verified(math.log(1e-9), math.log(1e-9))
    assert not accept.is_verified(math.log(1e-9) + 1e-12, math.log(1e-9))


def test_ratio_tolerance_covers_the_centroid_noise():
    """Rule 1 lets through the true patterns of centroids with noise σ (99.9 %), and is not much
    looser than that noise needs (fewer than 90 % pass with 2σ)."""
    from skyfix.identify.catalogue.hashing import edge_ratios

    rng = np.random.default_rng(2)
    f = (W / 2) / math.tan(math.radians(7.5))
    xy = rng.uniform([-W / 2, -H / 2], [W / 2, H / 2], (20000, 4, 2))

    def rays(p):
        v = np.concatenate([p / f, np.ones(p.shape[:-1] + (1,))], axis=-1)
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    true_ratios, _ = edge_ratios(rays(xy))
    for sigma in (0.5, 1.0):
        passed = []
        for noise in (sigma, 2 * sigma):
            ratios, largest = edge_ratios(rays(xy + rng.normal(0.0, noise, xy.shape)))
            tol = accept.ratio_tolerance(sigma, largest, f, 0.0)
            passed.append(np.mean(np.abs(ratios - true_ratios).max(axis=1) <= tol))
        assert passed[0] >= 0.998 and passed[1] < 0.9, (sigma, passed)


def test_quick_check_rule():
    """Rule 4 judges only with three or more catalogue stars, and fails a candidate whose matches
    have a chance above e^-3 (5 %)."""
    assert accept.QUICK_CATALOG_STARS == 15 and accept.QUICK_CENTROIDS == 30
    assert accept.quick_check_fails(3, -2.9)
    assert not accept.quick_check_fails(3, -3.0)
    assert not accept.quick_check_fails(2, 0.0)  # too few stars in view to judge: full verification


def test_refit_rules():
    # rule 6: at least four pairs, and beyond chance
    assert not accept.refit_accepted(3, 3, 200, 1.0, W * H, math.log(1e-9))
    assert accept.refit_accepted(30, 60, 200, 2.0, W * H, math.log(1e-9))
    assert not accept.refit_accepted(6, 400, 200, 30.0, W * H, math.log(1e-9))  # as many as chance gives
    # rule 7: 3 % of slack on the allowed range
    assert accept.refit_focal_allowed(1000.0 * 0.97, 1000.0, 1100.0)
    assert accept.refit_focal_allowed(1100.0 * 1.03, 1000.0, 1100.0)
    assert not accept.refit_focal_allowed(1000.0 * 0.969, 1000.0, 1100.0)
    assert not accept.refit_focal_allowed(1100.0 * 1.031, 1000.0, 1100.0)


def test_refit_focal_range_rule(database, monkeypatch):
    """identify applies rules 6 and 7 to every accepted candidate: with either refusing, a field
    that solves finds no match."""
    from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
    from skyfix.camera import Camera
    from skyfix.catalog import load_hipparcos
    from skyfix.identify import identify
    from skyfix.identify.methods import quad

    catalog = load_hipparcos(epoch=database.epoch, mag_limit=8.0)
    f = synthetic_centroids(Camera.from_fov(W, H, 15.0), random_attitudes(1, rng=21)[0], catalog,
                            sigma_px=0.5, rng=21)
    assert identify(f.xy, W, H, fov_deg=15.0, database=database).success
    for rule in ("refit_focal_allowed", "refit_accepted"):
        with monkeypatch.context() as m:
            m.setattr(quad, rule, lambda *args: False)
            res = identify(f.xy, W, H, fov_deg=15.0, database=database, max_patterns=200, check_mirror=False)
        assert not res.success and "no match" in res.reason, rule


def test_prob_threshold_bounds_the_reported_chance(database):
    """Rule 5: a success never reports a chance of a false match above ``prob_threshold``. Sparse
    fields (stars to magnitude 6) have first candidates between 1e-15 and 1e-20: with a threshold
    of 1e-20 they fail or solve with a later, better candidate."""
    from skyfix.analysis.synthetic_centroids import random_attitudes, synthetic_centroids
    from skyfix.camera import Camera
    from skyfix.catalog import load_hipparcos
    from skyfix.identify import identify

    catalog = load_hipparcos(epoch=database.epoch, mag_limit=8.0)
    cam = Camera.from_fov(W, H, 15.0)
    weak = 0
    for i, A in enumerate(random_attitudes(20, rng=31)):
        f = synthetic_centroids(cam, A, catalog, mag_limit=6.0, sigma_px=1.0, n_false=3, rng=i)
        usual = identify(f.xy, W, H, fov_deg=15.0, database=database)
        strict = identify(f.xy, W, H, fov_deg=15.0, database=database, prob_threshold=1e-20)
        assert usual.success and usual.prob_false <= 1e-9
        assert not strict.success or strict.prob_false <= 1e-20
        weak += usual.prob_false > 1e-20
    assert weak >= 2  # the threshold decided something


def test_chance_rule_is_the_binomial_tail():
    """The refit's and the final fit's chance test (module text, *Chance*): k of n catalogue stars
    each within r of one of n_img centroids with p = n_img·π·r²/area, discounting ⌈n_extra/2⌉."""
    from scipy.stats import binom

    p = 200 * math.pi * 3.0**2 / (W * H)
    got = accept.chance_log_probability(12, 80, 200, 3.0, W * H)
    assert math.exp(got) == pytest.approx(binom.sf(11, 80, p), rel=1e-9)
    paid = accept.chance_log_probability(12, 80, 200, 3.0, W * H, n_extra=3.0)  # two matches discounted
    assert math.exp(paid) == pytest.approx(binom.sf(9, 80, p), rel=1e-9)
    assert np.isfinite(got) and paid > got


def test_student_t_tail_is_scipy_s_and_the_closed_forms():
    # wrong_probability's roll tail, written out (scipy.special's import cost a solve 0.06 s):
    # ν = 1 (Cauchy) and ν = 2 have closed forms, the rest is scipy.special.stdtr.
    from scipy.special import stdtr

    for t in np.concatenate([np.logspace(-6, 3, 200), [0.5, 1.0, 3.0, 5.0]]):
        assert accept.student_t_two_sided(t, 1.0) == pytest.approx(1 - 2 / math.pi * math.atan(t), rel=1e-13)
        s = math.sqrt(2 + t * t)  # 1 − t/s, without the cancellation
        assert accept.student_t_two_sided(-t, 2.0) == pytest.approx(2 / (s * (s + t)), rel=1e-12)
        for nu in (1.5, 3.0, 4.5, 7.0, 12.0, 40.0, 150.0, 1000.0):
            ref = 2 * stdtr(nu, -t)
            if ref > 1e-290:
                assert accept.student_t_two_sided(t, nu) == pytest.approx(ref, rel=1e-9), (t, nu)
    assert accept.student_t_two_sided(0.0, 3.0) == 1.0
    assert accept.student_t_two_sided(1e200, 3.0) == 0.0
