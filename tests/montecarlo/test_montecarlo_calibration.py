"""Monte Carlo campaigns (issue 27): is ``prob_false`` calibrated — the summary's bins of
predicted ``prob_false`` against the wrong identifications seen (Clopper–Pearson) — and the
trial kinds a campaign chooses (the lost-in-space method, an attitude hint of the truth)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("pyarrow")

from skyfix.montecarlo.campaign import campaign_from_dict, load_campaign  # noqa: E402
from tests.conftest import ROOT


def _small(**parameters):
    return campaign_from_dict({"campaign": {"name": "c", "trials": 12, "seed": 9, "batch_size": 12},
                               "camera": {"preset": "generic"}, "parameters": parameters})


def _table(campaign, prob_false: np.ndarray, wrong: np.ndarray, mismatched: np.ndarray | None = None):
    """Solved rows of these chance figures and wrong flags (a wrong one with a wrong star unless
    ``mismatched`` says how many)."""
    from skyfix.montecarlo.results import batch_table

    mismatched = wrong.astype(int) if mismatched is None else mismatched
    rows = [{"trial": i, "seed": i, **campaign.fixed, "status": "solved", "reason": "", "wrong": bool(w),
             "n_mismatched": int(m), "prob_false": float(p), "error_x_arcsec": 1.0}
            for i, (p, w, m) in enumerate(zip(prob_false, wrong, mismatched, strict=True))]
    return batch_table(campaign, rows)


def test_prob_false_bins_flag_an_underestimate_and_pass_an_honest_figure():
    from skyfix.montecarlo.results import summarize

    c, rng = _small(), np.random.default_rng(4)
    pf = np.repeat([1e-12, 0.05], 1000)
    honest = summarize(_table(c, pf, rng.random(2000) < pf), c)["prob_false"]
    assert [(b["low"], b["solved"]) for b in honest["bins"]] == [(0.0, 1000), (0.01, 1000)]
    bin_ = honest["bins"][1]
    assert bin_["expected_wrong"] == pytest.approx(50.0)
    assert bin_["rate_lower_95"] <= bin_["mean_prob_false"] <= bin_["rate_upper_95"]
    assert honest["bins_calibrated"] and honest["calibrated"]
    # three times the wrong solutions the figure predicts: the bin and the Poisson check say so
    under = summarize(_table(c, pf, rng.random(2000) < 3 * pf), c)["prob_false"]
    assert not under["bins"][1]["calibrated"] and not under["bins_calibrated"] and not under["calibrated"]
    assert under["bins"][1]["rate_lower_95"] > 0.05


def test_a_wrong_attitude_with_every_star_right_is_the_precision_rules():
    from skyfix.montecarlo.results import summarize

    c = _small()
    s = summarize(_table(c, np.full(3, 1e-20), np.array([True, False, False]), np.zeros(3, int)), c)
    assert (s["wrong"], s["wrong_identification"], s["wrong_precision"]) == (1, 0, 1)
    assert s["prob_false"]["observed_wrong"] == 0


def test_every_identification_method_runs_in_a_campaign():
    """A method without a time limit (triangle) was handed ``time_limit_s``: every trial an error."""
    from skyfix.montecarlo.trials import run_trial

    c = _small(identify_method="triangle", mag_limit=6.0)
    rows = [run_trial(c, i) for i in range(6)]
    assert [r["status"] for r in rows] == ["solved"] * 6
    assert not any(r["wrong"] for r in rows)
    assert [r["n_mismatched"] for r in rows] == [0] * 6


def test_a_hint_of_the_truth_solves_near_it():
    from skyfix.montecarlo.trials import run_trial

    lost, hinted = _small(mag_limit=6.0, sigma_px=0.3), _small(mag_limit=6.0, sigma_px=0.3, hint="truth")
    a = [run_trial(lost, i) for i in range(6)]
    b = [run_trial(hinted, i) for i in range(6)]
    assert [r["status"] for r in b] == ["solved"] * 6 and not any(r["wrong"] for r in b)
    assert [r["hint"] for r in b] == ["truth"] * 6
    # the same frames (the hint draws nothing): the same stars, errors of the same size
    assert [r["n_stars"] for r in a] == [r["n_stars"] for r in b]
    bore = np.array([[r["boresight_error_arcsec"] for r in rows] for rows in (a, b)])
    ratio = bore[1] / bore[0]
    assert np.all((0.5 < ratio) & (ratio < 2.0))


@pytest.mark.slow
def test_prob_false_campaign_first_400_trials():
    """campaigns/prob-false.toml's first 400 trials (docs/montecarlo.md#prob_false): what is
    solved and its chance figures are fixed numbers; no wrong identification."""
    from skyfix.montecarlo.results import batch_table, summarize
    from skyfix.montecarlo.trials import run_batch

    c = load_campaign(ROOT / "campaigns" / "prob-false.toml")
    c = dataclasses.replace(c, trials=400, batch_size=400)
    s = summarize(batch_table(c, run_batch(c, 0)), c)
    assert (s["trials"], s["errors"], s["wrong_identification"]) == (400, 0, 0)
    assert s["solved"] == pytest.approx(150, abs=40)
    pf = s["prob_false"]
    assert pf["bins_calibrated"] and pf["calibrated"]
    assert max(b["high"] for b in pf["bins"]) <= 1e-3  # the solver reports no larger figure
