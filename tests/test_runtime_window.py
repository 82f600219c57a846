"""Smoke test of the windowed path: a GLFW window with an OpenGL 3.3 core context on an X
display (a private Xvfb from conftest.py when DISPLAY is not set), moderngl on it, and a
read-back of its default framebuffer."""

from __future__ import annotations

import pytest

from vrcorrect.runtime import gl as G


@pytest.fixture
def glfw_window(x_display):
    """A hidden 64 x 48 GLFW window whose OpenGL 3.3 core context is current."""
    import glfw

    errors: list[str] = []
    previous_reporting = glfw.ERROR_REPORTING
    glfw.ERROR_REPORTING = "raise"
    glfw.set_error_callback(lambda code, text: errors.append(f"{code:#x}: {text!r}"))
    glfw.init_hint(glfw.PLATFORM, glfw.PLATFORM_X11)  # the display fixture is an X server
    if not glfw.init():
        pytest.fail(f"glfw.init() failed on DISPLAY={x_display}: {errors}")
    try:
        glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
        glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
        glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
        glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
        glfw.window_hint(glfw.VISIBLE, False)
        window = glfw.create_window(64, 48, "vrcorrect test", None, None)
        if not window:
            pytest.fail(f"no GLFW window on DISPLAY={x_display}: {errors}")
        glfw.make_context_current(window)
        yield window
        glfw.make_context_current(None)
        glfw.destroy_window(window)
    finally:
        glfw.terminate()
        glfw.set_error_callback(None)
        glfw.ERROR_REPORTING = previous_reporting


def test_window_context_clears_and_reads_back(glfw_window):
    import glfw
    import moderngl

    ctx = moderngl.create_context(require=330)
    assert ctx.version_code >= 330
    assert glfw.get_framebuffer_size(glfw_window) == ctx.screen.size == (64, 48)
    ctx.screen.use()
    ctx.clear(0.25, 0.5, 0.75, 1.0)
    pixels = G.read_framebuffer(ctx.screen, components=4)
    assert pixels.shape == (48, 64, 4)
    assert (pixels == (64, 128, 191, 255)).all()  # 0.25 * 255 = 63.75 -> 64, 0.75 * 255 -> 191

    # orientation of the default framebuffer too: GL y = 0 is the bottom, read back last
    ctx.scissor = (0, 0, 64, 8)
    ctx.clear(1.0, 0.0, 0.0, 1.0)
    ctx.scissor = None
    pixels = G.read_framebuffer(ctx.screen)
    assert (pixels[-8:] == (255, 0, 0)).all() and (pixels[:-8] == (64, 128, 191)).all()
    G.check_gl_errors(ctx, "window test")
    glfw.swap_buffers(glfw_window)
    glfw.poll_events()
    G.check_gl_errors(ctx, "after swap")
    ctx.release()


_AFTER_EGL = """
import sys
from vrcorrect.runtime.gl import headless_context
from vrcorrect.runtime.glcache import egl_context
for make in (lambda: headless_context(require=430), lambda: egl_context(430, cache=False)):
    ctx = make()
    ctx.release()
from vrcorrect.runtime.shell.window import GlfwSession
with GlfwSession(platform="x11") as window:
    window.open(64, 48, "after EGL", visible=False, vsync=False)
    print("window", window.ctx.version_code, flush=True)
"""


def test_a_window_opens_on_a_thread_whose_headless_contexts_were_released(x_display, tmp_path):
    """A headless context (``headless_context``, ``egl_context``) released, then a GLFW window on
    the same thread: glcontext leaves a released EGL context current, and libglvnd then refuses the
    thread a GLX context (``BadAccess`` in ``glXMakeCurrent``, and Xlib ends the process).  Released
    contexts are no longer current, so the window opens.  (A process of its own: the failure ends it.)"""
    import os
    import subprocess
    import sys

    env = dict(os.environ, DISPLAY=x_display)
    result = subprocess.run([sys.executable, "-c", _AFTER_EGL], env=env, capture_output=True, text=True,
                            timeout=120, cwd=tmp_path)
    assert result.returncode == 0 and "window " in result.stdout, (result.returncode, result.stdout,
                                                                   result.stderr[-2000:])


_LATE_DISPLAY = """
import sys
import glfw
from vrcorrect.plumbing.errors import GLUnavailableError
real_init = glfw.init
def init():                                        # each attempt said, so the test knows when to start X
    ok = real_init()
    print("attempt", bool(ok), flush=True)
    return ok
glfw.init = init
from vrcorrect.runtime.shell.window import GlfwSession
GlfwSession.RETRY_DELAYS_S = tuple(float(d) for d in sys.argv[1].split(","))
try:
    with GlfwSession(platform="x11") as window:
        window.open(64, 48, "late display", visible=False, vsync=False)
        print("window", window.ctx.version_code, flush=True)
except GLUnavailableError as e:
    print("refused:", e, flush=True)
"""


def _free_display_number() -> int:
    import os

    for number in range(200 + os.getpid() % 300, 1000):
        if not os.path.exists(f"/tmp/.X{number}-lock") and not os.path.exists(f"/tmp/.X11-unix/X{number}"):
            return number
    raise AssertionError("no free X display number")


def test_a_display_that_answers_late_is_tried_again(tmp_path):
    """An X server that is not yet accepting connections when the window is asked for (a busy test
    machine refused one once) is tried again: here Xvfb starts on the named display half a second
    after the window's first attempt, and the window opens."""
    import os
    import shutil
    import subprocess
    import sys

    from conftest import stop_process

    number = _free_display_number()
    env = dict(os.environ, DISPLAY=f":{number}")
    client = subprocess.Popen([sys.executable, "-c", _LATE_DISPLAY, "1,2,4,8"], env=env, cwd=tmp_path,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = client.stdout.readline()                   # the first attempt has failed: no server yet
    server = subprocess.Popen([shutil.which("Xvfb"), f":{number}", "-screen", "0", "320x240x24", "-nolisten", "tcp"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        out, err = client.communicate(timeout=120)
    finally:
        stop_process(server)
    assert first == "attempt False\n", (first, out, err[-2000:])
    assert client.returncode == 0 and "attempt True" in out and "window " in out, (out, err[-2000:])


def test_a_display_that_never_answers_is_reported_after_the_tries(tmp_path):
    import os
    import subprocess
    import sys

    number = _free_display_number()
    env = dict(os.environ, DISPLAY=f":{number}")
    result = subprocess.run([sys.executable, "-c", _LATE_DISPLAY, "0.01,0.01"], env=env, cwd=tmp_path,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    lines = result.stdout.splitlines()
    assert lines[:3] == ["attempt False"] * 3 and len(lines) == 4, result.stdout
    assert lines[3].startswith("refused: cannot open a window: GLFW found no display"), result.stdout
    assert "3 attempts over 0.0 s" in lines[3] and f":{number}" in lines[3], result.stdout
