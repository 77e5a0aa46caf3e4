"""Writing simulated frames: the image (FITS with the truth in the header, or 16-bit PNG/TIFF)
and the truth JSON beside it (``sim.fits`` → ``sim.truth.json``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from skyfix.errors import SimulationError
from skyfix.obstime import later, parse_time

__all__ = ["write_frame", "truth_path", "read_truth"]


def truth_path(image_path: str | Path) -> Path:
    """The truth JSON path for an image path: ``dir/name.ext`` → ``dir/name.truth.json``."""
    p = Path(image_path)
    return p.with_suffix(".truth.json")


def read_truth(path: str | Path) -> dict:
    """The truth dict written beside an image (give the image or the JSON path)."""
    p = Path(path)
    if not p.name.endswith(".truth.json"):
        p = truth_path(p)
    try:
        return json.loads(p.read_text())
    except (OSError, ValueError) as exc:
        raise SimulationError(f"cannot read truth file {p}: {exc}") from None


def _fits_header(truth: dict):
    from astropy.io import fits

    hdr = fits.Header()
    # FITS: DATE-OBS is the exposure's start, DATE-AVG its middle (what skyfix reads first); the
    # truth's time is the middle (both were the middle's before, half an exposure late as read).
    # Only a frame whose stars were aberrated (an observer velocity) carries them: a solver that
    # reads a time removes the aberration of that moment, which a frame rendered at the catalogue
    # places does not show (20″ off). Its time is SIMDATE instead, which no solver reads.
    if truth.get("observer_velocity_km_s") is None:
        hdr["SIMDATE"] = (truth["time"].rstrip("Z"), "mid-exposure (UTC); stars not aberrated")
    else:
        start = later(parse_time(truth["time"]), -0.5 * float(truth["exposure_s"]))
        hdr["DATE-OBS"] = (start.iso.rstrip("Z"), "exposure start (UTC)")
        hdr["DATE-AVG"] = (truth["time"].rstrip("Z"), "mid-exposure time (UTC)")
    hdr["EXPTIME"] = (truth["exposure_s"], "exposure, s")
    hdr["TRU_RA"] = (truth["ra_deg"], "truth boresight RA, deg (ICRS)")
    hdr["TRU_DEC"] = (truth["dec_deg"], "truth boresight Dec, deg (ICRS)")
    hdr["TRU_ROLL"] = (truth["roll_deg"], "truth roll, deg (image-up from N through E)")
    for k, q in zip("XYZW", truth["quaternion_xyzw"], strict=True):
        hdr[f"TRU_Q{k}"] = (q, "truth attitude quaternion (scalar last)")
    if truth.get("rate_rad_s") is not None:
        for k, r in zip("XYZ", truth["rate_rad_s"], strict=True):
            hdr[f"RATE_{k}"] = (r, "body rate about camera axis, rad/s")
    hdr["SEED"] = (truth["seed"], "noise seed")
    hdr["FRAME"] = (truth["frame_index"], "frame index in the sequence")
    hdr["NSTARS"] = (len(truth["stars"]), "catalogue stars in the frame")
    cam = truth["camera"]
    for key, fits_key in (("width", "CAM_W"), ("height", "CAM_H"), ("fx", "CAM_FX"), ("fy", "CAM_FY"),
                          ("cx", "CAM_CX"), ("cy", "CAM_CY"), ("skew", "CAM_SKEW"), ("k1", "CAM_K1"),
                          ("k2", "CAM_K2"), ("k3", "CAM_K3"), ("p1", "CAM_P1"), ("p2", "CAM_P2")):
        if key in cam:
            hdr[fits_key] = (cam[key], f"camera {key} (0-based pixels)")
    sen = truth["sensor"]
    hdr["GAIN"] = (sen["gain_e_per_adu"], "electrons per ADU")
    hdr["RDNOISE"] = (sen["read_noise_e"], "read noise, electrons")
    hdr["BIAS"] = (sen["bias_adu"], "bias, ADU")
    hdr["QE"] = (sen["qe"], "quantum efficiency x fill factor")
    hdr["FULLWELL"] = (sen["full_well_e"], "full well, electrons")
    hdr["BITDEPTH"] = (sen["bit_depth"], "ADC bits")
    hdr["DARKCUR"] = (sen["dark_current_e_s"], "dark current, e-/s")
    hdr["PSF_FWHM"] = (truth["optics"]["psf_fwhm_px"], "PSF FWHM at the centre, px")
    hdr["APERTURE"] = (truth["optics"]["aperture_mm"], "aperture diameter, mm")
    hdr["TRUTH"] = ("see .truth.json", "full truth file beside this image")
    return hdr


def write_frame(frame, path: str | Path) -> tuple[Path, Path]:
    """Write ``frame.image`` to ``path`` (.fits/.fit/.fts, .png, .tif/.tiff by suffix) and its
    truth to ``path.with_suffix('.truth.json')``. Returns both paths.

    PNG and TIFF are 16-bit greyscale (float images are rounded and clipped to 0–65535), 8-bit for
    an 8-bit (JPEG-delivered) frame.
    """
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in (".fits", ".fit", ".fts", ".png", ".tif", ".tiff"):
        raise SimulationError(f"cannot write {p.name}: use .fits, .png or .tif")
    if not p.parent.exists():
        raise SimulationError(f"output folder {p.parent} does not exist")
    img = np.asarray(frame.image)
    if ext in (".fits", ".fit", ".fts"):
        from astropy.io import fits

        fits.PrimaryHDU(img, header=_fits_header(frame.truth)).writeto(p, overwrite=True)
    else:
        keep = img.dtype in (np.uint8, np.uint16)
        img16 = img if keep else np.clip(np.rint(img), 0, 65535).astype(np.uint16)
        if ext == ".png":
            from PIL import Image

            Image.fromarray(img16).save(p)
        else:
            import tifffile

            tifffile.imwrite(p, img16)
    tp = truth_path(p)
    tp.write_text(json.dumps(frame.truth, indent=1))
    return p, tp
