"""Image decoders side by side: file → 2-D float32 luminance, per format, size and library.

Run: ``.venv/bin/python benchmarks/bench_decode.py [--repeat N] [--sizes 1280x960,4000x3000]``

Writes star fields (Gaussian stars on a sloped sky with σ = 30 ADU noise) to a temporary
directory as 8- and 16-bit grey PNG, 8- and 16-bit colour PNG, 8- and 16-bit TIFF (uncompressed,
as the ESA frames, and LZW), FITS (uint16 as BITPIX 16 + BZERO 32768, and float32), grey and
colour JPEG (quality 90, 4:2:0), adds ``examples/sky.png``, then times every decoder that can
read each file, all calls interleaved (one call of each per round, in a shuffled order) so the
load of the shared machine falls on all alike. Each time is the whole contract of
:func:`skyfix.io.read_image`: the file read, the decode, and the conversion to float32
luminance (BT.601 for colour; a JPEG's Y plane) — by the same :func:`skyfix.io.as_image` for
every decoder. The table gives the median wall and process-CPU ms over the rounds (CPU time is
the steadier figure on a loaded machine) and, where it is not 0, each decoder's largest pixel
difference from the reference: the pixels written for the lossless formats, Pillow's decode for
JPEG and ``examples/sky.png``. Columns: ``read_image`` is this tree's reader (its decoder
chain), ``base read_image`` another tree's (``--base-io``), then skyfix's decoders one at a time
(:data:`skyfix.io.DECODERS`), then other libraries'. ``--solve IMAGE --base-io ...`` also times
``skyfix.solve(IMAGE)`` with this tree's reader against the other tree's, interleaved.

Libraries that are not installed are skipped (``pip install pyspng imagecodecs
opencv-python-headless`` for all of them).
"""

from __future__ import annotations

import argparse
import random
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from skyfix.io import as_image, read_image


def render_sky(h: int, w: int, seed: int = 0) -> np.ndarray:
    """Float sky in 16-bit ADU: sloped background, read noise, one Gaussian star per ~4000 px²."""
    rng = np.random.default_rng(seed)
    img = 800.0 + 400.0 * np.arange(w)[None, :] / w + rng.normal(0.0, 30.0, (h, w))
    n = max(50, h * w // 4000)
    xs, ys = rng.uniform(8, w - 8, n), rng.uniform(8, h - 8, n)
    flux = 10 ** rng.uniform(3.5, 6.0, n)
    yy, xx = np.mgrid[-6:7, -6:7]
    for x0, y0, f in zip(xs, ys, flux, strict=True):
        xi, yi = int(x0), int(y0)
        g = np.exp(-((xx + xi - x0) ** 2 + (yy + yi - y0) ** 2) / (2 * 1.3**2))
        img[yi - 6:yi + 7, xi - 6:xi + 7] += f / (2 * np.pi * 1.3**2) * g
    return np.clip(img, 0, 65535)


def write_files(d: Path, h: int, w: int) -> dict[str, tuple[Path, np.ndarray | None]]:
    """Every test file for one size; name → (path, the pixels written, or None for JPEG)."""
    import tifffile
    from astropy.io import fits
    from PIL import Image

    sky = render_sky(h, w)
    g16 = sky.astype(np.uint16)
    g8 = (sky / 64).clip(0, 255).astype(np.uint8)
    tint = np.array([1.0, 0.92, 0.8])
    rng = np.random.default_rng(1)
    rgb = sky[..., None] * tint + rng.normal(0, 20, (h, w, 3))
    rgb16 = rgb.clip(0, 65535).astype(np.uint16)
    rgb8 = (rgb / 64).clip(0, 255).astype(np.uint8)
    tag = f"{w}x{h}"
    out = {}

    def path(name, pixels=None):
        out[name] = (d / f"{tag}-{name}", pixels)
        return out[name][0]

    Image.fromarray(g8).save(path("grey8.png", g8))
    Image.fromarray(g16).save(path("grey16.png", g16))
    Image.fromarray(rgb8).save(path("rgb8.png", rgb8))
    _write_png_rgb16(path("rgb16.png", rgb16), rgb16)
    tifffile.imwrite(path("grey8.tif", g8), g8)
    tifffile.imwrite(path("grey16.tif", g16), g16)
    tifffile.imwrite(path("grey16-lzw.tif", g16), g16, compression="lzw")
    fits.writeto(path("uint16.fits", g16), g16)  # BITPIX 16, BZERO 32768
    fits.writeto(path("float32.fits", sky.astype(np.float32)), sky.astype(np.float32))
    Image.fromarray(g8).save(path("grey.jpg"), quality=90)
    Image.fromarray(rgb8).save(path("rgb.jpg"), quality=90)
    return out


def _write_png_rgb16(p: Path, rgb16: np.ndarray) -> None:
    """A 16-bit RGB PNG (Pillow cannot write one): OpenCV if present, else a minimal encoder."""
    import struct
    import zlib

    h, w, _ = rgb16.shape
    raw = np.zeros((h, 1 + w * 6), np.uint8)  # filter byte 0 per row, big-endian samples
    raw[:, 1:] = rgb16.astype(">u2").view(np.uint8).reshape(h, w * 6)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0)
    idat = zlib.compress(raw.tobytes(), 6)
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b""))


# ---- other libraries' decoders: path → raw array (grey 2-D, or (H, W, 3) RGB), finished by as_image ----

def pyspng_load(p: Path) -> np.ndarray:
    import pyspng

    a = pyspng.load(p.read_bytes())
    if a.dtype == np.uint16 and a.ndim == 3 and a.shape[2] in (2, 4):
        a = a[..., 0] if a.shape[2] == 2 else a[..., :3]  # pyspng: 16-bit grey as grey+alpha, RGB as RGBA
    return a


def ic_png(p: Path) -> np.ndarray:
    import imagecodecs

    return imagecodecs.png_decode(p.read_bytes())


def ic_tiff(p: Path) -> np.ndarray:
    import imagecodecs

    return imagecodecs.tiff_decode(p.read_bytes())


def cv2_imread(p: Path) -> np.ndarray:
    import cv2

    a = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    return a[..., 2::-1] if a.ndim == 3 else a  # BGR(A) → RGB


def cv2_imdecode(p: Path) -> np.ndarray:
    import cv2

    a = cv2.imdecode(np.fromfile(p, np.uint8), cv2.IMREAD_UNCHANGED)
    return a[..., 2::-1] if a.ndim == 3 else a


def cv2_imread_y(p: Path) -> np.ndarray:
    import cv2

    return cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)  # JPEG: libjpeg's Y plane, no colour pass


OTHERS: dict[str, tuple[Callable[[Path], np.ndarray], tuple[str, ...], str]] = {
    # name: (function, file suffixes it reads, python module it needs)
    "pyspng": (pyspng_load, (".png",), "pyspng"),
    "ic.png_decode": (ic_png, (".png",), "imagecodecs"),
    "ic.tiff_decode": (ic_tiff, (".tif",), "imagecodecs"),
    "cv2.imread": (cv2_imread, (".png", ".tif"), "cv2"),
    "cv2.imdecode": (cv2_imdecode, (".png", ".tif"), "cv2"),
    "cv2.imread(Y)": (cv2_imread_y, (".jpg",), "cv2"),
}
#: skyfix's own decoders (skyfix.io.DECODERS) timed here, and the suffixes each reads.
SKYFIX = {"skyfix-png": (".png",), "pillow": (".png", ".jpg"), "imagecodecs-jpeg": (".jpg",),
          "tifffile": (".tif",), "skyfix-fits": (".fits",), "astropy": (".fits",)}
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "sky.png"
ALL = (".png", ".tif", ".jpg", ".fits")


def available(module: str) -> bool:
    try:
        __import__(module)
    except ImportError:
        return False
    return True


def skyfix_png_zlib(p: Path) -> np.ndarray:
    """skyfix's PNG decoder as it runs without the ``deflate`` package: Python's zlib inflates."""
    import deflate

    from skyfix.io import read_image_with_header

    sys.modules["deflate"] = None  # `import deflate` raises ImportError
    try:
        return read_image_with_header(p, decoder="skyfix-png").data
    finally:
        sys.modules["deflate"] = deflate


def load_base_reader(path: str) -> Callable:
    """``read_image_with_header`` from another tree's ``skyfix/io.py`` (e.g. the base commit's),
    loaded on its own (its own ``skyfix._png`` must be importable as this tree's: see ``--base-io``)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("skyfix_io_base", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.read_image_with_header


def time_rounds(calls: dict[str, Callable[[], object]], rounds: int) -> dict[str, tuple[list, list]]:
    """Wall and process-CPU ms of each call, one call of each per round in a shuffled order."""
    for fn in calls.values():
        fn()
    out: dict[str, tuple[list, list]] = {k: ([], []) for k in calls}
    order = list(calls)
    for _ in range(rounds):
        random.shuffle(order)
        for k in order:
            c0, t0 = time.process_time(), time.perf_counter()
            calls[k]()
            out[k][0].append((time.perf_counter() - t0) * 1e3)
            out[k][1].append((time.process_time() - c0) * 1e3)
    return out


def decode_table(args, base_read: Callable | None) -> None:
    from skyfix.io import read_image_with_header

    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    others = {k: v for k, v in OTHERS.items() if available(v[2])}
    skipped = sorted(set(OTHERS) - set(others))
    with tempfile.TemporaryDirectory() as tmp:
        files: dict[str, Path] = {}
        ref: dict[str, np.ndarray] = {}  # the luminance of the pixels written (lossless formats)
        for w, h in sizes:
            for k, (p, pixels) in write_files(Path(tmp), h, w).items():
                files[f"{w}x{h} {k}"] = p
                if pixels is not None:
                    ref[f"{w}x{h} {k}"] = as_image(pixels)
        if EXAMPLE.exists():  # the project's example frame, 16-bit grey PNG written by Pillow
            files["examples/sky.png"] = EXAMPLE
            ref["examples/sky.png"] = read_image_with_header(EXAMPLE, decoder="pillow").data
        fns: dict[str, tuple[Callable[[Path], np.ndarray], tuple[str, ...]]] = {
            "read_image": (read_image, ALL)}
        if base_read is not None:
            fns["base read_image"] = ((lambda p: base_read(p).data), ALL)
        fns |= {k: ((lambda p, k=k: read_image_with_header(p, decoder=k).data), suf)
                for k, suf in SKYFIX.items()}
        if available("deflate"):
            fns["skyfix-png(zlib)"] = (skyfix_png_zlib, (".png",))
        fns |= {k: ((lambda p, fn=fn: as_image(fn(p))), suf) for k, (fn, suf, _) in others.items()}
        calls, diff = {}, {}
        for f, p in files.items():
            for d, (fn, suf) in fns.items():
                if p.suffix not in suf:
                    continue
                try:
                    out = fn(p)
                except Exception:  # e.g. imagecodecs missing for skyfix's optional decoder
                    continue
                if f not in ref:  # JPEG: Pillow's decode is the reference
                    ref[f] = read_image_with_header(p, decoder="pillow").data
                same = out.shape == ref[f].shape
                diff[f, d] = float(np.abs(out.astype(np.float64) - ref[f]).max()) if same else float("inf")
                calls[f, d] = (lambda fn=fn, p=p: fn(p))
        times = time_rounds(calls, args.repeat)
        kib = {f: files[f].stat().st_size / 1024 for f in files}
    names = list(fns)
    print(f"decode: median ms over {args.repeat} interleaved rounds, wall / process CPU; [max |Δpixel|] from "
          f"the pixels written (JPEG: from Pillow) where not 0; python {sys.version.split()[0]}"
          + (f"; not installed: {', '.join(skipped)}" if skipped else ""))
    print(f"{'file':26s} {'KiB':>6s} " + " ".join(f"{n:>17s}" for n in names))
    for f in files:
        cells = []
        for n in names:
            if (f, n) not in times:
                cells.append(f"{'':>17s}")
                continue
            wall, cpu = (np.median(v) for v in times[f, n])
            tag = "" if diff[f, n] == 0 else f"[{diff[f, n]:.3g}]"
            cells.append(f"{f'{wall:.1f}/{cpu:.1f}{tag}':>17s}")
        print(f"{f:26s} {kib[f]:6.0f} " + " ".join(cells))


def solve_ab(args, base_read: Callable) -> None:
    """File → attitude, ``skyfix.solve(path)``, with this tree's reader and the base reader, interleaved."""
    import skyfix
    import skyfix.io

    path = Path(args.solve)
    new_read = skyfix.io.read_image_with_header
    res: dict[str, dict[str, list]] = {"this tree": {}, "base reader": {}}

    def run(label, reader):
        cpu_read = []

        def timed(image, **kw):
            c0 = time.process_time()
            out = reader(image, **kw)
            cpu_read.append((time.process_time() - c0) * 1e3)
            return out

        # pipeline.solve imports read_image_with_header from skyfix.io at each call
        skyfix.io.read_image_with_header = timed
        c0 = time.process_time()
        try:
            sol = skyfix.solve(path)
        finally:
            skyfix.io.read_image_with_header = new_read
        cpu_total = (time.process_time() - c0) * 1e3
        assert sol.status == "solved", sol.reason
        for k, v in [*sol.time_ms.items(), ("read CPU", cpu_read[0]), ("total CPU", cpu_total)]:
            res[label].setdefault(k, []).append(v)

    for _ in range(2):  # warm-up: kernels, database
        run("this tree", new_read)
        run("base reader", base_read)
    res = {"this tree": {}, "base reader": {}}
    for _ in range(args.repeat):
        pair = [("this tree", new_read), ("base reader", base_read)]
        random.shuffle(pair)
        for label, reader in pair:
            run(label, reader)
    keys = list(res["this tree"])
    print(f"\nskyfix.solve({path}): its time_ms (wall) and process CPU ms of the read and of the whole call, "
          f"median of {args.repeat} interleaved pairs (the rest of the solve is the same code in both)")
    print(f"{'':12s} " + " ".join(f"{k:>9s}" for k in keys))
    for label, r in res.items():
        print(f"{label:12s} " + " ".join(f"{np.median(r[k]):9.2f}" for k in keys))
    new, base = res["this tree"], res["base reader"]
    print(f"{'ratio':12s} " + " ".join(f"{np.median(new[k]) / np.median(base[k]):9.2f}" for k in keys))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=15, help="rounds (each decoder once per file per round)")
    ap.add_argument("--sizes", default="1280x960,4000x3000")
    ap.add_argument("--base-io", help="another tree's src/skyfix/io.py: adds its read_image as a column "
                    "(it imports this tree's skyfix._png: where that changed, give a copy whose import "
                    "names the other tree's _png.py, copied beside it under another name)")
    ap.add_argument("--solve", metavar="IMAGE",
                    help="with --base-io: time skyfix.solve(IMAGE) with each reader")
    ap.add_argument("--no-table", action="store_true", help="skip the decoder table")
    args = ap.parse_args()
    base_read = load_base_reader(args.base_io) if args.base_io else None
    if not args.no_table:
        decode_table(args, base_read)
    if args.solve and base_read is not None:
        solve_ab(args, base_read)


if __name__ == "__main__":
    main()
