"""The overlay compositor (``vrcorrect overlay``): its pure parts (keys, window placement
beside the grabbed region, defaults), and, under Xvfb (conftest.py's ``x_display``), the
window against the real Corrector's output, the correction toggle, the X11 screen grab of a
known picture put on the screen by another X client, prescription hot reload, and the
command line."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from vrcorrect.specs.display import get_display
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.runtime import gl as G
from vrcorrect.runtime.gl import Rect
from vrcorrect.runtime.shell.overlay import (
    KEY_MAP, Overlay, OverlayConfig, OverlayState, default_display, default_region, full_screen_region,
    next_state, place_window, rects_overlap,
)
from vrcorrect.runtime.shell.source_spec import parse_region
from vrcorrect.runtime.shell.keys import KEY_ESCAPE, KEY_LEFT_BRACKET, KEY_RIGHT_BRACKET, MOD_CONTROL, Iterations, Screenshot

REPO = Path(__file__).resolve().parents[1]
SAMPLE_RX = (REPO / "vrcorrect" / "data" / "sample_rx.json").read_text()
W, H = 40, 32
GLFW_PRESS, GLFW_RELEASE = 1, 0


def key(ch: str) -> int:
    return ord(ch.upper())


# --------------------------------------------------------------------------
# Pure parts
# --------------------------------------------------------------------------


def test_keys():
    s = OverlayState()
    assert next_state(s, key("c")) == (OverlayState(correction=False), ())
    assert next_state(s, key("h")) == (OverlayState(show_keys=True), ())
    assert next_state(s, key("p")) == (s, (Screenshot(),))
    for k in (KEY_ESCAPE, key("q")):
        assert not next_state(s, k)[0].running
    assert next_state(s, key("c"), MOD_CONTROL) == (s, ())
    for ch in "vesyaxz":
        assert next_state(s, key(ch)) == (s, ())
    assert next_state(s, KEY_LEFT_BRACKET) == (s, (Iterations(up=False),))
    assert next_state(s, KEY_RIGHT_BRACKET) == (s, (Iterations(up=True),))
    assert next_state(s, KEY_RIGHT_BRACKET, MOD_CONTROL) == (s, ())
    assert [k for k, _ in KEY_MAP] == ["c", "p", "[ / ]", "h", "Esc / q"]


@pytest.mark.parametrize("text, rect", [("0,0,640,480", (0, 0, 640, 480)), (" 10 , 20 ,3,4 ", (10, 20, 3, 4))])
def test_parse_region(text, rect):
    r = parse_region(text)
    assert (r.x, r.y, r.width, r.height) == rect


@pytest.mark.parametrize("text", ["", "1,2,3", "-1,0,4,4", "0,0,0,4", "0,0,4,0", "a,b,c,d", "0,0,9000,4", None])
def test_parse_region_rejects(text):
    with pytest.raises(ValidationError, match="--region"):
        parse_region(text)


def test_window_is_placed_beside_the_region_never_over_it():
    screen = Rect(0, 0, 1024, 768)
    assert place_window((100, 80), Rect(0, 0, 100, 80), screen) == (100, 0)          # right of it
    assert place_window((100, 80), Rect(924, 0, 100, 80), screen) == (924, 80)       # below
    assert place_window((100, 80), Rect(924, 688, 100, 80), screen) == (824, 688)    # left
    for region in (Rect(0, 0, 100, 80), Rect(500, 300, 200, 200), Rect(0, 0, 1000, 700)):
        x, y = place_window((20, 20), region, screen)
        assert not rects_overlap(Rect(x, y, 20, 20), region)
        assert x + 20 <= 1024 and y + 20 <= 768
    with pytest.raises(ValidationError, match="--window"):
        place_window((600, 500), Rect(0, 0, 600, 500), screen)
    r = default_region((300, 200), screen)
    assert (r.x, r.y, r.width, r.height) == (0, 0, 300, 200)
    assert default_region((2000, 2000), screen).width == 512


def test_full_screen_grabs_another_monitor_or_refuses():
    primary, second = Rect(0, 0, 1920, 1080), Rect(1920, 0, 1280, 1024)
    assert full_screen_region(primary, [second], None) == second
    region = Rect(2000, 10, 300, 200)
    assert full_screen_region(primary, [second], region) == region
    with pytest.raises(ValidationError, match="off the primary monitor"):
        full_screen_region(primary, [second], Rect(10, 10, 300, 200))
    with pytest.raises(ValidationError, match="only monitor"):
        full_screen_region(primary, [], None)


def test_defaults_and_config_checks():
    assert default_display("screen") == "desktop" and default_display("clip.mp4") == "quest2"
    with pytest.raises(ValidationError, match="--eye"):
        OverlayConfig(source="x.png", eye="both")
    with pytest.raises(ValidationError, match="--region"):
        OverlayConfig(source="x.png", region=Rect(0, 0, 4, 4))


# --------------------------------------------------------------------------
# The window (Xvfb) with a folder of two images and the real Corrector
# --------------------------------------------------------------------------


def _images() -> list[np.ndarray]:
    from vrcorrect.plumbing.imageio import read_image

    sample = read_image(REPO / "vrcorrect" / "data" / "sample.png")
    face = np.round(sample[50:50 + H, 85:85 + W] * 255).astype(np.uint8)  # mid-tones and edges
    return [face, np.ascontiguousarray(face[::-1, ::-1])]


def _write_png(path: Path, image: np.ndarray) -> Path:
    from PIL import Image

    Image.fromarray(image).save(path)
    return path


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("frames")
    images = _images()
    for i, img in enumerate(images):
        _write_png(d / f"{i}.png", img)
    return d, images


@pytest.fixture(scope="module")
def overlay(x_display, folder, tmp_path_factory):
    d, _ = folder
    rx = tmp_path_factory.mktemp("rx") / "rx.json"
    rx.write_text(SAMPLE_RX)
    messages: list[str] = []
    # the tests compare the window with the Corrector run again on the same picture, which needs a
    # filter without memory (fista's frame depends on the frames before it: its own test below)
    config = OverlayConfig(source=str(d), rx=rx, window=(W, H), visible=False, vsync=False, platform="x11",
                           time_step_s=3.0, folder_interval_s=3.0, show_messages=False,
                           screenshot_dir=tmp_path_factory.mktemp("shots"), corrector_options={"filter": "fft"})
    with Overlay(config, echo=messages.append) as o:
        o.messages = messages
        yield o


def press(o: Overlay, ch: str | int) -> None:
    k = ch if isinstance(ch, int) else key(ch)
    o.key_callback(o.window, k, 0, GLFW_PRESS, 0)
    o.key_callback(o.window, k, 0, GLFW_RELEASE, 0)


def reference(o: Overlay, image: np.ndarray) -> np.ndarray:
    """What the overlay's Corrector writes for ``image`` into an offscreen framebuffer."""
    src = G.upload_texture(o.ctx, np.dstack([image, np.full(image.shape[:2], 255, np.uint8)]))
    tex, fb = G.render_target(o.ctx, width=image.shape[1], height=image.shape[0])
    try:
        o.corrector.apply(src, fb)
        return G.read_framebuffer(fb).astype(int)
    finally:
        G.release(fb, tex, src)


def test_window_shows_each_image_corrected_and_c_toggles(overlay, folder):
    _, images = folder
    o = overlay
    assert o.output_size == (W, H) and o.config.display is None and "quest" in o.display.name.lower()
    assert o.config.eye == "right" and o.corrector.eye_name == "right"
    for i, image in enumerate(images):
        o.frame = i  # source time i * 3 s: image i
        o.render()
        got = o.read_screen().astype(int)
        assert np.abs(got - reference(o, image)).max() <= 1, i
        assert np.abs(got - image).mean() > 2.0, "the correction changes the image"
    press(o, "c")
    assert not o.state.correction
    o.render()
    assert not o.corrector.enabled
    assert np.abs(o.read_screen().astype(int) - images[1]).max() <= 1
    press(o, "c")
    o.render()
    assert np.abs(o.read_screen().astype(int) - reference(o, images[1])).max() <= 1


def test_no_gpu_allocations_per_frame_and_report(overlay, monkeypatch):
    o = overlay
    calls = []
    for name in ("texture", "framebuffer", "renderbuffer", "buffer", "vertex_array", "program", "compute_shader",
                 "query", "sampler"):
        original = getattr(o.ctx, name)
        monkeypatch.setattr(o.ctx, name, lambda *a, _n=name, _o=original, **k: (calls.append(_n), _o(*a, **k))[1])
    n0 = len(o.reports)
    for _ in range(2):  # both images, both sizes of work: already warm from the test before
        o.step()
    assert calls == []
    o.report()
    # a slow machine may have reported on its own after a step (every report_interval_s): the
    # frames' stages are then in that line, and the explicit report covers what was left
    lines = o.reports[n0:]
    assert lines and all("fps" in line for line in lines)
    assert any("correct" in line and "source" in line and "gpu" in line for line in lines), lines


def test_brackets_change_the_iterations_live_and_the_report_shows_them(overlay):
    """With a projected-gradient corrector: ``]`` / ``[`` double / halve k within 1..64, the corrector
    is told, the window says so, and the report line gives k and the objective (a frame late)."""
    from vrcorrect.runtime.corrector import Corrector

    o = overlay
    own = o.corrector
    o.corrector = Corrector(o.ctx, o.rx_path, o.display, "right", filter="fista", iterations_per_frame=2)
    try:
        press(o, KEY_RIGHT_BRACKET)
        o.render()
        assert o.corrector.iterations_per_frame == 4 and o.status == "iterations per frame: 4"
        for _ in range(3):
            press(o, KEY_LEFT_BRACKET)
        o.render()
        assert o.corrector.iterations_per_frame == 1
        o.render()
        before = o.corrector.last_objective_fraction(o.output_size)
        o.render()
        line = o.report()
        assert "fista k 1" in line and f"right {before:.3f} of uncorrected" in line and 0 < before < 1
        for _ in range(7):
            press(o, KEY_RIGHT_BRACKET)
        o.render()
        assert o.corrector.iterations_per_frame == 64
    finally:
        o.corrector.release()
        o.corrector = own
    press(o, KEY_RIGHT_BRACKET)                                  # the fft corrector has no knob: says so
    o.render()
    assert "only with --filter admm or fista" in o.status
    assert "fista" not in o.report()


def test_screenshot_and_quit(overlay):
    from vrcorrect.plumbing.imageio import read_image

    o = overlay
    press(o, "p")
    o.step()
    path = o.screenshots[-1]
    assert path.exists() and path.name.startswith("vrcorrect-overlay")
    assert read_image(path).shape == (H, W, 3)
    press(o, "q")
    assert not o.running
    o.state = OverlayState()
    o._session.glfw.set_window_should_close(o.window, False)


def test_prescription_edit_is_picked_up_and_invalid_file_keeps_the_last_good(overlay):
    o = overlay
    o.frame = 0
    o.render()
    before = o.read_screen().astype(int)
    time.sleep(0.3)
    o.rx_path.write_text(SAMPLE_RX.replace('"sphere_D": -3.0', '"sphere_D": -2.0'))
    o.render()
    assert o.eye_source.wait(120)
    o.render()
    assert o.corrector.eye_rx.sphere_D == pytest.approx(-2.0)
    assert "reloaded" in o.status and "-2.00" in o.status
    changed = o.read_screen().astype(int)
    assert np.abs(changed - before).max() > 2
    time.sleep(0.3)
    o.rx_path.write_text("{ not json")
    o.render()
    assert o.eye_source.wait(120)
    o.render()
    assert o.corrector.eye_rx.sphere_D == pytest.approx(-2.0)
    assert "not reloaded" in o.status and any("not reloaded" in m for m in o.messages)
    assert (o.read_screen().astype(int) == changed).all()  # messages not drawn here (show_messages=False)
    o.config = o.config.__class__(**{**o.config.__dict__, "show_messages": True})
    o.render()
    assert np.abs(o.read_screen().astype(int)[:12] - changed[:12]).mean() > 5.0  # the message is drawn
    o.config = o.config.__class__(**{**o.config.__dict__, "show_messages": False})
    time.sleep(0.3)
    o.rx_path.write_text(SAMPLE_RX)
    o.render()
    assert o.eye_source.wait(120)
    o.render()
    assert o.corrector.eye_rx.sphere_D == pytest.approx(-3.0)
    assert np.abs(o.read_screen().astype(int) - before).max() <= 1


# --------------------------------------------------------------------------
# The screen source: a known picture on the Xvfb screen, drawn by another X client
# --------------------------------------------------------------------------

PICTURE_CLIENT = textwrap.dedent("""
    import sys, time, glfw, moderngl, numpy as np
    x, y, w, h = map(int, sys.argv[1:5])
    glfw.init_hint(glfw.PLATFORM, glfw.PLATFORM_X11)
    assert glfw.init()
    glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
    glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
    glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
    glfw.window_hint(glfw.DECORATED, False)
    glfw.window_hint(glfw.VISIBLE, False)
    win = glfw.create_window(w, h, "picture", None, None)
    glfw.set_window_pos(win, x, y)
    glfw.show_window(win)
    glfw.make_context_current(win)
    ctx = moderngl.create_context()
    img = np.random.default_rng(7).integers(0, 256, (h, w, 4), dtype=np.uint8)
    tex = ctx.texture((w, h), 4, np.ascontiguousarray(img[::-1]).tobytes())
    fb = ctx.framebuffer(color_attachments=[tex])
    for i in range(600):  # at most 30 s; redraws in case anything covered it
        ctx.copy_framebuffer(ctx.screen, fb)
        glfw.swap_buffers(win)
        glfw.poll_events()
        if i == 1:
            print("ready", flush=True)
        if sys.stdin in __import__("select").select([sys.stdin], [], [], 0.05)[0]:
            break
""")


@pytest.fixture
def picture_on_screen(x_display):
    """A 40x32 window of known random pixels at (0, 0) on the X screen, from another process."""
    env = dict(os.environ, DISPLAY=x_display)
    proc = subprocess.Popen([sys.executable, "-c", PICTURE_CLIENT, "0", "0", str(W), str(H)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout.readline().strip() == "ready"
        time.sleep(0.3)
        yield np.random.default_rng(7).integers(0, 256, (H, W, 4), dtype=np.uint8)[..., :3]
    finally:
        proc.stdin.write("\n")
        proc.stdin.close()
        proc.wait(timeout=30)


def test_screen_source_grabs_the_picture_and_not_itself(x_display, picture_on_screen, tmp_path):
    picture = picture_on_screen.astype(int)
    config = OverlayConfig(source="screen", window=(W, H), visible=True, vsync=False, platform="x11",
                           show_messages=False, rx=None, corrector_options={"filter": "fft"})
    with Overlay(config, echo=None) as o:
        assert o.display.name == get_display("desktop").name  # the screen's default
        r = o.region
        assert (r.x, r.y, r.width, r.height) == (0, 0, W, H)
        x, y = o._session.glfw.get_window_pos(o.window)
        assert not rects_overlap(Rect(x, y, W, H), r)
        assert (o.source.grabber.grab(r).astype(int) == picture).all()
        press(o, "c")  # correction off: the window shows the grab as it is
        for _ in range(3):
            o.step()
        assert (G.download_texture(o.source.render(0.0)[1])[..., :3].astype(int) == picture).all()
        o.render()
        assert np.abs(o.read_screen().astype(int) - picture).max() <= 1
        press(o, "c")
        o.render()
        assert np.abs(o.read_screen().astype(int) - reference(o, picture_on_screen)).max() <= 1


def test_region_outside_the_screen_is_refused(x_display):
    from vrcorrect.runtime.shell.sources import screen_bounds

    screen = screen_bounds()     # conftest's Xvfb is 1024x768; xvfb-run's default is 1280x1024
    config = OverlayConfig(source="screen", region=Rect(screen.width - 24, 0, 100, 100), window=(W, H),
                           visible=False, vsync=False, platform="x11")
    with pytest.raises(ValidationError, match=f"inside the {screen.width}x{screen.height} screen"):
        Overlay(config, echo=None)


class _FlakyMss:
    """Stands in for the ``mss`` module: ``MSS()`` refuses ``failures`` times, then connects to the
    real display (the failure seen once on a loaded machine: "cannot grab the X11 screen ':0'")."""

    def __init__(self, real, failures: int):
        self.real, self.failures, self.calls = real, failures, 0

    def MSS(self):  # noqa: N802 (mss's name)
        self.calls += 1
        if self.calls <= self.failures:
            raise RuntimeError("Cannot connect to display: connection refused")
        return self.real.MSS()


def test_a_refused_x_connection_is_tried_again(x_display, monkeypatch):
    import mss

    from vrcorrect.plumbing.errors import InputError
    from vrcorrect.runtime.shell import sources

    monkeypatch.setattr(sources.ScreenGrabber, "RETRY_DELAYS_S", (0.01, 0.01, 0.01))
    flaky = _FlakyMss(mss, failures=2)
    monkeypatch.setattr(sources, "_mss", lambda: flaky)
    grabber = sources.ScreenGrabber()                  # the third attempt connects
    try:
        assert flaky.calls == 3 and grabber.bounds.width > 0
        assert grabber.grab(Rect(0, 0, 4, 4)).shape == (4, 4, 3)
    finally:
        grabber.close()
    always = _FlakyMss(mss, failures=99)
    monkeypatch.setattr(sources, "_mss", lambda: always)
    with pytest.raises(InputError, match=r"cannot grab the X11 screen .*connection refused; 4 attempts"):
        sources.ScreenGrabber()
    assert always.calls == 4


# --------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------


@pytest.mark.parametrize("args, message", [
    (["--source", "/no/such/clip.mp4"], "no such file"),
    (["--source", "screen", "--region", "1,2,3"], "--region"),
    (["--source", "screen", "--region", "0,0,0,5"], "--region"),
    (["--source", "demo"], "--source"),
    (["--source", "screen", "--window", "0x4"], "--window"),
    (["--source", "screen", "--frames", "0"], "--frames"),
    (["--source", "screen", "--model", "m.onnx"], "only with --backend onnx"),
    (["--source", "screen", "--backend", "onnx", "--model", "/no/such/m.onnx"], "an existing ONNX model file"),
    (["--source", __file__, "--region", "0,0,4,4"], "--region"),
    (["--source", "screen", "--filter", "fista", "--iterations-per-frame", "0"], "--iterations-per-frame"),
    (["--source", "screen", "--filter", "separable", "--iterations-per-frame", "2"], "only with --filter admm or fista"),
])
def test_cli_bad_input_is_one_line_and_exit_2(args, message, capsys):
    from vrcorrect.apps.cli import main

    assert main(["overlay", *args]) == 2
    captured = capsys.readouterr()
    err = captured.err
    assert err.count("\n") == 1 and err.startswith("vrcorrect: error:") and message in err, err
    assert captured.out == ""


def _cli(args: list[str], env: dict[str, str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "vrcorrect.apps.cli", "overlay", *args], capture_output=True,
                          text=True, env=env, cwd=cwd, timeout=600)


def test_cli_screen_without_an_x_display_says_so(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["PYTHONPATH"] = str(REPO)
    result = _cli(["--source", "screen", "--window", "40x32", "--frames", "1"], env, tmp_path)
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1 and "DISPLAY" in result.stderr
    assert result.stdout == ""


def test_cli_renders_n_frames_and_reports(x_display, folder, tmp_path):
    d, _ = folder
    env = dict(os.environ, DISPLAY=x_display, PYTHONPATH=str(REPO))
    result = _cli(["--source", str(d), "--window", f"{W}x{H}", "--frames", "3"], env, tmp_path)
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "keys:" in out and "Esc / q" in out
    assert "3 frame(s)" in out and "fps" in out and "correct" in out and f"{W}x{H}" in out


def test_fista_reprojects_the_pictures_motion_unless_told_not_to(x_display, gl, folder, tmp_path):
    """With ``--filter fista`` the folder's pictures are tracked for the reprojected warm start (the
    test folder's pictures are unrelated: each change is a cut, a cold start); ``--no-reprojection``
    turns it off."""
    from vrcorrect.runtime.shell.sources import FolderSource, start_motion

    d, _ = folder
    env = dict(os.environ, DISPLAY=x_display, PYTHONPATH=str(REPO))
    for extra in ([], ["--no-reprojection"]):
        result = _cli(["--source", str(d), "--window", f"{W}x{H}", "--frames", "3", "--filter", "fista",
                       "--iterations-per-frame", "2", *extra], env, tmp_path)
        assert result.returncode == 0, result.stderr
        assert "3 frame(s)" in result.stdout

    class Fista:
        backend, options = "glsl", type("Options", (), {"filter": "fista"})()

    source = FolderSource(gl, W, H, d, interval_s=1.0)
    try:
        assert not start_motion(source, [Fista()], reprojection=False) and source.motion is None
        assert start_motion(source, [Fista()]) and source.motion is not None
        source.render(1.0)
        assert source.take_motion() == "cut"                # the test pictures are unrelated
    finally:
        source.release()
