"""The headset path: an OpenXR session through pyopenxr, each eye corrected before it is
submitted (``vrcorrect xr``, whose command line is :mod:`vrcorrect.apps.xr`).

The OpenXR instance enables ``XR_KHR_opengl_enable``; the OpenGL context is a GLFW window's
(X11/GLX: the session is bound with ``XrGraphicsBindingOpenGLXlibKHR``; the window is hidden
unless ``--mirror`` shows both eyes in it). One swapchain per view, in ``GL_SRGB8_ALPHA8``
when the runtime offers it (else ``GL_RGBA8``, see
:func:`~vrcorrect.runtime.shell.xr.session.choose_swapchain_format`). Each frame: ``xrWaitFrame``, ``xrBeginFrame``, and when the runtime says the frame should be
rendered, ``xrLocateViews``, the source renders each eye (the demo scene from that eye's
tracked pose and field of view, or a picture source: image, animated image, folder, video,
screen region), each eye's :class:`~vrcorrect.runtime.corrector.Corrector` writes the
corrected image straight into the acquired swapchain image (a framebuffer around the
runtime's GL texture), and ``xrEndFrame`` submits one projection layer.

The session's life cycle is :class:`~vrcorrect.runtime.shell.xr.session.SessionTracker`'s
(pure, in :mod:`~vrcorrect.runtime.shell.xr.session`, with the configuration and the summary).

No OpenXR runtime installed: :class:`~vrcorrect.plumbing.errors.XrUnavailableError`, one
paragraph saying what is missing and how to get one (``vrcorrect mirror`` works without), exit
status :data:`~vrcorrect.runtime.shell.xr.session.EXIT_NO_RUNTIME` (the instance's creation:
:mod:`~vrcorrect.runtime.shell.xr.instance`).

With an iterative method (``--filter admm``, the default, or ``fista``) each eye runs its iterations
spread over frames; in the
``--mirror`` window ``[`` / ``]`` halve / double the iterations per frame live, and the window's
title shows them with each eye's objective as a fraction of uncorrected (read a frame late, no
wait for the GPU); the run's summary gives the median objective per eye.

Tests drive it against a small runtime compiled from ``tests/xr_runtime/`` (no headset).
Layer 5: numpy, moderngl, glfw, pyopenxr; never torch.
"""

from __future__ import annotations

import ctypes
import signal
import threading
import time
from types import FrameType
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from ....plumbing.errors import XrSessionError
from ....specs.vocabulary import VIEW_ORDER
from ...corrector import Corrector, runs_iterations
from ...gaze import gaze_deg_of, gaze_in_view
from ...gl import check_gl_errors, fullscreen_triangle, release
from ...motion import view_shift
from ...optional import require_moderngl, require_xr
from ...shaders import compile_program
from ..keys import GLFW_PRESS, MOD_ALT, MOD_CONTROL, MOD_SUPER, change_iterations, iteration_key, knob_text
from ..scene import DemoScene, open_source
from ..source_spec import parse_region, parse_source
from ..sources import PictureFeed, ScreenSource, screen_bounds, start_motion, take_motion
from ..timing import StageTimes
from ..window import WindowApp
from .gaze import EXTENSION as GAZE_EXTENSION
from .gaze import EyeTracker, tracker_offered

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

from .instance import address, create_instance, find_system, quietly
from .session import (
    EXIT_GRACE_S,
    FORMAT_NAMES,
    GL_RGBA8,
    GL_SRGB8_ALPHA8,
    SESSION_STATES,
    XR_CPU_ONLY_STAGES,
    XR_STAGES,
    SessionTracker,
    XrConfig,
    XrRunSummary,
    choose_swapchain_format,
)
from .views import projection_from_fov, view_matrix

__all__ = ["XrApp"]

_GL_FRAMEBUFFER_SRGB = 0x8DB9


class XrApp(WindowApp):
    """The headset application (see the module docstring). Use as a context manager or call
    :meth:`close`; :meth:`run` runs the session and returns an :class:`XrRunSummary`.

    Raises (from the constructor)
    -----------------------------
    XrUnavailableError
        No OpenXR runtime, or no headset.
    InputError, ValidationError
        Bad prescription, display or source (checked before anything is opened).
    GLUnavailableError
        No X11 display or no OpenGL 4.3 context.
    XrSessionError
        The runtime refused a call while setting up.
    """

    def __init__(self, config: XrConfig = XrConfig(), *, echo: Callable[[str], None] | None = print):
        super().__init__(echo)
        self.config = config
        self._read_inputs(config.rx, config.display)  # read once for both eyes; a bad file fails here
        self.spec = None if config.source == "screen" else parse_source(config.source)
        self.region = parse_region(config.region) if config.region is not None else None
        self.xr = xr = require_xr()
        # a session or instance on its way out: pyopenxr raises the qualified success too
        self._lost_errors = (xr.SessionLostError, xr.InstanceLostError, xr.SessionLossPending)
        self.tracker = SessionTracker()
        self.eye_tracker: EyeTracker | None = None      # with --fovea, where the runtime offers one
        self._gaze_extension = False
        self.summary = XrRunSummary()
        self.instance = self.system_id = self.session = self.space = None
        self.swapchains: list[dict[str, Any]] = []
        self.correctors: dict[str, Corrector] = {}
        self.source: PictureFeed | None = None
        self._times: StageTimes | None = None
        self._mirror_prog = self._mirror_vao = self._convert_prog = self._convert_vao = None
        self._sampler = None
        self._quit_reason: str | None = None
        self._interrupts = 0
        self._exit_requested_at: float | None = None
        self._last_poll = 0.0
        self._first_display_time: int | None = None
        self._rendered_pending = False
        self._last_views: dict[str, np.ndarray] = {}    # each eye's view matrix at its last frame
        try:
            self._create_instance()
            self._open_gl_window()
            self._create_session()
            self._start_eye_tracker()
            self._build()
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------ set-up

    def _call(self, what: str, fn: Callable[..., Any], *args: Any) -> Any:
        """Run a pyopenxr call; its failures become :class:`XrSessionError` naming the call."""
        xr = self.xr
        try:
            return fn(*args)
        except self._lost_errors:
            raise
        except xr.XrException as exc:
            raise XrSessionError(f"{what} failed: {type(exc).__name__}: {exc}") from None

    def _create_instance(self) -> None:
        extensions = ["XR_KHR_opengl_enable"] + ([GAZE_EXTENSION] if self._wants_gaze() else [])
        self.instance, self.summary.runtime = create_instance(self.xr, self.config, extensions, self.say)
        found = find_system(self.xr, self.instance, self.summary.runtime, self._call)
        self.system_id, self.summary.system, self.gl_requirements = found.system_id, found.name, found.gl_requirements
        self.eye_size = self.summary.eye_size = found.eye_size

    def _wants_gaze(self) -> bool:
        """A fovea asks for the eye tracker where the runtime offers one."""
        self._gaze_extension = self.config.corrector_options.fovea_deg is not None and tracker_offered(self.xr)
        return self._gaze_extension

    def _start_eye_tracker(self) -> None:
        """With ``--fovea``: the eye tracker's action, or one line on why the window stays at ``--gaze``."""
        if self.config.corrector_options.fovea_deg is None:
            return
        at = "the fovea's window stays at --gaze {0:g},{1:g}".format(*self.config.corrector_options.gaze_deg)
        if not self._gaze_extension:
            self.summary.gaze = f"the runtime offers no eye tracker ({GAZE_EXTENSION}): {at}"
        else:
            try:
                self.eye_tracker = EyeTracker(self.xr, self.instance, self.system_id, self.session)
            except self.xr.XrException as exc:
                self.summary.gaze = f"the eye tracker's action failed ({type(exc).__name__}): {at}"
            else:
                self.summary.gaze = (f"{self.eye_tracker.why_not}: {at}" if self.eye_tracker.why_not else
                                     f"following the eye tracker ({GAZE_EXTENSION}); frames without a gaze: --gaze")
        self.say("gaze: " + self.summary.gaze)

    def _aim(self, views: Sequence[Any], display_time: int) -> None:
        """Place each eye's fovea where the tracked gaze crosses its view (or at ``--gaze``)."""
        gaze = self.eye_tracker.locate(self.space, display_time) if self.eye_tracker is not None else None
        for eye, v in zip(VIEW_ORDER, views):
            corrector = self.correctors[eye]
            o = v.pose.orientation
            uv = None if gaze is None else gaze_in_view(
                gaze, (o.x, o.y, o.z, o.w), (v.fov.angle_left, v.fov.angle_right, v.fov.angle_up, v.fov.angle_down))
            corrector.gaze_deg = (corrector.options.gaze_deg if uv is None else
                                  gaze_deg_of(uv, self.eye_size, corrector.display.pixels_per_degree))
            if uv is not None:
                self.summary.gazes.setdefault(eye, []).append(corrector.gaze_deg)
        if gaze is not None:
            self.summary.tracked_frames += 1

    def _open_gl_window(self) -> None:
        cfg = self.config
        w, h = self.eye_size
        mh = min(cfg.mirror_height, h)
        self.mirror_size = (2 * max(1, round(w * mh / h)), mh)
        title = f"vrcorrect xr mirror: what each eye is sent ({self.summary.system})"
        self._title = title
        self._open_window(*(self.mirror_size if cfg.mirror else (64, 64)), title,
                          platform="x11", visible=cfg.mirror, vsync=False)  # the session binding is Xlib/GLX
        self.summary.renderer = self.ctx.info.get("GL_RENDERER", "?")
        major, minor = self.ctx.version_code // 100, self.ctx.version_code % 100 // 10
        req = self.gl_requirements
        have = (major << 48) | (minor << 32)
        if have < int(req.min_api_version_supported):
            raise XrSessionError(f"OpenGL {major}.{minor} is older than the runtime's minimum "
                                 f"{int(req.min_api_version_supported) >> 48}.{(int(req.min_api_version_supported) >> 32) & 0xFFFF}")

    def _create_session(self) -> None:
        xr, glfw = self.xr, self.glfw
        glfw.make_context_current(self.window)
        display = glfw.get_x11_display()
        context = glfw.get_glx_context(self.window)
        drawable = glfw.get_glx_window(self.window)
        binding = xr.GraphicsBindingOpenGLXlibKHR()
        fields = dict(binding._fields_)
        binding.x_display = ctypes.cast(ctypes.c_void_p(address(display)), fields["x_display"])
        binding.glx_context = ctypes.cast(ctypes.c_void_p(address(context)), fields["glx_context"])
        binding.glx_drawable = int(drawable)
        self._binding = binding  # kept alive for the session
        info = xr.SessionCreateInfo(system_id=self.system_id,
                                    next=ctypes.cast(ctypes.pointer(binding), ctypes.c_void_p))
        self.session = self._call("xrCreateSession", xr.create_session, self.instance, info)
        self.space = self._call("xrCreateReferenceSpace", xr.create_reference_space, self.session,
                                xr.ReferenceSpaceCreateInfo(reference_space_type=xr.ReferenceSpaceType.LOCAL))
        formats = self._call("xrEnumerateSwapchainFormats", xr.enumerate_swapchain_formats, self.session)
        self.format = choose_swapchain_format(formats)
        self.summary.swapchain_format = FORMAT_NAMES[self.format]
        w, h = self.eye_size
        for eye in VIEW_ORDER:  # view 0 is the left eye in PRIMARY_STEREO
            handle = self._call("xrCreateSwapchain", xr.create_swapchain, self.session, xr.SwapchainCreateInfo(
                usage_flags=xr.SwapchainUsageFlags.COLOR_ATTACHMENT_BIT | xr.SwapchainUsageFlags.SAMPLED_BIT,
                format=self.format, sample_count=1, width=w, height=h, face_count=1, array_size=1, mip_count=1))
            chain = {"eye": eye, "handle": handle, "textures": [], "framebuffers": []}
            self.swapchains.append(chain)
            images = self._call("xrEnumerateSwapchainImages", xr.enumerate_swapchain_images, handle,
                                xr.SwapchainImageOpenGLKHR)
            for image in images:
                tex = self.ctx.external_texture(int(image.image), (w, h), 4, 0, "f1")
                chain["textures"].append(tex)
                chain["framebuffers"].append(self.ctx.framebuffer(color_attachments=[tex]))

    def _build(self) -> None:
        cfg, ctx = self.config, self.ctx
        w, h = self.eye_size
        ctx.disable_direct(_GL_FRAMEBUFFER_SRGB)  # sRGB swapchains store the corrector's codes as they are
        if self.spec is None:
            self.source = ScreenSource(ctx, w, h, self.region or screen_bounds())
        else:
            self.source = open_source(ctx, self.spec, w, h, folder_interval_s=cfg.folder_interval_s)
        self._start_eyes(ctx, VIEW_ORDER, cfg.corrector_options, first=dict(zip(VIEW_ORDER, self.source.render(0.0))))
        if not isinstance(self.source, DemoScene):     # a head-locked picture source
            start_motion(self.source, self.correctors.values(), cfg.reprojection)
        if self.format == GL_RGBA8:
            # correct into an sRGB texture; sampling it decodes to linear light, written into the linear swapchain
            self._staging = ctx.texture((w, h), 4, internal_format=GL_SRGB8_ALPHA8)
            self._staging_fb = ctx.framebuffer(color_attachments=[self._staging])
            self._convert_prog = compile_program(ctx, "passthrough.glsl")
            self._convert_vao = fullscreen_triangle(ctx, self._convert_prog)
        else:
            self._staging = self._staging_fb = None
        if cfg.mirror:
            # sampling either swapchain format gives linear light: encode it for the window
            self._mirror_prog = compile_program(ctx, "passthrough.glsl", defines={"ENCODE_SRGB": None})
            self._mirror_vao = fullscreen_triangle(ctx, self._mirror_prog)
        self._times = StageTimes(ctx, XR_STAGES, cpu_only=XR_CPU_ONLY_STAGES)
        check_gl_errors(ctx, "xr set-up")

    # ------------------------------------------------------------ events

    def key_callback(self, window: Any, key: int, scancode: int, action: int, mods: int) -> None:
        """GLFW key callback of the mirror window: ``[`` / ``]`` halve / double the iterations per
        frame of both eyes (iterative methods); presses only, without Control, Alt or Super."""
        knob = iteration_key(key)
        if action != GLFW_PRESS or knob is None or mods & (MOD_CONTROL | MOD_ALT | MOD_SUPER):
            return
        self.say(change_iterations(self.correctors.values(), knob.up))
        self._last_poll = 0.0                   # the title shows it at the next frame

    def knob_text(self) -> str | None:
        """Iterations per frame and each eye's objective as a fraction of uncorrected (a frame late),
        or None without an iterative method."""
        return knob_text(self.correctors, self.eye_size)

    def request_quit(self, reason: str) -> None:
        """Ask the loop to end the session (thread- and signal-safe: only sets flags)."""
        if self._quit_reason is None:
            self._quit_reason = reason

    def _on_sigint(self, signum: int, frame: FrameType | None) -> None:
        self._interrupts += 1
        self.request_quit("interrupted")

    def _poll_events(self) -> str | None:
        """Handle every queued event; returns ``"exit"`` or ``"lost"`` when the loop must stop."""
        xr = self.xr
        while True:
            try:
                buffer = xr.poll_event(self.instance)
            except xr.EventUnavailable:
                return None
            except self._lost_errors:
                return "lost"
            kind = xr.StructureType(buffer.type)
            if kind == xr.StructureType.EVENT_DATA_INSTANCE_LOSS_PENDING:
                self.say("the runtime is going away (instance loss pending)")
                return "lost"
            if kind != xr.StructureType.EVENT_DATA_SESSION_STATE_CHANGED:
                continue
            event = ctypes.cast(ctypes.byref(buffer), ctypes.POINTER(xr.EventDataSessionStateChanged)).contents
            state = SESSION_STATES[int(event.state)] if 0 <= int(event.state) < len(SESSION_STATES) else "UNKNOWN"
            self.say(f"session state: {state}")
            action = self.tracker.on_state(state)
            if action == "begin":
                self._call("xrBeginSession", xr.begin_session, self.session, xr.SessionBeginInfo(
                    primary_view_configuration_type=xr.ViewConfigurationType.PRIMARY_STEREO))
                self.tracker.began()
            elif action == "end":
                self._call("xrEndSession", xr.end_session, self.session)
                self.tracker.ended()
            elif action in ("exit", "lost"):
                return action

    # ------------------------------------------------------------ frames

    def _views(self, display_time: int):
        xr = self.xr
        state, views = self._call("xrLocateViews", xr.locate_views, self.session, xr.ViewLocateInfo(
            view_configuration_type=xr.ViewConfigurationType.PRIMARY_STEREO, display_time=display_time,
            space=self.space))
        flags = int(state.view_state_flags)
        valid = int(xr.ViewStateFlags.ORIENTATION_VALID_BIT) | int(xr.ViewStateFlags.POSITION_VALID_BIT)
        return (views if (flags & valid) == valid and len(views) == 2 else None)

    def _scene_time(self, display_time: int) -> float:
        if self.config.time_step_s is not None:
            return self.summary.frames * self.config.time_step_s
        if self._first_display_time is None:
            self._first_display_time = display_time
        return (display_time - self._first_display_time) / 1e9

    def _frame(self) -> None:
        xr, ctx, times = self.xr, self.ctx, self._times
        self._collect_times()  # the previous frame's GPU times: ready by now, nothing waits
        t_frame = time.perf_counter()
        with times.stage("wait"):
            frame_state = self._call("xrWaitFrame", xr.wait_frame, self.session)
        with times.stage("begin"):
            self._call("xrBeginFrame", xr.begin_frame, self.session)
        layers = []
        views = None
        if frame_state.should_render:
            with times.stage("locate"):
                views = self._views(frame_state.predicted_display_time)
                if views is not None and self.config.corrector_options.fovea_deg is not None:
                    self._aim(views, frame_state.predicted_display_time)      # the eye tracker's gaze
        if views is not None:
            t_s = self._scene_time(frame_state.predicted_display_time)
            motions: dict[str, tuple[int, int] | None] = {}
            with times.stage("scene"):
                if isinstance(self.source, DemoScene):  # the demo scene: from each tracked eye
                    eye_views = {}
                    for eye, v in zip(VIEW_ORDER, views):
                        o, p = v.pose.orientation, v.pose.position
                        vm = view_matrix((o.x, o.y, o.z, o.w), (p.x, p.y, p.z))
                        proj = projection_from_fov(v.fov.angle_left, v.fov.angle_right, v.fov.angle_up,
                                                   v.fov.angle_down)
                        eye_views[eye] = (proj @ vm, np.array([p.x, p.y, p.z]))
                        motions[eye] = self._head_motion(eye, vm, proj)
                    textures = self.source.render(t_s, views=eye_views)
                else:
                    textures = self.source.render(t_s)
                    motion = take_motion(self.source, self.correctors.values())
                    motions = {eye: motion for eye in VIEW_ORDER}
            w, h = self.eye_size
            indices = []
            with times.stage("acquire"):
                for chain in self.swapchains:
                    index = self._call("xrAcquireSwapchainImage", xr.acquire_swapchain_image, chain["handle"])
                    self._call("xrWaitSwapchainImage", xr.wait_swapchain_image, chain["handle"],
                               xr.SwapchainImageWaitInfo(timeout=xr.INFINITE_DURATION))
                    indices.append(index)
            for chain, index, texture in zip(self.swapchains, indices, textures):
                eye = chain["eye"]
                target = chain["framebuffers"][index]
                with times.stage(f"correct {eye}"):
                    self.correctors[eye].apply(texture, self._staging_fb or target, motion_px=motions.get(eye))
                if self._staging_fb is not None:
                    with times.stage("convert"):
                        self._staging.use(0)
                        self._convert_prog["u_source"].value = 0
                        target.use()
                        ctx.viewport = (0, 0, w, h)
                        self._convert_vao.render(vertices=3)
            if self.config.mirror:
                with times.stage("mirror"):
                    self._draw_mirror([c["textures"][i] for c, i in zip(self.swapchains, indices)])
            with times.stage("release"):
                for chain in self.swapchains:
                    self._call("xrReleaseSwapchainImage", xr.release_swapchain_image, chain["handle"])
            projection_views = []
            for chain, v in zip(self.swapchains, views):
                projection_views.append(xr.CompositionLayerProjectionView(
                    pose=v.pose, fov=v.fov, sub_image=xr.SwapchainSubImage(
                        swapchain=chain["handle"], image_rect=xr.Rect2Di(extent=xr.Extent2Di(w, h)))))
            layer = xr.CompositionLayerProjection(space=self.space, views=projection_views)
            layers = [ctypes.byref(layer)]
        with times.stage("end"):
            self._call("xrEndFrame", xr.end_frame, self.session, xr.FrameEndInfo(
                display_time=frame_state.predicted_display_time,
                environment_blend_mode=xr.EnvironmentBlendMode.OPAQUE, layers=layers))
        self.summary.frames_total += 1
        if layers:
            if self.config.mirror:
                self.glfw.swap_buffers(self.window)
            self.summary.frames += 1
            self.summary.frame_ms.append(1e3 * (time.perf_counter() - t_frame))
            self._rendered_pending = True
            frames = self.config.frames
            if frames is not None and self.summary.frames >= frames:
                self.request_quit("frames")

    def _head_motion(self, eye: str, view: np.ndarray, projection: np.ndarray) -> tuple[int, int] | None:
        """The demo scene's content shift for ``eye`` since its last frame, from the change of its
        tracked orientation (``None`` without ``reprojection``: the plain warm start); a turn that
        leaves nothing of the last view in sight resets the eye's iterations (a cold start)."""
        previous, self._last_views[eye] = self._last_views.get(eye), view
        corrector = self.correctors[eye]
        if not self.config.reprojection or previous is None or not runs_iterations(corrector):
            return None
        shift = view_shift(previous, view, projection, self.eye_size)
        w, h = self.eye_size
        if shift is None or abs(shift[0]) >= w or abs(shift[1]) >= h:
            corrector.reset()
            return None
        return shift

    def _collect_times(self) -> None:
        """Collect the last frame's stage times into the summary when it was rendered."""
        values = self._times.collect()          # GPU None where the query holds no time (gl.timer_query_ms)
        if self._rendered_pending:
            for name, value in values.items():
                self.summary.stage_ms.setdefault(name, []).append(value)
            for eye, corrector in self.correctors.items():
                fraction = corrector.previous_objective_fraction(self.eye_size)   # no wait for the GPU
                if fraction is not None:
                    self.summary.objective.setdefault(eye, []).append(fraction)
        self._rendered_pending = False

    def _draw_mirror(self, textures: Sequence["moderngl.Texture"]) -> None:
        moderngl = require_moderngl()
        ctx = self.ctx
        screen = ctx.screen
        screen.use()
        width, height = self._session.framebuffer_size
        half = width // 2
        if self._sampler is None:
            self._sampler = ctx.sampler(filter=(moderngl.LINEAR, moderngl.LINEAR), repeat_x=False, repeat_y=False)
        self._mirror_prog["u_source"].value = 0
        for i, tex in enumerate(textures):
            ctx.viewport = (i * half, 0, half, height)
            self._sampler.use(0)
            tex.use(0)
            self._mirror_vao.render(vertices=3)
        self._sampler.clear(0)

    def _poll_files(self) -> None:
        updates, messages = self._poll_eyes()             # installs what the worker designed; never waits
        for u in updates:
            self.say(f"{self.rx_path.name} reloaded: {u.eye} eye rebuilt")
        for message in messages:
            self.say(message)                              # e.g. an invalid edit: the last good Rx is kept
        now = time.monotonic()
        if now - self._last_poll < 1.0:
            return
        self._last_poll = now
        knob = self.knob_text()
        if knob and self.config.mirror and self.window is not None:
            self.glfw.set_window_title(self.window, f"{self._title}   {knob}")

    def run(self, *, handle_sigint: bool = True) -> XrRunSummary:
        """Run the session until it ends (see the module docstring); returns the summary."""
        xr = self.xr
        previous = None
        if handle_sigint and threading.current_thread() is threading.main_thread():
            previous = signal.signal(signal.SIGINT, self._on_sigint)
        glfw = self.glfw
        try:
            while True:
                try:
                    outcome = self._poll_events()
                except self._lost_errors:
                    outcome = "lost"
                if outcome == "exit":
                    self.summary.reason = self._quit_reason or "runtime"
                    break
                if outcome == "lost":
                    self.summary.reason = "session lost"
                    break
                glfw.poll_events()
                if self.config.mirror and glfw.window_should_close(self.window):
                    self.request_quit("window closed")
                if self._quit_reason is not None:
                    if self._interrupts > 1:
                        self.summary.reason = "interrupted"
                        break
                    if self.tracker.running and self._exit_requested_at is None:
                        self.say(f"ending the session ({self._quit_reason}) ...")
                        self._call("xrRequestExitSession", xr.request_exit_session, self.session)
                        self._exit_requested_at = time.monotonic()
                    elif not self.tracker.running and self._exit_requested_at is None:
                        self.summary.reason = self._quit_reason  # never began: nothing to end
                        break
                    elif self._exit_requested_at is not None \
                            and time.monotonic() - self._exit_requested_at > EXIT_GRACE_S:
                        self.say(f"the runtime did not end the session within {EXIT_GRACE_S:g} s; leaving")
                        self.summary.reason = "no exit"
                        break
                if self.tracker.running:
                    try:
                        self._frame()
                    except self._lost_errors:
                        self.summary.reason = "session lost"
                        break
                    self._poll_files()
                    check_gl_errors(self.ctx, f"xr frame {self.summary.frames_total}")
                else:
                    time.sleep(0.005)
        finally:
            if previous is not None:
                signal.signal(signal.SIGINT, previous)
            self.summary.states = list(self.tracker.history)
            if self._times is not None and self.ctx is not None:
                self._collect_times()
            iterating = [c for c in self.correctors.values() if runs_iterations(c)]
            ks = {c.iterations_per_frame for c in iterating}
            self.summary.iterations_per_frame = ks.pop() if len(ks) == 1 else None
            self.summary.method = "/".join(sorted({c.options.filter for c in iterating}))
        return self.summary

    # ------------------------------------------------------------ tear-down

    def close(self) -> None:
        """Destroy swapchains, space, session and instance; release GL objects; close the window."""
        xr = getattr(self, "xr", None)
        if self.ctx is not None:
            for c in self.correctors.values():
                c.release()
            self.correctors = {}
            if self.source is not None:
                self.source.release()
                self.source = None
            release(getattr(self, "_staging_fb", None), getattr(self, "_staging", None), self._convert_vao,
                    self._convert_prog, self._mirror_vao, self._mirror_prog, self._sampler)
            self._staging_fb = self._staging = self._convert_vao = self._convert_prog = None
            self._mirror_vao = self._mirror_prog = self._sampler = None
            for chain in self.swapchains:
                release(*chain["framebuffers"])  # the textures are the runtime's: not deleted here
        if self.eye_tracker is not None:
            self.eye_tracker.close()
            self.eye_tracker = None
        if xr is not None:
            for chain in self.swapchains:
                quietly(xr.destroy_swapchain, chain["handle"])
            self.swapchains = []
            if self.space is not None:
                quietly(xr.destroy_space, self.space)
                self.space = None
            if self.session is not None:
                quietly(xr.destroy_session, self.session)
                self.session = None
            if self.instance is not None:
                quietly(xr.destroy_instance, self.instance)
                self.instance = None
        self._close_window()
