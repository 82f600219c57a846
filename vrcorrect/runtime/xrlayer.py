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
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator, Mapping

from ..plumbing.errors import InputError, ValidationError
from ..plumbing.fileio import file_stamp
from ..specs.vocabulary import VIEW_ORDER, Backend
from .gl import fullscreen_triangle, headless_context, release
from .shaders import compile_program

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

    from ..specs.display import DisplayProfile
    from .corrector import Corrector
    from .eye_source import EyeSource, EyeUpdate

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
    from ..specs.display import get_display, preset_names

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


@dataclass
class _SharedChain:
    """A Vulkan swapchain's two shared images as the engine's textures: ``input`` (the submitted rects,
    copied there by the shim) and ``result`` (the correction, copied from there into the output image)."""

    format: SwapchainFormat
    input: "moderngl.Texture"
    result: "moderngl.Texture"
    names: tuple[tuple[int, int], ...]           # (texture, memory object) of each, for the deletion


class Engine:
    """The layer's correction engine (module docstring).  ``view_width``/``view_height``: the
    runtime's recommended view size (0 when unknown); ``api``: the session's graphics API
    (``"OpenGL"``: the application's context; ``"Vulkan"``: a headless context of the engine's)."""

    def __init__(self, view_width: int = 0, view_height: int = 0, api: str = "OpenGL",
                 env: Mapping[str, str] | None = None):
        self.env = os.environ if env is None else env
        self.log = _Log(log_path(self.env))
        self.view_size = (int(view_width), int(view_height))
        self.api = api
        self.ctx: moderngl.Context | None = None
        self.correctors: dict[str, Corrector] = {}
        self.display: DisplayProfile | None = None
        self.rx_path: Path | None = None
        self._rx_failed_stamp: Any = _NEVER          # the stamp of the prescription file that failed to build
        self._build_error: str | None = None
        self._source: EyeSource | None = None        # watches the prescription, designs the eye models
        self._let_go: list[EyeSource] = []           # sources closed without waiting; joined by close()
        self._display_why: list[str] = []            # why the source's display was chosen (set on its worker)
        self._t0 = 0.0                               # when the source's first designs were asked for
        self._last_check = -1.0
        self._off_reason: str | None = None
        self._config: LayerConfig | None = None
        self._config_error: str | None = None
        self._external: dict[tuple[int, int, int], moderngl.Texture] = {}    # the application's textures (OpenGL)
        self._staging: dict[tuple[int, int, str], moderngl.Texture] = {}
        self._framebuffers: dict[int, moderngl.Framebuffer] = {}             # by the texture's GL name
        self._programs: dict[tuple[str, bool], tuple[moderngl.Program, moderngl.VertexArray]] = {}
        self._sampler: moderngl.Sampler | None = None
        self._memory: _MemoryObjects | None = None
        self._chains: dict[int, _SharedChain] = {}
        self._announced: set[str] = set()
        self._queries: dict[str, list[moderngl.Query]] = {}
        self._cpu_ms: dict[str, list[float]] = {}
        self._gpu_ms: dict[str, list[float | None]] = {}
        self._query_used: dict[str, list[bool]] = {}
        self._sync_ms: list[tuple[float, float, float]] = []
        self._frame_ms: list[float] = []
        self._last_report = time.monotonic()
        self.frames = 0
        self.log.line(f"loaded ({api} session, runtime view size {view_width}x{view_height}, "
                      f"Python {sys.version.split()[0]}, vrcorrect from {Path(__file__).resolve().parents[1]})")

    # ------------------------------------------------------------ configuration and prescription

    def _check(self) -> str | None:
        """Re-read the off switch and the configuration (at most every 0.25 s; a new configuration
        gets a new eye source), take what the eye source has ready (every frame); returns the
        reason to pass through, or None (also while the first models build: no correctors yet,
        nothing to log)."""
        now = time.monotonic()
        if now - self._last_check >= _CHECK_INTERVAL_S or self._last_check < 0:
            self._last_check = now
            self._off_reason = _off(self.env)
            if self._off_reason:
                return self._off_reason
            self._configure()
        self._take_models()
        return self._off_reason or self._config_error or (None if self.correctors else self._build_error)

    def _configure(self) -> None:
        """Read the configuration: a changed one starts from scratch (the old eye source closed, the
        Correctors released); open an eye source when there is none and the prescription file is
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
            self._release_correctors()
            self._rx_failed_stamp = _NEVER
            self._build_error = None
        if config.rx is None:
            self._build_error = (f"no prescription: set rx in {config_path(self.env)} (vrcorrect layer install --rx) "
                                 f"or {RX_ENV}")
            return
        if self._source is None and file_stamp(config.rx) != self._rx_failed_stamp:
            self._open_source(config)

    def _open_source(self, config: LayerConfig) -> None:
        """An :class:`~vrcorrect.runtime.eye_source.EyeSource` for ``config``: the prescription read
        here (a small file), the display chosen and both eyes designed on its worker, with the
        options a :class:`~vrcorrect.runtime.corrector.Corrector` makes of the same configuration
        (so the correction is the one it would design itself); frames pass through meanwhile."""
        self.log.line(f"building the eye models for {config.rx} ...")
        self._build_error = None
        stamp = file_stamp(config.rx)
        try:
            from .eye_model import CorrectorOptions
            from .eye_source import EyeSource

            options = dict(config.options)
            backend = options.pop("backend", Backend.GLSL)  # Corrector(backend=...) then CorrectorOptions(backend=...)
            why: list[str] = []

            def display() -> DisplayProfile:            # on the worker: loading a profile takes seconds
                profile, reason = choose_display(config.display, self.view_size)
                why.append(reason)
                return profile

            self._t0 = time.perf_counter()
            source = EyeSource(config.rx, display, CorrectorOptions(backend=backend, **options))
        except Exception as exc:  # noqa: BLE001  (every failure is a pass-through with its reason)
            self._failed(stamp, exc)
            return
        self._source, self._display_why = source, why
        source.design_all()

    def _take_models(self) -> None:
        """On the application's thread, every frame: what the eye source has ready.  The first
        models become the Correctors (GL resources only); later ones are installed into them;
        the source's messages are logged (an invalid edit keeps the last good prescription)."""
        source, config = self._source, self._config
        if source is None or config is None:
            return
        seen = source.reloads_started
        updates, messages = source.poll()
        if source.reloads_started != seen:
            self.log.line(f"building the eye models for {config.rx} (changed" +
                          ("; correcting with the current ones meanwhile)" if self.correctors else ")") + " ...")
        if not self.correctors:
            start = [u for u in updates if u.reason == "start"]
            if not start:
                if messages:                         # the first thing the worker says: its start was refused
                    self._failed(source.snapshot.stamp, _one_line_text(messages[0]))
                return
            if not self._make_correctors(source, config, start):
                return
        reloads = {u.eye: u for u in updates if u.reason == "reload"}     # the newest of each eye
        if reloads:
            try:
                for u in reloads.values():
                    self.correctors[u.eye].install(u.model, u.prescription)
                self.log.line(f"{config.rx}: reloaded (built in {sum(u.seconds for u in reloads.values()):.1f} s)")
            except Exception as exc:  # noqa: BLE001
                self.log.line(f"{config.rx}: not reloaded: {_one_line(exc)}")
        for message in messages:
            self.log.line(_one_line_text(message))

    def _make_correctors(self, source: "EyeSource", config: LayerConfig, start: "list[EyeUpdate]") -> bool:
        """The two Correctors from the source's first models (on the application's thread: GL)."""
        from .corrector import Corrector

        correctors: dict[str, Corrector] = {}
        try:
            for u in start:
                correctors[u.eye] = Corrector(self._gl(), u.prescription, source.display, u.eye, eye_model=u.model,
                                              **dict(config.options))
        except Exception as exc:  # noqa: BLE001  (every failure is a pass-through with its reason)
            for c in correctors.values():
                try:
                    c.release()
                except Exception:  # noqa: BLE001
                    pass
            self._failed(source.snapshot.stamp, exc)
            return False
        self.correctors, self.display, self.rx_path = correctors, source.display, config.rx
        self._rx_failed_stamp = _NEVER
        why = self._display_why[0] if self._display_why else ""
        self.log.line(f"correcting with {config.rx} on display {source.display.name} ({why}); built in "
                      f"{time.perf_counter() - self._t0:.1f} s")
        source.check = correctors[source.eyes[0]].check_eye      # later designs refused as the Correctors would
        return True

    def _failed(self, stamp: Any, error: BaseException | str) -> None:
        """The first models could not be made: pass through with the reason until the prescription
        file or the configuration changes."""
        self._close_source()
        self._rx_failed_stamp = stamp
        assert self._config is not None
        text = _one_line(error) if isinstance(error, BaseException) else error
        self._build_error = f"prescription {self._config.rx}: {text}"

    def _close_source(self) -> None:
        """Let the eye source go without waiting for a design it may be running (it ends unused)."""
        if self._source is not None:
            self._source.close(wait=False)
            self._let_go = [s for s in self._let_go if not s.join(0.0)] + [self._source]   # the ones still running
            self._source = None

    def _gl(self) -> "moderngl.Context":
        """The engine's moderngl context: attached to the application's current one (OpenGL), or a
        headless one of its own (Vulkan), made on first use."""
        if self.ctx is None:
            import moderngl

            ctx = moderngl.create_context() if self.api == "OpenGL" else headless_context(require=430)
            if ctx.version_code < 430:
                raise ValidationError("OpenGL version", ctx.version_code, "4.3 or newer (compute shaders)")
            self.ctx = ctx
            self._sampler = ctx.sampler(filter=(moderngl.NEAREST, moderngl.NEAREST), repeat_x=False, repeat_y=False)
        return self.ctx

    @contextlib.contextmanager
    def _current(self) -> Iterator["moderngl.Context"]:
        """The engine's context, current for the block: the application's is current already
        (OpenGL); the engine's own is made current and the previous one restored after (Vulkan)."""
        ctx = self._gl()
        if self.api == "OpenGL":
            yield ctx
        else:
            with ctx:
                yield ctx

    def _release_correctors(self) -> None:
        for c in self.correctors.values():
            try:
                c.release()
            except Exception:  # noqa: BLE001
                pass
        self.correctors = {}

    # ------------------------------------------------------------ frames

    def begin_frame(self) -> bool:
        """Whether this frame is corrected (False: pass through; the reason is logged once)."""
        try:
            with self._current():
                reason = self._check()
        except Exception as exc:  # noqa: BLE001
            reason = f"the engine could not start on this GL context: {_one_line(exc)}"
        if reason:
            self.log.reason(reason)
            return False
        return bool(self.correctors)             # none yet: the eye models are building (logged once)

    def correct(self, view_index: int, src_texture: int, src_format: int, src_width: int, src_height: int,
                x: int, y: int, width: int, height: int, dst_texture: int, view_in_layer: int = -1) -> bool:
        """OpenGL: correct GL texture ``src_texture`` (an application swapchain image, ``src_format``,
        ``src_width`` x ``src_height``) over the rect (x, y, width, height; GL pixels, origin at the
        bottom left) into the same rect of ``dst_texture`` (the output image, same format and size).
        Returns False (with one log line) when it could not."""
        try:
            view = view_in_layer if view_in_layer >= 0 else view_index
            eye = eye_of_view(view)
            fmt = GL_FORMATS.get(src_format)
            if fmt is None:
                raise ValidationError("swapchain format", hex(src_format),
                                      ", ".join(f"{f.name} {hex(code)}" for code, f in GL_FORMATS.items()))
            _check_rect(x, y, width, height, src_width, src_height)
            ctx = self._gl()
            src = self._application_texture(src_texture, src_width, src_height, fmt)
            dst = self._application_texture(dst_texture, src_width, src_height, fmt)
            self._correct_rect(ctx, eye, fmt, src, dst, (x, y, width, height), flip=False)
            return True
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"view {view_index}: {_one_line(exc)}")
            return False

    def forget_textures(self, names: list[int], current: bool = True) -> None:
        """OpenGL: a swapchain is going away: let go of the wrappers and framebuffers made for its
        textures ``names`` (the runtime may reuse the names); the framebuffers are deleted only with
        the session's context ``current``, else just forgotten."""
        try:
            for name in names:
                for key in [k for k in self._external if k[0] == name]:
                    del self._external[key]           # an external texture: nothing to delete
                fb = self._framebuffers.pop(name, None)
                if fb is not None and current:
                    release(fb)
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"forgetting a swapchain's textures: {_one_line(exc)}")

    def import_images(self, chain: int, vk_format: int, width: int, height: int, input_fd: int, input_size: int,
                      result_fd: int, result_size: int) -> bool:
        """Vulkan: import a swapchain's two shared images (their memory as file descriptors, which the
        engine takes over: GL owns each once imported, the engine closes it otherwise) into the
        engine's context.  Returns False (with one log line) when it could not."""
        fds = [input_fd, result_fd]
        names: list[tuple[int, int]] = []
        try:
            fmt = VK_FORMATS.get(vk_format)
            if fmt is None:
                raise ValidationError("swapchain format", hex(vk_format),
                                      ", ".join(f"{f.name} {hex(code)}" for code, f in VK_FORMATS.items()))
            with self._current() as ctx:
                if self._memory is None:
                    self._memory = _MemoryObjects(ctx)
                packed = fmt.packing is not None
                internal, components, dtype = (_GL_R32UI, 1, "u4") if packed else (_GL_RGBA16F, 4, "f2")
                textures = []
                for i, size in ((0, input_size), (1, result_size)):
                    fd, fds[i] = fds[i], -1
                    names.append(self._memory.texture(fd, size, width, height, internal))
                    textures.append(ctx.external_texture(names[-1][0], (width, height), components, 0, dtype))
                self.release_images(chain)
                self._chains[chain] = _SharedChain(fmt, textures[0], textures[1], tuple(names))
            self.log.line(f"Vulkan swapchain {chain}: {fmt.name} {width}x{height}, shared with the engine's GL")
            return True
        except Exception as exc:  # noqa: BLE001
            for fd in fds:
                if fd >= 0:
                    os.close(fd)
            if self._memory is not None:
                for texture, memory in names:
                    self._memory.free(texture, memory)
            self.log.reason(f"the Vulkan application's images cannot be shared with the engine's GL: {_one_line(exc)}")
            return False

    def release_images(self, chain: int) -> None:
        """Vulkan: let go of a swapchain's shared images (before the shim frees their memory)."""
        shared = self._chains.pop(chain, None)
        if shared is None or self.ctx is None:
            return
        try:
            with self._current():
                for texture in (shared.input, shared.result):
                    release(self._framebuffers.pop(texture.glo, None))
                    texture.release()                # an external texture: moderngl forgets it, deletes nothing
                if self._memory is not None:
                    for texture_name, memory in shared.names:
                        self._memory.free(texture_name, memory)
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"Vulkan swapchain {chain}: releasing its images: {_one_line(exc)}")

    def correct_vulkan(self, view_index: int, chain: int, x: int, y: int, width: int, height: int,
                       view_in_layer: int = -1) -> bool:
        """Vulkan: correct the rect (x, y, width, height; Vulkan pixels, origin at the top left) of
        swapchain ``chain``'s shared ``input`` image into the same rect of its ``result`` image."""
        try:
            view = view_in_layer if view_in_layer >= 0 else view_index
            eye = eye_of_view(view)
            shared = self._chains.get(chain)
            if shared is None:
                raise ValidationError("swapchain", chain, "one whose images the engine imported")
            _check_rect(x, y, width, height, *shared.input.size)
            with self._current() as ctx:
                self._correct_rect(ctx, eye, shared.format, shared.input, shared.result, (x, y, width, height),
                                   flip=True)
            return True
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"view {view_index}: {_one_line(exc)}")
            return False

    def finish(self) -> bool:
        """Vulkan: wait for the GL work of the frame (``glFinish``), before the shim copies the results."""
        try:
            with self._current() as ctx:
                ctx.finish()
            return True
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"glFinish: {_one_line(exc)}")
            return False

    def _correct_rect(self, ctx: "moderngl.Context", eye: str, fmt: SwapchainFormat, src: "moderngl.Texture",
                      dst: "moderngl.Texture", rect: tuple[int, int, int, int], flip: bool) -> None:
        """Decode the rect of ``src`` into staging, correct it for ``eye``, encode the result into the
        rect of ``dst`` (module docstring)."""
        x, y, width, height = rect
        if fmt.encoding == "float" and fmt.name not in self._announced:
            self._announced.add(fmt.name)
            self.log.line(f"{fmt.name} swapchain (linear light): the correction works on values in [0, 1]; the "
                          "part of each value outside [0, 1] is carried through uncorrected")
        packed = fmt.packing is not None
        common = {"u_packing": _PACKINGS.get(fmt.packing or "", 0), "u_encoding": _ENCODINGS[fmt.encoding],
                  "u_offset": (x, y), "u_height": height, "u_flip": flip}
        staging = self._stage_texture(width, height, "f1" if fmt.stage_codes else "f4")
        result = self._stage_texture(width, height, "result")
        self._draw("DECODE", packed, {**common, "u_source": 0, "u_stage_codes": fmt.stage_codes}, [src], staging,
                   (0, 0, width, height))
        t0 = time.perf_counter()
        with self._query(eye):
            self.correctors[eye].apply(staging, self._framebuffer(result))
        self._draw("ENCODE", packed, {**common, "u_source": 0, "u_result": 1, "u_carry": fmt.encoding == "float"},
                   [src, result], dst, rect)
        error = ctx.error
        if error != "GL_NO_ERROR":
            raise RuntimeError(f"a GL error ({error}) during the correction")
        self._cpu_ms.setdefault(eye, []).append(1e3 * (time.perf_counter() - t0))

    def end_frame(self, corrected: bool, timings_ms: tuple[float, float, float, float] = (-1.0, -1.0, -1.0, -1.0)
                  ) -> None:
        """Per-frame bookkeeping: each eye's time, logged once a second.  GPU time comes from a
        timer query per eye and frame, read a frame later from a two-slot ring (no wait for the
        frame just issued); CPU time is the layer's own time in the call (issuing the work).
        ``timings_ms`` (from the shim): the layer's whole time in this ``xrEndFrame``, then for a
        Vulkan session the copy into the shared images with its fence wait, the ``glFinish``, and
        the copy into the output images (-1 for an OpenGL session)."""
        try:
            if not corrected:
                return
            self.log.corrected()
            self.frames += 1
            if timings_ms[0] >= 0:
                self._frame_ms.append(float(timings_ms[0]))
                if self.frames == 1:               # shaders compiled, buffers made on the application's thread
                    self.log.line(f"first corrected frame: {timings_ms[0]:.0f} ms in xrEndFrame (the Correctors' "
                                  "GL set-up: shaders and buffers)")
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
                self._cpu_ms.clear()
                self._gpu_ms.clear()
                self._sync_ms.clear()
                self._frame_ms.clear()
                self._last_report = now
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"timing: {_one_line(exc)}")

    # ------------------------------------------------------------ GL objects

    def _program(self, stage: str, packed: bool) -> tuple["moderngl.Program", "moderngl.VertexArray"]:
        key = (stage, packed)
        if key not in self._programs:
            defines: dict[str, None] = {stage: None}
            if packed:
                defines["PACKED"] = None
            program = compile_program(self._gl(), "layer_copy.glsl", defines=defines)
            self._programs[key] = (program, fullscreen_triangle(self._gl(), program))
        return self._programs[key]

    def _draw(self, stage: str, packed: bool, uniforms: Mapping[str, Any], textures: list["moderngl.Texture"],
              target: "moderngl.Texture", viewport: tuple[int, int, int, int]) -> None:
        """One pass of ``layer_copy.glsl`` into ``target`` over ``viewport``, ``textures`` on units 0, 1, ...
        read through the layer's nearest-texel sampler (a texture's own parameters are never set: it
        may be the application's), which is unbound again after the pass (the Corrector's passes
        sample with their textures' own parameters)."""
        ctx = self._gl()
        ctx.disable_direct(_GL_FRAMEBUFFER_SRGB)
        program, vao = self._program(stage, packed)
        _set_uniforms(program, uniforms)
        assert self._sampler is not None
        for unit, texture in enumerate(textures):
            texture.use(unit)
            self._sampler.use(unit)
        fb = self._framebuffer(target)
        fb.use()
        ctx.viewport = viewport
        vao.render(mode=ctx.TRIANGLES, vertices=3)
        for unit in range(len(textures)):
            self._sampler.clear(unit)

    def _application_texture(self, name: int, width: int, height: int, fmt: SwapchainFormat) -> "moderngl.Texture":
        key = (int(name), width, height)
        tex = self._external.get(key)
        if tex is None:
            tex = self._gl().external_texture(int(name), (width, height), 4, 0, "f2" if fmt.encoding == "float" else "f1")
            self._external[key] = tex
        return tex

    def _stage_texture(self, width: int, height: int, kind: str) -> "moderngl.Texture":
        """The layer's own textures: ``"f1"``/``"f4"`` staging (the Corrector's input), ``"result"``
        (RGBA8: the Corrector's sRGB-encoded output)."""
        key = (width, height, kind)
        tex = self._staging.get(key)
        if tex is None:
            tex = self._gl().texture((width, height), 4, dtype="f1" if kind == "result" else kind)
            self._staging[key] = tex
        return tex

    def _framebuffer(self, texture: "moderngl.Texture") -> "moderngl.Framebuffer":
        fb = self._framebuffers.get(texture.glo)
        if fb is None:
            fb = self._gl().framebuffer(color_attachments=[texture])
            self._framebuffers[texture.glo] = fb
        return fb

    def _query(self, eye: str) -> "moderngl.Query":
        """This frame's timer query for ``eye``; the slot's previous use (two frames ago) is read
        first (``None`` when it saturated: a 32-bit nanosecond count ends at 4.29 s)."""
        ring = self._queries.get(eye)
        if ring is None:
            ctx = self._gl()
            ring = self._queries[eye] = [ctx.query(time=True), ctx.query(time=True)]
            self._query_used[eye] = [False, False]
        slot = self.frames % 2
        if self._query_used[eye][slot]:
            ns = ring[slot].elapsed
            self._gpu_ms.setdefault(eye, []).append(None if ns >= 0xFFFFFFFF else ns / 1e6)
        self._query_used[eye][slot] = True
        return ring[slot]

    def release_gl(self, current: bool = True) -> None:
        """Release every GL object (the session is going away) and let the eye source go (a later
        frame starts from the configuration again); with ``current`` False (the session's context
        is not current) the objects are only forgotten, no GL call is made."""
        if current and self.ctx is not None:
            for chain in list(self._chains):
                self.release_images(chain)
            try:
                with self._current():
                    self._release_correctors()
                    release(*self._framebuffers.values())       # never the application's textures themselves
                    release(*self._staging.values(), *(q for ring in self._queries.values() for q in ring),
                            *(o for pair in self._programs.values() for o in reversed(pair)), self._sampler)
            except Exception:  # noqa: BLE001
                pass
            if self.api != "OpenGL":
                try:
                    self.ctx.release()                           # the engine's own context
                except Exception:  # noqa: BLE001
                    pass
        self.correctors = {}
        self._chains.clear()
        self._external.clear()
        self._staging.clear()
        self._framebuffers.clear()
        self._programs.clear()
        self._queries.clear()
        self._query_used.clear()
        self._sampler = None
        self._memory = None
        self.ctx = None
        self._config = None
        self._close_source()

    def close(self) -> None:
        """The instance ends (the application is likely to exit next): wait for any design still
        running on a let-go source, so that no worker is inside numpy while the process exits (a
        crash at exit otherwise); at most :data:`CLOSE_WAIT_S` s."""
        self._close_source()
        running = [s for s in self._let_go if not s.join(0.0)]
        self._let_go = []
        if running:
            self.log.line("waiting for the eye models being built to finish before closing")
            deadline = time.monotonic() + CLOSE_WAIT_S
            if not all(s.join(max(0.0, deadline - time.monotonic())) for s in running):
                self.log.line(f"an eye model build still running after {CLOSE_WAIT_S:g} s; closing anyway")
        self.log.line(f"closed after {self.frames} corrected frames")


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
