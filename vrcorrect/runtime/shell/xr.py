"""The headset path: an OpenXR session through pyopenxr, each eye corrected before it is
submitted (``vrcorrect xr``, whose command line is :mod:`vrcorrect.apps.xr`).

The OpenXR instance enables ``XR_KHR_opengl_enable``; the OpenGL context is a GLFW window's
(X11/GLX: the session is bound with ``XrGraphicsBindingOpenGLXlibKHR``; the window is hidden
unless ``--mirror`` shows both eyes in it). One swapchain per view, in ``GL_SRGB8_ALPHA8``
when the runtime offers it (else ``GL_RGBA8``, see :func:`choose_swapchain_format`). Each
frame: ``xrWaitFrame``, ``xrBeginFrame``, and when the runtime says the frame should be
rendered, ``xrLocateViews``, the source renders each eye (the demo scene from that eye's
tracked pose and field of view, or a picture source: image, animated image, folder, video,
screen region), each eye's :class:`~vrcorrect.runtime.corrector.Corrector` writes the
corrected image straight into the acquired swapchain image (a framebuffer around the
runtime's GL texture), and ``xrEndFrame`` submits one projection layer.

Session life cycle (:class:`SessionTracker`, pure): ``READY`` -> ``xrBeginSession``;
``SYNCHRONIZED`` / ``VISIBLE`` / ``FOCUSED`` -> frames (rendered when the runtime says so);
``STOPPING`` -> ``xrEndSession``; ``EXITING`` -> done; ``LOSS_PENDING`` (or an instance loss)
-> the session is destroyed and :data:`EXIT_SESSION_LOST` returned. Ctrl-C, closing the
mirror window, or ``--frames N`` reached ask the runtime to end the session
(``xrRequestExitSession``) and the loop runs until ``EXITING``; a second Ctrl-C, or a runtime
that does not get there within :data:`EXIT_GRACE_S`, ends it at once.

No OpenXR runtime installed: :class:`XrUnavailableError`, one paragraph saying what is missing
and how to get one (``vrcorrect mirror`` works without), exit status :data:`EXIT_NO_RUNTIME`.

With an iterative method (``--filter admm``, the default, or ``fista``) each eye runs its iterations
spread over frames; in the
``--mirror`` window ``[`` / ``]`` halve / double the iterations per frame live, and the window's
title shows them with each eye's objective as a fraction of uncorrected (read a frame late, no
wait for the GPU); the run's summary gives the median objective per eye.

Tests drive it against a small runtime compiled from ``tests/xr_runtime/`` (no headset).
Layer 5: numpy, moderngl, glfw, pyopenxr; never torch.

Longer than 700 lines on purpose: one OpenXR session's life (instance, GL binding, swapchains,
frame loop, tear-down) is one object whose steps share its handles, beside the pure parts it needs.
"""

from __future__ import annotations

import ctypes
import math
import os
import signal
import statistics
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

import numpy as np

from ...plumbing.errors import ValidationError, XrSessionError, XrUnavailableError
from ...specs.vocabulary import VIEW_ORDER, Backend, either, names
from ..corrector import Corrector, runs_iterations
from ..eye_model import CorrectorOptions, as_options
from ..gaze import gaze_deg_of, gaze_in_view
from ..gl import check_gl_errors, fullscreen_triangle, release
from ..motion import view_shift
from ..optional import require_moderngl, require_xr
from ..shaders import compile_program
from .scene import DemoScene, open_source
from .sources import PictureFeed, ScreenSource, parse_region, parse_source, screen_bounds, start_motion, take_motion
from .window import (
    GLFW_PRESS,
    MOD_ALT,
    MOD_CONTROL,
    MOD_SUPER,
    StageTimes,
    WindowApp,
    change_iterations,
    iteration_key,
    knob_text,
)
from .xr_gaze import EXTENSION as GAZE_EXTENSION
from .xr_gaze import EyeTracker, tracker_offered

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

__all__ = [
    "EXIT_NO_RUNTIME", "EXIT_SESSION_LOST", "EXIT_GRACE_S", "GL_SRGB8_ALPHA8", "GL_RGBA8", "XR_STAGES",
    "XR_CPU_ONLY_STAGES",
    "XrConfig", "SessionTracker", "choose_swapchain_format",
    "pose_matrix", "view_matrix", "projection_from_fov", "no_runtime_message", "XrApp", "XrRunSummary",
]

EXIT_NO_RUNTIME = 69
"""Exit status when no OpenXR runtime (or no headset) is available (sysexits' EX_UNAVAILABLE)."""
EXIT_SESSION_LOST = 75
"""Exit status when the runtime lost the session (``LOSS_PENDING``; sysexits' EX_TEMPFAIL: try
again once the runtime is back)."""
EXIT_GRACE_S = 5.0
"""Seconds the runtime gets to reach ``EXITING`` after ``xrRequestExitSession``."""

GL_SRGB8_ALPHA8 = 0x8C43
GL_RGBA8 = 0x8058
_GL_FRAMEBUFFER_SRGB = 0x8DB9
_FORMAT_NAMES = {GL_SRGB8_ALPHA8: "GL_SRGB8_ALPHA8", GL_RGBA8: "GL_RGBA8"}

XR_STAGES = ("wait", "begin", "locate", "scene", "acquire", "correct left", "correct right", "convert",
             "mirror", "release", "end")
"""Timed stages of a frame, in order. ``wait`` (``xrWaitFrame``, which paces the loop to the
display), ``begin``, ``locate``, ``acquire`` (acquire + wait for both swapchain images),
``release`` and ``end`` (``xrEndFrame``) are CPU time; the others have GPU time too.
``convert`` runs only with ``GL_RGBA8`` swapchains; ``mirror`` only with ``--mirror``."""
XR_CPU_ONLY_STAGES = ("wait", "begin", "locate", "acquire", "release", "end")
"""The stages of :data:`XR_STAGES` timed on the CPU only (the OpenXR calls)."""


# --------------------------------------------------------------------------
# Pure parts: messages, format choice, poses, the session state machine
# --------------------------------------------------------------------------


def no_runtime_message(detail: str = "") -> str:
    """The paragraph shown when the OpenXR loader finds no runtime (``detail``: what the
    loader said, if anything)."""
    runtime_json = os.environ.get("XR_RUNTIME_JSON")
    where = (f"XR_RUNTIME_JSON points to {runtime_json}, which the loader could not use" if runtime_json else
             "no active_runtime.json in ~/.config/openxr/1/ or /etc/xdg/openxr/1/ and XR_RUNTIME_JSON is not set")
    said = f" (the loader said: {detail.strip()})" if detail.strip() else ""
    return (f"no OpenXR runtime is installed or active: {where}{said}. vrcorrect xr needs one to reach a headset. "
            "Install one and make it the active runtime: Monado (open source; Debian/Ubuntu: apt-get install "
            "monado-service, then run monado-service; https://monado.freedesktop.org) or SteamVR (Steam on Linux; "
            "start SteamVR and choose it as the OpenXR runtime in its settings). Without a headset, vrcorrect "
            "mirror shows both corrected eyes in a window and needs no runtime.")


def no_headset_message(runtime: str) -> str:
    return (f"the OpenXR runtime ({runtime}) found no head-mounted display: connect and switch on the headset, "
            "check that the runtime sees it (Monado: monado-service's log; SteamVR: its status window), then try "
            "again. Without a headset, vrcorrect mirror shows both corrected eyes in a window.")


def choose_swapchain_format(offered: Sequence[int]) -> int:
    """The swapchain format to use from the runtime's list (in its order of preference):
    ``GL_SRGB8_ALPHA8`` if offered (the corrector's sRGB code values are stored as they are and
    the compositor decodes them), else ``GL_RGBA8`` (linear: the codes are decoded by a
    conversion pass).

    Raises
    ------
    XrSessionError
        Neither is offered (names the offered formats).
    """
    formats = [int(f) for f in offered]
    for wanted in (GL_SRGB8_ALPHA8, GL_RGBA8):
        if wanted in formats:
            return wanted
    raise XrSessionError("swapchain format = none usable; the runtime offers "
                         + (", ".join(f"0x{f:04X}" for f in formats) or "no formats")
                         + ", vrcorrect needs GL_SRGB8_ALPHA8 (0x8C43) or GL_RGBA8 (0x8058)")


def pose_matrix(orientation: Sequence[float], position: Sequence[float]) -> np.ndarray:
    """The 4x4 matrix of a pose: unit quaternion ``(x, y, z, w)`` then translation (m)."""
    x, y, z, w = (float(v) for v in orientation)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not math.isfinite(n) or n < 1e-6:
        raise ValidationError("pose.orientation", (x, y, z, w), "a non-zero quaternion (x, y, z, w)")
    x, y, z, w = x / n, y / n, z / n, w / n
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    m[:3, 3] = [float(v) for v in position]
    return m


def view_matrix(orientation: Sequence[float], position: Sequence[float]) -> np.ndarray:
    """World-to-eye matrix of an eye at a pose (the inverse of :func:`pose_matrix`)."""
    m = pose_matrix(orientation, position)
    inv = np.eye(4)
    inv[:3, :3] = m[:3, :3].T
    inv[:3, 3] = -m[:3, :3].T @ m[:3, 3]
    return inv


def projection_from_fov(angle_left: float, angle_right: float, angle_up: float, angle_down: float,
                        near_m: float = 0.05, far_m: float = 60.0) -> np.ndarray:
    """OpenGL projection (clip z in [-1, 1]) of an OpenXR field of view: four angles in radians
    (left and down negative for a view that contains the forward axis); may be asymmetric."""
    angles = (angle_left, angle_right, angle_up, angle_down)
    if not all(math.isfinite(a) and abs(a) < math.pi / 2 for a in angles) or angle_right <= angle_left \
            or angle_up <= angle_down:
        raise ValidationError("fov", angles, "angles in (-pi/2, pi/2) rad with left < right and down < up")
    if not 0 < near_m < far_m:
        raise ValidationError("near_m, far_m", (near_m, far_m), "0 < near_m < far_m")
    left, right = math.tan(angle_left), math.tan(angle_right)
    up, down = math.tan(angle_up), math.tan(angle_down)
    p = np.zeros((4, 4))
    p[0, 0] = 2 / (right - left)
    p[0, 2] = (right + left) / (right - left)
    p[1, 1] = 2 / (up - down)
    p[1, 2] = (up + down) / (up - down)
    p[2, 2] = -(far_m + near_m) / (far_m - near_m)
    p[2, 3] = -2 * far_m * near_m / (far_m - near_m)
    p[3, 2] = -1.0
    return p


SESSION_STATES = ("UNKNOWN", "IDLE", "READY", "SYNCHRONIZED", "VISIBLE", "FOCUSED", "STOPPING", "LOSS_PENDING",
                  "EXITING")
"""``XrSessionState`` names by value."""


@dataclass
class SessionTracker:
    """The application's side of the session state machine (pure: no OpenXR calls).

    :meth:`on_state` takes each state the runtime reports and returns what to do:
    ``"begin"`` (READY: ``xrBeginSession``), ``"end"`` (STOPPING: ``xrEndSession``), ``"exit"``
    (EXITING: leave the loop), ``"lost"`` (LOSS_PENDING: destroy the session, leave), or
    ``None``. :attr:`running` is True between a begin and an end; :attr:`history` lists the
    states seen.
    """

    state: str = "UNKNOWN"
    running: bool = False
    history: list[str] = field(default_factory=list)

    def on_state(self, state: str) -> str | None:
        if state not in SESSION_STATES:
            raise ValidationError("session state", state, "one of " + ", ".join(SESSION_STATES))
        self.state = state
        self.history.append(state)
        if state == "READY" and not self.running:
            return "begin"
        if state == "STOPPING" and self.running:
            return "end"
        if state == "EXITING":
            return "exit"
        if state == "LOSS_PENDING":
            return "lost"
        return None

    def began(self) -> None:
        self.running = True

    def ended(self) -> None:
        self.running = False

    @property
    def visible(self) -> bool:
        return self.state in ("VISIBLE", "FOCUSED")


# --------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class XrConfig:
    """How ``vrcorrect xr`` runs.

    Attributes
    ----------
    rx
        Prescription JSON (watched for changes); ``None``: the bundled sample.
    display
        Display preset or profile path the correction is designed for (the headset's panel).
    source
        ``"demo"`` (the 3D scene from the tracked eyes), an image, animated image or video
        file, a folder of images, or ``"screen"`` (an X11 screen region, ``region``).
    region
        ``"X,Y,W,H"`` of the screen for ``source="screen"`` (default: the whole screen).
    frames
        Leave (via ``xrRequestExitSession``) after this many rendered frames; ``None``: run
        until Ctrl-C, the mirror window closes, or the runtime ends the session.
    mirror
        Show what is submitted, both eyes side by side, in a window ``mirror_height`` px tall.
    validation
        Insert pyopenxr's bundled Khronos core validation layer (messages on stdout).
    backend, corrector_options
        Passed to each :class:`~vrcorrect.runtime.corrector.Corrector`.
    time_step_s
        Fixed scene time per rendered frame; ``None``: the runtime's predicted display times.
    reprojection
        With an iterative method (``admm``, ``fista``): start each frame's iterations from the previous solution moved by
        the motion since the last frame: in the demo scene the change of each eye's tracked
        orientation (:func:`~vrcorrect.runtime.motion.view_shift`), for a picture source (head-locked)
        the pictures' estimated shift, with a cold start on a scene cut.  ``False``: the plain warm
        start.
    """

    rx: str | Path | None = None
    display: str = "quest2"
    source: str = "demo"
    region: str | None = None
    frames: int | None = None
    mirror: bool = False
    mirror_height: int = 480
    validation: bool = False
    backend: str = Backend.GLSL
    corrector_options: CorrectorOptions | Mapping[str, Any] = field(default_factory=dict)
    time_step_s: float | None = None
    folder_interval_s: float = 3.0
    application_name: str = "vrcorrect"
    reprojection: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "corrector_options", as_options(self.backend, self.corrector_options))
        if self.frames is not None and not (isinstance(self.frames, int) and 1 <= self.frames <= 10_000_000):
            raise ValidationError("frames", self.frames, "None or a whole number of frames from 1 to 10000000")
        if not (isinstance(self.mirror_height, int) and 16 <= self.mirror_height <= 4096):
            raise ValidationError("mirror_height", self.mirror_height, "a whole number of pixels from 16 to 4096")
        if self.time_step_s is not None and not (math.isfinite(self.time_step_s) and self.time_step_s >= 0):
            raise ValidationError("time_step_s", self.time_step_s, "None or a number of seconds >= 0")
        if self.backend not in names(Backend):
            raise ValidationError("backend", self.backend, either(Backend))
        if self.region is not None and self.source != "screen":
            raise ValidationError("--region", self.region, "only with --source screen")


@dataclass
class XrRunSummary:
    """What a run did: ``frames`` rendered (submitted with a layer), ``frames_total`` (all
    ``xrEndFrame`` calls), why it stopped (``reason``: ``frames``, ``interrupted``, ``window
    closed``, ``runtime``, ``session lost``, ``no exit``), the states seen, per-frame stage times
    ``stage -> [(gpu_ms or None, cpu_ms), ...]`` and frame wall times (ms)."""

    frames: int = 0
    frames_total: int = 0
    reason: str = ""
    states: list[str] = field(default_factory=list)
    stage_ms: dict[str, list[tuple[float | None, float]]] = field(default_factory=dict)
    frame_ms: list[float] = field(default_factory=list)
    runtime: str = ""
    system: str = ""
    swapchain_format: str = ""
    eye_size: tuple[int, int] = (0, 0)
    renderer: str = ""
    objective: dict[str, list[float]] = field(default_factory=dict)
    """Iterative methods: each eye's objective as a fraction of uncorrected, per rendered frame
    (read a frame late)."""
    iterations_per_frame: int | None = None
    """Iterative methods: the iterations per frame at the end (the keys may change them)."""
    method: str = ""
    """The correction's method (``filter``)."""
    gaze: str = ""
    """With a fovea: where its window stood (the eye tracker's gaze, or why the configured one)."""
    tracked_frames: int = 0
    """Frames whose window followed the eye tracker."""
    gazes: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    """Each eye's tracked gaze (degrees from its view's centre), per tracked frame."""

    @property
    def exit_code(self) -> int:
        return EXIT_SESSION_LOST if self.reason == "session lost" else 0

    def medians(self, skip: int = 1) -> dict[str, tuple[float | None, float]]:
        """Median ``(gpu_ms, cpu_ms)`` per stage over the rendered frames after the first ``skip``."""
        out = {}
        for name in XR_STAGES:
            values = self.stage_ms.get(name, [])
            values = values[skip:] if len(values) > skip else values
            if not values:
                continue
            gpus = [g for g, _ in values if g is not None]
            out[name] = (statistics.median(gpus) if gpus else None, statistics.median(c for _, c in values))
        return out


# --------------------------------------------------------------------------
# pyopenxr
# --------------------------------------------------------------------------


class _CapturedStderr:
    """Collects what C code (the OpenXR loader) writes to file descriptor 2 while active."""

    def __enter__(self) -> "_CapturedStderr":
        sys.stderr.flush()
        self._file = tempfile.TemporaryFile()
        self._saved = os.dup(2)
        os.dup2(self._file.fileno(), 2)
        self.text = ""
        return self

    def __exit__(self, *exc: object) -> None:
        os.dup2(self._saved, 2)
        os.close(self._saved)
        self._file.seek(0)
        self.text = self._file.read().decode(errors="replace")
        self._file.close()


def _loader_detail(text: str) -> str:
    """The loader's first error line, without its ``Error [GENERAL | ...] :`` prefix."""
    for line in text.splitlines():
        if "Error" in line and ":" in line:
            return line.split("] :", 1)[-1].strip().rstrip(".") or line.strip()
    return ""


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
        xr, cfg = self.xr, self.config
        if cfg.validation:
            xr.api_layer.activate_core_validation_layer()
        info = xr.InstanceCreateInfo(
            application_info=xr.ApplicationInfo(application_name=cfg.application_name, application_version=1,
                                                engine_name="vrcorrect", engine_version=1,
                                                api_version=xr.Version(1, 0, 0)),
            enabled_extension_names=["XR_KHR_opengl_enable"] + ([GAZE_EXTENSION] if self._wants_gaze() else []))
        with _CapturedStderr() as captured:
            try:
                self.instance = xr.create_instance(info)
                error = None
            except (xr.RuntimeUnavailableError, xr.RuntimeFailureError, xr.InitializationFailedError) as exc:
                error = exc
            except xr.ExtensionNotPresentError:
                error = "extension"
        if captured.text and os.environ.get("VRCORRECT_DEBUG"):
            self.say(captured.text.rstrip())
        if error == "extension":
            raise XrUnavailableError("the active OpenXR runtime does not offer XR_KHR_opengl_enable (OpenGL), which "
                                     "vrcorrect xr needs; Monado and SteamVR do. Without a headset, vrcorrect mirror "
                                     "shows both corrected eyes in a window.")
        if error is not None:
            raise XrUnavailableError(no_runtime_message(_loader_detail(captured.text)))
        props = xr.get_instance_properties(self.instance)
        self.summary.runtime = props.runtime_name.decode(errors="replace")
        try:
            self.system_id = xr.get_system(self.instance, xr.SystemGetInfo(
                form_factor=xr.FormFactor.HEAD_MOUNTED_DISPLAY))
        except xr.FormFactorUnavailableError:
            raise XrUnavailableError(no_headset_message(self.summary.runtime)) from None
        except xr.XrException as exc:
            raise XrSessionError(f"xrGetSystem failed: {type(exc).__name__}: {exc}") from None
        sp = xr.get_system_properties(self.instance, self.system_id)
        self.summary.system = sp.system_name.decode(errors="replace")
        views = self._call("xrEnumerateViewConfigurationViews", xr.enumerate_view_configuration_views,
                           self.instance, self.system_id, xr.ViewConfigurationType.PRIMARY_STEREO)
        if len(views) != 2:
            raise XrSessionError(f"stereo view configuration = {len(views)} views; vrcorrect xr needs 2")
        sizes = {(v.recommended_image_rect_width, v.recommended_image_rect_height) for v in views}
        if len(sizes) != 1:
            raise XrSessionError(f"recommended view sizes = {sorted(sizes)}; vrcorrect xr needs both eyes the same")
        self.eye_size = sizes.pop()
        self.summary.eye_size = self.eye_size
        blend = self._call("xrEnumerateEnvironmentBlendModes", xr.enumerate_environment_blend_modes,
                           self.instance, self.system_id, xr.ViewConfigurationType.PRIMARY_STEREO)
        if xr.EnvironmentBlendMode.OPAQUE not in [xr.EnvironmentBlendMode(int(b)) for b in blend]:
            raise XrSessionError("environment blend modes lack OPAQUE, which a VR projection layer needs")
        # XR_KHR_opengl_enable: the requirements call must come before xrCreateSession
        pfn = ctypes.cast(xr.get_instance_proc_addr(self.instance, "xrGetOpenGLGraphicsRequirementsKHR"),
                          xr.PFN_xrGetOpenGLGraphicsRequirementsKHR)
        self.gl_requirements = xr.GraphicsRequirementsOpenGLKHR()
        result = xr.check_result(xr.Result(pfn(self.instance, self.system_id, ctypes.byref(self.gl_requirements))))
        if result.is_exception():
            raise XrSessionError(f"xrGetOpenGLGraphicsRequirementsKHR failed: {result}")

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
        binding.x_display = ctypes.cast(ctypes.c_void_p(_address(display)), fields["x_display"])
        binding.glx_context = ctypes.cast(ctypes.c_void_p(_address(context)), fields["glx_context"])
        binding.glx_drawable = int(drawable)
        self._binding = binding  # kept alive for the session
        info = xr.SessionCreateInfo(system_id=self.system_id,
                                    next=ctypes.cast(ctypes.pointer(binding), ctypes.c_void_p))
        self.session = self._call("xrCreateSession", xr.create_session, self.instance, info)
        self.space = self._call("xrCreateReferenceSpace", xr.create_reference_space, self.session,
                                xr.ReferenceSpaceCreateInfo(reference_space_type=xr.ReferenceSpaceType.LOCAL))
        formats = self._call("xrEnumerateSwapchainFormats", xr.enumerate_swapchain_formats, self.session)
        self.format = choose_swapchain_format(formats)
        self.summary.swapchain_format = _FORMAT_NAMES[self.format]
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
        self._start_eyes(ctx, VIEW_ORDER, cfg.corrector_options)
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
                _quietly(xr.destroy_swapchain, chain["handle"])
            self.swapchains = []
            if self.space is not None:
                _quietly(xr.destroy_space, self.space)
                self.space = None
            if self.session is not None:
                _quietly(xr.destroy_session, self.session)
                self.session = None
            if self.instance is not None:
                _quietly(xr.destroy_instance, self.instance)
                self.instance = None
        self._close_window()


def _address(handle: Any) -> int:
    """An integer address from what pyGLFW returns for native handles (int, c_void_p, pointer)."""
    if handle is None:
        return 0
    if isinstance(handle, int):
        return handle
    if isinstance(handle, ctypes.c_void_p):
        return handle.value or 0
    return ctypes.cast(handle, ctypes.c_void_p).value or 0


def _quietly(fn: Callable[..., Any], *args: Any) -> None:
    try:
        fn(*args)
    except Exception:  # tear-down: a lost session's handles may already be gone
        pass
