"""The observation options ``skyfix solve`` and ``skyfix track`` share (issue 24), read in one
place: ``--time``, ``--velocity-kms``, ``--position-km``, ``--site``, ``--weather``, ``--refraction``,
``--mounting`` and ``--apparent``, with the camera file's ``[mounting]`` and ``[exclusion]`` tables
and a preset's exclusion angles (docs/time-and-corrections.md#in-a-solve).

:func:`observation_options` checks them all before any work — each bad value is one line and
exit 2 (a time outside 1900–2100, a latitude of 100°, ``--weather`` without ``--site``, a speed of
c or more, ``--position-km`` without ``--velocity-kms`` or inside the Earth, a malformed mounting)
— and returns the keywords of :func:`skyfix.solve` and :class:`skyfix.track.Tracker`.
"""

from __future__ import annotations

from pathlib import Path

import typer

from skyfix.cli.common import checking, fail
from skyfix.errors import InputError

__all__ = ["OBSERVATION_HELP", "observation_option", "observation_options", "summary_suffix"]

#: The options' help, by flag (both commands declare them with these words).
OBSERVATION_HELP = {
    "--time": "Observation time, ISO 8601 (UTC unless it says so) or a Julian epoch J2026.25 (default: "
              "the image's FITS DATE-OBS or EXIF). Moves the catalogue to it and removes the aberration: "
              "the true attitude.",
    "--velocity-kms": "The camera's velocity relative to the Earth's centre, km/s, GCRS axes (vx,vy,vz): "
                      "its aberration is removed with the Earth's.",
    "--position-km": "The camera's position from the Earth's centre, km, GCRS axes (x,y,z), with "
                     "--velocity-kms: the orbit frame (the body's attitude in it, with a mounting) and the "
                     "Earth's limb.",
    "--site": "A camera on the ground: latitude, east longitude (degrees), height (m). Refraction per "
              "star; the boresight's Alt/Az and place of date are reported.",
    "--weather": "The air at --site: temperature (°C), pressure (hPa), relative humidity (0-1).",
    "--refraction": "Refraction model at --site: erfa (default), bennett (thesis 003), none.",
    "--mounting": "Camera → body rotation: quaternion x,y,z,w or Euler 1-2-3 angles φ,θ,ψ (degrees); "
                  "default: the camera file's [mounting]. The body's attitude is reported.",
    "--apparent": "Report the apparent attitude (against the catalogue places, as plate solvers do) "
                  "instead of the true one.",
}

_METAVARS = {"--time": "ISO8601", "--velocity-kms": "VX,VY,VZ", "--position-km": "X,Y,Z",
             "--site": "LAT,LON,HEIGHT_M", "--weather": "T_C,P_HPA,RH", "--refraction": "MODEL",
             "--mounting": "X,Y,Z,W|PHI,THETA,PSI"}


def observation_option(flag: str):
    """The typer declaration of one observation option (its flag, metavar, help; ``--apparent`` a
    flag, the others text, default None)."""
    if flag == "--apparent":
        return typer.Option(False, flag, help=OBSERVATION_HELP[flag])
    return typer.Option(None, flag, metavar=_METAVARS[flag], help=OBSERVATION_HELP[flag])


def observation_options(time: str | None, velocity_kms: str | None, site: str | None, weather: str | None,
                        refraction: str | None, mounting: str | None, apparent: bool,
                        camera: str | None = None, epoch: float | None = None,
                        position_km: str | None = None) -> dict:
    """The checked keywords for :func:`skyfix.solve` / :class:`skyfix.track.Tracker` (``time``,
    ``observer``, ``site``, ``weather``, ``refraction``, ``apparent``, ``mounting``,
    ``exclusion``); ``position_km`` is ``--position-km``'s value (it needs ``velocity_kms``: with it
    the observer's state, whose orbit frame the body's attitude is also given in);
    ``camera`` is ``--camera``'s value (a file's ``[mounting]`` and
    ``[exclusion]``, or a preset's exclusion angles). A bad value: one line, exit 2."""
    # the corrections load astropy/ERFA: not at every CLI start, and a site's refraction and the
    # body frames (ERFA, TOML) only when a site or a mounting is given (tests/cli/test_cli_start.py)
    from skyfix.corrections.observation import observe
    from skyfix.corrections.observer import parse_state, parse_velocity
    from skyfix.obstime import parse_time

    with checking("--time", time):
        the_time = None if time is None else parse_time(time, "--time")
    try:
        out = dict(time=the_time, observer=None, refraction=refraction or "erfa", apparent=bool(apparent))
        if position_km is not None and velocity_kms is None:
            raise InputError("--position-km needs --velocity-kms: the orbit frame is made from the camera's "
                             "position and velocity")
        if position_km is not None:
            out["observer"] = parse_state(velocity_kms, position_km)
        elif velocity_kms is not None:
            out["observer"] = parse_velocity(velocity_kms)
        out["site"] = out["weather"] = None
        if site is not None or weather is not None:
            from skyfix.corrections.refraction import check_site_weather

            out["site"], out["weather"] = check_site_weather(site, weather, names=("--site", "--weather"))
        if refraction is not None and site is None:
            raise InputError("--refraction needs a --site: refraction depends on where the camera is")
        if mounting is not None:
            from skyfix.frames import Mounting

            out["mounting"] = Mounting.parse(mounting, "--mounting")
        else:
            out["mounting"] = _camera_table(camera, "mounting")
        out["exclusion"] = _camera_table(camera, "exclusion")
        observe(epoch=epoch, **out)  # the combinations: a speed of c with the Earth's, a velocity and a site
    except InputError as exc:
        fail(str(exc))
    return out


def _camera_table(camera: str | None, table: str):
    """A camera file's ``[mounting]`` (a Mounting) or ``[exclusion]`` (its angles), or a preset's
    exclusion angles (its name); None when there are none."""
    from skyfix.corrections.bodies import EXCLUSION_DEG, Exclusion

    if camera is None:
        return None
    if not (camera.endswith(".toml") or Path(camera).is_file()):
        if table != "exclusion":
            return None
        from skyfix.presets import preset_names

        return camera if camera.lower() in preset_names() else None
    if table == "mounting":
        from skyfix.frames import Mounting

        return Mounting.load(camera)
    import tomllib

    try:
        angles = tomllib.loads(Path(camera).read_text(encoding="utf-8")).get("exclusion")
    except (OSError, tomllib.TOMLDecodeError):
        return None  # the camera loader reports the file
    if angles is None:
        return None
    unknown = set(angles) - set(Exclusion._fields)
    if unknown:
        raise InputError(f"{camera}: unknown [exclusion] keys {sorted(unknown)}; known: "
                         f"{', '.join(Exclusion._fields)}")
    return EXCLUSION_DEG._replace(**{k: float(v) for k, v in angles.items()})


def summary_suffix(sol) -> str:
    """What the one-line summary adds for an observation: the time and its source, a site's
    Alt/Az, the frame when apparent."""
    parts = []
    if sol.time:
        parts.append(f"{sol.time} ({sol.time_source})")
    if sol.alt_deg is not None:
        parts.append(f"Alt {sol.alt_deg:.4f}° Az {sol.az_deg:.4f}°")
    if sol.attitude_frame == "apparent" and sol.time:
        parts.append("apparent attitude")
    return "".join(f" | {p}" for p in parts)
