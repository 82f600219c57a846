"""Text for the windows: a glyph atlas from Pillow's default font, laid out as instanced quads.

:func:`build_font_atlas` renders the printable ASCII characters once at start;
:func:`layout_text`, :func:`text_width` and :func:`panel_instances` turn lines (with tab stops:
columns in a proportional font) into quads ``(N, 12)`` float32 (pure, no GL);
:class:`TextOverlay` draws them over a framebuffer (``text.glsl``) from one atlas texture and a
quad buffer of fixed capacity, both made once. :func:`default_font` is Pillow's default font at
a size, as the demo scene's banner uses it too.

Layer 5: numpy, Pillow, moderngl; never torch.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Mapping, Sequence

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ...plumbing.errors import ValidationError
from ..gl import release, upload_texture
from ..optional import require_moderngl
from ..shaders import compile_program

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

__all__ = ["Glyph", "FontAtlas", "default_font", "build_font_atlas", "INSTANCE_FLOATS", "layout_text",
           "text_width", "panel_instances", "key_map_panel", "TextOverlay"]

Colour = tuple[float, float, float, float]


def default_font(size_px: int) -> "ImageFont.ImageFont | ImageFont.FreeTypeFont":
    """Pillow's default font at ``size_px`` (its fixed bitmap font where Pillow lacks FreeType)."""
    try:
        return ImageFont.load_default(size=size_px)
    except TypeError:  # pragma: no cover - Pillow without FreeType
        return ImageFont.load_default()


@dataclass(frozen=True)
class Glyph:
    """A glyph's cell in the atlas (pixels, top-left origin) and its metrics: the cell is
    drawn ``offset_x`` pixels right of the pen, which then moves ``advance`` pixels."""

    x: int
    y: int
    width: int
    height: int
    offset_x: int
    advance: int


@dataclass(frozen=True, eq=False)
class FontAtlas:
    """Coverage image ``(H, W)`` uint8 of the printable ASCII glyphs, their cells, the line
    height, and ``solid``: a fully covered cell ``(x, y, w, h)`` for filled rectangles."""

    image: np.ndarray
    glyphs: Mapping[str, Glyph]
    line_height: int
    solid: tuple[int, int, int, int]

    def glyph(self, ch: str) -> Glyph:
        """The glyph of ``ch``; characters outside the atlas are drawn as ``?``."""
        return self.glyphs.get(ch) or self.glyphs["?"]


def build_font_atlas(size_px: int = 13) -> FontAtlas:
    """Render the printable ASCII characters (32-126) with Pillow's default font at
    ``size_px`` (its bitmap font where Pillow lacks FreeType) into a coverage atlas."""
    if not (isinstance(size_px, int) and 6 <= size_px <= 96):
        raise ValidationError("size_px", size_px, "an integer from 6 to 96 pixels")
    font = default_font(size_px)
    chars = [chr(c) for c in range(32, 127)]
    boxes = {ch: font.getbbox(ch) for ch in chars}
    left = min(0, min(b[0] for b in boxes.values()))
    cell_w = max(b[2] for b in boxes.values()) - left + 1
    line_h = max(max(b[3] for b in boxes.values()), size_px) + 2
    columns = 16
    rows = (len(chars) + 1 + columns - 1) // columns  # + the solid cell
    image = Image.new("L", (columns * cell_w, rows * line_h), 0)
    draw = ImageDraw.Draw(image)
    glyphs = {}
    for i, ch in enumerate(chars):
        r, c = divmod(i, columns)
        x, y = c * cell_w, r * line_h
        draw.text((x - left, y), ch, fill=255, font=font)
        glyphs[ch] = Glyph(x, y, cell_w, line_h, left, int(round(font.getlength(ch))))
    r, c = divmod(len(chars), columns)
    solid = (c * cell_w, r * line_h, cell_w, line_h)
    draw.rectangle((solid[0], solid[1], solid[0] + cell_w - 1, solid[1] + line_h - 1), fill=255)
    return FontAtlas(np.asarray(image, dtype=np.uint8).copy(), glyphs, line_h, solid)


INSTANCE_FLOATS = 12
"""Floats per drawn quad: rect (x, y, w, h), uv (left, top, right, bottom), colour RGBA."""


def _uv(atlas: FontAtlas, x: float, y: float, w: float, h: float) -> tuple[float, float, float, float]:
    height, width = atlas.image.shape
    return (x / width, 1.0 - y / height, (x + w) / width, 1.0 - (y + h) / height)


def _next_tab(pen: int, tab_stops: Sequence[int], tab_px: int) -> int:
    for stop in tab_stops:
        if stop > pen:
            return int(stop)
    return (pen // tab_px + 1) * tab_px


def layout_text(atlas: FontAtlas, lines: Sequence[str], x: int, y: int,
                colour: Colour = (1.0, 1.0, 1.0, 1.0), *,
                tab_stops: Sequence[int] = (), tab_px: int = 64) -> np.ndarray:
    """Quads ``(N, 12)`` float32 drawing ``lines`` with the top-left of the first at pixel
    ``(x, y)`` (image terms), one line every ``atlas.line_height``; spaces draw nothing.

    A tab moves the pen to the next of ``tab_stops`` (pixels from ``x``), past the last one
    to the next multiple of ``tab_px``: columns in a proportional font.
    """
    if not (isinstance(tab_px, int) and tab_px >= 1):
        raise ValidationError("tab_px", tab_px, "an integer >= 1 (pixels)")
    quads = []
    for row, line in enumerate(lines):
        pen = 0
        top = int(y) + row * atlas.line_height
        for ch in line:
            if ch == "\t":
                pen = _next_tab(pen, tab_stops, tab_px)
                continue
            g = atlas.glyph(ch)
            if ch != " ":
                quads.append((int(x) + pen + g.offset_x, top, g.width, g.height,
                              *_uv(atlas, g.x, g.y, g.width, g.height), *colour))
            pen += g.advance
    return np.array(quads, np.float32).reshape(-1, INSTANCE_FLOATS)


def text_width(atlas: FontAtlas, line: str, *, tab_stops: Sequence[int] = (), tab_px: int = 64) -> int:
    """Width in pixels of ``line`` as :func:`layout_text` draws it."""
    pen = 0
    for ch in line:
        pen = _next_tab(pen, tab_stops, tab_px) if ch == "\t" else pen + atlas.glyph(ch).advance
    return pen


def panel_instances(atlas: FontAtlas, lines: Sequence[str], x: int, y: int, *,
                    text: Colour = (1.0, 1.0, 1.0, 1.0),
                    background: Colour = (0.0, 0.0, 0.0, 0.7),
                    padding: int = 6, tab_stops: Sequence[int] = (),
                    tab_px: int = 64) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """A filled rectangle behind ``lines`` and the lines (see :func:`layout_text` for tabs):
    ``(quads, (x, y, w, h))``."""
    width = max((text_width(atlas, line, tab_stops=tab_stops, tab_px=tab_px) for line in lines),
                default=0) + 2 * padding
    height = len(lines) * atlas.line_height + 2 * padding
    sx, sy, sw, sh = atlas.solid
    # sample the middle of the solid cell: nearest filtering never reaches a neighbour
    back = np.array([[x, y, width, height, *_uv(atlas, sx + sw / 2 - 0.25, sy + sh / 2 - 0.25, 0.5, 0.5),
                      *background]], np.float32)
    quads = layout_text(atlas, lines, x + padding, y + padding, text, tab_stops=tab_stops, tab_px=tab_px)
    return np.concatenate([back, quads]), (x, y, width, height)



def key_map_panel(atlas: FontAtlas, keys: Sequence[tuple[str, str]], x: int, y: int, gap: int) -> np.ndarray:
    """The quads of a key map panel at pixel ``(x, y)``: a ``keys`` title, then one line per
    ``(key, what)`` pair, the keys in a column ``gap`` pixels wider than the widest."""
    tab_stops = (max(text_width(atlas, k) for k, _ in keys) + gap,)
    lines = ["keys"] + [f"{k}\t{what}" for k, what in keys]
    return panel_instances(atlas, lines, x, y, background=(0.05, 0.1, 0.25, 0.85), tab_stops=tab_stops)[0]


class TextOverlay:
    """Draws :func:`layout_text` / :func:`panel_instances` quads over a framebuffer
    (``text.glsl``); the atlas texture and a quad buffer of fixed capacity are made once."""

    def __init__(self, ctx: "moderngl.Context", atlas: FontAtlas, capacity: int = 8192):
        self.ctx, self.atlas, self.capacity = ctx, atlas, int(capacity)
        self.texture = self.program = self.buffer = self.vao = None
        try:
            self.texture = upload_texture(ctx, atlas.image[..., None])
            self.program = compile_program(ctx, "text.glsl")
            self.buffer = ctx.buffer(reserve=self.capacity * INSTANCE_FLOATS * 4)
            self.vao = ctx.vertex_array(self.program, [(self.buffer, "4f 4f 4f/i", "in_rect", "in_uv", "in_colour")])
            self.program["u_atlas"].value = 0
        except BaseException:
            self.release()
            raise

    def draw(self, quads: np.ndarray, framebuffer: "moderngl.Framebuffer", size: tuple[int, int]) -> None:
        """Draw ``quads`` (at most :attr:`capacity`; more are cut) over ``framebuffer`` of ``size``."""
        moderngl = require_moderngl()
        n = min(len(quads), self.capacity)
        if n == 0:
            return
        self.buffer.write(np.ascontiguousarray(quads[:n], np.float32).tobytes())
        framebuffer.use()
        self.ctx.viewport = (0, 0, *size)
        self.program["u_target_size"].value = (float(size[0]), float(size[1]))
        self.texture.use(0)
        self.ctx.enable(moderngl.BLEND)
        self.ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
        try:
            self.vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=n)
        finally:
            self.ctx.disable(moderngl.BLEND)

    def release(self) -> None:
        release(self.vao, self.buffer, self.program, self.texture)
        self.vao = self.buffer = self.program = self.texture = None
