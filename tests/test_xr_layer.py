"""vrcorrect as an OpenXR API layer (``layer/vrcorrect_layer.c`` + :mod:`vrcorrect.runtime.xrlayer`),
between a separate OpenXR OpenGL application in C that knows nothing of vrcorrect
(``tests/xr_gl_app/xr_gl_app.c``) and the project's test runtime (``tests/xr_runtime``), all loaded
by pyopenxr's real OpenXR loader, under Xvfb (``x_display``).

The application submits a known image per eye every frame and, after each ``xrEndFrame``, writes
its own released swapchain images back out; the runtime writes what it received.  Checked: with
the layer (explicit, through ``XR_API_LAYER_PATH``/``XR_ENABLE_API_LAYERS``, with Khronos' core
validation layer below it; or implicit, installed by ``vrcorrect layer install`` in a temporary
``XDG_DATA_HOME``) the application's frames go through unchanged while the eye models build on the
layer's worker thread (one "building" log line), then the runtime receives each eye corrected for
that eye, equal to ``Corrector.apply`` on the same image (the n-th corrected frame to the n-th
apply) within 2/255, over the
whole image, over a sub-rect with the application's scissor test left on (the GL state comes
back as it was), for both eyes in one side-by-side swapchain, and for RGBA8 (linear) swapchains;
a Python (pyopenxr) application gets the layer in its own interpreter; the application's images
are never modified; the session life cycle completes
and every swapchain is destroyed.  The manifest's ``disable_environment`` gives the application's
images unchanged; so do no prescription, an invalid prescription (then a valid one: correction
resumes; a later invalid edit keeps the last good prescription), a swapchain format the layer
does not correct, the off switch (variable or file) and a Vulkan session (named, the next step),
each with one log line naming the reason.  The ``layer`` command's install, status and uninstall.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
RUNTIME_SOURCE = ROOT / "tests" / "xr_runtime" / "xr_test_runtime.c"
APP_SOURCE = ROOT / "tests" / "xr_gl_app" / "xr_gl_app.c"
VIEW = (96, 64)
EYES = ("left", "right")
LAYER = "XR_APILAYER_VRCORRECT_correction"
VALIDATION = "XR_APILAYER_LUNARG_core_validation"
CLEAN_STATES = ["IDLE", "READY", "SYNCHRONIZED", "VISIBLE", "FOCUSED", "VISIBLE", "SYNCHRONIZED", "STOPPING",
                "IDLE", "EXITING"]
RX = {"schema": "vrcorrect.prescription/1",
      "right": {"sphere_D": -4.0, "cylinder_D": -2.0, "axis_deg": 30, "pupil_diameter_mm": 4.0},
      "left": {"sphere_D": 1.0, "cylinder_D": 0.0, "axis_deg": 0, "pupil_diameter_mm": 4.0}}


def _cc() -> str:
    cc = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc")
    if cc is None:
        pytest.fail("no C compiler (cc/gcc) to build the test equipment: install gcc")
    return cc


def _loader() -> Path:
    import xr

    path = Path(xr.__file__).parent / "library" / "linux_x86_64" / "libopenxr_loader.so"
    assert path.is_file(), path
    return path


def _validation_dir() -> Path:
    import xr

    folder = Path(xr.__file__).parent / "api_layer" / "linux_x86_64"
    assert (folder / "XrApiLayer_core_validation.json").is_file(), folder
    return folder


@pytest.fixture(scope="module")
def kit(tmp_path_factory) -> dict[str, Path]:
    """The test runtime and its manifest, the application, the layer (built as ``install`` builds it)
    with an explicit-layer manifest beside it, the two eyes' pictures and a prescription."""
    from vrcorrect.apps.layer import build_layer, manifest_text

    folder = tmp_path_factory.mktemp("xr_layer")
    cc = _cc()
    runtime = folder / "libvrcorrect_xr_test_runtime.so"
    build = subprocess.run([cc, "-std=c11", "-O1", "-Wall", "-Wextra", "-Werror", "-shared", "-fPIC",
                            "-fvisibility=hidden", "-o", str(runtime), str(RUNTIME_SOURCE), "-ldl", "-lm"],
                           capture_output=True, text=True)
    assert build.returncode == 0, build.stderr
    (folder / "runtime.json").write_text(json.dumps({"file_format_version": "1.0.0", "runtime": {
        "name": "vrcorrect test runtime", "library_path": str(runtime)}}))
    app = folder / "xr_gl_app"
    build = subprocess.run([cc, "-std=c11", "-O1", "-Wall", "-Wextra", "-Werror", "-Wno-missing-field-initializers",
                            "-o", str(app), str(APP_SOURCE), "-ldl", "-lGL", "-lX11"], capture_output=True, text=True)
    assert build.returncode == 0, build.stderr
    layer_dir = folder / "layer"
    library = build_layer(layer_dir)
    (layer_dir / "vrcorrect_layer.json").write_text(manifest_text(library))
    # two different pictures with edges, gradients and colour (bottom row first, as GL stores them)
    y, x = np.mgrid[0:VIEW[1], 0:VIEW[0]]
    pictures = {}
    for i, eye in enumerate(EYES):
        img = np.zeros((VIEW[1], VIEW[0], 4), np.uint8)
        img[..., 0] = (x * 255 // (VIEW[0] - 1)).astype(np.uint8)
        img[..., 1] = np.where(((x // (6 + 2 * i)) + (y // 8)) % 2 == 0, 230, 25)
        img[..., 2] = (y * 255 // (VIEW[1] - 1)).astype(np.uint8) if i == 0 else (255 - x * 2).clip(0, 255)
        img[..., 3] = 255
        pictures[eye] = img
        img.tofile(folder / f"{eye}.raw")
    rx = folder / "rx.json"
    rx.write_text(json.dumps(RX))
    return {"folder": folder, "runtime": folder / "runtime.json", "app": app, "layer_dir": layer_dir, "rx": rx,
            "left": folder / "left.raw", "right": folder / "right.raw"}


def _pictures(kit) -> dict[str, np.ndarray]:
    return {eye: np.fromfile(kit[eye], np.uint8).reshape(VIEW[1], VIEW[0], 4) for eye in EYES}


def _env(kit, out: Path, *, explicit: bool = True, validation: bool = False, home: Path | None = None,
         **extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("XR_", "XRTEST_", "APP_", "VRCORRECT_", "XDG_", "DISABLE_VRCORRECT"))}
    home = home or out / "home"
    env.update(HOME=str(home), XDG_CONFIG_HOME=str(home / ".config"), XDG_DATA_HOME=str(home / ".local" / "share"),
               XDG_STATE_HOME=str(home / ".local" / "state"),
               XR_RUNTIME_JSON=str(kit["runtime"]), XRTEST_OUT_DIR=str(out), XRTEST_VIEW_SIZE=f"{VIEW[0]}x{VIEW[1]}",
               APP_LOADER=str(_loader()), APP_IMAGE_LEFT=str(kit["left"]), APP_IMAGE_RIGHT=str(kit["right"]),
               APP_OUT_DIR=str(out), VRCORRECT_LAYER_LOG=str(out / "layer.log"))
    layers, paths = [], []
    if explicit:
        layers.append(LAYER)
        paths.append(str(kit["layer_dir"]))
    if validation:
        layers.append(VALIDATION)                 # below vrcorrect: validates what the layer sends
        paths.append(str(_validation_dir()))
        env["XR_CORE_VALIDATION_EXPORT_TYPE"] = "text"
    if layers:
        env["XR_ENABLE_API_LAYERS"] = os.pathsep.join(layers)
        env["XR_API_LAYER_PATH"] = os.pathsep.join(paths)
    env.update(extra)
    return env


def _run(kit, out: Path, timeout: float = 300, corrected: int = 0, **kw) -> subprocess.CompletedProcess:
    """Run the application to the end.  ``corrected``: the layer builds its eye models on a worker
    thread while frames pass through, so the application runs (20 ms a frame, ``APP_STOP_FILE``)
    until the layer has logged "correcting with" (on its first corrected frame) and the runtime has
    received ``corrected`` frames from there."""
    out.mkdir(parents=True, exist_ok=True)
    if not corrected:
        result = subprocess.run([str(kit["app"])], capture_output=True, text=True, timeout=timeout,
                                env=_env(kit, out, **kw))
    else:
        stop = out / "stop"
        stdout_path, stderr_path = out / "app_stdout.txt", out / "app_stderr.txt"
        with open(stdout_path, "w") as so, open(stderr_path, "w") as se:   # files: a full pipe would stall the app
            proc = subprocess.Popen([str(kit["app"])], stdout=so, stderr=se, text=True,
                                    env=_env(kit, out, APP_STOP_FILE=str(stop), **kw))
            try:
                _wait_for(proc, lambda: any("correcting with" in line for line in _layer_log(out)),
                          "the layer's eye models", timeout)
                ready = len(_frames(out))
                _wait_for(proc, lambda: len(_frames(out)) >= ready + corrected, "the corrected frames", timeout)
                stop.touch()
                proc.wait(timeout=timeout)
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
        result = subprocess.CompletedProcess(proc.args, proc.returncode, stdout_path.read_text(),
                                             stderr_path.read_text())
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "done" in result.stdout
    return result


def _wait_for(proc: subprocess.Popen, check, what: str, limit: float = 240) -> None:
    deadline = time.monotonic() + limit
    while time.monotonic() < deadline:
        if check():
            return
        if proc.poll() is not None:
            raise AssertionError(f"the application ended while waiting for {what}")
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


def _runtime_log(out: Path) -> list[str]:
    return (out / "runtime.log").read_text().splitlines()


def _frames(out: Path) -> list[int]:
    return sorted({int(p.name.split("_")[1]) for p in out.glob("frame_*_view_0.npy")})


def _received(out: Path, frame: int, view: int) -> np.ndarray:
    """What the runtime received (its .npy: top row first), in GL row order like the pictures."""
    return np.load(out / f"frame_{frame:05d}_view_{view}.npy")[::-1]


def _corrected_frames(kit, out: Path, n: int, rect: tuple[int, int, int, int] | None = None) -> list[int]:
    """The first ``n`` corrected frames the runtime received (the first frame whose left view is not
    the application's picture, and those after it); every frame before them passed through
    (both views equal to the application's pictures, or to their ``rect``)."""
    pictures = _pictures(kit)
    if rect is not None:
        x, y, w, h = rect
        pictures = {eye: p[y:y + h, x:x + w] for eye, p in pictures.items()}
    frames = _frames(out)
    first = next((i for i, f in enumerate(frames) if not np.array_equal(_received(out, f, 0), pictures["left"])),
                 None)
    assert first is not None, "no corrected frame"
    for f in frames[:first]:
        for view, eye in enumerate(EYES):
            assert np.array_equal(_received(out, f, view), pictures[eye]), (f, eye)
    assert len(frames) >= first + n, (len(frames), first, n)
    return frames[first:first + n]


def _layer_log(out: Path) -> list[str]:
    path = out / "layer.log"
    return path.read_text().splitlines() if path.exists() else []


def _assert_app_images_untouched(kit, out: Path) -> None:
    pictures = _pictures(kit)
    files = sorted(out.glob("app_*_view_*.raw"))
    assert files
    for f in files:
        eye = EYES[int(f.stem.rsplit("_", 1)[1])]
        assert np.array_equal(np.fromfile(f, np.uint8).reshape(pictures[eye].shape), pictures[eye]), f.name


def _assert_life_cycle(out: Path, swapchains: int) -> None:
    log = _runtime_log(out)
    assert [line.split()[1] for line in log if line.startswith("state ")] == CLEAN_STATES
    assert len([line for line in log if line.startswith("create_swapchain")]) == swapchains
    assert len([line for line in log if line.startswith("destroy_swapchain")]) == swapchains
    assert log[-2:] == ["destroy_session", "destroy_instance"]
    assert not any("still alive" in line for line in log)


_EYE_MODELS: dict[tuple[str, str], object] = {}


def _eye_model(kit, eye: str):
    """The eye's model for ``kit["rx"]`` on quest2 with the default options, designed once per
    session (the layer's own is built on its worker thread from the same inputs)."""
    from vrcorrect.runtime.corrector import CorrectorOptions, build_eye_model
    from vrcorrect.specs.display import get_display
    from vrcorrect.specs.prescription import load_prescription

    key = (str(kit["rx"]), eye)
    if key not in _EYE_MODELS:
        _EYE_MODELS[key] = build_eye_model(load_prescription(kit["rx"]).eye(eye), get_display("quest2"),
                                           CorrectorOptions())
    return _EYE_MODELS[key]


def _expected(kit, gl, frames: int, rect: tuple[int, int, int, int] | None = None) -> dict[str, list[np.ndarray]]:
    """Each eye's correction of its picture (or of the rect x, y, w, h of it, GL pixels) by a
    separate Corrector: the first ``frames`` applies, RGB in GL row order."""
    from vrcorrect.runtime.corrector import Corrector
    from vrcorrect.runtime.gl import read_framebuffer, release, render_target, upload_texture

    out = {}
    for eye, picture in _pictures(kit).items():
        if rect is not None:
            x, y, w, h = rect
            picture = picture[y:y + h, x:x + w]
        corrector = Corrector(gl, kit["rx"], "quest2", eye, eye_model=_eye_model(kit, eye))
        tex = upload_texture(gl, np.ascontiguousarray(picture[::-1]))
        target, fb = render_target(gl, width=picture.shape[1], height=picture.shape[0])
        try:
            out[eye] = []
            for _ in range(frames):
                corrector.apply(tex, fb)
                out[eye].append(read_framebuffer(fb, components=3)[::-1].astype(int))
        finally:
            corrector.release()
            release(fb, target, tex)
    return out


def _assert_validation_clean(stdout: str) -> None:
    lines = [line for line in stdout.splitlines() if "VALID_" in line]
    assert any("Core Validation Layer is initialized" in line for line in lines), stdout[-2000:]
    bad = [line for line in lines if "VALID_DEBUG" not in line and "VALID_INFO" not in line]
    assert not bad, "\n".join(bad)


# --------------------------------------------------------------------------
# Corrected frames
# --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def corrected_run(x_display, kit, tmp_path_factory):
    out = tmp_path_factory.mktemp("corrected")
    result = _run(kit, out, corrected=3, validation=True, VRCORRECT_RX=str(kit["rx"]), APP_FRAMES="3")
    return result, out


def test_each_eye_is_corrected_like_the_corrector_with_validation_clean(corrected_run, kit, gl):
    result, out = corrected_run
    _assert_validation_clean(result.stdout)
    frames = _corrected_frames(kit, out, 3)
    expected = _expected(kit, gl, len(frames))
    pictures = _pictures(kit)
    for n, frame in enumerate(frames):
        for view, eye in enumerate(EYES):
            got = _received(out, frame, view)[..., :3].astype(int)
            assert got.shape == (VIEW[1], VIEW[0], 3)
            diff = np.abs(got - expected[eye][n])
            assert diff.max() <= 2, (frame, eye, diff.max())
            assert np.abs(got - pictures[eye][..., :3].astype(int)).mean() > 3      # not the picture itself
    # each eye its own prescription: the other eye's correction is far from what it got
    got = _received(out, frames[0], 1)[..., :3].astype(int)
    assert np.abs(got - expected["left"][0]).mean() > 5 * max(np.abs(got - expected["right"][0]).mean(), 0.2)


def test_the_applications_images_and_structures_are_untouched_and_the_life_cycle_completes(corrected_run, kit):
    result, out = corrected_run
    _assert_app_images_untouched(kit, out)     # and the app checked its projection views after xrEndFrame
    _assert_life_cycle(out, swapchains=4)      # two of the application's, two outputs of the layer's
    assert "gl error 0x0" in result.stdout
    log = _layer_log(out)
    assert any("correcting with" in line and str(kit["rx"]) in line for line in log), log
    assert len([line for line in log if "building the eye models" in line]) == 1, log
    assert any("per eye" in line and "left" in line and "right" in line and " ms" in line for line in log), log
    assert not any("pass-through" in line for line in log), log


def test_frames_keep_flowing_unchanged_while_the_eye_models_build(corrected_run, kit, record_property):
    """The eye models (seconds of CPU) build on the layer's worker thread, not in xrEndFrame: the
    application's frames keep going through, unchanged, until the first corrected one, and the log
    says "building" before "correcting with".  How long xrEndFrame took meanwhile (the largest
    gap between the passed-through frames the runtime received, from the files' times; the
    application sleeps 20 ms a frame) is recorded, not asserted: timings belong in benchmarks."""
    _, out = corrected_run
    frames = _frames(out)
    first = frames.index(_corrected_frames(kit, out, 1)[0])       # the frames before it: passed through
    assert first >= 5, first                                       # several frames during the build
    log = _layer_log(out)
    building = [i for i, line in enumerate(log) if "building the eye models for" in line and str(kit["rx"]) in line]
    correcting = [i for i, line in enumerate(log) if "correcting with" in line]
    assert len(building) == 1 and len(correcting) == 1 and building[0] < correcting[0], log
    times = [(out / f"frame_{f:05d}_view_1.npy").stat().st_mtime for f in frames[:first]]
    gap = max(b - a for a, b in itertools.pairwise(times))
    record_property("largest_gap_between_frames_while_building_s", round(gap, 3))
    print(f"{first} frames passed through while the eye models built; largest gap between frames {gap:.3f} s")


def test_a_sub_rect_is_corrected_and_the_applications_gl_state_comes_back(x_display, kit, gl, tmp_path):
    rect = (8, 4, 64, 48)
    out = tmp_path / "rect"
    _run(kit, out, corrected=1, VRCORRECT_RX=str(kit["rx"]), APP_FRAMES="1", APP_RECT=",".join(map(str, rect)),
         APP_SCISSOR="1")
    expected = _expected(kit, gl, 1, rect)
    frame = _corrected_frames(kit, out, 1, rect)[0]
    for view, eye in enumerate(EYES):
        got = _received(out, frame, view)[..., :3].astype(int)
        assert got.shape == (rect[3], rect[2], 3)
        assert np.abs(got - expected[eye][0]).max() <= 2, eye
    _assert_app_images_untouched(kit, out)


def test_both_eyes_in_one_side_by_side_swapchain_are_each_corrected(x_display, kit, gl, tmp_path):
    """One swapchain twice as wide, each eye's view a rect in its half: one output swapchain,
    acquired once per frame, each half corrected for its own eye."""
    out = tmp_path / "side_by_side"
    _run(kit, out, corrected=1, VRCORRECT_RX=str(kit["rx"]), APP_FRAMES="1", APP_SIDE_BY_SIDE="1")
    assert f"create_swapchain 0 format=0x8c43 {2 * VIEW[0]}x{VIEW[1]}" in _runtime_log(out)
    expected = _expected(kit, gl, 1)
    frame = _corrected_frames(kit, out, 1)[0]
    for view, eye in enumerate(EYES):
        got = _received(out, frame, view)[..., :3].astype(int)
        assert np.abs(got - expected[eye][0]).max() <= 2, eye
    _assert_app_images_untouched(kit, out)
    _assert_life_cycle(out, swapchains=2)


def test_rgba8_swapchains_get_linear_light_of_each_eyes_correction(x_display, kit, gl, tmp_path):
    """An RGBA8 (linear) swapchain holds linear light: the layer corrects its sRGB encoding and
    writes the correction back as linear light, as ``vrcorrect xr`` does for RGBA8 swapchains."""
    from vrcorrect.runtime.corrector import Corrector
    from vrcorrect.runtime.gl import read_framebuffer, release, render_target, upload_texture
    from vrcorrect.specs.display import linear_to_srgb, srgb_to_linear

    out = tmp_path / "rgba8"
    _run(kit, out, corrected=1, VRCORRECT_RX=str(kit["rx"]), APP_FRAMES="1", APP_FORMAT="rgba8")
    assert "create_swapchain 0 format=0x8058 96x64" in _runtime_log(out)
    frame = _corrected_frames(kit, out, 1)[0]
    for view, (eye, picture) in enumerate(_pictures(kit).items()):
        codes = picture.copy()
        codes[..., :3] = np.round(linear_to_srgb(picture[..., :3] / 255.0) * 255.0).astype(np.uint8)
        corrector = Corrector(gl, kit["rx"], "quest2", eye, eye_model=_eye_model(kit, eye))
        tex = upload_texture(gl, np.ascontiguousarray(codes[::-1]))
        target, fb = render_target(gl, width=VIEW[0], height=VIEW[1])
        try:
            corrector.apply(tex, fb)
            expected = read_framebuffer(fb, components=3)[::-1] / 255.0
        finally:
            corrector.release()
            release(fb, target, tex)
        linear = np.round(srgb_to_linear(expected) * 255.0)
        got = _received(out, frame, view)[..., :3].astype(float)
        close = np.abs(got - linear) <= 2
        assert close.mean() > 0.99, (eye, close.mean())
        assert np.abs(got - picture[..., :3]).mean() > 3
    _assert_app_images_untouched(kit, out)
    _assert_life_cycle(out, swapchains=4)


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
    # small views and one iteration a frame for the application's own correction: its frames are
    # cheaper on a software renderer (whose GL calls hold the GIL the layer's worker thread needs)
    env = _env(kit, out, VRCORRECT_RX=str(kit["rx"]), XRTEST_VIEW_SIZE="32x32")
    with open(out / "stdout.txt", "w") as so, open(out / "stderr.txt", "w") as se:
        proc = subprocess.Popen([sys.executable, "-m", "vrcorrect.apps.cli", "xr", "--iterations-per-frame", "1",
                                 "--source", str(ROOT / "vrcorrect" / "data" / "sample.png"), "--frames", "1000000"],
                                stdout=so, stderr=se, text=True, cwd=ROOT, env=env)
        try:
            _wait_for(proc, lambda: any("correcting with" in line for line in _layer_log(out)),
                      "the layer's eye models", 300)
            ready = len(_frames(out))
            _wait_for(proc, lambda: len(_frames(out)) >= ready + 3, "corrected frames", 120)
            proc.send_signal(signal.SIGINT)                # the application ends its session
            proc.wait(timeout=120)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert proc.returncode == 0, (out / "stderr.txt").read_text()[-3000:]
    log = _layer_log(out)
    assert any("correcting with" in line for line in log), log
    closed = [int(m.group(1)) for line in log for m in [re.search(r"closed after (\d+) corrected frames", line)] if m]
    assert len(closed) == 1 and closed[0] >= 1, log
    assert not any("pass-through" in line for line in log), log
    states = [line.split()[1] for line in _runtime_log(out) if line.startswith("state ")]
    assert states == CLEAN_STATES


def test_the_installed_implicit_layer_corrects_and_its_disable_environment_turns_it_off(x_display, kit, gl, tmp_path):
    from vrcorrect.apps import layer

    home = tmp_path / "home"
    env = _env(kit, tmp_path, explicit=False, home=home)
    parser = argparse.ArgumentParser()
    layer.add_parser(parser.add_subparsers())
    args = parser.parse_args(["layer", "install", "--rx", str(kit["rx"]), "--display", "quest2"])
    assert layer.cmd_install(args, env=env) == 0
    manifest = home / ".local" / "share" / "openxr" / "1" / "api_layers" / "implicit.d" / "vrcorrect_layer.json"
    doc = json.loads(manifest.read_text())
    assert doc["api_layer"]["disable_environment"] == "DISABLE_VRCORRECT_LAYER"
    assert Path(doc["api_layer"]["library_path"]).is_file()

    on = tmp_path / "on"
    _run(kit, on, corrected=1, explicit=False, home=home, APP_FRAMES="1")
    expected = _expected(kit, gl, 1)
    frame = _corrected_frames(kit, on, 1)[0]
    for view, eye in enumerate(EYES):
        got = _received(on, frame, view)[..., :3].astype(int)
        assert np.abs(got - expected[eye][0]).max() <= 2, eye

    off = tmp_path / "off"
    _run(kit, off, explicit=False, home=home, APP_FRAMES="2", DISABLE_VRCORRECT_LAYER="1")
    pictures = _pictures(kit)
    for frame in _frames(off):
        for view, eye in enumerate(EYES):
            assert np.array_equal(_received(off, frame, view), pictures[eye])
    _assert_life_cycle(off, swapchains=2)
    assert _layer_log(off) == []                      # the loader did not load it at all


# --------------------------------------------------------------------------
# Pass-through, one log line naming the reason
# --------------------------------------------------------------------------


def _assert_passed_through(kit, out: Path) -> None:
    pictures = _pictures(kit)
    frames = _frames(out)
    assert frames
    for frame in frames:
        for view, eye in enumerate(EYES):
            assert np.array_equal(_received(out, frame, view), pictures[eye]), (frame, eye)


def _reasons(out: Path) -> list[str]:
    return [line for line in _layer_log(out) if "pass-through" in line]


def test_no_prescription_passes_through_with_one_log_line(x_display, kit, tmp_path):
    out = tmp_path / "none"
    _run(kit, out, APP_FRAMES="4")
    _assert_passed_through(kit, out)
    _assert_app_images_untouched(kit, out)
    _assert_life_cycle(out, swapchains=4)
    reasons = _reasons(out)
    assert len(reasons) == 1 and "no prescription" in reasons[0] and "VRCORRECT_RX" in reasons[0], reasons


@pytest.mark.parametrize("switch", ["environment", "file"])
def test_the_off_switch_passes_through_with_one_log_line(x_display, kit, tmp_path, switch):
    out = tmp_path / "off"
    extra = {"VRCORRECT_LAYER_OFF": "1"} if switch == "environment" else {}
    if switch == "file":                    # beside the layer configuration ($XDG_CONFIG_HOME/vrcorrect/)
        off = out / "home" / ".config" / "vrcorrect" / "layer.off"
        off.parent.mkdir(parents=True)
        off.touch()
    _run(kit, out, APP_FRAMES="3", VRCORRECT_RX=str(kit["rx"]), **extra)
    _assert_passed_through(kit, out)
    reasons = _reasons(out)
    word = "VRCORRECT_LAYER_OFF" if switch == "environment" else "layer.off exists"
    assert len(reasons) == 1 and word in reasons[0], reasons


def test_an_unsupported_swapchain_format_passes_through_with_one_log_line(x_display, kit, tmp_path):
    # the test runtime offers half-float swapchains too, which the layer does not correct (yet)
    out = tmp_path / "format"
    _run(kit, out, APP_FRAMES="3", APP_FORMAT="rgba16f", XRTEST_FORMATS="srgb,rgba8,rgba16f",
         VRCORRECT_RX=str(kit["rx"]))
    _assert_passed_through(kit, out)
    _assert_life_cycle(out, swapchains=2)             # no output swapchains were made
    reasons = _reasons(out)
    assert len(reasons) == 1 and "0x881A" in reasons[0] and "not supported" in reasons[0], reasons


@pytest.mark.parametrize("end", ["XRTEST_STOP_AFTER", "XRTEST_LOSS_AFTER"], ids=["runtime stops", "session lost"])
def test_the_runtime_ending_the_session_tears_the_layer_down_cleanly(x_display, kit, tmp_path, end):
    """The exit and loss paths of tests/test_xr.py with the layer in, while its worker thread is
    still building the eye models: the application ends normally and everything is destroyed,
    the layer's output swapchains included."""
    out = tmp_path / end.lower()
    result = _run(kit, out, APP_FRAMES="50", VRCORRECT_RX=str(kit["rx"]), **{end: "5"})
    assert result.returncode == 0, result.stdout + result.stderr
    log = _runtime_log(out)
    states = [line.split()[1] for line in log if line.startswith("state ")]
    assert ("LOSS_PENDING" in states) == (end == "XRTEST_LOSS_AFTER") and states[-1] in ("EXITING", "LOSS_PENDING")
    made = [line for line in log if line.startswith("create_swapchain")]
    assert len(made) == 4                             # the application's two and the layer's two outputs
    assert len([line for line in log if line.startswith("destroy_swapchain")]) == 4
    assert log[-2:] == ["destroy_session", "destroy_instance"]
    assert not any("still alive" in line for line in log)
    assert not any("Traceback" in line or "error" in line.lower() for line in _layer_log(out)), _layer_log(out)


def test_a_vulkan_session_passes_through_and_names_vulkan(x_display, kit, tmp_path):
    """The test runtime has OpenGL only, so it refuses the session; the layer has passed the
    request through untouched (the runtime's own error reaches the application) and said why."""
    out = tmp_path / "vulkan"
    out.mkdir()
    result = subprocess.run([str(kit["app"])], capture_output=True, text=True, timeout=120,
                            env=_env(kit, out, VRCORRECT_RX=str(kit["rx"]), APP_BINDING="vulkan"))
    assert result.returncode == 3, result.stdout + result.stderr
    assert "vulkan create_session -38" in result.stdout          # XR_ERROR_GRAPHICS_DEVICE_INVALID, the runtime's
    reasons = _reasons(out)
    assert len(reasons) == 1 and "Vulkan (XR_KHR_vulkan_enable)" in reasons[0] and "next step" in reasons[0], reasons
    assert "destroy_instance" in _runtime_log(out)


def test_an_invalid_prescription_passes_through_until_a_valid_one_arrives_and_hot_reload_keeps_the_last_good(x_display, kit, gl, tmp_path):
    out = tmp_path / "invalid"
    out.mkdir()
    rx = tmp_path / "rx.json"
    bad = dict(RX, right=dict(RX["right"], sphere_D=99.0))
    rx.write_text(json.dumps(bad))
    stop = tmp_path / "stop"
    proc = subprocess.Popen([str(kit["app"])], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_env(kit, out, VRCORRECT_RX=str(rx), APP_FRAMES="2", APP_STOP_FILE=str(stop)))
    try:
        def wait_for(check, what: str, limit: float = 240) -> None:
            _wait_for(proc, check, what, limit)

        wait_for(lambda: len(_frames(out)) >= 10, "ten passed-through frames")
        rx.write_text(json.dumps(RX))
        wait_for(lambda: any("correcting with" in line for line in _layer_log(out)), "the valid prescription")
        wait_for(lambda: any(_is_corrected(kit, out, f) for f in _frames(out)[-3:]), "a corrected frame")
        # hot reload: an invalid edit keeps the last good prescription (one log line), frames stay corrected
        rx.write_text("{ not json")
        wait_for(lambda: any("keeping the last good" in line for line in _layer_log(out)), "the reload message")
        after = len(_frames(out))
        wait_for(lambda: len(_frames(out)) >= after + 3, "three more frames")
        stop.touch()
        stdout, stderr = proc.communicate(timeout=240)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, stdout[-2000:] + stderr[-2000:]
    reasons = _reasons(out)
    assert len(reasons) == 1 and "sphere_D" in reasons[0] and str(rx) in reasons[0], reasons
    frames = _frames(out)
    pictures = _pictures(kit)
    first = next(f for f in frames if _is_corrected(kit, out, f))
    assert len([f for f in frames if f < first]) >= 10
    for f in frames[:10]:
        assert np.array_equal(_received(out, f, 0), pictures["left"])
    expected = _expected(kit, gl, 1)
    for view, eye in enumerate(EYES):
        assert np.abs(_received(out, first, view)[..., :3].astype(int) - expected[eye][0]).max() <= 2, eye
    assert all(_is_corrected(kit, out, f) for f in frames[-3:])
    assert len([line for line in _layer_log(out) if "keeping the last good" in line]) == 1
    _assert_app_images_untouched(kit, out)
    _assert_life_cycle(out, swapchains=4)


def _is_corrected(kit, out: Path, frame: int) -> bool:
    try:
        return not np.array_equal(_received(out, frame, 0), _pictures(kit)["left"])
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
    env = {"HOME": str(home), "XDG_CONFIG_HOME": str(home / "cfg"), "XDG_DATA_HOME": str(home / "data"),
           "XDG_STATE_HOME": str(home / "state")}
    parser = _parser()
    assert "not installed" in "\n".join(layer.status_lines(env))
    manifest = home / "data" / "openxr" / "1" / "api_layers" / "implicit.d" / "vrcorrect_layer.json"
    manifest.parent.mkdir(parents=True)
    manifest.write_text("{}")                                     # someone else's file
    with pytest.raises(InputError, match="--force"):
        layer.cmd_install(parser.parse_args(["layer", "install", "--rx", str(kit["rx"])]), env=env)
    assert manifest.read_text() == "{}"
    args = parser.parse_args(["layer", "install", "--rx", str(kit["rx"]), "--force"])
    assert args.func is layer.cmd_layer
    assert layer.cmd_install(args, env=env) == 0
    lines = "\n".join(layer.status_lines(env))
    assert "the loader will find it" in lines and f"prescription: {kit['rx']} (valid)" in lines, lines
    assert "display:" in lines and "nothing logged yet" in lines
    # a second install replaces its own files without --force
    assert layer.cmd_install(parser.parse_args(["layer", "install", "--display", "quest2"]), env=env) == 0
    assert "display: quest2" in "\n".join(layer.status_lines(env))
    assert json.loads((home / "cfg" / "vrcorrect" / "layer.json").read_text())["rx"] == str(kit["rx"])
    assert "DISABLE_VRCORRECT_LAYER=1" in "\n".join(
        layer.status_lines({**env, "DISABLE_VRCORRECT_LAYER": "1"}))
    assert layer.cmd_uninstall(parser.parse_args(["layer", "uninstall"]), env=env) == 0
    assert not manifest.exists()
    assert "not installed" in "\n".join(layer.status_lines(env))
    capsys.readouterr()


def test_install_refuses_a_bad_prescription_or_display_before_writing(kit, tmp_path):
    from vrcorrect.apps import layer
    from vrcorrect.plumbing.errors import VrcorrectError

    home = tmp_path / "home"
    env = {"HOME": str(home), "XDG_CONFIG_HOME": str(home / "cfg"), "XDG_DATA_HOME": str(home / "data")}
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(dict(RX, right=dict(RX["right"], sphere_D=99.0))))
    parser = _parser()
    with pytest.raises(VrcorrectError, match="sphere_D"):
        layer.cmd_install(parser.parse_args(["layer", "install", "--rx", str(bad)]), env=env)
    with pytest.raises(VrcorrectError, match="display"):
        layer.cmd_install(parser.parse_args(["layer", "install", "--display", "nope"]), env=env)
    with pytest.raises(VrcorrectError, match="--iterations-per-frame"):
        layer.cmd_install(parser.parse_args(["layer", "install", "--iterations-per-frame", "0"]), env=env)
    assert not (home / "cfg").exists()


def test_the_engine_never_imports_torch_or_the_apps():
    import ast

    tree = ast.parse((ROOT / "vrcorrect" / "runtime" / "xrlayer.py").read_text())
    names = {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    names |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    assert not any("torch" in n or "apps" in n for n in names), names
