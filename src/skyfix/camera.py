"""Camera model: intrinsics and a projection by name — ``pinhole`` with OpenCV's Brown–Conrady
distortion, or ``kannala-brandt`` (OpenCV's ``cv::fisheye``; all ``k = 0`` is the equidistant
fisheye) — pixel <-> ray, TOML I/O.

Conventions (docs/design.md#conventions): pixel ``(x, y)`` = (column, row), 0-based, ``(0, 0)`` is the centre
of the top-left pixel. Camera ``+z`` is the boresight, ``+x`` toward increasing column,
``+y`` toward increasing row. ``x_n = X/Z``, ``y_n = Y/Z``; the projection's distortion acts on
``(x_n, y_n)``; ``u = fx·x_d + s·y_d + cx``, ``v = fy·y_d + cy``. The formulas are
:mod:`skyfix._kernels.lens`'s (docs/design.md#the-camera-model).
"""

from __future__ import annotations

import dataclasses
import json
import math
import operator
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from skyfix._kernels import lens
from skyfix.errors import CameraError, unknown_name

__all__ = ["Camera", "MAX_FOV_DEG", "PRESETS", "PROJECTIONS", "PROJECTION_ALIASES", "Projection",
           "camera_from_preset"]


class Projection(NamedTuple):
    """A projection's kernel code (the number at ``lens.PROJECTION``) and its distortion
    coefficients (Camera fields, written to TOML in this order)."""

    code: float
    coefficients: tuple[str, ...]


# The projections by name (docs/design.md#the-camera-model).
PROJECTIONS: dict[str, Projection] = {
    "pinhole": Projection(lens.PINHOLE, ("k1", "k2", "k3", "p1", "p2")),
    "kannala-brandt": Projection(lens.KANNALA_BRANDT, ("k1", "k2", "k3", "k4")),
}
# Other names a camera file may give: equidistant is Kannala–Brandt with every k = 0.
PROJECTION_ALIASES = {"equidistant": "kannala-brandt"}
# The widest horizontal field (degrees, through the principal point) of each projection: a pinhole
# stops short of 180°; a fisheye's frame may reach past its image circle to θ < 180° at the side
# edges (an all-sky lens's circle inside a wide sensor: docs/all-sky.md).
MAX_FOV_DEG = {"pinhole": 170.0, "kannala-brandt": 360.0}
_PROJECTION_OF_CODE = {p.code: name for name, p in PROJECTIONS.items()}
_KNOWN_PROJECTIONS = (*PROJECTIONS, *PROJECTION_ALIASES)

# The camera's floating-point fields: its numbers for kernels less the projection's code.
_FLOAT_KEYS = tuple(k for k in lens.CAMERA_NUMBERS if k != "projection_code")
_float_values = operator.attrgetter(*_FLOAT_KEYS)
_INTRINSICS = ("fx", "fy", "cx", "cy", "skew")


@dataclass(frozen=True)
class Camera:
    """Intrinsics (pixels), a projection by name (:data:`PROJECTIONS`) and its distortion
    coefficients, OpenCV's meaning: for ``pinhole`` Brown–Conrady's ``k1, k2, k3, p1, p2``
    (``k4`` is 0), for ``kannala-brandt`` the θ polynomial's ``k1 … k4`` (``p1, p2`` are 0).
    ``projection="equidistant"`` is kept as ``kannala-brandt`` with every ``k = 0``."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    skew: float = 0.0
    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    name: str = ""
    pixel_pitch_um: float | None = None
    focal_length_mm: float | None = None
    k4: float = 0.0
    projection: str = "pinhole"

    def __post_init__(self) -> None:
        if self.projection != "pinhole" or self.k4 != 0.0:
            self._check_projection()
        if not (int(self.width) > 0 and int(self.height) > 0):
            raise CameraError(f"camera size must be positive, got {self.width}x{self.height}")
        if not all(math.isfinite(float(v)) for v in _float_values(self)):
            raise CameraError("camera parameters must be finite numbers")
        if self.fx <= 0 or self.fy <= 0:
            raise CameraError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        fov = self.fov_deg
        widest = MAX_FOV_DEG[self.projection]
        if not 0.01 < fov <= widest:
            if math.isnan(fov):
                raise CameraError(f"the {self.projection} polynomial (k1..k4) never reaches the frame's "
                                  "side edge")
            raise CameraError(f"impossible field of view {fov:.4g}° (must be 0.01°–{widest:g}° for the "
                              f"{self.projection} projection)")

    def _check_projection(self) -> None:
        """Resolve an alias to its projection's name; a coefficient of another projection is an error."""
        name = self.projection
        if not isinstance(name, str) or PROJECTION_ALIASES.get(name, name) not in PROJECTIONS:
            raise unknown_name("camera projection", name, _KNOWN_PROJECTIONS)
        if name == "equidistant" and any(getattr(self, k) != 0.0 for k in ("k1", "k2", "k3", "k4")):
            raise CameraError("an equidistant camera has k1 = k2 = k3 = k4 = 0; give projection = "
                              '"kannala-brandt" for a θ polynomial')
        name = PROJECTION_ALIASES.get(name, name)
        object.__setattr__(self, "projection", name)
        coefficients = PROJECTIONS[name].coefficients
        unused = [k for k in ("p1", "p2", "k4") if k not in coefficients and getattr(self, k) != 0.0]
        if unused:
            raise CameraError(f"{' and '.join(unused)} must be 0 for the {name} projection "
                              f"(its coefficients: {', '.join(coefficients)})")

    # --- construction -------------------------------------------------------------------
    @classmethod
    def from_fov(cls, width: int, height: int, fov_deg: float, projection: str = "pinhole",
                 **kw: float) -> Camera:
        """Square-pixel, centred camera whose horizontal field of view is ``fov_deg``.

        Pinhole: ``f = (width/2) / tan(fov/2)`` (Brown–Conrady distortion in ``kw`` left out);
        Kannala–Brandt: ``f = (width/2) / θ_d(fov/2)`` with the polynomial of ``kw`` — for the
        equidistant projection ``(width/2) / (fov/2)``, ``fov`` in radians."""
        widest = MAX_FOV_DEG.get(PROJECTION_ALIASES.get(projection, projection), 170.0)
        if not (isinstance(fov_deg, (int, float)) and 0.01 < fov_deg < widest):
            raise CameraError(f"impossible field of view {fov_deg}° (must be 0.01°–{widest:g}°)")
        half = math.radians(fov_deg) / 2.0
        if projection == "pinhole":
            f = (width / 2.0) / math.tan(half)
        else:
            numbers = np.zeros(len(lens.CAMERA_NUMBERS))
            numbers[[lens.K1, lens.K2, lens.K3, lens.K4]] = [kw.get(k, 0.0) for k in ("k1", "k2", "k3", "k4")]
            f = (width / 2.0) / lens.kb_theta_d(half, numbers)[0]
        return cls(width=int(width), height=int(height), fx=f, fy=f,
                   cx=(width - 1) / 2.0, cy=(height - 1) / 2.0, projection=projection, **kw)

    @classmethod
    def from_optics(cls, width: int, height: int, focal_length_mm: float, pixel_pitch_um: float,
                    **kw: float) -> Camera:
        """Square-pixel, centred camera from focal length (mm) and pixel pitch (µm)."""
        if focal_length_mm <= 0 or pixel_pitch_um <= 0:
            raise CameraError("focal length and pixel pitch must be positive")
        f = focal_length_mm * 1000.0 / pixel_pitch_um
        return cls(width=int(width), height=int(height), fx=f, fy=f,
                   cx=(width - 1) / 2.0, cy=(height - 1) / 2.0,
                   focal_length_mm=focal_length_mm, pixel_pitch_um=pixel_pitch_um, **kw)

    def replace(self, **changes: float) -> Camera:
        """A copy with some fields changed (checked as a new Camera is; a quarter of
        ``dataclasses.replace``'s cost, which the final fit pays several times a solve)."""
        unknown = changes.keys() - _FIELD_NAMES
        if unknown:
            if "projection_code" in changes:  # the kernels' numbers given back (calibrate.py)
                changes = dict(changes)
                changes["projection"] = _projection_of_code(changes.pop("projection_code"))
                unknown = changes.keys() - _FIELD_NAMES
            if unknown:
                raise TypeError(f"Camera has no field {', '.join(sorted(unknown))}")
        new = object.__new__(Camera)
        new.__dict__.update(self.__dict__)
        new.__dict__.update(changes)
        new.__post_init__()
        return new

    def scaled_focal(self, factor: float) -> Camera:
        """A copy with both focal lengths multiplied by ``factor``."""
        return self.replace(fx=self.fx * factor, fy=self.fy * factor)

    # --- derived ------------------------------------------------------------------------
    @property
    def projection_code(self) -> float:
        """The projection's number among the kernels' (``lens.PINHOLE``, ``lens.KANNALA_BRANDT``)."""
        return PROJECTIONS[self.projection].code

    def _angle(self, rd: float) -> float:
        """Angle (rad) from the boresight of distorted normalised radius ``rd``: pinhole
        ``atan rd`` (Brown–Conrady left out), Kannala–Brandt the θ of ``θ_d = rd`` — or, past the
        polynomial's reach, that reach (:func:`_kb_reach`) when it covers the hemisphere (an
        all-sky lens on a frame wider than its image circle); NaN when it falls short of it."""
        if self.projection == "pinhole":
            return math.atan(rd)
        numbers = self.numbers()
        theta = float(lens.kb_theta(float(rd), numbers))
        if math.isnan(theta) and math.isfinite(rd):
            reach = _kb_reach(numbers)
            return reach if reach >= math.pi / 2.0 else math.nan
        return theta

    @property
    def fov_deg(self) -> float:
        """Horizontal field of view through the principal point, degrees (centred; pinhole
        without its distortion, Kannala–Brandt with its polynomial)."""
        return math.degrees(2.0 * self._angle((self.width / 2.0) / self.fx))

    @property
    def fov_diagonal_deg(self) -> float:
        """Diagonal field of view, degrees (centred; as :attr:`fov_deg`). A fisheye's may pass 180°."""
        half = math.hypot(self.width / self.fx, self.height / self.fy) / 2.0
        return math.degrees(2.0 * self._angle(half))

    @property
    def has_distortion(self) -> bool:
        """Whether any distortion coefficient is nonzero (for ``kannala-brandt``: whether it is
        more than the equidistant projection)."""
        return any(getattr(self, k) != 0.0 for k in ("k1", "k2", "k3", "k4", "p1", "p2"))

    @property
    def plate_scale_rad(self) -> float:
        """Angular size of one pixel at the centre, radians."""
        return 1.0 / math.sqrt(self.fx * self.fy)

    # --- distortion and projection: the arithmetic is skyfix._kernels.lens's, shared with
    # every kernel that projects ----------------------------------------------------------
    def numbers(self) -> np.ndarray:
        """The twelve numbers kernels take for this camera (``skyfix._kernels.lens.CAMERA_NUMBERS``)."""
        return lens.camera_numbers(self)

    def distort(self, xn: np.ndarray, yn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distorted normalised coordinates of normalised ``(xn, yn)`` (the projection's)."""
        if self.projection == "pinhole" and not self.has_distortion:
            return xn, yn
        xn, yn = np.broadcast_arrays(np.asarray(xn, dtype=np.float64), np.asarray(yn, dtype=np.float64))
        xd, yd = lens.distort_points(np.ascontiguousarray(xn.ravel()), np.ascontiguousarray(yn.ravel()),
                                     self.numbers())
        return xd.reshape(xn.shape), yd.reshape(yn.shape)

    def undistort(self, xd: np.ndarray, yd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Invert :meth:`distort` (Brown–Conrady converged to 1e-5 px; Kannala–Brandt to 1e-14 rad,
        NaN past 90° from the boresight)."""
        if self.projection == "pinhole" and not self.has_distortion:
            return xd, yd
        xd, yd = np.broadcast_arrays(np.asarray(xd, dtype=np.float64), np.asarray(yd, dtype=np.float64))
        xn, yn = lens.undistort(np.ascontiguousarray(xd.ravel()), np.ascontiguousarray(yd.ravel()),
                                self.numbers())
        return xn.reshape(xd.shape), yn.reshape(yd.shape)

    def pixel_to_normalized(self, xy: np.ndarray) -> np.ndarray:
        """Undistorted normalised coordinates (N, 2) ``(X/Z, Y/Z)`` of pixels (N, 2)."""
        xy = np.asarray(xy, dtype=np.float64)
        xn, yn = lens.pixels_to_normalized(np.ascontiguousarray(xy.reshape(-1, 2)), self.numbers())
        return np.stack([xn, yn], axis=-1).reshape(xy.shape)

    def pixel_to_ray(self, xy: np.ndarray) -> np.ndarray:
        """Unit rays (N, 3) in the camera frame for pixel positions (N, 2) (Kannala–Brandt: also
        past 90° from the boresight)."""
        xy = np.asarray(xy, dtype=np.float64)
        rays = lens.pixel_rays(np.ascontiguousarray(xy.reshape(-1, 2)), self.numbers())
        return rays.reshape(xy.shape[:-1] + (3,))

    def ray_to_pixel(self, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel positions (N, 2) of camera-frame rays (N, 3), and a mask of rays in front (Z > 1e-9;
        the model projects no ray at 90° or more from the boresight)."""
        rays = np.asarray(rays, dtype=np.float64)
        uv, front = lens.project_rays(np.ascontiguousarray(rays.reshape(-1, 3)), self.numbers())
        return uv.reshape(rays.shape[:-1] + (2,)), front.reshape(rays.shape[:-1])

    def in_frame(self, xy: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Mask of pixel positions inside the frame (pixel centres' extent ± 0.5 px, less a margin)."""
        xy = np.asarray(xy)
        return ((xy[..., 0] >= -0.5 + margin) & (xy[..., 0] <= self.width - 0.5 - margin)
                & (xy[..., 1] >= -0.5 + margin) & (xy[..., 1] <= self.height - 0.5 - margin))

    # --- TOML ---------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The ``[camera]`` table (docs/design.md#camera-file-toml) as a dict: what
        :meth:`to_toml` writes and :meth:`from_dict` reads (the ``camera`` field of a solve's JSON)."""
        table: dict = {"name": self.name} if self.name else {}
        table.update(width=int(self.width), height=int(self.height))
        if self.projection != "pinhole":
            table["projection"] = self.projection
        for k in _INTRINSICS + PROJECTIONS[self.projection].coefficients:
            table[k] = float(getattr(self, k))
        for k in ("pixel_pitch_um", "focal_length_mm"):
            if getattr(self, k) is not None:
                table[k] = float(getattr(self, k))
        return table

    def to_toml(self) -> str:
        """The ``[camera]`` table (:meth:`to_dict`) as TOML text."""
        lines = ["[camera]"]
        for k, v in self.to_dict().items():
            lines.append(f"{k} = {json.dumps(v) if isinstance(v, str) else repr(v)}")
        return "\n".join(lines) + "\n"

    def save(self, path: str | Path) -> None:
        Path(path).write_text(self.to_toml())

    @classmethod
    def from_toml(cls, text: str) -> Camera:
        import tomllib  # here: a solve with no camera file does without it

        try:
            table = tomllib.loads(text)["camera"]
        except (tomllib.TOMLDecodeError, KeyError, TypeError) as exc:
            raise CameraError(f"not a camera file ({exc.__class__.__name__}: {exc})") from None
        return cls.from_dict(table)

    @classmethod
    def from_dict(cls, table: dict) -> Camera:
        """Camera from a ``[camera]`` table; ``fx`` may be replaced by ``fov_deg`` or by
        ``focal_length_mm`` with ``pixel_pitch_um``; ``projection`` names the projection
        (:data:`PROJECTIONS`, :data:`PROJECTION_ALIASES`; default ``pinhole``)."""
        table = dict(table)
        try:
            width, height = int(table.pop("width")), int(table.pop("height"))
        except (KeyError, TypeError, ValueError):
            raise CameraError("camera file needs integer width and height") from None
        known = {f.name for f in dataclasses.fields(cls)} | {"fov_deg"}
        unknown = set(table) - known
        if unknown:
            raise CameraError(f"unknown camera keys: {', '.join(sorted(unknown))}")
        try:
            if "fx" not in table:
                if "fov_deg" in table:
                    projection = str(table.get("projection", "pinhole"))
                    ks = {} if projection == "pinhole" else {
                        k: float(table[k]) for k in ("k1", "k2", "k3", "k4") if k in table}
                    base = cls.from_fov(width, height, float(table.pop("fov_deg")), projection=projection,
                                        **ks)
                elif "focal_length_mm" in table and "pixel_pitch_um" in table:
                    base = cls.from_optics(width, height, float(table["focal_length_mm"]),
                                           float(table["pixel_pitch_um"]))
                else:
                    raise CameraError("camera file needs fx/fy, fov_deg, or focal_length_mm"
                                      " with pixel_pitch_um")
                table.setdefault("fx", base.fx)
                table.setdefault("fy", base.fy)
            table.pop("fov_deg", None)
            table.setdefault("fy", table["fx"])
            table.setdefault("cx", (width - 1) / 2.0)
            table.setdefault("cy", (height - 1) / 2.0)
            kw = {k: (float(v) if k in _FLOAT_KEYS or k in ("pixel_pitch_um", "focal_length_mm")
                      else str(v)) for k, v in table.items()}
        except (TypeError, ValueError) as exc:
            raise CameraError(f"bad camera value: {exc}") from None
        return cls(width=width, height=height, **kw)

    @classmethod
    def load(cls, path: str | Path) -> Camera:
        """A camera from a TOML file (``[camera]``), or — when ``path`` is no file and does not
        end in ``.toml`` — from a preset name, as every ``--camera`` option takes: a bundled
        hardware preset (:mod:`skyfix.presets`, e.g. ``"sunsat"``, ``"generic"``) or one of
        :data:`PRESETS`."""
        p = Path(path)
        text = str(path)
        if not text.lower().endswith(".toml") and not p.exists():
            from skyfix.presets import load_preset, preset_names

            if text.lower().strip() in preset_names():
                return cls.from_dict(load_preset(text)["camera"])
            if text.lower().strip() in PRESETS:
                return camera_from_preset(text)
            raise unknown_name("camera preset or file", text, sorted({*preset_names(), *PRESETS}))
        try:
            text = p.read_text()
        except (OSError, UnicodeDecodeError) as exc:
            raise CameraError(f"cannot read camera file {p}: {exc}") from None
        return cls.from_toml(text)


_FIELD_NAMES = frozenset(f.name for f in dataclasses.fields(Camera))


def _kb_reach(numbers: np.ndarray) -> float:
    """The largest angle (rad, ≤ π) that a Kannala–Brandt polynomial maps outward: where ``θ_d``
    stops growing (sampled every 0.125°), or π."""
    theta = np.linspace(0.0, math.pi, 1441)
    grows = np.diff(lens.kb_theta_d(theta, numbers)[0]) > 0.0
    return float(theta[np.argmin(grows)]) if not grows.all() else math.pi


def _projection_of_code(code: float) -> str:
    try:
        return _PROJECTION_OF_CODE[float(code)]
    except (KeyError, TypeError, ValueError):
        raise unknown_name("camera projection code", code, map(str, _PROJECTION_OF_CODE)) from None


# The seeds' cameras (docs/seeds.md#the-seed-cameras); sizes and optics as the theses state them.
PRESETS: dict[str, dict] = {
    # Thesis 000: Aptina MT9V022 752×480, 6 µm pixels, 8.5 mm f/1.3 — the thesis's checkerboard
    # calibration (§5.2: fx 8.63 mm, fy 8.56 mm; Bouguet kc = k1, k2, p1, p2, k3 as OpenCV's); it
    # gives no principal point, so the centre.
    "mt9v022": dict(name="MT9V022 + 8.5 mm f/1.3", width=752, height=480,
                    fx=1438.3333333333333, fy=1426.6666666666667, k1=-0.3686, k2=0.3148, p1=-0.0023,
                    p2=0.0003, focal_length_mm=8.5, pixel_pitch_um=6.0),
    # Thesis 002: Cypress HAS2 1024×1024, 18 µm pixels (ExoplanetSat star camera).
    "has2": dict(name="Cypress HAS2 + 85 mm", width=1024, height=1024,
                 focal_length_mm=85.0, pixel_pitch_um=18.0),
    # Thesis 002: the OV5642 air-bearing testbed imager, 2560×1920 window, 1.4 µm, 85 mm lens.
    "ov5642": dict(name="OV5642 + 85 mm", width=2560, height=1920,
                   focal_length_mm=85.0, pixel_pitch_um=1.4),
    # Thesis 003: Aptina MT9P031 2592×1944, 2.2 µm, 6 mm f/2.5 — the thesis's 12.5 mm-grid
    # calibration (Table 4.4; Bouguet kc = k1, k2, p1, p2 as OpenCV's).
    "mt9p031": dict(name="Aptina MT9P031 + 6 mm f/2.5", width=2592, height=1944,
                    fx=2745.88, fy=2747.75, cx=1351.9, cy=975.691, k1=-0.1755, k2=0.1983,
                    p1=0.0002264, focal_length_mm=6.0, pixel_pitch_um=2.2),
    # Thesis 003: Droid X2 phone camera (OV8812) 3264×2448, 1.4 µm, 5 mm f/2.6 — the thesis's
    # 6 mm-grid calibration (Table 4.3).
    "droid_x2": dict(name="Droid X2 (OV8812) + 5 mm f/2.6", width=3264, height=2448,
                     fx=3520.75, fy=3521.15, cx=1620.66, cy=1214.52, k1=0.1043, k2=-0.4592,
                     focal_length_mm=5.0, pixel_pitch_um=1.4),
    # Thesis 004: Sunsat Sony ICX059AL 752×582, 6.5 µm (h) × 6.25 µm (v), 25 mm f/1.4:
    # 11.17° × 8.32° as quoted.
    "sunsat": dict(name="Sunsat Sony ICX059AL + 25 mm f/1.4", width=752, height=582,
                   fx=25000.0 / 6.5, fy=25000.0 / 6.25, focal_length_mm=25.0, pixel_pitch_um=6.5),
    # A generic modern CMOS star camera (1280×960, 3.75 µm, 16 mm: ~17° wide).
    "generic": dict(name="generic CMOS 1280x960", width=1280, height=960,
                    focal_length_mm=16.0, pixel_pitch_um=3.75),
}


def camera_from_preset(name: str) -> Camera:
    """A :class:`Camera` from a preset name in :data:`PRESETS`."""
    try:
        spec = dict(PRESETS[name.lower()])
    except KeyError:
        raise unknown_name("camera preset", name, PRESETS) from None
    return Camera.from_dict(spec)
