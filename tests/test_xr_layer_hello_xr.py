"""Khronos's sample OpenXR application ``hello_xr`` (Debian's binary, package ``libopenxr-utils``; it
knows nothing of vrcorrect or of these tests) unmodified on the project's test runtime, with and
without the vrcorrect layer installed as a user installs it (``vrcorrect layer install --rx``, an
implicit layer in a temporary ``XDG_DATA_HOME``), in both its OpenGL and its Vulkan sessions
(``-g OpenGL``: GL_RGBA16F swapchains, the first format of the runtime's Monado-like list it can
use; ``-g Vulkan``: XR_KHR_vulkan_enable, R8G8B8A8_SRGB), through Debian's OpenXR loader.  Its
OpenGL window needs XFree86-VidModeExtension, so it runs under Xorg with the dummy driver
(``xorg_display``); its standard input stays open (it quits at its end); the runtime asks it to
quit (``XRTEST_STOP_AFTER``, ``XRTEST_STOP_FILE``), paced at 20 ms a frame.

The runtime writes what each view received and, every frame, every swapchain's released image
(``XRTEST_DUMP_SWAPCHAINS``): hello_xr's own images.  Checked: without the layer frames arrive and
hello_xr exits cleanly; with the layer, frames pass through while the eye models build and then
each view arrives corrected, equal to ``Corrector.apply`` on hello_xr's image of that frame within
2/255, hello_xr's images are the same in every frame (never written), Khronos core validation
below the layer (and Vulkan validation in hello_xr's instance) reports no error, and the session
ends cleanly; with ``DISABLE_VRCORRECT_LAYER=1`` the loader leaves the layer out and frames arrive
as hello_xr drew them.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from xr_layer_kit import (EYES, Kit, assert_corrected, assert_life_cycle, assert_validation_clean,
                          assert_vulkan_validation_clean, corrector_input, env, frames, kit, layer_log,
                          primed_codes, primed_frames, received, run, runtime_log, submitted,
                          xorg_display)

__all__ = ["kit", "xorg_display"]          # fixtures
APIS = {"OpenGL": ("rgba16f", "0x881a"), "Vulkan": ("srgb", "0x2b")}     # what hello_xr chooses from the runtime's list


def _hello_xr() -> str:
    path = shutil.which("hello_xr")
    if path is None:
        pytest.fail("hello_xr not found: install Debian's libopenxr-utils (tools/setup.sh does)")
    return path


def _run(kit: Kit, out: Path, api: str, display: str, corrected: int = 0, **kw) -> subprocess.CompletedProcess:
    """hello_xr -g ``api`` to its end: the runtime asks it to quit after 8 frames, or (``corrected``)
    once the layer corrects and that many corrected frames arrived."""
    kw.setdefault("XRTEST_DUMP_SWAPCHAINS", "1")
    kw.setdefault("XRTEST_FRAME_MS", "20")
    if not corrected:
        kw.setdefault("XRTEST_STOP_AFTER", "8")
    environ = env(kit, out, app="vk", DISPLAY=display, vulkan_validation=api == "Vulkan", **kw)
    result = run([_hello_xr(), "-g", api], out, environ, corrected=corrected, stop_env="XRTEST_STOP_FILE", stdin=True)
    text = result.stdout + result.stderr
    assert result.returncode == 0, text[-3000:]
    if api == "Vulkan":
        assert_vulkan_validation_clean(text)
    return result


def _app_image(out: Path, frame: int, swapchain: int) -> np.ndarray:
    return np.load(out / f"frame_{frame:05d}_swapchain_{swapchain}.npy")


@pytest.fixture(scope="module")
def installed(kit, tmp_path_factory) -> Path:
    """A HOME where ``vrcorrect layer install --rx RX --pupil rx --robust off`` has run (the implicit layer
    and its configuration; the design of the prescription's pupil, as the reference Corrector's that the
    corrected views are compared with: ``xr_layer_kit.PINNED_OPTIONS``)."""
    from vrcorrect.apps import layer

    home = tmp_path_factory.mktemp("hello_xr_home")
    environ = {"HOME": str(home), "XDG_CONFIG_HOME": str(home / ".config"),
               "XDG_DATA_HOME": str(home / ".local" / "share"), "XDG_STATE_HOME": str(home / ".local" / "state")}
    parser = argparse.ArgumentParser()
    layer.add_parser(parser.add_subparsers())
    assert layer.cmd_install(parser.parse_args(["layer", "install", "--rx", str(kit.rx), "--pupil", "rx",
                                                          "--robust", "off"]), env=environ) == 0
    manifest = home / ".local" / "share" / "openxr" / "1" / "api_layers" / "implicit.d" / "vrcorrect_layer.json"
    doc = json.loads(manifest.read_text())
    assert doc["api_layer"]["disable_environment"] == "DISABLE_VRCORRECT_LAYER"
    assert Path(doc["api_layer"]["library_path"]).is_file()
    return home


@pytest.mark.parametrize("api", APIS)
def test_hello_xr_runs_unmodified_on_the_test_runtime_and_exits_cleanly(kit, xorg_display, tmp_path, api):
    out = tmp_path / api
    result = _run(kit, out, api, xorg_display, explicit=False, validation=True)
    assert_validation_clean(result.stdout)
    assert_life_cycle(out, swapchains=2)
    log = runtime_log(out)
    assert "actions attach 1" in log and len([line for line in log if line.startswith("actions suggest")]) == 5
    fmt, code = APIS[api]
    assert [line for line in log if line.startswith("create_swapchain")] == \
        [f"create_swapchain 0 format={code} 96x64", f"create_swapchain 1 format={code} 96x64"]
    views = submitted(out)
    received_frames = frames(out)
    assert len(received_frames) >= 5
    for frame in received_frames:
        assert views[frame] == [0, 1]
        for view in (0, 1):
            image = received(out, frame, view)
            assert np.array_equal(image, _app_image(out, frame, view))      # what hello_xr drew, as it drew it
            assert len(np.unique(image.reshape(-1, image.shape[-1]), axis=0)) > 3     # a scene, not a blank


@pytest.mark.parametrize("api", APIS)
def test_hello_xr_with_the_installed_layer_arrives_corrected_for_each_eye(kit, gl, xorg_display, installed, tmp_path,
                                                                          api):
    """The README's promise: ``vrcorrect layer install --rx``, then any OpenXR application."""
    out = tmp_path / api
    result = _run(kit, out, api, xorg_display, corrected=3, explicit=False, validation=True, home=installed, prime=None)
    assert_validation_clean(result.stdout)                      # core validation below the implicit layer
    assert_life_cycle(out, swapchains=4)
    fmt, code = APIS[api]
    log = runtime_log(out)
    assert len([line for line in log if line.startswith("create_swapchain") and f"format={code} 96x64" in line]) == 4
    views = submitted(out)
    received_frames = frames(out)
    first = next(i for i, f in enumerate(received_frames) if views[f] != views[received_frames[0]])
    apps = views[received_frames[0]]                           # hello_xr's two swapchains
    outputs = views[received_frames[first]]                    # the layer's
    assert len(set(apps + outputs)) == 4
    reference = {v: _app_image(out, received_frames[0], s) for v, s in enumerate(apps)}
    for frame in received_frames:
        for view, swapchain in enumerate(apps):                  # hello_xr's images, the same every frame
            assert np.array_equal(_app_image(out, frame, swapchain), reference[view]), (frame, view)
    for frame in received_frames[:first]:                        # passed through while the models built
        assert views[frame] == apps
        for view in (0, 1):
            assert np.array_equal(received(out, frame, view), reference[view])
    corrected = received_frames[first:first + 3]
    assert len(corrected) == 3 and all(views[f] == outputs for f in corrected)
    layer = layer_log(out)
    primed = primed_frames(layer)
    for view, eye in enumerate(EYES):
        # hello_xr's scene is still: the layer primed its correction on it off hello_xr's thread, for
        # its default budget (converged, or handed over and converging on hello_xr's frames), so each
        # corrected frame is a fresh Corrector's after as many frames
        expected = primed_codes(gl, kit, eye, corrector_input(reference[view], fmt), primed[eye], len(corrected))
        for frame, codes in zip(corrected, expected):
            got = received(out, frame, view)
            assert_corrected(got, reference[view], fmt, codes, (api, frame, eye))
        assert not np.array_equal(received(out, corrected[0], view), reference[view])
    assert any("correcting with" in line and str(kit.rx) in line for line in layer), layer
    assert not any("pass-through" in line for line in layer), layer


@pytest.mark.parametrize("api", APIS)
def test_disable_vrcorrect_layer_leaves_hello_xrs_frames_as_it_drew_them(kit, xorg_display, installed, tmp_path, api):
    out = tmp_path / api
    _run(kit, out, api, xorg_display, explicit=False, home=installed, DISABLE_VRCORRECT_LAYER="1")
    assert layer_log(out) == []                                  # the loader did not load it at all
    assert_life_cycle(out, swapchains=2)
    received_frames = frames(out)
    assert len(received_frames) >= 5
    for frame in received_frames:
        for view in (0, 1):
            assert np.array_equal(received(out, frame, view), _app_image(out, frame, view))


# the simulated eye tracker's path (XRTEST_GAZE_DEG): the corners of a rectangle, each held 3 frames
GAZE_CORNERS = ((-20.0, 15.0), (20.0, 15.0), (20.0, -15.0), (-20.0, -15.0))
GAZE_PATH = [GAZE_CORNERS[(i // 3) % 4] for i in range(4096)]    # the runtime takes at most 4096; the last holds
FOVEA_PX = 15                                       # the fovea's radius, px (the window adds its blend band)


def _gaze_pixel(point: tuple[float, float], view: int) -> tuple[float, float]:
    """Where the test runtime's gaze (degrees from the head's forward, x right, y up) crosses view
    ``view`` (the runtime's fields of view; its eyes look ahead): ``(x, y)`` px, rows top first."""
    from xr_layer_kit import VIEW

    left, right, up, down = (np.tan(a) for a in ((-0.80, 0.70, 0.75, -0.78), (-0.70, 0.80, 0.75, -0.78))[view])
    tx, ty = (np.tan(np.radians(a)) for a in point)
    return (tx - left) / (right - left) * VIEW[0], (up - ty) / (up - down) * VIEW[1]


def _codes(raw: np.ndarray, fmt: str) -> np.ndarray:
    """A stored view's RGB as sRGB code values 0..255 (float formats: their light in [0, 1], encoded)."""
    from vrcorrect.specs.display import linear_to_srgb
    from xr_layer_kit import ENCODING, light_or_codes

    rgb = light_or_codes(raw, fmt)
    return 255.0 * (rgb if ENCODING[fmt] == "srgb" else linear_to_srgb(np.clip(rgb, 0, 1)))


@pytest.mark.parametrize("api", APIS)
def test_hello_xr_gets_a_foveated_correction_that_follows_a_simulated_eye_tracker(kit, xorg_display, tmp_path, api):
    """``layer install --fovea DEG --periphery target``: the layer asks the runtime for the eye
    tracker (XR_EXT_eye_gaze_interaction), adds its own action set beside hello_xr's and its action
    set to hello_xr's syncs; every corrected frame is hello_xr's image, code for code, outside a window
    around that frame's gaze (the runtime's path, moving every 3 frames), and corrected inside it."""
    from vrcorrect.solvers.foveated import fovea_pixels
    from vrcorrect.specs.display import get_display

    ppd = get_display("quest2").pixels_per_degree
    half_side = fovea_pixels(FOVEA_PX / ppd, ppd)[0]         # the window: the radius and its blend band
    config = tmp_path / "layer.json"
    config.write_text(json.dumps({"rx": str(kit.rx), "display": "quest2",
                                  "options": {"fovea_deg": FOVEA_PX / ppd,
                                              "fovea_periphery": "target"}}))
    out = tmp_path / api
    fmt = APIS[api][0]
    gaze = ";".join(f"{x:g},{y:g}" for x, y in GAZE_PATH)
    _run(kit, out, api, xorg_display, corrected=12, validation=True, VRCORRECT_LAYER_CONFIG=str(config),
         XRTEST_GAZE_DEG=gaze)
    log = runtime_log(out)
    assert "actions attach 2" in log, log                      # hello_xr's set and the layer's
    layer = layer_log(out)
    assert any("asked the runtime for the eye tracker" in line for line in layer), layer
    assert any("following the eye tracker" in line for line in layer), layer
    views = submitted(out)
    received_frames = frames(out)
    apps = views[received_frames[0]]
    corrected = [f for f in received_frames if views[f] != apps]
    assert len(corrected) >= 12
    places = set()
    for frame in corrected:
        for view in (0, 1):
            got, drawn = (_codes(image, fmt) for image in (received(out, frame, view),
                                                           _app_image(out, frame, apps[view])))
            point = GAZE_PATH[min(frame, len(GAZE_PATH) - 1)]
            gx, gy = _gaze_pixel(point, view)
            inside = np.zeros(got.shape[:2], bool)
            y0, x0 = max(int(gy) - half_side - 1, 0), max(int(gx) - half_side - 1, 0)
            inside[y0:int(gy) + half_side + 2, x0:int(gx) + half_side + 2] = True
            changed = np.abs(got - drawn).max(axis=-1) > 2      # the layer's round trip: within 2/255 (kit)
            assert not changed[~inside].any(), (api, frame, view, np.argwhere(changed & ~inside)[:5])
            if changed.any():
                places.add((point, view))
    # the window was corrected at several of the path's corners, in both views
    assert len({p for p, _ in places}) >= 3 and {v for _, v in places} == {0, 1}, places
    assert_life_cycle(out, swapchains=4)
