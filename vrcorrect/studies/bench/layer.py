"""``vrcorrect bench layer``: what the OpenXR layer costs per frame, in OpenGL and in Vulkan sessions.

Runs the repository's two C test applications (``tests/xr_gl_app``: OpenGL under an X display,
``DISPLAY`` or a private Xvfb; ``tests/xr_vk_app``: Vulkan on the machine's Vulkan device) against
the test OpenXR runtime (``tests/xr_runtime``, through pyopenxr's loader), with the layer built as
``vrcorrect layer install`` builds it, the bundled sample prescription and sample image (both
eyes), sRGB swapchains.  The layer logs, once a second, each eye's GPU ms (timer queries) and CPU
ms (issuing the correction), its whole time in ``xrEndFrame`` and, for Vulkan, the three steps
the OpenGL path does not have: the copy of the submitted rects into the shared images with the
wait for the application's queue, ``glFinish``, and the copy of the result into the output image.
The table gives the median of those one-second means, the first one (the first frames: the
Correctors' allocations) left out.
"""

from __future__ import annotations

import os
import re
import shutil
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from ...plumbing.errors import InputError, ValidationError, VrcorrectError
from ...plumbing.fileio import package_data
from ...plumbing.imageio import read_image
from ...runtime.layer.build import build_layer, manifest_text
from . import machine_description, markdown_table, write_section
from .xr import build_test_runtime, x_display

TESTS = Path(__file__).resolve().parents[3] / "tests"
APPS = {"OpenGL": (TESTS / "xr_gl_app" / "xr_gl_app.c", ["-lGL", "-lX11"]),
        "Vulkan": (TESTS / "xr_vk_app" / "xr_vk_app.c", ["-lvulkan"])}
SIZES = ((96, 64), (256, 256))
_LINE = re.compile(r"per eye \(mean of (\d+) frames\): left GPU (\S+) ms, CPU ([\d.]+) ms; right GPU (\S+) ms, "
                   r"CPU ([\d.]+) ms; in xrEndFrame ([\d.]+) ms(?:; per frame, Vulkan copy in and wait ([\d.]+) ms, "
                   r"glFinish ([\d.]+) ms, copy out ([\d.]+) ms)?")
_FIRST = re.compile(r"first corrected frame: ([\d.]+) ms in xrEndFrame")
COLUMNS = ("left GPU", "left CPU", "right GPU", "right CPU", "xrEndFrame", "copy in + wait", "glFinish", "copy out",
           "first frame")


def _compile(api: str, folder: Path) -> Path:
    source, libs = APPS[api]
    if not source.exists():
        raise InputError(f"{source}: not found; vrcorrect bench layer runs from a checkout of the repository")
    cc = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc")
    if cc is None:
        raise InputError("no C compiler (cc or gcc) to build the test applications: apt-get install gcc libc6-dev")
    app = folder / source.stem
    result = subprocess.run([cc, "-std=c11", "-O2", "-o", str(app), str(source), "-ldl", *libs, "-lm"],
                            capture_output=True, text=True)
    if result.returncode != 0:
        raise VrcorrectError(f"compiling {source.name} failed:\n{result.stderr[-2000:]}")
    return app


def _picture(width: int, height: int, folder: Path) -> dict[str, Path]:
    """The sample image, cropped to the view's aspect and resized, as each application reads it
    (RGBA8; GL rows bottom first, Vulkan rows top first)."""
    from PIL import Image  # on use: Pillow (start-up time)

    rgb = np.round(read_image(package_data("sample.png")) * 255).astype(np.uint8)      # (H, W, 3) codes
    h, w = rgb.shape[:2]
    scale = min(w / width, h / height)
    cw, ch = int(width * scale), int(height * scale)
    crop = rgb[(h - ch) // 2:(h - ch) // 2 + ch, (w - cw) // 2:(w - cw) // 2 + cw]
    resized = np.asarray(Image.fromarray(crop).resize((width, height), Image.Resampling.LANCZOS))
    rgba = np.concatenate([resized, np.full((height, width, 1), 255, np.uint8)], axis=-1)
    paths = {"OpenGL": folder / "picture_gl.raw", "Vulkan": folder / "picture_vk.raw"}
    np.ascontiguousarray(rgba[::-1]).tofile(paths["OpenGL"])
    rgba.tofile(paths["Vulkan"])
    return paths


def _measure(api: str, app: Path, manifest: Path, layer_dir: Path, picture: Path, size: tuple[int, int],
             lines: int, folder: Path) -> list[tuple[float | None, ...]]:
    """Run ``app`` with the layer until ``lines`` + 1 timing lines were logged; their values (the first left out)."""
    import xr  # on use: pyopenxr (optional: the realtime extra)

    out = folder / f"{api}_{size[0]}x{size[1]}"
    out.mkdir()
    log, stop = out / "layer.log", out / "stop"
    env = {k: v for k, v in os.environ.items() if not k.startswith(("XR_", "XRTEST_", "APP_", "VRCORRECT_", "VK_"))}
    env.update(XR_RUNTIME_JSON=str(manifest), XRTEST_VIEW_SIZE=f"{size[0]}x{size[1]}", XR_API_LAYER_PATH=str(layer_dir),
               XR_ENABLE_API_LAYERS="XR_APILAYER_VRCORRECT_correction", VRCORRECT_LAYER_LOG=str(log),
               VRCORRECT_RX=str(package_data("sample_rx.json")), VRCORRECT_LAYER_CONFIG=str(out / "none.json"),
               APP_LOADER=str(Path(xr.__file__).parent / "library" / "linux_x86_64" / "libopenxr_loader.so"),
               APP_IMAGE_LEFT=str(picture), APP_IMAGE_RIGHT=str(picture), APP_STOP_FILE=str(stop), APP_FRAMES="1",
               MESA_SHADER_CACHE_DIR=str(out / "shader_cache"),      # empty: every run compiles, as a first launch
               VRCORRECT_CACHE_DIR=str(out / "vrcorrect_cache"))     # (the layer's programs and eye models too)

    def timing() -> list[re.Match[str]]:
        text = log.read_text() if log.exists() else ""
        return [m for m in map(_LINE.search, text.splitlines()) if m]

    with open(out / "stdout.txt", "w") as so:
        proc = subprocess.Popen([str(app)], stdout=so, stderr=subprocess.STDOUT, env=env)
        try:
            deadline = time.monotonic() + 600 + 120 * lines * size[0] * size[1] / 65536
            while len(timing()) < lines + 1:
                if proc.poll() is not None:
                    raise VrcorrectError(f"the {api} test application ended early:\n"
                                         + (out / "stdout.txt").read_text()[-2000:])
                if time.monotonic() > deadline:
                    raise VrcorrectError(f"the {api} run timed out; its log:\n" + (log.read_text()[-2000:]
                                                                                    if log.exists() else ""))
                time.sleep(0.2)
            stop.touch()
            proc.wait(timeout=300)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    first = [float(m.group(1)) for m in map(_FIRST.search, log.read_text().splitlines()) if m]
    values = []
    for m in timing()[1:lines + 1]:
        numbers = m.groups()[1:]
        values.append(tuple(float(v) if v not in (None, "-") and not v.startswith(">") else None for v in numbers)
                      + (first[0] if first else None,))
    return values


def _median(values: list[tuple[float | None, ...]], i: int) -> str:
    column = [v[i] for v in values if v[i] is not None]
    return f"{statistics.median(column):.2f}" if column else "-"


def run_layer_bench(repeats: int = 3, out: Path = Path("docs/benchmarks.md"), write: bool = True,
                    sizes=SIZES) -> str:
    """Measure both APIs at each view size; returns the Markdown (and writes the ``layer`` section of ``out``)."""
    if not (isinstance(repeats, int) and 1 <= repeats <= 100):
        raise ValidationError("--repeats", repeats, "a whole number from 1 to 100")
    rows = []
    with tempfile.TemporaryDirectory() as tmp, x_display():
        folder = Path(tmp)
        manifest = build_test_runtime(folder)
        layer_dir = folder / "layer"
        library = build_layer(layer_dir)
        (layer_dir / "vrcorrect_layer.json").write_text(manifest_text(library))
        apps = {api: _compile(api, folder) for api in APPS}
        for size in sizes:
            where = folder / f"{size[0]}x{size[1]}"
            where.mkdir()
            pictures = _picture(*size, where)
            for api, app in apps.items():
                values = _measure(api, app, manifest, layer_dir, pictures[api], size, repeats, folder)
                rows.append([f"{size[0]}x{size[1]}", api, *(_median(values, i) for i in range(len(COLUMNS)))])
    from ...runtime.eye_model import (
        CorrectorOptions,  # on use: start-up time (the CLI imports the studies to build its parser)
    )

    options = CorrectorOptions()
    steps = []
    for row in rows:
        if row[1] == "Vulkan" and "-" not in row[-5:-1]:
            own = sum(float(v) for v in row[-4:-1])
            steps.append(f"{own:.2f} ms at {row[0]}, {100 * own / float(row[-5]):.2f} % of the layer's time in "
                         "xrEndFrame")
    body = (
        "## The OpenXR layer per frame, OpenGL and Vulkan sessions (`vrcorrect bench layer`)\n\n"
        f"Machine: {machine_description()}; no GPU: OpenGL is Mesa llvmpipe and Vulkan is Mesa lavapipe, both "
        "software rendering on the CPU. The project's two test applications (tests/xr_gl_app under Xvfb, "
        "tests/xr_vk_app) against the test runtime (tests/xr_runtime, through pyopenxr's loader), with the layer "
        "and the bundled sample prescription and image (a still picture, both eyes), quest2 profile, sRGB swapchains, "
        f"the Corrector's default correction ({options.filter}, {options.iterations_per_frame} iterations a frame; "
        "once a still view has converged its early stop, on by default, skips the iterations, so a small view costs "
        "milliseconds: `vrcorrect bench realtime` measures moving content). Each cell is the median of "
        f"{repeats} one-second means the layer logs (the first left out), in ms: each eye's GPU time (timer "
        "queries) and CPU time (issuing its correction), the layer's whole time in xrEndFrame, and, for Vulkan, "
        "the steps the OpenGL path does not have: the copy of the submitted rects into the shared images with "
        "the wait for the application's queue (there is no GL_EXT_semaphore_fd on llvmpipe nor "
        "VK_KHR_external_semaphore_fd on lavapipe, so the layer waits on a fence and calls glFinish), glFinish, and the copy of the result into the output image (not waited "
        "for). `first frame`: the layer's time in the first corrected frame's xrEndFrame (one run). The layer "
        "builds its correction off the application's thread (a GL context of its own, its programs compiled or "
        "loaded from its cache, the design for the light's pupil made, and primed on the application's frame "
        "within its budget, 1 s for both eyes: on a GPU until converged, here a frame or two, so the "
        "application's first frames still cost full iterations until the early stop skips them). Each run starts "
        "with an empty Mesa shader cache (MESA_SHADER_CACHE_DIR) and an empty vrcorrect cache, as a first launch "
        "does. `-` where the figure does not exist.\n\n"
        + markdown_table(["view", "session", *COLUMNS], rows)
        + "\n\nThe Vulkan path's own steps (copy in and wait, glFinish, copy out) took "
        + ("; ".join(steps) or "-")
        + ". Both sessions run the same correction; the rest of the difference between their xrEndFrame times is "
        "the noise of a shared machine (about one frame a second at 256x256: each one-second mean is one frame). "
        "On a GPU (a projection from the bytes, not a measurement) each of the two copies reads and writes 4 bytes "
        "a pixel of an 8-bit swapchain (8 of a half-float one), 28 MB for a Quest 2 eye (1832x1920), some 0.1 ms "
        "at 300 GB/s; the fence wait would hold the layer until the application's rendering of the frame has "
        "finished on the queue, which external semaphores would avoid (not used: llvmpipe does not offer "
        "GL_EXT_semaphore_fd). No GPU figure: none was available.\n"
    )
    if write:
        write_section(out, "layer", body)
    return body
