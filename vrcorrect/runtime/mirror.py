"""The desktop mirror: both eyes side by side in a GLFW window (``vrcorrect mirror``).

Each frame a source (:mod:`vrcorrect.runtime.scene`: the 3D demo scene, an image, a folder,
a video) renders one RGBA8 texture of sRGB code values per eye; each eye's
:class:`~vrcorrect.runtime.corrector.Corrector` then writes, straight into its half of the
window (left eye on the left), the displayed (corrected) image, or what that eye sees of the
display without or with the correction. A panel shows milliseconds per stage (GPU time from
timer queries, and CPU time) and the state: view, correction on or off, the eye that live
edits go to, each eye's current prescription.

Keys are handled by a pure state machine, :func:`next_state` on a frozen
:class:`MirrorState`, which returns the new state and the side effects to perform
(:class:`Adjust`, :class:`Screenshot`, :class:`Iterations`); :meth:`Mirror.key_callback` is the
GLFW key callback that feeds it. :data:`KEY_MAP` lists the keys.

With ``--filter fista`` the correction is projected-gradient iterations spread over frames, and
``[`` / ``]`` halve / double the iterations per frame live (the speed-accuracy knob, 1 to 64);
the panel shows it with each eye's objective as a fraction of uncorrected, read back a frame
late so the panel never waits for the GPU (:meth:`Corrector.previous_objective_fraction
<vrcorrect.runtime.corrector.Corrector.previous_objective_fraction>`). :func:`add_filter_options`,
:func:`filter_options`, :func:`change_iterations` and :func:`knob_text` are shared with the
overlay and the headset.

GPU objects are made when the mirror opens (the correctors make theirs on the first frame of
a size); rendering frames allocates none. Text is drawn from a glyph atlas made with
Pillow's default font at start (:func:`build_font_atlas`), as instanced quads.

Layer 5: numpy, Pillow, moderngl, glfw; never torch. One :class:`Mirror` per process at a
time (GLFW is initialised and terminated with it).
"""

from __future__ import annotations

import argparse
import math
import time
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator, Mapping, Sequence

import numpy as np

from ..plumbing.errors import GLUnavailableError, InputError, ValidationError, VrcorrectError
from .gl import format_ms, timer_query_ms
from .scene import EYES, parse_size, parse_source

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

__all__ = [
    "VIEWS", "VIEW_TITLES", "KEY_MAP", "STEP_SPHERE_D", "STEP_CYLINDER_D", "STEP_AXIS_DEG", "STAGES",
    "MirrorState", "Adjust", "Screenshot", "Iterations", "next_state", "key_map_text", "eye_viewports",
    "ITERATIONS_RANGE", "KEY_LEFT_BRACKET", "KEY_RIGHT_BRACKET", "ITERATION_KEYS", "iteration_key",
    "next_iterations", "parse_iterations_per_frame", "add_filter_options", "filter_options", "change_iterations",
    "knob_text", "FILTER_CHOICES",
    "Glyph", "FontAtlas", "build_font_atlas", "layout_text", "text_width", "panel_instances",
    "MirrorConfig", "StageTimes", "TextOverlay", "GlfwSession", "write_screenshot", "Mirror", "add_parser",
    "cmd_mirror", "parse_frames",
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

# GLFW key codes (glfw3.h: printable keys are their upper-case ASCII code) and modifier bits.
KEY_ESCAPE = 256
KEY_LEFT_BRACKET, KEY_RIGHT_BRACKET = 91, 93      # GLFW_KEY_LEFT_BRACKET, GLFW_KEY_RIGHT_BRACKET ('[', ']')
MOD_SHIFT, MOD_CONTROL, MOD_ALT, MOD_SUPER = 0x1, 0x2, 0x4, 0x8

ITERATIONS_RANGE = (1, 64)
"""The iterations-per-frame knob's range on the command line and the keys (``filter="fista"``)."""

ITERATION_KEYS: tuple[tuple[str, str], ...] = (
    ("[ / ]", f"iterations per frame /2, x2 ({ITERATIONS_RANGE[0]}-{ITERATIONS_RANGE[1]}; --filter fista)"),
)
"""The knob's keys, in the mirror's, the overlay's and the headset mirror's key maps."""

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
    edit_eye: str = "right"
    show_keys: bool = False
    show_panel: bool = True
    running: bool = True

    def __post_init__(self) -> None:
        if self.view not in VIEWS:
            raise ValidationError("view", self.view, "one of " + ", ".join(VIEWS))
        if self.edit_eye not in EYES:
            raise ValidationError("edit_eye", self.edit_eye, "'left' or 'right'")


@dataclass(frozen=True)
class Adjust:
    """Change ``eye``'s prescription live by these amounts (dioptres, degrees)."""

    eye: str
    sphere_D: float = 0.0
    cylinder_D: float = 0.0
    axis_deg: float = 0.0


@dataclass(frozen=True)
class Screenshot:
    """Write the window's picture, as shown, to a PNG."""


@dataclass(frozen=True)
class Iterations:
    """Double (``up``) or halve the projected-gradient iterations per frame (:func:`next_iterations`)."""

    up: bool


Action = Adjust | Screenshot | Iterations


def iteration_key(key: int) -> Iterations | None:
    """The knob's action for ``key`` (``[`` halves, ``]`` doubles), or None."""
    return {KEY_LEFT_BRACKET: Iterations(False), KEY_RIGHT_BRACKET: Iterations(True)}.get(key)


def next_iterations(k: int, up: bool) -> int:
    """``k`` doubled (``up``) or halved, within :data:`ITERATIONS_RANGE`."""
    low, high = ITERATIONS_RANGE
    return min(high, max(low, 2 * k if up else k // 2))


def _letter(key: int) -> str | None:
    return chr(key).lower() if ord("A") <= key <= ord("Z") else None


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
    letter = _letter(key)
    sign = 1.0 if mods & MOD_SHIFT else -1.0
    if letter == "q":
        return replace(state, running=False), ()
    if letter == "c":
        return replace(state, correction=not state.correction), ()
    if letter == "v":
        return replace(state, view=VIEWS[(VIEWS.index(state.view) + 1) % len(VIEWS)]), ()
    if letter == "e":
        return replace(state, edit_eye="left" if state.edit_eye == "right" else "right"), ()
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


def key_map_text(keys: Sequence[tuple[str, str]] = KEY_MAP) -> str:
    """The key map (``(key, what)`` pairs; the mirror's by default) as printed at start: one
    key a line."""
    width = max(len(k) for k, _ in keys)
    return "\n".join(["keys:"] + [f"  {k:<{width}}  {what}" for k, what in keys])


def eye_viewports(width: int, height: int) -> dict[str, tuple[int, int, int, int]]:
    """GL viewports ``(x, y, w, h)`` of the two halves of a ``width`` x ``height`` window:
    the left eye on the left (an odd extra column goes to the right eye)."""
    if width < 2 or height < 1:
        raise ValidationError("window size", (width, height), "at least 2 x 1 pixels")
    half = width // 2
    return {"left": (0, 0, half, height), "right": (half, 0, width - half, height)}


def _format_eye(rx, offset: tuple[float, float, float]) -> str:
    text = f"{rx.sphere_D:+.2f} / {rx.cylinder_D:+.2f} x {rx.axis_deg:.0f}"
    if any(abs(v) > 1e-9 for v in offset):
        text += f"  (live {offset[0]:+.2f} / {offset[1]:+.2f} x {offset[2]:+.0f})"
    return text


# --------------------------------------------------------------------------
# Text: a glyph atlas from Pillow's default font, laid out as quads (pure)
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class Glyph:
    """A glyph's cell in the atlas (pixels, top-left origin) and its metrics: the cell is
    drawn ``offset_x`` pixels right of the pen, which then moves ``advance`` pixels."""

    x: int
    y: int
    width: int
    height: int
    offset_x: int
    advance: int


@dataclass(frozen=True, eq=False)
class FontAtlas:
    """Coverage image ``(H, W)`` uint8 of the printable ASCII glyphs, their cells, the line
    height, and ``solid``: a fully covered cell ``(x, y, w, h)`` for filled rectangles."""

    image: np.ndarray
    glyphs: Mapping[str, Glyph]
    line_height: int
    solid: tuple[int, int, int, int]

    def glyph(self, ch: str) -> Glyph:
        """The glyph of ``ch``; characters outside the atlas are drawn as ``?``."""
        return self.glyphs.get(ch) or self.glyphs["?"]


def build_font_atlas(size_px: int = 13) -> FontAtlas:
    """Render the printable ASCII characters (32-126) with Pillow's default font at
    ``size_px`` (its bitmap font where Pillow lacks FreeType) into a coverage atlas."""
    from PIL import Image, ImageDraw, ImageFont

    if not (isinstance(size_px, int) and 6 <= size_px <= 96):
        raise ValidationError("size_px", size_px, "an integer from 6 to 96 pixels")
    try:
        font = ImageFont.load_default(size=size_px)
    except TypeError:  # pragma: no cover - Pillow without FreeType
        font = ImageFont.load_default()
    chars = [chr(c) for c in range(32, 127)]
    boxes = {ch: font.getbbox(ch) for ch in chars}
    left = min(0, min(b[0] for b in boxes.values()))
    cell_w = max(b[2] for b in boxes.values()) - left + 1
    line_h = max(max(b[3] for b in boxes.values()), size_px) + 2
    columns = 16
    rows = (len(chars) + 1 + columns - 1) // columns  # + the solid cell
    image = Image.new("L", (columns * cell_w, rows * line_h), 0)
    draw = ImageDraw.Draw(image)
    glyphs = {}
    for i, ch in enumerate(chars):
        r, c = divmod(i, columns)
        x, y = c * cell_w, r * line_h
        draw.text((x - left, y), ch, fill=255, font=font)
        glyphs[ch] = Glyph(x, y, cell_w, line_h, left, int(round(font.getlength(ch))))
    r, c = divmod(len(chars), columns)
    solid = (c * cell_w, r * line_h, cell_w, line_h)
    draw.rectangle((solid[0], solid[1], solid[0] + cell_w - 1, solid[1] + line_h - 1), fill=255)
    return FontAtlas(np.asarray(image, dtype=np.uint8).copy(), glyphs, line_h, solid)


INSTANCE_FLOATS = 12
"""Floats per drawn quad: rect (x, y, w, h), uv (left, top, right, bottom), colour RGBA."""


def _uv(atlas: FontAtlas, x: float, y: float, w: float, h: float) -> tuple[float, float, float, float]:
    height, width = atlas.image.shape
    return (x / width, 1.0 - y / height, (x + w) / width, 1.0 - (y + h) / height)


def _next_tab(pen: int, tab_stops: Sequence[int], tab_px: int) -> int:
    for stop in tab_stops:
        if stop > pen:
            return int(stop)
    return (pen // tab_px + 1) * tab_px


def layout_text(atlas: FontAtlas, lines: Sequence[str], x: int, y: int,
                colour: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0), *,
                tab_stops: Sequence[int] = (), tab_px: int = 64) -> np.ndarray:
    """Quads ``(N, 12)`` float32 drawing ``lines`` with the top-left of the first at pixel
    ``(x, y)`` (image terms), one line every ``atlas.line_height``; spaces draw nothing.

    A tab moves the pen to the next of ``tab_stops`` (pixels from ``x``), past the last one
    to the next multiple of ``tab_px``: columns in a proportional font.
    """
    if not (isinstance(tab_px, int) and tab_px >= 1):
        raise ValidationError("tab_px", tab_px, "an integer >= 1 (pixels)")
    quads = []
    for row, line in enumerate(lines):
        pen = 0
        top = int(y) + row * atlas.line_height
        for ch in line:
            if ch == "\t":
                pen = _next_tab(pen, tab_stops, tab_px)
                continue
            g = atlas.glyph(ch)
            if ch != " ":
                quads.append((int(x) + pen + g.offset_x, top, g.width, g.height,
                              *_uv(atlas, g.x, g.y, g.width, g.height), *colour))
            pen += g.advance
    return np.array(quads, np.float32).reshape(-1, INSTANCE_FLOATS)


def text_width(atlas: FontAtlas, line: str, *, tab_stops: Sequence[int] = (), tab_px: int = 64) -> int:
    """Width in pixels of ``line`` as :func:`layout_text` draws it."""
    pen = 0
    for ch in line:
        pen = _next_tab(pen, tab_stops, tab_px) if ch == "\t" else pen + atlas.glyph(ch).advance
    return pen


def panel_instances(atlas: FontAtlas, lines: Sequence[str], x: int, y: int, *,
                    text: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0),
                    background: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.7),
                    padding: int = 6, tab_stops: Sequence[int] = (),
                    tab_px: int = 64) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """A filled rectangle behind ``lines`` and the lines (see :func:`layout_text` for tabs):
    ``(quads, (x, y, w, h))``."""
    width = max((text_width(atlas, line, tab_stops=tab_stops, tab_px=tab_px) for line in lines),
                default=0) + 2 * padding
    height = len(lines) * atlas.line_height + 2 * padding
    sx, sy, sw, sh = atlas.solid
    # sample the middle of the solid cell: nearest filtering never reaches a neighbour
    back = np.array([[x, y, width, height, *_uv(atlas, sx + sw / 2 - 0.25, sy + sh / 2 - 0.25, 0.5, 0.5),
                      *background]], np.float32)
    quads = layout_text(atlas, lines, x + padding, y + padding, text, tab_stops=tab_stops, tab_px=tab_px)
    return np.concatenate([back, quads]), (x, y, width, height)


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
        :func:`~vrcorrect.runtime.scene.parse_source`).
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
        on a scene cut (:func:`start_motion`).  The demo scene is not estimated.
    """

    rx: str | Path | None = None
    display: str = "quest2"
    source: str = "demo"
    eye_size: tuple[int, int] = (640, 640)
    frames: int | None = None
    screenshot_dir: str | Path = "."
    backend: str = "glsl"
    corrector_options: Mapping[str, Any] = field(default_factory=dict)
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
        w, h = self.eye_size
        if not all(isinstance(v, int) and 1 <= v <= 8192 for v in (w, h)):
            raise ValidationError("eye_size", self.eye_size, "(width, height) in pixels, each 1 to 8192")
        if self.frames is not None and not (isinstance(self.frames, int) and self.frames >= 1):
            raise ValidationError("frames", self.frames, "None or an integer >= 1")
        if self.time_step_s is not None and not (math.isfinite(self.time_step_s) and self.time_step_s >= 0):
            raise ValidationError("time_step_s", self.time_step_s, "None or a number of seconds >= 0")
        if self.platform not in (None, "x11", "wayland"):
            raise ValidationError("platform", self.platform, "None, 'x11' or 'wayland'")


STAGES = ("scene", "correct left", "correct right", "simulate left", "simulate right", "overlay", "present")
"""Timed stages of a frame. ``present`` (swapping buffers, which waits for the display when
vsync is on) is CPU time only; the others have GPU time (timer queries) and CPU time."""


class StageTimes:
    """GPU timer queries and CPU clocks per stage (``stages``; those in ``cpu_only`` get no
    GPU query). A frame's GPU times are read at the start of the next frame (:meth:`collect`),
    when they are ready, so nothing waits for the GPU."""

    def __init__(self, ctx: "moderngl.Context", stages: Sequence[str] = STAGES,
                 cpu_only: Sequence[str] = ("present",)):
        self.queries = {name: ctx.query(time=True) for name in stages if name not in cpu_only}
        self._cpu: dict[str, float] = {}
        self._pending: list[str] = []
        self.last: dict[str, tuple[float | None, float]] = {}
        self.smoothed: dict[str, tuple[float | None, float]] = {}

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        query = self.queries.get(name)
        t0 = time.perf_counter()
        if query is None:
            yield
        else:
            with query:
                yield
            self._pending.append(name)
        self._cpu[name] = 1e3 * (time.perf_counter() - t0)

    def collect(self) -> dict[str, tuple[float | None, float]]:
        """The last frame's ``stage -> (gpu_ms or None, cpu_ms)``; updates :attr:`smoothed`."""
        out = {name: (None, cpu) for name, cpu in self._cpu.items()}
        for name in self._pending:
            out[name] = (timer_query_ms(self.queries[name].elapsed), self._cpu[name])
        self._pending, self._cpu = [], {}
        for name, (gpu, cpu) in out.items():
            old = self.smoothed.get(name)
            if old is None or (old[0] is None) != (gpu is None):
                self.smoothed[name] = (gpu, cpu)
            else:
                k = 0.1
                self.smoothed[name] = (None if gpu is None else old[0] + k * (gpu - old[0]), old[1] + k * (cpu - old[1]))
        for name in list(self.smoothed):
            if name not in out:
                del self.smoothed[name]
        self.last = out
        return out

    def release(self) -> None:
        self.queries = {}  # moderngl queries have no release(): the context frees them


class TextOverlay:
    """Draws :func:`layout_text` / :func:`panel_instances` quads over a framebuffer
    (``text.glsl``); the atlas texture and a quad buffer of fixed capacity are made once."""

    def __init__(self, ctx: "moderngl.Context", atlas: FontAtlas, capacity: int = 8192):
        from .gl import upload_texture
        from .shaders import compile_program

        self.ctx, self.atlas, self.capacity = ctx, atlas, int(capacity)
        self.texture = self.program = self.buffer = self.vao = None
        try:
            self.texture = upload_texture(ctx, atlas.image[..., None])
            self.program = compile_program(ctx, "text.glsl")
            self.buffer = ctx.buffer(reserve=self.capacity * INSTANCE_FLOATS * 4)
            self.vao = ctx.vertex_array(self.program, [(self.buffer, "4f 4f 4f/i", "in_rect", "in_uv", "in_colour")])
            self.program["u_atlas"].value = 0
        except BaseException:
            self.release()
            raise

    def draw(self, quads: np.ndarray, framebuffer: "moderngl.Framebuffer", size: tuple[int, int]) -> None:
        """Draw ``quads`` (at most :attr:`capacity`; more are cut) over ``framebuffer`` of ``size``."""
        import moderngl

        n = min(len(quads), self.capacity)
        if n == 0:
            return
        self.buffer.write(np.ascontiguousarray(quads[:n], np.float32).tobytes())
        framebuffer.use()
        self.ctx.viewport = (0, 0, *size)
        self.program["u_target_size"].value = (float(size[0]), float(size[1]))
        self.texture.use(0)
        self.ctx.enable(moderngl.BLEND)
        self.ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
        try:
            self.vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=n)
        finally:
            self.ctx.disable(moderngl.BLEND)

    def release(self) -> None:
        from .gl import release

        release(self.vao, self.buffer, self.program, self.texture)
        self.vao = self.buffer = self.program = self.texture = None


# --------------------------------------------------------------------------
# The window
# --------------------------------------------------------------------------


def _glfw():
    try:
        import glfw
    except ImportError as exc:  # pragma: no cover - the realtime extra is installed in CI
        raise GLUnavailableError(f"glfw is not installed ({exc}); install the realtime extra: "
                                 "pip install -e '.[realtime]'") from None
    return glfw


class GlfwSession:
    """GLFW, initialised for one window with an OpenGL 4.3 core context (moderngl): made in two
    steps, :meth:`__init__` (GLFW itself: monitors can be asked for) then :meth:`open`; use as
    a context manager or call :meth:`close` (terminates GLFW).

    Raises :class:`~vrcorrect.plumbing.errors.GLUnavailableError` when there is no display or no
    OpenGL 4.3 core context (the corrector's compute shaders need it).
    """

    def __init__(self, platform: str | None = None):
        glfw = self.glfw = _glfw()
        self.errors: list[str] = []
        self.window = self.ctx = None
        self.framebuffer_size = (0, 0)
        self._initialised = False
        self._previous_error_callback = glfw.set_error_callback(
            lambda code, text: self.errors.append(text.decode(errors="replace") if isinstance(text, bytes) else text))
        if platform is not None:
            glfw.init_hint(glfw.PLATFORM, glfw.PLATFORM_X11 if platform == "x11" else glfw.PLATFORM_WAYLAND)
        if not glfw.init():
            reason = "; ".join(self.errors[-2:] or ["glfw.init failed"])
            self.close()
            raise GLUnavailableError(f"cannot open a window: GLFW found no display ({reason}); set DISPLAY, "
                                     "or run under xvfb-run")
        self._initialised = True

    def open(self, width: int, height: int, title: str, *, visible: bool = True, vsync: bool = True,
             fullscreen: bool = False, position: tuple[int, int] | None = None,
             key_callback: Callable[..., None] | None = None) -> None:
        """Open the window (``fullscreen``: on the primary monitor, at its current video mode,
        ``width`` and ``height`` ignored; ``position``: top-left corner on the screen) and make
        its context current."""
        import moderngl

        glfw = self.glfw
        glfw.default_window_hints()
        glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 4)
        glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
        glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
        glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
        glfw.window_hint(glfw.VISIBLE, False)
        glfw.window_hint(glfw.RESIZABLE, False)
        monitor = None
        if fullscreen:
            monitor = glfw.get_primary_monitor()
            mode = glfw.get_video_mode(monitor) if monitor else None
            if not mode:
                raise GLUnavailableError("no monitor to go full-screen on; use a window (--window WxH)")
            width, height = mode.size.width, mode.size.height
            glfw.window_hint(glfw.REFRESH_RATE, mode.refresh_rate)
        self.window = glfw.create_window(int(width), int(height), title, monitor, None)
        if not self.window:
            raise GLUnavailableError("cannot open a window with an OpenGL 4.3 core context (the corrector's compute "
                                     "shaders need it): " + "; ".join(self.errors[-2:] or ["no reason given"]))
        if position is not None and monitor is None:
            glfw.set_window_pos(self.window, *position)
        if visible:
            glfw.show_window(self.window)
        glfw.make_context_current(self.window)
        glfw.swap_interval(1 if vsync else 0)
        try:
            self.ctx = moderngl.create_context(require=430)
        except Exception as exc:
            raise GLUnavailableError(f"no OpenGL 4.3 context on the window ({exc})") from None
        self.framebuffer_size = tuple(glfw.get_framebuffer_size(self.window))
        if key_callback is not None:
            glfw.set_key_callback(self.window, key_callback)

    def close(self) -> None:
        """Close the window and terminate GLFW (release GL objects first)."""
        glfw = self.glfw
        if glfw is None:
            return
        if self.window is not None:
            glfw.destroy_window(self.window)
            self.window = None
        if self._initialised:
            glfw.terminate()
            self._initialised = False
        glfw.set_error_callback(self._previous_error_callback)
        self.glfw = self.ctx = None

    def __enter__(self) -> "GlfwSession":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def write_screenshot(folder: str | Path, prefix: str, pixels: np.ndarray) -> Path:
    """Write ``pixels`` (``(H, W, 3)`` uint8) to a new ``PREFIX-DATE-TIME-NNN.png`` in
    ``folder`` (made if needed); returns its path."""
    from ..plumbing.imageio import write_png

    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{folder}: cannot make the screenshot folder ({exc.strerror or exc})") from None
    stamp = time.strftime("%Y%m%d-%H%M%S")
    for n in range(1000):
        path = folder / f"{prefix}-{stamp}-{n:03d}.png"
        if not path.exists():
            write_png(path, pixels.astype(np.float32) / 255.0)
            return path
    raise InputError(f"{folder}: too many screenshots this second")


class Mirror:
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
        ``{"left": Corrector, "right": Corrector}``.
    source
        The eye source (:func:`~vrcorrect.runtime.scene.open_source`).
    status
        The last status message ("" if none).
    timings_ms
        The last collected frame's ``stage -> (gpu_ms or None, cpu_ms)``.
    frame
        Frames rendered so far.
    """

    def __init__(self, config: MirrorConfig = MirrorConfig(), *, echo: Callable[[str], None] | None = print):
        from ..specs.display import get_display
        from ..specs.prescription import bundled_sample_path
        from .corrector import RxSnapshot

        self.config = config
        self._echo = echo
        self.rx_path = Path(config.rx) if config.rx is not None else bundled_sample_path()
        # read once: both eyes are built from this parse; later edits (during the builds too) come
        # through each corrector's poll
        self._rx = RxSnapshot.read(self.rx_path)
        prescription = self._rx.prescription
        self.display = get_display(config.display)
        if self.display.transfer != "srgb":
            raise ValidationError("--display", f"{config.display} (transfer {self.display.transfer})",
                                  "a display with the sRGB transfer (the real-time path encodes sRGB only)")
        self.spec = parse_source(config.source)
        self.state = MirrorState(show_panel=config.panel)
        self.status = ""
        self.frame = 0
        self.timings_ms: dict[str, tuple[float | None, float]] = {}
        self.screenshots: list[Path] = []
        self._base = {eye: prescription.eye(eye) for eye in EYES}
        self._offsets = {eye: (0.0, 0.0, 0.0) for eye in EYES}
        self._actions: list[Action] = []
        self._glfw_mod = self._session = None
        self.window = self.ctx = self.source = self.overlay = self._times = None
        self.correctors: dict[str, Any] = {}
        self._frame_ms: float | None = None
        self._last_frame_end: float | None = None
        try:
            self._open_window()
            self._build()
        except BaseException:
            self.close()
            raise
        self._t0 = time.perf_counter()

    # ------------------------------------------------------------ set-up

    def _say(self, text: str) -> None:
        if self._echo is not None:
            self._echo(text)

    def _open_window(self) -> None:
        cfg = self.config
        session = self._session = GlfwSession(cfg.platform)
        self._glfw_mod = session.glfw
        w, h = cfg.eye_size
        session.open(2 * w, h, cfg.title, visible=cfg.visible, vsync=cfg.vsync, key_callback=self.key_callback)
        self.window, self.ctx, self.framebuffer_size = session.window, session.ctx, session.framebuffer_size

    def _build(self) -> None:
        from .corrector import Corrector
        from .gl import check_gl_errors
        from .scene import open_source

        cfg, ctx = self.config, self.ctx
        self.source = open_source(ctx, self.spec, *cfg.eye_size, folder_interval_s=cfg.folder_interval_s)
        for eye in EYES:
            self._say(f"building the {eye} eye's correction ({self._rx_text(eye)} on {self.display.name})...")
            t0 = time.perf_counter()
            self.correctors[eye] = Corrector(ctx, self._rx, self.display, eye, cfg.backend,
                                             **dict(cfg.corrector_options))
            self._say(f"  built in {time.perf_counter() - t0:.1f} s")
        start_motion(self.source, self.correctors.values(), cfg.reprojection)
        atlas = build_font_atlas(cfg.font_px)
        self.overlay = TextOverlay(ctx, atlas)
        gap = cfg.font_px
        first = max(text_width(atlas, name) for name in STAGES + EYES) + gap
        number = text_width(atlas, "00000.00") + gap
        self._tab_stops = (first, first + number)
        self._key_tab_stops = (max(text_width(atlas, k) for k, _ in KEY_MAP) + gap,)
        self._times = StageTimes(ctx)
        check_gl_errors(ctx, "mirror set-up")

    # ------------------------------------------------------------ state

    def current_rx(self, eye: str):
        """``eye``'s prescription as corrected now: the file's, plus the live changes."""
        base, (ds, dc, da) = self._base[eye], self._offsets[eye]
        return base.with_changes(sphere_D=base.sphere_D + ds, cylinder_D=base.cylinder_D + dc,
                                 axis_deg=(base.axis_deg + da) % 180.0)

    def _rx_text(self, eye: str) -> str:
        return _format_eye(self.current_rx(eye), self._offsets[eye])

    def _set_status(self, text: str) -> None:
        if text and text != self.status:
            self._say(text)
        self.status = text

    def key_callback(self, window: Any, key: int, scancode: int, action: int, mods: int) -> None:
        """GLFW key callback: a key press goes through :func:`next_state`; its side effects
        run at the start of the next frame (repeats and releases are ignored)."""
        if action != 1:  # GLFW_PRESS
            return
        new, actions = next_state(self.state, key, mods)
        if new.show_keys and not self.state.show_keys:
            self._say(key_map_text())
        self.state = new
        self._actions.extend(actions)
        if not new.running and self.window is not None:
            self._glfw_mod.set_window_should_close(self.window, True)

    def _run_actions(self) -> bool:
        """Perform queued side effects; True if a screenshot is due after this frame."""
        screenshot = False
        actions, self._actions = self._actions, []
        for action in actions:
            if isinstance(action, Screenshot):
                screenshot = True
            elif isinstance(action, Adjust):
                self._adjust(action)
            elif isinstance(action, Iterations):
                self._set_status(change_iterations(self.correctors.values(), action.up))
        return screenshot

    def _adjust(self, a: Adjust) -> None:
        eye = a.eye
        ds, dc, da = self._offsets[eye]
        new = (ds + a.sphere_D, dc + a.cylinder_D, da + a.axis_deg)
        self._say(f"{eye} eye: rebuilding the correction ...")
        t0 = time.perf_counter()
        try:
            self.correctors[eye].adjust(sphere_D=a.sphere_D, cylinder_D=a.cylinder_D, axis_deg=a.axis_deg)
        except VrcorrectError as exc:
            self._set_status(f"{eye} eye unchanged: {' '.join(str(exc).split())}")
            return
        self._offsets[eye] = new
        self._set_status(f"{eye} eye now {self._rx_text(eye)} (rebuilt in {time.perf_counter() - t0:.1f} s)")

    def _poll(self) -> None:
        for eye in EYES:
            corrector = self.correctors[eye]
            if corrector.poll():
                # what the corrector now corrects for, from its own read of the file (not a second read)
                self._base[eye] = corrector.prescription.eye(eye)
                self._set_status(f"{self.rx_path.name} reloaded: {eye} eye {self._rx_text(eye)}")
            elif corrector.status and corrector.status != self.status:
                self._set_status(corrector.status)

    # ------------------------------------------------------------ frames

    def scene_time(self) -> float:
        """Seconds of scene time for the frame about to be rendered."""
        step = self.config.time_step_s
        return self.frame * step if step is not None else time.perf_counter() - self._t0

    def panel_lines(self) -> list[str]:
        """The panel's text for the current state and the smoothed stage times."""
        s = self.state
        w, h = self.config.eye_size
        lines = [f"vrcorrect mirror  {self.display.name}  {w}x{h} per eye  {self.source.label}",
                 f"view: {VIEW_TITLES[s.view]}   correction {'ON' if s.correction else 'OFF'}   "
                 f"edits: {s.edit_eye} eye"]
        for eye in EYES:
            lines.append(f"{eye}\t{self._rx_text(eye)}")
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
        if self.status:
            lines.append(self.status[:120])
        lines.append("h: keys")
        return lines

    def render(self) -> bool:
        """Draw one frame into the window's back buffer (no swap). Returns True if a
        screenshot was asked for (taken by :meth:`step` before the swap)."""
        from .gl import check_gl_errors

        self.timings_ms = self._times.collect()
        screenshot = self._run_actions()
        self._poll()
        ctx, state = self.ctx, self.state
        for c in self.correctors.values():
            c.enabled = state.correction
        with self._times.stage("scene"):
            textures = dict(zip(EYES, self.source.render(self.scene_time())))
            motion = take_motion(self.source, self.correctors.values())
        screen = ctx.screen
        viewports = eye_viewports(*self.framebuffer_size)
        for eye in EYES:
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
                lines = ["keys"] + [f"{k}\t{what}" for k, what in KEY_MAP]
                x = viewports["right"][0] + 8 if state.show_panel else 8
                quads.append(panel_instances(atlas, lines, x, 8, background=(0.05, 0.1, 0.25, 0.85),
                                             tab_stops=self._key_tab_stops)[0])
            if quads:
                self.overlay.draw(np.concatenate(quads), screen, self.framebuffer_size)
        check_gl_errors(ctx, f"mirror frame {self.frame}")
        return screenshot

    def read_screen(self) -> np.ndarray:
        """The window's back buffer as drawn, ``(H, W, 3)`` uint8, top row first."""
        from .gl import read_framebuffer

        return read_framebuffer(self.ctx.screen, components=3)

    def screenshot(self) -> Path:
        """Write the back buffer (both halves, panel included when shown) to a new PNG in
        ``screenshot_dir``; returns its path."""
        path = write_screenshot(self.config.screenshot_dir, "vrcorrect-mirror", self.read_screen())
        self.screenshots.append(path)
        return path

    def step(self) -> None:
        """One frame: render, the screenshot if asked for, swap buffers, process events."""
        glfw = self._glfw_mod
        shot = self.render()
        if shot:
            try:
                self._set_status(f"screenshot {self.screenshot()}")
            except VrcorrectError as exc:
                self._set_status(f"no screenshot: {exc}")
        with self._times.stage("present"):
            glfw.swap_buffers(self.window)
        self.frame += 1
        now = time.perf_counter()
        if self._last_frame_end is not None:
            ms = 1e3 * (now - self._last_frame_end)
            self._frame_ms = ms if self._frame_ms is None else self._frame_ms + 0.1 * (ms - self._frame_ms)
        self._last_frame_end = now
        glfw.poll_events()

    @property
    def running(self) -> bool:
        """False once quit was pressed, the window was closed, or ``frames`` were rendered."""
        if not self.state.running or self.window is None:
            return False
        if self.config.frames is not None and self.frame >= self.config.frames:
            return False
        return not self._glfw_mod.window_should_close(self.window)

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
        from .gl import release

        if self.ctx is not None:
            for c in self.correctors.values():
                c.release()
            for obj in (self.overlay, self.source, self._times):
                if obj is not None:
                    obj.release()
            release(self.ctx)
        self.correctors, self.overlay, self.source, self._times, self.ctx = {}, None, None, None, None
        if self._session is not None:
            self._session.close()
        self.window, self._session, self._glfw_mod = None, None, None

    def __enter__(self) -> "Mirror":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


# --------------------------------------------------------------------------
# Command line: vrcorrect mirror
# --------------------------------------------------------------------------


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``mirror`` sub-command to an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        "mirror", help="a window with both eyes side by side, corrected live (keys: press h)",
        description=("Open a window showing both eyes side by side (left eye on the left): the displayed,\n"
                     "pre-corrected image or what each eye sees of it, with live prescription edits,\n"
                     "screenshots and stage timings. Needs a display (X11/Wayland) and OpenGL 4.3."),
        epilog=key_map_text(), formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rx", metavar="RX.json", help="prescription (default: the bundled sample); reloaded when it "
                                                   "changes on disk")
    p.add_argument("--display", default="quest2", metavar="PRESET",
                   help="display preset or profile .json (default quest2; list: vrcorrect displays)")
    p.add_argument("--source", default="demo", metavar="demo|IMAGE|VIDEO|DIR",
                   help="the built-in 3D scene (default), an image, a video (or animated GIF/PNG/WebP), "
                        "or a folder of images shown in turn")
    p.add_argument("--size", default="640x640", metavar="WxH",
                   help="each eye's size in pixels (default 640x640; the window is twice as wide)")
    p.add_argument("--frames", metavar="N", help="render N frames and exit (tests, CI)")
    p.add_argument("--screenshot-dir", default=".", metavar="DIR", help="where p writes screenshots (default .)")
    p.add_argument("--backend", choices=("glsl", "onnx"), default="glsl",
                   help="correction backend: glsl (default) or onnx (a learned model per eye)")
    p.add_argument("--model", metavar="MODEL.onnx",
                   help="ONNX model for --backend onnx (default: models/default.onnx)")
    add_filter_options(p)
    add_reprojection_option(p)
    p.set_defaults(func=cmd_mirror)
    return p


def parse_frames(text: str | None, field: str = "--frames", most: int = 10_000_000) -> int | None:
    """Check ``--frames``: ``None`` (run until closed) or a whole number from 1 to ``most``."""
    if text is None:
        return None
    try:
        value = int(text)
    except ValueError:
        value = 0
    if not 1 <= value <= most:
        raise ValidationError(field, text, f"a whole number of frames from 1 to {most}")
    return value


def parse_iterations_per_frame(text: str | int | None, field: str = "--iterations-per-frame") -> int | None:
    """Check ``--iterations-per-frame``: ``None`` (the default) or a whole number in
    :data:`ITERATIONS_RANGE`."""
    if text is None:
        return None
    low, high = ITERATIONS_RANGE
    try:
        value = int(text)
    except (TypeError, ValueError):
        value = low - 1
    if isinstance(text, bool) or not low <= value <= high:
        raise ValidationError(field, text, f"a whole number of iterations from {low} to {high}")
    return value


FILTER_CHOICES = ("fista", "fft", "separable")


def add_filter_options(p: argparse.ArgumentParser) -> None:
    """``--filter`` and ``--iterations-per-frame`` (``render``, ``mirror``, ``overlay``, ``xr``)."""
    low, high = ITERATIONS_RANGE
    p.add_argument("--filter", choices=FILTER_CHOICES, default="fista",
                   help="GLSL strategy: fista (default; projected-gradient iterations on the true objective, "
                        "warm-started from frame to frame, converging to the optimum over frames), fft (one pass of "
                        "the regularised inverse by FFT compute shaders, blended per frame: cheaper, further from "
                        "the optimum) or separable (low-rank spatial filters of that inverse)")
    p.add_argument("--iterations-per-frame", metavar="K",
                   help=f"with --filter fista: iterations per frame, {low} to {high} (default 4; the speed-accuracy "
                        "knob)")


def filter_options(args: argparse.Namespace) -> dict[str, Any]:
    """The :class:`~vrcorrect.runtime.corrector.Corrector` options of :func:`add_filter_options`'s
    arguments (checked: one line naming the option when wrong)."""
    k = parse_iterations_per_frame(args.iterations_per_frame)
    options: dict[str, Any] = {"filter": args.filter}
    if k is not None:
        if args.filter != "fista":
            raise ValidationError("--iterations-per-frame", args.iterations_per_frame, "only with --filter fista")
        options["iterations_per_frame"] = k
    return options


def add_reprojection_option(p: argparse.ArgumentParser) -> None:
    """``--no-reprojection`` (``mirror``, ``overlay``, ``xr``)."""
    p.add_argument("--no-reprojection", action="store_true",
                   help="with --filter fista: warm-start each frame from the previous solution as it was, instead "
                        "of moved by the motion since the last frame (an image, folder, video or screen source: "
                        "the pictures' estimated shift, with a cold start on a scene cut; xr's demo scene: the "
                        "turn of the tracked head)")


def _fista_glsl(correctors: Any) -> list:
    return [c for c in correctors if c.backend == "glsl" and c.options.filter == "fista"]


def start_motion(source: Any, correctors: Any, reprojection: bool = True) -> bool:
    """Have a CPU source (one with ``track_motion``: image, folder, video, screen) estimate its
    pictures' motion when ``reprojection`` is on and a corrector runs projected gradient; returns
    whether it does.  The demo scene is rendered on the GPU and its motion (a 3D camera and objects)
    is not a global shift: it keeps the plain warm start."""
    if reprojection and _fista_glsl(correctors) and hasattr(source, "track_motion"):
        source.track_motion()
        return True
    return False


def take_motion(source: Any, correctors: Any) -> tuple[int, int] | None:
    """The ``motion_px`` for this frame's ``Corrector.apply`` from ``source`` (:func:`start_motion`),
    after its ``render``; on a scene cut the projected-gradient correctors are reset (cold start)
    and ``None`` is returned."""
    take = getattr(source, "take_motion", None)
    motion = take() if take is not None else (0, 0)
    if motion == "cut":
        for c in _fista_glsl(correctors):
            c.reset()
        return None
    return motion


def change_iterations(correctors: Any, up: bool) -> str:
    """Double (``up``) or halve the iterations per frame of every corrector running projected
    gradient (``filter="fista"``, GLSL backend), all to one value (:func:`next_iterations` of the
    first's); returns the status message."""
    fista = [c for c in correctors if c.backend == "glsl" and c.options.filter == "fista"]
    if not fista:
        return "iterations per frame: only with --filter fista"
    k = next_iterations(fista[0].iterations_per_frame, up)
    for c in fista:
        c.iterations_per_frame = k
    return f"iterations per frame: {k}"


def knob_text(correctors: Mapping[str, Any], size: tuple[int, int], running: bool = True) -> str | None:
    """``"fista k 4   objective left 0.41 right 0.43 of uncorrected"`` for the correctors (by eye)
    that run projected gradient, or None when none does.  The objectives are the frame before the
    last one's (:meth:`~vrcorrect.runtime.corrector.Corrector.previous_objective_fraction`: no
    wait for the GPU); ``running`` False (correction off, or not shown) prints ``-``."""
    fista = {eye: c for eye, c in correctors.items() if c.backend == "glsl" and c.options.filter == "fista"}
    if not fista:
        return None
    ks = sorted({c.iterations_per_frame for c in fista.values()})
    parts = []
    for eye, c in fista.items():
        value = c.previous_objective_fraction(size) if running and c.enabled else None
        parts.append(f"{eye} {'-' if value is None else f'{value:.3f}'}")
    return f"fista k {'/'.join(map(str, ks))}   objective {' '.join(parts)} of uncorrected"


def cmd_mirror(args: argparse.Namespace) -> int:
    """``vrcorrect mirror``: check the arguments, open the mirror, run it, print a summary."""
    from .model_path import model_for_backend

    frames = parse_frames(args.frames)
    options = filter_options(args)
    model = model_for_backend(args.backend, args.model)
    if model:
        options["model"] = model
    config = MirrorConfig(rx=args.rx, display=args.display, source=args.source, eye_size=parse_size(args.size),
                          frames=frames, screenshot_dir=args.screenshot_dir, vsync=frames is None,
                          backend=args.backend, corrector_options=options, reprojection=not args.no_reprojection)
    parse_source(config.source)  # fail on a bad source before anything slow
    print(key_map_text())
    t0 = time.perf_counter()
    with Mirror(config) as mirror:
        t1 = time.perf_counter()
        mirror.run()
        t2 = time.perf_counter()
        n = mirror.frame
        print(f"{n} frame(s) in {t2 - t1:.2f} s ({1e3 * (t2 - t1) / max(n, 1):.1f} ms per frame; "
              f"set-up {t1 - t0:.1f} s) on {mirror.ctx.info.get('GL_RENDERER', '?')}")
        for name, (gpu, cpu) in mirror.timings_ms.items():
            print(f"  {name:<15} gpu {format_ms(gpu)} ms, cpu {cpu:.2f} ms (last frame)")
        knob = knob_text(mirror.correctors, config.eye_size, mirror.state.correction)
        if knob:
            print(f"  {knob}")
        for path in mirror.screenshots:
            print(f"wrote {path}")
    return 0
