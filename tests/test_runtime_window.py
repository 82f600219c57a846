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
