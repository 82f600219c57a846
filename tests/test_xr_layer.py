"""vrcorrect as an OpenXR API layer (``layer/`` + :mod:`vrcorrect.runtime.layer.engine`) in OpenGL sessions,
between a separate OpenXR OpenGL application in C that knows nothing of vrcorrect
(``tests/xr_gl_app/xr_gl_app.c``) and the project's test runtime (``tests/xr_runtime``), all loaded
by pyopenxr's real OpenXR loader, under Xvfb (``x_display``).  The equipment is
``tests/xr_layer_kit.py``; Vulkan sessions are ``test_xr_layer_vulkan.py``, Khronos's ``hello_xr``
``test_xr_layer_hello_xr.py``.

The application submits a known image per eye every frame and, after each ``xrEndFrame``, writes
its own released swapchain images back out (or checks them itself); the runtime writes what it
received.  Checked: with the layer (explicit, through ``XR_API_LAYER_PATH``/``XR_ENABLE_API_LAYERS``,
with Khronos' core validation layer below it) the application's frames go through unchanged while
the eye models build on the layer's worker thread (one "building" log line), then the runtime
receives each eye corrected for that eye, equal to ``Corrector.apply`` on the same image (the n-th
corrected frame to the n-th apply) within 2/255, over the whole image, over a sub-rect with the
application's scissor test left on (the GL state comes back as it was), for both eyes in one
side-by-side swapchain, and in every OpenGL format the layer corrects (``GL_SRGB8_ALPHA8``,
``GL_RGBA8``, ``GL_RGB10_A2``, ``GL_RGBA16F`` with values above 1, which are carried through); a
Python (pyopenxr) application gets the layer in its own interpreter; the application's images are
never modified; the session life cycle completes and every swapchain is destroyed.  No
prescription, an invalid prescription (then a valid one: correction resumes; a later invalid edit
keeps the last good prescription), a swapchain format the layer does not correct, the off switch
(variable or file) and a Direct3D session each pass the frames through with one log line naming
the reason.  The ``layer`` command's install, status and uninstall.
"""

from __future__ import annotations

import argparse
import itertools
import json
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from xr_layer_kit import (CLEAN_STATES, EYES, RX, VIEW, Kit, assert_corrected, assert_life_cycle, assert_validation_clean,
                          converged_codes, corrector_input, env, frames, kit, layer_log, light_or_codes, reasons, received, run,
                          runtime_log, stored, wait_for)

ROOT = Path(__file__).resolve().parents[1]
__all__ = ["kit"]          # the session's equipment (a fixture)


def _run(kit: Kit, out: Path, timeout: float = 300, corrected: int = 0, **kw) -> subprocess.CompletedProcess:
    """Run the GL application to the end (20 ms a frame with ``APP_STOP_FILE`` when ``corrected``)."""
    options = {k: kw.pop(k) for k in ("explicit", "validation", "home") if k in kw}
    result = run([str(kit.gl_app)], out, env(kit, out, app="gl", **options, **kw), corrected=corrected,
                 timeout=timeout)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "done" in result.stdout
    return result


def _pictures() -> dict[str, np.ndarray]:
    from xr_layer_kit import pictures

    return pictures()


def _corrected_frames(out: Path, n: int, rect: tuple[int, int, int, int] | None = None) -> list[int]:
    """The first ``n`` corrected frames the runtime received (the first frame whose left view is not
    the application's picture, and those after it); every frame before them passed through
    (both views equal to the application's pictures, or to their ``rect``: x, y from the bottom left)."""
    pics = _pictures()
    if rect is not None:
        x, y, w, h = rect
        pics = {eye: p[VIEW[1] - y - h:VIEW[1] - y, x:x + w] for eye, p in pics.items()}
    received_frames = frames(out)
    first = next((i for i, f in enumerate(received_frames)
                  if not np.array_equal(received(out, f, 0), pics["left"])), None)
    assert first is not None, "no corrected frame"
    for f in received_frames[:first]:
        for view, eye in enumerate(EYES):
            assert np.array_equal(received(out, f, view), pics[eye]), (f, eye)
    assert len(received_frames) >= first + n, (len(received_frames), first, n)
    return received_frames[first:first + n]


def _expected(kit: Kit, gl, count: int, rect: tuple[int, int, int, int] | None = None,
              fmt: str = "srgb") -> dict[str, list[np.ndarray]]:
    """Each eye's correction of its still picture (or of the rect x, y, w, h of it, GL pixels) by a
    separate Corrector, converged (the layer primes its correction on the application's frame off
    its thread, so every corrected frame of a still picture shows that): ``count`` times, sRGB
    codes, top row first."""
    out = {}
    for eye, picture in _pictures().items():
        if rect is not None:
            x, y, w, h = rect
            picture = picture[VIEW[1] - y - h:VIEW[1] - y, x:x + w]
        out[eye] = [converged_codes(gl, kit, eye, corrector_input(stored(picture, fmt), fmt))] * count
    return out


def _assert_app_images_untouched(out: Path) -> None:
    pics = _pictures()
    files = sorted(out.glob("app_*_view_*.raw"))
    assert files
    for f in files:
        eye = EYES[int(f.stem.rsplit("_", 1)[1])]
        image = np.fromfile(f, np.uint8).reshape(pics[eye].shape)[::-1]      # GL's rows: bottom first
        assert np.array_equal(image, pics[eye]), f.name


# --------------------------------------------------------------------------
# Corrected frames
# --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def corrected_run(x_display, kit, tmp_path_factory):
    out = tmp_path_factory.mktemp("corrected")
    result = _run(kit, out, corrected=3, validation=True, VRCORRECT_RX=str(kit.rx), APP_FRAMES="3")
    return result, out


def test_each_eye_is_corrected_like_the_corrector_with_validation_clean(corrected_run, kit, gl):
    result, out = corrected_run
    assert_validation_clean(result.stdout)
    corrected = _corrected_frames(out, 3)
    expected = _expected(kit, gl, len(corrected))
    pics = _pictures()
    for n, frame in enumerate(corrected):
        for view, eye in enumerate(EYES):
            got = received(out, frame, view)
            assert got.shape == (VIEW[1], VIEW[0], 4)
            assert_corrected(got, pics[eye], "srgb", expected[eye][n], (frame, eye))
            assert np.abs(got[..., :3].astype(int) - pics[eye][..., :3]).mean() > 3      # not the picture itself
    # each eye its own prescription: the other eye's correction is far from what it got
    got = received(out, corrected[0], 1)[..., :3].astype(int)
    assert np.abs(got - expected["left"][0]).mean() > 5 * max(np.abs(got - expected["right"][0]).mean(), 0.2)


def test_the_applications_images_and_structures_are_untouched_and_the_life_cycle_completes(corrected_run, kit):
    result, out = corrected_run
    _assert_app_images_untouched(out)          # and the app checked its projection views after xrEndFrame
    assert_life_cycle(out, swapchains=4)       # two of the application's, two outputs of the layer's
    assert "gl error 0x0" in result.stdout
    log = layer_log(out)
    assert any("correcting with" in line and str(kit.rx) in line for line in log), log
    assert len([line for line in log if "building the eye models" in line]) == 1, log
    timing = [line for line in log if "per eye" in line]
    from vrcorrect.studies.bench.layer import _LINE                 # what `vrcorrect bench layer` reads from it
    assert timing and all((m := _LINE.search(line)) and m.group(7) is None for line in timing), log
    assert not any("pass-through" in line for line in log), log


def test_frames_keep_flowing_unchanged_while_the_eye_models_build(corrected_run, record_property):
    """The eye models (seconds of CPU) build on the layer's worker thread, not in xrEndFrame: the
    application's frames keep going through, unchanged, until the first corrected one, and the log
    says "building" before "correcting with".  How long xrEndFrame took meanwhile (the largest
    gap between the passed-through frames the runtime received, from the files' times; the
    application sleeps 20 ms a frame) is recorded, not asserted: timings belong in benchmarks."""
    _, out = corrected_run
    received_frames = frames(out)
    first = received_frames.index(_corrected_frames(out, 1)[0])     # the frames before it: passed through
    assert first >= 5, first                                         # several frames during the build
    log = layer_log(out)
    building = [i for i, line in enumerate(log) if "building the eye models for" in line]
    correcting = [i for i, line in enumerate(log) if "correcting with" in line]
    assert len(building) == 1 and len(correcting) == 1 and building[0] < correcting[0], log
    times = [(out / f"frame_{f:05d}_view_1.npy").stat().st_mtime for f in received_frames[:first]]
    gap = max(b - a for a, b in itertools.pairwise(times))
    record_property("largest_gap_between_frames_while_building_s", round(gap, 3))
    print(f"{first} frames passed through while the eye models built; largest gap between frames {gap:.3f} s")


def test_a_sub_rect_is_corrected_and_the_applications_gl_state_comes_back(x_display, kit, gl, tmp_path):
    rect = (8, 4, 64, 48)
    out = tmp_path / "rect"
    _run(kit, out, corrected=1, VRCORRECT_RX=str(kit.rx), APP_FRAMES="1", APP_RECT=",".join(map(str, rect)),
         APP_SCISSOR="1")
    expected = _expected(kit, gl, 1, rect)
    frame = _corrected_frames(out, 1, rect)[0]
    pics = _pictures()
    for view, eye in enumerate(EYES):
        got = received(out, frame, view)
        assert got.shape == (rect[3], rect[2], 4)
        assert_corrected(got, pics[eye], "srgb", expected[eye][0], eye)
    _assert_app_images_untouched(out)


def test_a_foveated_layer_corrects_only_the_window_around_the_configured_gaze(x_display, kit, tmp_path):
    """``layer install --fovea DEG --gaze X,Y --periphery target``'s configuration, on a runtime
    without an eye tracker: each view is corrected inside the window around the configured gaze
    (degrees from the view's centre, y up) and is the application's picture, code for code, outside it."""
    from vrcorrect.specs.display import get_display

    ppd = get_display("quest2").pixels_per_degree
    from vrcorrect.solvers.foveated import fovea_pixels

    radius, (gx, gy) = 12, (60, 30)                          # px; the gaze's pixel (x, y rows top first)
    gaze_deg = [(gx + 0.5 - VIEW[0] / 2) / ppd, (VIEW[1] / 2 - gy - 0.5) / ppd]
    config = tmp_path / "layer.json"
    config.write_text(json.dumps({"rx": str(kit.rx), "display": "quest2",
                                  "options": {"fovea_deg": radius / ppd, "gaze_deg": gaze_deg,
                                              "fovea_periphery": "target"}}))
    out = tmp_path / "fovea"
    _run(kit, out, corrected=1, VRCORRECT_LAYER_CONFIG=str(config), APP_FRAMES="1")
    frame = _corrected_frames(out, 1)[0]
    pics = _pictures()
    solved = fovea_pixels(radius / ppd, ppd)[0]              # the window: the radius and its blend band
    y0, y1, x0, x1 = gy - solved, gy + solved, gx - solved, gx + solved
    outside = np.ones(VIEW[::-1], bool)
    outside[y0:y1, x0:x1] = False
    for view, eye in enumerate(EYES):
        got, picture = received(out, frame, view)[..., :3], pics[eye][..., :3]
        assert np.array_equal(got[outside], picture[outside]), eye
        inner = np.abs(got[y0 + 3:y1 - 3, x0 + 3:x1 - 3].astype(int) - picture[y0 + 3:y1 - 3, x0 + 3:x1 - 3])
        assert inner.max() >= 8, eye                                      # the window is corrected
    # the test runtime offers no eye tracker unless told to (XRTEST_GAZE_DEG): the configured gaze, said once
    assert sum("the runtime offers no eye tracker" in line for line in layer_log(out)) == 1, layer_log(out)


def test_a_layer_with_a_frame_budget_logs_its_choice_and_status_shows_it(x_display, kit, tmp_path):
    """``layer install --budget-ms``'s configuration: each eye's Corrector holds its frames at the
    budget; the log reports what the budget chose beside the frame times, and ``layer status`` shows
    the latest choice.  (A budget of 1 ms, under llvmpipe's frame, keeps the frames at the fewest
    iterations: one of 5 s took three minutes of the fewest frames at the most.)  With no pupil
    configured, the layer's default: the pupil followed from the light."""
    from vrcorrect.apps import layer
    from vrcorrect.runtime.pupil_bank import BANK_PUPILS_MM

    config = tmp_path / "layer.json"
    config.write_text(json.dumps({"rx": str(kit.rx), "display": "quest2", "options": {"budget_ms": 1}}))
    out = tmp_path / "budget"
    _run(kit, out, corrected=40, VRCORRECT_LAYER_CONFIG=str(config))
    chose = [line for line in layer_log(out) if "budget: " in line]
    assert chose, layer_log(out)
    assert "left budget 1 ms:" in chose[-1] and "right budget 1 ms:" in chose[-1], chose[-1]
    assert "iterations a frame (last " in chose[-1]            # frames were timed by the Corrector
    status = "\n".join(layer.status_lines({"HOME": str(tmp_path), "VRCORRECT_LAYER_CONFIG": str(config),
                                            "VRCORRECT_LAYER_LOG": str(out / "layer.log")}))
    assert "budget: 1 ms of GPU time a frame per eye; its latest choice: left budget 1 ms:" in status, status
    # no pupil configured: the layer's default, the pupil followed from each frame's light (measured on the
    # GPU) with the robust design; the log reports each eye's pupil and its design (a bank entry), status the latest
    pupils = [line.split("pupil: ", 1)[1] for line in layer_log(out) if "pupil: " in line and " pupil " in line]
    assert pupils, layer_log(out)
    for eye in EYES:
        found = re.search(eye + r" pupil (\d+\.\d+) mm \(auto: [\d.e+-]+ cd/m\^2\), design (\d+\.\d+) mm", pupils[-1])
        assert found, pupils[-1]
        seen, design = float(found[1]), float(found[2])
        assert 2.0 <= seen <= 7.5, pupils[-1]
        assert min(abs(design - entry) for entry in BANK_PUPILS_MM) < 0.006, pupils[-1]      # the bank's entry
    assert "pupil: followed from the light of the frames shown (auto); robust design" in status, status
    assert "pupil now: " + pupils[-1] in status, status


def test_both_eyes_in_one_side_by_side_swapchain_are_each_corrected(x_display, kit, gl, tmp_path):
    """One swapchain twice as wide, each eye's view a rect in its half: one output swapchain,
    acquired once per frame, each half corrected for its own eye."""
    out = tmp_path / "side_by_side"
    _run(kit, out, corrected=1, VRCORRECT_RX=str(kit.rx), APP_FRAMES="1", APP_SIDE_BY_SIDE="1")
    assert f"create_swapchain 0 format=0x8c43 {2 * VIEW[0]}x{VIEW[1]}" in runtime_log(out)
    expected = _expected(kit, gl, 1)
    frame = _corrected_frames(out, 1)[0]
    for view, eye in enumerate(EYES):
        assert_corrected(received(out, frame, view), _pictures()[eye], "srgb", expected[eye][0], eye)
    _assert_app_images_untouched(out)
    assert_life_cycle(out, swapchains=2)


@pytest.mark.parametrize("formats", [("rgba8", "rgba8"), ("rgba16f", "rgb10a2")], ids=["GL_RGBA8", "GL_RGBA16F+RGB10_A2"])
def test_every_format_arrives_corrected_in_its_own_encoding(x_display, kit, gl, tmp_path, formats):
    """``GL_RGBA8`` holds linear light (corrected on its sRGB encoding, written back as linear
    light, as ``vrcorrect xr`` does); ``GL_RGB10_A2`` linear light in 10 bits; ``GL_RGBA16F``
    linear light that may exceed 1 (here the pictures times 2): the correction works on the part in
    [0, 1] and the rest is carried through.  One swapchain per eye, each in its own format."""
    out = tmp_path / "_".join(formats)
    _run(kit, out, corrected=1, VRCORRECT_RX=str(kit.rx), APP_FRAMES="1", APP_FORMAT=",".join(formats),
         APP_GAIN="2", APP_CHECK="1")
    codes = {"rgba8": "0x8058", "rgb10a2": "0x8059", "rgba16f": "0x881a"}
    for i, fmt in enumerate(formats):
        assert f"create_swapchain {2 * i} format={codes[fmt]} 96x64" in runtime_log(out)
    received_frames = frames(out)
    # the application's images, as the first frames (passed through while the models build) hold them:
    # its pictures in each format (GL rounds to half floats its own way)
    sources = {eye: received(out, received_frames[0], view) for view, eye in enumerate(EYES)}
    first = next(f for f in received_frames if not np.array_equal(received(out, f, 0), sources["left"]))
    for view, (eye, fmt) in enumerate(zip(EYES, formats)):
        assert np.allclose(light_or_codes(sources[eye], fmt), light_or_codes(stored(_pictures()[eye], fmt, 2.0), fmt),
                           rtol=2 ** -10, atol=1 / 1023 + 1e-9), eye        # GL rounds its own way
        expected = converged_codes(gl, kit, eye, corrector_input(sources[eye], fmt))
        got = received(out, first, view)
        assert_corrected(got, sources[eye], fmt, expected, eye)
        if fmt == "rgba16f":
            assert got[..., :3].astype(np.float32).max() > 1.9          # what exceeds 1 arrives
    assert any("GL_RGBA16F swapchain" in line and "carried through" in line for line in layer_log(out)) == \
        ("rgba16f" in formats)
    assert_life_cycle(out, swapchains=4)


def test_a_python_openxr_application_gets_the_layer_in_its_own_interpreter(x_display, kit, tmp_path):
    """``vrcorrect xr`` (pyopenxr: Python is already running in the process) with the layer: the
    shim takes the GIL instead of starting Python, the layer's worker thread builds the eye models
    beside the application's own Python, and the session still completes (ended by Ctrl-C once
    the layer corrects)."""
    import re
    import signal
    import sys

    out = tmp_path / "python_app"
    out.mkdir()
    # small views, one iteration a frame and one design of one pupil for the application's own correction:
    # its frames are cheaper on a software renderer (whose GL calls hold the GIL the layer's worker thread
    # needs), and no pupil bank designs beside the layer's worker
    environ = env(kit, out, VRCORRECT_RX=str(kit.rx), XRTEST_VIEW_SIZE="32x32")
    with open(out / "stdout.txt", "w") as so, open(out / "stderr.txt", "w") as se:
        proc = subprocess.Popen([sys.executable, "-m", "vrcorrect.apps.cli", "xr", "--iterations-per-frame", "1",
                                 "--pupil", "rx", "--robust", "off",
                                 "--source", str(ROOT / "vrcorrect" / "data" / "sample.png"), "--frames", "1000000"],
                                stdout=so, stderr=se, text=True, cwd=ROOT, env=environ)
        try:
            wait_for(proc, lambda: any("correcting with" in line for line in layer_log(out)),
                     "the layer's eye models", 300)
            ready = len(frames(out))
            wait_for(proc, lambda: len(frames(out)) >= ready + 3, "corrected frames", 120)
            proc.send_signal(signal.SIGINT)                # the application ends its session
            proc.wait(timeout=120)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert proc.returncode == 0, (out / "stderr.txt").read_text()[-3000:]
    log = layer_log(out)
    assert any("correcting with" in line for line in log), log
    closed = [int(m.group(1)) for line in log for m in [re.search(r"closed after (\d+) corrected frames", line)] if m]
    assert len(closed) == 1 and closed[0] >= 1, log
    assert not any("pass-through" in line for line in log), log
    states = [line.split()[1] for line in runtime_log(out) if line.startswith("state ")]
    assert states == CLEAN_STATES


# --------------------------------------------------------------------------
# Pass-through, one log line naming the reason
# --------------------------------------------------------------------------


def _assert_passed_through(out: Path) -> None:
    pics = _pictures()
    received_frames = frames(out)
    assert received_frames
    for frame in received_frames:
        for view, eye in enumerate(EYES):
            assert np.array_equal(received(out, frame, view), pics[eye]), (frame, eye)


def test_no_prescription_passes_through_with_one_log_line(x_display, kit, tmp_path):
    out = tmp_path / "none"
    _run(kit, out, APP_FRAMES="4")
    _assert_passed_through(out)
    _assert_app_images_untouched(out)
    assert_life_cycle(out, swapchains=4)
    found = reasons(out)
    assert len(found) == 1 and "no prescription" in found[0] and "VRCORRECT_RX" in found[0], found


@pytest.mark.parametrize("switch", ["environment", "file"])
def test_the_off_switch_passes_through_with_one_log_line(x_display, kit, tmp_path, switch):
    out = tmp_path / "off"
    extra = {"VRCORRECT_LAYER_OFF": "1"} if switch == "environment" else {}
    if switch == "file":                    # beside the layer configuration ($XDG_CONFIG_HOME/vrcorrect/)
        off = out / "home" / ".config" / "vrcorrect" / "layer.off"
        off.parent.mkdir(parents=True)
        off.touch()
    _run(kit, out, APP_FRAMES="3", VRCORRECT_RX=str(kit.rx), **extra)
    _assert_passed_through(out)
    found = reasons(out)
    word = "VRCORRECT_LAYER_OFF" if switch == "environment" else "layer.off exists"
    assert len(found) == 1 and word in found[0], found


def test_an_unsupported_swapchain_format_passes_through_with_one_log_line(x_display, kit, tmp_path):
    """The test runtime offers GL_RGBA16 (16-bit normalized) when asked to, which the layer does not
    correct: no output swapchain is made, the frames go through as they are."""
    out = tmp_path / "format"
    _run(kit, out, APP_FRAMES="3", APP_FORMAT="rgba16", XRTEST_FORMATS="rgba16,srgb", VRCORRECT_RX=str(kit.rx))
    for frame in frames(out):
        for view, eye in enumerate(EYES):               # 16-bit: each byte v of the picture became v * 257
            assert np.array_equal(received(out, frame, view), _pictures()[eye].astype(np.uint16) * 257)
    assert_life_cycle(out, swapchains=2)             # no output swapchains were made
    found = reasons(out)
    assert len(found) == 1 and "0x805B" in found[0] and "not supported" in found[0] and "GL_RGBA16F" in found[0], found


@pytest.mark.parametrize("end", ["XRTEST_STOP_AFTER", "XRTEST_LOSS_AFTER"], ids=["runtime stops", "session lost"])
def test_the_runtime_ending_the_session_tears_the_layer_down_cleanly(x_display, kit, tmp_path, end):
    """The exit and loss paths of tests/test_xr.py with the layer in, while its worker thread is
    still building the eye models: the application ends normally and everything is destroyed,
    the layer's output swapchains included."""
    out = tmp_path / end.lower()
    result = _run(kit, out, APP_FRAMES="50", VRCORRECT_RX=str(kit.rx), **{end: "5"})
    assert result.returncode == 0, result.stdout + result.stderr
    log = runtime_log(out)
    states = [line.split()[1] for line in log if line.startswith("state ")]
    assert ("LOSS_PENDING" in states) == (end == "XRTEST_LOSS_AFTER") and states[-1] in ("EXITING", "LOSS_PENDING")
    made = [line for line in log if line.startswith("create_swapchain")]
    assert len(made) == 4                             # the application's two and the layer's two outputs
    assert len([line for line in log if line.startswith("destroy_swapchain")]) == 4
    assert log[-2:] == ["destroy_session", "destroy_instance"]
    assert not any("still alive" in line for line in log)
    assert not any("Traceback" in line or "error" in line.lower() for line in layer_log(out)), layer_log(out)


def test_a_direct3d_session_passes_through_and_names_direct3d(x_display, kit, tmp_path):
    """The test runtime has no Direct3D, so it refuses the session; the layer has passed the
    request through untouched (the runtime's own error reaches the application) and said why."""
    out = tmp_path / "d3d"
    result = run([str(kit.gl_app)], out, env(kit, out, VRCORRECT_RX=str(kit.rx), APP_BINDING="d3d11"), timeout=120)
    assert result.returncode == 3, result.stdout + result.stderr
    assert "d3d11 create_session -38" in result.stdout          # XR_ERROR_GRAPHICS_DEVICE_INVALID, the runtime's
    found = reasons(out)
    assert len(found) == 1 and "Direct3D 11 (XR_KHR_D3D11_enable)" in found[0] and "Vulkan" in found[0], found
    assert "destroy_instance" in runtime_log(out)


def test_an_invalid_prescription_passes_through_until_a_valid_one_arrives_and_hot_reload_keeps_the_last_good(x_display, kit, gl, tmp_path):
    out = tmp_path / "invalid"
    out.mkdir()
    rx = tmp_path / "rx.json"
    bad = dict(RX, right=dict(RX["right"], sphere_D=99.0))
    rx.write_text(json.dumps(bad))
    stop = tmp_path / "stop"
    proc = subprocess.Popen([str(kit.gl_app)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env(kit, out, VRCORRECT_RX=str(rx), APP_FRAMES="2", APP_STOP_FILE=str(stop)))
    try:
        def waiting(check, what: str, limit: float = 240) -> None:
            wait_for(proc, check, what, limit)

        waiting(lambda: len(frames(out)) >= 10, "ten passed-through frames")
        rx.write_text(json.dumps(RX))                     # in place: the eye source waits for it to settle
        waiting(lambda: any("correcting with" in line for line in layer_log(out)), "the valid prescription")
        waiting(lambda: any(_is_corrected(out, f) for f in frames(out)[-3:]), "a corrected frame")
        # hot reload: an invalid edit keeps the last good prescription (one log line), frames stay corrected
        rx.write_text("{ not json")
        waiting(lambda: any("keeping the last good" in line for line in layer_log(out)), "the reload message")
        after = len(frames(out))
        waiting(lambda: len(frames(out)) >= after + 3, "three more frames")
        stop.touch()
        stdout, stderr = proc.communicate(timeout=240)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, stdout[-2000:] + stderr[-2000:]
    found = reasons(out)
    assert len(found) == 1 and "sphere_D" in found[0] and str(rx) in found[0], found
    received_frames = frames(out)
    pics = _pictures()
    first = next(f for f in received_frames if _is_corrected(out, f))
    assert len([f for f in received_frames if f < first]) >= 10
    for f in received_frames[:10]:
        assert np.array_equal(received(out, f, 0), pics["left"])
    expected = _expected(kit, gl, 1)
    for view, eye in enumerate(EYES):
        assert_corrected(received(out, first, view), pics[eye], "srgb", expected[eye][0], eye)
    assert all(_is_corrected(out, f) for f in received_frames[-3:])
    assert len([line for line in layer_log(out) if "keeping the last good" in line]) == 1
    _assert_app_images_untouched(out)
    assert_life_cycle(out, swapchains=4)


def _is_corrected(out: Path, frame: int) -> bool:
    try:
        return not np.array_equal(received(out, frame, 0), _pictures()["left"])
    except (OSError, ValueError):
        return False                                      # being written


# --------------------------------------------------------------------------
# The layer command
# --------------------------------------------------------------------------


def _parser():
    from vrcorrect.apps import layer

    parser = argparse.ArgumentParser()
    layer.add_parser(parser.add_subparsers())
    return parser


def test_install_status_uninstall_and_never_overwriting_a_users_file(kit, tmp_path, capsys):
    from vrcorrect.apps import layer
    from vrcorrect.plumbing.errors import InputError

    home = tmp_path / "home"
    environ = {"HOME": str(home), "XDG_CONFIG_HOME": str(home / "cfg"), "XDG_DATA_HOME": str(home / "data"),
               "XDG_STATE_HOME": str(home / "state")}
    parser = _parser()
    assert "not installed" in "\n".join(layer.status_lines(environ))
    manifest = home / "data" / "openxr" / "1" / "api_layers" / "implicit.d" / "vrcorrect_layer.json"
    manifest.parent.mkdir(parents=True)
    manifest.write_text("{}")                                     # someone else's file
    with pytest.raises(InputError, match="--force"):
        layer.cmd_install(parser.parse_args(["layer", "install", "--rx", str(kit.rx)]), env=environ)
    assert manifest.read_text() == "{}"
    args = parser.parse_args(["layer", "install", "--rx", str(kit.rx), "--force"])
    assert args.func is layer.cmd_layer
    assert layer.cmd_install(args, env=environ) == 0
    lines = "\n".join(layer.status_lines(environ))
    assert "the loader will find it" in lines and f"prescription: {kit.rx} (valid)" in lines, lines
    assert "display:" in lines and "nothing logged yet" in lines
    # the pupil followed from the light with the robust design unless the configuration says otherwise
    assert "pupil: followed from the light of the frames shown (auto); robust design over the band of pupils " \
           "and +-0.25 D (the default" in lines, lines
    assert "pupil now: none logged yet" in lines, lines
    assert layer.cmd_install(parser.parse_args(["layer", "install", "--pupil", "3.5", "--robust", "off"]),
                             env=environ) == 0
    assert json.loads((home / "cfg" / "vrcorrect" / "layer.json").read_text())["options"] == \
        {"pupil": 3.5, "robust": False}
    lines = "\n".join(layer.status_lines(environ))
    assert "pupil: 3.5 mm; single-pupil design (robust off)" in lines and "pupil now" not in lines, lines
    assert layer.cmd_install(parser.parse_args(["layer", "install", "--pupil", "auto", "--robust", "on"]),
                             env=environ) == 0
    assert "pupil: followed from the light of the frames shown (auto); robust design over" in \
        "\n".join(layer.status_lines(environ))
    # a second install replaces its own files without --force
    assert layer.cmd_install(parser.parse_args(["layer", "install", "--display", "quest2"]), env=environ) == 0
    assert "display: quest2" in "\n".join(layer.status_lines(environ))
    assert "fovea: off, the whole view corrected" in "\n".join(layer.status_lines(environ))
    assert layer.cmd_install(parser.parse_args(["layer", "install", "--fovea", "12", "--gaze", "2,-1"]),
                             env=environ) == 0
    assert "fovea: a window of radius 12 deg around the gaze: the eye tracker's where the runtime offers " \
           "XR_EXT_eye_gaze_interaction, else (2, -1) deg from the view's centre; outside it a correction of the whole view at a quarter of the resolution" in "\n".join(layer.status_lines(environ))
    assert layer.cmd_install(parser.parse_args(["layer", "install", "--fovea", "12", "--periphery", "target"]),
                             env=environ) == 0
    assert "outside it the view as the application drew it" in "\n".join(layer.status_lines(environ))
    assert json.loads((home / "cfg" / "vrcorrect" / "layer.json").read_text())["rx"] == str(kit.rx)
    assert "DISABLE_VRCORRECT_LAYER=1" in "\n".join(
        layer.status_lines({**environ, "DISABLE_VRCORRECT_LAYER": "1"}))
    assert layer.cmd_uninstall(parser.parse_args(["layer", "uninstall"]), env=environ) == 0
    assert not manifest.exists()
    assert "not installed" in "\n".join(layer.status_lines(environ))
    capsys.readouterr()


def test_install_refuses_a_bad_prescription_or_display_before_writing(kit, tmp_path):
    from vrcorrect.apps import layer
    from vrcorrect.plumbing.errors import VrcorrectError

    home = tmp_path / "home"
    environ = {"HOME": str(home), "XDG_CONFIG_HOME": str(home / "cfg"), "XDG_DATA_HOME": str(home / "data")}
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(dict(RX, right=dict(RX["right"], sphere_D=99.0))))
    parser = _parser()
    with pytest.raises(VrcorrectError, match="sphere_D"):
        layer.cmd_install(parser.parse_args(["layer", "install", "--rx", str(bad)]), env=environ)
    with pytest.raises(VrcorrectError, match="display"):
        layer.cmd_install(parser.parse_args(["layer", "install", "--display", "nope"]), env=environ)
    with pytest.raises(VrcorrectError, match="--iterations-per-frame"):
        layer.cmd_install(parser.parse_args(["layer", "install", "--iterations-per-frame", "0"]), env=environ)
    with pytest.raises(VrcorrectError, match=r"--pupil.*1\.5.*2"):
        layer.cmd_install(parser.parse_args(["layer", "install", "--pupil", "1.5"]), env=environ)
    assert not (home / "cfg").exists()


def test_the_engine_never_imports_torch_or_the_apps():
    import ast

    names = set()
    for path in sorted((ROOT / "vrcorrect" / "runtime" / "layer").glob("*.py")):
        tree = ast.parse(path.read_text())
        names |= {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        names |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    assert "corrector" in names and not any("torch" in n or "apps" in n for n in names), names


def test_the_priming_budget_reads_seconds_or_converge_and_names_a_bad_value():
    import math

    from vrcorrect.plumbing.errors import ValidationError
    from vrcorrect.runtime.layer.config import PRIME_BUDGET_S, PRIME_ENV, prime_budget

    assert prime_budget({}) == PRIME_BUDGET_S == 1.0
    assert prime_budget({PRIME_ENV: " 2.5 "}) == 2.5 and prime_budget({PRIME_ENV: "0"}) == 0.0
    assert math.isinf(prime_budget({PRIME_ENV: "converge"}))
    for bad in ("-1", "soon", "nan", "61"):
        with pytest.raises(ValidationError, match=f"{PRIME_ENV}.*{bad}.*seconds from 0 to 60, or 'converge'"):
            prime_budget({PRIME_ENV: bad})


def test_a_stall_trace_writes_every_threads_stack_for_a_frame_that_outlasts_it_and_nothing_otherwise(tmp_path):
    """``VRCORRECT_LAYER_STALL_TRACE``'s watchdog (config.StallTrace): a frame disarmed in time leaves the
    file as it was; one that lasts past its seconds finds in it the stacks of the frame's thread
    (here, sleeping in this test) and of every other thread (one waiting in a function of its own),
    followed by which frame it was and how long it took."""
    import threading
    import time

    from vrcorrect.runtime.layer.config import StallTrace

    release = threading.Event()

    def a_worker_waiting_here():
        release.wait(30)

    worker = threading.Thread(target=a_worker_waiting_here)
    worker.start()
    path = tmp_path / "stalls" / "trace.txt"
    trace = StallTrace(path, seconds=0.05)
    try:
        assert trace.arm(7) == ""
        assert trace.disarm() == ""                         # at once: nothing written
        assert path.read_text() == ""
        assert trace.arm(8) == ""
        time.sleep(0.5)                                     # ten times the watch
        assert trace.disarm() == f"a frame took over 0.05 s in the layer: every thread's stack is in {path}"
        assert trace.disarm() == ""                         # disarmed once
    finally:
        release.set()
        worker.join()
        trace.close()
    text = path.read_text()
    assert "Timeout (0:00:00.050000)!" in text
    assert "a_stall_trace_writes_every_threads_stack" in text and "a_worker_waiting_here" in text
    said = re.search(r"the frame after 8 corrected ones, ([\d.]+) s in the layer; written 0.05 s into it", text)
    assert said and float(said.group(1)) >= 0.5, text
    assert "after 7 " not in text
    # not asked for: nothing; a file that cannot be written: off, said once, never an exception
    assert StallTrace(None).arm(1) == "" and StallTrace(None).disarm() == ""
    (tmp_path / "a_file").write_text("")
    blocked = StallTrace(tmp_path / "a_file" / "trace.txt")
    said = blocked.arm(1)
    assert "VRCORRECT_LAYER_STALL_TRACE" in said and "a_file" in said, said
    assert blocked.arm(2) == "" and blocked.disarm() == "" and blocked.path is None
