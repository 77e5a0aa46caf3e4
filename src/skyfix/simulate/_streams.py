"""The detector's random streams (:mod:`skyfix.simulate.sensor`'s draws): xoshiro256** run
inside the kernels, exact Poisson draws (bounds, inversion, PTRS; sparse ones by geometric gaps)
and normals by the ziggurat. :mod:`skyfix.simulate.sensor` runs them in its one pass over the
frame and exports the public ones (``poisson_image``, ``poisson_constant``,
``standard_normals``, ``stream_state``, ``stream_uniforms``).
"""

from __future__ import annotations

import math

import numpy as np

from skyfix._jit import njit
from skyfix.errors import SimulationError

# --- the detector's random streams ----------------------------------------------------------
# Every per-pixel draw comes from a xoshiro256** generator (Blackman & Vigna 2018) running
# inside the kernels: four uint64 of state, about 1 ns a number, nothing stored. Each stream's
# state is the next four raw 64-bit words of the frame's numpy Generator for that source
# (PCG64, spawned from the frame's SeedSequence), so the same seed gives the same frame, bit for
# bit, and switching one source off leaves every other source's draws as they were.

_U64 = np.uint64
_TO_UNIT = 1.0 / 9007199254740992.0  # 2^-53


def stream_state(rng: np.random.Generator) -> np.ndarray:
    """The (4,) uint64 xoshiro256** state of a stream: the next four raw words of ``rng``."""
    state = np.asarray(rng.bit_generator.random_raw(4), dtype=np.uint64)
    if not state.any():  # the one state xoshiro cannot leave (chance 2^-256)
        state[0] = 1
    return state


@njit(cache=True, nogil=True, inline="always")
def _rotl(x, k):
    return (x << _U64(k)) | (x >> _U64(64 - k))


@njit(cache=True, nogil=True, inline="always")
def _word(st):
    """(the next 64-bit word of the xoshiro256** state ``st`` — a tuple of four uint64, kept in
    registers by the kernels —, the state after it)."""
    s0, s1, s2, s3 = st
    word = _rotl(s1 * _U64(5), 7) * _U64(9)
    t = s1 << _U64(17)
    s2 ^= s0
    s3 ^= s1
    s1 ^= s2
    s0 ^= s3
    s2 ^= t
    s3 = _rotl(s3, 45)
    return word, (s0, s1, s2, s3)


@njit(cache=True, nogil=True, inline="always")
def _uniform(st):
    """(the next uniform in [0, 1) of the stream state ``st``, 53 bits; the state after it)."""
    word, st = _word(st)
    return np.float64(word >> _U64(11)) * _TO_UNIT, st


@njit(cache=True, nogil=True, inline="always")
def _load(state):
    return state[0], state[1], state[2], state[3]


@njit(cache=True, nogil=True, inline="always")
def _store(state, st):
    state[0], state[1], state[2], state[3] = st


@njit(cache=True, nogil=True)
def _fill_uniforms(state, out):
    st = _load(state)
    for i in range(out.size):
        out[i], st = _uniform(st)
    _store(state, st)


def stream_uniforms(state: np.ndarray, n: int) -> np.ndarray:
    """The next ``n`` uniforms of a stream (``state`` advanced in place): what the kernels draw."""
    out = np.empty(int(n), dtype=np.float64)
    _fill_uniforms(state, out)
    return out


# --- Poisson sampling --------------------------------------------------------------------
#: Below this mean a Poisson count is drawn by inverting one uniform (about mean + 1 steps, and
#: nearly always one comparison for a dark sky's pixel), at or above it by PTRS.
_SEARCH_MAX = 12.0
#: The detector's pixels are processed in chunks of this many (their charge and signal stay in
#: the L1 cache between the sources' loops).
_CHUNK = 2048


@njit(cache=True, nogil=True, inline="always")
def _settled(u, lam):
    """(u ≤ a lower bound of P(0) = e^(−lam): certainly 0; u inside bounds of (P(0), P(≤ 1)]:
    certainly 1) — the Taylor bounds 1 − λ + λ²/2 − λ³/6 ≤ e^(−λ) ≤ 1 − λ + λ²/2 and
    (1 + λ)e^(−λ) ≥ 1 − λ²/2 (its derivative λ(1 − e^(−λ)) ≥ 0), no exp: 98 % of the pixels of
    a 0.2 e⁻ sky."""
    above_one = 1.0 - lam + 0.5 * lam * lam
    zero = u <= above_one - lam * lam * lam / 6.0
    one = (above_one < u) & (u <= 1.0 - 0.5 * lam * lam)
    return zero, one


@njit(cache=True, nogil=True, inline="always")
def _certain(u, lam):
    """Poisson(lam) of the uniform u where bounds settle it without exp (:func:`_settled`): 0
    or 1; else -1."""
    zero, one = _settled(u, lam)
    return 0 if zero else (1 if one else -1)


@njit(cache=True, nogil=True)
def _invert_small(u, lam):
    # Poisson(lam) of the uniform u by sequential search of the CDF: about lam + 1 steps.
    k = _certain(u, lam)
    if k >= 0:
        return k
    p = math.exp(-lam)
    s = p
    k = 0
    while u > s and k < 1000:
        k += 1
        p *= lam / k
        s += p
    return k


@njit(cache=True, nogil=True)
def _ptrs(st, lam):
    """(Poisson(lam), lam >= 10, by Hörmann's transformed rejection (PTRS, 1993; numpy's
    ``random_poisson_ptrs``, the same constants) on the stream state ``st``: exact; the state
    after it)."""
    slam = math.sqrt(lam)
    loglam = math.log(lam)
    b = 0.931 + 2.53 * slam
    a = -0.059 + 0.02483 * b
    invalpha = 1.1239 + 1.1328 / (b - 3.4)
    vr = 0.9277 - 3.6224 / (b - 2.0)
    while True:
        uu, st = _uniform(st)
        uu -= 0.5
        v, st = _uniform(st)
        us = 0.5 - abs(uu)
        k = math.floor((2.0 * a / us + b) * uu + lam + 0.43)
        if us >= 0.07 and v <= vr:
            return k, st
        if k < 0 or (us < 0.013 and v > us):
            continue
        if (math.log(v) + math.log(invalpha) - math.log(a / (us * us) + b)
                <= -lam + k * loglam - math.lgamma(k + 1.0)):
            return k, st


@njit(cache=True, nogil=True, inline="always")
def _poisson(st, lam):
    """(Poisson(lam) from the stream state ``st``: one uniform inverted below _SEARCH_MAX, else
    PTRS; the state after it)."""
    if lam < _SEARCH_MAX:
        u, st = _uniform(st)
        k = _certain(u, lam)  # inline: a dark sky's pixel, settled in a comparison or two
        return (k if k >= 0 else _invert_small(u, lam)), st
    return _ptrs(st, lam)


@njit(cache=True, nogil=True)
def _poisson_chunk(e, u, size, st):
    """e[:size] (the means, float32) replaced by their Poisson draws from the stream state
    ``st``: a uniform each; the pixels that bounds settle (0 or 1: 98 % of them at a mean of
    0.2 e⁻, :func:`_settled`) without a branch; then the rest inverted (mean < 12) or by PTRS (fresh uniforms,
    after the chunk's). Returns the state after it."""
    for c in range(size):  # the stream alone: a tight loop
        u[c], st = _uniform(st)
    for c in range(size):  # no branch: vectorised
        v = u[c]
        m = np.float64(e[c])  # a mean >= 1.6 is never settled (its bounds < 0 <= v)
        zero, one = _settled(v, m)
        e[c] = np.float32(0.0) if zero else (np.float32(1.0) if one else m)
        u[c] = -1.0 if zero | one else v  # settled: marked by a negative u
    for c in range(size):
        if u[c] >= 0.0:
            m = np.float64(e[c])  # the CDF and PTRS in float64, as numpy's
            if m < _SEARCH_MAX:
                e[c] = _invert_small(u[c], m)
            else:
                k, st = _ptrs(st, m)
                e[c] = k
    return st


@njit(cache=True, nogil=True)
def _poisson_frame(lam, gain, scaled, state, out):
    """out = Poisson(lam·gain) (``lam`` when not ``scaled``; the product in float32) from the
    stream ``state``, a chunk at a time (:func:`_poisson_chunk`); returns how many means were
    negative or not finite (drawn as 0)."""
    p = lam.ravel()
    g = gain.ravel()
    o = out.ravel()
    e = np.empty(_CHUNK, np.float32)
    u = np.empty(_CHUNK, np.float64)
    st = _load(state)
    bad = 0
    for start in range(0, p.size, _CHUNK):
        size = min(_CHUNK, p.size - start)
        bad += _means(p, g, scaled, start, size, e)
        st = _poisson_chunk(e, u, size, st)
        o[start:start + size] = e[:size]
    _store(state, st)
    return bad


@njit(cache=True, nogil=True)
def _means(p, g, scaled, start, size, e):
    """e[:size] = p·g (``p`` when not ``scaled``; float32, as numpy multiplies two float32
    frames) from ``start``; a mean negative or not finite set to 0 and counted."""
    bad = 0
    for c in range(size):
        m = p[start + c] * g[start + c] if scaled else p[start + c]
        ok = m >= 0.0 and m < np.inf
        bad += not ok
        e[c] = m if ok else np.float32(0.0)
    return bad


def poisson_image(lam: np.ndarray, rng: np.random.Generator, gain: np.ndarray | None = None) -> np.ndarray:
    """Poisson draws (float32, same shape) with per-pixel means ``lam`` (electrons), or
    ``lam · gain`` (float32; a PRNU map, the product never stored).

    Exact Poisson, one pass, on a xoshiro256** stream seeded from ``rng``
    (:func:`stream_state`): a mean below 12 by inverting one uniform (a dark sky's pixel,
    mean < 1, is settled in one comparison nearly always), a larger one by PTRS.
    """
    lam = np.ascontiguousarray(lam, dtype=np.float32)
    out = np.empty(lam.shape, dtype=np.float32)
    scaled = gain is not None
    gain = np.ascontiguousarray(gain, dtype=np.float32) if scaled else np.ones((1, 1), np.float32)
    if scaled and gain.shape != lam.shape:
        raise SimulationError(f"gain map is {gain.shape}, the means {lam.shape}")
    if lam.size and _poisson_frame(lam, gain, scaled, stream_state(rng), out):
        raise SimulationError("expected electron counts must be finite and non-negative")
    return out


def poisson_constant(lam: float, shape: tuple[int, int], rng: np.random.Generator,
                     into: np.ndarray | None = None) -> np.ndarray:
    """Poisson draws (float32) with one mean ``lam`` for every pixel, exact; added to ``into``
    (float32, C-contiguous, in place: the same numbers as ``into + poisson_constant(…)``) and
    that returned, when given.

    A mean below 0.25 (a dark current of a fraction of an electron): the pixels that are not 0
    are found by geometric gaps between them (a pixel is not 0 with chance ``1 − e^(−lam)``,
    independently), each then drawn from the Poisson given ≥ 1 — about ``lam`` draws a pixel.
    Larger means: a draw a pixel (as :func:`poisson_image`). The detector's dark current is
    drawn so, inside its one pass.
    """
    out = np.zeros(shape, dtype=np.float32) if into is None else into
    if into is not None and not (into.dtype == np.float32 and into.shape == tuple(shape)
                                 and into.flags.c_contiguous):
        raise SimulationError("into must be a C-contiguous float32 frame of the shape")
    if lam <= 0 or out.size == 0:
        return out
    _poisson_constant(np.float32(lam), stream_state(rng), out)
    return out


#: Below this constant mean (a dark current of a fraction of an electron) the pixels that are
#: not 0 are found by exponential gaps between them instead of a draw a pixel.
_SPARSE_MAX = 0.25


@njit(cache=True, nogil=True, inline="always")
def _gap(st, lam):
    """(how many pixels of Poisson(lam) are 0 before the next that is not — geometric, with
    P(gap ≥ k) = e^(−k·lam): ⌊E / lam⌋ of an exponential E —, the state after it)."""
    u, st = _uniform(st)
    return np.int64(min(-math.log(1.0 - u) / lam, 4e18)), st


@njit(cache=True, nogil=True, inline="always")
def _nonzero(st, lam, p0):
    """(Poisson(lam) given ≥ 1 — a uniform mapped above P(0) = ``p0`` and inverted —, the state
    after it)."""
    u, st = _uniform(st)
    return _invert_small(p0 + u * (1.0 - p0), lam), st


@njit(cache=True, nogil=True)
def _poisson_constant(lam, state, out):
    o = out.ravel()
    st = _load(state)
    lam = np.float64(lam)
    if lam < _SPARSE_MAX:
        p0 = math.exp(-lam)
        i, st = _gap(st, lam)
        while i < o.size:
            k, st = _nonzero(st, lam, p0)
            o[i] += k
            g, st = _gap(st, lam)
            i += g + 1
    else:
        for i in range(o.size):
            k, st = _poisson(st, lam)
            o[i] += k
    _store(state, st)


# --- Gaussian deviates ------------------------------------------------------------------
# Marsaglia & Tsang's ziggurat (2000) in Doornik's form (ZIGNOR, 2005): 128 layers of equal area
# under the normal density; a deviate is one 64-bit word (the layer from its low 7 bits, the
# uniform from its top 53: no bit used twice), accepted in the layer's rectangle 98.8 % of the
# time; the wedges by the density itself, the tail beyond R by Marsaglia's exact method. Exact
# in distribution (to the 2^-53 resolution of its uniforms); the tables fit in the L1 cache.
_ZIG_LAYERS = 128
_ZIG_R = 3.442619855899  # the base layer's edge
_ZIG_V = 9.91256303526217e-3  # each layer's area


def _ziggurat_tables() -> tuple[np.ndarray, np.ndarray]:
    """The layers' right edges X (X[0] = V / f(R), X[1] = R, …, X[128] = 0) and X[i+1] / X[i]."""
    x = np.zeros(_ZIG_LAYERS + 1)
    f = math.exp(-0.5 * _ZIG_R**2)
    x[0], x[1] = _ZIG_V / f, _ZIG_R
    for i in range(2, _ZIG_LAYERS):
        x[i] = math.sqrt(-2.0 * math.log(_ZIG_V / x[i - 1] + f))
        f = math.exp(-0.5 * x[i] ** 2)
    return x, x[1:] / x[:-1]


_ZIG_X, _ZIG_RATIO = _ziggurat_tables()


@njit(cache=True, nogil=True, inline="always")
def _layer(word):
    """A word's layer (low 7 bits) and signed uniform in (−1, 1) (top 53 bits)."""
    return np.int64(word & _U64(_ZIG_LAYERS - 1)), 2.0 * (np.float64(word >> _U64(11)) * _TO_UNIT) - 1.0


@njit(cache=True, nogil=True)
def _normal_slow(st, i, u):
    """The ziggurat's rare paths for a word outside its layer's rectangle: the tail (layer 0),
    the wedge test, a new word; (the deviate, the state after it)."""
    while True:
        if i == 0:  # beyond R: Marsaglia's tail method
            while True:
                a, st = _uniform(st)
                b, st = _uniform(st)
                x = math.log(1.0 - a) / _ZIG_R
                if -2.0 * math.log(1.0 - b) >= x * x:
                    return (x - _ZIG_R if u < 0.0 else _ZIG_R - x), st
        x = u * _ZIG_X[i]
        f0 = math.exp(-0.5 * (_ZIG_X[i] * _ZIG_X[i] - x * x))
        f1 = math.exp(-0.5 * (_ZIG_X[i + 1] * _ZIG_X[i + 1] - x * x))
        v, st = _uniform(st)
        if f1 + v * (f0 - f1) < 1.0:
            return x, st
        word, st = _word(st)
        i, u = _layer(word)
        if abs(u) < _ZIG_RATIO[i]:
            return u * _ZIG_X[i], st


@njit(cache=True, nogil=True, inline="always")
def _normal(st):
    """(a standard normal deviate from the stream state ``st``, the state after it)."""
    word, st = _word(st)
    i, u = _layer(word)
    if abs(u) < _ZIG_RATIO[i]:
        return u * _ZIG_X[i], st
    return _normal_slow(st, i, u)


@njit(cache=True, nogil=True)
def _normals_chunk(z, size, st):
    """z[:size] = standard normal deviates (float32) from the stream state ``st`` (:func:`_normal`,
    one after another: the ziggurat in two passes, like the shot noise's, was slower). Returns
    the state after it."""
    for c in range(size):
        z[c], st = _normal(st)
    return st


@njit(cache=True, nogil=True)
def _fill_normals(state, out):
    z = np.empty(_CHUNK, np.float32)
    st = _load(state)
    for start in range(0, out.size, _CHUNK):
        size = min(_CHUNK, out.size - start)
        st = _normals_chunk(z, size, st)
        out[start:start + size] = z[:size]
    _store(state, st)


def standard_normals(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """float32 standard normal deviates by the ziggurat, on a xoshiro256** stream seeded from
    ``rng`` (:func:`stream_state`): what the detector's read and reset noise draw."""
    out = np.empty(shape, dtype=np.float32)
    _fill_normals(stream_state(rng), out.ravel())
    return out
