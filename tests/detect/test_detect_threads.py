"""The extraction's stages split between the calling thread and a helper (skyfix.detect._threads):
every result bit for bit the same whatever the bands, the threads, and who ran which chunk."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from skyfix.detect import _threads, background, extract_centroids, labelling
from skyfix.detect.components import _workspace


def _field(seed: int, h: int = 300, w: int = 410, n: int = 60) -> np.ndarray:
    """Stars on a sky with a gradient, noise and a few blobs wide enough to cross band edges."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    img = 200.0 + 120.0 * yy / h + rng.normal(0.0, 5.0, (h, w))
    xs, ys, fluxes = rng.uniform(3, w - 3, n), rng.uniform(3, h - 3, n), 10 ** rng.uniform(2.8, 4.6, n)
    for x0, y0, f, s in zip(xs, ys, fluxes, rng.choice([1.0, 1.3, 6.0], n), strict=True):
        img += f / (2 * np.pi * s * s) * np.exp(-((xx - x0) ** 2 + (yy - y0) ** 2) / (2 * s * s))
    return np.clip(np.round(img), 0, 4095).astype(np.float32)


def _everything(img: np.ndarray) -> dict[str, np.ndarray]:
    bg = background.estimate_background(img)
    c = extract_centroids(img, max_stars=10_000)
    out = {f"bg.{k}": np.asarray(getattr(bg, k)) for k in ("level", "noise", "level_smooth", "noise_smooth")}
    out.update({f"c.{k}": np.asarray(getattr(c, k)) for k in ("x", "y", "flux", "snr", "area", "peak",
                                                              "sigma_x", "elongation", "angle")})
    out["labels"] = _workspace(*img.shape).frames.labels.copy()
    out["n_components"] = np.array(c.meta["n_components"])
    return out


@pytest.mark.parametrize("parts", [1, 2, 3, 7])
def test_bands_and_threads_do_not_change_a_bit(monkeypatch, parts):
    """The background's tile rows and the frame's rows cut into 1–7 bands (the production cut is
    one or two), run by the helper thread or not: background, labels, components and centroids
    equal those of one band in one thread, bit for bit."""
    frames = [_field(seed) for seed in (1, 2)]
    monkeypatch.setenv("SKYFIX_THREADS", "1")
    ref = [_everything(f) for f in frames]
    cut = {}

    def split(n: int, least: int) -> list[int]:
        cut[n] = _threads.bands(n, parts)
        return cut[n]

    monkeypatch.setattr(background, "split", split)
    monkeypatch.setattr(labelling, "split", split)
    for threads in ("1", ""):
        monkeypatch.setenv("SKYFIX_THREADS", threads)
        for frame, want in zip(frames, ref, strict=True):
            got = _everything(frame)
            assert want["c.x"].size > 20 and int(want["n_components"]) > 30
            for key, value in want.items():
                np.testing.assert_array_equal(got[key], value, err_msg=key)
    assert len(cut[300]) == min(parts, 300) + 1  # the frame's rows were cut as asked


def test_components_crossing_band_edges_are_joined():
    """A frame whose blobs cross every edge of 7 bands of rows: each component once, with the
    area, box and sums of one band's labelling."""
    from skyfix.detect._grid import sky_grid

    img = _field(5)
    h, w = img.shape
    bg = background.estimate_background(img)
    sky = sky_grid(bg, (h, w))
    thr = bg.level_smooth + 5.0 * bg.noise_smooth
    frames = _workspace(h, w).frames
    found = labelling.smooth_threshold(img, thr, sky, frames)
    frames.labels.fill(0)
    one = labelling.label_components(img, frames, sky, labelling.MAX_COMPONENTS)
    labels_one = frames.labels.copy()
    edges = _threads.bands(h, 7)
    parts = [labelling._band_runs(img, frames, sky, edges[i], edges[i + 1]) for i in range(7)]
    runs, starts = labelling._joined(parts)
    crossing = sum(int(np.any((frames.mask[e - 1, :w] > 0) & (frames.mask[e, :w] > 0))) for e in edges[1:-1])
    assert crossing >= 3
    frames.labels.fill(0)
    banded = labelling.label_components(img, frames, sky, labelling.MAX_COMPONENTS,
                                        found._replace(runs=runs, starts=starts))
    np.testing.assert_array_equal(frames.labels, labels_one)
    np.testing.assert_array_equal(banded, one)


def test_run_chunks_shares_the_work_and_keeps_the_order(monkeypatch):
    monkeypatch.setenv("SKYFIX_THREADS", "")
    if not _threads.threads_enabled():
        pytest.skip("one CPU for this process")
    monkeypatch.setattr(_threads, "_PAYS", 0.0)  # every call hands chunks over (the chunks sleep)
    monkeypatch.setattr(_threads, "_PACE", _threads._Pace())
    who: list[int] = []

    def work(i: int) -> int:
        who.append(threading.get_ident())
        time.sleep(0.002)  # releases the GIL, as a nogil kernel does
        return i * i

    for _ in range(20):
        assert _threads.run_chunks(work, 4) == [0, 1, 4, 9]
    assert threading.get_ident() in who
    assert len(set(who)) == 2  # the helper took chunks too
    monkeypatch.setenv("SKYFIX_THREADS", "1")
    who.clear()
    assert _threads.run_chunks(work, 3) == [0, 1, 4]
    assert set(who) == {threading.get_ident()}


def test_a_chunk_that_fails_raises_in_the_caller(monkeypatch):
    monkeypatch.setenv("SKYFIX_THREADS", "")

    def work(i: int) -> int:
        time.sleep(0.001)
        if i == 2:
            raise ValueError("chunk 2")
        return i

    for _ in range(5):
        with pytest.raises(ValueError, match="chunk 2"):
            _threads.run_chunks(work, 6)
    assert _threads.run_chunks(lambda i: i, 3) == [0, 1, 2]  # the helper serves the next call


def test_a_split_that_does_not_pay_backs_off(monkeypatch):
    """After a call that ran fewer than 1.3 chunks at once, the next 1, then 2, 4 … calls (at
    most 64) run in the caller alone; a call that paid ends the back-off."""
    monkeypatch.setenv("SKYFIX_THREADS", "")
    if not _threads.threads_enabled():
        pytest.skip("one CPU for this process")
    pace = _threads._Pace()
    monkeypatch.setattr(_threads, "_PACE", pace)
    monkeypatch.setattr(_threads, "_PAYS", 1e9)  # nothing pays
    handed = []
    for _ in range(12):
        skipping = pace.skip > 0
        _threads.run_chunks(lambda i: i, 2)
        handed.append(not skipping)
    # handed over, then 1 call alone, handed, 2 alone, handed, 4 alone, handed …
    assert handed == [True, False, True, False, False, True, False, False, False, False, True, False]
    assert pace.backoff == 8
    monkeypatch.setattr(_threads, "_PAYS", 0.0)  # everything pays
    pace.skip = 0
    _threads.run_chunks(lambda i: i, 2)
    assert pace.backoff == 0 and pace.skip == 0


def test_split_and_bands():
    assert _threads.bands(10, 3) == [0, 3, 7, 10]
    assert _threads.bands(2, 5) == [0, 1, 2]
    assert _threads.bands(5, 0) == [0, 5]
    assert all(len(_threads.split(n, 100)) == 2 for n in (1, 99, 199))
