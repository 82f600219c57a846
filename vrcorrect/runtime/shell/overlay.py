"""The overlay compositor (``vrcorrect overlay``; its command line is :mod:`vrcorrect.apps.overlay`):
for applications that cannot call the library.

It takes frames from an external source - a video file, a folder of images, a still image
(:mod:`vrcorrect.runtime.shell.sources`), or a region of the X11 screen
(:class:`~vrcorrect.runtime.shell.sources.ScreenSource`) - corrects each one with one
:class:`~vrcorrect.runtime.corrector.Corrector` (a monitor is seen by both eyes, so one eye's
prescription: the right eye's unless told), and presents it full-screen on the primary monitor,
or in a window of a given size. Each frame the source is fitted (aspect kept, centred on black)
into one reused texture of the output size; nothing is allocated on the GPU per frame after the
first.

The screen grab must not see the overlay's own window, or the picture would feed back into
itself. So the grabbed region and the window never overlap: in a window the region defaults
to the top-left of the screen, the window's size, and the window is placed beside the region
(:func:`place_window`); full-screen, the overlay covers the primary monitor and the region
defaults to another monitor (:func:`full_screen_region`); with one monitor, full-screen and
``screen`` cannot go together. A window manager may move the window: a warning says so.

Keys (:data:`KEY_MAP`, printed at start, shown with ``h``) go through a pure state machine,
:func:`next_state` on a frozen :class:`OverlayState`, as in the mirror; with an iterative
method (``--filter admm``, the default, or ``fista``), ``[`` / ``]`` halve / double the iterations
per frame live, and the report line gives them with the objective as a fraction of uncorrected
(read a frame late: no wait for the GPU). The prescription file is watched
(:class:`~vrcorrect.runtime.eye_source.EyeSource`): an edit is designed off the render thread and
takes effect when ready, an invalid file keeps the last good prescription and says why (on stdout
and in the window). Frames per second and milliseconds per stage are printed once per
second and on exit. The window shell is :mod:`vrcorrect.runtime.shell.window`.

Layer 5: numpy, Pillow, moderngl, glfw, mss; never torch.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

import numpy as np

from ...plumbing.errors import ValidationError
from ...specs.vocabulary import Backend, Eye, either, names
from ..corrector import Corrector
from ..eye_model import CorrectorOptions, as_options
from ..gl import Rect, check_gl_errors, format_ms, release
from .keys import (
    ITERATION_KEYS,
    KEY_ESCAPE,
    MOD_ALT,
    MOD_CONTROL,
    MOD_SUPER,
    Iterations,
    Screenshot,
    change_iterations,
    iteration_key,
    key_letter,
    knob_text,
)
from .source_spec import parse_source
from .sources import PictureSource, ScreenSource, open_picture_source, screen_bounds, start_motion, take_motion
from .text import TextOverlay, build_font_atlas, key_map_panel, panel_instances
from .timing import StageTimes
from .window import KeyedWindowApp

if TYPE_CHECKING:  # pragma: no cover - typing only
    from types import ModuleType

__all__ = [
    "KEY_MAP", "STAGES", "SCREEN", "OverlayState", "next_state", "rects_overlap", "place_window", "default_region",
    "full_screen_region", "default_display", "OverlayConfig", "Overlay",
]

SCREEN = "screen"
"""The ``--source`` value that grabs the X11 screen."""

KEY_MAP: tuple[tuple[str, str], ...] = (
    ("c", "correction on/off"),
    ("p", "screenshot to PNG (as shown)"),
    *ITERATION_KEYS,
    ("h", "show/hide this key map"),
    ("Esc / q", "quit"),
)
"""Every key of the overlay, as shown by ``h`` and printed at start."""

STAGES = ("source", "correct", "text", "present")
"""Timed stages of a frame: getting the source frame into its texture (decoding, grabbing,
uploading, fitting), the correction, the key map and messages, swapping buffers (CPU only)."""


# --------------------------------------------------------------------------
# Pure parts: keys, placement, defaults
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class OverlayState:
    """What the user chose with the keys: correction on (``c``), key map shown (``h``),
    still running (``Esc``/``q`` end it)."""

    correction: bool = True
    show_keys: bool = False
    running: bool = True


OverlayAction = Screenshot | Iterations


def next_state(state: OverlayState, key: int, mods: int = 0) -> tuple[OverlayState, tuple[OverlayAction, ...]]:
    """The state after pressing ``key`` (a GLFW key code) with modifier bits ``mods``, and the
    side effects to perform. Keys with Control, Alt or Super, and keys not in
    :data:`KEY_MAP`, change nothing."""
    if mods & (MOD_CONTROL | MOD_ALT | MOD_SUPER):
        return state, ()
    letter = key_letter(key)
    if key == KEY_ESCAPE or letter == "q":
        return replace(state, running=False), ()
    if letter == "c":
        return replace(state, correction=not state.correction), ()
    if letter == "h":
        return replace(state, show_keys=not state.show_keys), ()
    if letter == "p":
        return state, (Screenshot(),)
    knob = iteration_key(key)
    return (state, (knob,)) if knob is not None else (state, ())


def rects_overlap(a: Rect, b: Rect) -> bool:
    """True if the two rectangles share at least one pixel."""
    return a.x < b.x + b.width and b.x < a.x + a.width and a.y < b.y + b.height and b.y < a.y + a.height


def _clamp(value: int, low: int, high: int) -> int:
    return max(low, min(value, high))


def place_window(size: tuple[int, int], region: Rect, screen: Rect) -> tuple[int, int]:
    """Top-left corner ``(x, y)`` for a window of ``size`` on ``screen`` that does not cover
    ``region``: right of it, else below, left, above (aligned with the region where it fits).

    Raises
    ------
    ValidationError
        No such place (the window is too big for the room beside the region).
    """
    w, h = size
    sw, sh = screen.width, screen.height
    candidates = (
        (region.x + region.width, _clamp(region.y, 0, sh - h)),
        (_clamp(region.x, 0, sw - w), region.y + region.height),
        (region.x - w, _clamp(region.y, 0, sh - h)),
        (_clamp(region.x, 0, sw - w), region.y - h),
    )
    for x, y in candidates:
        if 0 <= x and x + w <= sw and 0 <= y and y + h <= sh and not rects_overlap(Rect(x, y, w, h), region):
            return x, y
    raise ValidationError("--window", f"{w}x{h}", f"a window that fits on the {sw}x{sh} screen beside the grabbed "
                          f"region {region.x},{region.y},{region.width},{region.height} (make one of them smaller)")


def default_region(size: tuple[int, int], screen: Rect) -> Rect:
    """The region grabbed for a window of ``size`` when none is given: the screen's top-left
    corner, the window's size (at most half the screen's width, so the window fits beside it)."""
    return Rect(0, 0, max(1, min(size[0], screen.width // 2)), max(1, min(size[1], screen.height)))


def full_screen_region(primary: Rect, others: Sequence[Rect], region: Rect | None) -> Rect:
    """The region to grab while the overlay covers the ``primary`` monitor: ``region`` if it
    lies off that monitor, else (none given) the first of the ``others`` monitors.

    Raises
    ------
    ValidationError
        The region is on the primary monitor, or there is no other monitor.
    """
    if region is not None:
        if rects_overlap(region, primary):
            raise ValidationError("--region", f"{region.x},{region.y},{region.width},{region.height}",
                                  "a region off the primary monitor, which the full-screen overlay covers "
                                  "(or use --window WxH)")
        return region
    for other in others:
        if not rects_overlap(other, primary):
            return other
    raise ValidationError("--source", SCREEN, "another monitor to grab: full-screen on the only monitor would "
                          "grab itself; use --window WxH (the region then defaults to the screen beside it)")


def default_display(source: str) -> str:
    """``desktop`` for the screen (a monitor), ``quest2`` for files (like the other commands)."""
    return "desktop" if source == SCREEN else "quest2"


# --------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class OverlayConfig:
    """How the overlay runs.

    Attributes
    ----------
    source
        ``"screen"``, an image or video file, or a folder of images.
    region
        With ``screen``: the grabbed rectangle (default: see the module docstring).
    rx, eye
        Prescription JSON (watched for changes; ``None``: the bundled sample) and whose eye.
    display
        Display preset or profile path; ``None``: :func:`default_display`.
    window
        ``(width, height)`` of a window; ``None``: full-screen on the primary monitor.
    frames
        Render this many frames, then stop; ``None``: until quit.
    screenshot_dir
        Where ``p`` writes PNGs.
    backend, corrector_options
        Passed to the :class:`~vrcorrect.runtime.corrector.Corrector`.
    visible, vsync, platform
        Window settings (tests: hidden, no vsync, ``"x11"``).
    time_step_s
        Source time per frame (``None``: the wall clock).
    show_messages
        Draw status messages (an invalid prescription, a reload) over the picture.
    report_interval_s
        How often frames per second and stage times are printed (and on exit).
    """

    source: str
    region: Rect | None = None
    rx: str | Path | None = None
    eye: str = Eye.RIGHT
    display: str | None = None
    window: tuple[int, int] | None = None
    frames: int | None = None
    screenshot_dir: str | Path = "."
    backend: str = Backend.GLSL
    corrector_options: CorrectorOptions | Mapping[str, Any] = field(default_factory=dict)
    reprojection: bool = True               # fista: reproject the warm start by the pictures' motion
    visible: bool = True
    vsync: bool = True
    platform: str | None = None
    time_step_s: float | None = None
    show_messages: bool = True
    report_interval_s: float = 1.0
    font_px: int = 13
    folder_interval_s: float = 3.0
    title: str = "vrcorrect overlay"

    def __post_init__(self) -> None:
        object.__setattr__(self, "corrector_options", as_options(self.backend, self.corrector_options))
        if self.eye not in names(Eye):
            raise ValidationError("--eye", self.eye, either(Eye, quote=False))
        if self.backend not in names(Backend):
            raise ValidationError("--backend", self.backend, either(Backend, quote=False))
        if self.region is not None and self.source != SCREEN:
            raise ValidationError("--region", f"{self.region.x},{self.region.y},{self.region.width},"
                                  f"{self.region.height}", f"only with --source {SCREEN}")
        if self.frames is not None and not (isinstance(self.frames, int) and self.frames >= 1):
            raise ValidationError("frames", self.frames, "None or an integer >= 1")
        if self.time_step_s is not None and not (math.isfinite(self.time_step_s) and self.time_step_s >= 0):
            raise ValidationError("time_step_s", self.time_step_s, "None or a number of seconds >= 0")
        if not (math.isfinite(self.report_interval_s) and self.report_interval_s > 0):
            raise ValidationError("report_interval_s", self.report_interval_s, "a number of seconds > 0")


# --------------------------------------------------------------------------
# The compositor
# --------------------------------------------------------------------------


class Overlay(KeyedWindowApp[OverlayState, OverlayAction]):
    """The overlay (see the module docstring). Use as a context manager, or call :meth:`close`.

    Raises
    ------
    InputError, ValidationError
        Bad prescription, display, source, region or window (checked before the window opens
        where possible); no X display for ``screen``.
    GLUnavailableError
        No window with an OpenGL 4.3 core context.

    Attributes
    ----------
    state, corrector, source, status, frame, timings_ms, screenshots, region, output_size
    """

    key_map = KEY_MAP
    screenshot_prefix = "vrcorrect-overlay"

    def __init__(self, config: OverlayConfig, *, echo: Callable[[str], None] | None = print):
        super().__init__(echo)
        self.config = config
        # read once; a bad file fails here, before any window
        self._read_inputs(config.rx, config.display or default_display(config.source))
        self.spec = None
        if config.source != SCREEN:
            self.spec = parse_source(config.source)
            if self.spec.kind == "demo":
                raise ValidationError("--source", "demo", f"a video, an image, a folder of images or '{SCREEN}' "
                                      "(the demo scene is the mirror's: vrcorrect mirror)")
        self.screen = screen_bounds() if config.source == SCREEN else None
        self.state = OverlayState()
        self.timings_ms: dict[str, tuple[float | None, float]] = {}
        self.reports: list[str] = []
        self.region: Rect | None = None
        self.source: PictureSource | None = None
        self.text: TextOverlay | None = None
        self._times: StageTimes | None = None
        self._sums: dict[str, list[float]] = {}
        try:
            self._open()
            self._build()
        except BaseException:
            self.close()
            raise
        self._t0 = self._report_t0 = time.perf_counter()
        self._report_frame0 = 0

    def _open(self) -> None:
        """Place the grabbed region and the window apart (see the module docstring), open the window."""
        cfg = self.config
        glfw = self._start_glfw(cfg.platform)
        position = None
        if cfg.window is None:
            if self.screen is not None:
                primary, others = self._monitors(glfw)
                self.region = full_screen_region(primary, others, cfg.region)
        elif self.screen is not None:
            self.region = cfg.region or default_region(cfg.window, self.screen)
            position = place_window(cfg.window, self.region, self.screen)
        width, height = cfg.window or (1, 1)
        session = self._open_window(width, height, cfg.title, platform=cfg.platform, visible=cfg.visible,
                                    vsync=cfg.vsync, fullscreen=cfg.window is None, position=position)
        self.output_size = session.framebuffer_size
        if position is not None and cfg.visible:
            x, y = glfw.get_window_pos(self.window)
            if rects_overlap(Rect(max(x, 0), max(y, 0), *cfg.window), self.region):
                self.say(f"warning: the window manager put the window at {x},{y}, over the grabbed region; "
                         "move it off the region")

    @staticmethod
    def _monitors(glfw: "ModuleType") -> tuple[Rect, list[Rect]]:
        def rect(m: Any) -> Rect:
            x, y = glfw.get_monitor_pos(m)
            mode = glfw.get_video_mode(m)
            return Rect(max(int(x), 0), max(int(y), 0), int(mode.size.width), int(mode.size.height))

        primary = glfw.get_primary_monitor()
        if not primary:
            raise ValidationError("--window", None, "WxH: GLFW sees no monitor to go full-screen on")
        return rect(primary), [rect(m) for m in glfw.get_monitors() if m != primary]

    def _build(self) -> None:
        cfg, ctx = self.config, self.ctx
        w, h = self.output_size
        if self.region is not None:
            self.source = ScreenSource(ctx, w, h, self.region)
        else:
            self.source = open_picture_source(ctx, self.spec, w, h, folder_interval_s=cfg.folder_interval_s)
        self.say(f"{self.source.label}, {w}x{h}")
        self._start_eyes(ctx, (cfg.eye,), cfg.corrector_options, first={cfg.eye: self.source.render(0.0)[1]})
        start_motion(self.source, [self.corrector], cfg.reprojection)
        atlas = build_font_atlas(cfg.font_px)
        self.text = TextOverlay(ctx, atlas)
        self._times = StageTimes(ctx, STAGES)
        check_gl_errors(ctx, "overlay set-up")

    # ------------------------------------------------------------ keys and state

    def _next_state(self, key: int, mods: int) -> tuple[OverlayState, tuple[OverlayAction, ...]]:
        return next_state(self.state, key, mods)

    @property
    def corrector(self) -> Corrector | None:
        """The one eye's corrector (``None`` before it is built and after :meth:`close`)."""
        return self.correctors.get(self.config.eye)

    @corrector.setter
    def corrector(self, value: Corrector) -> None:
        self.correctors[self.config.eye] = value

    def _poll(self) -> None:
        updates, messages = self._poll_eyes()
        if updates:
            rx = self.corrector.eye_rx
            self.set_status(f"{self.rx_path.name} reloaded: {self.config.eye} eye {rx.sphere_D:+.2f} / "
                            f"{rx.cylinder_D:+.2f} x {rx.axis_deg:.0f}", hold_s=3.0)
        elif messages:
            self.set_status(messages[-1], hold_s=math.inf)
        else:
            self._expire_status()

    # ------------------------------------------------------------ frames

    def render(self) -> bool:
        """Draw one frame into the back buffer (no swap); True if a screenshot is due."""
        self._accumulate(self._times.collect())
        actions = self._take_actions()
        for action in actions:
            if isinstance(action, Iterations):
                self.set_status(change_iterations([self.corrector], action.up), hold_s=3.0)
        self._poll()
        ctx, state = self.ctx, self.state
        self.corrector.enabled = state.correction
        with self._times.stage("source"):
            texture = self.source.render(self.frame_time())[1]
            motion = take_motion(self.source, [self.corrector])
        with self._times.stage("correct"):
            self.corrector.apply(texture, ctx.screen, motion_px=motion)
        with self._times.stage("text"):
            quads = []
            atlas = self.text.atlas
            if self.status and self.config.show_messages:
                quads.append(panel_instances(atlas, [self.status[:160]], 8, 8, background=(0.3, 0.0, 0.0, 0.85))[0])
            if state.show_keys:
                y = 8 + (2 * atlas.line_height if quads else 0)
                quads.append(key_map_panel(atlas, KEY_MAP, 8, y, self.config.font_px))
            if quads:
                self.text.draw(np.concatenate(quads), ctx.screen, self.output_size)
        check_gl_errors(ctx, f"overlay frame {self.frame}")
        return any(isinstance(a, Screenshot) for a in actions)

    def _accumulate(self, times: Mapping[str, tuple[float | None, float]]) -> None:
        self.timings_ms = dict(times)
        for name, (gpu, cpu) in times.items():
            s = self._sums.setdefault(name, [0.0, 0.0, 0, 0])       # gpu, cpu, frames, frames with a gpu time
            if gpu is not None:                                      # None: no valid query (never a time)
                s[0] += gpu
                s[3] += 1
            s[1] += cpu
            s[2] += 1

    def report(self) -> str:
        """Frames per second and mean ms per stage since the last report (printed, kept in
        :attr:`reports`); starts the next interval."""
        now = time.perf_counter()
        frames = self.frame - self._report_frame0
        fps = frames / max(now - self._report_t0, 1e-9)
        parts = [f"{fps:.1f} fps"]
        for name in STAGES:
            if name in self._sums:
                gpu, cpu, n, n_gpu = self._sums[name]
                text = f"{name} {cpu / n:.2f} ms"
                if name in self._times.queries:
                    text += f" (gpu {format_ms(gpu / n_gpu if n_gpu else None, 'n/a')})"
                parts.append(text)
        knob = knob_text({self.config.eye: self.corrector}, self.output_size, self.state.correction)
        if knob:
            parts.append(knob)
        line = "  ".join(parts)
        self.reports.append(line)
        self.say(line)
        self._sums, self._report_t0, self._report_frame0 = {}, now, self.frame
        return line

    def _after_frame(self) -> None:
        """The report, when one is due."""
        if time.perf_counter() - self._report_t0 >= self.config.report_interval_s:
            self.report()

    def run(self) -> int:
        """Render frames until :attr:`running` is False, then report; returns the frame count."""
        while self.running:
            self.step()
        self._accumulate(self._times.collect())
        if self.frame > self._report_frame0:
            self.report()
        return self.frame

    def close(self) -> None:
        """Release every GL object, close the window and terminate GLFW."""
        if self.ctx is not None:
            for obj in (self.corrector, self.text, self.source, self._times):
                if obj is not None:
                    obj.release()
            release(self.ctx)
        self.correctors.clear()
        self.text = self.source = self._times = None
        self._close_window()
