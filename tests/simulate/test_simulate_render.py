"""render(): photometry, sub-pixel accuracy, PSF shapes, motion, presets, output files, bad input."""

import json
import math
from datetime import datetime, timedelta

import numpy as np
import pytest

from skyfix.camera import Camera, camera_from_preset
from skyfix.catalog import Catalog
from skyfix.errors import CameraError, SimulationError, SkyfixError, UnknownNameError
from skyfix.geometry import angle_between, attitude_from_radec_roll
from skyfix.simulate import Optics, Sensor, load_preset, render, render_sequence, star_electrons, write_frame
from skyfix.simulate.psf import add_gaussians, pixel_integrated_stamps
from skyfix.simulate.scene import simulation_time

EPOCH = 2025.0
A0 = attitude_from_radec_roll(math.radians(40.0), math.radians(20.0), math.radians(30.0))
CAM = Camera.from_fov(320, 240, 10.0)
SENSOR = Sensor(qe=0.5, full_well_e=1e9, gain_e_per_adu=1.0, bit_depth=16, bias_adu=0.0)
CLEAN = dict(sensor=SENSOR, sky_mag_arcsec2=None, noise=False, epoch=EPOCH)


def catalog_at_pixels(xy, mag, camera=CAM, A=A0):
    """A catalogue whose stars land on pixel positions ``xy`` for attitude ``A``."""
    xy = np.atleast_2d(np.asarray(xy, float))
    vec = camera.pixel_to_ray(xy) @ A  # A^T b
    n = len(xy)
    return Catalog(np.arange(1, n + 1), vec, np.broadcast_to(np.asarray(mag, np.float32), (n,)).copy(),
                   np.zeros(n), np.zeros(n), EPOCH)


def com(img):
    yy, xx = np.mgrid[: img.shape[0], : img.shape[1]]
    s = img.sum()
    return (img * xx).sum() / s, (img * yy).sum() / s


def pixelisation_bias(mu, sigma, terms=5):
    """COM of a pixel-binned Gaussian minus its centre (exact Fourier series): a property of
    the centroid estimator, not of the renderer."""
    k = np.arange(1, terms + 1)
    return -np.sum((-1.0) ** (k + 1) * np.exp(-2 * np.pi**2 * k**2 * sigma**2) * np.sin(2 * np.pi * k * mu)
                   / (np.pi * k))


# --- photometry -------------------------------------------------------------------------
def test_eq_3_3_electrons():
    optics = Optics(aperture_mm=20.0, throughput=0.8, zero_point_photons_s_m2=1e10)
    e = star_electrons(5.0, optics, SENSOR, 0.2)
    expect = 1e10 * 10 ** (-0.4 * 5) * math.pi * 0.01**2 * 0.8 * 0.5 * 0.2
    assert e == pytest.approx(expect, rel=1e-12)
    assert star_electrons(6.0, optics, SENSOR, 0.2) / e == pytest.approx(10**-0.4)


def test_isolated_star_sum_equals_model():
    optics = Optics(aperture_mm=20.0, psf_fwhm_px=2.5)
    cat = catalog_at_pixels([[150.3, 100.7]], 4.0)
    f = render(A0, CAM, optics=optics, exposure_s=0.2, catalog=cat, **CLEAN)
    model = star_electrons(4.0, optics, SENSOR, 0.2)
    (star,) = f.truth["stars"]
    assert star["electrons"] == pytest.approx(model, rel=1e-9)
    assert f.expected_e.sum() == pytest.approx(model, rel=0.005)
    assert float(f.image.astype(float).sum()) == pytest.approx(model, rel=0.005)  # noise off, gain 1


def test_sky_background_is_spread_per_pixel():
    optics = Optics(aperture_mm=20.0)
    f = render(A0, CAM, optics=optics, exposure_s=1.0, catalog=catalog_at_pixels(np.zeros((0, 2)), 0.0),
               sensor=SENSOR, sky_mag_arcsec2=21.0, noise=False, epoch=EPOCH)
    per_px_arcsec2 = (math.degrees(CAM.plate_scale_rad) * 3600) ** 2
    expect = star_electrons(21.0, optics, SENSOR, 1.0) * per_px_arcsec2
    assert f.truth["background_e"] == pytest.approx(expect)
    assert np.allclose(f.expected_e, expect, rtol=1e-5)


# --- sub-pixel accuracy --------------------------------------------------------------------
@pytest.mark.parametrize("sigma", [0.5, 0.7, 1.0, 2.0])
def test_centroid_equals_truth_at_any_phase(sigma):
    rng = np.random.default_rng(int(sigma * 10))
    worst = 0.0
    for _ in range(40):
        x, y = rng.uniform(30, 31, 2)
        img = np.zeros((61, 61))
        add_gaussians(img, x, y, 1.0, sigma**2, sigma**2, 0.0)
        cx, cy = com(img)
        # exact up to the COM estimator's own, known pixel-phase bias
        assert abs(cx - x - pixelisation_bias(x, sigma)) < 1e-5
        assert abs(cy - y - pixelisation_bias(y, sigma)) < 1e-5
        worst = max(worst, abs(cx - x), abs(cy - y))
    # 0.002 px for σ ≥ 0.5 px (at exactly 0.5 the COM estimator's bias amplitude is 0.0023 px)
    assert worst < (0.0024 if sigma == 0.5 else 0.002)


def test_elliptical_psf_keeps_flux_and_centroid():
    rng = np.random.default_rng(3)
    for _ in range(20):
        x, y = rng.uniform(40, 41, 2)
        img = np.zeros((81, 81))
        sxx, syy, sxy = 4.0, 1.5, 1.2
        add_gaussians(img, x, y, 100.0, sxx, syy, sxy)
        assert img.sum() == pytest.approx(100.0, rel=1e-6)
        cx, cy = com(img)
        assert abs(cx - x) < 1e-4 and abs(cy - y) < 1e-4
        # second moments match the covariance (+1/12 px² of pixel binning)
        yy, xx = np.mgrid[:81, :81]
        w = img / img.sum()
        assert (w * (xx - cx) ** 2).sum() == pytest.approx(sxx + 1 / 12, rel=0.01)
        assert (w * (xx - cx) * (yy - cy)).sum() == pytest.approx(sxy, rel=0.02)


@pytest.mark.parametrize("correlation", [0.0, 0.4])
def test_scattered_gaussians_are_the_stamps_placed(correlation):
    # psf._scatter has two forms (a round Gaussian's two factors, an elliptical one's whole
    # stamps): each adds exactly the stamps of pixel_integrated_stamps, clipped at the frame's edges
    rng = np.random.default_rng(9)
    n = 60
    x, y = rng.uniform(-6, 86, n), rng.uniform(-6, 66, n)
    flux, s = rng.uniform(10, 1e3, n), rng.uniform(0.6, 1.1, n)
    sxx, syy, sxy = s**2, (0.9 * s) ** 2, np.full(n, correlation)
    img = add_gaussians(np.zeros((60, 80)), x, y, flux, sxx, syy, sxy)
    half = math.ceil(6.0 * s.max())  # add_gaussians's stamp half-size at its n_sigma 6
    stamps, row0, col0 = pixel_integrated_stamps(x, y, sxx, syy, sxy, half, strips=4 if correlation else 1)
    ref = np.zeros((60 + 4 * half, 80 + 4 * half))
    for st, r, c, f in zip(stamps, row0 + 2 * half, col0 + 2 * half, flux, strict=True):
        ref[r:r + 2 * half + 1, c:c + 2 * half + 1] += f * st
    assert np.allclose(img, ref[2 * half:-2 * half, 2 * half:-2 * half], rtol=1e-12, atol=1e-9)
    assert img.sum() < flux.sum() - 10  # some light fell off the frame


def test_field_dependent_psf_and_defocus_through_render():
    optics = Optics(aperture_mm=20.0, psf_fwhm_px=2.0, ellipticity_edge=1.0, defocus_px=3.0)
    xy = [[160.2, 120.4], [290.6, 25.3]]
    cat = catalog_at_pixels(xy, [4.0, 4.0])
    f = render(A0, CAM, optics=optics, exposure_s=0.2, catalog=cat, **CLEAN)
    img = f.expected_e.astype(np.float64)
    for (x, y), star in zip(xy, f.truth["stars"], strict=True):
        r0, c0 = int(round(y)), int(round(x))
        cut = img[max(r0 - 20, 0):r0 + 21, c0 - 20:c0 + 21]
        cx, cy = com(cut)
        assert abs(cx + c0 - 20 - star["x"]) < 0.01 and abs(cy + max(r0 - 20, 0) - star["y"]) < 0.01
    # the edge star is elongated along the radius (toward the upper right), the centre one round
    def moments(x, y):
        r0, c0 = int(round(y)), int(round(x))
        cut = img[max(r0 - 15, 0):r0 + 16, c0 - 15:c0 + 16]
        yy, xx = np.mgrid[: cut.shape[0], : cut.shape[1]]
        w = cut / cut.sum()
        mx, my = (w * xx).sum(), (w * yy).sum()
        return (w * (xx - mx) ** 2).sum(), (w * (yy - my) ** 2).sum(), (w * (xx - mx) * (yy - my)).sum()
    vx, vy, cxy = moments(*xy[0])
    assert vx == pytest.approx(vy, rel=0.05)
    ex, ey, exy = moments(*xy[1])
    dx, dy = xy[1][0] - CAM.cx, xy[1][1] - CAM.cy
    rho2 = (dx * dx + dy * dy) / (0.25 * (CAM.width**2 + CAM.height**2))
    s2 = optics.psf_sigma_px**2
    phi = math.atan2(dy, dx)
    # covariance of the radial elongation; the defocus disk adds the same to both axes
    assert exy == pytest.approx(0.5 * s2 * ((1 + rho2) ** 2 - 1) * math.sin(2 * phi), rel=0.05)
    assert ex + ey == pytest.approx(vx + vy + s2 * ((1 + rho2) ** 2 - 1), rel=0.05)


def test_vignetting_reduces_off_axis_stars():
    optics = Optics(aperture_mm=20.0, vignetting_per_rad=2.0)
    cat = catalog_at_pixels([[159.5, 119.5], [300.0, 200.0]], 5.0)
    f = render(A0, CAM, optics=optics, exposure_s=0.2, catalog=cat, **CLEAN)
    e_on, e_off = (s["electrons"] for s in f.truth["stars"])
    beta = math.atan(math.hypot(300 - CAM.cx, 200 - CAM.cy) / CAM.fx)
    assert e_off / e_on == pytest.approx(1 - 2.0 * beta, rel=1e-6)


# --- scene ---------------------------------------------------------------------------------
def test_hipparcos_scene_matches_projection():
    f = render(A0, "generic", epoch=EPOCH, seed=1, noise=False, mag_limit=7.0)
    cam = camera_from_preset("generic")
    assert len(f.truth["stars"]) > 5
    for s in f.truth["stars"]:
        assert cam.in_frame(np.array([s["x"], s["y"]]))
        assert s["mag"] <= 7.0
    assert f.truth["ra_deg"] == pytest.approx(40.0) and f.truth["dec_deg"] == pytest.approx(20.0)
    assert f.truth["roll_deg"] == pytest.approx(30.0)


def test_aberration_shifts_stars_by_v_over_c():
    cat = catalog_at_pixels([[160.0, 120.0]], 3.0)
    v = 30.0 * A0[0]  # 30 km/s along camera +x, perpendicular to the star
    f0 = render(A0, CAM, exposure_s=0.1, catalog=cat, **CLEAN)
    f1 = render(A0, CAM, exposure_s=0.1, catalog=cat, observer_velocity_km_s=v, **CLEAN)
    dx = f1.truth["stars"][0]["x"] - f0.truth["stars"][0]["x"]
    assert dx * CAM.plate_scale_rad == pytest.approx(30.0 / 299792.458, rel=1e-3)  # 20.6″, toward +x


def test_false_stars_hot_pixels_cosmic_rays_and_stray_light():
    cat = catalog_at_pixels(np.zeros((0, 2)), 0.0)
    f = render(A0, CAM, exposure_s=1.0, catalog=cat, sensor=SENSOR, sky_mag_arcsec2=None, epoch=EPOCH,
               false_stars=3, hot_pixels=7, cosmic_rays=2,
               stray_light={"level_e_s": 100.0, "gradient": 0.5, "angle_deg": 0.0})
    t = f.truth
    assert len(t["false_stars"]) == 3 and len(t["hot_pixels"]) == 7 and len(t["cosmic_rays"]) == 2
    assert t["stars"] == []
    # stray light: 100 e⁻ at the centre rising toward +x
    row = f.expected_e[120]
    assert row[159:161].mean() == pytest.approx(100.0, rel=0.02)
    assert row[-1] > row[0] * 1.5
    hp = t["hot_pixels"][0]
    assert f.image[hp["y"], hp["x"]] > np.median(f.image) + 500


def test_hot_pixels_grow_with_exposure_like_thesis_000_table_5():
    cam = camera_from_preset("mt9v022")
    empty = catalog_at_pixels(np.zeros((0, 2)), 0.0, camera=cam)
    counts = []
    for t in (0.0243, 0.0486, 0.0729):  # 1, 2, 3 frames of rows
        f = render(A0, "mt9v022", exposure_s=t, catalog=empty, hot_pixels=450, sky_mag_arcsec2=None,
                   epoch=EPOCH, seed=1)
        img = f.image.astype(float)
        counts.append(int(np.sum(np.abs(img - img.mean()) > 5 * img.std())))
    # thesis: 24 / 149 / 318 hot pixels (> 5σ) with AEC and AGC off
    assert 15 < counts[0] < 40 and 120 < counts[1] < 190 and 250 < counts[2] < 350


# --- motion --------------------------------------------------------------------------------
def test_smear_length_and_mid_exposure_truth():
    rate = np.array([0.0, math.radians(0.5), 0.0])  # about camera y: stars move along x
    cat = catalog_at_pixels([[160.0, 120.0]], 3.0)
    t = 0.2
    f = render(A0, CAM, exposure_s=t, catalog=cat, rate_rad_s=rate, optics=Optics(psf_fwhm_px=1.5), **CLEAN)
    s = f.truth["stars"][0]
    cx, cy = com(f.expected_e.astype(np.float64))
    assert abs(cx - s["x"]) < 0.01 and abs(cy - s["y"]) < 0.01
    length = math.radians(0.5) * t * CAM.fx  # px
    yy, xx = np.mgrid[: CAM.height, : CAM.width]
    w = f.expected_e / f.expected_e.sum()
    var_x = float((w * (xx - cx) ** 2).sum())
    sigma = 1.5 / 2.3548
    assert var_x == pytest.approx(sigma**2 + 1 / 12 + length**2 / 12, rel=0.01)
    # the star moves toward -x under a positive rate about +y (ḃ = −ω × b)
    assert render(A0, CAM, exposure_s=t, catalog=cat, rate_rad_s=rate, **CLEAN).truth["stars"][0]["x"] \
        == pytest.approx(160.0, abs=1e-6)


def test_rate_sign_convention():
    # ω about camera +y: ḃ = −ω × b, so a star at the centre moves toward −x by ω·Δt·fx
    cat = catalog_at_pixels([[160.0, 120.0]], 3.0)
    w = math.radians(1.0)
    f0, f1 = render_sequence(A0, CAM, n_frames=2, fps=5.0, rate_rad_s=[0, w, 0], exposure_s=0.01,
                             catalog=cat, **CLEAN)
    (s0,), (s1,) = f0.truth["stars"], f1.truth["stars"]
    x0 = (s0["x"] - CAM.cx) / CAM.fx
    assert s1["x"] == pytest.approx(CAM.cx + CAM.fx * math.tan(math.atan(x0) - w * 0.2), abs=1e-6)
    assert s1["y"] == pytest.approx(s0["y"], abs=1e-4)


def test_rolling_shutter_skews_with_row():
    rate = np.array([0.0, math.radians(1.0), 0.0])
    line = 1e-4
    xy = [[160.0, 20.0], [160.0, 220.0]]
    cat = catalog_at_pixels(xy, 3.0)
    rs = render(A0, CAM, exposure_s=0.01, catalog=cat, rate_rad_s=rate,
                sensor=SENSOR.replace(line_time_s=line), sky_mag_arcsec2=None, noise=False, epoch=EPOCH)
    speed = -math.radians(1.0) * CAM.fx  # px/s along x
    for (x, _), s in zip(xy, rs.truth["stars"], strict=True):
        t_row = (s["y"] - (CAM.height - 1) / 2) * line
        assert s["x"] - x == pytest.approx(speed * t_row, rel=0.01)


def test_sequence_moves_and_matches_single_render():
    rate = [0.0, 0.0, math.radians(2.0)]
    frames = list(render_sequence(A0, "generic", n_frames=3, fps=10.0, rate_rad_s=rate, epoch=EPOCH,
                                  seed=4, mag_limit=6.5))
    single = render(A0, "generic", rate_rad_s=rate, epoch=EPOCH, seed=4, mag_limit=6.5)
    assert np.array_equal(frames[0].image, single.image)
    assert not np.array_equal(frames[0].image, frames[1].image)
    t0, t1 = (simulation_time(f.truth["time"])[0] for f in frames[:2])
    assert (t1 - t0) * 365.25 * 86400 == pytest.approx(0.1, abs=1e-3)
    q = [np.array(f.truth["quaternion_xyzw"]) for f in frames]
    ang = 2 * math.acos(min(1.0, abs(float(q[0] @ q[2]))))
    assert math.degrees(ang) == pytest.approx(2.0 * 0.2, rel=1e-6)


# --- repeatability, presets, output ----------------------------------------------------------
def test_bit_for_bit_repeatable():
    kw = dict(epoch=EPOCH, seed=9, hot_pixels=5, cosmic_rays=2, false_stars=2, rate_rad_s=[0.001, 0, 0])
    a = render(A0, "has2", **kw)
    b = render(A0, "has2", **kw)
    assert a.image.dtype == np.uint16 and np.array_equal(a.image, b.image)
    assert a.truth == b.truth
    assert not np.array_equal(a.image, render(A0, "has2", **{**kw, "seed": 10}).image)


@pytest.mark.parametrize("name", ["has2", "mt9v022", "ov5642", "mt9p031", "droid_x2", "sunsat", "generic"])
def test_every_preset_renders(name):
    tables = load_preset(name)
    cam = Camera.from_dict(tables["camera"])
    assert cam == camera_from_preset(name)  # TOML and camera.py agree
    f = render(A0, name, epoch=EPOCH, seed=0, mag_limit=8.0)
    assert f.image.shape == (cam.height, cam.width)
    assert f.image.max() <= 2 ** Sensor.from_preset(name).bit_depth - 1


def test_write_fits_png_tiff_and_truth(tmp_path):
    from astropy.io import fits
    from PIL import Image

    f = render(A0, "generic", epoch=EPOCH, seed=2, mag_limit=7.0)
    p, tp = write_frame(f, tmp_path / "sim.fits")
    assert tp.name == "sim.truth.json"
    with fits.open(p) as hdul:
        assert np.array_equal(hdul[0].data, f.image)
        h = hdul[0].header
        # J2025.0 is 18:00 TT, 69.184 s later than UTC (a Julian year is TT, as obstime reads it).
        # Rendered with no observer velocity, the stars are not aberrated: no DATE-OBS (a solve
        # reading it would remove the Earth's aberration of that moment, 20″), the time as SIMDATE
        assert h["TRU_RA"] == pytest.approx(40.0) and h["SIMDATE"] == "2024-12-31T17:58:50.816"
        assert "DATE-OBS" not in h and "DATE-AVG" not in h
    from skyfix.corrections import earth_state
    from skyfix.obstime import parse_time

    v = earth_state(parse_time(f.truth["time"]).jd_tt).velocity_km_s
    aberrated = render(A0, "generic", epoch=EPOCH, seed=2, mag_limit=7.0, observer_velocity_km_s=v)
    p, _ = write_frame(aberrated, tmp_path / "seen.fits")
    with fits.open(p) as hdul:
        h = hdul[0].header
        assert h["DATE-AVG"] == "2024-12-31T17:58:50.816" and "SIMDATE" not in h
        # DATE-OBS is the exposure's start (FITS), half an exposure before the middle
        start = datetime.fromisoformat(h["DATE-OBS"]) + timedelta(seconds=0.5 * h["EXPTIME"])
        assert start == datetime.fromisoformat(h["DATE-AVG"])
    truth = json.loads(tp.read_text())
    assert set(truth) >= {"ra_deg", "dec_deg", "roll_deg", "quaternion_xyzw", "time", "camera", "stars"}
    assert set(truth["stars"][0]) == {"id", "x", "y", "mag", "electrons"}
    assert Camera.from_dict(truth["camera"]) == camera_from_preset("generic")
    write_frame(f, tmp_path / "sim.png")
    assert np.array_equal(np.asarray(Image.open(tmp_path / "sim.png")), f.image)
    import tifffile

    write_frame(f, tmp_path / "sim.tif")
    assert np.array_equal(tifffile.imread(tmp_path / "sim.tif"), f.image)


def test_truth_positions_are_the_camera_projection():
    f = render(A0, "mt9p031", epoch=EPOCH, seed=0, mag_limit=5.0, noise=False)
    cam = camera_from_preset("mt9p031")
    s = f.truth["stars"][0]
    ray = cam.pixel_to_ray(np.array([[s["x"], s["y"]]]))[0]
    from skyfix.catalog import load_hipparcos

    cat = load_hipparcos(epoch=EPOCH)
    r = cat.vectors[np.flatnonzero(cat.ids == s["id"])[0]]
    assert math.degrees(angle_between(A0 @ r, ray)) * 3600 < 0.01


# --- bad input -----------------------------------------------------------------------------
def test_bad_input_raises_clear_errors():
    with pytest.raises(UnknownNameError, match="unknown camera preset"):
        render(A0, "no-such-camera")
    with pytest.raises(SimulationError, match="positive"):
        render(A0, "generic", exposure_s=-0.1)
    with pytest.raises(CameraError, match="field of view"):
        Camera.from_fov(640, 480, 200.0)
    with pytest.raises(SkyfixError, match="field of view"):
        Camera.from_dict({"width": 640, "height": 480, "fov_deg": 0.0})
    with pytest.raises(SimulationError, match="rotation"):
        render(2 * A0, "generic")
    with pytest.raises(UnknownNameError, match="unknown preset"):
        render(A0, "generic", sensor="nope")
    with pytest.raises(SimulationError, match="time"):
        render(A0, "generic", epoch="yesterday-ish")
    with pytest.raises(SimulationError, match="frame period"):
        next(render_sequence(A0, "generic", n_frames=2, fps=100.0, exposure_s=0.5))
    with pytest.raises(SimulationError, match="use .fits"):
        write_frame(render(A0, CAM, **CLEAN, exposure_s=0.01, catalog=catalog_at_pixels(np.zeros((0, 2)), 0)),
                    "x.jpg")
