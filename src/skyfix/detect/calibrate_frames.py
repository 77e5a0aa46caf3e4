"""Frame calibration: master dark and flat from stacks, hot/dead pixel maps, and their use.

Order of application (documented, and what :func:`calibrate_frame` does):

1. **dark**: subtract the master dark (bias + dark current at the same exposure and
   temperature);
2. **flat**: divide by the master flat, normalised to a median of 1 (vignetting and PRNU);
3. **bad pixels**: replace hot and dead pixels by the median of their good 8-neighbours.

Hot pixels follow thesis 000 (§3.5): a pixel of the master dark more than ``nsigma`` (5)
robust standard deviations above the dark's median. Dead pixels are those whose flat response
is outside ``[low, high]`` (default 0.5–1.5) of the median.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from skyfix.detect._stats import robust_level_noise
from skyfix.errors import ImageReadError, unknown_name
from skyfix.io import read_image

__all__ = [
    "COMBINES", "master_frame", "master_dark", "master_flat", "hot_pixel_map", "dead_pixel_map",
    "calibrate_frame", "repair_pixels", "dark_report", "save_calibration", "load_calibration",
]


def _stack(frames: Iterable[np.ndarray] | np.ndarray) -> np.ndarray:
    if isinstance(frames, np.ndarray) and frames.ndim == 3:
        stack = frames.astype(np.float32, copy=False)
    else:
        frames = list(frames)
        images = [read_image(f) for f in frames]
        for f, img in zip(frames, images, strict=True):
            if img.shape != images[0].shape:
                (h, w), (h0, w0) = img.shape, images[0].shape
                raise ImageReadError(f"{_label(f, frames)}: {w}×{h} pixels, but {_label(frames[0], frames)} "
                                     f"is {w0}×{h0}: a stack needs frames of one size")
        stack = np.stack(images).astype(np.float32, copy=False) if images else np.zeros((0, 0, 0), np.float32)
    if stack.ndim != 3 or stack.shape[0] == 0:
        raise ImageReadError("a calibration stack needs at least one 2-D frame")
    return stack


def _label(frame: object, frames: list) -> str:
    """A frame's file name, or its place in the stack for an array."""
    if isinstance(frame, (str, Path)):
        return str(frame)
    return f"frame {next(i for i, f in enumerate(frames) if f is frame)}"


def master_frame(frames: Iterable[np.ndarray | str | Path] | np.ndarray, *, combine: str = "clipped_mean",
                 clip_sigma: float = 3.0) -> np.ndarray:
    """Combine a stack of frames pixel by pixel.

    Parameters
    ----------
    frames : (N, H, W) array, or an iterable of 2-D arrays or image paths
        The exposures (all the same size).
    combine : {"clipped_mean", "median", "mean"}
        ``"clipped_mean"``: mean of the values within ``clip_sigma`` robust σ (1.4826·MAD over the
        stack) of the pixel's median — cosmic rays and satellite trails drop out, the noise
        stays that of a mean. Falls back to the median for fewer than 3 frames.
    clip_sigma : float
        Clip half-width for ``"clipped_mean"``, in robust σ.

    Returns
    -------
    ndarray of float32, shape (H, W)
    """
    if not isinstance(combine, str) or combine not in COMBINES:
        raise unknown_name("combine", combine, COMBINES)
    return COMBINES[combine](_stack(frames), clip_sigma)


def _mean(stack: np.ndarray, clip_sigma: float) -> np.ndarray:
    return stack.mean(axis=0, dtype=np.float64).astype(np.float32)


def _median(stack: np.ndarray, clip_sigma: float) -> np.ndarray:
    return np.median(stack, axis=0).astype(np.float32)


def _clipped_mean(stack: np.ndarray, clip_sigma: float) -> np.ndarray:
    med = np.median(stack, axis=0)
    if stack.shape[0] < 3:
        return med.astype(np.float32)
    mad = np.median(np.abs(stack - med), axis=0)
    # quantised stacks have MAD 0 on quiet pixels: clip no tighter than one level there
    lim = clip_sigma * np.where(mad > 0, 1.4826 * mad, 1.0)
    keep = np.abs(stack - med) <= lim
    n = keep.sum(axis=0)
    total = np.where(keep, stack, 0.0).sum(axis=0, dtype=np.float64)
    return np.where(n > 0, total / np.maximum(n, 1), med).astype(np.float32)


#: Ways to combine a stack pixel by pixel, by name (``combine=`` of :func:`master_frame`).
COMBINES = {"clipped_mean": _clipped_mean, "median": _median, "mean": _mean}


def master_dark(darks: Iterable[np.ndarray | str | Path] | np.ndarray, **kw) -> np.ndarray:
    """Master dark (bias + dark current), ADU: :func:`master_frame` of the dark exposures."""
    return master_frame(darks, **kw)


def master_flat(flats: Iterable[np.ndarray | str | Path] | np.ndarray, dark: np.ndarray | None = None,
                **kw) -> np.ndarray:
    """Master flat normalised to a median of 1: ``(combine(flats) − dark) / median``.

    Pixels with no response (≤ 0 after the dark) are set to 1 so that dividing by the flat
    never makes infinities; :func:`dead_pixel_map` finds them for repair.
    """
    flat = master_frame(flats, **kw).astype(np.float64)
    if dark is not None:
        flat = flat - dark
    med = np.median(flat[flat > 0]) if np.any(flat > 0) else 0.0
    if not med > 0:
        raise ImageReadError("the flat frames have no signal above the dark")
    flat = flat / med
    return np.where(flat > 0, flat, 1.0).astype(np.float32)


def hot_pixel_map(dark: np.ndarray, nsigma: float = 5.0) -> np.ndarray:
    """Pixels of a master dark more than ``nsigma`` robust σ above its median (thesis 000)."""
    d = np.asarray(dark, dtype=np.float64)
    sample = d[:: max(1, d.shape[0] // 256), :: max(1, d.shape[1] // 256)].ravel()
    quantum = 1.0 if np.all(sample == np.floor(sample)) else 0.0
    level, sigma = robust_level_noise(sample.copy(), quantum, False)
    return d > level + nsigma * max(sigma, 1e-12)


def dead_pixel_map(flat: np.ndarray, low: float = 0.5, high: float = 1.5) -> np.ndarray:
    """Pixels of a normalised master flat whose response is outside ``[low, high]``."""
    f = np.asarray(flat, dtype=np.float64)
    return (f < low) | (f > high)


def repair_pixels(image: np.ndarray, bad: np.ndarray) -> np.ndarray:
    """Replace the pixels marked ``bad`` by the median of their good 8-neighbours (new array).

    A bad pixel with no good neighbour takes the frame's median.
    """
    img = np.array(image, dtype=np.float32, copy=True)
    bad = np.asarray(bad, dtype=bool)
    if bad.shape != img.shape:
        raise ValueError(f"bad-pixel map {bad.shape} does not match the image {img.shape}")
    ys, xs = np.nonzero(bad)
    if ys.size == 0:
        return img
    h, w = img.shape
    dy = np.array([-1, -1, -1, 0, 0, 1, 1, 1])
    dx = np.array([-1, 0, 1, -1, 1, -1, 0, 1])
    ny = ys[:, None] + dy
    nx = xs[:, None] + dx
    inside = (ny >= 0) & (ny < h) & (nx >= 0) & (nx < w)
    nyc, nxc = np.clip(ny, 0, h - 1), np.clip(nx, 0, w - 1)
    vals = np.where(inside & ~bad[nyc, nxc], image[nyc, nxc], np.nan).astype(np.float64)
    good_any = np.isfinite(vals).any(axis=1)
    fill = np.full(ys.size, float(np.median(img[~bad])) if np.any(~bad) else 0.0)
    fill[good_any] = np.nanmedian(vals[good_any], axis=1)
    img[ys, xs] = fill
    return img


def calibrate_frame(image: np.ndarray, *, dark: np.ndarray | None = None, flat: np.ndarray | None = None,
                    bad_pixels: np.ndarray | None = None) -> np.ndarray:
    """Apply dark → flat → bad-pixel repair to one frame; float32 (H, W), ADU.

    Parameters
    ----------
    image : (H, W) array
    dark : (H, W) array, optional
        Master dark at the frame's exposure (:func:`master_dark`).
    flat : (H, W) array, optional
        Normalised master flat (:func:`master_flat`).
    bad_pixels : (H, W) bool array, optional
        Hot and dead pixels (:func:`hot_pixel_map` | :func:`dead_pixel_map`).
    """
    img = np.asarray(image, dtype=np.float32)
    for name, arr in (("dark", dark), ("flat", flat), ("bad-pixel map", bad_pixels)):
        if arr is not None and np.shape(arr) != img.shape:
            raise ImageReadError(f"{name} of shape {np.shape(arr)} does not match the image {img.shape}")
    out = img.astype(np.float32, copy=True)
    if dark is not None:
        out -= np.asarray(dark, dtype=np.float32)
    if flat is not None:
        out /= np.asarray(flat, dtype=np.float32)
    if bad_pixels is not None:
        out = repair_pixels(out, bad_pixels)
    return out


def dark_report(darks_by_exposure: Mapping[float, Iterable[np.ndarray | str | Path] | np.ndarray],
                nsigma: float = 5.0) -> list[dict]:
    """Dark level and hot-pixel count per exposure (like thesis 000 Table 5).

    Returns one dict per exposure, sorted by exposure (NaN, unknown, last): ``exposure_s``, ``n_frames``,
    ``dark_level_adu`` (median of the master dark), ``dark_noise_adu`` (temporal noise of one
    frame, from the first frame minus the master; NaN for a single frame), ``dsnu_adu`` (robust
    spatial σ of the master dark less its own temporal noise) and ``hot_pixels`` (count,
    ``nsigma`` rule).
    """
    rows = []
    for exposure in sorted(darks_by_exposure, key=lambda e: (math.isnan(e), e)):  # unknown (NaN) last
        stack = _stack(darks_by_exposure[exposure])
        master = master_frame(stack)
        hot = hot_pixel_map(master, nsigma)
        good = master[~hot].astype(np.float64)
        _, dsnu = robust_level_noise(good[:: max(1, good.size // 65536)].copy(), 0.0, False)
        n = stack.shape[0]
        diff = (stack[0] - master)[~hot].astype(np.float64)
        _, temporal = robust_level_noise(diff[:: max(1, diff.size // 65536)].copy(), 0.0, False)
        # the master contains the frame: frame − master has variance σ²·(1 − 1/n)
        temporal = temporal * np.sqrt(n / (n - 1)) if n > 1 else float("nan")
        if n > 1:  # the master still carries σ²/n of temporal noise
            dsnu = np.sqrt(max(dsnu**2 - temporal**2 / n, 0.0))
        rows.append({"exposure_s": float(exposure), "n_frames": int(n),
                     "dark_level_adu": float(np.median(master)), "dark_noise_adu": float(temporal),
                     "dsnu_adu": float(dsnu), "hot_pixels": int(hot.sum())})
    return rows


def save_calibration(path: str | Path, *, dark: np.ndarray | None = None, flat: np.ndarray | None = None,
                     bad_pixels: np.ndarray | None = None) -> None:
    """Write the maps to a ``.npz`` or a multi-extension ``.fits`` (DARK, FLAT, BADPIX)."""
    path = Path(path)
    maps = {k: v for k, v in (("dark", dark), ("flat", flat), ("bad_pixels", bad_pixels)) if v is not None}
    if path.suffix.lower() in (".fits", ".fit", ".fts"):
        from astropy.io import fits

        hdus = [fits.PrimaryHDU()]
        names = {"dark": "DARK", "flat": "FLAT", "bad_pixels": "BADPIX"}
        for k, v in maps.items():
            data = v.astype(np.uint8) if k == "bad_pixels" else np.asarray(v, np.float32)
            hdus.append(fits.ImageHDU(data, name=names[k]))
        fits.HDUList(hdus).writeto(path, overwrite=True)
    else:
        np.savez_compressed(path, **{k: np.asarray(v) for k, v in maps.items()})


def load_calibration(path: str | Path) -> dict[str, np.ndarray]:
    """Read maps written by :func:`save_calibration`: keys ``dark``, ``flat``, ``bad_pixels``."""
    path = Path(path)
    if not path.exists():
        raise ImageReadError(f"{path}: no such calibration file")
    try:
        if path.suffix.lower() in (".fits", ".fit", ".fts"):
            from astropy.io import fits

            out = {}
            with fits.open(path) as hdul:
                for key, name in (("dark", "DARK"), ("flat", "FLAT"), ("bad_pixels", "BADPIX")):
                    if name in hdul:
                        data = np.array(hdul[name].data)
                        out[key] = data.astype(bool) if key == "bad_pixels" else data.astype(np.float32)
            return out
        with np.load(path) as z:
            return {k: (z[k].astype(bool) if k == "bad_pixels" else z[k].astype(np.float32)) for k in z.files}
    except ImageReadError:
        raise
    except Exception as exc:
        raise ImageReadError(f"{path}: unreadable calibration file ({type(exc).__name__})") from None
