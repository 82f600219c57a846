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
(view 0 the left eye, view 1 the right), with the copy passes around it
(:mod:`~vrcorrect.runtime.layer.pipeline`), built off the frame (:mod:`~vrcorrect.runtime.layer.builder`);
the configuration, the off switch and the log: :mod:`~vrcorrect.runtime.layer.config`; the Vulkan
side: :mod:`~vrcorrect.runtime.layer.vulkan`.

Layer 5: numpy and moderngl, never torch, never :mod:`vrcorrect.apps`.
"""

from __future__ import annotations

import contextlib
import math
import os
import queue
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator, Mapping

from ...plumbing.errors import InputError, ValidationError
from ...plumbing.fileio import file_stamp
from ..gaze import gaze_deg_of

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

    from ...specs.display import DisplayProfile
    from ..eye_source import EyeSource
from .builder import Builder, CaptureRequest
from .config import (
    _CHECK_INTERVAL_S,
    _NEVER,
    _REPORT_INTERVAL_S,
    CLOSE_WAIT_S,
    PRIME_MAX_FRAMES,
    RX_ENV,
    STALL_TRACE_ENV,
    LayerConfig,
    LayerLog,
    StallTrace,
    _off,
    config_path,
    eye_of_view,
    log_path,
    one_line,
    read_config,
)
from .interop import GL_FORMATS, QUERY_MAX_MS, VK_FORMATS, AppGlx, ChainMemory, SwapchainFormat, Target, check_rect
from .pipeline import Pipeline
from .vulkan import VulkanFrames

__all__ = ["Engine"]


class Engine(VulkanFrames):
    """The layer's correction engine (module docstring).  ``view_width``/``view_height``: the
    runtime's recommended view size (0 when unknown); ``api``: the session's graphics API
    (``"OpenGL"``: contexts that share the application's; ``"Vulkan"``: headless contexts of the
    engine's own)."""

    def __init__(self, view_width: int = 0, view_height: int = 0, api: str = "OpenGL",
                 env: Mapping[str, str] | None = None):
        self.env = os.environ if env is None else env
        self.log = LayerLog(log_path(self.env))
        self.view_size = (int(view_width), int(view_height))
        self.api = api
        self.pipeline: Pipeline | None = None
        self.glx_binding: tuple[int, int, int] | None = None   # OpenGL: the application's Display*, FBConfig, context
        self.program_cache: Path | None | bool = None            # the program cache's folder (None: the default)
        self.display: DisplayProfile | None = None
        self.rx_path: Path | None = None
        self._rx_failed_stamp: Any = _NEVER          # the stamp of the prescription file that failed to build
        self._build_error: str | None = None
        self._source: EyeSource | None = None        # watches the prescription, designs the eye models
        self._builder: Builder | None = None        # builds the pipelines off the application's thread
        self._let_go: list[Any] = []                 # sources and builders let go without waiting; joined by close()
        self._last_check = -1.0
        self._off_reason: str | None = None
        self._config: LayerConfig | None = None
        self._config_error: str | None = None
        self._app_glx: AppGlx | None = None
        self._targets: dict[Any, set[Target]] = {}  # per swapchain (and the rects seen): what a pipeline prepares
        self._targets_lock = threading.Lock()
        self._asked: set[Target] = set()             # targets a rebuild was asked for
        self._chains: dict[int, ChainMemory] = {}
        self.capture: CaptureRequest | None = None  # set by the builder: the next frame's views, please
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
        self._stall = StallTrace(self.env.get(STALL_TRACE_ENV))     # off unless asked for
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
        """A :class:`Builder` for ``config``: on its own thread it opens the
        :class:`~vrcorrect.runtime.eye_source.EyeSource` (the modules it needs are imported there, not
        on the application's thread) and takes its models, or the cached ones; frames pass through
        meanwhile."""
        self.log.line(f"building the eye models for {config.rx} ...")
        self._build_error = None
        self._t0 = time.perf_counter()
        self._builder = Builder(self, config, file_stamp(config.rx))

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

    def _install(self, pipeline: Pipeline, info: Mapping[str, Any]) -> None:
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
            text = f"the Vulkan application's images cannot be shared with the engine's GL: {one_line(exc)}"
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
            if pipeline.light_pupils:
                primed += "; designed for the light's pupil while priming: " + ", ".join(
                    f"{mm:.2f} mm ({eye})" for eye, mm in pipeline.light_pupils.items())
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
        text = one_line(error) if isinstance(error, BaseException) else error
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

    def _drop_events(self, builder: Builder) -> None:
        """Release the pipelines a builder posted that were not taken."""
        while True:
            try:
                event = builder.events.get_nowait()
            except queue.Empty:
                return
            if event[0] == "pipeline":
                self._release(event[1])

    @contextlib.contextmanager
    def _current(self, pipeline: Pipeline) -> Iterator["moderngl.Context"]:
        """``pipeline``'s context current on this thread for the block; what was current before comes
        back after (OpenGL: the application's context)."""
        if self.api == "OpenGL":
            if self._app_glx is None:
                self._app_glx = AppGlx()
            with self._app_glx.engine_current(pipeline.loader.inner):
                yield pipeline.ctx
        else:
            with pipeline.ctx:
                yield pipeline.ctx

    def _release(self, pipeline: Pipeline) -> None:
        """Release ``pipeline`` with its context current on this thread (what was current comes back)."""
        loader = pipeline.loader
        try:
            if self.api == "OpenGL":
                if self._app_glx is None:
                    self._app_glx = AppGlx()
                with self._app_glx.engine_current(loader.inner):
                    pipeline.release()
            else:
                loader.__enter__()
                try:
                    pipeline.release()
                finally:
                    loader.inner.__exit__()          # (the moderngl context is gone: its loader's context)
        except Exception as exc:  # noqa: BLE001
            self.log.line(f"releasing a pipeline: {one_line(exc)}")

    def _release_pipeline(self) -> None:
        if self.pipeline is not None:
            old, self.pipeline = self.pipeline, None
            self._release(old)

    # ------------------------------------------------------------ frames

    def begin_frame(self) -> int:
        """What the shim does with this frame: 1 correct it, 0 pass it through (the reason is logged
        once), 2 hand its views to :meth:`capture_gl`/:meth:`capture_vulkan` and pass it through (the
        first pipeline is being built and primes itself on them).  The stall trace watches the frame
        from here to :meth:`end_frame`, or to here alone where it passes through."""
        if said := self._stall.arm(self.frames):
            self.log.line(said)
        mode = self._mode()
        if mode == 0:                            # no end_frame for this one
            self._stall_said()
        return mode

    def _stall_said(self) -> None:
        if said := self._stall.disarm():
            if self.pipeline is not None:
                said += f"; each eye's longest pass call in its last correction: {self.pipeline.longest_calls()}"
            self.log.line(said)

    def _mode(self) -> int:
        try:
            reason = self._check()
        except Exception as exc:  # noqa: BLE001
            reason = f"the engine could not start: {one_line(exc)}"
        if reason:
            self.log.reason(reason)
            return 0
        if self.pipeline is not None:
            self._waited_ready = False
            return 3 if self.pipeline.semaphores is not None else 1
        request = self.capture                   # none yet: the models or the pipeline are being built
        return 2 if request is not None and not request.ready.is_set() else 0

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
            check_rect(x, y, width, height, src_width, src_height)
            if self._app_glx is None:
                self._app_glx = AppGlx()
            self._add_capture({"eye": eye, "code": int(src_format), "texture": int(src_texture),
                               "rect": (int(x), int(y), int(width), int(height)), "fence": self._app_glx._fence()})
            return True
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"view {view_index}: {one_line(exc)}")
            return False

    def _announce(self, fmt: SwapchainFormat) -> None:
        if fmt.encoding == "float" and fmt.name not in self._announced:
            self._announced.add(fmt.name)
            self.log.line(f"{fmt.name} swapchain (linear light): the correction works on values in [0, 1]; the "
                          "part of each value outside [0, 1] is carried through uncorrected")

    def _timed(self, pipeline: Pipeline, eye: str) -> Any:
        query, previous = pipeline.query(eye, self.frames)
        if previous is not False:
            self._gpu_ms.setdefault(eye, []).append(previous)    # type: ignore[arg-type]
        return query

    def _state_lines(self) -> list[str]:
        """``budget: left ...; right ...``: what each eye's frame budget chose, and ``pupil: left ...;
        right ...``: each eye's viewing pupil with ``pupil="auto"`` (none where there is nothing to say)."""
        p = self.pipeline
        if p is None:
            return []
        eyes = sorted(p.correctors.items())
        budgets = [f"{eye} {c.budget.describe()}" for eye, c in eyes if c.budget is not None]
        pupils = [f"{eye} {c.pupil_status}" for eye, c in eyes if c.pupil_status]
        return ((["budget: " + "; ".join(budgets)] if budgets else []) +
                (["pupil: " + "; ".join(pupils)] if pupils else []))

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

    def _aim(self, pipeline: "Pipeline", eye: str, width: int, height: int) -> None:
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
            check_rect(x, y, width, height, src_width, src_height)
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
            self.log.reason(f"view {view_index}: {one_line(exc)}")
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
            self.log.reason(f"forgetting a swapchain's textures: {one_line(exc)}")

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
        self._stall_said()
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
                    gpu_text = (f">{QUERY_MAX_MS:.0f}" if saturated else
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
                for words in self._state_lines():
                    self.log.line(words)
                self._cpu_ms.clear()
                self._gpu_ms.clear()
                self._sync_ms.clear()
                self._frame_ms.clear()
                self._last_report = now
        except Exception as exc:  # noqa: BLE001
            self.log.reason(f"timing: {one_line(exc)}")

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
        self._stall.close()
        self.log.line(f"closed after {self.frames} corrected frames")
