"""The pure parts of the headset path (``vrcorrect xr``): its exit statuses and stages, the
messages when no runtime or no headset is there, the swapchain format's choice, the session's state
machine (:class:`SessionTracker`), the configuration (:class:`XrConfig`) and the run's summary
(:class:`XrRunSummary`). No OpenXR call here: the tests run these without a runtime.

Session life cycle (:class:`SessionTracker`): ``READY`` -> ``xrBeginSession``;
``SYNCHRONIZED`` / ``VISIBLE`` / ``FOCUSED`` -> frames (rendered when the runtime says so);
``STOPPING`` -> ``xrEndSession``; ``EXITING`` -> done; ``LOSS_PENDING`` (or an instance loss)
-> the session is destroyed and :data:`EXIT_SESSION_LOST` returned. Ctrl-C, closing the
mirror window, or ``--frames N`` reached ask the runtime to end the session
(``xrRequestExitSession``) and the loop runs until ``EXITING``; a second Ctrl-C, or a runtime
that does not get there within :data:`EXIT_GRACE_S`, ends it at once.

Layer 5: numpy; never torch.
"""

from __future__ import annotations

import math
import os
import statistics
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence

from ....plumbing.errors import ValidationError, XrSessionError
from ....specs.vocabulary import Backend, either, names
from ...eye_model import CorrectorOptions, as_options

if TYPE_CHECKING:  # pragma: no cover - typing only
    pass

__all__ = ["EXIT_NO_RUNTIME", "EXIT_SESSION_LOST", "EXIT_GRACE_S", "GL_SRGB8_ALPHA8", "GL_RGBA8", "FORMAT_NAMES", "XR_STAGES",
           "XR_CPU_ONLY_STAGES", "SESSION_STATES", "no_runtime_message", "no_headset_message", "choose_swapchain_format",
           "SessionTracker", "XrConfig", "XrRunSummary"]

EXIT_NO_RUNTIME = 69
"""Exit status when no OpenXR runtime (or no headset) is available (sysexits' EX_UNAVAILABLE)."""
EXIT_SESSION_LOST = 75
"""Exit status when the runtime lost the session (``LOSS_PENDING``; sysexits' EX_TEMPFAIL: try
again once the runtime is back)."""
EXIT_GRACE_S = 5.0
"""Seconds the runtime gets to reach ``EXITING`` after ``xrRequestExitSession``."""

GL_SRGB8_ALPHA8 = 0x8C43
GL_RGBA8 = 0x8058
FORMAT_NAMES = {GL_SRGB8_ALPHA8: "GL_SRGB8_ALPHA8", GL_RGBA8: "GL_RGBA8"}

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
