"""A star calibration of a camera on the ground (docs/calibration.md#on-the-ground): with the
images' time and site (``calibrate_stars(observation=…)``, ``skyfix calibrate stars --time
--site``) the catalogue is fitted as the camera saw it — aberrated and refracted per star — and
the camera file holds the lens; without them the atmosphere goes into the camera.

The frames: an ESA-like camera (1024×768, 11.4°, k1 0.09, principal point (+6, −4) px off
centre) on an alt-az mount (image up toward the zenith, as a mount that does not turn the camera
about its axis keeps it) at ESTEC, 2019-07-29T20:47:26 UTC, 8 pointings at altitudes 25° and 45°.
Refraction squeezes each frame along its vertical by R₀/sin²h (1.6e-3 at 25°, 5.6e-4 at 45°),
always along the image's y axis: the fit without it puts the squeeze into fy."""

import math

import numpy as np
import pytest

from skyfix.calibration.joint import MatchedImage, fit_joint
from skyfix.calibration.stars import calibrate_stars, ground_observation
from skyfix.camera import Camera
from skyfix.catalog import load_hipparcos
from skyfix.errors import InputError

SITE = "52.2187,4.4206,10"
TIME = "2019-07-29T20:47:26Z"
TRUTH = Camera.from_fov(1024, 768, 11.4).replace(cx=511.5 + 6, cy=383.5 - 4, k1=0.09)
PARAMS = ("f", "aspect", "principal_point", "k1")
POINTINGS = [(alt, az) for alt in (25.0, 45.0) for az in (45.0, 135.0, 225.0, 315.0)]


def _attitudes(obs) -> list[np.ndarray]:
    """Camera attitudes (ICRS axes, physical) for each (alt, az), image up (−y) toward the zenith."""
    enu_to_icrs = obs.ground.A_icrs_to_enu.T
    zenith = enu_to_icrs[:, 2]
    out = []
    for alt, az in POINTINGS:
        a, z = math.radians(alt), math.radians(az)
        b = enu_to_icrs @ np.array([math.cos(a) * math.sin(z), math.cos(a) * math.cos(z), math.sin(a)])
        up = zenith - (zenith @ b) * b
        y = -up / np.linalg.norm(up)
        out.append(np.array([np.cross(y, b), y, b]))
    return out


def _grid_error_px(camera: Camera, A: np.ndarray, A_true: np.ndarray) -> float:
    """Largest distance over a 17×13 grid between a pixel and where the fitted camera and
    attitude put the direction TRUTH sees there."""
    g = np.stack(np.meshgrid(np.linspace(0, 1023, 17), np.linspace(0, 767, 13)), -1).reshape(-1, 2)
    uv, _ = camera.ray_to_pixel(TRUTH.pixel_to_ray(g) @ A_true @ A.T)
    return float(np.hypot(*(uv - g).T).max())


@pytest.fixture(scope="module")
def ground():
    obs = ground_observation(TIME, SITE)
    return obs, _attitudes(obs), load_hipparcos(epoch=obs.epoch, mag_limit=8.0)


def _matched(ground, seen: bool, sigma_px: float = 0.12, seed: int = 0) -> list[MatchedImage]:
    """Each pointing's stars where the camera sees them (refracted, aberrated) with Gaussian
    noise, paired with their catalogue places (``seen`` False) or their seen directions."""
    obs, attitudes, stars = ground
    rng = np.random.default_rng(seed)
    directions = obs.seen(stars.vectors, stars.ids)
    out = []
    for i, A in enumerate(attitudes):
        uv, front = TRUTH.ray_to_pixel(directions @ A.T)
        k = np.flatnonzero(front & TRUTH.in_frame(uv))
        out.append(MatchedImage(f"frame {i}", uv[k] + rng.normal(0.0, sigma_px, (len(k), 2)),
                                directions[k] if seen else stars.vectors[k], A))
    return out


def test_the_fit_recovers_the_lens_only_with_the_atmosphere_in_the_stars(ground):
    """8 ground frames of exact stars with 0.12 px of noise (the ESA frames' σ): fitted to the
    seen directions the camera is the lens within issue 25's tolerances (focal lengths within
    0.05 %, and within 3σ; distortion within 0.2 px over the frame) and the residual σ is the
    noise (measured: fx, fy within 0.5σ, grid 0.03 px, σ 0.119 px); fitted to the catalogue
    places fy carries the squeeze (measured fy/fx − 1 = −7.6e-4, 26σ; cy 3.8 px off, the grid
    3.3 px) and the residuals grow (σ 0.148 px)."""
    _, attitudes, _ = ground
    with_air = fit_joint(_matched(ground, seen=True), TRUTH.replace(fy=TRUTH.fx, cx=511.5, cy=383.5, k1=0.0),
                         PARAMS)
    without = fit_joint(_matched(ground, seen=False), TRUTH.replace(fy=TRUTH.fx, cx=511.5, cy=383.5, k1=0.0),
                        PARAMS)
    good, bad = with_air.camera, without.camera
    for k in ("fx", "fy"):
        assert abs(getattr(good, k) / getattr(TRUTH, k) - 1) < 5e-4
        assert abs(getattr(good, k) - getattr(TRUTH, k)) < 3 * with_air.sigma[k]
    assert _grid_error_px(good, with_air.attitudes[0], attitudes[0]) < 0.2
    assert 0.11 < with_air.sigma_px < 0.13
    aspect = bad.fy / bad.fx - 1
    assert -1.0e-3 < aspect < -0.5e-3
    assert abs(bad.fy - TRUTH.fy) > 20 * without.sigma["fy"]
    assert _grid_error_px(bad, without.attitudes[0], attitudes[0]) > 0.3
    assert np.all(without.rms_arcsec() > with_air.rms_arcsec())


@pytest.mark.slow
def test_rendered_ground_frames_calibrate_to_the_lens_with_time_and_site(ground):
    """The same 8 pointings rendered by skyfix.simulate with the sky as the camera sees it (the
    catalogue's directions replaced by their seen ones: the simulator has no air of its own),
    solved blind and calibrated: with the time and site (``observation=``) fx, fy within 0.05 %
    and the grid within 0.2 px (measured: −2.2e-5, +0.5e-5, 0.037 px; principal point (−0.62,
    +0.51) px off; σ 0.099 px, per-frame RMS 4.5–6.3″); without them fy −1.0e-3 off, cy 4.7 px,
    the grid 3.3 px, σ 0.133 px, RMS 6.8–8.6″."""
    from skyfix.catalog import Catalog
    from skyfix.simulate import render

    obs, attitudes, stars = ground
    sky = Catalog(stars.ids, obs.seen(stars.vectors, stars.ids), stars.mag, np.zeros(len(stars)),
                  np.zeros(len(stars)), obs.epoch)
    frames = [render(A, TRUTH, sensor="generic", optics="generic", exposure_s=0.3, epoch=obs.epoch,
                     catalog=sky, seed=10 + i).image for i, A in enumerate(attitudes)]
    good = calibrate_stars(frames, observation=obs)
    bad = calibrate_stars(frames)
    assert good.observation is obs and bad.observation is None and bad.boresights_altaz() is None
    for (alt, az), seen_at in zip(POINTINGS, good.boresights_altaz(), strict=True):
        assert abs(seen_at.alt_deg - alt) < 0.01 and abs((seen_at.az_deg - az + 180) % 360 - 180) < 0.01
    cam = good.camera
    assert abs(cam.fx / TRUTH.fx - 1) < 5e-4 and abs(cam.fy / TRUTH.fy - 1) < 5e-4
    assert _grid_error_px(cam, good.fit.attitudes[0], attitudes[0]) < 0.2
    assert abs(bad.camera.fy / bad.camera.fx - 1) > 5e-4
    assert _grid_error_px(bad.camera, bad.fit.attitudes[0], attitudes[0]) > 1.0
    assert np.mean(good.fit.rms_arcsec()) < np.mean(bad.fit.rms_arcsec())
    import tomllib

    table = tomllib.loads(good.to_toml())["calibration"]
    assert table["site"] == [52.2187, 4.4206, 10.0] and "refraction" in table["corrections"]


def test_a_site_needs_a_time(tmp_path):
    """In the API an InputError; on the command line one line, exit status 2, no camera file."""
    from typer.testing import CliRunner

    from skyfix.cli import app

    assert ground_observation() is None
    with pytest.raises(InputError, match="a site needs a time"):
        ground_observation(site=SITE)
    obs = ground_observation(TIME)
    assert obs.site is None and "aberration" in obs.applied
    paths = [tmp_path / f"f{i}.fits" for i in range(3)]
    for p in paths:
        p.write_bytes(b"")
    out = tmp_path / "camera.toml"
    result = CliRunner().invoke(app, ["calibrate", "stars", *map(str, paths), "-o", str(out), "--site", SITE])
    assert result.exit_code == 2, result.output
    assert result.stderr.strip().splitlines() == [
        f"skyfix: error: --site {SITE}: a site needs a time (--time): where the zenith is among the stars "
        "depends on it"]
    assert not out.exists()


@pytest.mark.slow
def test_esa_frames_with_their_time_and_site(real_dir):
    """The 8 ESA frames (ESTEC, 2019-07-29T20:47:26 UTC: the file names' time is UTC — the fitted
    boresights are then at 41.0–41.4° and 61.1–61.5°, their names' Alt 40 and 60; at UTC+2 they
    would not be, and the fit is far worse). With the time and site the camera file loses the
    atmosphere: fx +1.36 px (refraction's horizontal squeeze R₀ = 2.8e-4 at any altitude) and fy
    +2.43 px (R₀/sin²h, 3.7–6.5e-4), σ 0.122 → 0.118 px per axis, per-frame RMS 6.03–7.67″ →
    5.93–7.50″ (docs/calibration.md#on-the-ground)."""
    paths = sorted((real_dir / "esa-tetra3").glob("*.tiff"))
    plain = calibrate_stars(paths)
    ground = calibrate_stars(paths, observation=ground_observation(TIME, SITE))
    assert ground.fit.params == plain.fit.params == PARAMS
    assert 1.0 < ground.camera.fx - plain.camera.fx < 1.8
    assert 2.0 < ground.camera.fy - plain.camera.fy < 2.9
    assert ground.fit.sigma_px < plain.fit.sigma_px < 0.125
    alts = sorted(a.alt_deg for a in ground.boresights_altaz())  # the names' Alt 40 and 60
    assert 40.9 < alts[0] and alts[3] < 41.5 and 61.0 < alts[4] and alts[7] < 61.6
    rms = ground.fit.rms_arcsec()
    assert np.all(rms < ground.before.rms_arcsec())
    assert np.mean(rms) < np.mean(plain.fit.rms_arcsec())
    assert 5.8 < rms.min() and rms.max() < 7.6  # not the issue's 5″: the centroids' noise and S-curve
    _check_what_limits_the_esa_residuals(paths, ground)
    # The residual RMS measures the stars' centroid noise, which falls with brightness: with the
    # 40 brightest centroids of each image it is 3.36–4.83″ (below 5″ and the uncalibrated
    # 5.74–7.87″ on every frame; measured), and the camera is the same within 2σ.
    bright = calibrate_stars(paths, observation=ground_observation(TIME, SITE), max_stars=40)
    assert bright.fit.params == PARAMS
    assert np.all(bright.fit.rms_arcsec() < 5.0)
    assert np.all(bright.fit.rms_arcsec() < bright.before.rms_arcsec())
    for k in ("fx", "fy", "k1"):
        assert abs(getattr(bright.camera, k) - getattr(ground.camera, k)) < 2 * bright.fit.sigma[k]


def _check_what_limits_the_esa_residuals(paths, cal) -> None:
    """docs/calibration.md's account of the ESA residuals: each inlier's Cramér–Rao bound (its
    flux over the frame's sky σ, the frame's PSF σ; shot noise left out) alone gives per-frame
    RMS 4.0–5.9″ — three frames above 5″; the stars of SNR > 9.6 carry a pixel-phase S-curve
    a·sin(2πφ) of a = 0.069 px (x) and 0.060 px (y); no camera term is left (the residuals'
    means over a 4 × 3 grid within 0.03 px)."""
    from scipy.spatial import cKDTree

    from skyfix.detect import cramer_rao_centroid, extract_centroids, measure_psf
    from skyfix.io import read_image

    fit = cal.fit
    arcsec = 206264.80624709636 * fit.camera.plate_scale_rad
    bound, xy_all, res_all, snr_all = [], [], [], []
    for path, xy, res, k in zip(paths, fit.xy, fit.residuals_px, fit.inliers, strict=True):
        image = read_image(path)
        stars = extract_centroids(image, max_stars=300, centroid="gaussian")
        d, i = cKDTree(stars.xy).query(xy[k])
        assert np.all(d < 1e-9)
        bright = np.argsort(-stars.flux[i])[:20]
        psf = measure_psf(image, xy[k][bright])
        s = float(np.nanmedian(np.sqrt(psf["sigma_x"] * psf["sigma_y"])))
        gain = 1e6  # electrons per ADU: the star's own shot noise negligible (the bound's lowest)
        crb = np.array([cramer_rao_centroid(s, f * gain, (stars.noise * gain) ** 2)
                        for f in np.maximum(stars.flux[i], 1e-3)])
        bound.append(math.sqrt(2.0 * np.mean(crb**2)) * arcsec)
        xy_all.append(xy[k])
        res_all.append(res[k])
        snr_all.append(stars.snr[i])
    bound = np.array(bound)
    assert 3.8 < bound.min() < 4.3 and 5.7 < bound.max() < 6.1 and np.sum(bound > 5.0) == 3
    xy, res, snr = np.concatenate(xy_all), np.concatenate(res_all), np.concatenate(snr_all)
    b = snr > 9.6
    for axis, (lo, hi) in enumerate(((0.055, 0.085), (0.045, 0.075))):
        phase = xy[b, axis] - np.round(xy[b, axis])
        M = np.column_stack([np.sin(2 * np.pi * phase), np.cos(2 * np.pi * phase), np.ones(b.sum())])
        amplitude = np.linalg.lstsq(M, res[b, axis], rcond=None)[0][0]
        assert lo < amplitude < hi, (axis, amplitude)
    cell = (np.clip(xy[:, 0] / 256, 0, 3).astype(int), np.clip(xy[:, 1] / 256, 0, 2).astype(int))
    for i in range(4):
        for j in range(3):
            inside = (cell[0] == i) & (cell[1] == j)
            assert np.all(np.abs(res[inside].mean(axis=0)) < 0.03)
