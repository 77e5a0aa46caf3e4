"""Identification methods by name: one interface, one registry (as :data:`skyfix.attitude.METHODS`).

An identification method recognises the stars of one frame, lost in space. It is a callable

.. code-block:: text

    method(xy, width, height, *, fov_deg=None, fov_tolerance_deg=None, camera=None,
           database=None, epoch=None, **options) -> Identification

It takes

- ``xy`` — (N, 2) float centroids in pixels, ``(x, y)`` = (column, row), ``(0, 0)`` the centre
  of the top-left pixel, brightest first. Non-finite rows are skipped; the indices the method
  returns refer to the caller's rows.
- ``width``, ``height`` — the frame's size, pixels.
- what is known of the camera: nothing (the field of view is then found, within what the
  database serves), a horizontal field of view ``fov_deg`` (± ``fov_tolerance_deg``, default
  10 % of it), or a calibrated :class:`~skyfix.camera.Camera` ``camera`` (used as given; it
  overrides ``fov_deg``).
- ``database`` — the :class:`~skyfix.identify.PatternDatabase` (default:
  :func:`~skyfix.identify.default_database`). Its :meth:`~skyfix.identify.PatternDatabase.star_index`
  serves every method's verification; its pattern table, the methods that look patterns up.
- ``epoch`` — Julian year of the catalogue positions returned (default: the database's).
- ``options`` — the method's own keywords (work bounds, tolerances, thresholds), each with a
  documented default; :func:`method_options` lists them.

and returns an :class:`~skyfix.identify.Identification`: ``success`` and ``reason`` (a frame
that cannot be identified is a result with the reason, never an exception; only impossible input
raises, e.g. :class:`~skyfix.errors.CameraError` for an impossible ``fov_deg``), the stars
matched (``star_index`` into ``xy``, with ``catalog_ids``, ``catalog_vectors``, ``catalog_mag``),
the attitude ``A_icrs_to_cam``, the ``camera`` (the one given, or one with the focal length and
k1 fitted), ``prob_false``, the work done, ``method`` (its name here), ``time_s`` and the
refit's ``match_radius_px``. A success must have passed the acceptance rules of
:mod:`skyfix.identify.accept` that apply to it (beyond chance with every candidate counted;
refit beyond chance), so that :func:`skyfix.final_fit.final_fit` and the pipeline can take any
method's result as they take the 4-star method's.

Registered methods (:data:`METHODS`; docs/identification-methods.md describes each):

- ``"quad-hash"`` (the default; also ``"hash"``) — 4-star edge-ratio hashing with binomial
  verification, :func:`skyfix.identify.methods.quad.identify`.
- ``"triangle"`` — triangles of the brightest stars through the pair table, with an honest
  chance test for frames of three or four stars, :func:`skyfix.identify.methods.triangle.identify`.
- The seeds' methods (theses 000 §2.6 and 004 ch. 3): ``"liebe"`` (:mod:`skyfix.identify.methods.liebe`),
  ``"planar"`` (:mod:`skyfix.identify.methods.planar`), ``"area-moment"``
  (:mod:`skyfix.identify.methods.area_moment`), ``"pyramid"`` (:mod:`skyfix.identify.methods.pyramid`),
  ``"grid"`` (:mod:`skyfix.identify.methods.grid`),
  ``"voting"`` (:mod:`skyfix.identify.methods.voting`), ``"van-bezooijen"``
  (:mod:`skyfix.identify.methods.match_groups`).

Examples
--------
>>> from skyfix.identify import METHODS, method_options
>>> list(METHODS)[:3]
['quad-hash', 'hash', 'triangle']
>>> "max_patterns" in method_options("quad-hash")
True
"""

from __future__ import annotations

import functools
import importlib
import inspect
from collections.abc import Iterator, MutableMapping
from typing import Protocol

import numpy as np

from skyfix.camera import Camera
from skyfix.errors import unknown_name
from skyfix.identify.catalogue.database import PatternDatabase
from skyfix.identify.common.result import Identification
from skyfix.identify.methods import quad

__all__ = ["DEFAULT_METHOD", "INTERFACE_KEYWORDS", "METHODS", "IdentifyMethod", "get_method", "identify",
           "method_options"]


class IdentifyMethod(Protocol):
    """The interface every identification method implements (see the module text)."""

    def __call__(self, xy: np.ndarray, width: int, height: int, *, fov_deg: float | None = None,
                 fov_tolerance_deg: float | None = None, camera: Camera | None = None,
                 database: PatternDatabase | None = None, epoch: float | None = None,
                 **options) -> Identification: ...


class _Registry(MutableMapping):
    """``name → method``, each method's module imported the first time its name is looked up: a
    solve imports the methods it runs, not every one (their kernels' set-up costs a process
    start ~0.1 s). Iterating gives the names without importing anything; a method can be
    registered (or replaced) as in a dict, ``METHODS[name] = function``."""

    def __init__(self, modules: dict[str, str]) -> None:
        self._entries: dict[str, str | IdentifyMethod] = dict(modules)  # a str: the module, not yet imported

    def __getitem__(self, name: str) -> IdentifyMethod:
        entry = self._entries[name]
        if isinstance(entry, str):
            entry = self._entries[name] = importlib.import_module(entry).identify
        return entry

    def __setitem__(self, name: str, method: IdentifyMethod) -> None:
        self._entries[name] = method

    def __delitem__(self, name: str) -> None:
        del self._entries[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def __repr__(self) -> str:
        return f"METHODS({', '.join(self._entries)})"


#: The methods by name (each name is its module's ``METHOD``; ``"hash"`` is the 4-star hash too).
METHODS: MutableMapping[str, IdentifyMethod] = _Registry({
    quad.METHOD: "skyfix.identify.methods.quad",
    "hash": "skyfix.identify.methods.quad",
    "triangle": "skyfix.identify.methods.triangle",
    "liebe": "skyfix.identify.methods.liebe",
    "planar": "skyfix.identify.methods.planar",
    "area-moment": "skyfix.identify.methods.area_moment",
    "pyramid": "skyfix.identify.methods.pyramid",
    "grid": "skyfix.identify.methods.grid",
    "voting": "skyfix.identify.methods.voting",
    "van-bezooijen": "skyfix.identify.methods.match_groups",
})
DEFAULT_METHOD = quad.METHOD

# The keywords every method takes (the interface); the rest of a method's keywords are its options.
INTERFACE_KEYWORDS = ("xy", "width", "height", "fov_deg", "fov_tolerance_deg", "camera", "database", "epoch")


def get_method(name: str) -> IdentifyMethod:
    """The method registered as ``name`` (any case).

    Raises
    ------
    skyfix.errors.InputError
        No method has that name (the message lists those that do).
    """
    method = METHODS.get(name.lower()) if isinstance(name, str) else None
    if method is None:
        raise unknown_name("identification method", name, METHODS)
    return method


@functools.cache
def method_options(name: str) -> tuple[str, ...]:
    """The keywords of the method ``name`` beyond the interface's, in its signature's order
    (looked up once: ``inspect.signature`` costs ~0.2 ms)."""
    params = inspect.signature(get_method(name)).parameters
    return tuple(p for p in params if p not in INTERFACE_KEYWORDS)


def identify(xy: np.ndarray, width: int, height: int, *, method: str = DEFAULT_METHOD,
             fov_deg: float | None = None, fov_tolerance_deg: float | None = None,
             camera: Camera | None = None, database: PatternDatabase | None = None,
             epoch: float | None = None, **options) -> Identification:
    """Identify the stars of one frame with the method named ``method`` (see the module text
    for the interface; ``options`` are the method's own, :func:`method_options`).

    Raises
    ------
    skyfix.errors.InputError
        An unknown method.
    """
    found = get_method(method)
    if found is not METHODS[DEFAULT_METHOD]:
        from skyfix import warmup

        warmup.ensure(f"method-{method.lower()}", missing_ok=True)  # its kernels, compiled up front
    return found(xy, width, height, fov_deg=fov_deg, fov_tolerance_deg=fov_tolerance_deg, camera=camera,
                 database=database, epoch=epoch, **options)
