"""A deeper catalogue from a user's file (issue 26 part 4): columns found by name, brightest
first, moved by proper motion, one-line errors; and a pattern database built from it solves a
field narrower than the default bands serve."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyfix.catalog_file import load_catalog_file
from skyfix.errors import CatalogError
from skyfix.geometry import radec_to_vector

ARCSEC = math.pi / (180 * 3600)


def _write(path, header, rows):
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    return path


def test_columns_by_name_brightest_first_and_moved_by_proper_motion(tmp_path):
    path = _write(tmp_path / "deep.csv", "SOURCE_ID,RA,DEC,phot_g_mean_mag,pmra,pmdec,parallax",
                  ["11,10.0,20.0,12.5,,,",             # no proper motion: it stays
                   "12,10.1,20.1,11.0,1000.0,-500.0,2.0",  # 1″/yr east, 0.5″/yr south
                   "13,10.2,,9.0,,,",                  # no Dec: dropped
                   "14,10.3,20.3,13.0,,,-1.0"])
    cat = load_catalog_file(path, position_epoch=2016.0, epoch=2026.0)
    assert list(cat.ids) == [12, 11, 14] and cat.band == "G" and cat.epoch == 2026.0
    np.testing.assert_array_equal(cat.mag, np.array([11.0, 12.5, 13.0], dtype=np.float32))
    still = radec_to_vector(math.radians(10.0), math.radians(20.0))
    assert math.acos(min(1.0, float(cat.vectors[1] @ still))) / ARCSEC < 1e-6
    start = radec_to_vector(math.radians(10.1), math.radians(20.1))
    moved = math.acos(min(1.0, float(cat.vectors[0] @ start))) / ARCSEC
    assert moved == pytest.approx(10.0 * math.hypot(1.0, 0.5), rel=1e-3)
    assert cat.parallax[0] == pytest.approx(2e-3 * ARCSEC) and cat.parallax[2] == 0.0  # negative: none
    assert list(load_catalog_file(path, mag_limit=12.5).ids) == [12, 11]


def test_a_fits_table_reads_as_its_csv(tmp_path):
    from astropy.table import Table

    Table({"ra": [1.0, 2.0], "dec": [-5.0, 5.0], "hpmag": [8.0, 7.0]}).write(tmp_path / "c.fits")
    cat = load_catalog_file(tmp_path / "c.fits", epoch=2016.0)
    assert cat.band == "Hp" and list(cat.mag) == [7.0, 8.0] and list(cat.ids) == [1, 2]


@pytest.mark.parametrize(("text", "message"), [
    ("ra,dec,flux\n1,2,3\n", "has no mag column (one of mag, phot_g_mean_mag, gmag, g, hpmag, vmag, v; "
                             "it has ra, dec, flux)"),
    ("ra,dec,mag\n", "holds no star"),
    ("ra,dec,mag\n1,95,3\n", "holds no star with RA, Dec and a magnitude"),
])
def test_a_catalogue_it_cannot_use_is_one_line(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(CatalogError, match="bad.csv") as info:
        load_catalog_file(path)
    assert message in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(CatalogError, match="cannot read the catalogue"):
        load_catalog_file(tmp_path / "missing.csv")


@pytest.mark.slow
def test_a_database_from_a_deeper_catalogue_solves_a_field_below_the_bands(tmp_path):
    """0.6° frames (below the fine band's 0.74°): a database built by ``skyfix database build
    --catalog`` from a CSV — here the bundled Gaia stars of a 4° cone in Cygnus, 31 stars deg⁻²,
    standing in for a deeper file — solves them; the default bands refuse the hint."""
    from typer.testing import CliRunner

    from skyfix.analysis.field_campaign import FieldCase, case_camera
    from skyfix.analysis.synthetic_centroids import synthetic_centroids
    from skyfix.analysis.truth import attitude_error_rad, judge_error
    from skyfix.catalog import load_gaia
    from skyfix.cli import app
    from skyfix.geometry import attitude_from_radec_roll, vector_to_radec
    from skyfix.identify import PatternDatabase
    from skyfix.pipeline import solve_centroids

    gaia = load_gaia(epoch=2016.0)
    centre = radec_to_vector(math.radians(300.0), math.radians(30.0))
    idx = gaia.cone(centre, math.radians(4.0))
    ra, dec = (np.degrees(a) for a in vector_to_radec(gaia.vectors[idx]))
    _write(tmp_path / "deep.csv", "source_id,ra,dec,phot_g_mean_mag",
           [f"{i},{r:.9f},{d:.9f},{m:.4f}"
            for i, r, d, m in zip(gaia.ids[idx], ra, dec, gaia.mag[idx], strict=True)])
    out = tmp_path / "deep.npz"
    result = CliRunner().invoke(app, ["database", "build", "--fov-min", "0.5", "--fov-max", "0.75",
                                      "--catalog", str(tmp_path / "deep.csv"), "-o", str(out)])
    assert result.exit_code == 0, result.output
    db = PatternDatabase.load(out)
    assert db.meta["catalog_source"] == "file:deep.csv" and len(db.star_ids) == len(idx)

    camera = case_camera(FieldCase("0.6°", 0.6, 10.0))
    rng = np.random.default_rng(3)
    sky = load_gaia(epoch=2025.0)
    countable = solved = 0
    for _ in range(10):
        r, phi = math.radians(2.5) * math.sqrt(rng.random()), 2 * math.pi * rng.random()
        A = attitude_from_radec_roll(math.radians(300.0) + r * math.cos(phi) / math.cos(math.radians(30.0)),
                                     math.radians(30.0) + r * math.sin(phi), 2 * math.pi * rng.random())
        f = synthetic_centroids(camera, A, sky, mag_limit=10.0, sigma_px=0.5, n_false=2, dropout=0.05,
                                mag_sigma=0.3, rng=rng)
        sol = solve_centroids(f.xy, 1280, 960, epoch=2025.0, database=db)
        if (f.star_id != 0).sum() >= 8:
            countable += 1
            solved += sol.solved
        if sol.solved:
            err = attitude_error_rad(sol.A_icrs_to_cam, sol.camera, A, camera)
            assert not judge_error(err, 1.7).wrong
    assert countable >= 5 and solved >= countable - 1, (countable, solved)
    assert "outside every default FOV band" in solve_centroids(f.xy, 1280, 960, fov_deg=0.6).reason
