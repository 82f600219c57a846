"""The window shell the real-time applications share (the mirror, the overlay, the headset app).

* :func:`srgb_display`: the display profile of an application, refused unless its transfer is
  sRGB (the real-time path encodes sRGB only).
* :class:`GlfwSession`: GLFW with one window and its OpenGL 4.3 core context (moderngl).
* :class:`StageTimes`: GPU timer queries and CPU clocks per stage of a frame, read a frame late.
* :func:`write_screenshot`: a PNG of what a window shows.
* Keys shared by the windows: GLFW key codes and modifier bits, :func:`key_map_text`, the
  :class:`Screenshot` and :class:`Iterations` actions and the iterations-per-frame knob of
  projected gradient (:func:`change_iterations`, :func:`knob_text`).
* :class:`WindowApp`: where an application's messages go, its status line, its inputs (the
  prescription read once, the display) and its window; :class:`KeyedWindowApp` adds what the
  mirror and the overlay share: keys through a pure state machine, screenshots, frames until quit.

Layer 5: numpy, Pillow, moderngl, glfw (pyopenxr for the headset); never torch.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, Callable, Generic, Iterable, Iterator, Mapping, Protocol, Self, Sequence, TypeVar

import numpy as np

from ...plumbing.errors import GLUnavailableError, InputError, ValidationError, VrcorrectError
from ...plumbing.imageio import write_png
from ...specs.display import get_display
from ...specs.prescription import EyeRx, bundled_sample_path
from ...specs.vocabulary import ITERATIONS_PER_FRAME, ITERATIVE_FILTERS, names
from ..corrector import Corrector, runs_iterations
from ..eye_model import CorrectorOptions
from ..eye_source import EyeSource, EyeUpdate
from ..gl import read_framebuffer, timer_query_ms
from ..optional import require_glfw, require_moderngl
from ..rx_snapshot import RxSnapshot

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

    from ...specs.display import DisplayProfile

__all__ = [
    "srgb_display", "GlfwSession", "StageTimes", "write_screenshot",
    "GLFW_PRESS", "KEY_ESCAPE", "KEY_LEFT_BRACKET", "KEY_RIGHT_BRACKET", "MOD_SHIFT", "MOD_CONTROL", "MOD_ALT",
    "MOD_SUPER", "key_letter", "key_map_text", "Screenshot", "Iterations", "ITERATION_KEYS",
    "iteration_key", "next_iterations", "change_iterations", "knob_text", "WindowApp", "KeyState",
    "FrameConfig", "KeyedWindowApp",
]

def srgb_display(name_or_path: str | Path) -> "DisplayProfile":
    """The display preset or profile ``name_or_path``, which must have the sRGB transfer.

    Raises
    ------
    ValidationError
        Another transfer (names ``--display``): the real-time path encodes sRGB only.
    """
    # lazy: the display module loads colour-science's tables, not needed to build the CLI's parser

    display = get_display(name_or_path)
    if display.transfer != "srgb":
        raise ValidationError("--display", f"{name_or_path} (transfer {display.transfer})",
                              "a display with the sRGB transfer (the real-time path encodes sRGB only)")
    return display


# --------------------------------------------------------------------------
# The window
# --------------------------------------------------------------------------


class GlfwSession:
    """GLFW, initialised for one window with an OpenGL 4.3 core context (moderngl): made in two
    steps, :meth:`__init__` (GLFW itself: monitors can be asked for) then :meth:`open`; use as
    a context manager or call :meth:`close` (terminates GLFW).

    Raises :class:`~vrcorrect.plumbing.errors.GLUnavailableError` when there is no display or no
    OpenGL 4.3 core context (the corrector's compute shaders need it).
    """

    def __init__(self, platform: str | None = None):
        glfw = require_glfw()
        self.glfw: ModuleType | None = glfw
        self.errors: list[str] = []
        self.window: Any = None                           # a GLFW window handle
        self.ctx: moderngl.Context | None = None
        self.framebuffer_size: tuple[int, int] = (0, 0)
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
        moderngl = require_moderngl()
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

    def __exit__(self, *exc: object) -> None:
        self.close()


class StageTimes:
    """GPU timer queries and CPU clocks per stage (``stages``; those in ``cpu_only`` get no
    GPU query). A frame's GPU times are read at the start of the next frame (:meth:`collect`),
    when they are ready, so nothing waits for the GPU."""

    def __init__(self, ctx: "moderngl.Context", stages: Sequence[str], cpu_only: Sequence[str] = ("present",)):
        self.queries: dict[str, moderngl.Query] = {name: ctx.query(time=True) for name in stages
                                                   if name not in cpu_only}
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
        out: dict[str, tuple[float | None, float]] = {name: (None, cpu) for name, cpu in self._cpu.items()}
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


def write_screenshot(folder: str | Path, prefix: str, pixels: np.ndarray) -> Path:
    """Write ``pixels`` (``(H, W, 3)`` uint8) to a new ``PREFIX-DATE-TIME-NNN.png`` in
    ``folder`` (made if needed); returns its path."""
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


# --------------------------------------------------------------------------
# Keys (pure)
# --------------------------------------------------------------------------

# GLFW key codes (glfw3.h: printable keys are their upper-case ASCII code) and modifier bits.
GLFW_PRESS = 1
KEY_ESCAPE = 256
KEY_LEFT_BRACKET, KEY_RIGHT_BRACKET = 91, 93      # GLFW_KEY_LEFT_BRACKET, GLFW_KEY_RIGHT_BRACKET ('[', ']')
MOD_SHIFT, MOD_CONTROL, MOD_ALT, MOD_SUPER = 0x1, 0x2, 0x4, 0x8

ITERATION_KEYS: tuple[tuple[str, str], ...] = (
    ("[ / ]", f"iterations per frame /2, x2 ({ITERATIONS_PER_FRAME.low}-{ITERATIONS_PER_FRAME.high}; "
              f"--filter {' or '.join(names(ITERATIVE_FILTERS))})"),
)
"""The knob's keys, in the mirror's, the overlay's and the headset mirror's key maps."""


@dataclass(frozen=True)
class Screenshot:
    """Write the window's picture, as shown, to a PNG."""


@dataclass(frozen=True)
class Iterations:
    """Double (``up``) or halve the projected-gradient iterations per frame (:func:`next_iterations`)."""

    up: bool


def key_letter(key: int) -> str | None:
    """The lower-case letter of a GLFW key code, or None for keys that are not letters."""
    return chr(key).lower() if ord("A") <= key <= ord("Z") else None


def key_map_text(keys: Sequence[tuple[str, str]]) -> str:
    """A key map (``(key, what)`` pairs) as printed at start: one key a line."""
    width = max(len(k) for k, _ in keys)
    return "\n".join(["keys:"] + [f"  {k:<{width}}  {what}" for k, what in keys])


def iteration_key(key: int) -> Iterations | None:
    """The knob's action for ``key`` (``[`` halves, ``]`` doubles), or None."""
    return {KEY_LEFT_BRACKET: Iterations(False), KEY_RIGHT_BRACKET: Iterations(True)}.get(key)


def next_iterations(k: int, up: bool) -> int:
    """``k`` doubled (``up``) or halved, within
    :data:`~vrcorrect.specs.vocabulary.ITERATIONS_PER_FRAME`."""
    low, high = ITERATIONS_PER_FRAME
    return min(high, max(low, 2 * k if up else k // 2))


def change_iterations(correctors: Iterable["Corrector"], up: bool) -> str:
    """Double (``up``) or halve the iterations per frame of every corrector that iterates over
    frames (:func:`runs_iterations`), all to one value (:func:`next_iterations` of the first's);
    returns the status message."""
    iterating = [c for c in correctors if runs_iterations(c)]
    if not iterating:
        return f"iterations per frame: only with --filter {' or '.join(names(ITERATIVE_FILTERS))}"
    budgeted = [c.budget for c in iterating if getattr(c, "budget", None) is not None]
    if budgeted:
        return (f"iterations per frame: chosen by the frame budget ({budgeted[0].budget_ms:g} ms, --budget-ms); "
                "run without it to set them by hand")
    k = next_iterations(iterating[0].iterations_per_frame, up)
    for c in iterating:
        c.iterations_per_frame = k
    return f"iterations per frame: {k}"


def knob_text(correctors: Mapping[str, "Corrector"], size: tuple[int, int], running: bool = True) -> str | None:
    """``"admm k 2   objective left 0.41 right 0.43 of uncorrected"`` for the correctors (by eye)
    that iterate over frames, or None when none does.  The objectives are the frame before the
    last one's (:meth:`~vrcorrect.runtime.corrector.Corrector.previous_objective_fraction`: no
    wait for the GPU); ``running`` False (correction off, or not shown) prints ``-``."""
    iterating = {eye: c for eye, c in correctors.items() if runs_iterations(c)}
    if not iterating:
        return None
    ks = sorted({c.iterations_per_frame for c in iterating.values()})
    methods = "/".join(sorted({c.options.filter for c in iterating.values()}))
    parts = []
    for eye, c in iterating.items():
        value = c.previous_objective_fraction(size) if running and c.enabled else None
        parts.append(f"{eye} {'-' if value is None else f'{value:.3f}'}")
    text = f"{methods} k {'/'.join(map(str, ks))}   objective {' '.join(parts)} of uncorrected"
    budgets = [c.budget for c in iterating.values() if getattr(c, "budget", None) is not None]
    if budgets:                                 # what the frame budget chose: iterations (mean) and window
        b = budgets[0]
        window = "" if b.fovea_deg is None else f", fovea {b.fovea_deg:.3g} deg"
        text += (f"   budget {b.budget_ms:g} ms: k " + "/".join(f"{x.q:.1f}" for x in budgets) + window
                 + ("" if b.last_ms is None else " (" + "/".join(
                     "-" if x.last_ms is None else f"{x.last_ms:.1f}" for x in budgets) + " ms)"))
    return text


# --------------------------------------------------------------------------
# The applications' shared shell
# --------------------------------------------------------------------------


class WindowApp:
    """What the mirror, the overlay and the headset app share: where messages go (``echo``:
    ``print`` by default, ``None``: nowhere), the status line, the prescription file read once
    and the display (:meth:`_read_inputs`), and the GLFW window with its context
    (:meth:`_open_window`, :meth:`_close_window`). A context manager: leaving it calls :meth:`close`.

    Attributes
    ----------
    status
        The last status message (``""`` if none).
    rx_path, display
        The prescription file (watched by the correctors) and the display profile.
    window, ctx
        The GLFW window and its moderngl context (None until opened, and after :meth:`close`).
    """

    def __init__(self, echo: Callable[[str], None] | None = print):
        self._echo = echo
        self.status = ""
        self._status_until = 0.0
        self._session: GlfwSession | None = None
        self.window: Any = None                           # a GLFW window handle
        self.ctx: moderngl.Context | None = None
        self.correctors: dict[str, Corrector] = {}
        self.eye_source: EyeSource | None = None

    def _start_eyes(self, ctx: "moderngl.Context", eyes: Sequence[str], options: CorrectorOptions) -> None:
        """Each eye's :class:`~vrcorrect.runtime.corrector.Corrector`, designed now (the start: the
        window says "building"), from the one read of the prescription; then the
        :class:`~vrcorrect.runtime.eye_source.EyeSource` that watches the file and designs later
        changes off the render thread (:meth:`_poll_eyes`)."""
        for eye in eyes:
            self.say(f"building the {eye} eye's correction ({_eye_words(self._rx.prescription.eye(eye))} on "
                     f"{self.display.name})...")
            t0 = time.perf_counter()
            self.correctors[eye] = Corrector(ctx, self._rx, self.display, eye, options.backend, options=options)
            self.say(f"  built in {time.perf_counter() - t0:.1f} s")
        first = self.correctors[eyes[0]]
        self.eye_source = EyeSource(self._rx, self.display, first.options, eyes=tuple(eyes), check=first.check_eye)

    def _poll_eyes(self) -> tuple[list[EyeUpdate], list[str]]:
        """Install the eyes the :class:`~vrcorrect.runtime.eye_source.EyeSource` has designed since
        the last frame (GL work only) and return them with its messages; never waits."""
        if self.eye_source is None:
            return [], []
        updates, messages = self.eye_source.poll()
        for u in updates:
            corrector = self.correctors[u.eye]
            corrector.install(u.model, u.prescription)
            corrector.set_offset(u.offset)
        return updates, messages

    def _adjust_eye(self, eye: str, sphere_D: float = 0.0, cylinder_D: float = 0.0, axis_deg: float = 0.0) -> EyeRx:
        """Have ``eye`` redesigned with these live changes on top of its current ones, off the render
        thread; returns the eye it will be (``ValidationError`` at once when out of range)."""
        ds, dc, da = self.correctors[eye].live_offset
        return self.eye_source.adjust(eye, (ds + sphere_D, dc + cylinder_D, da + axis_deg))

    def say(self, text: str) -> None:
        """A progress or status line for the user (to ``echo``)."""
        if self._echo is not None:
            self._echo(text)

    def set_status(self, text: str, hold_s: float | None = None) -> None:
        """Make ``text`` the status (said when it changes); ``hold_s``: seconds before
        :meth:`_expire_status` may clear it (``None``: the hold as it was)."""
        if text and text != self.status:
            self.say(text)
        self.status = text
        if hold_s is not None:
            self._status_until = time.perf_counter() + hold_s

    def _expire_status(self) -> None:
        if self.status and time.perf_counter() > self._status_until:
            self.status = ""

    def _read_inputs(self, rx: str | Path | None, display: str | Path) -> None:
        """Read the prescription once (``None``: the bundled sample; a bad file fails here, before
        any window; later edits come through the eye source, :meth:`_poll_eyes`) and the sRGB
        display."""
        # lazy: the prescription module loads its schema, not needed to build the CLI's parser

        self.rx_path = Path(rx) if rx is not None else bundled_sample_path()
        self._rx: RxSnapshot = RxSnapshot.read(self.rx_path)
        self.display = srgb_display(display)

    def _start_glfw(self, platform: str | None) -> ModuleType:
        """Initialise GLFW (``platform``: ``"x11"``, ``"wayland"`` or ``None``, GLFW's choice), so
        that monitors can be asked for before the window opens; returns the glfw module."""
        if self._session is None:
            self._session = GlfwSession(platform)
        return self.glfw

    def _open_window(self, width: int, height: int, title: str, *, platform: str | None, visible: bool,
                     vsync: bool, fullscreen: bool = False, position: tuple[int, int] | None = None) -> GlfwSession:
        """Open the window (GLFW initialised first if :meth:`_start_glfw` was not called) with
        :meth:`key_callback`, and make its context current (see :meth:`GlfwSession.open`)."""
        self._start_glfw(platform)
        session = self._session
        session.open(width, height, title, visible=visible, vsync=vsync, fullscreen=fullscreen, position=position,
                     key_callback=self.key_callback)
        self.window, self.ctx = session.window, session.ctx
        return session

    @property
    def glfw(self) -> ModuleType:
        """The glfw module of the open window."""
        if self._session is None or self._session.glfw is None:
            raise GLUnavailableError("the window is closed")
        return self._session.glfw

    def key_callback(self, window: Any, key: int, scancode: int, action: int, mods: int) -> None:
        """GLFW key callback (none by default)."""

    def _close_window(self) -> None:
        """Stop the eye source's worker, close the window and terminate GLFW (release GL objects
        first)."""
        if self.eye_source is not None:
            self.eye_source.close()
            self.eye_source = None
        if self._session is not None:
            self._session.close()
        self._session = self.window = self.ctx = None

    def close(self) -> None:
        self._close_window()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class KeyState(Protocol):
    """What :class:`KeyedWindowApp` needs of its key state (a frozen dataclass)."""

    @property
    def show_keys(self) -> bool: ...

    @property
    def running(self) -> bool: ...


class FrameConfig(Protocol):
    """What :class:`KeyedWindowApp` needs of its configuration (a frozen dataclass)."""

    @property
    def frames(self) -> int | None: ...

    @property
    def screenshot_dir(self) -> str | Path: ...

    @property
    def time_step_s(self) -> float | None: ...


StateT = TypeVar("StateT", bound=KeyState)
ActionT = TypeVar("ActionT")


class KeyedWindowApp(WindowApp, Generic[StateT, ActionT]):
    """A :class:`WindowApp` whose keys go through a pure state machine (:meth:`_next_state` on
    :attr:`state`), whose side effects (``ActionT``) run at the start of the next frame, with
    screenshots of what it shows and frames until quit: the mirror and the overlay. Subclasses
    set :attr:`key_map`, :attr:`screenshot_prefix`, ``config``, ``state`` and ``_times`` (with a
    ``present`` stage), and define :meth:`render`."""

    key_map: tuple[tuple[str, str], ...] = ()
    screenshot_prefix = "vrcorrect"
    config: FrameConfig
    state: StateT
    _times: StageTimes | None

    def __init__(self, echo: Callable[[str], None] | None = print):
        super().__init__(echo)
        self.frame = 0
        self.screenshots: list[Path] = []
        self._actions: list[ActionT] = []
        self._t0 = time.perf_counter()

    def _next_state(self, key: int, mods: int) -> tuple[StateT, tuple[ActionT, ...]]:  # pragma: no cover
        raise NotImplementedError

    def key_callback(self, window: Any, key: int, scancode: int, action: int, mods: int) -> None:
        """GLFW key callback: a key press goes through the state machine; its side effects run at
        the start of the next frame (repeats and releases are ignored)."""
        if action != GLFW_PRESS:
            return
        new, actions = self._next_state(key, mods)
        if new.show_keys and not self.state.show_keys:
            self.say(key_map_text(self.key_map))
        self.state = new
        self._actions.extend(actions)
        if not new.running and self.window is not None:
            self.glfw.set_window_should_close(self.window, True)

    def _take_actions(self) -> list[ActionT]:
        actions, self._actions = self._actions, []
        return actions

    def read_screen(self) -> np.ndarray:
        """The window's back buffer as drawn, ``(H, W, 3)`` uint8, top row first."""
        return read_framebuffer(self.ctx.screen, components=3)

    def screenshot(self) -> Path:
        """Write the back buffer (as shown) to a new PNG in ``screenshot_dir``; returns its path."""
        path = write_screenshot(self.config.screenshot_dir, self.screenshot_prefix, self.read_screen())
        self.screenshots.append(path)
        return path

    def render(self) -> bool:  # pragma: no cover - overridden
        """Draw one frame into the back buffer (no swap); True if a screenshot is due."""
        raise NotImplementedError

    def _after_frame(self) -> None:
        """What the application does after each frame's events (nothing by default)."""

    def step(self) -> None:
        """One frame: render, the screenshot if asked for, swap buffers, process events, then
        :meth:`_after_frame`."""
        glfw = self.glfw
        if self.render():
            try:
                self.set_status(f"screenshot {self.screenshot()}", hold_s=3.0)
            except VrcorrectError as exc:
                self.set_status(f"no screenshot: {exc}")
        with self._times.stage("present"):
            glfw.swap_buffers(self.window)
        self.frame += 1
        glfw.poll_events()
        self._after_frame()

    @property
    def running(self) -> bool:
        """False once quit was pressed, the window was closed, or ``frames`` were rendered."""
        if not self.state.running or self.window is None:
            return False
        if self.config.frames is not None and self.frame >= self.config.frames:
            return False
        return not self.glfw.window_should_close(self.window)

    def frame_time(self) -> float:
        """Seconds of source time for the frame about to be rendered: ``time_step_s`` per frame, or the clock."""
        step = self.config.time_step_s
        return self.frame * step if step is not None else time.perf_counter() - self._t0


def _eye_words(e: EyeRx) -> str:
    return f"{e.sphere_D:+.2f} / {e.cylinder_D:+.2f} x {e.axis_deg:.0f}"
