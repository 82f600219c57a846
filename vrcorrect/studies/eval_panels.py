"""The pictures of ``vrcorrect evaluate`` (:mod:`vrcorrect.studies.evaluation`): one panel per image
and prescription, a column per method (what the eye sees, its FLIP error map in magma, its scores
as captions), the target first with the error map's legend.

Layer 6: numpy, Pillow.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from PIL import Image, ImageDraw, ImageFont

__all__ = ["panel_size", "magma", "legend", "compose_panel", "score_lines", "correction_panel"]

_GAP_PX = 6


def _font_px(size: int) -> int:
    return int(min(14, max(8, size // 18)))


def _caption_px(size: int) -> int:
    return 3 * (_font_px(size) + 3) + 4


def _header_px(size: int) -> int:
    return _font_px(size) + 10


def panel_size(size: int, columns: int, height: int | None = None) -> tuple[int, int]:
    """``(width, height)`` in pixels of a panel of ``columns`` columns of ``size``-pixel images.

    Layout: a title strip; then per column a caption (3 lines), the image as
    seen, a gap and the FLIP error map; columns separated by a gap.  Images
    ``size`` wide and ``height`` (default ``size``) tall.
    """
    h = size if height is None else height
    width = columns * size + (columns - 1) * _GAP_PX
    return width, _header_px(size) + _caption_px(size) + 2 * h + _GAP_PX


def _font(px: int):
    try:
        return ImageFont.load_default(size=px)
    except TypeError:  # pragma: no cover - Pillow without FreeType sizes
        return ImageFont.load_default()


def _fitted_font(draw, text: str, px: int, width: int):
    """The default font at ``px`` or smaller (down to 6) so that ``text`` fits ``width``."""
    while True:
        font = _font(px)
        if px <= 6 or draw.textlength(text, font=font) <= width:
            return font
        px -= 1


def _to_uint8(rgb: np.ndarray) -> np.ndarray:
    return np.round(np.clip(np.asarray(rgb, dtype=np.float64), 0.0, 1.0) * 255.0).astype(np.uint8)


def magma(error_map: np.ndarray) -> np.ndarray:
    """An ``(H, W)`` FLIP map in [0, 1] as magma-coloured uint8 RGB."""
    from matplotlib import colormaps  # on use: start-up time (apps/__init__)

    rgba = colormaps["magma"](np.clip(np.asarray(error_map, dtype=np.float64), 0.0, 1.0))
    return _to_uint8(rgba[..., :3])


def legend(height: int, size: int) -> np.ndarray:
    """What goes under the target column (``height x size``): the colour bar of the FLIP maps."""
    im = Image.new("RGB", (size, height), "white")
    draw = ImageDraw.Draw(im)
    px = _font_px(size)
    bar_h = max(4, height // 10)
    x0, x1 = max(2, size // 16), size - max(2, size // 16)
    y0 = height // 2 - bar_h // 2
    ramp = magma(np.tile(np.linspace(0.0, 1.0, max(x1 - x0, 1))[None, :], (bar_h, 1)))
    im.paste(Image.fromarray(ramp, "RGB"), (x0, y0))
    title = "FLIP error maps"
    draw.text((x0, max(0, y0 - 2 * px - 4)), title, fill="black", font=_fitted_font(draw, title, px, size - x0))
    font = _font(px)
    draw.text((x0, y0 + bar_h + 2), "0", fill="black", font=font)
    one_w = draw.textlength("1", font=font)
    draw.text((x1 - one_w, y0 + bar_h + 2), "1", fill="black", font=font)
    return np.asarray(im)


def compose_panel(title: str, columns: Sequence[tuple[list[str], np.ndarray, np.ndarray]]):
    """A PIL image: ``columns`` of (caption lines, seen sRGB, image under it as uint8 RGB), one shape."""
    h, size = columns[0][1].shape[:2]
    width, height = panel_size(size, len(columns), h)
    im = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(im)
    px = _font_px(size)
    header = _header_px(size)
    draw.text((4, 4), title, fill="black", font=_fitted_font(draw, title, px, width - 8))
    caption = _caption_px(size)
    for i, (lines, seen, under) in enumerate(columns):
        x = i * (size + _GAP_PX)
        for j, line in enumerate(lines[:3]):
            draw.text((x + 2, header + 2 + j * (px + 3)), line, fill="black",
                      font=_fitted_font(draw, line, px, size - 4))
        y = header + caption
        im.paste(Image.fromarray(_to_uint8(seen), "RGB"), (x, y))
        im.paste(Image.fromarray(np.asarray(under, dtype=np.uint8), "RGB"), (x, y + h + _GAP_PX))
    return im


def score_lines(label: str, m) -> list[str]:
    return [label, f"JOD {m.jod:.2f}  FLIP {m.flip:.3f}", f"SSIM {m.ssim:.3f}  PSNR {m.psnr:.2f} dB"]


def correction_panel(title: str, goal: str, seen: Sequence[tuple[str, object, dict]]):
    """``vrcorrect correct --panel``: what the eye sees with its glasses (``goal``: the column's caption),
    then each ``(label, metrics, images)`` of :func:`~vrcorrect.vision.metrics.evaluate_seen` (no
    correction, this correction): the view, its scores, its FLIP map under it. A PIL image."""
    images = seen[0][2]
    h, w = images["target_srgb"].shape[:2]
    columns = [([goal, "the target: what every", "other column is judged by"], images["target_srgb"], legend(h, w))]
    columns += [(score_lines(label, m)[:2] + [f"objective {m.objective:.3g}"], im["seen_srgb"], magma(im["flip_map"]))
                for label, m, im in seen]
    return compose_panel(title, columns)
