"""Test equipment shared by the OpenXR layer's tests (``test_xr_layer*.py``): the test runtime (built
by ``tools/xr_test_runtime.sh``), the C test applications (``tests/xr_gl_app``, ``tests/xr_vk_app``),
the layer (built as ``vrcorrect layer install`` builds it) with an explicit-layer manifest, the two
eyes' pictures and a prescription; how to run an application and read what the runtime received;
and what each view must hold: ``Corrector.apply`` on the application's image, in the swapchain
format's own encoding, within 2/255 of the Corrector's sRGB code values.

Pictures are numpy arrays with row 0 the top of the image; so are the runtime's ``.npy`` files,
for both APIs.  The GL application takes its raw files in GL's row order (bottom row first), the
Vulkan application in Vulkan's (top row first).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import pytest

from vrcorrect.specs.vocabulary import VIEW_ORDER

ROOT = Path(__file__).resolve().parents[1]
RUNTIME_SCRIPT = ROOT / "tools" / "xr_test_runtime.sh"
GL_APP_SOURCE = ROOT / "tests" / "xr_gl_app" / "xr_gl_app.c"
VK_APP_SOURCE = ROOT / "tests" / "xr_vk_app" / "xr_vk_app.c"
VIEW = (96, 64)
EYES = VIEW_ORDER                    # view i is EYES[i] (PRIMARY_STEREO)
LAYER = "XR_APILAYER_VRCORRECT_correction"
VALIDATION = "XR_APILAYER_LUNARG_core_validation"
VULKAN_VALIDATION = "VK_LAYER_KHRONOS_validation"
CLEAN_STATES = ["IDLE", "READY", "SYNCHRONIZED", "VISIBLE", "FOCUSED", "VISIBLE", "SYNCHRONIZED", "STOPPING",
                "IDLE", "EXITING"]
RX = {"schema": "vrcorrect.prescription/1",
      "right": {"sphere_D": -4.0, "cylinder_D": -2.0, "axis_deg": 30, "pupil_diameter_mm": 4.0},
      "left": {"sphere_D": 1.0, "cylinder_D": 0.0, "axis_deg": 0, "pupil_diameter_mm": 4.0}}
# the swapchain formats by the test runtime's names (XRTEST_FORMATS): how their values are stored
ENCODING = {"srgb": "srgb", "bgra8srgb": "srgb", "rgba8": "linear8", "bgra8": "linear8", "rgb10a2": "linear10",
            "rgba16f": "float"}


def cc() -> str:
    compiler = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc")
    if compiler is None:
        pytest.fail("no C compiler (cc/gcc) to build the test equipment: install gcc")
    return compiler


def loader() -> Path:
    import xr

    path = Path(xr.__file__).parent / "library" / "linux_x86_64" / "libopenxr_loader.so"
    assert path.is_file(), path
    return path


def validation_dir() -> Path:
    import xr

    folder = Path(xr.__file__).parent / "api_layer" / "linux_x86_64"
    assert (folder / "XrApiLayer_core_validation.json").is_file(), folder
    return folder


def pictures() -> dict[str, np.ndarray]:
    """Two different pictures with edges, gradients and colour, (H, W, 4) uint8, top row first."""
    w, h = VIEW
    y, x = np.mgrid[0:h, 0:w]
    y = h - 1 - y                              # as the first tests drew them, bottom row first
    out = {}
    for i, eye in enumerate(EYES):
        img = np.zeros((h, w, 4), np.uint8)
        img[..., 0] = (x * 255 // (w - 1)).astype(np.uint8)
        img[..., 1] = np.where(((x // (6 + 2 * i)) + (y // 8)) % 2 == 0, 230, 25)
        img[..., 2] = (y * 255 // (h - 1)).astype(np.uint8) if i == 0 else (255 - x * 2).clip(0, 255)
        img[..., 3] = 255
        out[eye] = img
    return out


@dataclass(frozen=True)
class Kit:
    folder: Path
    runtime: Path                        # the runtime's manifest (XR_RUNTIME_JSON)
    gl_app: Path
    vk_app: Path
    layer_dir: Path                      # the layer and its explicit-layer manifest
    rx: Path
    raw: dict[tuple[str, str], Path]     # (app, eye) -> the picture as that application reads it


def build_kit(folder: Path) -> Kit:
    """Build everything into ``folder`` (the runtime through ``tools/xr_test_runtime.sh``, whose last
    line of output must be the manifest)."""
    from vrcorrect.runtime.layer.build import build_layer, manifest_text

    compiler = cc()
    script = subprocess.run(["bash", str(RUNTIME_SCRIPT), str(folder / "runtime")], capture_output=True, text=True,
                            env={**os.environ, "CC": compiler})
    assert script.returncode == 0, script.stderr
    runtime = Path(script.stdout.strip().splitlines()[-1])
    assert runtime.is_file() and json.loads(runtime.read_text())["runtime"]["library_path"], script.stdout
    strict = ["-std=c11", "-O1", "-Wall", "-Wextra", "-Werror", "-Wno-missing-field-initializers"]
    apps = {}
    for name, source, libs in (("gl", GL_APP_SOURCE, ["-lGL", "-lX11"]), ("vk", VK_APP_SOURCE, ["-lvulkan"])):
        apps[name] = folder / f"xr_{name}_app"
        build = subprocess.run([compiler, *strict, "-o", str(apps[name]), str(source), "-ldl", *libs, "-lm"],
                               capture_output=True, text=True)
        assert build.returncode == 0, build.stderr
    layer_dir = folder / "layer"
    library = build_layer(layer_dir)
    (layer_dir / "vrcorrect_layer.json").write_text(manifest_text(library))
    raw = {}
    for eye, picture in pictures().items():
        for app, rows in (("gl", picture[::-1]), ("vk", picture)):
            raw[app, eye] = folder / f"{app}_{eye}.raw"
            np.ascontiguousarray(rows).tofile(raw[app, eye])
    rx = folder / "rx.json"
    rx.write_text(json.dumps(RX))
    return Kit(folder, runtime, apps["gl"], apps["vk"], layer_dir, rx, raw)


_KITS: dict[str, Kit] = {}


@pytest.fixture(scope="session")
def kit(tmp_path_factory) -> Kit:
    """One build of the equipment for the whole session."""
    if "kit" not in _KITS:
        _KITS["kit"] = build_kit(tmp_path_factory.mktemp("xr_layer_kit"))
    return _KITS["kit"]


PINNED_OPTIONS = {"pupil": "rx", "robust": False}
"""The layer's options in the runs whose views are compared with :func:`converged_codes`: the design
for the prescription's own pupil, as the reference Corrector's (:func:`eye_model`).  The layer's
default (the pupil followed from the light, robust) designs for each frame's light as it comes, which
a reference cannot replay code for code; the runs that configure the layer themselves, or install it,
run that default."""


def env(kit: Kit, out: Path, *, app: str = "gl", explicit: bool = True, validation: bool = False,
        vulkan_validation: bool = False, home: Path | None = None, prime: str | None = "converge",
        **extra: str) -> dict[str, str]:
    """The environment of a run writing to ``out``: a private HOME and XDG folders, the test runtime,
    the application's inputs; the layer explicit (``XR_API_LAYER_PATH``) unless ``explicit`` is False;
    Khronos core validation below it; Khronos Vulkan validation in the application's instance.
    ``prime``: the layer's ``VRCORRECT_LAYER_PRIME_S`` (``converge``, so that the first corrected frame
    of a still picture is :func:`converged_codes`; ``None``: unset, the layer's default budget).  An
    explicit layer without a ``VRCORRECT_LAYER_CONFIG`` of the test's gets a configuration of
    :data:`PINNED_OPTIONS` where the layer looks for one (``$XDG_CONFIG_HOME/vrcorrect/layer.json``; the
    prescription from ``VRCORRECT_RX``)."""
    out.mkdir(parents=True, exist_ok=True)
    environ = {k: v for k, v in os.environ.items()
               if not k.startswith(("XR_", "XRTEST_", "APP_", "VRCORRECT_", "XDG_", "DISABLE_VRCORRECT", "VK_"))}
    home = home or out / "home"
    environ.update(HOME=str(home), XDG_CONFIG_HOME=str(home / ".config"),
                   XDG_DATA_HOME=str(home / ".local" / "share"), XDG_STATE_HOME=str(home / ".local" / "state"),
                   XR_RUNTIME_JSON=str(kit.runtime), XRTEST_OUT_DIR=str(out),
                   XRTEST_VIEW_SIZE=f"{VIEW[0]}x{VIEW[1]}", APP_LOADER=str(loader()),
                   APP_IMAGE_LEFT=str(kit.raw[app, "left"]), APP_IMAGE_RIGHT=str(kit.raw[app, "right"]),
                   APP_OUT_DIR=str(out), VRCORRECT_LAYER_LOG=str(out / "layer.log"),
                   # one Mesa shader cache for the session's runs (a user's machine has one too): the layer's
                   # first corrected frame compiles its shaders once, not in every run
                   MESA_SHADER_CACHE_DIR=str(kit.folder / "mesa_shader_cache"))
    layers, paths = [], []
    if explicit:
        layers.append(LAYER)
        paths.append(str(kit.layer_dir))
    if validation:
        layers.append(VALIDATION)                 # below vrcorrect: validates what the layer sends
        paths.append(str(validation_dir()))
        environ["XR_CORE_VALIDATION_EXPORT_TYPE"] = "text"
    if layers:
        environ["XR_ENABLE_API_LAYERS"] = os.pathsep.join(layers)
        environ["XR_API_LAYER_PATH"] = os.pathsep.join(paths)
    if vulkan_validation:
        environ["VK_INSTANCE_LAYERS"] = VULKAN_VALIDATION
        environ["VK_LOADER_DEBUG"] = "layer"          # the Vulkan loader says when it inserts the layer
    if prime is not None:
        environ["VRCORRECT_LAYER_PRIME_S"] = prime
    pinned = home / ".config" / "vrcorrect" / "layer.json"            # where the layer looks by default
    if explicit and "VRCORRECT_LAYER_CONFIG" not in extra and not pinned.exists():
        pinned.parent.mkdir(parents=True, exist_ok=True)
        pinned.write_text(json.dumps({"options": PINNED_OPTIONS}))
    environ.update(extra)
    return environ


def wait_for(proc: subprocess.Popen, check: Callable[[], bool], what: str, limit: float = 240) -> None:
    deadline = time.monotonic() + limit
    while time.monotonic() < deadline:
        if check():
            return
        if proc.poll() is not None:
            raise AssertionError(f"the application ended while waiting for {what}")
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


def run(command: list[str], out: Path, environ: dict[str, str], *, corrected: int = 0, stop_env: str = "APP_STOP_FILE",
        timeout: float = 300, stdin: bool = False) -> subprocess.CompletedProcess:
    """Run an application to its end (stdout and stderr to files: a full pipe would stall it).
    ``corrected``: the layer builds its eye models on a worker thread while frames pass through, so
    the run goes on until the layer has logged "correcting with" and the runtime has received
    ``corrected`` frames from there; then the stop file (named by ``stop_env`` in the application's
    or the runtime's environment) appears.  ``stdin``: give the application a pipe that stays open
    (hello_xr quits at the end of its standard input)."""
    out.mkdir(parents=True, exist_ok=True)
    stop = out / "stop"
    environ = dict(environ)
    if corrected:
        environ[stop_env] = str(stop)
    stdout_path, stderr_path = out / "app_stdout.txt", out / "app_stderr.txt"
    with open(stdout_path, "w") as so, open(stderr_path, "w") as se:
        proc = subprocess.Popen(command, stdout=so, stderr=se, text=True, env=environ,
                                stdin=subprocess.PIPE if stdin else subprocess.DEVNULL)
        try:
            if corrected:
                wait_for(proc, lambda: any("correcting with" in line for line in layer_log(out)),
                         "the layer's eye models", timeout)
                ready = len(frames(out))
                wait_for(proc, lambda: len(frames(out)) >= ready + corrected, "the corrected frames", timeout)
                stop.touch()
            proc.wait(timeout=timeout)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            if proc.stdin:
                proc.stdin.close()
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout_path.read_text(), stderr_path.read_text())


def runtime_log(out: Path) -> list[str]:
    return (out / "runtime.log").read_text().splitlines()


def frames(out: Path) -> list[int]:
    """The xrEndFrame calls whose views the runtime wrote (both views written)."""
    return sorted({int(p.name.split("_")[1]) for p in out.glob("frame_*_view_1.npy")})


def received(out: Path, frame: int, view: int) -> np.ndarray:
    """What the runtime received for a view, as it stores it (top row first)."""
    return np.load(out / f"frame_{frame:05d}_view_{view}.npy")


def layer_log(out: Path) -> list[str]:
    path = out / "layer.log"
    return path.read_text().splitlines() if path.exists() else []


def reasons(out: Path) -> list[str]:
    return [line for line in layer_log(out) if "pass-through" in line]


def submitted(out: Path) -> dict[int, list[int]]:
    """Each frame's views' swapchains (runtime.log's "end_frame N layers=1 views=S:x,y,wxh ...")."""
    out_map = {}
    for line in runtime_log(out):
        m = re.match(r"end_frame (\d+) layers=1 views=(.*)$", line)
        if m:
            out_map[int(m.group(1))] = [int(v.split(":")[0]) for v in m.group(2).split()]
    return out_map


def assert_life_cycle(out: Path, swapchains: int) -> None:
    log = runtime_log(out)
    assert [line.split()[1] for line in log if line.startswith("state ")] == CLEAN_STATES
    assert len([line for line in log if line.startswith("create_swapchain")]) == swapchains
    assert len([line for line in log if line.startswith("destroy_swapchain")]) == swapchains
    assert log[-2:] == ["destroy_session", "destroy_instance"]
    assert not any("still alive" in line for line in log)


def assert_validation_clean(stdout: str) -> None:
    lines = [line for line in stdout.splitlines() if "VALID_" in line]
    assert any("Core Validation Layer is initialized" in line for line in lines), stdout[-2000:]
    bad = [line for line in lines if "VALID_DEBUG" not in line and "VALID_INFO" not in line]
    assert not bad, "\n".join(bad)


def assert_vulkan_validation_clean(text: str) -> None:
    """Khronos Vulkan validation ran (the Vulkan loader inserted it into the application's instance,
    below the layer's Vulkan calls, which go through the application's device) and reported no error,
    and no performance warning about the layer's copies (``vkCmdCopyImage``: the shared images are in
    TRANSFER_SRC/DST_OPTIMAL for them; the runtime's read-back is a ``vkCmdCopyImageToBuffer``)."""
    assert f'Insert instance layer "{VULKAN_VALIDATION}"' in text, text[-2000:]
    errors = [line for line in text.splitlines() if "Validation Error" in line]
    assert not errors, "\n".join(errors[:5])
    copies = [line for line in text.splitlines() if "Performance Warning" in line
              and re.search(r"vkCmdCopyImage(?!ToBuffer)|vkCmdPipelineBarrier|vkQueueSubmit", line)]
    assert not copies, "\n".join(copies[:5])


# --------------------------------------------------------------------------
# What a view must hold
# --------------------------------------------------------------------------

_EYE_MODELS: dict[tuple[str, str], object] = {}


def eye_model(kit: Kit, eye: str):
    """The eye's model for ``kit.rx`` on quest2 with the default options, designed once per session
    (the layer builds its own on its worker thread from the same inputs)."""
    from vrcorrect.runtime.corrector import CorrectorOptions, build_eye_model
    from vrcorrect.specs.display import get_display
    from vrcorrect.specs.prescription import load_prescription

    key = (str(kit.rx), eye)
    if key not in _EYE_MODELS:
        _EYE_MODELS[key] = build_eye_model(load_prescription(kit.rx).eye(eye), get_display("quest2"),
                                           CorrectorOptions())
    return _EYE_MODELS[key]


def stored(picture: np.ndarray, fmt: str, gain: float = 1.0) -> np.ndarray:
    """What an application that wrote ``picture``'s bytes into a ``fmt`` swapchain stores, as the
    runtime writes it: RGBA8 (BGRA reordered), packed 10-bit (alpha 3) or float16 (v / 255 * gain)."""
    if fmt == "rgb10a2":
        q = np.round(picture[..., :3].astype(np.float64) * 1023 / 255).astype(np.uint32)
        return q[..., 0] | q[..., 1] << 10 | q[..., 2] << 20 | np.uint32(3) << 30
    if fmt == "rgba16f":
        values = picture.astype(np.float32) / 255 * np.float32(gain)
        values[..., 3] = 1.0
        return values.astype(np.float16)
    return picture


def light_or_codes(raw: np.ndarray, fmt: str) -> np.ndarray:
    """A stored view's RGB: code values in [0, 1] (sRGB formats) or linear light (the others)."""
    if fmt == "rgb10a2":
        raw = raw.astype(np.uint32)
        return np.stack([(raw >> s) & 1023 for s in (0, 10, 20)], axis=-1) / 1023.0
    if fmt == "rgba16f":
        return raw[..., :3].astype(np.float64)
    return raw[..., :3] / 255.0


def corrector_input(raw: np.ndarray, fmt: str) -> tuple[str, np.ndarray]:
    """What the Corrector is given for a stored picture: its sRGB code values as RGBA8 (8-bit
    formats; an 8-bit linear value is encoded to them) or linear light clamped to [0, 1] (float)."""
    from vrcorrect.specs.display import linear_to_srgb

    rgb = light_or_codes(raw, fmt)
    if ENCODING[fmt] == "srgb":
        return "codes", raw
    if ENCODING[fmt] == "linear8":
        codes = np.round(linear_to_srgb(rgb) * 255).astype(np.uint8)
        return "codes", np.concatenate([codes, np.full(codes.shape[:2] + (1,), 255, np.uint8)], axis=-1)
    light = np.clip(rgb, 0, 1).astype(np.float32)
    return "linear", np.concatenate([light, np.ones(light.shape[:2] + (1,), np.float32)], axis=-1)


def _input_texture(gl, kind: str, image: np.ndarray):
    """A Corrector's input texture: sRGB codes (``"codes"``) or linear light (``"linear"``, top row first)."""
    from vrcorrect.runtime.gl import upload_texture

    if kind == "codes":
        return upload_texture(gl, np.ascontiguousarray(image))
    h, w = image.shape[:2]
    return gl.texture((w, h), 4, np.ascontiguousarray(image[::-1]).tobytes(), dtype="f4")


def corrector_codes(gl, kit: Kit, eye: str, inputs: list[tuple[str, np.ndarray]]) -> list[np.ndarray]:
    """``Corrector.apply`` of a fresh Corrector on each input in turn (the n-th corrected frame is the
    n-th apply: the default filter continues its iterations from frame to frame): sRGB codes, int
    (H, W, 3), top row first."""
    from vrcorrect.runtime.corrector import Corrector
    from vrcorrect.runtime.gl import read_framebuffer, release, render_target

    corrector = Corrector(gl, kit.rx, "quest2", eye, eye_model=eye_model(kit, eye))
    results = []
    try:
        for kind, image in inputs:
            h, w = image.shape[:2]
            tex = _input_texture(gl, kind, image)
            target, fb = render_target(gl, width=w, height=h)
            try:
                corrector.apply(tex, fb)
                results.append(read_framebuffer(fb, components=3).astype(int))
            finally:
                release(fb, target, tex)
    finally:
        corrector.release()
    return results


_CONVERGED: dict[tuple[str, str, bytes], np.ndarray] = {}


def converged_codes(gl, kit: Kit, eye: str, kind_image: tuple[str, np.ndarray], limit: int = 60) -> np.ndarray:
    """What a fresh Corrector shows of a still picture once converged: ``Corrector.apply`` on it
    frame after frame until its early stop's criterion holds (the last two frames' objectives agree
    to ``EARLY_STOP_TOLERANCE``), then once more (a frame the early stop skips): sRGB codes, int
    (H, W, 3), top row first.  The layer corrects a still view from its first corrected frame on as
    this: it primes its correction on the application's frame off the application's thread."""
    from vrcorrect.runtime.corrector import Corrector
    from vrcorrect.runtime.gl import read_framebuffer, release, render_target
    from vrcorrect.runtime.strategies.admm import EARLY_STOP_TOLERANCE

    kind, image = kind_image
    key = (eye, kind, image.tobytes() + str(image.shape).encode())
    if key in _CONVERGED:
        return _CONVERGED[key]
    corrector = Corrector(gl, kit.rx, "quest2", eye, eye_model=eye_model(kit, eye))
    h, w = image.shape[:2]
    tex = _input_texture(gl, kind, image)
    target, fb = render_target(gl, width=w, height=h)
    try:
        previous = None
        for _ in range(limit):
            corrector.apply(tex, fb)
            fraction = corrector.last_objective_fraction((w, h))
            if previous is not None and abs(fraction - previous) <= EARLY_STOP_TOLERANCE * max(previous, 1e-30):
                break
            previous = fraction
        else:
            raise AssertionError(f"the {eye} eye's correction did not converge in {limit} frames")
        corrector.apply(tex, fb)
        _CONVERGED[key] = read_framebuffer(fb, components=3).astype(int)
    finally:
        release(fb, target, tex)
        corrector.release()
    return _CONVERGED[key]


def primed_codes(gl, kit: Kit, eye: str, kind_image: tuple[str, np.ndarray], primed: int, count: int) -> list[np.ndarray]:
    """What a fresh Corrector shows of a still picture on each of ``count`` frames after ``primed``
    frames of it (the layer primes that many off the application's thread, within its budget, then
    corrects each of the application's frames): :func:`corrector_codes` of ``primed + count`` copies,
    the last ``count``."""
    return corrector_codes(gl, kit, eye, [kind_image] * (primed + count))[primed:]


def primed_frames(log: list[str]) -> dict[str, int]:
    """Each eye's priming frames, from the layer log's "correcting with" line."""
    import re

    line = next(line for line in log if "correcting with" in line and "primed on the application's frame" in line)
    found = dict((eye, int(n)) for eye, n in re.findall(r"(left|right) (\d+)", line.split("primed on the application's frame")[1]))
    assert set(found) == set(EYES), line
    return found


def assert_corrected(got: np.ndarray, source: np.ndarray, fmt: str, codes: np.ndarray, where: object = "") -> None:
    """``got`` (a view as the runtime stored it) holds the Corrector's code values ``codes`` in ``fmt``'s
    encoding, within 2/255 of them: each value lies between the encodings of ``codes - 2`` and
    ``codes + 2`` (and the value's own rounding); for a float format, after the part of the source
    (``source``, as stored) outside [0, 1] is taken off again, which must have been carried through."""
    from vrcorrect.specs.display import srgb_to_linear

    assert got.shape[:2] == codes.shape[:2], (where, got.shape, codes.shape)
    lo, hi = np.clip(codes - 2, 0, 255) / 255.0, np.clip(codes + 2, 0, 255) / 255.0
    value = light_or_codes(got, fmt)
    encoding = ENCODING[fmt]
    if encoding == "srgb":
        step = 0.0
    else:
        lo, hi = srgb_to_linear(lo), srgb_to_linear(hi)
        step = {"linear8": 0.5 / 255, "linear10": 0.5 / 1023, "float": 0.0}[encoding]
    if encoding == "float":
        light = light_or_codes(source, fmt)
        value = value - (light - np.clip(light, 0, 1))          # the carried part, taken off
        step = 2.0 ** -10 * np.maximum(np.abs(light), 1.0)       # float16 rounding of the sum
    outside = (value < lo - step - 1e-9) | (value > hi + step + 1e-9)
    assert not outside.any(), (where, fmt, int(outside.sum()), float(np.abs(value - np.clip(value, lo, hi)).max()))


# --------------------------------------------------------------------------
# An X server for hello_xr's OpenGL window
# --------------------------------------------------------------------------

XORG_DUMMY_CONF = ROOT / "tests" / "xr_runtime" / "xorg-dummy.conf"


@pytest.fixture(scope="session")
def xorg_display(tmp_path_factory) -> Iterator[str]:
    """A private Xorg server with the dummy driver (Debian xserver-xorg-core, xserver-xorg-video-dummy;
    tools/setup.sh installs them); ``-displayfd`` picks a free display number.  Stopped at the end."""
    from conftest import _read_display_number, stop_process

    xorg = shutil.which("Xorg")
    if xorg is None:
        pytest.fail("Xorg not found: install xserver-xorg-core and xserver-xorg-video-dummy (tools/setup.sh does)")
    folder = tmp_path_factory.mktemp("xorg")
    read_fd, write_fd = os.pipe()
    log = folder / "Xorg.log"
    with open(folder / "stderr.txt", "w") as err:
        proc = subprocess.Popen([xorg, "-config", str(XORG_DUMMY_CONF), "-logfile", str(log), "-nolisten", "tcp",
                                 "-noreset", "-displayfd", str(write_fd)], pass_fds=(write_fd,),
                                stdout=subprocess.DEVNULL, stderr=err, stdin=subprocess.DEVNULL)
    os.close(write_fd)
    try:
        number = _read_display_number(read_fd, proc)          # conftest's, for Xvfb: the same protocol
        if number is None:
            proc.kill()
            proc.wait()
            detail = (folder / "stderr.txt").read_text()[-1500:]
            pytest.fail(f"Xorg with the dummy driver did not start (it runs as root here, as in CI):\n{detail}")
        yield f":{number}"
    finally:
        os.close(read_fd)
        stop_process(proc)
