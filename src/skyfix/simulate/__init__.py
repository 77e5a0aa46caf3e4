"""Star-image simulator: attitude → catalogue stars → camera model → PSF → sensor → image + truth.

Thesis 002 ch. 3, corrected (docs/seeds.md#thesis-002-corrections): PSF covariance ``diag(σ², σ²)``, pixel
integration instead of point sampling, Poisson shot and dark noise, stray light spread over the
frame, full-well clipping, rolling shutter and continuous smear.

>>> from skyfix.geometry import attitude_from_radec_roll
>>> from skyfix.simulate import render, write_frame
>>> A = attitude_from_radec_roll(1.4, 0.1, 0.0)
>>> frame = render(A, "has2", exposure_s=0.1, epoch=2025.0, seed=1)   # doctest: +SKIP
>>> write_frame(frame, "sim.fits")                                     # doctest: +SKIP

Sequences: :func:`render_sequence` with an attitude profile (:data:`PROFILES`: constant,
inertial-axis, slew, pendulum), each frame's truth holding its attitude, rate and time.
"""

from skyfix.simulate.motion import attitude_at
from skyfix.simulate.optics import Optics
from skyfix.simulate.photometry import sky_electrons_per_pixel, star_electrons
from skyfix.simulate.presets import load_preset, preset_names
from skyfix.simulate.profiles import PROFILES, Profile, make_profile
from skyfix.simulate.render import SimulatedFrame, render, resolve_setup
from skyfix.simulate.sensor import NOISE_SOURCES, Sensor, conversion_gain_e_per_adu
from skyfix.simulate.sequence import render_sequence
from skyfix.simulate.truth import read_truth, truth_path, write_frame

__all__ = [
    "Sensor",
    "Optics",
    "SimulatedFrame",
    "render",
    "render_sequence",
    "PROFILES",
    "Profile",
    "make_profile",
    "write_frame",
    "read_truth",
    "truth_path",
    "resolve_setup",
    "attitude_at",
    "star_electrons",
    "sky_electrons_per_pixel",
    "conversion_gain_e_per_adu",
    "load_preset",
    "preset_names",
    "NOISE_SOURCES",
]
