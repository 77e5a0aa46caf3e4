"""Pictures of results: the image with its identified stars circled and labelled."""

from __future__ import annotations

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
