"""Observation times from ISO text, FITS headers and EXIF, against astropy and Pillow (issue 24).

astropy's ``Time`` converts UTC with its own leap-second table (no download:
``iers.conf.auto_download`` off); skyfix uses ERFA's built-in one.
"""

import logging
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest
from astropy.utils import iers

from skyfix.errors import InputError
from skyfix.obstime import (
    NO_TIME,
    UNKNOWN_ZONE_S,
    ObservationTime,
    julian_year,
    parse_time,
    time_from_exif,
    time_from_fits_header,
    time_from_image,
)

iers.conf.auto_download = False

DAY_S = 86400.0


def seconds_apart(t: ObservationTime, astropy_time) -> float:
    tt = astropy_time.tt
    return abs((t.jd_tt - tt.jd1) - tt.jd2) * DAY_S


@pytest.mark.parametrize(("text", "utc"), [
    ("2026-03-01T22:00:00Z", "2026-03-01T22:00:00"),
    ("2026-03-01T22:00:00.250+02:00", "2026-03-01T20:00:00.250"),
    ("2026-03-01 22:00", "2026-03-01T22:00:00"),
    ("1999-12-31T23:59:59.999-05:30", "2000-01-01T05:29:59.999"),
    ("2016-12-31T23:59:60.5Z", "2016-12-31T23:59:60.5"),  # leap seconds
    ("1972-06-30T23:59:60", "1972-06-30T23:59:60"),
    ("2100-12-31T23:59:59Z", "2100-12-31T23:59:59"),
])
@pytest.mark.filterwarnings("ignore::erfa.ErfaWarning")  # astropy's "dubious year" after its table
def test_iso_text_is_the_time_astropy_reads(text, utc):
    from astropy.time import Time

    t = parse_time(text)
    ref = Time(utc, scale="utc")
    assert seconds_apart(t, ref) < 1e-4  # measured ≤ 20 µs: a float64 Julian date's resolution
    assert t.source == "--time" and t.uncertainty_s == 0.0
    assert t.iso == ref.isot[:23] + "Z"


def test_a_datetime_and_a_julian_epoch():
    from astropy.time import Time

    when = datetime(2026, 3, 1, 22, 0, tzinfo=timezone(timedelta(hours=2)))
    assert seconds_apart(parse_time(when), Time(when)) < 1e-4
    t = parse_time("J2026.25")
    assert seconds_apart(t, Time(2026.25, format="jyear", scale="tt")) < 1e-4
    assert julian_year(t) == pytest.approx(2026.25, abs=1e-12)
    assert julian_year(parse_time("2026-01-01T00:00:00Z")) == pytest.approx(
        Time("2026-01-01T00:00:00", scale="utc").tt.jyear, abs=1e-11)


@pytest.mark.parametrize("text", ["", "yesterday", "2026-13-01", "2026-02-30", "2026-03-01T24:00:00",
                                  "2026-01-01T23:59:60.5Z", "J20x6"])
def test_text_that_is_not_a_time_is_an_input_error(text):
    with pytest.raises(InputError, match="cannot read the time"):
        parse_time(text)


@pytest.mark.parametrize("text", ["1899-12-31T23:59:59Z", "2101-01-01", "J1850.0", "0001-01-01"])
def test_times_outside_1900_to_2100_are_input_errors(text):
    with pytest.raises(InputError, match="outside 1900–2100"):
        parse_time(text)
    if not text.startswith("J"):
        with pytest.raises(InputError, match="outside 1900–2100"):
            time_from_fits_header({"DATE-OBS": text})


# --- FITS ---------------------------------------------------------------------------------------
def write_fits(path, **cards):
    from astropy.io import fits

    hdu = fits.PrimaryHDU(np.zeros((8, 10), np.float32))
    for key, value in cards.items():
        hdu.header[key.replace("_", "-")] = value
    hdu.writeto(path)
    return path


def test_fits_date_obs_and_exptime_give_mid_exposure(tmp_path):
    from astropy.io import fits
    from astropy.time import Time, TimeDelta

    from skyfix.io import read_image_with_header

    path = write_fits(tmp_path / "a.fits", DATE_OBS="2026-03-01T22:00:00.125", EXPTIME=30.0)
    ref = Time(fits.getheader(path)["DATE-OBS"], scale="utc") + TimeDelta(15.0, format="sec")
    for t in (time_from_image(path), time_from_fits_header(read_image_with_header(path).header),
              time_from_fits_header(fits.getheader(path))):
        assert seconds_apart(t, ref) < 1e-4
        assert t.source == "DATE-OBS" and t.iso == "2026-03-01T22:00:15.125Z"


@pytest.mark.parametrize(("cards", "scale", "shift_s"), [
    ({"MJD_OBS": 61000.25, "TIMESYS": "TT", "EXPOSURE": 4.0}, "tt", 2.0),
    ({"DATE_OBS": "2026-03-01T22:00:00", "TIMESYS": "TAI"}, "tai", 0.0),
    ({"DATE_OBS": "2026-03-01T22:00:00", "TIMESYS": "GPS"}, "tai", 19.0),
    ({"DATE_BEG": "2026-03-01T22:00:00", "DATE_OBS": "2026-03-01", "EXPTIME": 2.0}, "utc", 1.0),
    ({"DATE_AVG": "2026-03-01T22:00:00", "DATE_OBS": "2026-03-01T21:00:00", "EXPTIME": 2.0}, "utc", 0.0),
    ({"DATE_OBS": "2026-03-01", "TIME_OBS": "22:00:00"}, "utc", 0.0),
])
def test_fits_keywords_and_time_scales(tmp_path, cards, scale, shift_s):
    from astropy.time import Time, TimeDelta

    t = time_from_image(write_fits(tmp_path / "b.fits", **cards))
    when = cards.get("MJD_OBS")
    ref = (Time(when, format="mjd", scale=scale) if when else Time("2026-03-01T22:00:00", scale=scale))
    assert seconds_apart(t, ref + TimeDelta(shift_s, format="sec")) < 1e-4
    assert t.source == next(k.replace("_", "-") for k in ("DATE_AVG", "DATE_BEG", "DATE_OBS", "MJD_OBS")
                            if k in cards)


def test_malformed_date_obs_is_one_warning_and_no_time(tmp_path, caplog):
    path = write_fits(tmp_path / "c.fits", DATE_OBS="2026-02-30T25:61", EXPTIME=1.0)
    with caplog.at_level(logging.WARNING):
        t = time_from_image(path)
    assert t == NO_TIME or (t.source == "none" and not t.known)
    assert [r.levelno for r in caplog.records] == [logging.WARNING]
    message = caplog.records[0].getMessage()
    assert "DATE-OBS" in message and "\n" not in message and "no observation time" in message
    assert time_from_fits_header({}) is NO_TIME
    caplog.clear()
    with caplog.at_level(logging.WARNING):  # a bad DATE-OBS falls back on a good MJD-OBS
        t = time_from_fits_header({"DATE-OBS": "soon", "MJD-OBS": 61000.0})
    assert t.source == "MJD-OBS" and len(caplog.records) == 1


# --- EXIF ---------------------------------------------------------------------------------------
def write_photo(path, stamp="2026:03:01 23:00:00", offset="+01:00", subsec="25", exposure=(1, 4)):
    """A small photo with EXIF time tags: in the Exif IFD of a JPEG, in the first IFD of a TIFF
    (Pillow writes no Exif IFD into a TIFF; skyfix reads either)."""
    from PIL import Image, TiffImagePlugin

    tags = {36867: stamp, 36881: offset, 37521: subsec,  # DateTimeOriginal, OffsetTime-, SubSecTime-
            33434: None if exposure is None else TiffImagePlugin.IFDRational(*exposure)}  # ExposureTime, s
    image = Image.new("L", (16, 12), 40)
    if str(path).endswith(".tif"):
        info = TiffImagePlugin.ImageFileDirectory_v2()
        info.update({k: v for k, v in tags.items() if v is not None})
        image.save(path, tiffinfo=info)
    else:
        exif = Image.Exif()
        exif.get_ifd(0x8769).update({k: v for k, v in tags.items() if v is not None})
        image.save(path, exif=exif)
    return path


def pillow_time(path):
    """The mid-exposure time as Pillow reads the tags, by the EXIF standard's meaning."""
    from astropy.time import Time, TimeDelta
    from PIL import Image

    with Image.open(path) as im:
        exif = im.getexif()
        tags = {**exif, **exif.get_ifd(0x8769)}
    when = datetime.strptime(f"{tags[36867]}.{tags[37521]}{tags[36881]}", "%Y:%m:%d %H:%M:%S.%f%z")
    return Time(when) + TimeDelta(float(tags[33434]) / 2, format="sec")


@pytest.mark.parametrize("suffix", [".jpg", ".tif"])
def test_exif_date_time_original_is_the_time_pillow_reads(tmp_path, suffix):
    path = write_photo(tmp_path / f"photo{suffix}")
    t = time_from_image(path)
    assert seconds_apart(t, pillow_time(path)) < 1e-4
    assert t.source == "EXIF" and t.iso == "2026-03-01T22:00:00.375Z" and t.uncertainty_s == 0.0
    from PIL import Image

    with Image.open(path) as im:
        assert time_from_exif(im) == t


def test_exif_without_a_zone_says_so(tmp_path, caplog):
    path = write_photo(tmp_path / "local.jpg", offset=None, subsec=None, exposure=None)
    with caplog.at_level(logging.WARNING):
        t = time_from_image(path)
    assert t.source == "EXIF" and t.iso == "2026-03-01T23:00:00.000Z" and t.uncertainty_s == UNKNOWN_ZONE_S
    assert len(caplog.records) == 1 and "time zone is unknown" in caplog.records[0].getMessage()


def test_exif_bad_or_absent(tmp_path, caplog):
    with caplog.at_level(logging.WARNING):
        assert time_from_image(write_photo(tmp_path / "bad.jpg", stamp="2026:03:01 ??")) == NO_TIME
    assert len(caplog.records) == 1
    with pytest.raises(InputError, match="outside 1900–2100"):
        time_from_image(write_photo(tmp_path / "old.jpg", stamp="1850:03:01 23:00:00"))
    from PIL import Image

    Image.new("L", (16, 12)).save(tmp_path / "plain.png")
    assert time_from_image(tmp_path / "plain.png") == NO_TIME
    assert time_from_image(tmp_path / "missing.fits") == NO_TIME


def test_no_time_has_no_julian_year():
    assert not NO_TIME.known and NO_TIME.source == "none"
    with pytest.raises(InputError, match="no observation time"):
        julian_year(NO_TIME)


def test_one_reader_of_times_takes_every_form():
    """skyfix.obstime.parse_time is the one time reader (issue 28: the simulator had its own): ISO
    text, a Julian epoch as text or a number (TT), a datetime, an astropy Time name one instant."""
    from astropy.time import Time

    iso = parse_time("2026-03-01T22:00:00Z")
    assert parse_time(datetime(2026, 3, 1, 22, tzinfo=timezone.utc)) == parse_time(datetime(2026, 3, 1, 22))
    assert parse_time(Time("2026-03-01T22:00:00", scale="utc")).jd_tt == iso.jd_tt
    assert parse_time(datetime(2026, 3, 1, 22)).jd_tt == iso.jd_tt
    assert parse_time(2025.5).jd_tt == parse_time("J2025.5").jd_tt
    assert julian_year(parse_time(np.float64(2025.5))) == pytest.approx(2025.5, abs=1e-12)
    with pytest.raises(InputError, match="finite"):
        parse_time(float("nan"))
    with pytest.raises(InputError, match="1900"):
        parse_time(1800.0)
