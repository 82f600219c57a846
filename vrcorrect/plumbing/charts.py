"""Procedural test charts (sRGB code values in [0, 1], float32 ``(H, W, 3)``).

Charts are generated, not shipped, so they are exact at any size: a Siemens
star (resolution in every orientation, shows the direction of astigmatic
blur), text (what readers care about), colour bars (chromatic effects), and
the bundled sample image that combines them with a photograph.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from .errors import ValidationError
from .fileio import package_data


def _check_size(size: int) -> None:
    if not (isinstance(size, int) and 8 <= size <= 8192):
        raise ValidationError("size", size, "an integer from 8 to 8192 pixels")


def siemens_star(size: int = 256, spokes: int = 36, supersample: int = 4) -> np.ndarray:
    """Black-and-white Siemens star with ``spokes`` black/white sector pairs."""
    _check_size(size)
    n = size * supersample
    c = (np.arange(n) + 0.5) / supersample - size / 2.0
    X, Y = np.meshgrid(c, c)
    theta = np.arctan2(Y, X)
    r = np.hypot(X, Y)
    star = (np.sin(spokes * theta) >= 0).astype(np.float32)
    star[r > 0.47 * size] = 1.0
    star = star.reshape(size, supersample, size, supersample).mean(axis=(1, 3))
    return np.repeat(star[..., None], 3, axis=2).astype(np.float32)


def colour_bars(width: int = 256, height: int = 256) -> np.ndarray:
    """Saturated colour bars over a fine black/white grating strip."""
    _check_size(width)
    _check_size(height)
    colours = np.array([[1, 1, 1], [1, 1, 0], [0, 1, 1], [0, 1, 0], [1, 0, 1], [1, 0, 0], [0, 0, 1], [0, 0, 0]],
                       dtype=np.float32)
    xs = np.minimum((np.arange(width) * len(colours)) // width, len(colours) - 1)
    img = np.repeat(colours[xs][None], height, axis=0)
    strip = height * 3 // 4
    x = np.arange(width)
    period = np.maximum(2, 2 + (x * 6) // width)       # 1-px lines at the left, wider to the right
    grating = ((x // (period // 2)) % 2).astype(np.float32)
    img[strip:] = grating[None, :, None]
    return img


def text_chart(width: int = 256, height: int = 256) -> np.ndarray:
    """Black text of decreasing size on white."""
    _check_size(width)
    _check_size(height)
    im = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(im)
    y = 4
    size = max(6, height // 7)
    lines = ["Sharp eyes", "read this line", "without glasses?", "0123456789 ABCDEFG", "the quick brown fox jumps"]
    for line in lines:
        try:
            font = ImageFont.load_default(size=size)
        except TypeError:  # Pillow without FreeType sizes
            font = ImageFont.load_default()
        draw.text((4, y), line, fill="black", font=font)
        y += int(size * 1.25)
        size = max(6, int(size * 0.75))
        if y > height - size:
            break
    return np.asarray(im, dtype=np.float32) / 255.0


def sample_image_path() -> Path:
    """The bundled sample image (512x512 PNG: photo, star, text, colour bars)."""
    return package_data("sample.png")


def make_sample_image(photo: np.ndarray) -> np.ndarray:
    """Compose the 512x512 sample from a photograph (sRGB, any size >= 256) and the charts."""
    im = Image.fromarray(np.round(np.clip(photo, 0, 1) * 255).astype(np.uint8))
    side = min(im.size)
    im = im.crop(((im.size[0] - side) // 2, 0, (im.size[0] - side) // 2 + side, side))
    tile = np.asarray(im.resize((256, 256), Image.LANCZOS), dtype=np.float32) / 255.0
    out = np.ones((512, 512, 3), dtype=np.float32)
    out[:256, :256] = tile
    out[:256, 256:] = siemens_star(256)
    out[256:, :256] = text_chart(256, 256)
    out[256:, 256:] = colour_bars(256, 256)
    return out
