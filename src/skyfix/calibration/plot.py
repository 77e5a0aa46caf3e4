"""The residual quivers of a star calibration across the frame: before (the uncalibrated pinhole)
and after (the calibrated camera), every image's stars on one frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skyfix.calibration.stars import StarCalibration

__all__ = ["plot_residuals"]


def plot_residuals(calibration: StarCalibration, path: str | Path, *, dpi: int = 100) -> None:
    """Write a PNG of two panels: each star's residual (model − measured, px) as an arrow at its
    place on the frame, before and after; each panel's arrows scaled to its own largest."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cam = calibration.camera
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2), dpi=dpi)
    for ax, fit, title in ((axes[0], calibration.before, "before: uncalibrated pinhole"),
                           (axes[1], calibration.fit, "after: " + calibration.model)):
        xy, res = [], []
        for r, k, m in zip(fit.residuals_px, fit.inliers, fit.xy, strict=True):
            xy.append(m[k])
            res.append(r[k])
        xy, res = np.concatenate(xy), np.concatenate(res)
        longest = float(np.percentile(np.hypot(*res.T), 99)) or 1.0
        scale = 0.06 * cam.width / longest  # the 99th percentile arrow is 6 % of the frame wide
        ax.quiver(xy[:, 0], xy[:, 1], res[:, 0] * scale, res[:, 1] * scale, angles="xy", scale_units="xy",
                  scale=1.0, width=0.002)
        ax.set_xlim(-0.5, cam.width - 0.5)
        ax.set_ylim(cam.height - 0.5, -0.5)
        ax.set_aspect("equal")
        rms = float(np.sqrt(np.mean(np.sum(res**2, axis=1))))
        ax.set_title(f"{title}\nRMS {rms:.3f} px, arrow of {longest:.3g} px = {0.06 * cam.width:.0f} px")
        ax.plot([cam.cx], [cam.cy], "r+", markersize=12)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)

