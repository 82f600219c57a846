"""The OpenXR API layer's engine: what ``layer/vrcorrect_layer.c`` (a thin C shim that embeds
Python) calls on the application's thread.

The shim intercepts the application's OpenXR calls; for OpenGL and Vulkan sessions it gives each
application swapchain a layer-owned output swapchain and, at ``xrEndFrame``, has :class:`Engine`
correct the application's last released image over the submitted ``imageRect`` into the output
image; the frame then goes down with the output swapchains in place of the application's.

Per frame the shim calls :meth:`Engine.begin_frame` (``False``: pass the frame through), then once
per view :meth:`Engine.correct` (OpenGL) or :meth:`Engine.correct_vulkan` and then
:meth:`Engine.finish` (Vulkan), and :meth:`Engine.end_frame`.  Every failure becomes a pass-through
(``False``) and one log line naming the reason (a reason is logged again only after a corrected
frame or a different reason); the engine never raises into the shim.

The correction is the project's :class:`~vrcorrect.runtime.corrector.Corrector`, one per view
(view 0 the left eye, view 1 the right, as in ``XR_VIEW_CONFIGURATION_TYPE_PRIMARY_STEREO``), built
from the user's prescription JSON and display profile.  Around it, two passes of
``shaders/layer_copy.glsl``:

* *decode*: the submitted rect, texel for texel, into a layer-owned staging texture: sRGB code
  values (RGBA8) for an 8-bit swapchain, which the Corrector decodes itself (for an sRGB swapchain
  exactly the application's codes; an 8-bit UNORM swapchain holds linear light, encoded here), or
  linear light clamped to [0, 1] (RGBA32F) for a 10-bit or half-float swapchain;
* *encode*: the Corrector's sRGB-encoded result into the output image's rect in the swapchain's own
  encoding: the code values as they are for an sRGB swapchain, linear light otherwise, with the
  application's alpha.  **Values outside [0, 1]** (a float swapchain holds linear light, which an
  engine rendering in HDR lets exceed 1): the correction works on the part in [0, 1], what the
  display shows up to its white; the rest of each value (``v - clamp(v, 0, 1)``) is carried through
  uncorrected and added back, so nothing the application rendered is lost or clipped.  The engine
  says so in the log the first time it corrects such a swapchain.

*OpenGL sessions*: the engine runs on the application's GL context (current at ``xrEndFrame``),
through a moderngl context attached to it; the application's textures are only sampled, through a
sampler object of the layer's (their parameters are never set); the shim saves and restores the GL
state around.  Formats: ``GL_RGBA16F``, ``GL_RGB10_A2``, ``GL_SRGB8_ALPHA8``, ``GL_RGBA8``.

*Vulkan sessions*: a Vulkan application has no GL context, so the engine makes its own (headless
EGL, Mesa's llvmpipe here) and makes it current only inside its calls.  The shim copies the submitted
rects on the application's queue into Vulkan images of its own whose memory the engine imports
(:meth:`Engine.import_images`, ``GL_EXT_memory_object_fd`` through ctypes: moderngl has no wrapper),
the engine corrects from there into a second shared image, and the shim copies that into the
output image.  32-bit formats are imported as ``GL_R32UI`` and (un)packed in the shader
(``R8G8B8A8``/``B8G8R8A8``, sRGB or not, ``A2B10G10R10``), the half-float one as ``GL_RGBA16F``.  A
Vulkan image's first row is its top row: the passes flip the rect into GL's orientation and back.

The eye models (:func:`~vrcorrect.runtime.eye_model.build_eye_model`: PSFs, kernels, filter design;
seconds of CPU) come from an :class:`~vrcorrect.runtime.eye_source.EyeSource`, the one the mirror,
the overlay and ``vrcorrect xr`` use, never from ``xrEndFrame``: the engine reads the prescription
(a small file) and asks for both eyes (:meth:`~vrcorrect.runtime.eye_source.EyeSource.design_all`);
the source's worker chooses the display and designs them while frames pass through (one log line,
"building the eye models ..."), and on the first frame after the design the two Correctors are made
on the application's thread from the models (GL resources only).  Hot reload is the source's too:
it watches the prescription file's stamp, the engine keeps correcting with the current Correctors
while the new models design, then installs them
(:meth:`~vrcorrect.runtime.corrector.Corrector.install`, GL work only); an invalid new file keeps
the last good prescription (one log line).  An invalid first prescription passes the frames
through with its reason until the file changes; a new configuration gets a new source.  Designs
run one at a time; of edits made meanwhile only the newest is designed.  (The shim releases the
GIL between its calls, so the worker runs.)

Configuration (:class:`LayerConfig`): ``$XDG_CONFIG_HOME/vrcorrect/layer.json`` (or the file named by
``VRCORRECT_LAYER_CONFIG``) with ``rx`` (prescription path), ``display`` (preset or profile path;
absent: the preset whose per-eye resolution equals the runtime's recommended view size, else
``quest2``), ``options`` (:class:`~vrcorrect.runtime.eye_model.CorrectorOptions` fields).
``VRCORRECT_RX`` overrides ``rx``.  Off switch: ``VRCORRECT_LAYER_OFF=1`` or the file
``layer.off`` beside the configuration (checked every quarter second: on and off live).
Log: ``VRCORRECT_LAYER_LOG``, else ``$XDG_STATE_HOME/vrcorrect/layer.log`` (``~/.local/state``).

Layer 5: numpy and moderngl, never torch, never :mod:`vrcorrect.apps`.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import math
import os
import queue
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator, Mapping

import numpy as np

from ...plumbing.errors import InputError, ValidationError
from ...plumbing.fileio import file_stamp
from ...specs.vocabulary import VIEW_ORDER, Backend
from ..gaze import gaze_deg_of
from ..gl import fullscreen_triangle, release
from ..shaders import compile_program

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

    from ...specs.display import DisplayProfile
    from ..corrector import Corrector
    from ..eye_source import EyeSource

__all__ = ["LAYER_NAME", "DISABLE_ENV", "OFF_ENV", "LayerConfig", "Engine", "SwapchainFormat", "GL_FORMATS",
           "VK_FORMATS", "config_path", "log_path", "off_file", "eye_of_view", "read_config"]

LAYER_NAME = "XR_APILAYER_VRCORRECT_correction"
DISABLE_ENV = "DISABLE_VRCORRECT_LAYER"      # the manifest's disable_environment: the loader skips the layer
OFF_ENV = "VRCORRECT_LAYER_OFF"              # the engine's live off switch (the layer stays loaded)
CONFIG_ENV = "VRCORRECT_LAYER_CONFIG"
RX_ENV = "VRCORRECT_RX"
LOG_ENV = "VRCORRECT_LAYER_LOG"
_GL_FRAMEBUFFER_SRGB = 0x8DB9
_GL_TEXTURE_2D = 0x0DE1
_GL_TEXTURE_BINDING_2D = 0x8069
_GL_R32UI = 0x8236
_GL_RGBA16F = 0x881A
_GL_HANDLE_TYPE_OPAQUE_FD_EXT = 0x9586
_CHECK_INTERVAL_S = 0.25
_REPORT_INTERVAL_S = 1.0
CAPTURE_WAIT_S = 2.0
"""How long a build waits for the application's next frame to prime its correction on (no frame: it
is handed over unprimed, warmed up only)."""
PRIME_MAX_FRAMES = 40
"""Frames a build corrects a captured view for at most before handing over (converged sooner)."""
PRIME_ENV = "VRCORRECT_LAYER_PRIME_S"
PRIME_BUDGET_S = 1.0
"""Seconds a build primes its correction for at most (all eyes together; ``VRCORRECT_LAYER_PRIME_S``
sets another, ``converge`` none).  On a GPU priming converges well inside it (a frame's iterations
take milliseconds); on a software renderer, where a frame of both eyes at 96x64 takes 0.1-0.2 s and
a still scene needs some 35 frames, the correction is handed over after the budget and goes on
converging on the application's frames, as it does after any cut, instead of keeping the
application uncorrected for seconds more."""
BUILD_NICE = 10
"""The build worker's CPU priority (Linux nice value, per thread): the application's threads come first.
Not the lowest: the worker holds Python's lock between its GL calls, and a worker the scheduler leaves
waiting while it holds it keeps the application's ``xrEndFrame`` waiting too (nice 19 on a busy machine
held passed-through frames up to 0.54 s on the lock; nice 10, 0.12 s)."""
CLOSE_WAIT_S = 30.0
"""How long the instance's end waits for an eye-model build still running (:meth:`Engine.close`)."""
_QUERY_MAX_MS = 0xFFFFFFFF / 1e6
_NEVER = object()
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


def _config_home(env: Mapping[str, str]) -> Path:
    base = env.get("XDG_CONFIG_HOME") or str(Path(env.get("HOME") or Path.home()) / ".config")
    return Path(base)


def config_path(env: Mapping[str, str] | None = None) -> Path:
    """The layer configuration file (``VRCORRECT_LAYER_CONFIG`` or ``$XDG_CONFIG_HOME/vrcorrect/layer.json``)."""
    env = os.environ if env is None else env
    named = env.get(CONFIG_ENV)
    return Path(named) if named else _config_home(env) / "vrcorrect" / "layer.json"


def off_file(env: Mapping[str, str] | None = None) -> Path:
    """The off switch file: while it exists the layer passes every frame through."""
    return config_path(env).with_name("layer.off")


def log_path(env: Mapping[str, str] | None = None) -> Path:
    """Where the layer (C shim and engine) appends its log lines."""
    env = os.environ if env is None else env
    if env.get(LOG_ENV):
        return Path(env[LOG_ENV])
    state = env.get("XDG_STATE_HOME") or str(Path(env.get("HOME") or Path.home()) / ".local" / "state")
    return Path(state) / "vrcorrect" / "layer.log"


def prime_budget(env: Mapping[str, str] | None = None) -> float:
    """The priming budget in seconds (:data:`PRIME_BUDGET_S`; ``VRCORRECT_LAYER_PRIME_S``: seconds,
    or ``converge`` for no budget but :data:`PRIME_MAX_FRAMES`).

    Raises
    ------
    ValidationError
        The variable is neither a number of seconds from 0 to 60 nor ``converge``.
    """
    env = os.environ if env is None else env
    text = env.get(PRIME_ENV, "").strip()
    if not text:
        return PRIME_BUDGET_S
    if text == "converge":
        return math.inf
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0.0 <= value <= 60.0:
        raise ValidationError(PRIME_ENV, text, "seconds from 0 to 60, or 'converge'")
    return value


def eye_of_view(view: int) -> str:
    """``"left"`` for view 0, ``"right"`` for view 1 (``PRIMARY_STEREO``,
    :data:`~vrcorrect.specs.vocabulary.VIEW_ORDER`); other views are refused."""
    if view in (0, 1):
        return VIEW_ORDER[int(view)]
    raise ValidationError("view", view, "0 (left eye) or 1 (right eye): stereo projection views only")


@dataclass(frozen=True)
class LayerConfig:
    """What the layer corrects with: read from the configuration file and the environment."""

    rx: Path | None = None
    display: str | None = None
    options: Mapping[str, Any] = field(default_factory=dict)
    source: Path | None = None              # the configuration file it came from (None: none found)


def read_config(env: Mapping[str, str] | None = None) -> LayerConfig:
    """The configuration (file, then ``VRCORRECT_RX``).  A missing file is an empty configuration.

    Raises
    ------
    InputError
        The file exists but cannot be read or is not a JSON object.
    ValidationError
        A field of the wrong type.
    """
    env = os.environ if env is None else env
    path = config_path(env)
    doc: dict[str, Any] = {}
    source = None
    if path.exists():
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(f"{path}: cannot read the layer configuration: {exc}") from None
        if not isinstance(doc, dict):
            raise InputError(f"{path}: the layer configuration must be a JSON object")
        source = path
    rx = doc.get("rx")
    if rx is not None and not isinstance(rx, str):
        raise ValidationError("rx", rx, "a prescription JSON path", source=str(path))
    display = doc.get("display")
    if display is not None and not isinstance(display, str):
        raise ValidationError("display", display, "a display preset name or profile path", source=str(path))
    options = doc.get("options", {})
    if not isinstance(options, dict):
        raise ValidationError("options", options, "an object of corrector options", source=str(path))
    if env.get(RX_ENV):
        rx = env[RX_ENV]
    rx_path = None
    if rx:
        rx_path = Path(rx).expanduser()
        if not rx_path.is_absolute() and source is not None:
            rx_path = source.parent / rx_path
    return LayerConfig(rx=rx_path, display=display, options=dict(options), source=source)


class _Log:
    """One line per event, to the log file and stderr; pass-through reasons only when they change."""

    def __init__(self, path: Path):
        self.path = path
        self.last_reason: str | None = None

    def line(self, text: str) -> None:
        stamp = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with open(self.path, "a", encoding="utf-8") as f:
                f.write(f"{stamp} {text}\n")
        except OSError:
            pass
        try:
            sys.stderr.write(f"vrcorrect layer: {text}\n")
        except Exception:  # noqa: BLE001  (a closed stderr must not break the frame)
            pass

    def reason(self, text: str) -> None:
        if text != self.last_reason:
            self.last_reason = text
            self.line(f"pass-through: {text}")

    def corrected(self) -> None:
        self.last_reason = None


def _off(env: Mapping[str, str]) -> str | None:
    value = env.get(OFF_ENV, "").strip().lower()
    if value and value not in ("0", "false", "no", "off"):
        return f"switched off ({OFF_ENV}={env[OFF_ENV]})"
    switch = off_file(env)
    if switch.exists():
        return f"switched off (the file {switch} exists)"
    return None


def choose_display(name: str | None, view_size: tuple[int, int]) -> tuple[DisplayProfile, str]:
    """The display profile and why it was chosen: the user's, else the preset whose per-eye
    resolution equals the runtime's recommended view size, else ``quest2``."""
    from ...specs.display import get_display, preset_names

    if name:
        return get_display(name), "configured"
    for key in preset_names():
        try:
            profile = get_display(key)
        except Exception:  # noqa: BLE001
            continue
        if profile.kind == "headset" and profile.resolution_px == tuple(view_size):
            return profile, f"matches the runtime's view size {view_size[0]}x{view_size[1]}"
    return get_display("quest2"), (f"no preset has the runtime's view size {view_size[0]}x{view_size[1]}; "
                                   "set display in the layer configuration")


class _MemoryObjects:
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


class _Semaphores:
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
class _ChainMemory:
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


class _Pipeline:
    """Everything the engine corrects with, in a GL context of its own: the two Correctors, the passes
    of ``shaders/layer_copy.glsl``, the staging textures, and what it made of the application's
    images (OpenGL: wrappers of its textures; Vulkan: the imported shared images).  Built and warmed
    up on the build worker (:class:`_Builder`: every program compiled and run once for each
    :data:`Target`, then each Corrector reset, so that its first frame is a cold start as a fresh
    Corrector's is), then used on the application's thread only."""

    def __init__(self, ctx: "moderngl.Context", api: str, correctors: "dict[str, Corrector]",
                 display: "DisplayProfile", rx: Path):
        import moderngl

        self.ctx, self.api, self.correctors, self.display, self.rx = ctx, api, correctors, display, rx
        self.targets: set[Target] = set()
        self.steps: dict[str, float] = {}                 # seconds of each step of its build
        self.primed_frames: dict[str, int] = {}           # frames each eye was primed for
        self.prime_converged: dict[str, bool] = {}        # whether its priming converged
        self.formats = GL_FORMATS if api == "OpenGL" else VK_FORMATS
        self._external: dict[tuple[int, int, int], moderngl.Texture] = {}    # the application's textures (OpenGL)
        self._staging: dict[tuple[int, int, str], moderngl.Texture] = {}
        self._framebuffers: dict[int, moderngl.Framebuffer] = {}             # by the texture's GL name
        self._programs: dict[tuple[str, bool], tuple[moderngl.Program, moderngl.VertexArray]] = {}
        self._sampler = ctx.sampler(filter=(moderngl.NEAREST, moderngl.NEAREST), repeat_x=False, repeat_y=False)
        self._memory: _MemoryObjects | None = None
        self.chains: dict[int, _SharedChain] = {}
        self.semaphores: _Semaphores | None = None       # Vulkan: external semaphores, where GL has them
        self.sync = ""                                    # Vulkan: how it is ordered with the copies (for the log)
        self._queries: dict[str, list[moderngl.Query]] = {}
        self._query_used: dict[str, list[bool]] = {}

    @property
    def loader(self) -> Any:
        """The context's :class:`~vrcorrect.runtime.glcache.CachingLoader`."""
        return self.ctx.extra

    # ------------------------------------------------------------ the build worker's part

    def warm_up(self, targets: set[Target], stopped: Any = lambda: False) -> None:
        """Run every pass once for each target, on private textures of the target's format and size:
        a cold frame, then a warm one on other content (the early stop's comparison and plan); then
        each Corrector starts cold again.  ``stopped()`` True ends it early."""
        rng = np.random.default_rng(46)
        for code, width, height in sorted(targets - self.targets):
            if stopped():
                return
            fmt = self.formats[code]
            src, dst = (self._private_texture(code, fmt, width, height) for _ in range(2))
            try:
                for eye in self.correctors:
                    for _ in range(2):
                        src.write(self._content(rng, src))
                        self.correct_rect(eye, fmt, src, dst, (0, 0, width, height), flip=self.api == "Vulkan")
                    self.correctors[eye].reset()
            finally:
                for texture in (src, dst):
                    release(self._framebuffers.pop(texture.glo, None))
                    texture.release()
            self.targets.add((code, width, height))
        self.ctx.finish()

    def copy_views(self, views: list[dict[str, Any]], chains: Mapping[int, _ChainMemory]) -> list[dict[str, Any]]:
        """The captured views' rects copied into textures of this context (OpenGL: from the
        application's texture once its fence has passed; Vulkan: from the shared ``input`` image,
        imported here), one per eye: what :meth:`prime` corrects."""
        copy = ctypes.CFUNCTYPE(None, *([ctypes.c_uint, ctypes.c_uint] + [ctypes.c_int] * 4) * 2,
                                ctypes.c_int, ctypes.c_int, ctypes.c_int)(self.loader._address("glCopyImageSubData"))
        out = []
        seen = set()
        for view in views:
            if view["eye"] in seen or view["eye"] not in self.correctors:
                continue
            seen.add(view["eye"])
            x, y, width, height = view["rect"]
            fmt = self.formats[view["code"]]
            if self.api == "OpenGL":
                _wait_sync(self.loader, view["fence"])
                source = int(view["texture"])
            else:
                memory = chains.get(view["chain"])
                try:
                    if memory is not None and view["chain"] not in self.chains:
                        self.import_chain(view["chain"], memory)
                except OSError:                  # the swapchain went away meanwhile: this view is not primed
                    memory = None
                if memory is None or view["chain"] not in self.chains:
                    continue
                source = self.chains[view["chain"]].input.glo
            texture = self._private_texture(view["code"], fmt, width, height)
            copy(source, _GL_TEXTURE_2D, 0, x, y, 0, texture.glo, _GL_TEXTURE_2D, 0, 0, 0, 0, width, height, 1)
            out.append({"eye": view["eye"], "code": view["code"], "format": fmt, "texture": texture,
                        "rect": (0, 0, width, height)})
        error = self.ctx.error
        if error != "GL_NO_ERROR":
            for c in out:
                c["texture"].release()
            raise RuntimeError(f"a GL error ({error}) copying the captured views")
        return out

    def prime(self, copies: list[dict[str, Any]], stopped: Any = lambda: False,
              budget_s: float = PRIME_BUDGET_S) -> None:
        """Correct each eye's captured view as frames would, from a cold start until the early stop
        would skip the next frame of the same content (the last two frames' objectives agree to its
        tolerance), so that the application's first corrected frames are already converged, or until
        the eye's share of ``budget_s`` is spent (then the application's frames go on from there);
        the Correctors keep that state (a fresh Corrector given the same number of frames reaches the
        same one).  :attr:`primed_frames` counts each eye's frames, :attr:`prime_converged` says
        whether they converged."""
        from ..strategies.admm import EARLY_STOP_TOLERANCE

        share = budget_s / max(len(copies), 1)
        for c in copies:
            x, y, width, height = c["rect"]
            scratch = self._private_texture(c["code"], c["format"], width, height)
            deadline = time.perf_counter() + share
            self.prime_converged[c["eye"]] = False
            try:
                corrector = self.correctors[c["eye"]]
                previous = None
                for n in range(PRIME_MAX_FRAMES):
                    if stopped():
                        return
                    if n > 0 and time.perf_counter() >= deadline:
                        break
                    self.primed_frames[c["eye"]] = n + 1
                    self.correct_rect(c["eye"], c["format"], c["texture"], scratch, c["rect"],
                                      flip=self.api == "Vulkan")
                    fraction = corrector.last_objective_fraction((width, height))
                    if fraction is None:                       # no guard: nothing to converge on
                        self.prime_converged[c["eye"]] = True
                        break
                    if previous is not None and abs(fraction - previous) <= EARLY_STOP_TOLERANCE * max(previous, 1e-30):
                        self.prime_converged[c["eye"]] = True
                        break
                    previous = fraction
                self.targets.add((c["code"], width, height))
            finally:
                for texture in (c["texture"], scratch):
                    release(self._framebuffers.pop(texture.glo, None))
                    texture.release()
        self.ctx.finish()

    def _private_texture(self, code: int, fmt: SwapchainFormat, width: int, height: int) -> "moderngl.Texture":
        """A texture of the engine's own as the application's images are stored (OpenGL: the swapchain's
        internal format; Vulkan: the shared images' R32UI or RGBA16F)."""
        if self.api == "Vulkan":
            return (self.ctx.texture((width, height), 1, dtype="u4") if fmt.packing is not None
                    else self.ctx.texture((width, height), 4, dtype="f2"))
        return self.ctx.texture((width, height), 4, dtype="f2" if fmt.encoding == "float" else "f1",
                                internal_format=code)

    @staticmethod
    def _content(rng: np.random.Generator, texture: "moderngl.Texture") -> bytes:
        w, h = texture.size
        if texture.dtype == "f2":
            return rng.random((h, w, 4)).astype(np.float16).tobytes()
        if texture.dtype == "u4":
            return rng.integers(0, 2 ** 32, (h, w), dtype=np.uint32).tobytes()
        return rng.integers(0, 256, (h, w, 4), dtype=np.uint8).tobytes()

    # ------------------------------------------------------------ frames (the application's thread)

    def correct_rect(self, eye: str, fmt: SwapchainFormat, src: "moderngl.Texture", dst: "moderngl.Texture",
                     rect: tuple[int, int, int, int], flip: bool, query: "moderngl.Query | None" = None) -> float:
        """Decode the rect of ``src`` into staging, correct it for ``eye``, encode the result into the
        rect of ``dst`` (module docstring); returns the CPU ms of the correction."""
        x, y, width, height = rect
        packed = fmt.packing is not None
        common = {"u_packing": _PACKINGS.get(fmt.packing or "", 0), "u_encoding": _ENCODINGS[fmt.encoding],
                  "u_offset": (x, y), "u_height": height, "u_flip": flip}
        staging = self._stage_texture(width, height, "f1" if fmt.stage_codes else "f4")
        result = self._stage_texture(width, height, "result")
        self._draw("DECODE", packed, {**common, "u_source": 0, "u_stage_codes": fmt.stage_codes}, [src], staging,
                   (0, 0, width, height))
        t0 = time.perf_counter()
        with query if query is not None else contextlib.nullcontext():
            self.correctors[eye].apply(staging, self._framebuffer(result))
        self._draw("ENCODE", packed, {**common, "u_source": 0, "u_result": 1, "u_carry": fmt.encoding == "float"},
                   [src, result], dst, rect)
        error = self.ctx.error
        if error != "GL_NO_ERROR":
            raise RuntimeError(f"a GL error ({error}) during the correction")
        return 1e3 * (time.perf_counter() - t0)

    def application_texture(self, name: int, width: int, height: int, fmt: SwapchainFormat) -> "moderngl.Texture":
        """OpenGL: an application's texture (a swapchain image: shared with this context) as this
        context's moderngl texture (a wrapper: nothing is made or deleted)."""
        key = (int(name), width, height)
        tex = self._external.get(key)
        if tex is None:
            tex = self.ctx.external_texture(int(name), (width, height), 4, 0, "f2" if fmt.encoding == "float" else "f1")
            self._external[key] = tex
        return tex

    def forget_textures(self, names: list[int]) -> None:
        """OpenGL: a swapchain goes away: the wrappers and framebuffers made for its textures."""
        for name in names:
            for key in [k for k in self._external if k[0] == name]:
                del self._external[key]
            release(self._framebuffers.pop(name, None))

    def import_chain(self, chain: int, memory: _ChainMemory) -> None:
        """Vulkan: import duplicates of a swapchain's shared images into this context."""
        if self._memory is None:
            self._memory = _MemoryObjects(self.ctx)
        packed = memory.format.packing is not None
        internal, components, dtype = (_GL_R32UI, 1, "u4") if packed else (_GL_RGBA16F, 4, "f2")
        names: list[tuple[int, int]] = []
        textures = []
        try:
            for fd, size in zip(memory.fds, memory.sizes):
                names.append(self._memory.texture(os.dup(fd), size, memory.width, memory.height, internal))
                textures.append(self.ctx.external_texture(names[-1][0], (memory.width, memory.height), components, 0,
                                                          dtype))
        except Exception:
            for texture, memory_object in names:
                self._memory.free(texture, memory_object)
            raise
        self.release_chain(chain)
        self.chains[chain] = _SharedChain(memory.format, textures[0], textures[1], tuple(names))

    def release_chain(self, chain: int) -> None:
        shared = self.chains.pop(chain, None)
        if shared is None:
            return
        for texture in (shared.input, shared.result):
            release(self._framebuffers.pop(texture.glo, None))
            texture.release()                         # an external texture: moderngl forgets it, deletes nothing
        if self._memory is not None:
            for texture_name, memory_object in shared.names:
                self._memory.free(texture_name, memory_object)

    def query(self, eye: str, frame: int) -> tuple["moderngl.Query", float | None | bool]:
        """This frame's timer query for ``eye``, and the slot's previous result (two frames ago) in ms:
        ``None`` when it saturated (a 32-bit nanosecond count ends at 4.29 s), ``False`` when unused."""
        ring = self._queries.get(eye)
        if ring is None:
            ring = self._queries[eye] = [self.ctx.query(time=True), self.ctx.query(time=True)]
            self._query_used[eye] = [False, False]
        slot = frame % 2
        previous: float | None | bool = False
        if self._query_used[eye][slot]:
            ns = ring[slot].elapsed
            previous = None if ns >= 0xFFFFFFFF else ns / 1e6
        self._query_used[eye][slot] = True
        return ring[slot], previous

    # ------------------------------------------------------------ GL objects

    def _program(self, stage: str, packed: bool) -> tuple["moderngl.Program", "moderngl.VertexArray"]:
        key = (stage, packed)
        if key not in self._programs:
            defines: dict[str, None] = {stage: None}
            if packed:
                defines["PACKED"] = None
            program = compile_program(self.ctx, "layer_copy.glsl", defines=defines)
            self._programs[key] = (program, fullscreen_triangle(self.ctx, program))
        return self._programs[key]

    def _draw(self, stage: str, packed: bool, uniforms: Mapping[str, Any], textures: list["moderngl.Texture"],
              target: "moderngl.Texture", viewport: tuple[int, int, int, int]) -> None:
        """One pass of ``layer_copy.glsl`` into ``target`` over ``viewport``, ``textures`` on units 0, 1, ...
        read through the layer's nearest-texel sampler (a texture's own parameters are never set: it
        may be the application's), which is unbound again after the pass (the Corrector's passes
        sample with their textures' own parameters)."""
        ctx = self.ctx
        ctx.disable_direct(_GL_FRAMEBUFFER_SRGB)
        program, vao = self._program(stage, packed)
        _set_uniforms(program, uniforms)
        for unit, texture in enumerate(textures):
            texture.use(unit)
            self._sampler.use(unit)
        fb = self._framebuffer(target)
        fb.use()
        ctx.viewport = viewport
        vao.render(mode=ctx.TRIANGLES, vertices=3)
        for unit in range(len(textures)):
            self._sampler.clear(unit)

    def _stage_texture(self, width: int, height: int, kind: str) -> "moderngl.Texture":
        """The layer's own textures: ``"f1"``/``"f4"`` staging (the Corrector's input), ``"result"``
        (RGBA8: the Corrector's sRGB-encoded output)."""
        key = (width, height, kind)
        tex = self._staging.get(key)
        if tex is None:
            tex = self.ctx.texture((width, height), 4, dtype="f1" if kind == "result" else kind)
            self._staging[key] = tex
        return tex

    def _framebuffer(self, texture: "moderngl.Texture") -> "moderngl.Framebuffer":
        fb = self._framebuffers.get(texture.glo)
        if fb is None:
            fb = self.ctx.framebuffer(color_attachments=[texture])
            self._framebuffers[texture.glo] = fb
        return fb

    def release(self) -> None:
        """Release every GL object and the context itself (the context must be current on the calling
        thread; it is not current anywhere afterwards)."""
        try:
            for chain in list(self.chains):
                self.release_chain(chain)
            if self.semaphores is not None:
                self.semaphores.release()
                self.semaphores = None
            for c in self.correctors.values():
                c.release()
            release(*self._framebuffers.values())       # never the application's textures themselves
            release(*self._staging.values(), *(o for pair in self._programs.values() for o in reversed(pair)),
                    self._sampler)                       # (moderngl's queries go with the context)
        finally:
            self.correctors = {}
            self._framebuffers.clear()
            self._staging.clear()
            self._external.clear()
            self._programs.clear()
            self._queries.clear()
            try:
                self.ctx.release()                       # the engine's own context (its loader destroys it)
            except Exception:  # noqa: BLE001
                pass


class _AppGlx:
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


class _CaptureRequest:
    """The builder's request for a frame's content to prepare its pipeline on (priming, off the
    application's thread): the application's thread adds each view of the next frame it sees
    (OpenGL: the application's texture, with a fence after its rendering; Vulkan: the shared
    ``input`` image the shim copied the rect into) and sets :attr:`ready` at the frame's end."""

    def __init__(self) -> None:
        self.views: list[dict[str, Any]] = []
        self.ready = threading.Event()


class _Builder:
    """The engine's build worker (one per configuration): it takes the eye models (from the cache, or
    from the eye source's worker, which designs them) and makes from them, off the application's
    thread, a :class:`_Pipeline` on a GL context of its own (compiled, from the program cache where
    it can, and warmed up for the swapchains the application made); the application's thread takes
    it from :attr:`events` when it is ready.  It does the same for a prescription edit (the eye
    source's reload: the current pipeline corrects meanwhile) and for a view size or format the
    current pipeline was not prepared for.  Events: ``("log", text)``, ``("failed", stamp, text)``
    (the first models or pipeline could not be made), ``("pipeline", pipeline, what)``."""

    def __init__(self, engine: "Engine", config: LayerConfig, stamp: Any):
        self.engine, self.config, self.stamp = engine, config, stamp
        self.source: EyeSource | None = None
        self.display_holder: dict[str, Any] = {}
        self.events: queue.Queue[tuple[Any, ...]] = queue.Queue()
        self._wake = threading.Event()
        self._stopped = False
        self._rebuild = False
        self.thread = threading.Thread(target=self._run, name="vrcorrect-layer-build", daemon=True)
        self.thread.start()

    def request_rebuild(self) -> None:
        self._rebuild = True
        self._wake.set()

    def stop(self) -> None:
        """Stop after the step running (a pipeline it builds is released, not handed over; its eye
        source is let go)."""
        self._stopped = True
        self._wake.set()

    def join(self, timeout: float) -> bool:
        """Wait at most ``timeout`` s for the thread and its eye source's worker to end."""
        deadline = time.monotonic() + timeout
        self.thread.join(timeout)
        source = self.source
        return not self.thread.is_alive() and (source is None or source.join(max(0.0, deadline - time.monotonic())))

    def _post(self, *event: Any) -> None:
        self.events.put(event)

    def _run(self) -> None:
        try:
            # below the application's threads for the CPU (a Linux thread's own nice value; the eye
            # source's worker and GL's threads made from here inherit it)
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), BUILD_NICE)
        except (AttributeError, OSError):
            pass
        try:
            if self._open():
                self._loop()
        except Exception as exc:  # noqa: BLE001  (every failure is a pass-through with its reason)
            stamp = self.source.snapshot.stamp if self.source is not None else self.stamp
            self._post("failed", stamp, f"the layer's build worker failed: {_one_line(exc)}")
        finally:
            if self._stopped and self.source is not None:
                self.source.close(wait=False)

    def _open(self) -> bool:
        """The eye source (the prescription read, the options checked, with the options a
        :class:`~vrcorrect.runtime.corrector.Corrector` makes of the same configuration: the
        correction is the one it would design itself)."""
        from ..eye_model import CorrectorOptions
        from ..eye_source import EyeSource

        config, holder = self.config, self.display_holder
        try:
            options = dict(config.options)
            backend = options.pop("backend", Backend.GLSL)  # Corrector(backend=...) then CorrectorOptions(backend=...)

            def display() -> DisplayProfile:            # on a worker: loading a profile takes seconds
                if "display" in holder:                 # from the cache
                    return holder["display"]
                profile, reason = choose_display(config.display, self.engine.view_size)
                holder["why"] = reason
                return profile

            self.source = EyeSource(config.rx, display, CorrectorOptions(backend=backend, **options))
        except Exception as exc:  # noqa: BLE001
            self._post("failed", self.stamp, _one_line(exc))
            return False
        if not self._stopped:
            self.engine._source = self.source
        return not self._stopped

    def _loop(self) -> None:
        from .. import eye_cache

        source, config = self.source, self.config
        assert source is not None
        t0 = time.perf_counter()
        eyes = {eye: source.eye_rx(eye) for eye in source.eyes}
        cache_key = eye_cache.key(eyes, config.display, self.engine.view_size, source.options)
        cached = eye_cache.load(cache_key, self.engine.env)
        models: dict[str, tuple[Any, Any]] | None = None
        design_s = 0.0
        if cached is not None:
            self.display_holder["display"], self.display_holder["why"] = cached["display"], cached["why"]
            models = {eye: (cached["models"][eye], source.prescription) for eye in source.eyes}
            self._post("log", f"the eye models for {config.rx} came from the cache ({eye_cache.cache_dir(self.engine.env)})")
        else:
            source.design_all()
        built: _Pipeline | None = None                    # the last pipeline handed over (its Correctors' check)
        pending = models is not None                      # models not yet built into a pipeline
        first = True
        while not self._stopped:
            seen = source.reloads_started
            updates, messages = source.poll()
            if source.reloads_started != seen:
                self._post("log", f"building the eye models for {config.rx} (changed; correcting with the current ones "
                                  "meanwhile) ...")
            if models is None:
                start = [u for u in updates if u.reason == "start"]
                if not start:
                    if messages:                              # the worker's first word: its start was refused
                        self._post("failed", source.snapshot.stamp, _one_line_text(messages[0]))
                        return
                else:
                    models = {u.eye: (u.model, u.prescription) for u in start}
                    design_s = max(u.seconds for u in start)
                    pending = True
                    eye_cache.store(cache_key, source.display, self.display_holder.get("why", ""),
                                    {eye: m for eye, (m, _) in models.items()}, self.engine.env)
            reloads = {u.eye: u for u in updates if u.reason == "reload"}
            if reloads and models is not None:
                models.update({eye: (u.model, u.prescription) for eye, u in reloads.items()})
                pending = True
                eyes = {eye: source.eye_rx(eye) for eye in source.eyes}
                eye_cache.store(eye_cache.key(eyes, config.display, self.engine.view_size, source.options),
                                source.display, self.display_holder.get("why", ""),
                                {eye: m for eye, (m, _) in models.items()}, self.engine.env)
            if models is not None:
                for message in messages:
                    self._post("log", _one_line_text(message))
            targets = self.engine.targets()
            if models is not None and (pending or self._rebuild) and targets:
                self._rebuild = False
                what = "start" if first else ("reload" if reloads or pending else "targets")
                try:
                    pipeline, seconds = self._build(models, targets)
                except Exception as exc:  # noqa: BLE001
                    if first:
                        self._post("failed", source.snapshot.stamp, _one_line(exc))
                        return
                    self._post("log", f"{config.rx}: not rebuilt, keeping the current correction: {_one_line(exc)}")
                    pending = False
                    continue
                if pipeline is None:                          # stopped meanwhile
                    return
                info = {"what": what, "seconds": time.perf_counter() - t0, "gl_seconds": seconds,
                        "design_seconds": design_s, "cached_models": cached is not None and first,
                        "why": self.display_holder.get("why", ""), "stats": pipeline.loader.stats}
                if first:
                    source.check = pipeline.correctors[source.eyes[0]].check_eye   # later designs refused alike
                built, first, pending = pipeline, False, False
                self._post("pipeline", pipeline, info)
                t0 = time.perf_counter()
                continue
            self._wake.wait(0.25 if not pending else 0.05)
            self._wake.clear()
        del built

    def _build(self, models: dict[str, tuple[Any, Any]], targets: set[Target]) -> tuple["_Pipeline | None", float]:
        """A pipeline for ``models`` warmed up for ``targets``, on a new context current on this thread
        only while it is built; ``None`` when the builder was stopped meanwhile."""
        from ..corrector import Corrector
        from ..glcache import egl_context, glx_context

        t0 = time.perf_counter()
        engine = self.engine
        request = _CaptureRequest()
        engine.capture = request                     # the next frame's views, taken while this builds
        if engine.api == "OpenGL":
            if engine.glx_binding is None:
                raise RuntimeError("the OpenGL session's GLX binding is unknown")
            ctx = glx_context(*engine.glx_binding, require=430, cache=engine.program_cache)
        else:
            ctx = egl_context(430, cache=engine.program_cache)
        pipeline = None
        handed = False
        try:
            if ctx.version_code < 430:
                raise ValidationError("OpenGL version", ctx.version_code, "4.3 or newer (compute shaders)")
            if engine.api == "Vulkan":
                _MemoryObjects(ctx)                              # refuses a GL without GL_EXT_memory_object_fd now
            assert self.source is not None
            display = self.source.display
            correctors: dict[str, Corrector] = {}
            try:
                for eye, (model, prescription) in models.items():
                    if self._stopped:
                        break
                    correctors[eye] = Corrector(ctx, prescription, display, eye, eye_model=model,
                                                **dict(self.config.options))
            except Exception:
                for c in correctors.values():
                    c.release()
                raise
            pipeline = _Pipeline(ctx, engine.api, correctors, display, self.config.rx)
            if engine.api == "Vulkan":
                pipeline.sync = engine.attach_semaphores(pipeline)
            steps = pipeline.steps
            steps["correctors"] = time.perf_counter() - t0
            copies = []
            if not self._stopped and request.ready.wait(CAPTURE_WAIT_S):
                copies = pipeline.copy_views(request.views, engine.chain_memory())
            steps["capture"] = time.perf_counter() - t0 - sum(steps.values())
            primed = {(c["code"], c["rect"][2], c["rect"][3]) for c in copies}
            if not self._stopped:
                pipeline.warm_up(targets - primed, stopped=lambda: self._stopped)
            steps["warm-up"] = time.perf_counter() - t0 - sum(steps.values())
            if not self._stopped and copies:
                try:
                    budget = prime_budget(engine.env)
                except ValidationError as exc:
                    budget = PRIME_BUDGET_S
                    self._post("log", f"{exc}; priming for {PRIME_BUDGET_S:g} s")
                pipeline.prime(copies, stopped=lambda: self._stopped, budget_s=budget)
            steps["priming"] = time.perf_counter() - t0 - sum(steps.values())
            if self._stopped:
                return None, 0.0
            handed = True
            return pipeline, time.perf_counter() - t0
        finally:
            if engine.capture is request:
                engine.capture = None
            if handed:
                ctx.extra.__exit__(None, None, None)       # current nowhere until the application's thread takes it
            elif pipeline is not None:
                pipeline.release()                         # released on this thread, where it is current
            else:
                ctx.release()


class Engine:
    """The layer's correction engine (module docstring).  ``view_width``/``view_height``: the
    runtime's recommended view size (0 when unknown); ``api``: the session's graphics API
    (``"OpenGL"``: contexts that share the application's; ``"Vulkan"``: headless contexts of the
    engine's own)."""

    def __init__(self, view_width: int = 0, view_height: int = 0, api: str = "OpenGL",
                 env: Mapping[str, str] | None = None):
        self.env = os.environ if env is None else env
        self.log = _Log(log_path(self.env))
        self.view_size = (int(view_width), int(view_height))
        self.api = api
        self.pipeline: _Pipeline | None = None
        self.glx_binding: tuple[int, int, int] | None = None   # OpenGL: the application's Display*, FBConfig, context
        self.program_cache: Path | None | bool = None            # the program cache's folder (None: the default)
        self.display: DisplayProfile | None = None
        self.rx_path: Path | None = None
        self._rx_failed_stamp: Any = _NEVER          # the stamp of the prescription file that failed to build
        self._build_error: str | None = None
        self._source: EyeSource | None = None        # watches the prescription, designs the eye models
        self._builder: _Builder | None = None        # builds the pipelines off the application's thread
        self._let_go: list[Any] = []                 # sources and builders let go without waiting; joined by close()
        self._last_check = -1.0
        self._off_reason: str | None = None
        self._config: LayerConfig | None = None
        self._config_error: str | None = None
        self._app_glx: _AppGlx | None = None
        self._targets: dict[Any, set[Target]] = {}  # per swapchain (and the rects seen): what a pipeline prepares
        self._targets_lock = threading.Lock()
        self._asked: set[Target] = set()             # targets a rebuild was asked for
        self._chains: dict[int, _ChainMemory] = {}
        self.capture: _CaptureRequest | None = None  # set by the builder: the next frame's views, please
        self._semaphore_fds: tuple[int, int] | None = None   # Vulkan: the shim's external semaphores (ours to close)
        self._semaphore_note = "the Vulkan session's semaphores were not offered"
        self._waited_ready = False                   # Vulkan, with semaphores: GL waited for this frame's copy in
        self._sync_logged: str | None = None
        self._announced: set[str] = set()
        self._cpu_ms: dict[str, list[float]] = {}
        self._gpu_ms: dict[str, list[float | None]] = {}
        self._sync_ms: list[tuple[float, float, float]] = []
        self._frame_ms: list[float] = []
        self._last_report = time.monotonic()
        self._gaze_uv: dict[str, tuple[float, float]] = {}   # the eye tracker's gaze this frame, per eye
        self._gaze_said: str | None = None
        self.frames = 0
        self.log.line(f"loaded ({api} session, runtime view size {view_width}x{view_height}, "
                      f"Python {sys.version.split()[0]}, vrcorrect from {Path(__file__).resolve().parents[2]})")

    # ------------------------------------------------------------ what the shim tells

    def attach_glx(self, display: int, fbconfig: int, context: int) -> bool:
        """OpenGL: the session's GLX binding (``Display*``, ``GLXFBConfig``, ``GLXContext``), with which
        the engine's contexts share the application's textures."""
        self.glx_binding = (int(display), int(fbconfig), int(context))
        return True

    def add_swapchain(self, chain: int, code: int, width: int, height: int) -> bool:
        """OpenGL: a swapchain the layer corrects (its format and size): the pipelines are prepared for it."""
        if code not in GL_FORMATS:
            self.log.reason(f"swapchain format {hex(code)} is not one the engine knows")
            return False
        self._add_targets(("chain", chain), self._chain_targets(code, width, height))
        return True

    def _chain_targets(self, code: int, width: int, height: int) -> set[Target]:
        """A swapchain's likely rects: the whole image, and the runtime's view size where it fits."""
        out = {(int(code), int(width), int(height))}
        vw, vh = self.view_size
        if 0 < vw <= width and 0 < vh <= height:
            out.add((int(code), vw, vh))
        return out

    def _add_targets(self, owner: Any, targets: set[Target]) -> None:
        with self._targets_lock:
            self._targets.setdefault(owner, set()).update(targets)

    def targets(self) -> set[Target]:
        """Everything a pipeline should be prepared for (any thread)."""
        with self._targets_lock:
            return set().union(*self._targets.values()) if self._targets else set()

    def _covered(self, target: Target) -> bool:
        """Whether the pipeline was prepared for ``target``; if not, ask the builder for one that is
        (frames pass through meanwhile, with one log line)."""
        p = self.pipeline
        if p is not None and target in p.targets:
            return True
        self._add_targets("rects", {target})
        if target not in self._asked and self._builder is not None:
            self._asked.add(target)
            self._builder.request_rebuild()
        fmt = (GL_FORMATS if self.api == "OpenGL" else VK_FORMATS).get(target[0])
        self.log.reason(f"preparing the correction for a {target[1]}x{target[2]} view of "
                        f"{fmt.name if fmt else hex(target[0])} off the application's thread (frames pass through "
                        "meanwhile)")
        return False

    # ------------------------------------------------------------ configuration and prescription

    def _check(self) -> str | None:
        """Re-read the off switch and the configuration (at most every 0.25 s; a new configuration
        gets a new eye source and builder), take what the builder has ready (every frame); returns
        the reason to pass through, or None (also while the first pipeline builds: nothing to log)."""
        now = time.monotonic()
        if now - self._last_check >= _CHECK_INTERVAL_S or self._last_check < 0:
            self._last_check = now
            self._off_reason = _off(self.env)
            if self._off_reason:
                return self._off_reason
            self._configure()
        self._take_events()
        return self._off_reason or self._config_error or (None if self.pipeline else self._build_error)

    def _configure(self) -> None:
        """Read the configuration: a changed one starts from scratch (the old source and builder let
        go, the pipeline released); open a source when there is none and the prescription file is
        not the one that failed (the same bad file is not rebuilt)."""
        try:
            config = read_config(self.env)
            self._config_error = None
        except (InputError, ValidationError) as exc:
            self._config_error = f"layer configuration: {exc}"
            return
        if config != self._config:
            self._config = config
            self._close_source()
            self._release_pipeline()
            self._rx_failed_stamp = _NEVER
            self._build_error = None
        if config.rx is None:
            self._build_error = (f"no prescription: set rx in {config_path(self.env)} (vrcorrect layer install --rx) "
                                 f"or {RX_ENV}")
            return
        if self._source is None and file_stamp(config.rx) != self._rx_failed_stamp:
            self._open_source(config)

    def _open_source(self, config: LayerConfig) -> None:
        """A :class:`_Builder` for ``config``: on its own thread it opens the
        :class:`~vrcorrect.runtime.eye_source.EyeSource` (the modules it needs are imported there, not
        on the application's thread) and takes its models, or the cached ones; frames pass through
        meanwhile."""
        self.log.line(f"building the eye models for {config.rx} ...")
        self._build_error = None
        self._t0 = time.perf_counter()
        self._builder = _Builder(self, config, file_stamp(config.rx))

    def _take_events(self) -> None:
        """On the application's thread, every frame: what the builder has ready: log lines, a failure,
        or a pipeline, which replaces the current one (released here)."""
        builder = self._builder
        if builder is None:
            return
        while True:
            try:
                event = builder.events.get_nowait()
            except queue.Empty:
                return
            if event[0] == "log":
                self.log.line(event[1])
            elif event[0] == "failed":
                self._failed(event[1], event[2])
                return
            elif event[0] == "pipeline":
                self._install(event[1], event[2])

    def _install(self, pipeline: _Pipeline, info: Mapping[str, Any]) -> None:
        """Correct with ``pipeline`` from now on (Vulkan: it imports the swapchains' shared images
        first); the old one is released."""
        try:
            if self.api == "Vulkan":
                with pipeline.ctx:
                    for chain in [c for c in pipeline.chains if c not in self._chains]:
                        pipeline.release_chain(chain)                 # gone while it was built
                    for chain, memory in self._chains.items():
                        if chain not in pipeline.chains:
                            pipeline.import_chain(chain, memory)
        except Exception as exc:  # noqa: BLE001
            self._release(pipeline)
            text = f"the Vulkan application's images cannot be shared with the engine's GL: {_one_line(exc)}"
            if self.pipeline is None and self._source is not None:
                self._failed(self._source.snapshot.stamp, text)
            else:
                self.log.line(text)
            return
        old, self.pipeline = self.pipeline, pipeline
        if old is not None:
            self._release(old)
        self._asked -= pipeline.targets
        stats = info["stats"]
        programs = (f"{stats.loaded} programs from the cache, {stats.linked} compiled" if stats.disabled is None
                    else f"programs compiled ({stats.disabled})")
        if pipeline.sync and pipeline.sync != self._sync_logged:
            self._sync_logged = pipeline.sync
            self.log.line(f"Vulkan copies synchronised by {pipeline.sync}")
        if info["what"] == "start":
            self.display, self.rx_path = pipeline.display, pipeline.rx
            self._rx_failed_stamp = _NEVER
            models = "eye models from the cache" if info["cached_models"] else \
                f"eye models designed in {info['design_seconds']:.1f} s"
            steps = ", ".join(f"{k} {v:.1f} s" for k, v in pipeline.steps.items())
            primed = ", ".join(f"{eye} {n}" for eye, n in pipeline.primed_frames.items())
            if primed:
                over_budget = sum(pipeline.primed_frames.values()) < PRIME_MAX_FRAMES * len(pipeline.primed_frames)
                primed += (" frames, converged" if all(pipeline.prime_converged.values()) else
                           " frames, then converging on the application's frames (priming "
                           + ("budget reached)" if over_budget else f"stopped at {PRIME_MAX_FRAMES} frames an eye)"))
            self.log.line(f"correcting with {pipeline.rx} on display {pipeline.display.name} ({info['why']}); built in "
                          f"{time.perf_counter() - self._t0:.1f} s off the application's thread ({models}; GL "
                          f"{info['gl_seconds']:.1f} s: {steps}; {programs}"
                          + (f"; primed on the application's frame: {primed}" if primed else "") + ")")
        elif info["what"] == "reload":
            self.log.line(f"{pipeline.rx}: reloaded (built in {info['seconds']:.1f} s off the application's thread; "
                          f"{programs})")
        else:
            sizes = ", ".join(f"{w}x{h}" for _, w, h in sorted(pipeline.targets))
            self.log.line(f"prepared for {sizes} (built in {info['seconds']:.1f} s off the application's thread)")

    def _failed(self, stamp: Any, error: BaseException | str) -> None:
        """The first models or pipeline could not be made: pass through with the reason until the
        prescription file or the configuration changes."""
        self._close_source()
        self._rx_failed_stamp = stamp
        assert self._config is not None
        text = _one_line(error) if isinstance(error, BaseException) else error
        self._build_error = f"prescription {self._config.rx}: {text}"

    def _close_source(self) -> None:
        """Let the eye source and the builder go without waiting for what they may be running (they
        end unused; a pipeline the builder made and did not hand over is released)."""
        if self._builder is not None:
            builder, self._builder = self._builder, None
            builder.stop()
            self._drop_events(builder)
            self._let_go.append(builder)
        if self._source is not None:
            self._source.close(wait=False)
            self._let_go = [s for s in self._let_go if not s.join(0.0)] + [self._source]   # the ones still running
            self._source = None

    def _drop_events(self, builder: _Builder) -> None:
        """Release the pipelines a builder posted that were not taken."""
        while True:
            try:
                event = builder.events.get_nowait()
            except queue.Empty:
                return
            if event[0] == "pipeline":
                self._release(event[1])

    @contextlib.contextmanager
    def _current(self, pipeline: _Pipeline) -> Iterator["moderngl.Context"]:
        """``pipeline``'s context current on this thread for the block; what was current before comes
        back after (OpenGL: the application's context)."""
        if self.api == "OpenGL":
            if self._app_glx is None:
                self._app_glx = _AppGlx()
            with self._app_glx.engine_current(pipeline.loader.inner):
                yield pipeline.ctx
        else:
            with pipeline.ctx:
                yield pipeline.ctx

    def _release(self, pipeline: _Pipeline) -> None:
        """Release ``pipeline`` with its context current on this thread (what was current comes back)."""
        loader = pipeline.loader
        try:
            if self.api == "OpenGL":
                if self._app_glx is None:
                    self._app_glx = _AppGlx()
                with self._app_glx.engine_current(loader.inner):
                    pipeline.release()
            else:
                loader.__enter__()
                try:
                    pipeline.release()
                finally:
                    loader.inner.__exit__()          # (the moderngl context is gone: its loader's context)
        except Exception as exc:  # noqa: BLE001
            self.log.line(f"releasing a pipeline: {_one_line(exc)}")

    def _release_pipeline(self) -> None:
        if self.pipeline is not None:
            old, self.pipeline = self.pipeline, None
            self._release(old)

    # ------------------------------------------------------------ frames

    def begin_frame(self) -> int:
        """What the shim does with this frame: 1 correct it, 0 pass it through (the reason is logged
        once), 2 hand its views to :meth:`capture_gl`/:meth:`capture_vulkan` and pass it through (the
        first pipeline is being built and primes itself on them)."""
        try:
            reason = self._check()
        except Exception as exc:  # noqa: BLE001
            reason = f"the engine could not start: {_one_line(exc)}"
        if reason:
            self.log.reason(reason)
            return 0
        if self.pipeline is not None:
            self._waited_ready = False
            return 3 if self.pipeline.semaphores is not None else 1
        request = self.capture                   # none yet: the models or the pipeline are being built
        return 2 if request is not None and not request.ready.is_set() else 0

    def import_semaphores(self, ready_fd: int, done_fd: int) -> bool:
        """Vulkan: the shim's two external semaphores as file descriptors (the engine's to close), or -1
        when the device has no ``VK_KHR_external_semaphore_fd``; each pipeline imports duplicates where
        its GL has ``GL_EXT_semaphore_fd``."""
        if ready_fd < 0 or done_fd < 0:
            self._semaphore_note = "the Vulkan device has no VK_KHR_external_semaphore_fd"
            return False
        self._semaphore_fds = (int(ready_fd), int(done_fd))
        return True

    def attach_semaphores(self, pipeline: _Pipeline) -> str:
        """(The builder, on the pipeline's context.)  Import the external semaphores into ``pipeline``
        where its GL can; returns how the pipeline is synchronised with the shim's copies."""
        if self._semaphore_fds is None:
            return f"a fence and glFinish ({self._semaphore_note})"
        missing = sorted({"GL_EXT_semaphore", "GL_EXT_semaphore_fd"} - set(pipeline.ctx.extensions))
        if missing:
            renderer = pipeline.ctx.info.get("GL_RENDERER", "?")
            return f"a fence and glFinish (the engine's GL, {renderer}, lacks {' and '.join(missing)})"
        pipeline.semaphores = _Semaphores(pipeline.loader, self._semaphore_fds)
        return "external semaphores (VK_KHR_external_semaphore_fd, GL_EXT_semaphore_fd): no CPU wait"

    def drain(self) -> bool:
        """Vulkan, with semaphores: the frame failed after the shim's copy in signalled ``ready``: GL
        waits for it all the same (a binary semaphore is waited for before it is signalled again)."""
        try:
            p = self.pipeline
            if p is not None and p.semaphores is not None and not self._waited_ready:
                with self._current(p):
                    p.semaphores.wait_ready([c.input for c in p.chains.values()])
                self._waited_ready = True
            return True
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"waiting for the Vulkan copy: {_one_line(exc)}")
            return False

    def chain_memory(self) -> dict[int, _ChainMemory]:
        """The Vulkan swapchains' shared images now (any thread)."""
        return dict(self._chains)

    def _add_capture(self, view: dict[str, Any]) -> None:
        request = self.capture
        if request is not None and not request.ready.is_set():
            request.views.append(view)

    def capture_gl(self, view_index: int, src_texture: int, src_format: int, src_width: int, src_height: int,
                   x: int, y: int, width: int, height: int, view_in_layer: int = -1) -> bool:
        """OpenGL: hand the builder a view of this frame (the application's texture and rect, and a fence
        after the application's rendering, made on its context); the frame passes through."""
        try:
            eye = eye_of_view(view_in_layer if view_in_layer >= 0 else view_index)
            if src_format not in GL_FORMATS:
                return False
            _check_rect(x, y, width, height, src_width, src_height)
            if self._app_glx is None:
                self._app_glx = _AppGlx()
            self._add_capture({"eye": eye, "code": int(src_format), "texture": int(src_texture),
                               "rect": (int(x), int(y), int(width), int(height)), "fence": self._app_glx._fence()})
            return True
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"view {view_index}: {_one_line(exc)}")
            return False

    def capture_vulkan(self, view_index: int, chain: int, x: int, y: int, width: int, height: int,
                       view_in_layer: int = -1) -> bool:
        """Vulkan: hand the builder a view of this frame (its rect, copied by the shim into the chain's
        shared ``input`` image); the frame passes through."""
        try:
            eye = eye_of_view(view_in_layer if view_in_layer >= 0 else view_index)
            memory = self._chains.get(chain)
            if memory is None:
                return False
            _check_rect(x, y, width, height, memory.width, memory.height)
            self._add_capture({"eye": eye, "code": memory.code, "chain": int(chain),
                               "rect": (int(x), int(y), int(width), int(height))})
            return True
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"view {view_index}: {_one_line(exc)}")
            return False

    def _announce(self, fmt: SwapchainFormat) -> None:
        if fmt.encoding == "float" and fmt.name not in self._announced:
            self._announced.add(fmt.name)
            self.log.line(f"{fmt.name} swapchain (linear light): the correction works on values in [0, 1]; the "
                          "part of each value outside [0, 1] is carried through uncorrected")

    def _timed(self, pipeline: _Pipeline, eye: str) -> Any:
        query, previous = pipeline.query(eye, self.frames)
        if previous is not False:
            self._gpu_ms.setdefault(eye, []).append(previous)    # type: ignore[arg-type]
        return query

    def _budget_words(self) -> str:
        """``budget: left ...; right ...``: what each eye's frame budget chose (empty without one)."""
        p = self.pipeline
        if p is None:
            return ""
        parts = [f"{eye} {c.budget.describe()}" for eye, c in sorted(p.correctors.items()) if c.budget is not None]
        return ("budget: " + "; ".join(parts)) if parts else ""

    def look(self, view_in_layer: int, u: float, v: float) -> None:
        """The eye tracker's gaze for this frame's view (``vrcorrect_gaze.c``): ``(u, v)`` its place in
        the view's rect, 0..1 from the left and top edges; NaN when the tracker gives none (the
        configured gaze then applies)."""
        eye = eye_of_view(view_in_layer)
        tracked = math.isfinite(u) and math.isfinite(v)
        if tracked:
            self._gaze_uv[eye] = (float(u), float(v))
        else:
            self._gaze_uv.pop(eye, None)
        said = "tracked" if tracked else "untracked"
        if said != self._gaze_said:
            self.log.line("gaze: following the eye tracker (XR_EXT_eye_gaze_interaction)" if tracked else
                          "gaze: the eye tracker gives no gaze; the fovea's window is at the configured gaze")
            self._gaze_said = said

    def _aim(self, pipeline: "_Pipeline", eye: str, width: int, height: int) -> None:
        """Place ``eye``'s fovea at the tracked gaze of this frame, or at the configured one."""
        corrector = pipeline.correctors[eye]
        uv = self._gaze_uv.get(eye)
        if uv is None:
            corrector.gaze_deg = corrector.options.gaze_deg
            return
        corrector.gaze_deg = gaze_deg_of(uv, (width, height), corrector.display.pixels_per_degree)

    def correct(self, view_index: int, src_texture: int, src_format: int, src_width: int, src_height: int,
                x: int, y: int, width: int, height: int, dst_texture: int, view_in_layer: int = -1) -> bool:
        """OpenGL: correct GL texture ``src_texture`` (an application swapchain image, ``src_format``,
        ``src_width`` x ``src_height``) over the rect (x, y, width, height; GL pixels, origin at the
        bottom left) into the same rect of ``dst_texture`` (the output image, same format and size),
        on the engine's context.  Returns False (with one log line) when it could not."""
        try:
            view = view_in_layer if view_in_layer >= 0 else view_index
            eye = eye_of_view(view)
            fmt = GL_FORMATS.get(src_format)
            if fmt is None:
                raise ValidationError("swapchain format", hex(src_format),
                                      ", ".join(f"{f.name} {hex(code)}" for code, f in GL_FORMATS.items()))
            _check_rect(x, y, width, height, src_width, src_height)
            p = self.pipeline
            if p is None or not self._covered((int(src_format), int(width), int(height))):
                return False
            self._announce(fmt)
            if self.capture is not None and not self.capture.ready.is_set():    # a rebuild primes on this frame
                self.capture_gl(view_index, src_texture, src_format, src_width, src_height, x, y, width, height,
                                view_in_layer)
            self._aim(p, eye, width, height)
            with self._current(p):
                src = p.application_texture(src_texture, src_width, src_height, fmt)
                dst = p.application_texture(dst_texture, src_width, src_height, fmt)
                ms = p.correct_rect(eye, fmt, src, dst, (x, y, width, height), flip=False, query=self._timed(p, eye))
            self._cpu_ms.setdefault(eye, []).append(ms)
            return True
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"view {view_index}: {_one_line(exc)}")
            return False

    def forget_textures(self, names: list[int], current: bool = True) -> None:
        """OpenGL: a swapchain is going away: let go of the wrappers and framebuffers made for its
        textures ``names`` (the runtime may reuse the names).  ``current`` is kept for the shim's
        call: the engine's objects live on its own context, released there."""
        try:
            if self.pipeline is not None:
                with self._current(self.pipeline):
                    self.pipeline.forget_textures([int(n) for n in names])
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"forgetting a swapchain's textures: {_one_line(exc)}")

    def import_images(self, chain: int, vk_format: int, width: int, height: int, input_fd: int, input_size: int,
                      result_fd: int, result_size: int) -> bool:
        """Vulkan: a swapchain's two shared images (their memory as file descriptors, which the engine
        takes over and keeps until :meth:`release_images`): every pipeline imports them (the current
        one now).  Returns False (with one log line) when it could not."""
        fds = (int(input_fd), int(result_fd))
        try:
            fmt = VK_FORMATS.get(vk_format)
            if fmt is None:
                raise ValidationError("swapchain format", hex(vk_format),
                                      ", ".join(f"{f.name} {hex(code)}" for code, f in VK_FORMATS.items()))
            self.release_images(chain)
            memory = _ChainMemory(fmt, int(vk_format), int(width), int(height), fds, (int(input_size), int(result_size)))
            self._chains[chain] = memory
            fds = ()
            self._add_targets(("chain", chain), self._chain_targets(int(vk_format), int(width), int(height)))
            if self.pipeline is not None:
                with self._current(self.pipeline):
                    self.pipeline.import_chain(chain, memory)
            self.log.line(f"Vulkan swapchain {chain}: {fmt.name} {width}x{height}, shared with the engine's GL")
            return True
        except Exception as exc:  # noqa: BLE001
            for fd in fds:
                if fd >= 0:
                    os.close(fd)
            self.release_images(chain)
            self.log.reason(f"the Vulkan application's images cannot be shared with the engine's GL: {_one_line(exc)}")
            return False

    def release_images(self, chain: int) -> None:
        """Vulkan: let go of a swapchain's shared images (before the shim frees their memory)."""
        memory = self._chains.pop(chain, None)
        with self._targets_lock:
            self._targets.pop(("chain", chain), None)
        try:
            if self.pipeline is not None and chain in self.pipeline.chains:
                with self._current(self.pipeline):
                    self.pipeline.release_chain(chain)
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"Vulkan swapchain {chain}: releasing its images: {_one_line(exc)}")
        finally:
            if memory is not None:
                memory.close()

    def correct_vulkan(self, view_index: int, chain: int, x: int, y: int, width: int, height: int,
                       view_in_layer: int = -1) -> bool:
        """Vulkan: correct the rect (x, y, width, height; Vulkan pixels, origin at the top left) of
        swapchain ``chain``'s shared ``input`` image into the same rect of its ``result`` image."""
        try:
            view = view_in_layer if view_in_layer >= 0 else view_index
            eye = eye_of_view(view)
            memory = self._chains.get(chain)
            if memory is None:
                raise ValidationError("swapchain", chain, "one whose images the engine imported")
            _check_rect(x, y, width, height, memory.width, memory.height)
            p = self.pipeline
            if p is None or not self._covered((memory.code, int(width), int(height))):
                return False
            shared = p.chains.get(chain)
            if shared is None:
                raise ValidationError("swapchain", chain, "one whose images the engine imported")
            self._announce(shared.format)
            if self.capture is not None and not self.capture.ready.is_set():    # a rebuild primes on this frame
                self.capture_vulkan(view_index, chain, x, y, width, height, view_in_layer)
            self._aim(p, eye, width, height)
            with self._current(p):
                if p.semaphores is not None and not self._waited_ready:       # the shim's copy in, on the GPU
                    p.semaphores.wait_ready([c.input for c in p.chains.values()])
                    self._waited_ready = True
                ms = p.correct_rect(eye, shared.format, shared.input, shared.result, (x, y, width, height), flip=True,
                                    query=self._timed(p, eye))
            self._cpu_ms.setdefault(eye, []).append(ms)
            return True
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"view {view_index}: {_one_line(exc)}")
            return False

    def finish(self) -> bool:
        """Vulkan: the GL work of the frame done before the shim copies the results: signalled on the
        ``done`` semaphore (with semaphores), else waited for (``glFinish``)."""
        try:
            p = self.pipeline
            if p is None:
                raise RuntimeError("no correction is ready")
            with self._current(p) as ctx:
                if p.semaphores is not None:
                    p.semaphores.signal_done([c.result for c in p.chains.values()])
                    _flush(p.loader)
                else:
                    ctx.finish()
            return True
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"glFinish: {_one_line(exc)}")
            return False

    def end_frame(self, corrected: bool, timings_ms: tuple[float, float, float, float] = (-1.0, -1.0, -1.0, -1.0)
                  ) -> None:
        """Per-frame bookkeeping: each eye's time, logged once a second.  GPU time comes from a
        timer query per eye and frame, read a frame later from a two-slot ring (no wait for the
        frame just issued); CPU time is the layer's own time in the call (issuing the work).
        ``timings_ms`` (from the shim): the layer's whole time in this ``xrEndFrame``, then for a
        Vulkan session the copy into the shared images with its fence wait, the ``glFinish``, and
        the copy into the output images (-1 for an OpenGL session)."""
        request = self.capture
        if request is not None and request.views and not request.ready.is_set():
            request.ready.set()                  # this frame's views are the builder's to take
        try:
            if not corrected:
                return
            self.log.corrected()
            self.frames += 1
            if timings_ms[0] >= 0:
                self._frame_ms.append(float(timings_ms[0]))
                if self.frames == 1:               # everything was built off the application's thread
                    self.log.line(f"first corrected frame: {timings_ms[0]:.0f} ms in xrEndFrame")
            if timings_ms[1] >= 0:
                self._sync_ms.append((float(timings_ms[1]), float(timings_ms[2]), float(timings_ms[3])))
            now = time.monotonic()
            if now - self._last_report >= _REPORT_INTERVAL_S and self._cpu_ms:
                parts = []
                for eye in sorted(self._cpu_ms):
                    cpu = self._cpu_ms[eye]
                    gpu = [v for v in self._gpu_ms.get(eye, []) if v is not None]
                    saturated = any(v is None for v in self._gpu_ms.get(eye, []))
                    gpu_text = (f">{_QUERY_MAX_MS:.0f}" if saturated else
                                f"{sum(gpu) / len(gpu):.1f}" if gpu else "-")
                    parts.append(f"{eye} GPU {gpu_text} ms, CPU {sum(cpu) / len(cpu):.1f} ms")
                count = max(len(v) for v in self._cpu_ms.values())
                line = f"{self.frames} frames corrected; per eye (mean of {count} frames): " + "; ".join(parts)
                if self._frame_ms:
                    line += f"; in xrEndFrame {sum(self._frame_ms) / len(self._frame_ms):.1f} ms"
                if self._sync_ms:
                    mean = [sum(s[i] for s in self._sync_ms) / len(self._sync_ms) for i in range(3)]
                    line += (f"; per frame, Vulkan copy in and wait {mean[0]:.2f} ms, glFinish {mean[1]:.2f} ms, "
                             f"copy out {mean[2]:.2f} ms")
                self.log.line(line)
                budgets = self._budget_words()
                if budgets:
                    self.log.line(budgets)
                self._cpu_ms.clear()
                self._gpu_ms.clear()
                self._sync_ms.clear()
                self._frame_ms.clear()
                self._last_report = now
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"timing: {_one_line(exc)}")

    # ------------------------------------------------------------ the end

    def release_gl(self, current: bool = True) -> None:
        """The session is going away: let the eye source and the builder go, release the pipeline
        (on its own context) and close the shared images' descriptors (a later frame starts from the
        configuration again).  ``current`` is kept for the shim's call: the engine's objects live on
        contexts of its own, always released."""
        self._close_source()
        self._release_pipeline()
        for chain in list(self._chains):
            self.release_images(chain)
        if self._semaphore_fds is not None:
            for fd in self._semaphore_fds:
                try:
                    os.close(fd)
                except OSError:
                    pass
            self._semaphore_fds = None
        with self._targets_lock:
            self._targets.clear()
        self._asked.clear()
        self._config = None

    def close(self) -> None:
        """The instance ends (the application is likely to exit next): wait for any design or build
        still running on a let-go source or builder, so that no worker is inside numpy or GL while
        the process exits (a crash at exit otherwise); at most :data:`CLOSE_WAIT_S` s."""
        self._close_source()
        running = [s for s in self._let_go if not s.join(0.0)]
        self._let_go = []
        if running:
            self.log.line("waiting for the eye models being built to finish before closing")
            deadline = time.monotonic() + CLOSE_WAIT_S
            if not all(s.join(max(0.0, deadline - time.monotonic())) for s in running):
                self.log.line(f"an eye model build still running after {CLOSE_WAIT_S:g} s; closing anyway")
        self.log.line(f"closed after {self.frames} corrected frames")


def _flush(loader: Any) -> None:
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


def _check_rect(x: int, y: int, width: int, height: int, image_width: int, image_height: int) -> None:
    if width < 1 or height < 1 or x < 0 or y < 0 or x + width > image_width or y + height > image_height:
        raise ValidationError("imageRect", (x, y, width, height), f"inside the {image_width}x{image_height} swapchain image")


def _set_uniforms(program: "moderngl.Program", values: Mapping[str, Any]) -> None:
    """Set the uniforms the program has (the compiler drops those a stage does not use)."""
    for name, value in values.items():
        if name in program:
            program[name] = value


def _one_line(exc: BaseException) -> str:
    text = _one_line_text(str(exc))
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _one_line_text(text: str) -> str:
    return " ".join(text.split())
