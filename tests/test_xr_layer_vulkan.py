"""The OpenXR layer in Vulkan sessions (``layer/vrcorrect_vulkan.c``), between a separate OpenXR Vulkan
application in C that knows nothing of vrcorrect (``tests/xr_vk_app/xr_vk_app.c``, the Vulkan twin of
the GL test application) and the project's test runtime, on Mesa's lavapipe (a software Vulkan
device), through pyopenxr's real OpenXR loader; the layer's engine corrects on its own headless
EGL context (llvmpipe) from images whose memory it imports.  Equipment: ``tests/xr_layer_kit.py``.

The application writes a known picture per eye into its swapchain images with transfer commands
and checks after every ``xrEndFrame`` (``APP_CHECK``) that its images still hold exactly that;
the runtime writes what it received.  Checked, with Khronos core validation below the layer and
Khronos Vulkan validation in the application's instance reporting no error: frames pass through
unchanged while the eye models build, then each view arrives corrected like ``Corrector.apply``
within 2/255, for XR_KHR_vulkan_enable2 (the layer adds its device extensions to
``xrCreateVulkanDeviceKHR``'s create info) and XR_KHR_vulkan_enable (it adds them to the lists the
application asks for), in every Vulkan format it corrects (R8G8B8A8 and B8G8R8A8, sRGB and UNORM,
A2B10G10R10, R16G16B16A16_SFLOAT with values above 1 carried through), over a sub-rect of each
half of one double-width swapchain; an unsupported format, a device made without the extensions
and the runtime stopping or losing the session while the models build each end cleanly, with one
log line naming the reason where frames pass through.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
from xr_layer_kit import (EYES, VIEW, Kit, assert_corrected, assert_life_cycle, assert_validation_clean,
                          assert_vulkan_validation_clean, converged_codes, corrector_input, env, frames, kit, layer_log,
                          pictures, reasons, received, run, runtime_log, stored)

__all__ = ["kit"]          # the session's equipment (a fixture)
VK_CODES = {"srgb": "0x2b", "rgba8": "0x25", "bgra8srgb": "0x32", "bgra8": "0x2c", "rgb10a2": "0x40",
            "rgba16f": "0x61", "rgba16": "0x5b"}


def _run(kit: Kit, out: Path, corrected: int = 0, **kw) -> subprocess.CompletedProcess:
    """Run the Vulkan application to the end, with Vulkan validation in its instance and core
    validation below the layer (20 ms a frame with ``APP_STOP_FILE`` when ``corrected``)."""
    kw.setdefault("validation", True)
    result = run([str(kit.vk_app)], out, env(kit, out, app="vk", vulkan_validation=True, **kw), corrected=corrected)
    text = result.stdout + result.stderr
    assert result.returncode == 0, text[-3000:]
    assert "done" in result.stdout
    assert_vulkan_validation_clean(text)
    if kw["validation"]:
        assert_validation_clean(result.stdout)
    return result


def _sources(fmts: tuple[str, str], gain: float = 1.0, rect: tuple[int, int, int, int] | None = None) -> dict:
    """What each eye's swapchain holds (the application's picture in its format), or the rect of it
    (x, y from the top left)."""
    out = {}
    for eye, fmt in zip(EYES, fmts):
        image = stored(pictures()[eye], fmt, gain)
        if rect is not None:
            x, y, w, h = rect
            image = image[y:y + h, x:x + w]
        out[eye] = image
    return out


def _assert_corrected_from(out: Path, gl, kit: Kit, fmts: tuple[str, str], sources: dict, count: int) -> list[int]:
    """Every frame passes through until the first corrected one; then ``count`` frames arrive
    corrected like Corrector.apply on each eye's still image, converged (the layer primes its
    correction on the application's frame, off its thread).  Returns the corrected frames."""
    received_frames = frames(out)
    first = next((i for i, f in enumerate(received_frames)
                  if not np.array_equal(received(out, f, 0), sources["left"])), None)
    assert first is not None, "no corrected frame"
    for f in received_frames[:first]:
        for view, eye in enumerate(EYES):
            assert np.array_equal(received(out, f, view), sources[eye]), (f, eye)
    corrected = received_frames[first:first + count]
    assert len(corrected) == count, (len(received_frames), first)
    for view, (eye, fmt) in enumerate(zip(EYES, fmts)):
        expected = converged_codes(gl, kit, eye, corrector_input(sources[eye], fmt))    # primed: converged at once
        for frame in corrected:
            got = received(out, frame, view)
            assert got.shape == sources[eye].shape, (got.shape, sources[eye].shape)
            assert_corrected(got, sources[eye], fmt, expected, (frame, eye, fmt))
    return corrected


@pytest.fixture(scope="module")
def corrected_run(kit, tmp_path_factory):
    out = tmp_path_factory.mktemp("vk_corrected")
    result = _run(kit, out, corrected=3, VRCORRECT_RX=str(kit.rx), APP_FRAMES="3", APP_CHECK="1")
    return result, out


def test_each_eye_arrives_corrected_like_the_corrector_with_both_validations_clean(corrected_run, kit, gl):
    result, out = corrected_run
    corrected = _assert_corrected_from(out, gl, kit, ("srgb", "srgb"), _sources(("srgb", "srgb")), 3)
    pics = pictures()
    for view, eye in enumerate(EYES):
        got = received(out, corrected[0], view)[..., :3].astype(int)
        assert np.abs(got - pics[eye][..., :3]).mean() > 3                     # not the picture itself
    assert "images checked unchanged after every frame" in result.stdout    # the application's own images
    assert "instance XR_KHR_vulkan_enable2" in result.stdout


def test_the_life_cycle_completes_and_the_log_names_the_vulkan_costs(corrected_run):
    _, out = corrected_run
    assert_life_cycle(out, swapchains=4)               # two of the application's, two outputs of the layer's
    log = runtime_log(out)
    assert "create_session vulkan" in log
    assert [line for line in log if line.startswith("create_vulkan_device")] == ["create_vulkan_device 0 extensions=2"]
    layer = layer_log(out)
    assert layer[0].split(" ", 1)[1].startswith("loaded (Vulkan session"), layer
    assert len([line for line in layer if "shared with the engine's GL" in line]) == 2, layer
    assert len([line for line in layer if "building the eye models" in line]) == 1, layer
    timing = [line for line in layer if "per eye" in line]
    assert timing and all("Vulkan copy in and wait" in line and "glFinish" in line and "copy out" in line
                          for line in timing), layer
    from vrcorrect.studies.bench.layer import _LINE                 # what `vrcorrect bench layer` reads from it
    assert all((m := _LINE.search(line)) and m.group(7) is not None for line in timing), timing
    assert not any("pass-through" in line for line in layer), layer
    # how the copies are ordered with the GL work: external semaphores need VK_KHR_external_semaphore_fd on the
    # device and GL_EXT_semaphore_fd in the engine's GL; lavapipe and llvmpipe (Mesa 22.3) offer neither, so the
    # fence and glFinish run here, and the log says which one is missing
    sync = [line for line in layer if "Vulkan copies synchronised by" in line]
    assert len(sync) == 1, layer
    assert "external semaphores" in sync[0] or ("a fence and glFinish (" in sync[0] and (
        "VK_KHR_external_semaphore_fd" in sync[0] or "GL_EXT_semaphore_fd" in sync[0])), sync


@pytest.mark.parametrize("fmts, enable", [
    (("bgra8srgb", "rgba8"), "XR_KHR_vulkan_enable"),
    (("bgra8", "rgb10a2"), "XR_KHR_vulkan_enable2"),
    (("rgba16f", "srgb"), "XR_KHR_vulkan_enable2"),
], ids=["B8G8R8A8_SRGB+R8G8B8A8_UNORM", "B8G8R8A8_UNORM+A2B10G10R10", "R16G16B16A16_SFLOAT+R8G8B8A8_SRGB"])
def test_every_vulkan_format_arrives_corrected_in_its_own_encoding(kit, gl, tmp_path, fmts, enable):
    """One swapchain per eye, each in its own format; the half-float one holds the picture times 2:
    the correction works on the part in [0, 1] and the rest is carried through."""
    out = tmp_path / "_".join(fmts)
    extra = {"APP_ENABLE": "1"} if enable == "XR_KHR_vulkan_enable" else {}
    result = _run(kit, out, corrected=1, VRCORRECT_RX=str(kit.rx), APP_FRAMES="1", APP_FORMAT=",".join(fmts),
                  APP_GAIN="2", APP_CHECK="1", **extra)
    assert f"instance {enable}" in result.stdout
    if enable == "XR_KHR_vulkan_enable":            # the layer's names in the runtime's (empty) lists
        assert "runtime device extensions: VK_KHR_external_memory VK_KHR_external_memory_fd" in result.stdout
    for i, fmt in enumerate(fmts):
        assert f"create_swapchain {2 * i} format={VK_CODES[fmt]} 96x64" in runtime_log(out)
    sources = _sources(fmts, gain=2.0)
    corrected = _assert_corrected_from(out, gl, kit, fmts, sources, 1)
    if "rgba16f" in fmts:
        view = fmts.index("rgba16f")
        assert received(out, corrected[0], view)[..., :3].astype(np.float32).max() > 1.9     # what exceeds 1 arrives
        assert any("VK_FORMAT_R16G16B16A16_SFLOAT swapchain" in line and "carried through" in line
                   for line in layer_log(out))
    assert_life_cycle(out, swapchains=4)


def test_a_sub_rect_of_each_half_of_one_double_width_swapchain_is_corrected(kit, gl, tmp_path):
    """Both eyes in one swapchain twice as wide, each view a sub-rect of its half (Vulkan pixels from
    the top left): one output swapchain, acquired once per frame; each rect corrected for its eye,
    the rest of the output image is not submitted."""
    rect = (8, 4, 64, 48)
    out = tmp_path / "side_by_side_rect"
    _run(kit, out, corrected=1, VRCORRECT_RX=str(kit.rx), APP_FRAMES="1", APP_SIDE_BY_SIDE="1",
         APP_RECT=",".join(map(str, rect)), APP_CHECK="1")
    log = runtime_log(out)
    assert f"create_swapchain 0 format=0x2b {2 * VIEW[0]}x{VIEW[1]}" in log
    ends = [line for line in log if line.startswith("end_frame") and "views=1:" in line]
    assert ends and all(line.endswith(f"views=1:8,4,64x48 1:{VIEW[0] + 8},4,64x48") for line in ends), ends[:2]
    _assert_corrected_from(out, gl, kit, ("srgb", "srgb"), _sources(("srgb", "srgb"), rect=rect), 1)
    assert_life_cycle(out, swapchains=2)


def _assert_passed_through(out: Path, sources: dict) -> None:
    received_frames = frames(out)
    assert received_frames
    for frame in received_frames:
        for view, eye in enumerate(EYES):
            assert np.array_equal(received(out, frame, view), sources[eye]), (frame, eye)


def test_an_unsupported_format_passes_through_with_one_log_line(kit, tmp_path):
    out = tmp_path / "rgba16"
    _run(kit, out, APP_FRAMES="3", APP_FORMAT="rgba16", XRTEST_FORMATS="rgba16,srgb", VRCORRECT_RX=str(kit.rx))
    _assert_passed_through(out, {eye: p.astype(np.uint16) * 257 for eye, p in pictures().items()})
    assert_life_cycle(out, swapchains=2)              # no output swapchains
    found = reasons(out)
    assert len(found) == 1 and "0x5B is not supported" in found[0] and "R8G8B8A8_SRGB" in found[0], found


def test_a_device_made_without_the_layers_extensions_passes_through_with_one_log_line(kit, tmp_path):
    """XR_KHR_vulkan_enable: the application lists the runtime's device extensions (to which the layer
    added its own) but makes its device without them, so the layer cannot share images with its
    GL engine: the session passes through."""
    out = tmp_path / "no_external_memory"
    result = _run(kit, out, APP_FRAMES="3", APP_ENABLE="1", APP_IGNORE_EXTENSIONS="1", APP_CHECK="1",
                  VRCORRECT_RX=str(kit.rx))
    assert "VK_KHR_external_memory_fd (ignored)" in result.stdout
    _assert_passed_through(out, _sources(("srgb", "srgb")))
    assert_life_cycle(out, swapchains=2)
    found = reasons(out)
    assert len(found) == 1 and "without VK_KHR_external_memory_fd" in found[0], found


@pytest.mark.parametrize("end", ["XRTEST_STOP_AFTER", "XRTEST_LOSS_AFTER"], ids=["runtime stops", "session lost"])
def test_the_runtime_ending_the_session_while_the_models_build_tears_the_layer_down_cleanly(kit, tmp_path, end):
    out = tmp_path / end.lower()
    _run(kit, out, APP_FRAMES="50", VRCORRECT_RX=str(kit.rx), **{end: "5"})
    log = runtime_log(out)
    states = [line.split()[1] for line in log if line.startswith("state ")]
    assert ("LOSS_PENDING" in states) == (end == "XRTEST_LOSS_AFTER") and states[-1] in ("EXITING", "LOSS_PENDING")
    assert len([line for line in log if line.startswith("create_swapchain")]) == 4
    assert len([line for line in log if line.startswith("destroy_swapchain")]) == 4
    assert log[-2:] == ["destroy_session", "destroy_instance"]
    assert not any("still alive" in line for line in log)
    layer = layer_log(out)
    assert not any("correcting with" in line for line in layer), layer        # it ended during the build
    assert not any("Traceback" in line or "error" in line.lower() for line in layer), layer
