"""The tracker's streak fit walks its windows by recurrences (skyfix.detect.streak_fit): each row's
Gaussians start from the row above's (the column walk) and step along the row, where they may
skip the re-seeding (streaks short enough that nothing underflows within the reach). Every
profile value the walk reaches must still be the direct formula's, and a fit whose window has
Gaussians that underflow at its corner (a long streak) must find the streak."""

import math

import numpy as np

from skyfix.detect.streak import streak_model_sigma
from skyfix.detect.streak_fit import _column_next, _column_start, _row_from, _row_next, _shape, fit_streaks


def test_column_walk_matches_exp_over_whole_windows():
    """Every pixel of 41 × 41 windows around streaks 0–60 px long at any angle: the walk's three
    Gaussians within 1e-12 of exp (relative, where above 1e-30), including windows whose corner
    Gaussians underflow and are seeded afresh down the column."""
    rng = np.random.default_rng(7)
    worst = 0.0
    for half_len, s in [(5e-4, 1.04), (4.0, 1.04), (4.0, 2.5), (15.0, 0.8), (30.0, 0.6)]:
        for _ in range(4):
            angle = rng.uniform(-np.pi, np.pi)
            shape = _shape(math.cos(angle), math.sin(angle), half_len, s)
            q = shape.q
            dx0, dy0 = -20.0 + rng.uniform(-0.5, 0.5), -20.0 + rng.uniform(-0.5, 0.5)
            col = _column_start(dx0, dy0, shape)
            for row in range(41):
                steps = int(rng.integers(0, 41))
                walk = _row_from(col, steps, shape)
                for k in range(steps, 41):
                    a, b, gp, _, gm, _, gb, _ = walk
                    ux, uy = shape.ux, shape.uy
                    dx, dy = dx0 + k, dy0 + row
                    assert abs(a - (dx * ux + dy * uy)) < 1e-9 and abs(b - (dy * ux - dx * uy)) < 1e-9
                    for z, g in (((a + half_len) * q, gp), ((a - half_len) * q, gm), (b * q, gb)):
                        exact = math.exp(-z * z)
                        err = abs(g - exact) / max(exact, 1e-30)
                        worst = max(worst, err if exact > 1e-30 else 0.0)
                        assert abs(g - exact) <= 1e-12 * max(exact, 1e-18), (half_len, s, row, k, z, g, exact)
                    walk = _row_next(walk, shape)
                col = _column_next(col, shape)
    assert worst > 0.0  # the recurrences are not exact: the test sees their error


def test_long_streak_fit_finds_its_centre():
    """A 50 px streak (its window's corner Gaussians underflow) and a 9 px one, rendered as the
    model without noise on a flat sky: the fit recovers both centres to 1e-3 px from a start
    0.2 px off."""
    s = streak_model_sigma(None)
    img = np.full((120, 160), 100.0, np.float32)
    yy, xx = np.mgrid[0:120, 0:160]
    truths = [(60.3, 40.6, 35.0, 35.0), (120.2, 80.4, 6.0, -6.5)]
    for xc, yc, mx, my in truths:
        length = math.hypot(mx, my)
        ux, uy = mx / length, my / length
        a = (xx - xc) * ux + (yy - yc) * uy
        b = (yy - yc) * ux - (xx - xc) * uy
        q = 1.0 / (math.sqrt(2.0) * s)
        h = 0.5 * length
        along = np.vectorize(math.erf)((a + h) * q) - np.vectorize(math.erf)((a - h) * q)
        img += (400.0 * along / length * np.exp(-(b * q) ** 2)).astype(np.float32)
    xy = np.array([[t[0] + 0.2, t[1] - 0.15] for t in truths])
    motion = np.array([[t[2], t[3]] for t in truths])
    f = fit_streaks(img, xy, motion, np.int64(4), s, 0.0, np.full(2, 0.1))
    for i, (xc, yc, _, _) in enumerate(truths):
        assert abs(f.x[i] - xc) < 1e-3 and abs(f.y[i] - yc) < 1e-3, (i, f.x[i], f.y[i])
