"""Pictures of results: the image with its identified stars circled and labelled, and the RA/Dec
grid of a solved frame.

The grid is drawn against the catalogue places (:meth:`skyfix.solution.Solution.radec_of_pixels`:
``A_apparent_to_cam``, the WCS's mapping), so each circled star sits at its catalogue RA/Dec on it,
as a plate solver's user expects; the numbers in the caption are the reported ones (the one-line
summary's and the JSON's: the true attitude when an observation time corrected the stars, which
the caption then says).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from skyfix.solution import Solution

__all__ = ["plot_solution"]


def _display_stretch(image: np.ndarray) -> np.ndarray:
    """Map to [0, 1] with a robust asinh stretch so faint stars and bright ones both show."""
    lo, hi = np.percentile(image, [50.0, 99.9])
    scaled = np.clip((image - lo) / max(hi - lo, 1e-9), 0.0, None)
    return np.arcsinh(10.0 * scaled) / np.arcsinh(10.0)


def plot_solution(image: np.ndarray, solution: Solution, path: str | Path, *, dpi: int = 100) -> None:
    """Write a PNG of ``image`` with each matched star circled and labelled ``HIP n``.

    Parameters
    ----------
    image : (H, W) array
        The image that was solved.
    solution : Solution
        Its solution; a failed one is drawn with its reason as the title.
    path : path
        Output PNG.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    h, w = image.shape
    fig = plt.figure(figsize=(w / dpi, h / dpi), dpi=dpi)
    ax = fig.add_axes((0, 0, 1, 1))
    # extent puts pixel centres at integer coordinates (docs/design.md#pixel-coordinates).
    ax.imshow(_display_stretch(image), cmap="gray", origin="upper", extent=(-0.5, w - 0.5, h - 0.5, -0.5))
    if solution.solved:
        _radec_grid(ax, solution, w, h)
    radius = max(6.0, 0.012 * max(w, h))
    for m in solution.matches:
        ax.add_patch(plt.Circle((m.x, m.y), radius, fill=False, color="#35d435", lw=1.2))
        ax.annotate(f"HIP {m.id}", (m.x + radius, m.y - radius), color="#ffd43b",
                    fontsize=max(6, min(10, w // 120)))
    if solution.solved:
        # The image centre's numbers, as the one-line summary and other solvers give them; the
        # boresight (principal point) marked and named where the stars put it elsewhere.
        title = (f"centre RA {solution.center_ra_deg:.4f}°  Dec {solution.center_dec_deg:+.4f}°  "
                 f"roll {solution.center_roll_deg:.2f}°\nFOV {solution.fov_deg:.2f}°  "
                 f"{solution.n_matched} stars  rmse {solution.rmse_arcsec:.1f}″")
        if solution.attitude_frame == "ICRS" and solution.time:
            title += "  (true attitude, ICRS; grid: catalogue places)"
        bx, by = solution.boresight_px
        if solution.boresight_off_centre:
            ax.plot([bx], [by], marker="+", markersize=2 * radius, color="#ff6b6b", mew=1.5)
            title += (f"\nboresight (+) at ({bx:.0f}, {by:.0f}): RA {solution.ra_deg:.4f}° "
                      f"Dec {solution.dec_deg:+.4f}°")
    else:
        title = f"failed: {solution.reason}"
    ax.text(0.01, 0.01, title, transform=ax.transAxes, color="white", fontsize=9,
            va="bottom", ha="left", bbox=dict(facecolor="black", alpha=0.6, lw=0))
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.axis("off")
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def _grid_step(span_deg: float) -> float:
    """A round grid step (degrees) giving a few lines over ``span_deg``."""
    for step in (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 15.0, 30.0):
        if span_deg / step <= 6:
            return step
    return 45.0


def _radec_grid(ax, solution: Solution, w: int, h: int) -> None:
    """Lines of constant Dec and RA (relative to the centre's, so that the 0/360° seam draws no
    line) over the frame, from :meth:`Solution.radec_of_pixels` on a coarse mesh."""
    xs, ys = np.linspace(-0.5, w - 0.5, 64), np.linspace(-0.5, h - 0.5, 48)
    gx, gy = np.meshgrid(xs, ys)
    radec = solution.radec_of_pixels(np.column_stack([gx.ravel(), gy.ravel()]))
    ra0 = solution.radec_of_pixel((w - 1) / 2.0, (h - 1) / 2.0)[0]
    d_ra = ((radec[:, 0] - ra0 + 180.0) % 360.0 - 180.0).reshape(gx.shape)
    dec = radec[:, 1].reshape(gx.shape)
    style = dict(colors="#4dabf7", linewidths=0.6, alpha=0.7)
    step = _grid_step(float(np.ptp(dec)))
    levels = np.arange(math.floor(dec.min() / step), math.ceil(dec.max() / step) + 1) * step
    ax.contour(gx, gy, dec, levels=levels, **style)
    ra_step = _grid_step(float(np.ptp(d_ra)))
    first = math.floor((ra0 + d_ra.min()) / ra_step) * ra_step
    levels = np.arange(first, ra0 + d_ra.max() + ra_step, ra_step) - ra0
    ax.contour(gx, gy, d_ra, levels=np.unique(levels), **style)
