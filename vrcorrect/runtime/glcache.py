"""OpenGL contexts that can be built off an application's frame: a GL function loader that caches
compiled programs between runs and lets other Python threads run during long GL calls.

moderngl takes its GL functions from a loader object (``moderngl.create_context(context=loader)``:
``load(name)`` returns each function's address; ``__enter__``, ``__exit__`` and ``release`` make the
context current, not current, and destroy it).  :class:`CachingLoader` wraps the loader of any
context (glcontext's EGL context, or :class:`GlxSharedContext`) and hands moderngl, for a few
functions, trampolines of its own:

* **Program binaries** (``glGetProgramBinary``): a program linked from GLSL is written to the cache
  folder (:func:`cache_dir`: ``$VRCORRECT_CACHE_DIR``, else ``$XDG_CACHE_HOME/vrcorrect``, default
  ``~/.cache/vrcorrect``), under ``programs/<driver>/<key>.bin``, the key a SHA-256 of the driver (GL
  vendor, renderer, version, GLSL version) and of every stage's type and source; the next link of
  the same sources on the same driver loads it (``glProgramBinary``) instead of compiling, and a
  stage that belongs to a cached program is not compiled at all (``glCompileShader`` waits for the
  link, which compiles it after all if the binary does not load: a changed driver, a damaged file).
  A driver that offers no binary format (``GL_NUM_PROGRAM_BINARY_FORMATS`` 0: Mesa with its own
  shader cache off) compiles every time.
* **The GIL**: moderngl holds Python's global interpreter lock through every GL call, so a shader
  compile (seconds on llvmpipe) or a first dispatch (where llvmpipe compiles the shader's machine
  code) on a worker thread would stop every other Python thread, the OpenXR layer's
  ``xrEndFrame`` among them.  The calls that can take long (compiles, links, binary loads,
  dispatches, draws, ``glFinish``/``glFlush``, read-backs, uploads, waits) go through a ctypes
  trampoline, and ctypes releases the GIL for the length of the real call.

Used by the OpenXR layer's engine (:mod:`vrcorrect.runtime.layer.engine`), which builds its Correctors
on a worker thread, each build on a context of its own (:func:`egl_context`, or for an OpenGL
session :class:`GlxSharedContext`, a GLX context on its own X connection that shares the
application's textures), and hands the context to the application's thread when it is ready.

Layer 5: ctypes, moderngl, glcontext; never torch.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import os
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator, Mapping

from ..plumbing.errors import GLUnavailableError
from .gl import MESA_DEBIAN_PACKAGES, EglStandalone

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

__all__ = ["CACHE_ENV", "cache_dir", "CachingLoader", "GlxSharedContext", "egl_context", "glx_context",
           "ProgramCacheStats"]

CACHE_ENV = "VRCORRECT_CACHE_DIR"

_GL_COMPILE_STATUS = 0x8B81
_GL_LINK_STATUS = 0x8B82
_GL_INFO_LOG_LENGTH = 0x8B84
_GL_SHADER_TYPE = 0x8B4F
_GL_PROGRAM_BINARY_LENGTH = 0x8741
_GL_NUM_PROGRAM_BINARY_FORMATS = 0x87FE
_GL_PROGRAM_BINARY_RETRIEVABLE_HINT = 0x8257
_GL_VENDOR, _GL_RENDERER, _GL_VERSION, _GL_SHADING_LANGUAGE_VERSION = 0x1F00, 0x1F01, 0x1F02, 0x8B8C

u32, i32, u64, ptr, size = ctypes.c_uint, ctypes.c_int, ctypes.c_uint64, ctypes.c_void_p, ctypes.c_ssize_t

# GL calls that may take long, by signature (restype, argtypes): each goes through a trampoline that
# releases the GIL for the real call.
_SLOW: dict[str, tuple[Any, tuple[Any, ...]]] = {
    "glDispatchCompute": (None, (u32, u32, u32)),
    "glDispatchComputeIndirect": (None, (size,)),
    "glDrawArrays": (None, (u32, i32, i32)),
    "glDrawArraysInstanced": (None, (u32, i32, i32, i32)),
    "glDrawElements": (None, (u32, i32, u32, ptr)),
    "glDrawElementsInstanced": (None, (u32, i32, u32, ptr, i32)),
    "glFinish": (None, ()),
    "glFlush": (None, ()),
    "glGetTexImage": (None, (u32, i32, u32, u32, ptr)),
    "glReadPixels": (None, (i32, i32, i32, i32, u32, u32, ptr)),
    "glGetBufferSubData": (None, (u32, size, size, ptr)),
    "glMapBufferRange": (ptr, (u32, size, size, u32)),
    "glTexImage2D": (None, (u32, i32, i32, i32, i32, i32, u32, u32, ptr)),
    "glTexSubImage2D": (None, (u32, i32, i32, i32, i32, i32, u32, u32, ptr)),
    "glTexImage3D": (None, (u32, i32, i32, i32, i32, i32, i32, u32, u32, ptr)),
    "glTexSubImage3D": (None, (u32, i32, i32, i32, i32, i32, i32, i32, u32, u32, ptr)),
    "glBufferData": (None, (u32, size, ptr, u32)),
    "glBufferSubData": (None, (u32, size, size, ptr)),
    "glCopyBufferSubData": (None, (u32, u32, size, size, size)),
    "glBlitFramebuffer": (None, (i32, i32, i32, i32, i32, i32, i32, i32, u32, u32)),
    "glGenerateMipmap": (None, (u32,)),
    "glClientWaitSync": (u32, (ptr, u32, u64)),
    "glClear": (None, (u32,)),
}


def cache_dir(env: Mapping[str, str] | None = None) -> Path:
    """vrcorrect's cache folder: ``$VRCORRECT_CACHE_DIR``, else ``$XDG_CACHE_HOME/vrcorrect``
    (default ``~/.cache/vrcorrect``)."""
    env = os.environ if env is None else env
    if env.get(CACHE_ENV):
        return Path(env[CACHE_ENV])
    base = env.get("XDG_CACHE_HOME") or str(Path(env.get("HOME") or Path.home()) / ".cache")
    return Path(base) / "vrcorrect"


class ProgramCacheStats:
    """What a loader's program cache did: programs loaded from binaries, linked from GLSL (and
    stored), and why it could not cache (``disabled``: the reason, or ``None``)."""

    def __init__(self) -> None:
        self.loaded = 0
        self.linked = 0
        self.stored = 0
        self.disabled: str | None = None

    def __repr__(self) -> str:
        return (f"ProgramCacheStats(loaded={self.loaded}, linked={self.linked}, stored={self.stored}, "
                f"disabled={self.disabled!r})")


class CachingLoader:
    """A moderngl loader around ``inner`` (a glcontext-like object: ``load(name)``, ``__enter__``,
    ``__exit__``, ``release``) with the program cache in ``folder`` (``None``: :func:`cache_dir`;
    ``False``: no cache, only the GIL release) and the GIL released during slow calls (module
    docstring).  ``on_release`` is called once the inner context is released."""

    def __init__(self, inner: Any, folder: Path | None | bool = None,
                 on_release: Callable[[], None] | None = None):
        self.inner = inner
        self.folder = None if folder is False else (cache_dir() / "programs" if folder in (None, True) else Path(folder))
        self.stats = ProgramCacheStats()
        self._on_release = on_release
        self._callbacks: list[Any] = []          # the trampolines (kept alive as long as the loader)
        self._real: dict[str, Any] = {}
        self._shaders: dict[int, list[Any]] = {}     # shader -> [type, source, compiled?]
        self._attached: dict[int, list[int]] = {}    # program -> shaders
        self._driver: str | None = None
        self._lock = threading.Lock()

    # ------------------------------------------------------------ the loader protocol

    def load(self, name: str) -> int:
        address = self._address(name)
        if not address:
            return 0
        hook = _HOOKS.get(name)
        if hook is not None and self.folder is not None:
            return self._trampoline(name, address, *hook[0], getattr(self, hook[1]))
        if name in _SLOW:
            return self._trampoline(name, address, *_SLOW[name], self._slow(name))
        if name in ("glCompileShader", "glLinkProgram"):          # no cache: still without the GIL
            return self._trampoline(name, address, *_HOOKS[name][0], self._slow(name))
        return address

    def load_opengl_function(self, name: str) -> int:
        return self.load(name)

    def __enter__(self) -> Any:
        return self.inner.__enter__()

    def __exit__(self, *args: Any) -> Any:
        return self.inner.__exit__(*args)

    def release(self) -> None:
        try:
            self.inner.release()
        finally:
            if self._on_release is not None:
                self._on_release()

    # ------------------------------------------------------------ plumbing

    def _address(self, name: str) -> int:
        loader = getattr(self.inner, "load_opengl_function", None) or self.inner.load
        return int(loader(name) or 0)

    def _function(self, name: str, restype: Any = None, argtypes: tuple[Any, ...] = ()) -> Any:
        """The real GL function ``name`` (called through ctypes: the GIL is released during the call)."""
        key = f"{name}/{restype}/{argtypes}"
        fn = self._real.get(key)
        if fn is None:
            address = self._address(name)
            if not address:
                raise RuntimeError(f"the GL has no {name}")
            fn = self._real[key] = ctypes.CFUNCTYPE(restype, *argtypes)(address)
        return fn

    def _trampoline(self, name: str, address: int, restype: Any, argtypes: tuple[Any, ...],
                    body: Callable[..., Any]) -> int:
        real = ctypes.CFUNCTYPE(restype, *argtypes)(address)
        self._real[f"{name}/{restype}/{argtypes}"] = real
        callback = ctypes.CFUNCTYPE(restype, *argtypes)(lambda *a: body(real, *a))
        self._callbacks.append(callback)
        return ctypes.cast(callback, ctypes.c_void_p).value or 0

    @staticmethod
    def _slow(name: str) -> Callable[..., Any]:
        def call(real: Any, *args: Any) -> Any:
            return real(*args)
        return call

    # ------------------------------------------------------------ the program cache

    def _driver_key(self) -> str | None:
        """The driver's identity (hashed), or None when it offers no program binary format."""
        if self._driver is None:
            get_string = self._function("glGetString", ctypes.c_char_p, (u32,))
            parts = [get_string(e) or b"" for e in (_GL_VENDOR, _GL_RENDERER, _GL_VERSION, _GL_SHADING_LANGUAGE_VERSION)]
            count = ctypes.c_int(0)
            self._function("glGetIntegerv", None, (u32, ctypes.POINTER(ctypes.c_int)))(
                _GL_NUM_PROGRAM_BINARY_FORMATS, ctypes.byref(count))
            if count.value < 1:
                self.stats.disabled = "the driver offers no program binary format"
                self._driver = ""
            else:
                self._driver = hashlib.sha256(b"\n".join(parts)).hexdigest()[:24]
        return self._driver or None

    def _shader_hash(self, shader: int) -> str:
        kind, text = self._shaders[shader][0], self._shaders[shader][1]
        return hashlib.sha256(f"{kind}\n".encode() + text).hexdigest()

    def _marker(self, driver: str, shader_hash: str) -> Path:
        assert self.folder is not None
        return self.folder / driver / "stages" / shader_hash

    def _create_shader(self, real: Any, kind: int) -> int:
        shader = real(kind)
        if shader:
            self._shaders[int(shader)] = [int(kind), b"", True]
        return shader

    def _shader_source(self, real: Any, shader: int, count: int, strings: Any, lengths: Any) -> None:
        real(shader, count, strings, lengths)
        parts = []
        for i in range(count):
            if lengths and lengths[i] >= 0:
                parts.append(ctypes.string_at(strings[i], lengths[i]))
            else:
                parts.append(ctypes.string_at(strings[i]))
        entry = self._shaders.setdefault(int(shader), [0, b"", True])
        entry[1] = b"".join(parts)

    def _compile_shader(self, real: Any, shader: int) -> None:
        entry = self._shaders.get(int(shader))
        driver = self._driver_key() if entry is not None else None
        if entry is not None and driver and self._marker(driver, self._shader_hash(int(shader))).exists():
            entry[2] = False                     # part of a cached program: compiled at the link, if at all
            return
        real(shader)

    def _get_shader_iv(self, real: Any, shader: int, pname: int, params: Any) -> None:
        entry = self._shaders.get(int(shader))
        if entry is not None and not entry[2] and pname in (_GL_COMPILE_STATUS, _GL_INFO_LOG_LENGTH):
            params[0] = 1 if pname == _GL_COMPILE_STATUS else 0
            return
        real(shader, pname, params)

    def _attach_shader(self, real: Any, program: int, shader: int) -> None:
        real(program, shader)
        self._attached.setdefault(int(program), []).append(int(shader))

    def _delete_shader(self, real: Any, shader: int) -> None:
        real(shader)
        self._shaders.pop(int(shader), None)
        for shaders in self._attached.values():
            if int(shader) in shaders:
                shaders.remove(int(shader))

    def _link_program(self, real: Any, program: int) -> None:
        shaders = [s for s in self._attached.pop(int(program), []) if s in self._shaders]
        driver = self._driver_key()
        if not driver or not shaders:
            self._compile_pending(shaders)
            real(program)
            return
        stages = sorted(self._shader_hash(s) for s in shaders)
        key = hashlib.sha256((driver + "\n" + "\n".join(stages)).encode()).hexdigest()
        path = self.folder / driver / f"{key}.bin"          # type: ignore[operator]
        if path.is_file() and self._load_binary(program, path):
            self.stats.loaded += 1
            return
        self._compile_pending(shaders)
        self._function("glProgramParameteri", None, (u32, u32, i32))(program, _GL_PROGRAM_BINARY_RETRIEVABLE_HINT, 1)
        real(program)
        self.stats.linked += 1
        if self._status(program) and self._store(program, path):
            self.stats.stored += 1
            for h in stages:
                marker = self._marker(driver, h)
                marker.parent.mkdir(parents=True, exist_ok=True)
                marker.touch()

    def _compile_pending(self, shaders: list[int]) -> None:
        compile_ = self._function("glCompileShader", None, (u32,))
        for s in shaders:
            entry = self._shaders.get(s)
            if entry is not None and not entry[2]:
                compile_(s)
                entry[2] = True

    def _status(self, program: int) -> bool:
        value = ctypes.c_int(0)
        self._function("glGetProgramiv", None, (u32, u32, ctypes.POINTER(ctypes.c_int)))(
            program, _GL_LINK_STATUS, ctypes.byref(value))
        return bool(value.value)

    def _load_binary(self, program: int, path: Path) -> bool:
        try:
            data = path.read_bytes()
        except OSError:
            return False
        if len(data) < 5:
            return False
        fmt = int.from_bytes(data[:4], "little")
        blob = data[4:]
        self._function("glProgramBinary", None, (u32, u32, ctypes.c_char_p, i32))(program, fmt, blob, len(blob))
        if self._status(program):
            return True
        while self._function("glGetError", u32, ())():
            pass
        return False

    def _store(self, program: int, path: Path) -> bool:
        length = ctypes.c_int(0)
        self._function("glGetProgramiv", None, (u32, u32, ctypes.POINTER(ctypes.c_int)))(
            program, _GL_PROGRAM_BINARY_LENGTH, ctypes.byref(length))
        if length.value <= 0:
            return False
        buffer = ctypes.create_string_buffer(length.value)
        written, fmt = ctypes.c_int(0), ctypes.c_uint(0)
        self._function("glGetProgramBinary", None, (u32, i32, ctypes.POINTER(ctypes.c_int), ctypes.POINTER(ctypes.c_uint),
                                                    ptr))(program, length.value, ctypes.byref(written),
                                                          ctypes.byref(fmt), buffer)
        if written.value <= 0:
            return False
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f"{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
            tmp.write_bytes(int(fmt.value).to_bytes(4, "little") + buffer.raw[:written.value])
            tmp.replace(path)
        except OSError:
            return False
        return True


# the functions the program cache watches: (restype, argtypes), method
_HOOKS: dict[str, tuple[tuple[Any, tuple[Any, ...]], str]] = {
    "glCreateShader": ((u32, (u32,)), "_create_shader"),
    "glShaderSource": ((None, (u32, i32, ctypes.POINTER(ptr), ctypes.POINTER(ctypes.c_int))), "_shader_source"),
    "glCompileShader": ((None, (u32,)), "_compile_shader"),
    "glGetShaderiv": ((None, (u32, u32, ctypes.POINTER(ctypes.c_int))), "_get_shader_iv"),
    "glAttachShader": ((None, (u32, u32)), "_attach_shader"),
    "glDeleteShader": ((None, (u32,)), "_delete_shader"),
    "glLinkProgram": ((None, (u32,)), "_link_program"),
}


# ---------------------------------------------------------------------------------------------- contexts


def _egl_initialize() -> None:
    """Initialise the EGL display glcontext will use (the first device's, ``EGL_PLATFORM_DEVICE_EXT``)
    through ctypes, which lets other Python threads run meanwhile: the first initialisation loads the
    GL driver (hundreds of ms), which glcontext would do holding the GIL.  Any failure is left for
    glcontext to report."""
    try:
        egl = ctypes.CDLL("libEGL.so.1")
        lookup = egl.eglGetProcAddress
        lookup.restype = ptr
        lookup.argtypes = [ctypes.c_char_p]
        query = ctypes.CFUNCTYPE(u32, i32, ctypes.POINTER(ptr), ctypes.POINTER(ctypes.c_int))(lookup(b"eglQueryDevicesEXT"))
        platform = ctypes.CFUNCTYPE(ptr, u32, ptr, ptr)(lookup(b"eglGetPlatformDisplayEXT"))
        count = ctypes.c_int(0)
        if not query(0, None, ctypes.byref(count)) or count.value < 1:
            return
        devices = (ptr * count.value)()
        if not query(count.value, devices, ctypes.byref(count)):
            return
        display = platform(0x313F, devices[0], None)               # EGL_PLATFORM_DEVICE_EXT
        if display:
            egl.eglInitialize.argtypes = [ptr, ptr, ptr]
            egl.eglInitialize(display, None, None)
    except (OSError, AttributeError, TypeError, ValueError):
        pass


def egl_context(require: int = 430, cache: Path | None | bool = None) -> "moderngl.Context":
    """A headless OpenGL context through EGL (as :func:`vrcorrect.runtime.gl.headless_context`),
    current on the calling thread, with a :class:`CachingLoader` (``cache``: its folder, ``None``
    the default, ``False`` none).  ``with ctx:`` makes it current on a thread, leaving makes no
    context current."""
    import moderngl  # on use: moderngl (optional: the realtime extra)

    _egl_initialize()
    try:
        inner = EglStandalone.standalone(require)
    except Exception as exc:  # glcontext raises bare Exception
        raise GLUnavailableError(
            f"no headless OpenGL {require // 100}.{require % 100 // 10} context through EGL ({exc}); on Debian/Ubuntu "
            f"install Mesa's EGL and software GL: apt-get install {' '.join(MESA_DEBIAN_PACKAGES)}") from None
    loader = CachingLoader(inner, cache)
    ctx = moderngl.create_context(require=require, standalone=True, context=loader)
    ctx.extra = loader
    return ctx


class GlxSharedContext:
    """A GLX context that shares objects (textures, buffers, programs, syncs) with an application's
    GLX context, on an X connection of its own (so that a worker thread may make it current while
    the application's thread uses its own connection), with no drawable (``GLX_ARB_create_context``:
    OpenGL 3.0 and later may be current without one).  A glcontext-like object: ``load``,
    ``__enter__`` (current on the calling thread), ``__exit__`` (no context current on the calling
    thread), ``release`` (destroy it and close the connection).

    ``display``, ``fbconfig``, ``context``: the application's ``Display*``, ``GLXFBConfig`` and
    ``GLXContext`` (addresses, from ``XrGraphicsBindingOpenGLXlibKHR``; the configuration is read from
    the context, the ``GLXFBConfig`` is used only where that fails: applications may leave it NULL)."""

    def __init__(self, display: int, fbconfig: int, context: int, require: int = 430):
        self.gl = gl = ctypes.CDLL("libGL.so.1")
        self.x11 = x11 = ctypes.CDLL("libX11.so.6")
        x11.XDisplayString.restype = ctypes.c_char_p
        x11.XDisplayString.argtypes = [ptr]
        x11.XOpenDisplay.restype = ptr
        x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
        x11.XCloseDisplay.argtypes = [ptr]
        x11.XFree.argtypes = [ptr]
        gl.glXGetProcAddressARB.restype = ptr
        gl.glXGetProcAddressARB.argtypes = [ctypes.c_char_p]
        gl.glXGetFBConfigAttrib.argtypes = [ptr, ptr, i32, ctypes.POINTER(ctypes.c_int)]
        gl.glXChooseFBConfig.restype = ctypes.POINTER(ptr)
        gl.glXChooseFBConfig.argtypes = [ptr, i32, ctypes.POINTER(ctypes.c_int), ctypes.POINTER(ctypes.c_int)]
        gl.glXMakeContextCurrent.argtypes = [ptr, ctypes.c_ulong, ctypes.c_ulong, ptr]
        gl.glXDestroyContext.argtypes = [ptr, ptr]
        self.dpy = None
        self.ctx = None
        x11.XScreenCount.argtypes = [ptr]
        gl.glXQueryContext.argtypes = [ptr, ptr, i32, ctypes.POINTER(ctypes.c_int)]
        # the config's ID from the context itself (a direct context answers without asking the server);
        # the binding's glxFBConfig only where that fails (some applications leave it NULL)
        config_id = ctypes.c_int(0)
        if gl.glXQueryContext(display, context, 0x8013, ctypes.byref(config_id)) or not config_id.value:
            if not fbconfig or gl.glXGetFBConfigAttrib(display, fbconfig, 0x8013, ctypes.byref(config_id)):
                raise RuntimeError("the application's GLX context's configuration could not be read")
        name = x11.XDisplayString(display)
        self.dpy = x11.XOpenDisplay(name)
        if not self.dpy:
            raise RuntimeError(f"could not open a second connection to the X display {name!r}")
        try:
            # every X request on this connection with its errors caught (Xlib's default handler would end
            # the application)
            with _x_errors_ignored(x11, self.dpy):
                config = None
                attribs = (ctypes.c_int * 3)(0x8013, config_id.value, 0)
                for screen in range(x11.XScreenCount(self.dpy)):       # the screen whose configs hold it
                    count = ctypes.c_int(0)
                    configs = gl.glXChooseFBConfig(self.dpy, screen, attribs, ctypes.byref(count))
                    if configs and count.value >= 1:
                        config = configs[0]
                        x11.XFree(ctypes.cast(configs, ptr))
                        break
                if config is None:
                    raise RuntimeError(f"the application's GLXFBConfig {config_id.value:#x} is not on the second "
                                       "connection")
                address = gl.glXGetProcAddressARB(b"glXCreateContextAttribsARB")
                if not address:
                    raise RuntimeError("GLX lacks glXCreateContextAttribsARB (GLX_ARB_create_context)")
                create = ctypes.CFUNCTYPE(ptr, ptr, ptr, ptr, i32, ctypes.POINTER(ctypes.c_int))(address)
                for major, minor in ((4, 6), (4, 5), (require // 100, require % 100 // 10)):
                    attrs = (ctypes.c_int * 7)(0x2091, major, 0x2092, minor, 0x9126, 1, 0)   # core profile
                    self.ctx = create(self.dpy, config, context, 1, attrs)
                    x11.XSync(self.dpy, 0)
                    if self.ctx:
                        break
            if not self.ctx:
                raise RuntimeError(f"could not make an OpenGL {require // 100}.{require % 100 // 10} core context that "
                                   "shares the application's (glXCreateContextAttribsARB)")
        except Exception:
            self.release()
            raise
        self._load = gl.glXGetProcAddressARB

    def load(self, name: str) -> int:
        return int(self._load(name.encode()) or 0)

    def __enter__(self) -> "GlxSharedContext":
        if not self.gl.glXMakeContextCurrent(self.dpy, 0, 0, self.ctx):
            raise RuntimeError("glXMakeContextCurrent failed for the engine's context (no drawable)")
        return self

    def __exit__(self, *args: Any) -> None:
        if self.dpy:
            self.gl.glXMakeContextCurrent(self.dpy, 0, 0, None)

    def release(self) -> None:
        if self.ctx:
            self.gl.glXMakeContextCurrent(self.dpy, 0, 0, None)
            self.gl.glXDestroyContext(self.dpy, self.ctx)
            self.ctx = None
        if self.dpy:
            self.x11.XCloseDisplay(self.dpy)
            self.dpy = None


_X_ERROR_HANDLER = ctypes.CFUNCTYPE(ctypes.c_int, ptr, ptr)


@contextlib.contextmanager
def _x_errors_ignored(x11: Any, display: int) -> Iterator[None]:
    """Xlib's default error handler ends the process; while the block runs, X errors on ``display``
    (the engine's own connection) are ignored and those on any other connection go to the handler
    that was installed (the application's, or Xlib's)."""
    x11.XSetErrorHandler.restype = ptr
    x11.XSetErrorHandler.argtypes = [ptr]
    x11.XSync.argtypes = [ptr, i32]
    previous: list[int | None] = [None]

    def handler(dpy: int, event: int) -> int:
        if dpy == display or not previous[0]:
            return 0
        return _X_ERROR_HANDLER(previous[0])(dpy, event)

    callback = _X_ERROR_HANDLER(handler)
    previous[0] = x11.XSetErrorHandler(ctypes.cast(callback, ptr))
    try:
        yield
    finally:
        x11.XSync(display, 0)
        x11.XSetErrorHandler(previous[0])


def glx_context(display: int, fbconfig: int, context: int, require: int = 430,
                cache: Path | None | bool = None) -> "moderngl.Context":
    """A :class:`GlxSharedContext` as a moderngl context with a :class:`CachingLoader`, current on
    the calling thread (leave with ``ctx.extra.__exit__()`` or ``ctx.__exit__()``)."""
    import moderngl  # on use: moderngl (optional: the realtime extra)

    inner = GlxSharedContext(display, fbconfig, context, require)
    try:
        inner.__enter__()
        loader = CachingLoader(inner, cache)
        ctx = moderngl.create_context(require=require, standalone=True, context=loader)
    except Exception:
        inner.release()
        raise
    ctx.extra = loader
    return ctx
