"""One tracked frame with the Kalman filter in one compiled call: from the window plan through
the centroids, the match and the attitude fit to the filter's gated correction and the
Solution's numbers (docs/tracking.md#one-tracking-update).

:func:`track_step` runs, with nothing in Python between them:

1. :func:`skyfix.track.measure.measure_frame` at the filter's prediction — windows planned,
   tiles cut and centroided, stars matched, the attitude fitted;
2. when the fit holds (at least ``min_stars`` stars, and :func:`window_fit_agrees`), the
   filter's gated correction (:func:`skyfix.track.filter.gated_correct`: the NIS against the
   prediction, the update when it is within the gate) and the corrected rate
   (:func:`skyfix.track.filter.corrected_rate`);
3. when the filter took it, the Solution's numbers of the corrected estimate
   (:func:`skyfix.track.windows.solution_numbers`).

The kernels are those the step-by-step path calls (a predictor other than the MEKF: its
``predict``, ``measure_frame``, its ``update_gated``); only the sequence is here. One call
because the Python between them cost more than the filter's work: a tracked update at rest was
~100 µs of Python around ~40 µs of compiled work.
"""

from __future__ import annotations

import numpy as np

from skyfix._jit import njit
from skyfix.track.filter import corrected_rate, gated_correct
from skyfix.track.measure import measure_frame
from skyfix.track.windows import solution_numbers

__all__ = ["track_step", "window_fit_agrees"]


@njit(cache=True, inline="always")
def window_fit_agrees(n_fit, n_found):
    """Whether a windows' fit speaks for the frame: at least half of the windows that found a
    star are in it. Tracking, nearly every window's star fits; when most do not, the prediction
    has put the windows where the stars are not quite (a manoeuvre, a wrong rate): the few that
    agree may agree on a biased attitude — in one simulated slew, 7 of 16 agreed on one 65″ off
    at 6σ — so the frame is solved lost in space instead."""
    return 2 * n_fit >= n_found


@njit(cache=True)
def track_step(img, A, P, rate, gyro_rate, bias, gyro, exposure_s, line_time_s, local_t, select_mag, cam,
               settings_t, view_t, tiles, max_tile, vectors, zero_point, match_t, centroid_t, min_stars,
               outlier_k, nis_gate, mags, places):
    """The steps of the module docstring for the frame ``img`` at the filter's prediction:
    attitude ``A`` (3, 3), covariance ``P`` (6, 6: attitude, then rate or bias), rate ``rate``;
    ``gyro_rate`` and ``bias`` the gyro's rate and bias in gyro mode (``gyro``; else any (3,)
    arrays, unused) — :meth:`skyfix.track.filter.AttitudeFilter.step_inputs`. ``exposure_s`` …
    ``outlier_k`` are :func:`~skyfix.track.measure.measure_frame`'s, ``nis_gate`` the filter's
    gate, ``mags`` the star index's magnitudes and ``places`` its catalogue places (the Solution's
    matches: :func:`~skyfix.track.windows.solution_numbers`).

    Returns four plain tuples: ``measure_frame``'s; the gate — of
    :func:`~skyfix.track.filter.gated_correct` (the two input codes, whether ``S`` was positive
    definite, ``z``, ``S``, NIS, whether corrected, attitude, ``dx``, covariance (6, 6)), or
    NaN NIS and not corrected when the fit did not hold; the corrected rate and bias; and
    :func:`~skyfix.track.windows.solution_numbers`'s ``head``, ``table``, RMS of the corrected
    estimate and the fitted stars (empty, NaN when not corrected)."""
    P_att = P[:3, :3].copy()
    P_rate = P[3:, 3:].copy()
    m = measure_frame(img, A, P_att, rate, P_rate, exposure_s, line_time_s, local_t, select_mag, cam,
                      settings_t, view_t, tiles, max_tile, vectors, zero_point, match_t, centroid_t,
                      min_stars, outlier_k)
    ok, n_found, n_fit, A_fit, P_fit = m[3], m[4], m[6], m[7], m[8]
    gate = (np.int64(0), np.int64(0), True, np.zeros(3), np.zeros((3, 3)), np.nan, False, A, np.zeros(6), P)
    if ok and window_fit_agrees(n_fit, n_found):
        gate = gated_correct(A, P, A_fit, P_fit.copy(), nis_gate)  # R symmetrised, the fit's own kept
    new_rate, new_bias = rate, bias
    head, table, rmse = np.zeros(28), np.zeros((6, 0)), np.nan
    if gate[6]:
        A_new, dx, P_new = gate[7], gate[8], gate[9]
        new_rate, new_bias = corrected_rate(rate, gyro_rate, bias, dx, gyro)
        head, table, rmse = solution_numbers(A_new, P_new[:3, :3].copy(), new_rate, P_new[3:, 3:].copy(),
                                             m[12][:n_fit], m[13][:n_fit], m[11][:n_fit], vectors, places,
                                             mags)
    return m, gate, (new_rate, new_bias), (head, table, rmse)
