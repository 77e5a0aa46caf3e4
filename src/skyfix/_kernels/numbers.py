"""A solved Solution's numbers in one compiled call (:func:`skyfix.pipeline.solve`'s last step):
the pointing and quaternion of the attitude, the matches' table and the residuals' RMS."""

from __future__ import annotations

import math

import numpy as np

from skyfix._jit import njit
from skyfix._kernels import rotation

_ARCSEC = math.pi / (180 * 3600)


def solution_numbers(A: np.ndarray, xy: np.ndarray, idx: np.ndarray, v: np.ndarray, mag: np.ndarray,
                     resid: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The numbers of a solved Solution in one call: RA, Dec, roll in degrees and the quaternion
    ``[x, y, z, w]`` (7,) (:func:`skyfix._kernels.rotation.pointing`) of the attitude ``A``; the
    table (6, M) of the matches' x, y (``xy[idx]``), RA and Dec (degrees) of their catalogue
    vectors ``v``, magnitude ``mag`` and residual (``resid``, rad → arcsec); the residuals' RMS
    (radians)."""
    f64 = np.float64
    return _solution_numbers(np.ascontiguousarray(A, dtype=f64), np.ascontiguousarray(xy, dtype=f64),
                             np.ascontiguousarray(idx, dtype=np.int64), np.ascontiguousarray(v, dtype=f64),
                             np.ascontiguousarray(mag, dtype=f64), np.ascontiguousarray(resid, dtype=f64))


@njit(cache=True)
def _solution_numbers(A, xy, idx, v, mag, resid):
    """:func:`solution_numbers`, compiled (its arguments contiguous, float64 but ``idx``)."""
    n = v.shape[0]
    table = np.empty((6, n))
    ss = 0.0
    for i in range(n):
        table[0, i] = xy[idx[i], 0]
        table[1, i] = xy[idx[i], 1]
        ra, dec = rotation.vector_radec(v[i, 0], v[i, 1], v[i, 2])
        table[2, i] = np.degrees(ra)
        table[3, i] = np.degrees(dec)
        table[4, i] = mag[i]
        table[5, i] = resid[i] / _ARCSEC
        ss += resid[i] * resid[i]
    out = rotation.pointing(A)
    for k in range(3):
        out[k] = np.degrees(out[k])
    return out, table, np.sqrt(ss / n) if n else np.nan
