"""What the mirror shows each eye: the built-in 3D demo scene, or a still image, a folder of
images, an animated image or a video.

Every source renders, per frame, one RGBA8 texture per eye at the eye size, holding sRGB
code values in OpenGL's orientation (what :class:`~vrcorrect.runtime.corrector.Corrector`
takes). A source's GPU objects are made when it is opened (and, for a folder, when the next
image has another size); rendering a frame allocates nothing.

* :class:`DemoScene` - a moving 3D scene with fine detail and text: a turning cube covered
  with test charts (Siemens stars, text, colour bars, a checkerboard), two chart panels, a
  checkered floor and a scrolling line of text; each eye from its own position (the
  interpupillary distance apart). Drawn with 4x multisampling where the GL has it, textures
  decoded, filtered and mipmapped in linear light (sRGB textures), shaded in linear light
  and encoded to sRGB code values.
* Image sources (:class:`StillSource`, :class:`FolderSource`, :class:`AnimatedImageSource`,
  :class:`VideoSource`): the picture is fitted into the eye size, aspect kept, centred on
  black (DESIGN.md: outside the image the panel is black), resampled on the GPU in linear
  light; an image of exactly the eye size is shown texel for texel. Both eyes see the same.
* :class:`ScreenSource` - a region of the X11 screen, grabbed every frame (``mss``; the
  overlay's source ``screen``), fitted the same way.

Pure helpers (no GL): :func:`parse_size`, :func:`parse_source`, :func:`parse_region`, :func:`fit_rect`,
:func:`frame_index`, :func:`frame_at`, :func:`folder_images`, the matrices
(:func:`perspective`, :func:`translation`, :func:`rotation_x`, :func:`rotation_y`,
:func:`scaling`), the meshes and :func:`scene_transforms`.

Layer 5: numpy, Pillow, moderngl; video files through ``imageio-ffmpeg`` and the screen
through ``mss`` when installed (both in the ``realtime`` extra).
"""

from __future__ import annotations

import bisect
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator, Mapping, Sequence

import numpy as np

from ..plumbing.errors import InputError, ValidationError
from .gl import Rect

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

__all__ = [
    "EYES", "IMAGE_SUFFIXES", "ANIMATED_SUFFIXES", "VIDEO_SUFFIXES", "MAX_EYE_SIZE",
    "SourceSpec", "SceneConfig", "parse_size", "parse_source", "fit_rect", "frame_index", "frame_at",
    "folder_images", "perspective", "translation", "rotation_x", "rotation_y", "scaling",
    "cube_mesh", "quad_mesh", "scene_transforms", "chart_atlas", "text_banner",
    "DemoScene", "StillSource", "FolderSource", "AnimatedImageSource", "VideoSource", "open_source",
    "parse_region", "screen_bounds", "ScreenGrabber", "ScreenSource",
]

EYES = ("left", "right")
"""The eyes, in the order the mirror shows them (left eye on the left)."""

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".gif", ".ppm", ".pgm", ".tga")
"""Image files a source may be (read with Pillow); GIF, PNG (APNG) and WebP may be animated."""

ANIMATED_SUFFIXES = (".gif", ".png", ".webp")
"""Image files that are played as a video when they hold more than one frame."""

VIDEO_SUFFIXES = (".mp4", ".m4v", ".mov", ".mkv", ".webm", ".avi", ".mpg", ".mpeg", ".ogv", ".wmv", ".flv")
"""Video files, decoded by the ffmpeg that ``imageio-ffmpeg`` ships (the ``realtime`` extra)."""

MAX_EYE_SIZE = 8192
"""Largest eye width or height accepted by :func:`parse_size` (pixels)."""

FFMPEG_HINT = "pip install imageio-ffmpeg (part of the realtime extra: pip install -e '.[realtime]')"


# --------------------------------------------------------------------------
# Parsing and pure helpers
# --------------------------------------------------------------------------


def parse_size(text: str, field: str = "--size") -> tuple[int, int]:
    """``"WxH"`` (e.g. ``"640x480"``) as ``(width, height)`` in pixels, each 1 to :data:`MAX_EYE_SIZE`."""
    match = re.fullmatch(r"\s*(\d{1,5})\s*[xX]\s*(\d{1,5})\s*", text) if isinstance(text, str) else None
    allowed = f"WIDTHxHEIGHT in pixels, each from 1 to {MAX_EYE_SIZE} (e.g. 640x640)"
    if not match:
        raise ValidationError(field, text, allowed)
    width, height = int(match.group(1)), int(match.group(2))
    if not (1 <= width <= MAX_EYE_SIZE and 1 <= height <= MAX_EYE_SIZE):
        raise ValidationError(field, text, allowed)
    return width, height


def parse_region(text: str, field: str = "--region") -> Rect:
    """``"X,Y,W,H"`` (pixels; ``(X, Y)`` the top-left corner, from the screen's top-left) as a
    :class:`~vrcorrect.runtime.gl.Rect`; W and H from 1 to :data:`MAX_EYE_SIZE`."""
    allowed = f"X,Y,WIDTH,HEIGHT in pixels (X, Y >= 0; WIDTH, HEIGHT 1 to {MAX_EYE_SIZE}), e.g. 0,0,640,480"
    match = re.fullmatch(r"\s*(\d{1,5})\s*,\s*(\d{1,5})\s*,\s*(\d{1,5})\s*,\s*(\d{1,5})\s*", text) \
        if isinstance(text, str) else None
    if not match:
        raise ValidationError(field, text, allowed)
    x, y, w, h = (int(g) for g in match.groups())
    if not (1 <= w <= MAX_EYE_SIZE and 1 <= h <= MAX_EYE_SIZE):
        raise ValidationError(field, text, allowed)
    return Rect(x, y, w, h)


@dataclass(frozen=True)
class SourceSpec:
    """A checked ``--source``: ``kind`` is ``"demo"``, ``"image"`` (a still or animated image
    file), ``"folder"`` (images cycled) or ``"video"``; ``path`` is ``None`` for the demo."""

    kind: str
    path: Path | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("demo", "image", "folder", "video"):
            raise ValidationError("source.kind", self.kind, "demo, image, folder or video")
        if (self.kind == "demo") != (self.path is None):
            raise ValidationError("source.path", self.path, "None for the demo, a path otherwise")

    @property
    def label(self) -> str:
        return "demo scene" if self.path is None else f"{self.kind} {self.path.name}"


def _supported_text() -> str:
    return (f"'demo', an image ({' '.join(s.lstrip('.') for s in IMAGE_SUFFIXES)}; animated GIF/PNG/WebP "
            f"play), a video ({' '.join(s.lstrip('.') for s in VIDEO_SUFFIXES)}; needs imageio-ffmpeg) "
            "or a folder of images")


def _ffmpeg_available() -> bool:
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        return False
    return True


def parse_source(text: str, field: str = "--source") -> SourceSpec:
    """Check a ``--source`` value: ``demo``, an image or video file, or a folder of images.

    Raises
    ------
    InputError
        A path that does not exist, a folder without images, a file of an unsupported
        kind, or a video when ``imageio-ffmpeg`` is not installed (names what is supported).
    """
    if not isinstance(text, str) or not text.strip():
        raise ValidationError(field, text, _supported_text())
    if text == "demo":
        return SourceSpec("demo")
    path = Path(text)
    if not path.exists():
        raise InputError(f"{path}: no such file or folder; {field} takes {_supported_text()}")
    if path.is_dir():
        folder_images(path)  # raises when empty
        return SourceSpec("folder", path)
    suffix = path.suffix.lower()
    if suffix in IMAGE_SUFFIXES:
        return SourceSpec("image", path)
    if suffix in VIDEO_SUFFIXES:
        if not _ffmpeg_available():
            raise InputError(f"{path}: video files need imageio-ffmpeg, which is not installed ({FFMPEG_HINT}); "
                             "without it, use an animated GIF/PNG/WebP, a folder of images or an image")
        return SourceSpec("video", path)
    raise InputError(f"{path}: unsupported file type {suffix or '(none)'!r}; {field} takes {_supported_text()}")


def folder_images(folder: str | Path) -> tuple[Path, ...]:
    """The image files (by suffix, see :data:`IMAGE_SUFFIXES`) directly in ``folder``, sorted by name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder")
    try:
        files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    except OSError as exc:
        raise InputError(f"{folder}: cannot list the folder ({exc.strerror or exc})") from None
    if not files:
        raise InputError(f"{folder}: no images in the folder (looked for {' '.join(IMAGE_SUFFIXES)})")
    return tuple(files)


def fit_rect(src_width: int, src_height: int, dst_width: int, dst_height: int) -> Rect:
    """The largest rectangle of the source's aspect ratio inside ``dst``, centred (image terms).

    A source of exactly the destination's size fills it; otherwise one side fills and the
    other is centred, rounded to whole pixels (at least 1).
    """
    for name, v in (("src_width", src_width), ("src_height", src_height),
                    ("dst_width", dst_width), ("dst_height", dst_height)):
        if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1:
            raise ValidationError(name, v, "an integer >= 1 (pixels)")
    if src_width * dst_height >= dst_width * src_height:  # source relatively wider: full width
        width, height = dst_width, max(1, min(dst_height, round(dst_width * src_height / src_width)))
    else:
        width, height = max(1, min(dst_width, round(dst_height * src_width / src_height))), dst_height
    return Rect((dst_width - width) // 2, (dst_height - height) // 2, int(width), int(height))


def frame_index(t_s: float, frames_per_s: float, count: int) -> int:
    """Index of the frame shown at time ``t_s`` of a looping sequence of ``count`` frames
    played at ``frames_per_s`` (frame i is shown from ``i / frames_per_s``)."""
    if not (isinstance(count, (int, np.integer)) and count >= 1):
        raise ValidationError("count", count, "an integer >= 1")
    if not (math.isfinite(frames_per_s) and frames_per_s > 0):
        raise ValidationError("frames_per_s", frames_per_s, "a finite number > 0")
    if not math.isfinite(t_s):
        raise ValidationError("t_s", t_s, "a finite time in seconds")
    return int(math.floor(max(t_s, 0.0) * frames_per_s + 1e-9)) % int(count)


def frame_at(t_s: float, durations_s: Sequence[float]) -> int:
    """Index of the frame shown at ``t_s`` in a looping sequence with these frame durations."""
    if len(durations_s) == 0 or any(not (math.isfinite(d) and d > 0) for d in durations_s):
        raise ValidationError("durations_s", durations_s, "one or more finite durations > 0 (seconds)")
    starts = np.concatenate([[0.0], np.cumsum(durations_s)])
    total = float(starts[-1])
    t = math.fmod(max(float(t_s), 0.0) + 1e-9, total) if math.isfinite(t_s) else 0.0  # 1e-9: 0.1 + 0.2 is 0.3
    return min(bisect.bisect_right(starts.tolist(), t) - 1, len(durations_s) - 1)


# --------------------------------------------------------------------------
# Matrices (row-major numpy, column vectors: p' = M @ p; upload M.T for GLSL)
# --------------------------------------------------------------------------


def perspective(fov_y_deg: float, aspect: float, near_m: float, far_m: float) -> np.ndarray:
    """OpenGL perspective projection (camera looks down -z; depth to [-1, 1])."""
    if not (0.0 < fov_y_deg < 180.0):
        raise ValidationError("fov_y_deg", fov_y_deg, "an angle between 0 and 180 degrees")
    if not (aspect > 0 and 0 < near_m < far_m):
        raise ValidationError("aspect/near_m/far_m", (aspect, near_m, far_m), "aspect > 0 and 0 < near < far")
    f = 1.0 / math.tan(math.radians(fov_y_deg) / 2.0)
    m = np.zeros((4, 4))
    m[0, 0] = f / aspect
    m[1, 1] = f
    m[2, 2] = (far_m + near_m) / (near_m - far_m)
    m[2, 3] = 2.0 * far_m * near_m / (near_m - far_m)
    m[3, 2] = -1.0
    return m


def translation(x: float, y: float, z: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def scaling(s: float) -> np.ndarray:
    return np.diag([s, s, s, 1.0])


def rotation_x(angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    m = np.eye(4)
    m[1:3, 1:3] = ((c, -s), (s, c))
    return m


def rotation_y(angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    m = np.eye(4)
    m[0, 0], m[0, 2], m[2, 0], m[2, 2] = c, s, -s, c
    return m


def _gl_matrix(m: np.ndarray) -> bytes:
    return np.ascontiguousarray(m.T, dtype=np.float32).tobytes()


# --------------------------------------------------------------------------
# Meshes: interleaved (x, y, z, nx, ny, nz, u, v) float32, counter-clockwise front faces
# --------------------------------------------------------------------------


def quad_mesh(width: float, height: float, uv: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 1.0)) -> np.ndarray:
    """A ``width`` x ``height`` rectangle in the z = 0 plane facing +z, centred on the origin;
    ``uv = (u0, v0, u1, v1)`` from its bottom-left to its top-right corner. ``(6, 8)``."""
    w, h = width / 2.0, height / 2.0
    u0, v0, u1, v1 = uv
    corners = [(-w, -h, u0, v0), (w, -h, u1, v0), (w, h, u1, v1), (-w, h, u0, v1)]
    rows = [(x, y, 0.0, 0.0, 0.0, 1.0, u, v) for x, y, u, v in (corners[i] for i in (0, 1, 2, 0, 2, 3))]
    return np.array(rows, np.float32)


def _tile_uv(tile: int, columns: int, rows: int) -> tuple[float, float, float, float]:
    """uv rectangle of atlas tile ``tile`` (row-major from the image's top-left), GL orientation."""
    col, row = tile % columns, tile // columns
    return (col / columns, 1.0 - (row + 1) / rows, (col + 1) / columns, 1.0 - row / rows)


def cube_mesh(size: float = 1.0, columns: int = 3, rows: int = 2) -> np.ndarray:
    """A cube of edge ``size`` centred on the origin; face i shows atlas tile i of a
    ``columns`` x ``rows`` atlas (faces +z, +x, -z, -x, +y, -y). ``(36, 8)``."""
    face = quad_mesh(size, size)
    face[:, 2] = size / 2.0  # pushed out to +z
    turns = [np.eye(4), rotation_y(math.pi / 2), rotation_y(math.pi), rotation_y(-math.pi / 2),
             rotation_x(-math.pi / 2), rotation_x(math.pi / 2)]
    out = []
    for i, turn in enumerate(turns):
        f = face.copy()
        f[:, 0:3] = f[:, 0:3] @ turn[:3, :3].T
        f[:, 3:6] = f[:, 3:6] @ turn[:3, :3].T
        u0, v0, u1, v1 = _tile_uv(i % (columns * rows), columns, rows)
        f[:, 6] = u0 + face[:, 6] * (u1 - u0)
        f[:, 7] = v0 + face[:, 7] * (v1 - v0)
        out.append(f)
    return np.concatenate(out).astype(np.float32)


def _floor_mesh(half_width_m: float, depth_m: float, y_m: float) -> np.ndarray:
    """The floor: a rectangle in the plane y = ``y_m`` facing +y, from z = 1 to z = -depth;
    uv in metres (the checker texture repeats)."""
    x0, x1, z0, z1 = -half_width_m, half_width_m, 1.0, -depth_m
    corners = [(x0, z0), (x1, z0), (x1, z1), (x0, z1)]
    rows = [(x, y_m, z, 0.0, 1.0, 0.0, x, -z) for x, z in (corners[i] for i in (0, 1, 2, 0, 2, 3))]
    return np.array(rows, np.float32)


# --------------------------------------------------------------------------
# The demo scene: configuration, pure transforms, textures
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class SceneConfig:
    """The demo scene's settings (metres, seconds, degrees).

    Attributes
    ----------
    ipd_m
        Distance between the two eyes' viewpoints (interpupillary distance), 0 to 0.1 m.
    fov_y_deg
        Vertical field of view of each eye.
    turn_rad_per_s
        How fast the cube turns.
    scroll_per_s
        How fast the text banner scrolls (banner lengths per second).
    text
        The scrolling line of text.
    samples
        Multisampling per pixel (0 or 1: none); lowered to what the GL supports.
    tile_px
        Side of each chart tile of the cube's texture atlas.
    """

    ipd_m: float = 0.064
    fov_y_deg: float = 60.0
    turn_rad_per_s: float = 0.45
    scroll_per_s: float = 0.04
    text: str = ("vrcorrect mirror - sharp images without glasses - ChromaCorrect pre-correction - "
                 "0123456789 - The quick brown fox jumps over the lazy dog -  ")
    samples: int = 4
    tile_px: int = 256

    def __post_init__(self) -> None:
        if not (0.0 <= self.ipd_m <= 0.1):
            raise ValidationError("ipd_m", self.ipd_m, "0 to 0.1 m")
        if not (10.0 <= self.fov_y_deg <= 150.0):
            raise ValidationError("fov_y_deg", self.fov_y_deg, "10 to 150 degrees")
        if not (isinstance(self.samples, int) and 0 <= self.samples <= 16):
            raise ValidationError("samples", self.samples, "an integer from 0 to 16")
        if not (isinstance(self.tile_px, int) and 16 <= self.tile_px <= 2048):
            raise ValidationError("tile_px", self.tile_px, "an integer from 16 to 2048")
        if not (isinstance(self.text, str) and self.text.strip()):
            raise ValidationError("text", self.text, "a non-empty line of text")


_FLOOR_Y_M = -1.2
_CUBE_AT = (0.0, -0.3, -2.8)
_CUBE_SIZE_M = 0.8
_PANELS = ((-1.6, 0.05, -4.2, 1.1, 0), (1.6, 0.05, -4.2, 1.1, 1))  # x, y, z, size, atlas tile
_BANNER = (0.0, 1.15, -4.0, 4.4, 0.42)                           # x, y, z, width, height (m)
_SKY_CODES = (0.62, 0.72, 0.86)                                   # sRGB code values
_LIGHT = np.array([0.45, 0.8, 0.55]) / np.linalg.norm([0.45, 0.8, 0.55])


def eye_position(eye: str, config: SceneConfig = SceneConfig()) -> np.ndarray:
    """Where ``eye`` looks from (m): half the IPD left or right of the origin."""
    if eye not in EYES:
        raise ValidationError("eye", eye, "'left' or 'right'")
    return np.array([(-0.5 if eye == "left" else 0.5) * config.ipd_m, 0.0, 0.0])


def scene_transforms(t_s: float, eye: str, aspect: float, config: SceneConfig = SceneConfig()) -> dict[str, np.ndarray]:
    """The matrices of the scene at time ``t_s`` seen by ``eye``: ``view_projection`` and one
    model matrix per object (``cube``, ``floor``, ``panel0``, ``panel1``, ``banner``)."""
    view = translation(*(-eye_position(eye, config)))
    projection = perspective(config.fov_y_deg, aspect, 0.05, 60.0)
    angle = config.turn_rad_per_s * t_s
    cube = translation(*_CUBE_AT) @ rotation_y(angle) @ rotation_x(0.45 + 0.35 * math.sin(0.6 * angle))
    out = {"view_projection": projection @ view, "cube": cube, "floor": np.eye(4),
           "banner": translation(*_BANNER[:3])}
    for i, (x, y, z, _, _) in enumerate(_PANELS):
        out[f"panel{i}"] = translation(x, y, z) @ rotation_y(-0.35 * math.copysign(1.0, x))
    return out


def _checker(size: int, squares: int) -> np.ndarray:
    """A black-and-white checkerboard, ``squares`` x ``squares``, code values (size, size, 3)."""
    idx = (np.arange(size) * squares) // size
    board = ((idx[:, None] + idx[None, :]) % 2).astype(np.float32)
    return np.repeat((0.08 + 0.84 * board)[..., None], 3, axis=2)


def _rings(size: int) -> np.ndarray:
    """A zone plate (concentric rings of rising spatial frequency): fine detail in every direction."""
    c = (np.arange(size) + 0.5) / size - 0.5
    r2 = c[:, None] ** 2 + c[None, :] ** 2
    v = 0.5 + 0.5 * np.cos(math.pi * size * 0.5 * r2)
    return np.repeat(v[..., None], 3, axis=2).astype(np.float32)


def chart_atlas(tile_px: int = 256) -> np.ndarray:
    """The cube's texture: a 3 x 2 grid of ``tile_px`` tiles, sRGB codes ``(2t, 3t, 4)`` uint8:
    Siemens star (36 spokes), text, colour bars / row 2: checkerboard, zone plate, star (72)."""
    from ..plumbing.charts import colour_bars, siemens_star, text_chart

    t = tile_px
    tiles = [siemens_star(t, 36), text_chart(t, t), colour_bars(t, t),
             _checker(t, 16), _rings(t), siemens_star(t, 72)]
    atlas = np.zeros((2 * t, 3 * t, 4), np.uint8)
    for i, tile in enumerate(tiles):
        r, c = divmod(i, 3)
        codes = np.round(np.clip(tile, 0.0, 1.0) * 255.0).astype(np.uint8)
        codes[:2], codes[-2:], codes[:, :2], codes[:, -2:] = 40, 40, 40, 40  # dark tile edges
        atlas[r * t:(r + 1) * t, c * t:(c + 1) * t, :3] = codes
    atlas[..., 3] = 255
    return atlas


def _font(size_px: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size_px)
    except TypeError:  # pragma: no cover - Pillow without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def text_banner(text: str, height_px: int = 64) -> np.ndarray:
    """One line of ``text``, dark on a light band, as sRGB codes ``(height_px, W, 4)`` uint8."""
    from PIL import Image, ImageDraw

    if not (isinstance(height_px, int) and 8 <= height_px <= 512):
        raise ValidationError("height_px", height_px, "an integer from 8 to 512")
    font = _font(int(height_px * 0.62))
    left, top, right, bottom = font.getbbox(text)
    width = max(8, int(math.ceil(font.getlength(text))) + 2)
    im = Image.new("RGBA", (width, height_px), (246, 240, 214, 255))
    draw = ImageDraw.Draw(im)
    draw.text((1, (height_px - (bottom - top)) // 2 - top), text, fill=(20, 24, 60, 255), font=font)
    return np.asarray(im, dtype=np.uint8).copy()


# --------------------------------------------------------------------------
# GPU side
# --------------------------------------------------------------------------


class _EyeTarget:
    """An eye's RGBA8 output texture (+ framebuffer), with a depth buffer and multisampled
    colour for drawing when ``samples`` > 1 (resolved into the texture)."""

    def __init__(self, ctx: "moderngl.Context", width: int, height: int, samples: int, depth: bool):
        from .gl import render_target

        self.ctx = ctx
        self.texture, self.framebuffer = render_target(ctx, width=width, height=height)
        self._objects: list[Any] = []
        self.draw_framebuffer = self.framebuffer
        self.multisampled = bool(depth and samples > 1)
        if self.multisampled:
            colour = ctx.renderbuffer((width, height), 4, samples=samples)
            depth_rb = ctx.depth_renderbuffer((width, height), samples=samples)
            self.draw_framebuffer = ctx.framebuffer(color_attachments=[colour], depth_attachment=depth_rb)
            self._objects = [self.draw_framebuffer, colour, depth_rb]
        elif depth:
            depth_rb = ctx.depth_renderbuffer((width, height))
            self.draw_framebuffer = ctx.framebuffer(color_attachments=[self.texture], depth_attachment=depth_rb)
            self._objects = [self.draw_framebuffer, depth_rb]

    def resolve(self) -> None:
        if self.multisampled:
            self.ctx.copy_framebuffer(self.framebuffer, self.draw_framebuffer)

    def release(self) -> None:
        from .gl import release

        release(*self._objects, self.framebuffer, self.texture)
        self._objects = []


class DemoScene:
    """The built-in moving 3D scene (see the module docstring), rendered per eye.

    Parameters
    ----------
    ctx
        A moderngl context (OpenGL 3.3 or newer).
    width, height
        Each eye's size in pixels.
    config
        :class:`SceneConfig`.
    """

    label = "demo scene"

    def __init__(self, ctx: "moderngl.Context", width: int, height: int, config: SceneConfig = SceneConfig()):
        from ..specs.display import srgb_to_linear
        from .gl import check_gl_errors, upload_texture
        from .shaders import compile_program

        self.ctx, self.size, self.config = ctx, (int(width), int(height)), config
        self._objects: list[Any] = []
        try:
            self.samples = min(config.samples, int(ctx.max_samples)) if config.samples > 1 else 0
            self.program = self._keep(compile_program(ctx, "scene.glsl"))
            atlas = self._keep(upload_texture(ctx, chart_atlas(config.tile_px), filter="mipmap", srgb=True))
            floor = np.round(_checker(64, 8) * 255).astype(np.uint8)
            floor_tex = self._keep(upload_texture(ctx, np.dstack([floor, np.full(floor.shape[:2], 255, np.uint8)]),
                                                  filter="mipmap", srgb=True))
            floor_tex.repeat_x = floor_tex.repeat_y = True
            banner = text_banner(config.text, 64)
            banner_tex = self._keep(upload_texture(ctx, banner, filter="mipmap", srgb=True))
            banner_tex.repeat_x = True
            for tex in (atlas, floor_tex, banner_tex):
                tex.anisotropy = min(8.0, float(ctx.max_anisotropy or 1.0))
            bx, by, bz, bw, bh = _BANNER
            # the banner shows a window of the text as wide as its aspect ratio, scrolled by u_uv_offset
            visible = (bw / bh) * banner.shape[0] / banner.shape[1]
            meshes = {
                "cube": (cube_mesh(_CUBE_SIZE_M), atlas),
                "floor": (_floor_mesh(14.0, 40.0, _FLOOR_Y_M), floor_tex),
                "banner": (quad_mesh(bw, bh, (0.0, 0.0, visible, 1.0)), banner_tex),
            }
            for i, (_, _, _, size, tile) in enumerate(_PANELS):
                meshes[f"panel{i}"] = (quad_mesh(size, size, _tile_uv(tile, 3, 2)), atlas)
            self._draws = {}
            for name, (mesh, tex) in meshes.items():
                vbo = self._keep(ctx.buffer(mesh.tobytes()))
                vao = self._keep(ctx.vertex_array(self.program, [(vbo, "3f 3f 2f", "in_position", "in_normal",
                                                                  "in_uv")]))
                self._draws[name] = (vao, tex, len(mesh))
            self.sky_codes = _SKY_CODES
            p = self.program
            p["u_light_direction"].value = tuple(float(v) for v in _LIGHT)
            p["u_fog_colour"].value = tuple(float(v) for v in srgb_to_linear(np.array(_SKY_CODES)))
            p["u_fog_per_m"].value = 0.025
            p["u_texture"].value = 0
            self._targets = {eye: _EyeTarget(ctx, *self.size, self.samples, depth=True) for eye in EYES}
            check_gl_errors(ctx, "DemoScene build")
        except BaseException:
            self.release()
            raise

    def _keep(self, obj: Any) -> Any:
        self._objects.append(obj)
        return obj

    def render(self, t_s: float, views: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None
               ) -> tuple["moderngl.Texture", "moderngl.Texture"]:
        """Draw the scene at time ``t_s`` for both eyes; ``(left, right)`` RGBA8 textures of sRGB codes.

        ``views``: each eye's ``(view_projection (4, 4), camera position (3,) m)``, e.g. from a
        headset's tracked poses and fields of view (:mod:`vrcorrect.runtime.xr`); by default the
        fixed eyes of :func:`scene_transforms` (``ipd_m`` apart, ``fov_y_deg``)."""
        import moderngl

        ctx, p = self.ctx, self.program
        width, height = self.size
        ctx.enable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        try:
            for eye in EYES:
                target = self._targets[eye]
                fb = target.draw_framebuffer
                fb.use()
                ctx.viewport = (0, 0, width, height)
                fb.clear(*self.sky_codes, 1.0, depth=1.0)
                transforms = scene_transforms(t_s, eye, width / height, self.config)
                if views is None:
                    view_projection, camera = transforms["view_projection"], eye_position(eye, self.config)
                else:
                    view_projection, camera = views[eye]
                p["u_view_projection"].write(_gl_matrix(np.asarray(view_projection, np.float64)))
                p["u_camera"].value = tuple(float(v) for v in camera)
                for name, (vao, tex, count) in self._draws.items():
                    p["u_model"].write(_gl_matrix(transforms[name]))
                    banner = name == "banner"
                    p["u_unlit"].value = 1.0 if banner else 0.0
                    p["u_uv_offset"].value = ((self.config.scroll_per_s * t_s) % 1.0 if banner else 0.0, 0.0)
                    tex.use(0)
                    vao.render(moderngl.TRIANGLES, vertices=count)
                target.resolve()
        finally:
            ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        return self._targets["left"].texture, self._targets["right"].texture

    def release(self) -> None:
        from .gl import release

        for target in getattr(self, "_targets", {}).values():
            target.release()
        self._targets = {}
        release(*reversed(self._objects))
        self._objects = []


class _FittedImage:
    """One picture fitted into an eye-sized RGBA8 texture of sRGB codes (black around it).

    The picture is uploaded as an sRGB texture with mipmaps (decoded, filtered and reduced in
    linear light) and drawn with ``composite.glsl`` (ENCODE_SRGB) into its :func:`fit_rect`.
    The picture's texture is reused while the picture size stays the same.
    """

    def __init__(self, ctx: "moderngl.Context", width: int, height: int):
        from .gl import fullscreen_triangle
        from .shaders import compile_program

        self.ctx, self.size = ctx, (int(width), int(height))
        self.target = _EyeTarget(ctx, width, height, 0, depth=False)
        self.program = None
        self.vao = None
        self.picture = None
        try:
            self.program = compile_program(ctx, "composite.glsl", defines={"ENCODE_SRGB": None})
            self.vao = fullscreen_triangle(ctx, self.program)
            self.program["u_source"].value = 0
        except BaseException:
            self.release()
            raise

    def show(self, image: np.ndarray) -> None:
        """Fit ``image`` (uint8 ``(H, W, 3|4)`` sRGB codes, top row first) into the texture."""
        from .gl import draw_fullscreen, release, upload_texture, write_texture

        img = np.asarray(image)
        if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] not in (3, 4):
            raise ValidationError("image", f"{img.dtype} array of shape {img.shape}", "uint8 (H, W, 3 or 4)")
        if self.picture is not None and self.picture.size == (img.shape[1], img.shape[0]) \
                and self.picture.components == img.shape[2]:
            write_texture(self.picture, img)
        else:
            release(self.picture)
            self.picture = None
            self.picture = upload_texture(self.ctx, img, filter="mipmap", srgb=True)
        fb = self.target.framebuffer
        fb.use()
        self.ctx.viewport = (0, 0, *self.size)
        fb.clear(0.0, 0.0, 0.0, 1.0)
        self.picture.use(0)
        draw_fullscreen(self.vao, fb, rect=fit_rect(img.shape[1], img.shape[0], *self.size))

    def release(self) -> None:
        from .gl import release

        release(self.picture, self.vao, self.program)
        self.picture = self.vao = self.program = None
        self.target.release()


def _as_codes(image: np.ndarray) -> np.ndarray:
    """Code values in [0, 1] (float) or uint8 -> uint8."""
    a = np.asarray(image)
    if a.dtype == np.uint8:
        return a
    return np.round(np.clip(a.astype(np.float32), 0.0, 1.0) * 255.0).astype(np.uint8)


class _PictureSource:
    """Base of the image sources: both eyes see the same fitted picture."""

    label = "image"

    def __init__(self, ctx: "moderngl.Context", width: int, height: int):
        self.ctx, self.size = ctx, (int(width), int(height))
        self._fitted = _FittedImage(ctx, width, height)
        self._shown: Any = None
        self.motion = None      # a MotionTracker when the caller wants the frames' motion (track_motion)
        self._codes: np.ndarray | None = None                # the picture shown (for track_motion)

    def track_motion(self) -> None:
        """Estimate the content's motion between consecutive pictures on the CPU, before upload
        (:mod:`vrcorrect.runtime.motion`), for :meth:`take_motion`."""
        from .motion import MotionTracker

        if self.motion is None:
            self.motion = MotionTracker()
            if self._codes is not None:                      # the picture shown already: the first
                self.motion.new_frame(self._codes)

    def take_motion(self) -> tuple[int, int] | str:
        """The content's motion in eye-texture pixels since the last call: ``(dx, dy)`` (x right,
        y down; ``(0, 0)`` when the picture has not changed or motion is not tracked) or ``"cut"``
        (unrelated pictures: the corrector should start cold)."""
        return (0, 0) if self.motion is None else self.motion.take()

    def _show(self, key: Any, image_fn) -> None:
        if key != self._shown:
            codes = _as_codes(image_fn())
            if self.motion is not None:
                r = fit_rect(codes.shape[1], codes.shape[0], *self.size)
                self.motion.new_frame(codes, (r.width / codes.shape[1], r.height / codes.shape[0]))
            self._fitted.show(codes)
            self._shown, self._codes = key, codes

    def render(self, t_s: float) -> tuple["moderngl.Texture", "moderngl.Texture"]:
        self._update(t_s)
        texture = self._fitted.target.texture
        return texture, texture

    def _update(self, t_s: float) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def release(self) -> None:
        self._fitted.release()


class StillSource(_PictureSource):
    """One image (array of sRGB code values, uint8 or float in [0, 1], or a file) for both eyes."""

    def __init__(self, ctx: "moderngl.Context", width: int, height: int, image: np.ndarray | str | Path,
                 label: str = "image"):
        from ..plumbing.imageio import read_image

        picture = read_image(image) if isinstance(image, (str, Path)) else np.asarray(image)
        super().__init__(ctx, width, height)
        self.label = label
        self._picture = _as_codes(picture)
        try:
            self._show(0, lambda: self._picture)
        except BaseException:
            self.release()
            raise

    def _update(self, t_s: float) -> None:
        pass


class FolderSource(_PictureSource):
    """The images of a folder, in name order, each shown for ``interval_s`` seconds, looping."""

    def __init__(self, ctx: "moderngl.Context", width: int, height: int, folder: str | Path,
                 interval_s: float = 3.0):
        if not (math.isfinite(interval_s) and interval_s > 0):
            raise ValidationError("interval_s", interval_s, "a number of seconds > 0")
        self.files = folder_images(folder)
        self.interval_s = float(interval_s)
        self.label = f"folder {Path(folder).name} ({len(self.files)} images)"
        super().__init__(ctx, width, height)
        try:
            self._update(0.0)
        except BaseException:
            self.release()
            raise

    def _update(self, t_s: float) -> None:
        from ..plumbing.imageio import read_image

        i = frame_index(t_s, 1.0 / self.interval_s, len(self.files))
        self._show(i, lambda: read_image(self.files[i]))
        self.index = i


class AnimatedImageSource(_PictureSource):
    """An animated GIF, PNG (APNG) or WebP, played at its own frame durations, looping."""

    MAX_FRAMES = 10000

    def __init__(self, ctx: "moderngl.Context", width: int, height: int, path: str | Path):
        from PIL import Image

        self.path = Path(path)
        try:
            self._image = Image.open(self.path)
            count = min(int(getattr(self._image, "n_frames", 1)), self.MAX_FRAMES)
            durations = []
            for i in range(count):
                self._image.seek(i)
                durations.append(max(float(self._image.info.get("duration") or 100.0), 10.0) / 1000.0)
        except (OSError, ValueError, EOFError) as exc:
            raise InputError(f"{self.path}: cannot read the animation ({exc})") from None
        self.durations_s = tuple(durations)
        self.label = f"animation {self.path.name} ({count} frames)"
        super().__init__(ctx, width, height)
        try:
            self._update(0.0)
        except BaseException:
            self.release()
            raise

    @staticmethod
    def is_animated(path: str | Path) -> bool:
        """True if the image file holds more than one frame."""
        from PIL import Image

        try:
            with Image.open(path) as im:
                return int(getattr(im, "n_frames", 1)) > 1
        except (OSError, ValueError):
            return False

    def _frame(self, i: int) -> np.ndarray:
        try:
            self._image.seek(i)
            return np.asarray(self._image.convert("RGB"), dtype=np.uint8)
        except (OSError, ValueError, EOFError) as exc:
            raise InputError(f"{self.path}: cannot read frame {i} ({exc})") from None

    def _update(self, t_s: float) -> None:
        i = frame_at(t_s, self.durations_s)
        self._show(i, lambda: self._frame(i))
        self.index = i

    def release(self) -> None:
        super().release()
        self._image.close()


class VideoSource(_PictureSource):
    """A video file decoded by ffmpeg (``imageio-ffmpeg``), played in real time, looping.

    Frames are read in order from ffmpeg's pipe; when rendering falls behind, frames in
    between are read and skipped, so the video keeps to the clock.
    """

    def __init__(self, ctx: "moderngl.Context", width: int, height: int, path: str | Path):
        self.path = Path(path)
        self.label = f"video {self.path.name}"
        self._frames: Iterator[bytes] | None = None
        self._open()
        super().__init__(ctx, width, height)
        try:
            self._update(0.0)
        except BaseException:
            self.release()
            raise

    def _open(self) -> None:
        try:
            import imageio_ffmpeg
        except ImportError:
            raise InputError(f"{self.path}: video files need imageio-ffmpeg ({FFMPEG_HINT})") from None
        self._close()
        try:
            frames = imageio_ffmpeg.read_frames(str(self.path))
            meta = next(frames)
        except (OSError, RuntimeError, StopIteration) as exc:
            raise InputError(f"{self.path}: ffmpeg cannot read the video ({str(exc).strip().splitlines()[-1:]})") \
                from None
        self._frames = frames
        self._passes = getattr(self, "_passes", -1) + 1
        self.frame_size = tuple(int(v) for v in meta["size"])
        fps = float(meta.get("fps") or 0.0)
        self.frames_per_s = fps if math.isfinite(fps) and fps > 0 else 25.0
        self._pass_start_s: float | None = None
        self._read = -1          # index (in this pass) of the last frame read
        self._last: np.ndarray | None = None

    def _close(self) -> None:
        frames = getattr(self, "_frames", None)
        if frames is not None:
            frames.close()  # imageio-ffmpeg stops its ffmpeg process
        self._frames = None

    def _next(self) -> np.ndarray | None:
        try:
            data = next(self._frames)
        except StopIteration:
            return None
        except (OSError, RuntimeError) as exc:
            raise InputError(f"{self.path}: ffmpeg failed while decoding ({exc})") from None
        w, h = self.frame_size
        return np.frombuffer(data, np.uint8).reshape(h, w, 3)

    def _update(self, t_s: float) -> None:
        if self._pass_start_s is None:
            self._pass_start_s = t_s
        target = int(math.floor((t_s - self._pass_start_s) * self.frames_per_s + 1e-9))
        while self._read < target:
            frame = self._next()
            if frame is None:  # end of the video: start again from its first frame
                if self._read < 0:
                    raise InputError(f"{self.path}: the video has no frames")
                self._open()
                self._pass_start_s = t_s
                target = 0
                continue
            self._read += 1
            self._last = frame
        key = (self._passes, self._read)
        self._show(key, lambda: self._last)

    def release(self) -> None:
        self._close()
        if hasattr(self, "_fitted"):
            super().release()


SCREEN_HINT = "pip install mss (part of the realtime extra: pip install -e '.[realtime]')"


def _mss():
    if not os.environ.get("DISPLAY"):
        raise InputError("the screen source needs an X11 display, and DISPLAY is not set "
                         "(under Wayland, only XWayland windows can be grabbed)")
    try:
        import mss
    except ImportError as exc:
        raise InputError(f"the screen source needs mss ({exc}; {SCREEN_HINT})") from None
    return mss


class ScreenGrabber:
    """Grabs rectangles of the X11 screen (the root window, all monitors) with ``mss``
    (XCB ``ShmGetImage``, or ``GetImage`` where shared memory is not available).

    Raises :class:`~vrcorrect.plumbing.errors.InputError` when there is no X display (or no ``mss``).
    What is grabbed is what the X server holds: windows above the region are in it, so a
    window showing the grab must lie outside the region.
    """

    def __init__(self) -> None:
        mss = _mss()
        try:
            self._mss = mss.MSS()
            whole = self._mss.monitors[0]
        except Exception as exc:  # mss raises ScreenShotError and ctypes/XCB errors
            raise InputError(f"cannot grab the X11 screen {os.environ.get('DISPLAY')!r} "
                             f"({' '.join(str(exc).split())[:200]})") from None
        self.bounds = Rect(0, 0, int(whole["width"]), int(whole["height"]))
        self._origin = (int(whole["left"]), int(whole["top"]))

    def grab(self, region: Rect) -> np.ndarray:
        """The pixels of ``region`` (screen pixels from the top-left of the whole screen) as
        ``(H, W, 3)`` uint8 sRGB codes, top row first."""
        region.check_inside(self.bounds.width, self.bounds.height)
        box = {"left": self._origin[0] + int(region.x), "top": self._origin[1] + int(region.y),
               "width": int(region.width), "height": int(region.height)}
        try:
            shot = self._mss.grab(box)
        except Exception as exc:
            raise InputError(f"grabbing the screen region {box} failed ({' '.join(str(exc).split())[:200]})") from None
        return np.asarray(shot)[..., 2::-1]  # BGRA -> RGB (a view; _FittedImage copies it once)

    def close(self) -> None:
        if getattr(self, "_mss", None) is not None:
            self._mss.close()
            self._mss = None


def screen_bounds() -> Rect:
    """The whole X11 screen (all monitors) as a rectangle at (0, 0)."""
    grabber = ScreenGrabber()
    try:
        return grabber.bounds
    finally:
        grabber.close()


class ScreenSource(_PictureSource):
    """A region of the X11 screen, grabbed every frame and fitted like an image (an output of
    the region's size shows it pixel for pixel). The picture texture is made on the first
    frame and rewritten in place after that.

    Raises :class:`~vrcorrect.plumbing.errors.ValidationError` when ``region`` is not inside the screen.
    """

    def __init__(self, ctx: "moderngl.Context", width: int, height: int, region: Rect):
        self.grabber = ScreenGrabber()
        try:
            b = self.grabber.bounds
            if region.x + region.width > b.width or region.y + region.height > b.height:
                raise ValidationError("--region", f"{region.x},{region.y},{region.width},{region.height}",
                                      f"a rectangle inside the {b.width}x{b.height} screen")
            self.region = region
            self.label = f"screen {region.width}x{region.height}+{region.x}+{region.y}"
            super().__init__(ctx, width, height)
        except BaseException:
            self.grabber.close()
            raise
        self._frames = 0
        try:
            self._update(0.0)
        except BaseException:
            self.release()
            raise

    def _update(self, t_s: float) -> None:
        self._frames += 1
        self._show(self._frames, lambda: self.grabber.grab(self.region))

    def release(self) -> None:
        self.grabber.close()
        if hasattr(self, "_fitted"):
            super().release()


def open_source(ctx: "moderngl.Context", spec: SourceSpec, width: int, height: int, *,
                scene_config: SceneConfig = SceneConfig(), folder_interval_s: float = 3.0):
    """The source ``spec`` (see :func:`parse_source`) rendering ``width`` x ``height`` eye
    textures: :class:`DemoScene`, :class:`StillSource`, :class:`AnimatedImageSource`,
    :class:`FolderSource` or :class:`VideoSource`. Each has ``render(t_s) -> (left, right)``,
    ``label``, ``size`` and ``release()``."""
    if spec.kind == "demo":
        return DemoScene(ctx, width, height, scene_config)
    if spec.kind == "folder":
        return FolderSource(ctx, width, height, spec.path, folder_interval_s)
    if spec.kind == "video":
        return VideoSource(ctx, width, height, spec.path)
    if spec.path.suffix.lower() in ANIMATED_SUFFIXES and AnimatedImageSource.is_animated(spec.path):
        return AnimatedImageSource(ctx, width, height, spec.path)
    return StillSource(ctx, width, height, spec.path, label=f"image {spec.path.name}")
