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
