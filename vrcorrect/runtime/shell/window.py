"""The window shell the real-time applications share (the mirror, the overlay, the headset app).

* :func:`srgb_display`: the display profile of an application, refused unless its transfer is
  sRGB (the real-time path encodes sRGB only).
* :class:`GlfwSession`: GLFW with one window and its OpenGL 4.3 core context (moderngl).
* :func:`write_screenshot`: a PNG of what a window shows.
* :class:`WindowApp`: where an application's messages go, its status line, its inputs (the
  prescription read once, the display) and its window; :class:`KeyedWindowApp` adds what the
  mirror and the overlay share: keys through a pure state machine, screenshots, frames until quit.

The keys the windows share are in :mod:`~vrcorrect.runtime.shell.keys`, the stage times of a frame
in :mod:`~vrcorrect.runtime.shell.timing`.

Layer 5: numpy, Pillow, moderngl, glfw (pyopenxr for the headset); never torch.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, Callable, Generic, Mapping, Protocol, Self, Sequence, TypeVar

import numpy as np

from ...plumbing.errors import GLUnavailableError, InputError, ValidationError, VrcorrectError
from ...plumbing.imageio import write_png
from ...specs.display import get_display
from ...specs.prescription import EyeRx, bundled_sample_path
from .. import eye_cache
from ..corrector import Corrector
from ..eye_model import CorrectorOptions, band_switches, initial_pupil_mm
from ..eye_source import EyeSource, EyeUpdate
from ..gl import download_texture, read_framebuffer
from ..optional import require_glfw, require_moderngl
from ..pupil_bank import codes_light_and_band
from ..rx_snapshot import RxSnapshot
from .keys import GLFW_PRESS, key_map_text
from .timing import StageTimes

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

    from ...specs.display import DisplayProfile

__all__ = [
    "srgb_display", "GlfwSession", "write_screenshot", "WindowApp", "KeyState", "FrameConfig", "KeyedWindowApp",
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

    #: Seconds to wait before each further attempt to reach a display that is named (``DISPLAY``):
    #: a connection refused once by a busy X server (seen once on a loaded test machine: "X11:
    #: Failed to open display :0" while that server ran) is tried again; one that stays unreachable
    #: is reported after the last.
    RETRY_DELAYS_S: tuple[float, ...] = (0.2, 0.5, 1.0)

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
        delays = self.RETRY_DELAYS_S if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") else ()
        for delay in (0.0, *delays):
            time.sleep(delay)
            if glfw.init():
                break
        else:
            reason = "; ".join(self.errors[-2:] or ["glfw.init failed"])
            tries = f", {len(delays) + 1} attempts over {sum(delays):.1f} s" if delays else ""
            self.close()
            raise GLUnavailableError(f"cannot open a window: GLFW found no display ({reason}{tries}); set DISPLAY, "
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
        The prescription file (watched by the eye source, :attr:`eye_source`) and the display profile.
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

    def _start_eyes(self, ctx: "moderngl.Context", eyes: Sequence[str], options: CorrectorOptions,
                    first: Mapping[str, Any] | None = None) -> None:
        """The :class:`~vrcorrect.runtime.eye_source.EyeSource` that owns the prescription (from its
        one read), watches the file and designs later changes off the render thread
        (:meth:`_poll_eyes`); then each eye's :class:`~vrcorrect.runtime.corrector.Corrector` of that
        source, designed now (the start: the window says "building") or taken from vrcorrect's cache
        folder where an earlier run kept it (:func:`~vrcorrect.runtime.eye_cache.start_key`), keeping
        the pupil bank's designs there too
        (:meth:`~vrcorrect.runtime.corrector.Corrector.keep_pupil_designs`).

        ``first``: each eye's first source frame (a texture of sRGB codes).  With ``pupil="auto"`` the
        first design is for the pupil of its light (:meth:`_first_light`), as a render's and the OpenXR
        layer's are, not a mid-grey frame's that the bank would leave a few seconds later."""
        self.eye_source = EyeSource(self._rx, self.display, options, eyes=tuple(eyes))
        prescription = self.eye_source.prescription
        age = options.age_years if options.age_years is not None else prescription.age_years
        auto = options.pupil == "auto" and first is not None
        lights: dict[int, tuple[float, str | None]] = {}  # by texture: a picture source gives both eyes one
        for eye in eyes:
            eye_rx = self.eye_source.eye_rx(eye)
            light, band = None, None
            if auto:
                if id(first[eye]) not in lights:
                    lights[id(first[eye])] = self._first_light(first[eye], band_switches(options))
                light, band = lights[id(first[eye])]
            pupil = initial_pupil_mm(eye_rx, self.display, options, light, age)
            # each eye's first design and the pupil bank's (pupil "auto") are kept in vrcorrect's cache
            # folder: launched again, the window starts at once and follows the light without designing
            cache_key = eye_cache.start_key(eye_rx, self.display, options, age, pupil, band or "default")
            kept = eye_cache.load_design(cache_key)
            whence = f"; pupil {pupil:.2f} mm from the first frame's light" if auto else ""
            whence += "; a page on white paper: the page band" if band == "page" else ""
            self.say(f"{'starting' if kept is not None else 'building'} the {eye} eye's correction "
                     f"({_eye_words(prescription.eye(eye))} on {self.display.name}{whence})...")
            t0 = time.perf_counter()
            self.correctors[eye] = Corrector(ctx, self.eye_source, self.display, eye, options.backend, options=options,
                                             eye_model=kept, first_luminance=light, first_band=band)
            self.correctors[eye].keep_pupil_designs()
            if kept is None:
                eye_cache.store_design(cache_key, self.correctors[eye].model)
                self.say(f"  built in {time.perf_counter() - t0:.1f} s")
            else:
                self.say(f"  designed before: taken from {eye_cache.cache_dir()} ({time.perf_counter() - t0:.1f} s)")
        self.eye_source.check = self.correctors[eyes[0]].check_eye      # a learned model's range, before each design

    def _first_light(self, texture: Any, band: bool = False) -> tuple[float, str | None]:
        """The mean relative luminance (white = 1) on the display of a source frame, ``texture`` (sRGB
        codes, 8-bit or float), read back once: what the corrector's meter measures of that frame; and
        with ``band`` its band (:func:`~vrcorrect.runtime.pupil_bank.codes_light_and_band`; else None)."""
        return codes_light_and_band(download_texture(texture), self.display, band)

    def _poll_eyes(self) -> tuple[list[EyeUpdate], list[str]]:
        """Install the eyes the :class:`~vrcorrect.runtime.eye_source.EyeSource` has designed since
        the last frame (GL work only) and return them with its messages; never waits."""
        if self.eye_source is None:
            return [], []
        updates, messages = self.eye_source.poll()
        for u in updates:
            self.correctors[u.eye].install(u.model)
        return updates, messages

    def _adjust_eye(self, eye: str, sphere_D: float = 0.0, cylinder_D: float = 0.0, axis_deg: float = 0.0) -> EyeRx:
        """Have ``eye`` redesigned with these live changes on top of those asked for so far, off the
        render thread; returns the eye it will be (``ValidationError`` at once when out of range)."""
        ds, dc, da = self.eye_source.offsets.get(eye, (0.0, 0.0, 0.0))
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
