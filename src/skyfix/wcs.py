"""FITS WCS of a solution: TAN (pinhole) or ARC (Kannala–Brandt) projection about the optical
axis, SIP for lens distortion.

Pixels: skyfix ``(x, y)`` is 0-based (docs/design.md); FITS pixel ``(p1, p2) = (x + 1, y + 1)``,
with ``p2`` the array row as stored (row 0 first). So ``CRPIX = (cx + 1, cy + 1)``.

Geometry. The pinhole's tangent point is the optical axis, camera ``+z`` = ``A[2]``: that is
``CRVAL``. A sky direction ``r`` has TAN standard coordinates ``ξ = r·E / r·Z``,
``η = r·N / r·Z`` (E, N: east and north at CRVAL) and pinhole coordinates
``x_n = r·X / r·Z``, ``y_n = r·Y / r·Z`` (X, Y: camera axes = ``A[0]``, ``A[1]``). Both pairs
span the same tangent plane, so ``(x_n, y_n) = M (ξ, η)`` with ``M = [[X·E, X·N], [Y·E, Y·N]]``
(orthogonal), and the undistorted pixel offset is ``K₂ (x_n, y_n)`` with
``K₂ = [[fx, s], [0, fy]]``. Hence ``CD = (180/π) (K₂ M)⁻¹`` degrees per pixel. At roll 0
(north up = −y, east left = −x) both ``CD1_1`` and ``CD2_2`` are negative and ``det CD > 0``:
a row-0-on-top image that a FITS viewer shows row 1 at the bottom is the mirrored sky.

Fisheye. FITS ``ARC`` (zenithal equidistant) places a direction at ``ρ`` (its angle from
``CRVAL``) along the same bearing as TAN does at ``tan ρ``: its intermediate coordinates are
``ρ·(ξ, η)/|(ξ, η)|``. The equidistant camera's distorted coordinates are ``θ·(x_n, y_n)/r``,
``θ = ρ`` (skyfix._kernels.lens), so the same ``M`` and ``K₂`` give the same ``CD``: an
equidistant camera (Kannala–Brandt, every ``k = 0``) is exactly ``ARC``, and Kannala–Brandt's
θ polynomial is SIP on top of ``ARC`` — as Brown–Conrady is on top of ``TAN``.

Distortion. SIP's forward polynomials ``A, B`` map the measured pixel offset ``(u, v)`` to
the undistorted one ``(U, V) = (u + f(u, v), v + g(u, v))`` (``K₂`` times the projection's
undistorted coordinates: TAN's ``(x_n, y_n)``, ARC's ``θ·(x_n, y_n)/r``); the inverse
``AP, BP`` map back. Both are fitted by least squares to the camera model over the frame,
raising the order until the worst residual over the frame is below ``tol_px``.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from astropy.io import fits
from astropy.wcs import WCS, FITSFixedWarning

from skyfix.camera import Camera
from skyfix.geometry import vector_to_radec

__all__ = ["solution_wcs", "wcs_header", "write_wcs", "read_wcs"]

# Order 9 covers ordinary lenses to 0.005 px; strong wide-angle distortion (60°, k1 = −0.3)
# needs ~13. Only the lowest order that meets the tolerance is written.
_MAX_SIP_ORDER = 13
# The FITS projection of each camera projection (skyfix.camera.PROJECTIONS).
_FITS_PROJECTION = {"pinhole": "TAN", "kannala-brandt": "ARC"}


def _monomials(u: np.ndarray, v: np.ndarray, order: int) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Design matrix of ``u^p v^q`` for ``2 ≤ p + q ≤ order`` (SIP has no constant or linear terms)."""
    terms = [(p, t - p) for t in range(2, order + 1) for p in range(t, -1, -1)]
    return np.column_stack([u**p * v**q for p, q in terms]), terms


def _fit_sip(u: np.ndarray, v: np.ndarray, du: np.ndarray, dv: np.ndarray, scale: float,
             tol_px: float) -> tuple[np.ndarray, np.ndarray, int, float]:
    """SIP coefficient matrices mapping offsets ``(u, v)`` to corrections ``(du, dv)``.

    Variables are divided by ``scale`` for conditioning and the coefficients scaled back.
    Returns ``(A, B, order, worst residual px)``.
    """
    un, vn = u / scale, v / scale
    for order in range(2, _MAX_SIP_ORDER + 1):
        X, terms = _monomials(un, vn, order)
        coef, *_ = np.linalg.lstsq(X, np.column_stack([du, dv]), rcond=None)
        worst = float(np.max(np.hypot(*(X @ coef - np.column_stack([du, dv])).T)))
        if worst < tol_px:
            break
    A = np.zeros((order + 1, order + 1))
    B = np.zeros((order + 1, order + 1))
    for (p, q), (ca, cb) in zip(terms, coef, strict=True):
        A[p, q] = ca / scale ** (p + q)
        B[p, q] = cb / scale ** (p + q)
    return A, B, order, worst


def _frame_grid(camera: Camera, n: int = 41) -> np.ndarray:
    """Pixel positions (M, 2) on an ``n × n`` grid covering the frame to its outer pixel edges."""
    xs = np.linspace(-0.5, camera.width - 0.5, n)
    ys = np.linspace(-0.5, camera.height - 0.5, n)
    gx, gy = np.meshgrid(xs, ys)
    return np.column_stack([gx.ravel(), gy.ravel()])


def wcs_header(A_icrs_to_cam: np.ndarray, camera: Camera, tol_px: float = 0.005,
               mirrored: bool = False) -> fits.Header:
    """The FITS WCS header cards of :func:`solution_wcs` (TAN or ARC, with SIP when distorted).

    Parameters as :func:`solution_wcs`.
    """
    A = np.asarray(A_icrs_to_cam, dtype=np.float64)
    ra, dec = vector_to_radec(A[2])
    ra, dec = float(ra), float(dec)
    # East and north of TAN's (and ARC's) standard coordinates (LONPOLE 180); also right at a pole.
    east = np.array([-np.sin(ra), np.cos(ra), 0.0])
    north = np.array([-np.sin(dec) * np.cos(ra), -np.sin(dec) * np.sin(ra), np.cos(dec)])
    M = np.array([[A[0] @ east, A[0] @ north], [A[1] @ east, A[1] @ north]])
    K2 = np.array([[camera.fx, camera.skew], [0.0, camera.fy]])
    cd = np.degrees(np.linalg.inv(K2 @ M))

    sip = camera.has_distortion
    code = _FITS_PROJECTION[camera.projection] + ("-SIP" if sip else "")
    h = fits.Header()
    h["WCSAXES"] = 2
    h["CTYPE1"] = f"RA---{code}"
    h["CTYPE2"] = f"DEC--{code}"
    h["CUNIT1"] = "deg"
    h["CUNIT2"] = "deg"
    h["CRVAL1"] = np.degrees(ra)
    h["CRVAL2"] = np.degrees(dec)
    h["CRPIX1"] = camera.cx + 1.0
    h["CRPIX2"] = camera.cy + 1.0
    for i in range(2):
        for j in range(2):
            h[f"CD{i + 1}_{j + 1}"] = cd[i, j]
    h["LONPOLE"] = 180.0
    h["RADESYS"] = "ICRS"
    h["IMAGEW"] = (int(camera.width), "image width, pixels")
    h["IMAGEH"] = (int(camera.height), "image height, pixels")
    if sip:
        _add_sip(h, camera, tol_px)
    if mirrored:
        _mirror_header(h, camera.width)
    return h


def _mirror_header(h: fits.Header, width: int) -> None:
    """Make the header of the flipped frame (``x' = (W − 1) − x``) the frame's own, in place:
    ``CRPIX1`` flipped, the first column of ``CD`` negated, and SIP's terms in ``u^p v^q``
    multiplied by ``(−1)^(p+1)`` (``A``, ``AP``: their output is ``u``) or ``(−1)^p`` (``B``,
    ``BP``), since ``u' = −u``."""
    h["CRPIX1"] = (width + 1.0) - h["CRPIX1"]
    h["CD1_1"] = -h["CD1_1"]
    h["CD2_1"] = -h["CD2_1"]
    for key in list(h.keys()):
        name, _, powers = key.partition("_")
        if name in ("A", "B", "AP", "BP") and powers.count("_") == 1 and powers != "ORDER":
            p = int(powers.split("_")[0])
            odd_output = name in ("A", "AP")
            if (p + odd_output) % 2:
                h[key] = -h[key]
    h["HISTORY"] = "skyfix: a mirror image (solved as the frame flipped left-right)"


def _undistorted(camera: Camera, xy: np.ndarray) -> np.ndarray:
    """The coordinates (M, 2) of pixels ``xy`` in the FITS projection's plane, in focal lengths:
    TAN's ``(X/Z, Y/Z)``, ARC's ``θ·(X, Y)/|(X, Y)|`` (``θ`` the ray's angle from the boresight)."""
    if camera.projection == "pinhole":
        return camera.pixel_to_normalized(xy)
    b = camera.pixel_to_ray(xy)
    rho = np.hypot(b[:, 0], b[:, 1])
    s = np.divide(np.arctan2(rho, b[:, 2]), rho, out=np.ones_like(rho), where=rho > 0)
    return b[:, :2] * s[:, None]


def _add_sip(h: fits.Header, camera: Camera, tol_px: float) -> None:
    """Append SIP forward and inverse polynomials fitted to the camera's distortion (over the
    frame's pixels that the model maps to a ray)."""
    xy = _frame_grid(camera)
    n = _undistorted(camera, xy)
    keep = np.all(np.isfinite(n), axis=1)
    xy, n = xy[keep], n[keep]
    u, v = xy[:, 0] - camera.cx, xy[:, 1] - camera.cy
    U = camera.fx * n[:, 0] + camera.skew * n[:, 1]
    V = camera.fy * n[:, 1]
    scale = 0.5 * max(camera.width, camera.height)
    a, b, order, worst = _fit_sip(u, v, U - u, V - v, scale, tol_px)
    ap, bp, order_p, worst_p = _fit_sip(U, V, u - U, v - V, scale, tol_px)
    h["A_ORDER"] = order
    h["B_ORDER"] = order
    h["AP_ORDER"] = order_p
    h["BP_ORDER"] = order_p
    for name, mat in (("A", a), ("B", b), ("AP", ap), ("BP", bp)):
        for p in range(mat.shape[0]):
            for q in range(mat.shape[1] - p):
                if mat[p, q] != 0.0:
                    h[f"{name}_{p}_{q}"] = mat[p, q]
    model = "Brown-Conrady" if camera.projection == "pinhole" else "Kannala-Brandt"
    h["HISTORY"] = (f"skyfix SIP fit to {model}: order {order}, worst {worst:.2g} px; "
                    f"inverse order {order_p}, worst {worst_p:.2g} px")


def solution_wcs(A_icrs_to_cam: np.ndarray, camera: Camera, tol_px: float = 0.005,
                 mirrored: bool = False) -> WCS:
    """An astropy WCS with the same pixel ↔ sky mapping as the camera model at attitude ``A``.

    Parameters
    ----------
    A_icrs_to_cam : (3, 3) attitude matrix, ``b = A r`` (docs/design.md#attitude-matrix).
    camera : the camera model: TAN for a pinhole, ARC for Kannala–Brandt (equidistant exactly),
        with SIP for distortion (Brown–Conrady, or a θ polynomial beyond equidistant).
    tol_px : worst SIP fit residual over the frame, pixels (sets the polynomial order).
    mirrored : ``A`` and ``camera`` are those of the frame flipped left-right (a Solution's
        ``mirrored``, :mod:`skyfix.parity`): the WCS is made the frame's own (``det CD < 0``).

    Returns
    -------
    astropy.wcs.WCS
        FITS pixel = skyfix pixel + 1 (use ``origin=1`` with ``x + 1``, or ``origin=0`` with ``x``).
    """
    w = WCS(wcs_header(A_icrs_to_cam, camera, tol_px, mirrored))
    w.pixel_shape = (int(camera.width), int(camera.height))
    return w


def write_wcs(path: str | Path, A_icrs_to_cam: np.ndarray, camera: Camera, tol_px: float = 0.005,
              mirrored: bool = False) -> None:
    """Write the WCS as a FITS file holding only a header (like astrometry.net's ``.wcs``);
    ``mirrored`` as :func:`solution_wcs`'s.

    Read it back with ``astropy.wcs.WCS(astropy.io.fits.getheader(path))``.
    """
    hdu = fits.PrimaryHDU(header=wcs_header(A_icrs_to_cam, camera, tol_px, mirrored))
    hdu.writeto(Path(path), overwrite=True)


def read_wcs(path: str | Path) -> WCS:
    """Read a WCS header file written by :func:`write_wcs` (or astrometry.net)."""
    header = fits.getheader(Path(path))
    with warnings.catch_warnings():
        # A header-only file has NAXIS = 0, which astropy reports although the WCS is complete.
        warnings.simplefilter("ignore", FITSFixedWarning)
        w = WCS(header)
    if "IMAGEW" in header and "IMAGEH" in header:
        w.pixel_shape = (int(header["IMAGEW"]), int(header["IMAGEH"]))
    return w
