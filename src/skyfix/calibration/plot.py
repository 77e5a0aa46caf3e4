"""The residual quivers of a star calibration across the frame: before (the uncalibrated pinhole)
and after (the calibrated camera), every image's stars on one frame; a checkerboard calibration's
reprojection errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skyfix.calibration.checkerboard import BoardCalibration
from skyfix.calibration.stars import StarCalibration

__all__ = ["plot_reprojection", "plot_residuals"]


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



def plot_reprojection(calibration: BoardCalibration, path: str | Path, *, dpi: int = 100) -> None:
    """Write a PNG of a checkerboard calibration's reprojection errors: each corner's residual
    (measured − model, px) as a point, one colour an image (thesis 003's scatter, where an image
    outside the main cluster shows), and as an arrow at its place on the frame."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cam = calibration.camera
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2), dpi=dpi, gridspec_kw={"width_ratios": [1, 1.6]})
    for name, r, rms in zip(calibration.names, calibration.residuals_px, calibration.rms_px(), strict=True):
        axes[0].plot(r[:, 0], r[:, 1], ".", markersize=3, label=f"{Path(name).name} {rms:.3f} px")
    axes[0].set_aspect("equal")
    axes[0].set_xlabel("x residual, px")
    axes[0].set_ylabel("y residual, px")
    sx, sy = calibration.pixel_error_px
    axes[0].set_title(f"reprojection error: std ({sx:.3f}, {sy:.3f}) px, {len(calibration.names)} images")
    if len(calibration.names) <= 20:
        axes[0].legend(fontsize=6, markerscale=2)
    xy, res = np.concatenate(calibration.corners), np.concatenate(calibration.residuals_px)
    longest = float(np.percentile(np.hypot(*res.T), 99)) or 1.0
    scale = 0.06 * cam.width / longest
    axes[1].quiver(xy[:, 0], xy[:, 1], res[:, 0] * scale, res[:, 1] * scale, angles="xy", scale_units="xy",
                   scale=1.0, width=0.002)
    axes[1].set_xlim(-0.5, cam.width - 0.5)
    axes[1].set_ylim(cam.height - 0.5, -0.5)
    axes[1].set_aspect("equal")
    axes[1].plot([cam.cx], [cam.cy], "r+", markersize=12)
    axes[1].set_title(f"residuals across the frame ({calibration.model}); arrow of {longest:.3g} px = "
                      f"{0.06 * cam.width:.0f} px")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
