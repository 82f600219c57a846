"""The desktop mirror: both eyes side by side in a GLFW window (``vrcorrect mirror``, whose
command line is :mod:`vrcorrect.apps.mirror`).

Each frame a source (:func:`vrcorrect.runtime.shell.scene.open_source`: the 3D demo scene, an image, a
folder, a video) renders one RGBA8 texture of sRGB code values per eye; each eye's
:class:`~vrcorrect.runtime.corrector.Corrector` then writes, straight into its half of the
window (left eye on the left), the displayed (corrected) image, or what that eye sees of the
display without or with the correction. A panel shows milliseconds per stage (GPU time from
timer queries, and CPU time) and the state: view, correction on or off, the eye that live
edits go to, each eye's current prescription, as its corrector holds it (the file's, plus the
live changes: :attr:`Corrector.live_offset <vrcorrect.runtime.corrector.Corrector.live_offset>`).

Keys are handled by a pure state machine, :func:`next_state` on a frozen
:class:`MirrorState`, which returns the new state and the side effects to perform
(:class:`Adjust`, :class:`~vrcorrect.runtime.shell.keys.Screenshot`,
:class:`~vrcorrect.runtime.shell.keys.Iterations`); :meth:`Mirror.key_callback` is the GLFW key
callback that feeds it. :data:`KEY_MAP` lists the keys.

With an iterative method (``--filter admm``, the default, or ``fista``) the correction is
iterations spread over frames, and ``[`` / ``]`` halve / double the iterations per frame live (the
speed-accuracy knob, 1 to 64); the panel shows it with each eye's objective as a fraction of
uncorrected, read back a frame late so the panel never waits for the GPU
(:func:`~vrcorrect.runtime.shell.keys.knob_text`).

A prescription edit (the file, or the keys' live changes) is designed off the render thread
(:class:`~vrcorrect.runtime.eye_source.EyeSource`): the frames go on with the current correction
until the new one is ready, then it is installed between two frames.

GPU objects are made when the mirror opens (the correctors make theirs on the first frame of
a size); rendering frames allocates none. Text is drawn from a glyph atlas
(:mod:`vrcorrect.runtime.shell.text`); the window shell is :mod:`vrcorrect.runtime.shell.window`.

Layer 5: numpy, Pillow, moderngl, glfw; never torch. One :class:`Mirror` per process at a
time (GLFW is initialised and terminated with it).
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping

import numpy as np

from ...plumbing.errors import ValidationError, VrcorrectError
from ...specs.vocabulary import VIEW_ORDER, Backend, Eye, either, names
from ..corrector import Corrector
from ..eye_model import CorrectorOptions, as_options
from ..gl import check_gl_errors, format_ms, release
from .keys import (
    ITERATION_KEYS,
    KEY_ESCAPE,
    MOD_ALT,
    MOD_CONTROL,
    MOD_SHIFT,
    MOD_SUPER,
    Iterations,
    Screenshot,
    change_iterations,
    iteration_key,
    key_letter,
    knob_text,
)
from .scene import open_source
from .source_spec import parse_source
from .sources import PictureFeed, start_motion, take_motion
from .text import TextOverlay, build_font_atlas, key_map_panel, panel_instances, text_width
from .timing import StageTimes
from .window import KeyedWindowApp

if TYPE_CHECKING:  # pragma: no cover - typing only
    from ...specs.prescription import EyeRx

__all__ = [
    "VIEWS", "VIEW_TITLES", "KEY_MAP", "STEP_SPHERE_D", "STEP_CYLINDER_D", "STEP_AXIS_DEG", "STAGES",
    "MirrorState", "Adjust", "Action", "next_state", "eye_viewports", "MirrorConfig", "Mirror",
]

# --------------------------------------------------------------------------
# State machine (pure: no GL, no GLFW)
# --------------------------------------------------------------------------

VIEWS = ("displayed", "seen_uncorrected", "seen_corrected")
"""What the halves show: the displayed image, what the eye sees of the uncorrected image,
what the eye sees of the corrected image (``v`` cycles in this order)."""

VIEW_TITLES = {"displayed": "displayed image", "seen_uncorrected": "eye sees, uncorrected",
               "seen_corrected": "eye sees, corrected"}

STEP_SPHERE_D = 0.25
STEP_CYLINDER_D = 0.25
STEP_AXIS_DEG = 5.0

KEY_MAP: tuple[tuple[str, str], ...] = (
    ("c", "correction on/off"),
    ("v", "view: displayed image / eye sees uncorrected / eye sees corrected"),
    ("e", "eye that live edits go to: left/right"),
    ("s / S", f"sphere -/+{STEP_SPHERE_D:.2f} D"),
    ("y / Y", f"cylinder -/+{STEP_CYLINDER_D:.2f} D"),
    ("a / A", f"axis -/+{STEP_AXIS_DEG:g} deg"),
    ("p", "screenshot to PNG (both halves, as shown)"),
    *ITERATION_KEYS,
    ("h", "show/hide this key map"),
    ("i", "show/hide the timing panel"),
    ("Esc / q", "quit"),
)
"""Every key, as shown by ``h`` and printed at start."""


@dataclass(frozen=True)
class MirrorState:
    """What the user chose with the keys.

    Attributes
    ----------
    correction
        Correction on (``c`` toggles).
    view
        One of :data:`VIEWS` (``v`` cycles).
    edit_eye
        ``"left"`` or ``"right"``: the eye ``s``/``y``/``a`` change (``e`` toggles).
    show_keys
        The key map is shown (``h``).
    show_panel
        The timing and state panel is shown (``i``).
    running
        False once ``Esc`` or ``q`` was pressed.
    """

    correction: bool = True
    view: str = "displayed"
    edit_eye: str = Eye.RIGHT
    show_keys: bool = False
    show_panel: bool = True
    running: bool = True

    def __post_init__(self) -> None:
        if self.view not in VIEWS:
            raise ValidationError("view", self.view, "one of " + ", ".join(VIEWS))
        if self.edit_eye not in names(VIEW_ORDER):
            raise ValidationError("edit_eye", self.edit_eye, either(VIEW_ORDER))


@dataclass(frozen=True)
class Adjust:
    """Change ``eye``'s prescription live by these amounts (dioptres, degrees)."""

    eye: str
    sphere_D: float = 0.0
    cylinder_D: float = 0.0
    axis_deg: float = 0.0


Action = Adjust | Screenshot | Iterations


def next_state(state: MirrorState, key: int, mods: int = 0) -> tuple[MirrorState, tuple[Action, ...]]:
    """The state after pressing ``key`` (a GLFW key code) with modifier bits ``mods``, and the
    side effects to perform, in order.

    Shift selects the upper-case action of ``s``, ``y``, ``a`` (``+``); keys pressed with
    Control, Alt or Super, and keys not in :data:`KEY_MAP`, change nothing.
    """
    if mods & (MOD_CONTROL | MOD_ALT | MOD_SUPER):
        return state, ()
    if key == KEY_ESCAPE:
        return replace(state, running=False), ()
    letter = key_letter(key)
    sign = 1.0 if mods & MOD_SHIFT else -1.0
    if letter == "q":
        return replace(state, running=False), ()
    if letter == "c":
        return replace(state, correction=not state.correction), ()
    if letter == "v":
        return replace(state, view=VIEWS[(VIEWS.index(state.view) + 1) % len(VIEWS)]), ()
    if letter == "e":
        return replace(state, edit_eye=Eye.LEFT if state.edit_eye == Eye.RIGHT else Eye.RIGHT), ()
    if letter == "h":
        return replace(state, show_keys=not state.show_keys), ()
    if letter == "i":
        return replace(state, show_panel=not state.show_panel), ()
    if letter == "p":
        return state, (Screenshot(),)
    knob = iteration_key(key)
    if knob is not None:
        return state, (knob,)
    if letter == "s":
        return state, (Adjust(state.edit_eye, sphere_D=sign * STEP_SPHERE_D),)
    if letter == "y":
        return state, (Adjust(state.edit_eye, cylinder_D=sign * STEP_CYLINDER_D),)
    if letter == "a":
        return state, (Adjust(state.edit_eye, axis_deg=sign * STEP_AXIS_DEG),)
    return state, ()


def eye_viewports(width: int, height: int) -> dict[str, tuple[int, int, int, int]]:
    """GL viewports ``(x, y, w, h)`` of the two halves of a ``width`` x ``height`` window:
    the left eye on the left (an odd extra column goes to the right eye)."""
    if width < 2 or height < 1:
        raise ValidationError("window size", (width, height), "at least 2 x 1 pixels")
    half = width // 2
    return {Eye.LEFT: (0, 0, half, height), Eye.RIGHT: (half, 0, width - half, height)}


def _format_eye(rx: "EyeRx", offset: tuple[float, float, float]) -> str:
    text = f"{rx.sphere_D:+.2f} / {rx.cylinder_D:+.2f} x {rx.axis_deg:.0f}"
    if any(abs(v) > 1e-9 for v in offset):
        text += f"  (live {offset[0]:+.2f} / {offset[1]:+.2f} x {offset[2]:+.0f})"
    return text


# --------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class MirrorConfig:
    """How the mirror runs.

    Attributes
    ----------
    rx
        Prescription JSON (watched for changes); ``None``: the bundled sample.
    display
        Display preset name or profile path (the correction is designed for it).
    source
        ``"demo"``, an image or video file, or a folder of images (see
        :func:`~vrcorrect.runtime.shell.source_spec.parse_source`).
    eye_size
        Each eye's ``(width, height)`` in pixels; the window is twice as wide.
    frames
        Render this many frames, then stop; ``None``: until the window is closed.
    screenshot_dir
        Folder screenshots go to (made when the first is taken).
    backend, corrector_options
        Passed to each :class:`~vrcorrect.runtime.corrector.Corrector`.
    visible, vsync, platform
        Window shown; swaps synchronised to the display; GLFW platform (``"x11"``,
        ``"wayland"``, ``None``: GLFW's choice).
    time_step_s
        Fixed scene time per frame (deterministic runs); ``None``: the clock.
    panel, font_px
        Initial state of the timing panel; text size in pixels.
    folder_interval_s
        Seconds each image of a folder source is shown.
    reprojection
        With ``filter="fista"`` and a CPU source (image, folder, video): estimate the pictures'
        motion (:mod:`vrcorrect.runtime.motion`) and reproject the warm start by it, starting cold
        on a scene cut (:func:`~vrcorrect.runtime.shell.sources.start_motion`).  The demo scene is not estimated.
    """

    rx: str | Path | None = None
    display: str = "quest2"
    source: str = "demo"
    eye_size: tuple[int, int] = (640, 640)
    frames: int | None = None
    screenshot_dir: str | Path = "."
    backend: str = Backend.GLSL
    corrector_options: CorrectorOptions | Mapping[str, Any] = field(default_factory=dict)
    visible: bool = True
    vsync: bool = True
    platform: str | None = None
    time_step_s: float | None = None
    panel: bool = True
    font_px: int = 13
    folder_interval_s: float = 3.0
    title: str = "vrcorrect mirror"
    reprojection: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "corrector_options", as_options(self.backend, self.corrector_options))
        w, h = self.eye_size
        if not all(isinstance(v, int) and 1 <= v <= 8192 for v in (w, h)):
            raise ValidationError("eye_size", self.eye_size, "(width, height) in pixels, each 1 to 8192")
        if self.frames is not None and not (isinstance(self.frames, int) and self.frames >= 1):
            raise ValidationError("frames", self.frames, "None or an integer >= 1")
        if self.time_step_s is not None and not (math.isfinite(self.time_step_s) and self.time_step_s >= 0):
            raise ValidationError("time_step_s", self.time_step_s, "None or a number of seconds >= 0")
        if self.platform not in (None, "x11", "wayland"):
            raise ValidationError("platform", self.platform, "None, 'x11' or 'wayland'")


#: The frame times a mirror keeps for its summary's median (about 2 minutes at 90 Hz).
FRAME_TIMES_KEPT = 10_000

SLOW_FRAME_S = 0.05
"""Frames further apart than this (under 20 a second: a software renderer) step the scene's clock
by :data:`SLOW_FRAME_STEP_S` instead of the wall clock: with frames seconds apart the demo scene
would jump between them, and a warm start from the previous frame (the iterative methods) would
start from a picture unlike the new one (ghosts of the cube's previous pose)."""
SLOW_FRAME_STEP_S = 1 / 90
"""The scene's step per frame when frames are slow: one frame of a 90 Hz headset."""

STAGES = ("scene", "correct left", "correct right", "simulate left", "simulate right", "overlay", "present")
"""Timed stages of a frame. ``present`` (swapping buffers, which waits for the display when
vsync is on) is CPU time only; the others have GPU time (timer queries) and CPU time."""



class Mirror(KeyedWindowApp[MirrorState, Action]):
    """The mirror window (see the module docstring). Use as a context manager, or call
    :meth:`close`.

    Parameters
    ----------
    config
        :class:`MirrorConfig`.
    echo
        Where progress and status lines go (``print`` by default; ``None``: nowhere).

    Raises
    ------
    InputError, ValidationError
        Bad prescription, display, source or settings (checked before the window opens).
    GLUnavailableError
        No window with an OpenGL 4.3 core context (no display, old driver).

    Attributes
    ----------
    state
        The current :class:`MirrorState`.
    correctors
        ``{"left": Corrector, "right": Corrector}``: each eye's state (its prescription, the
        live changes) is its corrector's.
    source
        The eye source (:func:`~vrcorrect.runtime.shell.scene.open_source`).
    status
        The last status message ("" if none).
    timings_ms
        The last collected frame's ``stage -> (gpu_ms or None, cpu_ms)``.
    frame
        Frames rendered so far.
    """

    key_map = KEY_MAP
    screenshot_prefix = "vrcorrect-mirror"

    def __init__(self, config: MirrorConfig = MirrorConfig(), *, echo: Callable[[str], None] | None = print):
        super().__init__(echo)
        self.config = config
        # read once: both eyes are built from this parse; later edits (during the builds too) come
        # through each corrector's poll
        self._read_inputs(config.rx, config.display)
        self.spec = parse_source(config.source)
        self.state = MirrorState(show_panel=config.panel)
        self.timings_ms: dict[str, tuple[float | None, float]] = {}
        self.correctors: dict[str, Corrector] = {}
        self.source: PictureFeed | None = None
        self.overlay: TextOverlay | None = None
        self._times: StageTimes | None = None
        self._frame_ms: float | None = None
        self._last_frame_end: float | None = None
        self.frame_ms: deque[float] = deque(maxlen=FRAME_TIMES_KEPT)
        """Each frame's time from the end of the one before (ms; the first frame has none), the last
        :data:`FRAME_TIMES_KEPT` (a mirror may run for hours)."""
        self._scene_s = 0.0                               # the scene's clock (wall time, or stepped)
        self._scene_wall: float | None = None
        self.stepped = False                              # the last frame stepped the clock (slow frames)
        try:
            w, h = config.eye_size
            session = self._open_window(2 * w, h, config.title, platform=config.platform, visible=config.visible,
                                        vsync=config.vsync)
            self.framebuffer_size = session.framebuffer_size
            self._build()
        except BaseException:
            self.close()
            raise
        self._t0 = time.perf_counter()

    # ------------------------------------------------------------ set-up

    def _build(self) -> None:
        cfg, ctx = self.config, self.ctx
        self.source = open_source(ctx, self.spec, *cfg.eye_size, folder_interval_s=cfg.folder_interval_s)
        self._start_eyes(ctx, VIEW_ORDER, cfg.corrector_options, first=dict(zip(VIEW_ORDER, self.source.render(0.0))))
        start_motion(self.source, self.correctors.values(), cfg.reprojection)
        atlas = build_font_atlas(cfg.font_px)
        self.overlay = TextOverlay(ctx, atlas)
        gap = cfg.font_px
        first = max(text_width(atlas, name) for name in STAGES + names(VIEW_ORDER)) + gap
        number = text_width(atlas, "00000.00") + gap
        self._tab_stops = (first, first + number)
        self._times = StageTimes(ctx, STAGES)
        check_gl_errors(ctx, "mirror set-up")

    # ------------------------------------------------------------ state

    def current_rx(self, eye: str) -> "EyeRx":
        """``eye``'s prescription as corrected now: the file's, plus the live changes (its
        corrector's; before the corrector is built, the file's as read at start)."""
        corrector = self.correctors.get(eye)
        return corrector.eye_rx if corrector is not None else self._rx.prescription.eye(eye)

    def _rx_text(self, eye: str) -> str:
        corrector = self.correctors.get(eye)
        return _format_eye(self.current_rx(eye), corrector.live_offset if corrector is not None else (0.0, 0.0, 0.0))

    def _next_state(self, key: int, mods: int) -> tuple[MirrorState, tuple[Action, ...]]:
        return next_state(self.state, key, mods)

    def _run_actions(self) -> bool:
        """Perform queued side effects; True if a screenshot is due after this frame."""
        screenshot = False
        for action in self._take_actions():
            if isinstance(action, Screenshot):
                screenshot = True
            elif isinstance(action, Adjust):
                self._adjust(action)
            elif isinstance(action, Iterations):
                self.set_status(change_iterations(self.correctors.values(), action.up))
        return screenshot

    def _adjust(self, a: Adjust) -> None:
        """Have the eye redesigned with the key's change, off the render thread (the frames go on
        with the current correction until the new one is installed by :meth:`_poll`)."""
        eye = a.eye
        try:
            e = self._adjust_eye(eye, a.sphere_D, a.cylinder_D, a.axis_deg)
        except VrcorrectError as exc:
            self.set_status(f"{eye} eye unchanged: {' '.join(str(exc).split())}")
            return
        self.set_status(f"{eye} eye: designing {e.sphere_D:+.2f} / {e.cylinder_D:+.2f} x {e.axis_deg:.0f} ...")

    def _poll(self) -> None:
        updates, messages = self._poll_eyes()
        for u in updates:            # what each corrector now corrects for
            if u.reason == "reload":
                self.set_status(f"{self.rx_path.name} reloaded: {u.eye} eye {self._rx_text(u.eye)}")
            else:
                self.set_status(f"{u.eye} eye now {self._rx_text(u.eye)} (designed in {u.seconds:.1f} s)")
        for message in messages:
            self.set_status(message)

    # ------------------------------------------------------------ frames

    def panel_lines(self) -> list[str]:
        """The panel's text for the current state and the smoothed stage times."""
        s = self.state
        w, h = self.config.eye_size
        lines = [f"vrcorrect mirror  {self.display.name}  {w}x{h} per eye  {self.source.label}",
                 f"view: {VIEW_TITLES[s.view]}   correction {'ON' if s.correction else 'OFF'}   "
                 f"edits: {s.edit_eye} eye"]
        for eye in VIEW_ORDER:
            lines.append(f"{eye}\t{self._rx_text(eye)}")
            corrector = self.correctors.get(eye)
            if corrector is not None and corrector.pupil_status:
                lines.append(f"\t{corrector.pupil_status}")
        knob = knob_text(self.correctors, self.config.eye_size, s.correction and s.view != "seen_uncorrected")
        if knob:
            lines.append(knob)
        lines.append("stage\tgpu ms\tcpu ms")
        for name in STAGES:
            if name in self._times.smoothed:
                gpu, cpu = self._times.smoothed[name]
                lines.append(f"{name}\t{format_ms(gpu)}\t{cpu:.2f}")
        frame = self._frame_ms
        if frame is not None:
            lines.append(f"frame {frame:.1f} ms ({1e3 / frame:.0f} fps)" if frame > 0 else "frame -")
        if self.stepped:
            lines.append(f"slow frames: the scene steps {1e3 * SLOW_FRAME_STEP_S:.1f} ms a frame (as at 90 Hz), "
                         "not the clock, so the warm start follows it")
        if self.status:
            lines.append(self.status[:120])
        lines.append("h: keys")
        return lines

    def render(self) -> bool:
        """Draw one frame into the window's back buffer (no swap). Returns True if a
        screenshot was asked for (taken by :meth:`step` before the swap)."""
        self.timings_ms = self._times.collect()
        screenshot = self._run_actions()
        self._poll()
        ctx, state = self.ctx, self.state
        for c in self.correctors.values():
            c.enabled = state.correction
        with self._times.stage("scene"):
            textures = dict(zip(VIEW_ORDER, self.source.render(self.scene_time())))
            motion = take_motion(self.source, self.correctors.values())
        screen = ctx.screen
        viewports = eye_viewports(*self.framebuffer_size)
        for eye in VIEW_ORDER:
            c, texture, viewport = self.correctors[eye], textures[eye], viewports[eye]
            if state.view == "displayed":
                with self._times.stage(f"correct {eye}"):
                    c.apply(texture, screen, viewport, motion_px=motion)
            else:
                with self._times.stage(f"simulate {eye}"):
                    c.simulate(texture, screen, viewport, corrected=state.view == "seen_corrected", motion_px=motion)
        with self._times.stage("overlay"):
            quads = []
            atlas = self.overlay.atlas
            if state.show_panel:
                quads.append(panel_instances(atlas, self.panel_lines(), 8, 8, tab_stops=self._tab_stops)[0])
            if state.show_keys:
                x = viewports[Eye.RIGHT][0] + 8 if state.show_panel else 8
                quads.append(key_map_panel(atlas, KEY_MAP, x, 8, self.config.font_px))
            if quads:
                self.overlay.draw(np.concatenate(quads), screen, self.framebuffer_size)
        check_gl_errors(ctx, f"mirror frame {self.frame}")
        return screenshot

    def scene_time(self) -> float:
        """Seconds of scene time for the frame about to be rendered: ``time_step_s`` per frame when
        set; otherwise the wall clock, except that frames further apart than :data:`SLOW_FRAME_S`
        advance it by :data:`SLOW_FRAME_STEP_S` (:attr:`stepped` says so, and the panel)."""
        if self.config.time_step_s is not None:
            return self.frame_time()
        now = time.perf_counter()
        if self._scene_wall is not None:
            dt = now - self._scene_wall
            self.stepped = dt > SLOW_FRAME_S
            self._scene_s += SLOW_FRAME_STEP_S if self.stepped else dt
        self._scene_wall = now
        return self._scene_s

    def _after_frame(self) -> None:
        """Smooth the frame time the panel shows (from one frame's end to the next's)."""
        now = time.perf_counter()
        if self._last_frame_end is not None:
            ms = 1e3 * (now - self._last_frame_end)
            self.frame_ms.append(ms)
            self._frame_ms = ms if self._frame_ms is None else self._frame_ms + 0.1 * (ms - self._frame_ms)
        self._last_frame_end = now

    def run(self) -> int:
        """Render frames until :attr:`running` is False; returns the number rendered."""
        if self.frame == 0:
            self._t0 = time.perf_counter()
        while self.running:
            self.step()
        self.timings_ms = self._times.collect()
        return self.frame

    def close(self) -> None:
        """Release every GL object, close the window and terminate GLFW."""
        if self.ctx is not None:
            for c in self.correctors.values():
                c.release()
            for obj in (self.overlay, self.source, self._times):
                if obj is not None:
                    obj.release()
            release(self.ctx)
        self.correctors, self.overlay, self.source, self._times = {}, None, None, None
        self._close_window()
