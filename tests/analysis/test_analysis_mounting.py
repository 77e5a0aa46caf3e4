"""``skyfix analyze mounting IMAGES… --site``: a camera fixed on the ground, a night of rendered
frames with their DATE-OBS, solved at the site at each one's time and averaged into its mounting
(camera → ENU), against the mounting they were rendered with (thesis 003 §2.9–2.10)."""

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from skyfix.attitude import attitude_error
from skyfix.camera import Camera
from skyfix.cli import app
from skyfix.corrections.observation import observe
from skyfix.frames import matrix_from_euler123
from skyfix.geometry import attitude_from_quaternion
from skyfix.obstime import later, parse_time

pytestmark = pytest.mark.filterwarnings("ignore::erfa.ErfaWarning")
runner = CliRunner()
SITE = "-30.24,-70.74,2200"  # Cerro Pachón
START = parse_time("2026-05-01T01:00:00Z")


def test_a_night_of_frames_gives_the_mounting(tmp_path):
    """Four 8° frames two hours apart of a camera fixed 10° from the zenith, rendered with the
    stars' aberration (the site's and the Earth's velocity, ERFA's) and no refraction (6.6 hPa: a
    near-vacuum): the mounting within 1″, the images' scatter about it under 1″."""
    from skyfix.corrections import earth_state
    from skyfix.simulate import render
    from skyfix.simulate.optics import Optics
    from skyfix.simulate.truth import write_frame

    cam = Camera.from_fov(1280, 960, 8.0)
    camera_file = tmp_path / "camera.toml"
    camera_file.write_text(cam.to_toml())
    # camera axes in ENU: the boresight 10° from the zenith toward the north, rolled
    A_cam_to_enu = matrix_from_euler123(math.radians(10.0), 0.0, math.radians(30.0)).T
    paths = []
    for k in range(4):
        t = later(START, 7200.0 * k)
        frame_obs = observe(t, site=SITE, weather="10,6.6,0.0")
        A = A_cam_to_enu.T @ frame_obs.ground.A_icrs_to_enu  # the physical attitude at t
        v_site = np.asarray(frame_obs.ground.velocity_c) * 299792.458
        frame = render(A, cam, optics=Optics(aperture_mm=25.0, throughput=0.8, psf_fwhm_px=2.0),
                       exposure_s=0.2, epoch=t.iso, observer_velocity_km_s=v_site, seed=k)
        assert np.linalg.norm(v_site - earth_state(t.jd_tt).velocity_km_s) < 0.5  # the site's own: 0.4 km/s
        paths.append(tmp_path / f"night-{k}.fits")
        write_frame(frame, paths[-1])
    result = runner.invoke(app, ["analyze", "mounting", *map(str, paths), "--site", SITE, "--weather",
                                 "10,6.6,0.0", "--camera", str(camera_file), "--json"])
    assert result.exit_code == 0, result.output
    lines = [json.loads(line) for line in result.stdout.splitlines()]
    assert len(lines) == 5 and all(abs(r["alt_deg"] - 80.0) < 0.01 for r in lines[:4])
    est = lines[-1]
    A_est = attitude_from_quaternion(est["quaternion_xyzw"])
    # the rotation from the truth about the camera's axes: across the boresight, and the roll
    err = attitude_error(A_est.T, A_cam_to_enu.T) * 180 / math.pi * 3600
    cross, roll = math.hypot(err[0], err[1]), float(err[2])
    boresight = A_cam_to_enu[:, 2]
    sigma = np.sqrt(np.diag(est["covariance_arcsec2"]))
    print(f"mounting off the truth: boresight {cross:.2f}″, roll {roll:+.2f}″; its error bars (E, N, up) "
          f"{sigma.round(2).tolist()}″, standard error {est['standard_error_arcsec']:.2f}″")
    assert cross < 1.0  # an 8° field pins its roll to a few arcseconds only
    assert abs(roll) < 3.0 * math.sqrt(float(boresight @ np.array(est["covariance_arcsec2"]) @ boresight))
    assert est["n_images"] == 4

def test_bad_input(tmp_path):
    result = runner.invoke(app, ["analyze", "mounting", "a.fits", "b.fits", "--site", "100,0"])
    assert result.exit_code == 2 and "site latitude 100.0" in result.stderr
    result = runner.invoke(app, ["analyze", "mounting", "a.fits", "--weather", "10,1000", "--site", "40,0",
                                 "--camera", str(tmp_path / "none.toml")])
    assert result.exit_code == 2 and result.stderr.count("\n") == 1


