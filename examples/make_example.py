"""Regenerate examples/sky.png, the bundled sky image, with skyfix's own simulator.

A generic 1280×960 CMOS camera with a 16 mm lens (~17° wide) pointed at Orion, 0.1 s,
every detector noise source on, a little lens distortion, two false stars and a few hot
pixels. The truth is written beside it (examples/sky.truth.json).

    python examples/make_example.py
"""

from pathlib import Path

import numpy as np

from skyfix.camera import camera_from_preset
from skyfix.geometry import attitude_from_radec_roll
from skyfix.simulate import render, write_frame

HERE = Path(__file__).parent


def main() -> None:
    camera = camera_from_preset("generic").replace(k1=-0.05, name="generic CMOS, 16 mm, mild barrel")
    A = attitude_from_radec_roll(np.radians(84.0), np.radians(-2.0), np.radians(20.0))
    frame = render(A, camera, sensor="generic", optics="generic", exposure_s=0.1, epoch="2026-01-15T03:00:00",
                   seed=2026, false_stars=2, hot_pixels=20, cosmic_rays=1)
    write_frame(frame, HERE / "sky.png")
    camera.save(HERE / "sky.camera.toml")


if __name__ == "__main__":
    main()
