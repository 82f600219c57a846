"""The OpenXR API layer's interop with the application's graphics: the swapchain formats it corrects
(OpenGL and Vulkan codes), Vulkan memory and semaphores imported into GL (``GL_EXT_memory_object_fd``,
``GL_EXT_semaphore_fd``), the chains of images shared between the application and the layer's
context, the application's GLX context, and the few raw GL calls the layer makes itself.

Layer 5: numpy, moderngl (through the caching loader's entry points); never torch.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Iterator, Mapping

from ...plumbing.errors import ValidationError

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl


__all__ = ["GL_FORMATS", "GL_RGB10_A2", "GL_RGBA16F", "GL_RGBA8", "GL_SRGB8_ALPHA8", "QUERY_MAX_MS", "AppGlx",
           "ChainMemory", "MemoryObjects", "Semaphores", "SwapchainFormat", "Target", "VK_FORMATS", "check_rect",
           "flush_gl"]


_GL_FRAMEBUFFER_SRGB = 0x8DB9
_GL_TEXTURE_2D = 0x0DE1
_GL_TEXTURE_BINDING_2D = 0x8069
_GL_R32UI = 0x8236
_GL_RGBA16F = 0x881A
_GL_HANDLE_TYPE_OPAQUE_FD_EXT = 0x9586
QUERY_MAX_MS = 0xFFFFFFFF / 1e6
# shaders/layer_copy.glsl's codes
_ENCODINGS = {"srgb": 0, "linear": 1, "float": 2}
_PACKINGS = {"rgba8": 0, "bgra8": 1, "a2b10g10r10": 2}


@dataclass(frozen=True)
class SwapchainFormat:
    """A swapchain format the layer corrects: what its stored values mean.

    ``encoding``: ``"srgb"`` (sRGB code values), ``"linear"`` (normalized linear light) or
    ``"float"`` (linear light, any value); ``bits`` per colour channel; ``packing``: for a Vulkan
    32-bit format, how the 32 bits hold the channels (``"rgba8"``, ``"bgra8"``, ``"a2b10g10r10"``),
    ``None`` for a texture GL reads and writes itself."""

    name: str
    encoding: str
    bits: int
    packing: str | None = None

    @property
    def stage_codes(self) -> bool:
        """The Corrector's input: sRGB code values (8-bit formats), else linear light in a float texture."""
        return self.bits == 8


GL_SRGB8_ALPHA8 = 0x8C43
GL_RGBA8 = 0x8058
GL_RGB10_A2 = 0x8059
GL_RGBA16F = 0x881A
GL_FORMATS = {
    GL_RGBA16F: SwapchainFormat("GL_RGBA16F", "float", 16),
    GL_RGB10_A2: SwapchainFormat("GL_RGB10_A2", "linear", 10),
    GL_SRGB8_ALPHA8: SwapchainFormat("GL_SRGB8_ALPHA8", "srgb", 8),
    GL_RGBA8: SwapchainFormat("GL_RGBA8", "linear", 8),
}
"""The OpenGL swapchain formats the layer corrects (``GLenum`` -> meaning)."""

VK_FORMATS = {
    97: SwapchainFormat("VK_FORMAT_R16G16B16A16_SFLOAT", "float", 16),
    64: SwapchainFormat("VK_FORMAT_A2B10G10R10_UNORM_PACK32", "linear", 10, "a2b10g10r10"),
    43: SwapchainFormat("VK_FORMAT_R8G8B8A8_SRGB", "srgb", 8, "rgba8"),
    50: SwapchainFormat("VK_FORMAT_B8G8R8A8_SRGB", "srgb", 8, "bgra8"),
    37: SwapchainFormat("VK_FORMAT_R8G8B8A8_UNORM", "linear", 8, "rgba8"),
    44: SwapchainFormat("VK_FORMAT_B8G8R8A8_UNORM", "linear", 8, "bgra8"),
}
"""The Vulkan swapchain formats the layer corrects (``VkFormat`` -> meaning)."""


class MemoryObjects:
    """``GL_EXT_memory_object_fd`` through ctypes (moderngl has no wrapper): Vulkan memory, exported
    as a file descriptor by the shim, as the storage of a GL texture of the engine's own EGL context."""

    def __init__(self, ctx: "moderngl.Context"):
        missing = sorted({"GL_EXT_memory_object", "GL_EXT_memory_object_fd"} - set(ctx.extensions))
        if missing:
            raise RuntimeError(f"the engine's GL ({ctx.info.get('GL_RENDERER', '?')}) lacks {' and '.join(missing)}, "
                               "needed to import the Vulkan application's images")
        egl = ctypes.CDLL("libEGL.so.1")
        lookup = egl.eglGetProcAddress
        lookup.restype = ctypes.c_void_p
        lookup.argtypes = [ctypes.c_char_p]
        u32, i32, u64, ptr = ctypes.c_uint, ctypes.c_int, ctypes.c_uint64, ctypes.POINTER(ctypes.c_uint)

        def fn(name: str, restype: Any, *argtypes: Any) -> Any:
            address = lookup(name.encode())
            if not address:
                raise RuntimeError(f"EGL gives no {name}")
            return ctypes.CFUNCTYPE(restype, *argtypes)(address)

        self.create_memory = fn("glCreateMemoryObjectsEXT", None, i32, ptr)
        self.delete_memory = fn("glDeleteMemoryObjectsEXT", None, i32, ptr)
        self.import_fd = fn("glImportMemoryFdEXT", None, u32, u64, u32, i32)
        self.storage = fn("glTexStorageMem2DEXT", None, u32, i32, u32, i32, i32, u32, u64)
        self.gen_textures = fn("glGenTextures", None, i32, ptr)
        self.delete_textures = fn("glDeleteTextures", None, i32, ptr)
        self.bind_texture = fn("glBindTexture", None, u32, u32)
        self.get_integer = fn("glGetIntegerv", None, u32, ctypes.POINTER(ctypes.c_int))
        self.get_error = fn("glGetError", u32)

    def texture(self, fd: int, size: int, width: int, height: int, internal_format: int) -> tuple[int, int]:
        """A texture whose storage is the memory behind ``fd`` (GL owns ``fd`` from here): (texture, memory object)."""
        while self.get_error():
            pass
        memory = ctypes.c_uint(0)
        self.create_memory(1, ctypes.byref(memory))
        self.import_fd(memory.value, size, _GL_HANDLE_TYPE_OPAQUE_FD_EXT, fd)
        texture = ctypes.c_uint(0)
        self.gen_textures(1, ctypes.byref(texture))
        previous = ctypes.c_int(0)
        self.get_integer(_GL_TEXTURE_BINDING_2D, ctypes.byref(previous))
        self.bind_texture(_GL_TEXTURE_2D, texture.value)
        self.storage(_GL_TEXTURE_2D, 1, internal_format, width, height, memory.value, 0)
        self.bind_texture(_GL_TEXTURE_2D, previous.value)
        error = self.get_error()
        if error:
            self.free(texture.value, memory.value)
            raise RuntimeError(f"GL error 0x{error:04X} importing a {width}x{height} Vulkan image ({size} bytes)")
        return texture.value, memory.value

    def free(self, texture: int, memory: int) -> None:
        self.delete_textures(1, ctypes.byref(ctypes.c_uint(texture)))
        self.delete_memory(1, ctypes.byref(ctypes.c_uint(memory)))


class Semaphores:
    """Vulkan sessions, where the device has ``VK_KHR_external_semaphore_fd`` and the engine's GL
    ``GL_EXT_semaphore_fd``: the shim's two exported semaphores imported into a pipeline's context.
    ``ready`` (the shim's copy into the shared ``input`` images has finished) is waited on by GL before
    it reads them, ``done`` (the correction has finished) signalled by GL for the shim's copy out:
    neither side waits on the CPU.  Both images stay in ``GENERAL`` on GL's side."""

    LAYOUT_GENERAL = 0x958D                  # GL_LAYOUT_GENERAL_EXT

    def __init__(self, loader: Any, fds: tuple[int, int]):
        def fn(name: str, *argtypes: Any) -> Any:
            address = loader._address(name)
            if not address:
                raise RuntimeError(f"the engine's GL gives no {name}")
            return ctypes.CFUNCTYPE(None, *argtypes)(address)

        uint_p = ctypes.POINTER(ctypes.c_uint)
        gen = fn("glGenSemaphoresEXT", ctypes.c_int, uint_p)
        import_fd = fn("glImportSemaphoreFdEXT", ctypes.c_uint, ctypes.c_uint, ctypes.c_int)
        self._wait = fn("glWaitSemaphoreEXT", ctypes.c_uint, ctypes.c_uint, uint_p, ctypes.c_uint, uint_p, uint_p)
        self._signal = fn("glSignalSemaphoreEXT", ctypes.c_uint, ctypes.c_uint, uint_p, ctypes.c_uint, uint_p, uint_p)
        self._delete = fn("glDeleteSemaphoresEXT", ctypes.c_int, uint_p)
        self.names = (ctypes.c_uint * 2)()
        gen(2, self.names)
        for name, fd in zip(self.names, fds):
            import_fd(name, _GL_HANDLE_TYPE_OPAQUE_FD_EXT, os.dup(fd))     # GL owns the duplicate

    def _call(self, fn: Any, semaphore: int, textures: list["moderngl.Texture"]) -> None:
        n = len(textures)
        names = (ctypes.c_uint * max(n, 1))(*[t.glo for t in textures])
        layouts = (ctypes.c_uint * max(n, 1))(*([self.LAYOUT_GENERAL] * n))
        fn(semaphore, 0, None, n, names, layouts)

    def wait_ready(self, textures: list["moderngl.Texture"]) -> None:
        self._call(self._wait, self.names[0], textures)

    def signal_done(self, textures: list["moderngl.Texture"]) -> None:
        self._call(self._signal, self.names[1], textures)

    def release(self) -> None:
        self._delete(2, self.names)


@dataclass
class ChainMemory:
    """A Vulkan swapchain's two shared images as the shim exported them: the format, the size, and
    the memory of ``input`` (the submitted rects, copied there by the shim) and ``result`` (the
    correction, copied from there into the output image) as file descriptors the engine owns until
    the swapchain goes away; each pipeline imports duplicates of them."""

    format: SwapchainFormat
    code: int
    width: int
    height: int
    fds: tuple[int, int]
    sizes: tuple[int, int]

    def close(self) -> None:
        for fd in self.fds:
            try:
                os.close(fd)
            except OSError:
                pass


@dataclass
class _SharedChain:
    """A Vulkan swapchain's two shared images as one pipeline's textures."""

    format: SwapchainFormat
    input: "moderngl.Texture"
    result: "moderngl.Texture"
    names: tuple[tuple[int, int], ...]           # (texture, memory object) of each, for the deletion


Target = tuple[int, int, int]
"""What a pipeline is prepared for: (swapchain format code, rect width, rect height)."""


class AppGlx:
    """OpenGL sessions: the engine's own GLX context made current on the application's thread for a
    correction, and the application's put back after.  The engine's context shares the application's
    textures; the two are ordered by fences: the application's rendering is complete before the
    engine reads its image, and the correction is complete before the application (and the runtime
    behind it) goes on.  The waits are on the CPU (``glClientWaitSync``): drivers that do not order
    work across contexts on the GPU (llvmpipe) need it; on a GPU it waits for the correction, as the
    Vulkan path's fence does."""

    SYNC_GPU_COMMANDS_COMPLETE = 0x9117
    SYNC_FLUSH_COMMANDS_BIT = 0x1
    WAIT_NS = 5_000_000_000

    def __init__(self) -> None:
        gl = self.gl = ctypes.CDLL("libGL.so.1")
        for name in ("glXGetCurrentDisplay", "glXGetCurrentContext"):
            getattr(gl, name).restype = ctypes.c_void_p
        for name in ("glXGetCurrentDrawable", "glXGetCurrentReadDrawable"):
            getattr(gl, name).restype = ctypes.c_ulong
        gl.glXMakeContextCurrent.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_void_p]
        lookup = gl.glXGetProcAddressARB
        lookup.restype = ctypes.c_void_p
        lookup.argtypes = [ctypes.c_char_p]

        def fn(name: str, restype: Any, *argtypes: Any) -> Any:
            address = lookup(name.encode())
            if not address:
                raise RuntimeError(f"GLX gives no {name}")
            return ctypes.CFUNCTYPE(restype, *argtypes)(address)

        self.fence_sync = fn("glFenceSync", ctypes.c_void_p, ctypes.c_uint, ctypes.c_uint)
        self.client_wait = fn("glClientWaitSync", ctypes.c_uint, ctypes.c_void_p, ctypes.c_uint, ctypes.c_uint64)
        self.delete_sync = fn("glDeleteSync", None, ctypes.c_void_p)
        self.flush = fn("glFlush", None)

    def _fence(self) -> int | None:
        fence = self.fence_sync(self.SYNC_GPU_COMMANDS_COMPLETE, 0)
        self.flush()
        return fence

    def _wait(self, fence: int | None) -> None:
        if fence:
            self.client_wait(fence, self.SYNC_FLUSH_COMMANDS_BIT, self.WAIT_NS)
            self.delete_sync(fence)

    @contextlib.contextmanager
    def engine_current(self, inner: Any) -> Iterator[None]:
        """The engine's context (``inner``: a :class:`~vrcorrect.runtime.glcache.GlxSharedContext`)
        current for the block; whatever was current before comes back after."""
        gl = self.gl
        app = (gl.glXGetCurrentDisplay(), gl.glXGetCurrentDrawable(), gl.glXGetCurrentReadDrawable(),
               gl.glXGetCurrentContext())
        fence = self._fence() if app[3] else None
        inner.__enter__()
        done = None
        try:
            self._wait(fence)
            yield
            if inner.ctx:                                # (not when the block released the context)
                done = self._fence()
        finally:
            if app[3]:
                gl.glXMakeContextCurrent(*app)
                self._wait(done)
            else:
                inner.__exit__()


def flush_gl(loader: Any) -> None:
    ctypes.CFUNCTYPE(None)(loader._address("glFlush"))()


def _wait_sync(loader: Any, fence: int | None) -> None:
    """Wait (on the CPU, at most 5 s) for a GL sync object made on another context of the share group,
    then delete it."""
    if not fence:
        return
    wait = ctypes.CFUNCTYPE(ctypes.c_uint, ctypes.c_void_p, ctypes.c_uint, ctypes.c_uint64)(
        loader._address("glClientWaitSync"))
    delete = ctypes.CFUNCTYPE(None, ctypes.c_void_p)(loader._address("glDeleteSync"))
    wait(fence, 0x1, 5_000_000_000)
    delete(fence)


def check_rect(x: int, y: int, width: int, height: int, image_width: int, image_height: int) -> None:
    if width < 1 or height < 1 or x < 0 or y < 0 or x + width > image_width or y + height > image_height:
        raise ValidationError("imageRect", (x, y, width, height), f"inside the {image_width}x{image_height} swapchain image")


def _set_uniforms(program: "moderngl.Program", values: Mapping[str, Any]) -> None:
    """Set the uniforms the program has (the compiler drops those a stage does not use)."""
    for name, value in values.items():
        if name in program:
            program[name] = value
