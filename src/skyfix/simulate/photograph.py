"""A rendered frame made into a processed astrophotograph (issue 26): a stretched background,
nebulosity, a sky gradient, colour and a caption burned in — what a user's picture of the sky
carries and a star camera's raw frame does not. The stars stay where the render put them, so the
frame's truth still holds.
"""

from __future__ import annotations

import numpy as np

__all__ = ["photograph"]


def photograph(image: np.ndarray, *, caption: str | None = "M42 & Horsehead  30x60s  ISO 1600",
               nebulae: int = 2, gradient: float = 0.05, stretch: float = 0.02, colour: bool = True,
               seed: int = 0) -> np.ndarray:
    """``image`` (a rendered frame, ADU) as an 8-bit photograph: the sky level subtracted and the
    frame scaled to its brightest pixel, ``nebulae`` broad Gaussian glows (peak 5–10 % of white,
    100–250 px across, placed by ``seed``) and a left-to-right ``gradient`` added, an asinh
    stretch (``stretch``: the level that the stretch lifts most, as a share of white), a slight
    colour cast when ``colour``, and ``caption`` written in white along the bottom (none: no
    text). Returns (H, W, 3) uint8 when ``colour``, else (H, W)."""
    from PIL import Image, ImageDraw, ImageFont

    img = np.asarray(image, dtype=np.float64)
    h, w = img.shape
    level = float(np.median(img))
    linear = np.clip((img - level) / max(float(img.max()) - level, 1e-12), 0.0, None)
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    for _ in range(int(nebulae)):
        cx, cy = rng.uniform(0.15, 0.85) * w, rng.uniform(0.15, 0.85) * h
        sx, sy = rng.uniform(100.0, 250.0, 2)
        linear += rng.uniform(0.05, 0.10) * np.exp(-(((xx - cx) / sx) ** 2 + ((yy - cy) / sy) ** 2))
    linear += gradient * xx / w
    stretched = np.arcsinh(linear / stretch) / np.arcsinh(1.0 / stretch)
    planes = [stretched * k for k in ((1.0, 0.9, 1.1) if colour else (1.0,))]
    out = np.clip(np.stack(planes, axis=-1) * 255.0, 0.0, 255.0).astype(np.uint8)
    if caption:
        picture = Image.fromarray(out if colour else out[..., 0])
        font = ImageFont.load_default(size=max(12, h // 24))
        ImageDraw.Draw(picture).text((w // 30, h - h // 12), caption, fill=(255, 255, 255) if colour else 255,
                                     font=font)
        out = np.asarray(picture)
    return out if colour else out.reshape(h, w)
