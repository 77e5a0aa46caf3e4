"""The seed camera presets against their theses, and solved lost in space (issue 10;
docs/presets.md). ``skyfix analyze presets --n 100`` is the full campaign; these pin its numbers
on a few frames, the corrected presets' photometry against the thesis figures they were matched
to, and the definition of a detectable star."""

import json
import math

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.special import ndtr
from typer.testing import CliRunner

from skyfix.analysis.preset_campaign import DETECTABLE_SNR, CampaignRow, run_campaign, summarize_row
from skyfix.analysis.preset_check import (
    THESIS_FIGURES,
    detection_snr,
    smoothed_peak_fraction,
    threshold_spots,
)
from skyfix.analysis.synthetic_centroids import random_attitudes
from skyfix.detect import extract_centroids
from skyfix.simulate import render

EPOCH = 2025.0


def _truth_xy_mag(frame):
    stars = frame.truth["stars"]
    return np.array([[s["x"], s["y"]] for s in stars]).reshape(-1, 2), np.array([s["mag"] for s in stars])


def _lens_cap_sigma(preset: str) -> float:
    """σ of a frame with no stars and no sky (the theses' lens-cap noise floor), ADU."""
    frame = render(np.eye(3), preset, epoch=EPOCH, seed=7, mag_limit=-30.0, sky_mag_arcsec2=None)
    return float(np.std(frame.image.astype(np.float64)))


# --- the detection statistic ---------------------------------------------------------------
def test_smoothed_peak_fraction_limits():
    """A point source puts all its light in one pixel, 1/4 of it at the smoothed peak (the
    binomial kernel's centre weight), at any phase; a star of σ 0.6 px loses some of its peak off
    the pixel centre; a wide star's is the Gaussian's 1/(2π(σ² + ½ + 1/12))."""
    assert smoothed_peak_fraction(1e-4) == pytest.approx(0.25, rel=1e-6)
    centred = smoothed_peak_fraction(0.6, n_phase=1)
    assert 0.8 * centred < smoothed_peak_fraction(0.6) < centred < 0.25
    s = 5.0
    assert smoothed_peak_fraction(s) == pytest.approx(1 / (2 * math.pi * (s * s + 0.5 + 1 / 12)), rel=0.01)


@pytest.mark.parametrize("preset", ["generic", "has2"])
def test_detectable_stars_are_the_ones_the_extractor_finds(preset):
    """Of the truth's stars with detection SNR ≥ 8 the extractor finds ≥ 90% (measured on these
    frames: generic 165 of 168, has2 24 of 24), of those below 3 under 3% (0.16%, 0.17%)."""
    found, s_det = [], []
    for k, A in enumerate(random_attitudes(3, np.random.default_rng(5))):
        frame = render(A, preset, epoch=EPOCH, seed=k)
        xy, _ = _truth_xy_mag(frame)
        c = extract_centroids(frame.image, max_stars=1000)
        d, _ = cKDTree(np.c_[c.x, c.y]).query(xy)
        found.append(d < 2.0)
        s_det.append(detection_snr(frame.truth))
    found, s_det = np.concatenate(found), np.concatenate(s_det)
    assert found[s_det >= DETECTABLE_SNR].mean() >= 0.90
    assert found[s_det < 3.0].mean() < 0.03


# --- the campaign on a few frames ----------------------------------------------------------
@pytest.fixture(scope="module")
def small_campaign():
    """generic and mt9v022, 5 frames each, seed 1, skyfix's own databases."""
    rows = (CampaignRow("generic"), CampaignRow("mt9v022"))
    campaign = run_campaign(5, seed=1, rows=rows)
    return {row.preset: frames for row, _, frames in campaign.rows}


def test_generic_solves_every_frame_to_two_arcsec(small_campaign):
    """Measured: 5/5 solved both ways, boresight median 0.97″ / p95 1.71″ (no hint), 1.08″ / 1.71″
    (camera given); normalised RMS 0.58–1.08."""
    for key in ("bands/blind", "bands/camera"):
        s = summarize_row(small_campaign["generic"], key)
        assert s["frames_4_detectable"] == 5 and s["solved"] == 5 and s["wrong"] == 0, s
        assert s["boresight_p95_arcsec"] < 3.5, s
        assert s["roll_p95_arcsec"] < 25.0, s
        assert all(0.3 < z < 2.0 for z in s["normalised_rms"]), s


def test_mt9v022_sees_about_five_stars_and_is_never_wrong(small_campaign):
    """Thesis 000 saw at most ~4 stars a frame; the preset's frames have 4–7 detectable (median
    5). Measured with thesis 000's calibrated lens (issue 25): 4 of 5 solve, with no hint as with
    the camera given (a sparse 752×480 frame is tried through the MT9V022 preset's camera:
    skyfix.identify.lost.preset_cameras), 3.0–23″ off (thesis 000's estimate: 11.4″); the fifth,
    4 detectable stars, is refused as too uncertain (σ 16″), not wrong. (With the nominal pinhole
    that frame had 3 detectable — the barrel widens the field — and the other 4 all solved; before
    the preset fallback 4 of 5 failed "no match".) With the detector's noise drawn differently
    (issue 27 part 5: the same model, another realisation) that fifth frame solves too: 5 of 5."""
    frames = small_campaign["mt9v022"]
    detectable = [f.n_detectable for f in frames]
    assert 3 <= np.median(detectable) <= 7 and max(detectable) <= 10, detectable
    for key in ("bands/blind", "bands/camera"):
        s = summarize_row(frames, key)
        assert s["wrong"] == 0, s
        assert s["frames_4_detectable"] == 5 and s["solved_of_4_detectable"] >= 4, s
        assert s["solved_of_4_detectable"] + s["failures"].get("attitude too uncertain", 0) == 5, s
        solved = [f.solves[key] for f in frames if f.solves[key].solved]
        assert all(o.boresight_arcsec < 45.0 for o in solved), s


# --- the corrected presets against their theses ----------------------------------------------
def test_mt9p031_matches_thesis_003():
    """Lens-cap noise 35.21 counts (Table 9.1; measured 35.20), centre FWHM 7.6151 px (§9.VIII.A;
    measured 7.60), and the thesis's own processing — a 1024-count threshold, spots ≥ 6 px — finds
    16.23 stars an image (Table 9.4): 18.2 a frame on these 6 frames, 15.8 on 30."""
    fig = THESIS_FIGURES["mt9p031"]
    assert _lens_cap_sigma("mt9p031") == pytest.approx(fig.noise_floor_adu, rel=0.02)
    counts, fwhm = [], None
    for k, A in enumerate(random_attitudes(6, np.random.default_rng(3))):
        frame = render(A, "mt9p031", epoch=EPOCH, seed=k, mag_limit=7.5)  # fainter stars make no spot
        c = extract_centroids(frame.image, max_stars=100)
        centres, _ = threshold_spots(frame.image, fig.rule.level_adu(c.background_level, c.noise),
                                     fig.rule.min_area)
        xy, _ = _truth_xy_mag(frame)
        d, j = cKDTree(xy).query(centres)
        counts.append(len(set(j[d < 3.0])))
        if fwhm is None:
            from skyfix.analysis.psf_field import measure_psf_field

            psf = measure_psf_field(frame.image, c, min_snr=10.0)
            fwhm = float(np.median(psf.fwhm_px[psf.radius < 1 / 3]))
    assert fwhm == pytest.approx(fig.fwhm_px, rel=0.05)
    assert np.mean(counts) == pytest.approx(fig.stars_per_frame, rel=0.3), counts


def test_droid_x2_matches_thesis_003():
    """Lens-cap noise 1.51 counts in the green channel (Table 9.1; measured 1.508); at 66 ms 1–3
    stars a frame, none fainter than magnitude 2.6 (Table 9.4: 1.85 starlight spots an image;
    measured 1.9 a frame, the faintest 1.93)."""
    fig = THESIS_FIGURES["droid_x2"]
    assert _lens_cap_sigma("droid_x2") == pytest.approx(fig.noise_floor_adu, rel=0.02)
    n_found, mags = [], []
    for k, A in enumerate(random_attitudes(8, np.random.default_rng(3))):
        frame = render(A, "droid_x2", epoch=EPOCH, seed=k, mag_limit=5.0)
        xy, mag = _truth_xy_mag(frame)
        c = extract_centroids(frame.image, max_stars=100)
        if len(c.x) == 0:
            n_found.append(0)
            continue
        d, j = cKDTree(xy).query(np.c_[c.x, c.y])
        real = np.unique(j[d < 2.0])
        n_found.append(len(real))
        mags.extend(mag[real])
    assert 1.0 <= np.mean(n_found) <= 3.0, n_found
    assert max(mags) <= fig.limiting_mag, mags


def test_sunsat_matches_thesis_004():
    """§8.5.2: 3 mV peak to peak of CCD noise at 1.5 mV a level, σ ≈ 1/3 level before the ADC
    (measured 0.34; 0.51 with the rounding to 6 bits); §8.6: Mv 3 saturates slightly; §8.7: with
    a threshold 2 levels over the dark level and spots of ≥ 10 px every Mv 6 star is seen
    (measured: 124 of the 126 Mv ≤ 6 stars of 12 frames, the two missed of Mv 5.45 and 6.0)."""
    from skyfix.analysis.preset_check import pixel_noise_adu
    from skyfix.simulate import Optics, Sensor, star_electrons

    frame = render(np.eye(3), "sunsat", epoch=EPOCH, seed=7, mag_limit=-30.0, sky_mag_arcsec2=None)
    analogue = math.sqrt(pixel_noise_adu(frame.truth) ** 2 - 1 / 12)
    assert 0.25 < analogue < 0.45
    assert 0.4 < _lens_cap_sigma("sunsat") < 0.6
    sensor, optics = Sensor.from_preset("sunsat"), Optics.from_preset("sunsat")
    headroom_e = (sensor.max_adu - sensor.bias_adu) * sensor.gain_e_per_adu - sensor.dark_current_e_s
    s = optics.psf_sigma_px
    centre = (ndtr(0.5 / s) - ndtr(-0.5 / s)) ** 2  # a centred star's pixel, exact
    e3 = float(star_electrons(3.0, optics, sensor, 1.0))
    assert 0.9 < e3 * centre / headroom_e < 1.4  # a centred Mv 3 star just reaches the ADC's top
    rule = THESIS_FIGURES["sunsat"].rule
    n_bright = n_seen = 0
    for k, A in enumerate(random_attitudes(12, np.random.default_rng(3))):
        frame = render(A, "sunsat", epoch=EPOCH, seed=k)
        c = extract_centroids(frame.image, max_stars=100)
        centres, _ = threshold_spots(frame.image, rule.level_adu(c.background_level, c.noise), rule.min_area)
        xy, mag = _truth_xy_mag(frame)
        bright = (mag <= 6.0) & np.all((xy > 8) & (xy < [744, 574]), axis=1)
        seen = np.zeros(len(xy), bool)
        if len(centres):
            d, j = cKDTree(xy).query(centres)
            seen[j[d < 3.0]] = True
        n_bright += int(bright.sum())
        n_seen += int((seen & bright).sum())
    assert n_seen >= 0.95 * n_bright, (n_seen, n_bright)


# --- the command -----------------------------------------------------------------------------
def test_cli_analyze_presets(tmp_path):
    from skyfix.cli import app

    runner = CliRunner()
    out = tmp_path / "campaign"
    result = runner.invoke(app, ["analyze", "presets", "--n", "2", "--presets", "generic", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "| generic | 0.1 s | bands | no hint | 2 |" in result.output
    data = json.loads((out / "presets.json").read_text())
    (row,) = data["rows"]
    assert row["preset"] == "generic" and row["summary"]["bands/blind"]["solved"] == 2
    assert (out / "presets.png").stat().st_size > 10_000
    import pyarrow.parquet as pq

    rows = pq.read_table(out / "presets.parquet").to_pylist()  # the engine's rows, a frame each
    assert [(r["trial"], r["preset"], r["database"]) for r in rows] == [(0, "generic", "bands"),
                                                                        (1, "generic", "bands")]
    assert [r["blind_boresight_arcsec"] for r in rows] == [f["solves"]["bands/blind"]["boresight_arcsec"]
                                                           for f in row["frames"]]
    assert not (out / "presets.parquet.parts").exists()
    bad = runner.invoke(app, ["analyze", "presets", "--presets", "nosuch", "--out", str(out)])
    assert bad.exit_code == 2 and "--presets: unknown preset 'nosuch'" in bad.output
    assert len(bad.output.strip().splitlines()) == 1


def test_cli_analyze_presets_unreachable_scheduler_is_one_line(tmp_path, monkeypatch):
    from skyfix.cli import app
    from skyfix.montecarlo import engine

    monkeypatch.setattr(engine, "CONNECT_TIMEOUT_S", 1.0)
    result = CliRunner().invoke(app, ["analyze", "presets", "--n", "1", "--presets", "generic", "--scheduler",
                                      "tcp://127.0.0.1:9", "--out", str(tmp_path / "c")])
    assert result.exit_code == 2, result.output
    *progress, error = result.stderr.strip().splitlines()  # off a terminal the progress is lines
    assert error.startswith("skyfix: error: cannot reach the Dask scheduler at tcp://127.0.0.1:9: "), error
    assert all(line.startswith("skyfix: preset campaign") for line in progress), progress
    assert "Traceback" not in result.output
    both = CliRunner().invoke(app, ["analyze", "presets", "--workers", "2", "--scheduler", "tcp://127.0.0.1:9"])
    assert both.exit_code == 2 and "give --workers or --scheduler, not both" in both.stderr
