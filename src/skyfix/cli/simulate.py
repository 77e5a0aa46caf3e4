"""``skyfix simulate``: one rendered star image, or a sequence of frames as the camera turns
(a motion profile by name), each with its truth file (docs/simulating.md).

The simulator, the camera model and the geometry (numpy, numba) are imported when the command
runs, not when the command table is set up: every ``skyfix`` start loads this module.
"""

from __future__ import annotations

import contextlib
import math
from pathlib import Path

import typer

from skyfix.cli.common import (
    VERBOSE,
    add_verbosity,
    checking,
    compile_notice,
    counter_bar,
    fail,
    guarded,
    load_camera,
    prepare_outputs,
)
from skyfix.errors import SimulationError, UnknownNameError
from skyfix.validate import check_count, check_positive

__all__ = ["simulate"]


def _camera_arg(value: str):
    """``--camera``: a TOML file's path or a preset's name, checked (a name no preset has, or a file
    that is no camera file, fails); the simulator takes the sensor, optics and exposure with it — a
    preset's, or the file's own ``[sensor]``, ``[optics]`` and ``[defaults]`` tables when it has them
    (:func:`skyfix.simulate.resolve_setup`; before, a file's were ignored for the generic preset's)."""
    with checking("--camera", value):
        load_camera(value)
    return Path(value) if value.endswith(".toml") or Path(value).is_file() else value


def _sensor_arg(value: str | None):
    """``--sensor``: the Sensor of a TOML file, or a preset's name (checked)."""
    if value is None:
        return None
    from skyfix.simulate import Sensor

    with checking("--sensor", value):
        if value.endswith(".toml") or Path(value).is_file():
            return Sensor.load(value)
        Sensor.from_preset(value)
    return value


@guarded
def simulate(
    out_dir: Path = typer.Argument(None, metavar="[OUT_DIR]",
                                   help="Folder for the frames (frame-0000.fits … with NAME.truth.json "
                                        "beside each); or give one image file with -o."),
    ra: float = typer.Option(None, "--ra", help="Boresight right ascension, degrees (unless --allsky)."),
    dec: float = typer.Option(None, "--dec", help="Boresight declination, degrees (unless --allsky)."),
    roll: float = typer.Option(0.0, "--roll", help="Roll (PA of image-up from north through east), degrees."),
    camera: str = typer.Option("generic", "--camera", help="Camera preset name or TOML file."),
    sensor: str = typer.Option(None, "--sensor", help="Sensor preset name or TOML file."),
    exposure: float = typer.Option(None, "--exposure", help="Exposure, seconds (default: the preset's)."),
    time: str = typer.Option(None, "--time",
                             help="Mid-exposure time of the first frame, ISO 8601 (UTC unless it says so) "
                                  "or a Julian epoch J2026.25 (default: now)."),
    velocity_kms: str = typer.Option(None, "--velocity-kms", metavar="VX,VY,VZ",
                                     help="The camera's velocity relative to the Earth's centre, km/s, "
                                          "GCRS axes (an orbit); the stars are aberrated by it and by "
                                          "the Earth's own velocity at the time (default: 0,0,0)."),
    seed: int = typer.Option(0, "--seed", help="Noise seed (same seed, same image, bit for bit)."),
    false_stars: int = typer.Option(0, "--false-stars", help="False stars / debris to add."),
    hot_pixels: int = typer.Option(0, "--hot-pixels", help="Hot pixels to add."),
    frames: int = typer.Option(1, "--frames", help="Number of frames (a sequence when > 1)."),
    fps: float = typer.Option(10.0, "--fps", help="Frame rate of a sequence, frames per second."),
    output: Path = typer.Option(None, "--output", "-o",
                                help="Image file: .fits, .png or .tif (a sequence: NAME-0000.fits …)."),
    profile: str = typer.Option(None, "--profile", metavar="NAME", rich_help_panel="Motion",
                                help="How the camera turns: constant (--rate-dps), inertial-axis, slew, "
                                     "pendulum (docs/simulating.md). Default: constant."),
    rate_dps: str = typer.Option(None, "--rate-dps", metavar="WX,WY,WZ", rich_help_panel="Motion",
                                 help="constant: body rate wx,wy,wz about the camera axes, deg/s; "
                                      "inertial-axis: the rate about --axis, deg/s."),
    axis: str = typer.Option(None, "--axis", metavar="RA,DEC", rich_help_panel="Motion",
                             help="inertial-axis: the ICRS axis as RA,DEC, degrees."),
    rotation_deg: str = typer.Option(None, "--rotation-deg", metavar="X,Y,Z", rich_help_panel="Motion",
                                     help="slew: the turn as a rotation vector x,y,z in the camera axes, "
                                          "degrees (0,10,0: 10° about camera y). Default 0,10,0."),
    max_rate_dps: float = typer.Option(None, "--max-rate-dps", rich_help_panel="Motion",
                                       help="slew: the coasting rate, deg/s (default 2)."),
    accel_dps2: float = typer.Option(None, "--accel-dps2", rich_help_panel="Motion",
                                     help="slew: the (peak) acceleration, deg/s² (default 1)."),
    smooth: bool = typer.Option(False, "--smooth", rich_help_panel="Motion",
                                help="slew: ramp the rate as a half cosine (no jump in acceleration) "
                                     "instead of a trapezoid."),
    start: float = typer.Option(None, "--start", rich_help_panel="Motion",
                                help="slew: when it starts, seconds after the first frame (default 0)."),
    amplitude_deg: str = typer.Option(None, "--amplitude-deg", metavar="X,Y,Z", rich_help_panel="Motion",
                                      help="pendulum: amplitude about camera x,y,z, degrees (default "
                                           "0.5,2,0.2: mostly pitch, as thesis 002's air bearing)."),
    period: float = typer.Option(None, "--period", rich_help_panel="Motion",
                                 help="pendulum: the damped period, seconds (default 8)."),
    damping: float = typer.Option(None, "--damping", rich_help_panel="Motion",
                                  help="pendulum: the damping ratio, 0 to < 1 (default 0.05)."),
    phase_deg: str = typer.Option(None, "--phase-deg", metavar="X,Y,Z", rich_help_panel="Motion",
                                  help="pendulum: phase of each axis, degrees (default 0,0,90: through "
                                       "equilibrium at the first frame, yaw a quarter period behind)."),
    seeing: float = typer.Option(0.0, "--seeing", rich_help_panel="What real frames carry",
                                 help="Seeing disc FWHM, arcsec, added in quadrature to the PSF (0: none)."),
    scintillation: bool = typer.Option(False, "--scintillation", rich_help_panel="What real frames carry",
                                       help="Jitter each star's flux by Young's scintillation (aperture, "
                                            "exposure, --airmass, --site-altitude)."),
    airmass: float = typer.Option(1.0, "--airmass", rich_help_panel="What real frames carry",
                                  help="Airmass of the field, 1–40 (scintillation)."),
    site_altitude: float = typer.Option(0.0, "--site-altitude", rich_help_panel="What real frames carry",
                                        help="The site's altitude, m (scintillation)."),
    psf_growth: float = typer.Option(None, "--psf-growth", rich_help_panel="What real frames carry",
                                     help="PSF σ at the field corner (1 + G) times the centre's, both axes "
                                          "(default: the preset's, usually 0)."),
    jpeg_quality: int = typer.Option(None, "--jpeg-quality", rich_help_panel="What real frames carry",
                                     help="Deliver the frame as an 8-bit JPEG of this quality, 1–95, decoded "
                                          "(the image is then 8-bit)."),
    allsky: str = typer.Option(None, "--allsky", metavar="LAT,LON", rich_help_panel="All-sky",
                               help="An all-sky frame from this site (degrees) at --time, looking up "
                                    "(instead of --ra/--dec): a fisheye's image circle in the --camera's "
                                    "frame size, a random skyline and light dome (--seed); solve it with "
                                    "--site LAT,LON --refraction none (docs/all-sky.md)."),
    lens_fov: float = typer.Option(180.0, "--lens-fov", rich_help_panel="All-sky",
                                   help="The all-sky lens's field across its image circle, degrees "
                                        "(90–220)."),
    verbose: int = VERBOSE,
) -> None:
    """Render a simulated star image, or a sequence of frames as the camera turns, and write the
    truth beside each image (NAME.truth.json: attitude, body rate, time, every star)."""
    from skyfix.geometry import attitude_from_radec_roll
    from skyfix.simulate import render, render_sequence, write_frame

    add_verbosity(verbose)
    frames = check_count(frames, "--frames")
    check_positive(fps, "--fps")
    if exposure is not None:
        check_positive(exposure, "--exposure")
    for name, value in (("--false-stars", false_stars), ("--hot-pixels", hot_pixels), ("--seed", seed)):
        check_count(value, name, minimum=0)
    if allsky is not None:
        _simulate_allsky(allsky, lens_fov, out_dir, output, camera, sensor, exposure, time, seed, frames,
                         ra, dec)
        return
    if ra is None or dec is None:
        fail("give the boresight, --ra and --dec (or --allsky LAT,LON for an all-sky frame)")
    if not (math.isfinite(ra) and math.isfinite(roll)):
        fail("--ra and --roll must be finite numbers of degrees")
    if not -90.0 <= dec <= 90.0:
        fail(f"--dec {dec:g} is outside -90..90 degrees")
    realism = _realism(seeing, scintillation, airmass, site_altitude, psf_growth, jpeg_quality)
    A = attitude_from_radec_roll(math.radians(ra), math.radians(dec), math.radians(roll))
    motion_options = {"--rate-dps": rate_dps, "--axis": axis, "--rotation-deg": rotation_deg,
                      "--max-rate-dps": max_rate_dps, "--accel-dps2": accel_dps2, "--smooth": smooth or None,
                      "--start": start, "--amplitude-deg": amplitude_deg, "--period": period,
                      "--damping": damping, "--phase-deg": phase_deg}
    motion = _simulate_profile(profile, A, {k: v for k, v in motion_options.items() if v is not None})
    cam, sensor_arg = _camera_arg(camera), _sensor_arg(sensor)
    first, velocity = _sky_seen_at(time, velocity_kms)  # --time and --velocity-kms checked now
    paths = _output_paths(out_dir, output, frames)
    timed = all(p.suffix.lower() in (".fits", ".fit", ".fts") for p in paths)
    if velocity_kms is not None and not timed:
        fail("--velocity-kms needs FITS frames: a PNG or TIFF frame carries no time, so a solve could "
             "not remove the aberration it would show")
    prepare_outputs({"--output" if out_dir is None else "OUT_DIR": paths})
    if not timed:  # no time in the file: the stars at their catalogue places, as a solve without one
        velocity = None
    kw = dict(sensor=sensor_arg, exposure_s=exposure, epoch=first, seed=seed,
              false_stars=false_stars, hot_pixels=hot_pixels, observer_velocity_km_s=velocity, **realism)
    if psf_growth is not None:
        from skyfix.simulate import resolve_setup

        kw["optics"] = resolve_setup(cam, None, None, None)[2].replace(psf_growth_edge=psf_growth)
    with _rendering(frames) as progress:
        if frames == 1 and out_dir is None and motion is None:
            image, truth = write_frame(render(A, cam, **kw), output)
            typer.echo(f"wrote {image} and {truth}")
            return
        sequence = render_sequence(A, cam, n_frames=frames, fps=fps, profile=motion, **kw)
        for path, frame in zip(paths, sequence, strict=True):
            write_frame(frame, path)
            if progress is not None:
                progress.advance(0)
    if frames == 1:
        typer.echo(f"wrote {paths[0]} and {paths[0].with_suffix('.truth.json')}")
    else:
        where = out_dir if out_dir is not None else paths[0].parent
        typer.echo(f"wrote {frames} frames to {where} ({paths[0].name} … {paths[-1].name}, "
                   "truth beside each)")


def _simulate_allsky(site_text: str, lens_fov: float, out_dir: Path | None, output: Path | None, camera: str,
                     sensor: str | None, exposure: float | None, time: str | None, seed: int, frames: int,
                     ra: float | None, dec: float | None) -> None:
    """``skyfix simulate --allsky LAT,LON``: one all-sky frame
    (:func:`skyfix.simulate.allsky.render_allsky`)."""
    import numpy as np

    from skyfix.corrections.refraction import Site
    from skyfix.simulate import write_frame
    from skyfix.simulate.allsky import all_sky_camera, random_landscape, render_allsky

    if ra is not None or dec is not None:
        fail("--allsky looks up from its site: leave out --ra and --dec")
    if frames != 1:
        fail("--allsky renders one frame: leave out --frames")
    if not (math.isfinite(lens_fov) and 90.0 <= lens_fov <= 220.0):
        fail(f"--lens-fov {lens_fov:g} must be from 90 to 220 degrees")
    with checking("--allsky", site_text):
        site = Site.parse(site_text, "--allsky")
    with checking("--camera", camera):
        size = load_camera(camera)
    sensor_arg = _sensor_arg(sensor)
    first, velocity = _sky_seen_at(time, None)  # the Earth's velocity: the FITS carries its time
    path, = _output_paths(out_dir, output, 1)
    prepare_outputs({"--output" if out_dir is None else "OUT_DIR": [path]})
    if path.suffix.lower() not in (".fits", ".fit", ".fts"):  # no time in the file: catalogue places
        velocity = None
    lens_camera = all_sky_camera(size.width, size.height, lens_fov)
    landscape = random_landscape(np.random.default_rng(seed))
    options = {} if exposure is None else {"exposure_s": exposure}
    with _rendering(1):
        frame = render_allsky(lens_camera, site=(site.lat_deg, site.lon_deg), time=first, landscape=landscape,
                              fov_deg=lens_fov, seed=seed, sensor=sensor_arg, observer_velocity_km_s=velocity,
                              **options)
        image, truth = write_frame(frame, path)
    typer.echo(f"wrote {image} and {truth}")


def _output_paths(out_dir: Path | None, output: Path | None, frames: int) -> list[Path]:
    """The frames' files — ``OUT_DIR/frame-NNNN.fits``, or ``-o FILE`` (numbered when more than
    one) — checked: exactly one of the two, and a folder that is no file (the caller makes their folders)."""
    if (out_dir is None) == (output is None):
        fail("give an output folder (OUT_DIR) or an image file (-o FILE), not both" if out_dir is not None
             else "give an output folder (OUT_DIR) or an image file (-o FILE)")
    if out_dir is not None:
        if out_dir.exists() and not out_dir.is_dir():
            fail(f"OUT_DIR {out_dir} is a file; give a folder (or write one image with -o {out_dir})")
        paths = [out_dir / f"frame-{k:04d}.fits" for k in range(frames)]
    elif frames == 1:
        paths = [output]
    else:
        paths = [output.with_name(f"{output.stem}-{k:04d}{output.suffix}") for k in range(frames)]
    return paths


@contextlib.contextmanager
def _rendering(frames: int):
    """The progress of rendering ``frames`` (None when there is none to show), with the compile
    notice; the simulator's own ValueErrors (sensor and preset values) become one-line errors."""
    progress = _simulate_progress(frames)
    try:
        with compile_notice(progress):
            yield progress
    except ValueError as exc:
        fail(f"bad value: {exc}")
    finally:
        if progress is not None:
            progress.stop()


def _sky_seen_at(time: str | None, velocity_kms: str | None):
    """The first frame's mid-exposure time (ISO 8601 UTC; now when not given) and the camera's
    barycentric velocity then, km/s: the Earth's (ERFA ``epv00``) plus ``--velocity-kms``. FITS
    frames show the stellar aberration a real camera would (up to 20.5″ from the Earth's orbit),
    so that a solve reading the frame's time (DATE-OBS) gives back the truth's attitude."""
    from datetime import UTC, datetime

    from skyfix.corrections import earth_state
    from skyfix.corrections.observer import parse_velocity
    from skyfix.obstime import parse_time

    text = time if time is not None else datetime.now(UTC).isoformat(timespec="milliseconds")
    with checking("--time", time):
        t = parse_time(text)
    velocity = earth_state(t.jd_tt).velocity_km_s
    if velocity_kms is not None:
        with checking("--velocity-kms", velocity_kms):
            velocity = velocity + parse_velocity(velocity_kms).velocity_km_s
    return t.iso, velocity


def _realism(seeing: float, scintillation: bool, airmass: float, site_altitude: float,
             psf_growth: float | None, jpeg_quality: int | None) -> dict:
    """``render``'s ``atmosphere`` and ``jpeg_quality`` from the options, checked (exit 2)."""
    from skyfix.simulate.atmosphere import Atmosphere

    if not (math.isfinite(seeing) and seeing >= 0):
        fail(f"--seeing {seeing:g} must be a FWHM of 0 arcsec or more")
    if not 1.0 <= airmass <= 40.0:
        fail(f"--airmass {airmass:g} must be from 1 to 40")
    if not -500.0 <= site_altitude <= 10000.0:
        fail(f"--site-altitude {site_altitude:g} must be from -500 to 10000 m")
    if psf_growth is not None and not (math.isfinite(psf_growth) and psf_growth >= 0):
        fail(f"--psf-growth {psf_growth:g} must be 0 or more")
    if jpeg_quality is not None and not 1 <= jpeg_quality <= 95:
        fail(f"--jpeg-quality {jpeg_quality} must be from 1 to 95")
    return dict(atmosphere=Atmosphere(seeing, scintillation, airmass, site_altitude),
                jpeg_quality=jpeg_quality)


#: Each profile's options on the command line, with their defaults (None: required).
_PROFILE_OPTIONS: dict[str, dict[str, object]] = {
    "constant": {"--rate-dps": "0,0,0"},
    "inertial-axis": {"--axis": None, "--rate-dps": None},
    "slew": {"--rotation-deg": "0,10,0", "--max-rate-dps": 2.0, "--accel-dps2": 1.0, "--smooth": False,
             "--start": 0.0},
    "pendulum": {"--amplitude-deg": "0.5,2,0.2", "--period": 8.0, "--damping": 0.05, "--phase-deg": "0,0,90"},
}


def _simulate_profile(name: str | None, A, given: dict):
    """The simulate command's attitude profile from ``--profile`` and its options (None: a camera
    at rest); an option of another profile, or a value that makes no sense, fails (exit 2)."""
    from skyfix.simulate import PROFILES, make_profile

    if name is None:
        if not given:
            return None
        name = "constant"
    if name not in PROFILES:
        fail(f"--profile {name!r} is not a motion profile; choose one of {', '.join(PROFILES)}")
    allowed = _PROFILE_OPTIONS[name]
    for option in given:
        if option not in allowed:
            fail(f"{option} is not an option of --profile {name} (its options: {', '.join(allowed)})")
    opts = {**allowed, **given}
    for option, value in opts.items():
        if value is None:
            fail(f"--profile {name} needs {option}")
    def radians(option: str, n: int, form: str) -> list[float]:
        return [math.radians(v) for v in _numbers(opts[option], n, option, form)]

    def positive_radians(option: str) -> float:
        return math.radians(check_positive(opts[option], option))

    try:
        if name == "constant":
            params = dict(rate_rad_s=radians("--rate-dps", 3, "wx,wy,wz"))
        elif name == "inertial-axis":
            ra_rad, dec_rad = radians("--axis", 2, "RA,DEC")
            if not abs(dec_rad) <= math.pi / 2:
                fail(f"--axis declination {math.degrees(dec_rad):g} is outside -90..90 degrees")
            from skyfix.geometry import radec_to_vector

            params = dict(axis_icrs=radec_to_vector(ra_rad, dec_rad),
                          rate_rad_s=radians("--rate-dps", 1, "W")[0])
        elif name == "slew":
            params = dict(rotation_rad=radians("--rotation-deg", 3, "x,y,z"),
                          max_rate_rad_s=positive_radians("--max-rate-dps"),
                          accel_rad_s2=positive_radians("--accel-dps2"),
                          start_s=opts["--start"], shape="smooth" if opts["--smooth"] else "trapezoid")
        else:
            if not 0.0 <= opts["--damping"] < 1.0:
                fail(f"--damping {opts['--damping']:g} must be a damping ratio from 0 to below 1")
            params = dict(amplitude_rad=radians("--amplitude-deg", 3, "ax,ay,az"),
                          period_s=check_positive(opts["--period"], "--period"),
                          damping_ratio=opts["--damping"], phase_rad=radians("--phase-deg", 3, "px,py,pz"))
        return make_profile(name, A, **params)
    except (SimulationError, UnknownNameError) as exc:  # a parameter out of range, in the profile's own words
        fail(f"--profile {name}: {exc}")


def _numbers(text: str, n: int, option: str, form: str) -> list[float]:
    """``n`` finite comma-separated numbers, or fail saying ``option`` takes ``form``."""
    try:
        values = [float(v) for v in str(text).split(",")]
    except ValueError:
        values = []
    if len(values) != n or not all(map(math.isfinite, values)):
        fail(f"{option} takes {n} number{'s' if n > 1 else ''}: {form} (got {text!r})")
    return values


def _simulate_progress(n: int):
    """Progress on stderr while a sequence renders (not for one frame): a bar on a terminal, a
    line per frame off one."""
    return counter_bar("rendering", n) if n >= 2 else None
