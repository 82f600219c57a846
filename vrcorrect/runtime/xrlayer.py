"""The OpenXR API layer's engine: what ``layer/vrcorrect_layer.c`` (a thin C shim that embeds
Python) calls on the application's thread, with the application's GL context current.

The shim intercepts the application's OpenXR calls; for OpenGL sessions it gives each application
swapchain a layer-owned output swapchain and, at ``xrEndFrame``, asks :class:`Engine` to correct
the application's last released image over the submitted ``imageRect`` into the output image;
the frame then goes down with the output swapchains in place of the application's.

Per frame the shim calls :meth:`Engine.begin_frame` (``False``: pass the frame through),
:meth:`Engine.correct` once per view and :meth:`Engine.end_frame`.  Every failure becomes a
pass-through (``False``) and one log line naming the reason (a reason is logged again only after
a corrected frame or a different reason); the engine never raises into the shim.

The correction is the project's :class:`~vrcorrect.runtime.corrector.Corrector`, one per view
(view 0 the left eye, view 1 the right, as in ``XR_VIEW_CONFIGURATION_TYPE_PRIMARY_STEREO``), built
from the user's prescription JSON and display profile on a moderngl context attached to the
application's GL context.  The source image is read with ``texelFetch`` over the submitted rect
(linear light for both swapchain formats: GL decodes an sRGB image, an RGBA8 image holds linear
light), encoded to sRGB code values into a layer-owned RGBA8 texture (for an sRGB swapchain, the
application's codes exactly, which the Corrector decodes itself); the corrected sRGB codes are
written as they are into an sRGB output image (``GL_FRAMEBUFFER_SRGB`` off), or decoded to linear
light for an RGBA8 output image, as ``vrcorrect xr`` does.  The application's textures are only
sampled (their parameters are never set); the shim saves and restores the GL state around.

The eye models (:func:`~vrcorrect.runtime.eye_model.build_eye_model`: PSFs, kernels, filter design;
seconds of CPU) are built on a background thread, never in ``xrEndFrame``: frames pass through
meanwhile (one log line, "building the eye models ..."), and on the first frame after the build
the two Correctors are made on the application's thread from the prebuilt models (GL resources
only).  Hot reload works the same way: the engine watches the prescription file's stamp, keeps
correcting with the current Correctors while the new models build, then swaps them; an invalid new
file keeps the last good prescription (one log line).  One build at a time: a change during a
build starts another after it.  (The shim releases the GIL between its calls, so the worker runs.)

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

import json
import os
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from ..plumbing.errors import InputError, ValidationError

__all__ = ["LAYER_NAME", "DISABLE_ENV", "OFF_ENV", "LayerConfig", "Engine", "config_path", "log_path",
           "off_file", "eye_of_view", "read_config"]

LAYER_NAME = "XR_APILAYER_VRCORRECT_correction"
DISABLE_ENV = "DISABLE_VRCORRECT_LAYER"      # the manifest's disable_environment: the loader skips the layer
OFF_ENV = "VRCORRECT_LAYER_OFF"              # the engine's live off switch (the layer stays loaded)
CONFIG_ENV = "VRCORRECT_LAYER_CONFIG"
RX_ENV = "VRCORRECT_RX"
LOG_ENV = "VRCORRECT_LAYER_LOG"
GL_SRGB8_ALPHA8 = 0x8C43
GL_RGBA8 = 0x8058
_GL_FRAMEBUFFER_SRGB = 0x8DB9
_CHECK_INTERVAL_S = 0.25
_REPORT_INTERVAL_S = 1.0
_QUERY_MAX_MS = 0xFFFFFFFF / 1e6
_NEVER = object()

_COPY_SHADER = """
#version 430
#if defined VERTEX_SHADER
in vec2 in_pos;
void main() { gl_Position = vec4(in_pos, 0.0, 1.0); }
#elif defined FRAGMENT_SHADER
uniform sampler2D u_source;
uniform ivec2 u_offset;
uniform bool u_encode;
out vec4 f_color;
vec3 encode(vec3 c) {
    c = clamp(c, 0.0, 1.0);
    return mix(12.92 * c, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c));
}
void main() {
    vec4 texel = texelFetch(u_source, ivec2(gl_FragCoord.xy) + u_offset, 0);
    f_color = u_encode ? vec4(encode(texel.rgb), texel.a) : texel;
}
#endif
"""


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
    """``"left"`` for view 0, ``"right"`` for view 1 (``PRIMARY_STEREO``); other views are refused."""
    if view == 0:
        return "left"
    if view == 1:
        return "right"
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


def _stamp(path: Path) -> tuple[int, int] | None:
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_mtime_ns, st.st_size)


def choose_display(name: str | None, view_size: tuple[int, int]) -> tuple[Any, str]:
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


class Engine:
    """The layer's correction engine (module docstring).  ``view_width``/``view_height``: the
    runtime's recommended view size (0 when unknown); ``api``: the session's graphics API."""

    def __init__(self, view_width: int = 0, view_height: int = 0, api: str = "OpenGL",
                 env: Mapping[str, str] | None = None):
        self.env = os.environ if env is None else env
        self.log = _Log(log_path(self.env))
        self.view_size = (int(view_width), int(view_height))
        self.api = api
        self.ctx: Any = None
        self.correctors: dict[str, Any] = {}
        self.display: Any = None
        self.rx_path: Path | None = None
        self._rx_failed_stamp: Any = _NEVER          # the stamp of the prescription file that failed to build
        self._rx_stamp: Any = _NEVER                 # the stamp of the file the correctors were built from
        self._build_error: str | None = None
        self._job: _Build | None = None              # the eye models being built on the worker thread
        self._last_check = -1.0
        self._off_reason: str | None = None
        self._config: LayerConfig | None = None
        self._config_error: str | None = None
        self._textures: dict[tuple[int, int, int], Any] = {}
        self._staging: dict[tuple[int, int, str], Any] = {}
        self._copy = None
        self._copy_vao = None
        self._queries: dict[str, Any] = {}
        self._cpu_ms: dict[str, list[float]] = {}
        self._gpu_ms: dict[str, list[float | None]] = {}
        self._query_used: dict[str, list[bool]] = {}
        self._last_report = time.monotonic()
        self.frames = 0
        self.log.line(f"loaded ({api} session, runtime view size {view_width}x{view_height}, "
                      f"Python {sys.version.split()[0]})")

    # ------------------------------------------------------------ configuration and prescription

    def _check(self) -> str | None:
        """Re-read the off switch, the configuration and the prescription file's stamp (at most
        every 0.25 s), start a build when the file changed, install a finished one (every frame);
        returns the reason to pass through, or None (also while the first models build: no
        correctors yet, nothing to log)."""
        now = time.monotonic()
        if now - self._last_check < _CHECK_INTERVAL_S and self._last_check >= 0:
            self._finish_build()
            return self._off_reason or self._config_error or self._build_error
        self._last_check = now
        self._off_reason = _off(self.env)
        if self._off_reason:
            return self._off_reason
        try:
            config = read_config(self.env)
            self._config_error = None
        except (InputError, ValidationError) as exc:
            self._config_error = f"layer configuration: {exc}"
            return self._config_error
        if config != self._config:
            self._config = config
            self._release_correctors()
            self._rx_failed_stamp = self._rx_stamp = _NEVER
            self._build_error = None
        if config.rx is None:
            self._build_error = (f"no prescription: set rx in {config_path(self.env)} (vrcorrect layer install --rx) "
                                 f"or {RX_ENV}")
            return self._build_error
        self._finish_build()
        stamp = _stamp(config.rx)
        if self._job is None and stamp != self._rx_stamp and stamp != self._rx_failed_stamp:
            self._start_build(config)      # the same bad file is not rebuilt; a change during a build waits
        return None if self.correctors else self._build_error

    def _start_build(self, config: LayerConfig) -> None:
        """Build both eyes' models on a daemon thread (CPU: numpy, scipy)."""
        reload = bool(self.correctors)
        job = _Build(config, reload)
        if not reload:
            self._build_error = None
        self.log.line(f"building the eye models for {config.rx}" + (" (changed; correcting with the current "
                                                                    "ones meanwhile)" if reload else "") + " ...")
        job.thread = threading.Thread(target=job.run, args=(self.view_size,), daemon=True,
                                      name="vrcorrect-layer-build")
        self._job = job
        job.thread.start()

    def _finish_build(self) -> None:
        """On the application's thread: when the worker is done, make the Correctors from its
        models (GL resources only) and swap them in, or record why not."""
        job = self._job
        if job is None or job.thread is None or job.thread.is_alive():
            return
        self._job = None
        config = job.config
        if config != self._config:
            return                                   # built for an earlier configuration: a new build follows
        reload = bool(self.correctors)
        correctors: dict[str, Any] = {}
        error = job.error
        if error is None:
            from .corrector import Corrector

            try:
                for eye in ("left", "right"):
                    correctors[eye] = Corrector(self._gl(), job.snapshot, job.display, eye,
                                                eye_model=job.models[eye], **dict(config.options))
            except Exception as exc:  # noqa: BLE001  (every failure is a pass-through with its reason)
                error = exc
                for c in correctors.values():
                    try:
                        c.release()
                    except Exception:  # noqa: BLE001
                        pass
                correctors = {}
        stamp = job.snapshot.stamp if job.snapshot is not None else job.stamp
        if error is not None:
            self._rx_failed_stamp = stamp
            if reload:                               # an invalid edit keeps the last good prescription
                self.log.line(f"{config.rx}: not reloaded, keeping the last good prescription: {_one_line(error)}")
            else:
                self._build_error = f"prescription {config.rx}: {_one_line(error)}"
            return
        self._release_correctors()
        self.correctors, self.display, self.rx_path = correctors, job.display, config.rx
        self._rx_stamp = stamp
        self._rx_failed_stamp = _NEVER
        self._build_error = None
        seconds = time.perf_counter() - job.t0
        if reload:
            self.log.line(f"{config.rx}: reloaded (built in {seconds:.1f} s)")
        else:
            self.log.line(f"correcting with {config.rx} on display {job.display.name} ({job.why}); built in "
                          f"{seconds:.1f} s")

    def _gl(self) -> Any:
        if self.ctx is None:
            import moderngl

            ctx = moderngl.create_context()             # attaches to the application's current context
            if ctx.version_code < 430:
                raise ValidationError("OpenGL version", ctx.version_code, "4.3 or newer (compute shaders)")
            self.ctx = ctx
            self._copy = ctx.program(vertex_shader=_stage(_COPY_SHADER, "VERTEX_SHADER"),
                                     fragment_shader=_stage(_COPY_SHADER, "FRAGMENT_SHADER"))
            self._copy_vao = _triangle(ctx, self._copy)
        return self.ctx

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
            if self.ctx is None:
                self._gl()
            reason = self._check()
        except Exception as exc:  # noqa: BLE001
            reason = f"the engine could not start on this GL context: {_one_line(exc)}"
        if reason:
            self.log.reason(reason)
            return False
        return bool(self.correctors)             # none yet: the eye models are building (logged once)

    def correct(self, view_index: int, src_texture: int, src_format: int, src_width: int, src_height: int,
                x: int, y: int, width: int, height: int, dst_texture: int, view_in_layer: int = -1) -> bool:
        """Correct GL texture ``src_texture`` (an application swapchain image, ``src_format``,
        ``src_width`` x ``src_height``) over the rect (x, y, width, height; GL pixels, origin at the
        bottom left) into the same rect of ``dst_texture`` (the output image, same format and size).
        Returns False (with one log line) when it could not."""
        try:
            view = view_in_layer if view_in_layer >= 0 else view_index
            eye = eye_of_view(view)
            if src_format not in (GL_SRGB8_ALPHA8, GL_RGBA8):
                raise ValidationError("swapchain format", hex(src_format), "GL_SRGB8_ALPHA8 or GL_RGBA8")
            if width < 1 or height < 1 or x < 0 or y < 0 or x + width > src_width or y + height > src_height:
                raise ValidationError("imageRect", (x, y, width, height),
                                      f"inside the {src_width}x{src_height} swapchain image")
            ctx = self._gl()
            srgb = src_format == GL_SRGB8_ALPHA8
            src = self._external(src_texture, src_width, src_height, srgb)
            dst = self._external(dst_texture, src_width, src_height, srgb)
            codes = self._stage_texture(width, height, "f1")
            # the submitted rect, read as linear light (GL decodes an sRGB image; an RGBA8 image holds
            # linear light) and encoded to sRGB code values in the layer's own RGBA8 texture: for an
            # sRGB swapchain exactly the application's codes, what the Corrector decodes itself
            fb_in = self._framebuffer(codes)
            ctx.disable_direct(_GL_FRAMEBUFFER_SRGB)
            fb_in.use()
            fb_in.viewport = (0, 0, width, height)
            src.use(0)
            self._copy["u_source"] = 0
            self._copy["u_offset"] = (x, y)
            self._copy["u_encode"] = True
            self._copy_vao.render(mode=ctx.TRIANGLES, vertices=3)
            t0 = time.perf_counter()
            query = self._query(eye)
            with query:
                ctx.disable_direct(_GL_FRAMEBUFFER_SRGB)
                if srgb:
                    self.correctors[eye].apply(codes, self._framebuffer(dst), viewport=(x, y, width, height))
                else:
                    encoded = self._stage_texture(width, height, "srgb")
                    self.correctors[eye].apply(codes, self._framebuffer(encoded))
                    self._to_linear(encoded, dst, (x, y, width, height))
            error = ctx.error
            if error != "GL_NO_ERROR":
                raise RuntimeError(f"a GL error ({error}) during the correction")
            self._cpu_ms.setdefault(eye, []).append(1e3 * (time.perf_counter() - t0))
            return True
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"view {view_index}: {_one_line(exc)}")
            return False

    def end_frame(self, corrected: bool) -> None:
        """Per-frame bookkeeping: each eye's time, logged once a second.  GPU time comes from a
        timer query per eye and frame, read a frame later from a two-slot ring (no wait for the
        frame just issued); CPU time is the layer's own time in the call (issuing the work)."""
        try:
            if not corrected:
                return
            self.log.corrected()
            self.frames += 1
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
                self.log.line(f"{self.frames} frames corrected; per eye (mean of {count} frames): " + "; ".join(parts))
                self._cpu_ms.clear()
                self._gpu_ms.clear()
                self._last_report = now
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"timing: {_one_line(exc)}")

    # ------------------------------------------------------------ GL objects

    def _external(self, name: int, width: int, height: int, srgb: bool) -> Any:
        key = (int(name), width, height)
        tex = self._textures.get(key)
        if tex is None:
            tex = self.ctx.external_texture(int(name), (width, height), 4, 0, "f1")
            self._textures[key] = tex
        return tex

    def _stage_texture(self, width: int, height: int, kind: str) -> Any:
        key = (width, height, kind)
        tex = self._staging.get(key)
        if tex is None:
            ctx = self.ctx
            if kind == "srgb":
                tex = ctx.texture((width, height), 4, internal_format=GL_SRGB8_ALPHA8)
            else:
                tex = ctx.texture((width, height), 4, dtype=kind)
            tex.filter = (ctx.NEAREST, ctx.NEAREST)
            self._staging[key] = tex
        return tex

    def _framebuffer(self, texture: Any) -> Any:
        fb = getattr(texture, "_layer_fb", None)
        if fb is None:
            fb = self.ctx.framebuffer(color_attachments=[texture])
            texture._layer_fb = fb
        return fb

    def _to_linear(self, encoded: Any, dst: Any, rect: tuple[int, int, int, int]) -> None:
        """Sample the sRGB-encoded correction (GL decodes it) into the linear output image's rect."""
        fb = self._framebuffer(dst)
        fb.use()
        fb.viewport = rect
        encoded.use(0)
        self._copy["u_source"] = 0
        self._copy["u_offset"] = (-rect[0], -rect[1])
        self._copy["u_encode"] = False
        self._copy_vao.render(mode=self.ctx.TRIANGLES, vertices=3)

    def _query(self, eye: str) -> Any:
        """This frame's timer query for ``eye``; the slot's previous use (two frames ago) is read
        first (``None`` when it saturated: a 32-bit nanosecond count ends at 4.29 s)."""
        ring = self._queries.get(eye)
        if ring is None:
            ring = self._queries[eye] = [self.ctx.query(time=True), self.ctx.query(time=True)]
            self._query_used[eye] = [False, False]
        slot = self.frames % 2
        if self._query_used[eye][slot]:
            ns = ring[slot].elapsed
            self._gpu_ms.setdefault(eye, []).append(None if ns >= 0xFFFFFFFF else ns / 1e6)
        self._query_used[eye][slot] = True
        return ring[slot]

    def release_gl(self, current: bool = True) -> None:
        """Release every GL object (the session is going away); with ``current`` False (the
        session's context is not current) the objects are only forgotten, no GL call is made."""
        if current:
            self._release_correctors()
            objects = [*self._staging.values(), *(q for ring in self._queries.values() for q in ring),
                       self._copy_vao, getattr(self._copy_vao, "_layer_vbo", None), self._copy]
            objects += [getattr(t, "_layer_fb", None) for t in self._textures.values()]   # never the app's textures
            for obj in objects:
                for o in (getattr(obj, "_layer_fb", None), obj):
                    try:
                        if o is not None:
                            o.release()
                    except Exception:  # noqa: BLE001
                        pass
        self.correctors = {}
        self._textures.clear()
        self._staging.clear()
        self._queries.clear()
        self._query_used.clear()
        self._copy = self._copy_vao = None
        self.ctx = None
        self._config = None

    def close(self) -> None:
        self.log.line(f"closed after {self.frames} corrected frames")


class _Build:
    """One build of both eyes' models, run on a worker thread: the prescription file read once
    (:class:`~vrcorrect.runtime.corrector.RxSnapshot`), the display chosen, and
    :func:`~vrcorrect.runtime.eye_model.build_eye_model` per eye with the options a
    :class:`~vrcorrect.runtime.corrector.Corrector` computes from the same configuration (so its
    correction is the same as one that designs its own).  No GL; never raises (``error``)."""

    def __init__(self, config: LayerConfig, reload: bool):
        self.config, self.reload = config, reload
        self.stamp = _stamp(config.rx) if config.rx is not None else None
        self.thread: threading.Thread | None = None
        self.snapshot: Any = None
        self.display: Any = None
        self.why = ""
        self.models: dict[str, Any] = {}
        self.error: BaseException | None = None
        self.t0 = time.perf_counter()

    def run(self, view_size: tuple[int, int]) -> None:
        try:
            from .corrector import RxSnapshot
            from .eye_model import CorrectorOptions, build_eye_model

            options = dict(self.config.options)
            backend = options.pop("backend", "glsl")    # Corrector(backend=...) then CorrectorOptions(backend=...)
            opts = CorrectorOptions(backend=backend, **options)
            self.snapshot = RxSnapshot.read(self.config.rx)
            self.display, self.why = choose_display(self.config.display, view_size)
            for eye in ("left", "right"):
                rx = self.snapshot.prescription.eye(eye)
                # the eye as the Corrector designs it (its live offset is zero: the axis wraps into [0, 180))
                rx = rx.with_changes(sphere_D=rx.sphere_D + 0.0, cylinder_D=rx.cylinder_D + 0.0,
                                     axis_deg=(rx.axis_deg + 0.0) % 180.0)
                self.models[eye] = build_eye_model(rx, self.display, opts)
        except BaseException as exc:  # noqa: BLE001  (reported on the application's thread)
            self.error = exc


def _stage(source: str, stage: str) -> str:
    version, rest = source.strip().split("\n", 1)
    return f"{version}\n#define {stage}\n{rest}"


def _triangle(ctx: Any, program: Any) -> Any:
    import numpy as np

    vbo = ctx.buffer(np.array([-1, -1, 3, -1, -1, 3], dtype="f4").tobytes())
    vao = ctx.vertex_array(program, [(vbo, "2f", "in_pos")])
    vao._layer_vbo = vbo
    return vao


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
