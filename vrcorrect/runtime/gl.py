"""OpenGL plumbing for the real-time path: contexts, error checks, the fullscreen triangle,
textures, render targets and read-back.

Orientation
-----------
vrcorrect images are numpy arrays ``(H, W, C)`` with row 0 the **top** of the image. OpenGL
puts row 0 of a texture or framebuffer at the **bottom** (texture coordinate v = 0, window
y = 0, ``glReadPixels`` starts there). This module is the one place where the two meet:

* :func:`upload_texture` writes the image's rows bottom row first, and
  :func:`download_texture` / :func:`read_framebuffer` return rows top row first, so that on
  the GL side everything is GL-natural: v = 1 and ``gl_FragCoord.y = height - 0.5`` are the
  image's top row, and a texture drawn to a window appears upright;
* rectangles are given in image terms, ``Rect(x, y, width, height)`` with ``(x, y)`` the
  top-left corner, and become GL viewports through :func:`gl_viewport` and texture
  coordinates through :func:`uv_rect`.

Shaders never flip anything.

Object lifetime: moderngl objects live until released (or their context is). Release them
with :func:`release`, not ``.release()``: whenever moderngl creates a framebuffer it rebinds
the one last used, and if that framebuffer was deleted the driver raises
``GL_INVALID_OPERATION``; :func:`release` unbinds a bound framebuffer first.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass
from types import ModuleType
from typing import TYPE_CHECKING, Callable, Mapping, Protocol

import numpy as np
import numpy.typing as npt

from ..plumbing.errors import GLError, GLUnavailableError, ValidationError

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

MESA_DEBIAN_PACKAGES = ("libegl1", "libegl-mesa0", "libgl1", "libglx-mesa0", "libgl1-mesa-dri")
"""Debian/Ubuntu packages that give a headless EGL context on Mesa's llvmpipe."""

_DTYPES = {np.dtype(np.uint8): "f1", np.dtype(np.float32): "f4"}
_NUMPY_OF = {"f1": np.dtype(np.uint8), "f4": np.dtype(np.float32)}
_FILTERS = ("nearest", "linear", "mipmap")
_SRGB_FORMATS = {3: 0x8C41, 4: 0x8C43}  # GL_SRGB8, GL_SRGB8_ALPHA8


def _moderngl() -> ModuleType:
    try:
        import moderngl  # optional dependency (the realtime extra): a clear error when it is missing
    except ImportError as exc:  # pragma: no cover - the realtime extra is installed in CI
        raise GLUnavailableError(f"moderngl is not installed ({exc}); install the realtime extra: "
                                 "pip install -e '.[realtime]' (tools/setup.sh does)") from None
    return moderngl


# --------------------------------------------------------------------------
# Contexts and errors
# --------------------------------------------------------------------------


def headless_context(*, require: int = 330) -> "moderngl.Context":
    """A standalone OpenGL core context through EGL: no window, no display.

    Parameters
    ----------
    require
        Minimum OpenGL version as moderngl writes it (330 = 3.3; compute shaders need 430).
        Mesa's llvmpipe gives 4.5.

    Raises
    ------
    GLUnavailableError
        moderngl missing, EGL or GL libraries missing, or the version not available; the
        message names the Debian packages that provide Mesa's EGL and llvmpipe.
    """
    if not isinstance(require, int) or isinstance(require, bool) or not 200 <= require <= 460:
        raise ValidationError("require", require, "an OpenGL version code from 200 to 460 (330 = 3.3)")
    moderngl = _moderngl()
    try:
        inner = EglStandalone.standalone(require)
        return moderngl.create_context(require=require, standalone=True, context=inner)
    except Exception as exc:  # glcontext raises bare Exception ('libEGL.so.1 not loaded', 'egl... failed')
        raise GLUnavailableError(
            f"no headless OpenGL {require // 100}.{require % 100 // 10} context through EGL ({exc}); "
            f"on Debian/Ubuntu install Mesa's EGL and software GL: apt-get install "
            f"{' '.join(MESA_DEBIAN_PACKAGES)} (tools/setup.sh does)") from None


class EglStandalone:
    """glcontext's standalone EGL context (made by ``make``), which stops being current on its thread
    once released: the context that was current before it was made is current again (none if there
    was none, or it is gone).  glcontext destroys the context on release but leaves it current: GL
    calls then went to a destroyed context instead of the one the caller had, and libglvnd refused
    that thread any GLX context (GLFW's ``glXMakeCurrent`` failed with ``BadAccess`` and Xlib ended
    the process: a headless corrector, then a window, on one thread).  A glcontext-like object:
    ``load``, ``__enter__``, ``__exit__``, ``release``."""

    _EGL_DRAW, _EGL_READ = 0x3059, 0x305A

    def __init__(self, make: Callable[[], object]):
        self._egl = egl = ctypes.CDLL("libEGL.so.1")
        for name in ("eglGetCurrentContext", "eglGetCurrentDisplay", "eglGetCurrentSurface"):
            getattr(egl, name).restype = ctypes.c_void_p
        egl.eglGetCurrentSurface.argtypes = [ctypes.c_int32]
        egl.eglMakeCurrent.argtypes = [ctypes.c_void_p] * 4
        self.previous = (egl.eglGetCurrentDisplay(), egl.eglGetCurrentSurface(self._EGL_DRAW),
                         egl.eglGetCurrentSurface(self._EGL_READ), egl.eglGetCurrentContext())
        self.inner = make()
        self.handle = egl.eglGetCurrentContext()        # glcontext leaves a new context current

    @classmethod
    def standalone(cls, require: int) -> "EglStandalone":
        """glcontext's standalone EGL context of OpenGL ``require`` (330 = 3.3), made current."""
        import glcontext  # on use: glcontext (moderngl's own dependency, with the realtime extra)

        return cls(lambda: glcontext.get_backend_by_name("egl")(mode="standalone", glversion=require))

    def load(self, name: str) -> int:
        return self.inner.load(name)                    # type: ignore[attr-defined]

    def load_opengl_function(self, name: str) -> int:
        loader = getattr(self.inner, "load_opengl_function", None) or self.inner.load  # type: ignore[attr-defined]
        return loader(name)

    def __enter__(self) -> object:
        return self.inner.__enter__()                   # type: ignore[attr-defined]

    def __exit__(self, *args: object) -> object:
        return self.inner.__exit__(*args)               # type: ignore[attr-defined]

    def release(self) -> None:
        egl = self._egl
        if self.handle and egl.eglGetCurrentContext() == self.handle:
            display, draw, read, context = self.previous
            if not (context and context != self.handle and egl.eglMakeCurrent(display, draw, read, context)):
                egl.eglMakeCurrent(egl.eglGetCurrentDisplay(), None, None, None)
        self.inner.release()                            # type: ignore[attr-defined]


def check_gl_errors(ctx: "moderngl.Context", where: str) -> None:
    """Raise :class:`GLError` naming ``where`` if OpenGL has error flags set (and clear them).

    ``glGetError`` returns one flag per call; all pending flags (up to 16) are collected.
    """
    errors = []
    for _ in range(16):
        error = ctx.error
        if error == "GL_NO_ERROR":
            break
        errors.append(error)
    if errors:
        raise GLError(f"{where}: OpenGL reported {', '.join(errors)}")


TIMER_SATURATED_NS = 2 ** 32 - 1
"""moderngl (5.x) reads ``GL_TIME_ELAPSED`` with ``glGetQueryObjectuiv``: 32-bit nanoseconds. An
interval of 4.29 s or more does not fit; Mesa returns this value (saturated) for it, other drivers
may wrap, so a result this large is never a time."""


def timer_query_ms(raw_ns: object) -> float | None:
    """A timer query's raw result (nanoseconds) as milliseconds, or ``None`` when it is not a
    time: missing, not a finite number, negative, or :data:`TIMER_SATURATED_NS` or more (a
    32-bit read of an interval of 4.29 s or more, which printed as "4294.97 ms"). Show ``None``
    as no time ("-"/"n/a"), never as a number."""
    if raw_ns is None or isinstance(raw_ns, bool):
        return None
    try:
        value = float(raw_ns)
    except (TypeError, ValueError):
        return None
    if not np.isfinite(value) or value < 0 or value >= TIMER_SATURATED_NS:
        return None
    return value / 1e6


SOFTWARE_RENDERERS = ("llvmpipe", "softpipe", "swrast")
"""Words in ``GL_RENDERER`` that name Mesa's software renderers (the CPU, not a GPU)."""


def software_renderer(renderer: str) -> bool:
    """Whether ``renderer`` (``GL_RENDERER``) is one of Mesa's software renderers."""
    return any(word in renderer.lower() for word in SOFTWARE_RENDERERS)


def format_ms(ms: float | None, missing: str = "-") -> str:
    """``"12.34"`` for a time in milliseconds, ``missing`` for ``None`` (no valid measurement)."""
    return missing if ms is None else f"{ms:.2f}"


# --------------------------------------------------------------------------
# Orientation: the one place where image rows meet OpenGL rows
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class Rect:
    """A pixel rectangle in image terms: ``(x, y)`` is its top-left corner, y grows downwards."""

    x: int
    y: int
    width: int
    height: int

    def __post_init__(self) -> None:
        for name in ("x", "y", "width", "height"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 0:
                raise ValidationError(f"rect.{name}", value, "an integer >= 0 (pixels)")
        if self.width == 0 or self.height == 0:
            raise ValidationError("rect", self, "width and height >= 1")

    def check_inside(self, width: int, height: int) -> "Rect":
        """Itself, if it lies inside a ``width`` x ``height`` image."""
        if self.x + self.width > width or self.y + self.height > height:
            raise ValidationError("rect", self, f"a rectangle inside the {width}x{height} target")
        return self


def gl_viewport(rect: Rect, width: int, height: int) -> tuple[int, int, int, int]:
    """GL viewport ``(x, y_from_bottom, width, height)`` of ``rect`` in a ``width`` x ``height`` target."""
    rect.check_inside(width, height)
    return (int(rect.x), int(height - rect.y - rect.height), int(rect.width), int(rect.height))


def uv_rect(rect: Rect, width: int, height: int) -> tuple[float, float, float, float]:
    """Texture coordinates ``(u0, v0, du, dv)`` of ``rect`` in a ``width`` x ``height`` image
    uploaded with :func:`upload_texture` (composite.glsl's ``u_source_rect``)."""
    x, y, w, h = gl_viewport(rect, width, height)
    return (x / width, y / height, w / width, h / height)


def _gl_rows(image: np.ndarray) -> np.ndarray:
    """Image rows (top first) <-> OpenGL rows (bottom first): the same flip both ways."""
    return np.ascontiguousarray(image[::-1])


# --------------------------------------------------------------------------
# Textures and render targets
# --------------------------------------------------------------------------


def _texture_code(dtype: npt.DTypeLike, field: str) -> str:
    try:
        dt = np.dtype(dtype)
    except TypeError:
        dt = None
    if dt not in _DTYPES:
        raise ValidationError(field, str(dtype), "uint8 (normalised to [0, 1] in shaders) or float32")
    return _DTYPES[dt]


def _check_size(ctx: "moderngl.Context", width: int, height: int, field: str) -> None:
    limit = int(ctx.info["GL_MAX_TEXTURE_SIZE"])
    if not (1 <= width <= limit and 1 <= height <= limit):
        raise ValidationError(field, (width, height), f"width and height from 1 to {limit} (GL_MAX_TEXTURE_SIZE)")


def _set_sampling(texture: "moderngl.Texture", filter: str) -> None:
    moderngl = _moderngl()
    if filter not in _FILTERS:
        raise ValidationError("filter", filter, "one of: " + ", ".join(_FILTERS))
    if filter == "mipmap":
        texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
    else:
        mode = moderngl.NEAREST if filter == "nearest" else moderngl.LINEAR
        texture.filter = (mode, mode)
    texture.repeat_x = False  # clamp to edge
    texture.repeat_y = False


def upload_texture(ctx: "moderngl.Context", image: np.ndarray, *, filter: str = "nearest",
                   srgb: bool = False) -> "moderngl.Texture":
    """A 2D texture holding ``image``.

    Parameters
    ----------
    image
        ``(H, W, C)`` with C = 1 to 4 (RGB: 3, RGBA: 4), top row first, dtype uint8 (shaders
        read ``code / 255``) or float32 (stored as 32-bit floats, read as they are).
    filter
        ``"nearest"`` (default: exact texel values), ``"linear"``, or ``"mipmap"`` (trilinear
        over a mipmap chain built here; :func:`write_texture` rebuilds it). Edges clamp.
    srgb
        Store uint8 RGB/RGBA code values as an sRGB texture (``GL_SRGB8``/``GL_SRGB8_ALPHA8``):
        shaders then read linear light, decoded (and filtered, and mipmapped) by the GPU.

    Rows are stored bottom row first (module docstring, "Orientation"): v = 1 samples the
    image's top row.
    """
    arr = np.asarray(image)
    if arr.ndim != 3 or not 1 <= arr.shape[2] <= 4:
        raise ValidationError("image", f"array of shape {arr.shape}", "(H, W, C) with C from 1 to 4")
    code = _texture_code(arr.dtype, "image.dtype")
    height, width, components = arr.shape
    _check_size(ctx, width, height, "image size (width, height)")
    extra = {}
    if srgb:
        if code != "f1" or components not in _SRGB_FORMATS:
            raise ValidationError("srgb", f"{arr.dtype} image with {components} channel(s)",
                                  "uint8 RGB or RGBA code values for an sRGB texture")
        extra["internal_format"] = _SRGB_FORMATS[components]
    texture = ctx.texture((width, height), components, _gl_rows(arr).tobytes(), dtype=code, alignment=1, **extra)
    if filter == "mipmap":
        texture.build_mipmaps()
    _set_sampling(texture, filter)
    return texture


def write_texture(texture: "moderngl.Texture", image: np.ndarray) -> None:
    """Replace the contents of a texture made by :func:`upload_texture` with ``image`` of the
    same shape and dtype (top row first, as there); a mipmap chain is rebuilt. No allocation."""
    moderngl = _moderngl()
    arr = np.asarray(image)
    width, height = texture.size
    expected = (height, width, texture.components)
    if arr.shape != expected or texture.dtype not in _NUMPY_OF or arr.dtype != _NUMPY_OF[texture.dtype]:
        raise ValidationError("image", f"{arr.dtype} array of shape {arr.shape}",
                              f"{_NUMPY_OF.get(texture.dtype, texture.dtype)} of shape {expected} (the texture's)")
    texture.write(_gl_rows(arr).tobytes(), alignment=1)
    if texture.filter[0] == moderngl.LINEAR_MIPMAP_LINEAR:
        texture.build_mipmaps()
        texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)


def download_texture(texture: "moderngl.Texture") -> np.ndarray:
    """The texture's level 0 as ``(H, W, C)``, top row first; uint8 for 8-bit, float32 for float."""
    if texture.dtype not in _NUMPY_OF:
        raise ValidationError("texture.dtype", texture.dtype, "'f1' (uint8) or 'f4' (float32)")
    width, height = texture.size
    data = np.frombuffer(texture.read(alignment=1), dtype=_NUMPY_OF[texture.dtype])
    return _gl_rows(data.reshape(height, width, texture.components))


def render_target(ctx: "moderngl.Context", *, width: int, height: int, dtype: npt.DTypeLike = np.uint8,
                  components: int = 4, filter: str = "nearest") -> tuple["moderngl.Texture", "moderngl.Framebuffer"]:
    """A texture to draw into and its framebuffer: ``(texture, framebuffer)``.

    ``dtype`` uint8 (RGBA8; writes are clamped to [0, 1] and rounded to codes) or float32
    (RGBA32F; written as they are). ``components`` 1, 2 or 4 (3-component formats are not
    required to be renderable). Release both when done.
    """
    code = _texture_code(dtype, "dtype")
    if components not in (1, 2, 4):
        raise ValidationError("components", components, "1, 2 or 4 (RGB targets are not renderable everywhere)")
    _check_size(ctx, width, height, "render target size (width, height)")
    texture = ctx.texture((int(width), int(height)), components, dtype=code)
    _set_sampling(texture, filter)
    return texture, ctx.framebuffer(color_attachments=[texture])


def read_framebuffer(framebuffer: "moderngl.Framebuffer", *, components: int = 3, dtype: npt.DTypeLike = np.uint8,
                     rect: Rect | None = None) -> np.ndarray:
    """Pixels of colour attachment 0 (or of a window's default framebuffer) as ``(H, W, C)``,
    top row first. ``rect`` (image terms) reads part of it."""
    code = _texture_code(dtype, "dtype")
    if components not in (1, 2, 3, 4):
        raise ValidationError("components", components, "1 to 4")
    width, height = framebuffer.size
    viewport = (0, 0, width, height) if rect is None else gl_viewport(rect, width, height)
    if framebuffer.glo == 0:
        # moderngl (5.13) calls glReadBuffer(GL_COLOR_ATTACHMENT0) on the default framebuffer too,
        # which sets GL_INVALID_OPERATION while the read itself (from GL_BACK) succeeds. Refuse
        # to run on an error left by someone else, then clear exactly that one.
        ctx = framebuffer.ctx
        check_gl_errors(ctx, "before reading the default framebuffer")
        data = framebuffer.read(viewport=viewport, components=components, dtype=code, alignment=1)
        leftover = [e for e in (ctx.error, ctx.error) if e != "GL_NO_ERROR"]
        if leftover not in ([], ["GL_INVALID_OPERATION"]):
            raise GLError(f"reading the default framebuffer: OpenGL reported {', '.join(leftover)}")
    else:
        data = framebuffer.read(viewport=viewport, components=components, dtype=code, alignment=1)
    arr = np.frombuffer(data, dtype=_NUMPY_OF[code]).reshape(viewport[3], viewport[2], components)
    return _gl_rows(arr)


def bind_textures(program: "moderngl.Program", textures: Mapping[str, "moderngl.Texture"]) -> None:
    """Bind each texture to its own unit (0, 1, ...) and point the sampler uniform of that name at it."""
    for unit, (name, texture) in enumerate(textures.items()):
        try:
            uniform = program[name]
        except KeyError:
            raise ValidationError(f"textures.{name}", name, "a sampler uniform the program uses (unused "
                                  "uniforms are optimised away by the compiler)") from None
        uniform.value = unit
        texture.use(location=unit)


# --------------------------------------------------------------------------
# Drawing
# --------------------------------------------------------------------------


def fullscreen_triangle(ctx: "moderngl.Context", program: "moderngl.Program") -> "moderngl.VertexArray":
    """A vertex array that draws one triangle covering the viewport, for a program whose vertex
    stage uses ``fullscreen.glsl`` (positions from ``gl_VertexID``; no vertex buffer)."""
    vao = ctx.vertex_array(program, [])
    vao.vertices = 3
    return vao


def draw_fullscreen(vao: "moderngl.VertexArray", framebuffer: "moderngl.Framebuffer", *,
                    rect: Rect | None = None) -> None:
    """Draw the fullscreen triangle into ``framebuffer``, or into the part ``rect`` of it
    (image terms: top-left origin), by setting the viewport."""
    moderngl = _moderngl()
    width, height = framebuffer.size
    framebuffer.use()
    ctx = vao.ctx
    ctx.viewport = (0, 0, width, height) if rect is None else gl_viewport(rect, width, height)
    vao.render(mode=moderngl.TRIANGLES, vertices=3)


class Releasable(Protocol):
    """What :func:`release` takes: a moderngl object (texture, buffer, program, framebuffer, ...)."""

    def release(self) -> None: ...


def release(*objects: Releasable | None) -> None:
    """Release moderngl objects in the order given (``None`` is skipped).

    A framebuffer that is the context's bound one (its last ``use()``) is unbound first, by
    binding the default framebuffer (a window's, or none in a headless context), so that
    moderngl does not later rebind a deleted framebuffer (``GL_INVALID_OPERATION``).
    """
    moderngl = _moderngl()
    for obj in objects:
        if obj is None:
            continue
        if isinstance(obj, moderngl.Framebuffer) and getattr(obj.ctx, "fbo", None) is obj:
            ctx = obj.ctx
            default = ctx.screen if ctx.screen is not None else ctx.detect_framebuffer(0)
            if default is not obj:
                default.use()
        obj.release()
