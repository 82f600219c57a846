"""The built-in 3D demo scene the mirror and the headset show each eye, and :func:`open_source`,
the eye source a ``--source`` names (this scene, or a picture source of
:mod:`vrcorrect.runtime.shell.sources`).

:class:`DemoScene` renders, per frame, one RGBA8 texture per eye at the eye size, holding sRGB
code values in OpenGL's orientation (what :class:`~vrcorrect.runtime.corrector.Corrector`
takes): a turning cube covered with test charts (Siemens stars, text, colour bars, a
checkerboard), two chart panels, a checkered floor and a scrolling line of text; each eye from
its own position (the interpupillary distance apart), or from a headset's tracked poses. Drawn
with 4x multisampling where the GL has it, textures decoded, filtered and mipmapped in linear
light (sRGB textures), shaded in linear light and encoded to sRGB code values. Its GPU objects
are made when it is opened; rendering a frame allocates nothing.

Pure helpers (no GL): the matrices (:func:`perspective`, :func:`translation`,
:func:`rotation_x`, :func:`rotation_y`, :func:`scaling`), the meshes, :func:`scene_transforms`,
:func:`chart_atlas` and :func:`text_banner`.

Layer 5: numpy, Pillow, moderngl; never torch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np
from PIL import Image, ImageDraw

from ...plumbing.charts import colour_bars, siemens_star, text_chart
from ...plumbing.errors import ValidationError
from ...specs.vocabulary import VIEW_ORDER, Eye, either, names
from ..gl import check_gl_errors, release, upload_texture
from ..optional import require_moderngl
from ..shaders import compile_program
from .source_spec import SourceSpec
from .sources import EyeTarget, PictureFeed, open_picture_source
from .text import default_font

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

__all__ = [
    "SceneConfig", "perspective", "translation", "rotation_x", "rotation_y", "scaling", "cube_mesh", "quad_mesh",
    "eye_position", "scene_transforms", "chart_atlas", "text_banner", "DemoScene", "open_source",
]

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
    if eye not in names(VIEW_ORDER):
        raise ValidationError("eye", eye, either(VIEW_ORDER))
    return np.array([(-0.5 if eye == Eye.LEFT else 0.5) * config.ipd_m, 0.0, 0.0])


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


def text_banner(text: str, height_px: int = 64) -> np.ndarray:
    """One line of ``text``, dark on a light band, as sRGB codes ``(height_px, W, 4)`` uint8."""
    if not (isinstance(height_px, int) and 8 <= height_px <= 512):
        raise ValidationError("height_px", height_px, "an integer from 8 to 512")
    font = default_font(int(height_px * 0.62))
    left, top, right, bottom = font.getbbox(text)
    width = max(8, int(math.ceil(font.getlength(text))) + 2)
    im = Image.new("RGBA", (width, height_px), (246, 240, 214, 255))
    draw = ImageDraw.Draw(im)
    draw.text((1, (height_px - (bottom - top)) // 2 - top), text, fill=(20, 24, 60, 255), font=font)
    return np.asarray(im, dtype=np.uint8).copy()


# --------------------------------------------------------------------------
# GPU side
# --------------------------------------------------------------------------


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
        from ...specs.display import srgb_to_linear  # lazy: colour-science's tables, not needed to import the runtime

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
            self._targets = {eye: EyeTarget(ctx, *self.size, self.samples, depth=True) for eye in VIEW_ORDER}
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
        headset's tracked poses and fields of view (:mod:`vrcorrect.runtime.shell.xr`); by default the
        fixed eyes of :func:`scene_transforms` (``ipd_m`` apart, ``fov_y_deg``)."""
        moderngl = require_moderngl()
        ctx, p = self.ctx, self.program
        width, height = self.size
        ctx.enable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        try:
            for eye in VIEW_ORDER:
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
        return tuple(self._targets[eye].texture for eye in VIEW_ORDER)

    def release(self) -> None:
        for target in getattr(self, "_targets", {}).values():
            target.release()
        self._targets = {}
        release(*reversed(self._objects))
        self._objects = []


def open_source(ctx: "moderngl.Context", spec: SourceSpec, width: int, height: int, *,
                scene_config: SceneConfig = SceneConfig(), folder_interval_s: float = 3.0) -> PictureFeed:
    """The source ``spec`` (see :func:`~vrcorrect.runtime.shell.source_spec.parse_source`) rendering
    ``width`` x ``height`` eye textures: :class:`DemoScene`, or a picture source
    (:func:`~vrcorrect.runtime.shell.sources.open_picture_source`). Each has
    ``render(t_s) -> (left, right)``, ``label``, ``size`` and ``release()``."""
    if spec.kind == "demo":
        return DemoScene(ctx, width, height, scene_config)
    return open_picture_source(ctx, spec, width, height, folder_interval_s=folder_interval_s)
