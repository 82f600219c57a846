"""``vrcorrect bench xr``: milliseconds per stage of the headset loop (``vrcorrect xr``).

Runs :class:`~vrcorrect.runtime.shell.xr.XrApp` against the test OpenXR runtime of the repository
(``tests/xr_runtime/xr_test_runtime.c``, compiled here with the machine's C compiler and loaded
by pyopenxr's OpenXR loader through ``XR_RUNTIME_JSON``), on an X display (``DISPLAY``, or a
private Xvfb started here): the GL context is a GLFW/GLX one, Mesa llvmpipe under Xvfb. The
test runtime neither paces ``xrWaitFrame`` to a display nor reads the images back here (no
``XRTEST_OUT_DIR``), so ``wait`` and ``end`` are the loop's own overhead, not a compositor's.

Each case renders the demo scene from the runtime's two eye poses, corrects both eyes into the
sRGB swapchain images (the default ``Corrector``: ADMM, 2 iterations a frame, warm-started from
the tracked pose) and submits a projection
layer; the first rendered frame (per-size spectra and allocations) is left out of the medians.
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from ...plumbing.errors import InputError, ValidationError, VrcorrectError
from ...runtime.shell.xr import XR_CPU_ONLY_STAGES as CPU_ONLY_STAGES
from ...runtime.shell.xr import XR_STAGES, XrApp, XrConfig
from . import machine_description, markdown_table, write_section

EYE_SIZES = ((1832, 1920), (512, 512))          # a Quest 2 eye, and a small one for the loop's overhead
RUNTIME_SOURCE = Path(__file__).resolve().parents[3] / "tests" / "xr_runtime" / "xr_test_runtime.c"


def build_test_runtime(folder: Path) -> Path:
    """Compile the test runtime into ``folder``; returns its manifest (an ``XR_RUNTIME_JSON`` value)."""
    if not RUNTIME_SOURCE.exists():
        raise InputError(f"{RUNTIME_SOURCE}: not found; vrcorrect bench xr runs from a checkout of the repository "
                         "(it compiles the test OpenXR runtime in tests/xr_runtime/)")
    cc = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc")
    if cc is None:
        raise InputError("no C compiler (cc or gcc) to build the test OpenXR runtime: apt-get install gcc libc6-dev")
    library = folder / "libvrcorrect_xr_test_runtime.so"
    result = subprocess.run([cc, "-std=c11", "-O2", "-shared", "-fPIC", "-fvisibility=hidden", "-o", str(library),
                             str(RUNTIME_SOURCE), "-ldl", "-lm"], capture_output=True, text=True)
    if result.returncode != 0:
        raise VrcorrectError(f"compiling the test OpenXR runtime failed:\n{result.stderr[-2000:]}")
    manifest = folder / "runtime.json"
    manifest.write_text(json.dumps({"file_format_version": "1.0.0", "runtime": {
        "name": "vrcorrect test runtime", "library_path": str(library)}}))
    return manifest


@contextmanager
def x_display() -> Iterator[str]:
    """``DISPLAY`` if set, else a private Xvfb for the duration."""
    if os.environ.get("DISPLAY"):
        yield os.environ["DISPLAY"]
        return
    xvfb = shutil.which("Xvfb")
    if xvfb is None:
        raise InputError("no X display: set DISPLAY or install Xvfb (apt-get install xvfb)")
    read_fd, write_fd = os.pipe()
    proc = subprocess.Popen([xvfb, "-displayfd", str(write_fd), "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
                            pass_fds=(write_fd,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write_fd)
    try:
        with os.fdopen(read_fd) as f:
            number = f.readline().strip()
        if not number.isdigit():
            raise InputError("Xvfb did not start")
        os.environ["DISPLAY"] = f":{number}"
        yield os.environ["DISPLAY"]
    finally:
        os.environ.pop("DISPLAY", None)
        proc.terminate()
        proc.wait(timeout=10)


@contextmanager
def _environment(**values: str) -> Iterator[None]:
    saved = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def run_xr_bench(repeats: int = 3, out: Path = Path("docs/benchmarks.md"), write: bool = True,
                 sizes=EYE_SIZES) -> str:
    """Measure each eye size; returns the Markdown (and writes the ``xr`` section of ``out``)."""
    if not (isinstance(repeats, int) and 1 <= repeats <= 1000):
        raise ValidationError("--repeats", repeats, "a whole number from 1 to 1000")
    columns, results = [], []
    renderer = runtime = ""
    with tempfile.TemporaryDirectory() as tmp, x_display():
        manifest = build_test_runtime(Path(tmp))
        for w, h in sizes:
            with _environment(XR_RUNTIME_JSON=str(manifest), XRTEST_VIEW_SIZE=f"{w}x{h}"):
                t0 = time.perf_counter()
                with XrApp(XrConfig(source="demo", frames=repeats + 1), echo=None) as app:
                    build_s = time.perf_counter() - t0
                    summary = app.run(handle_sigint=False)
            renderer, runtime = summary.renderer, summary.runtime
            columns.append(f"{w}x{h} per eye")
            results.append((summary, build_s))
    from ...runtime.eye_model import (
        CorrectorOptions,  # on use: start-up time (the CLI imports the studies to build its parser)
    )

    options = CorrectorOptions()
    rows = []
    for name in XR_STAGES:
        cells = []
        for summary, _ in results:
            med = summary.medians(skip=1).get(name)
            if med is None:
                cells.append("-")
            elif name in CPU_ONLY_STAGES:
                cells.append(f"{med[1]:.2f}")
            else:
                cells.append(f"{'-' if med[0] is None else f'{med[0]:.2f}'} / {med[1]:.2f}")
        if any(c != "-" for c in cells):
            rows.append([name, *cells])
    frame_cells = [f"**{statistics.median(s.frame_ms[1:] or s.frame_ms):.1f}**" for s, _ in results]
    rows.append(["**frame (wall, CPU)**", *frame_cells])
    rows.append(["set-up s (instance, window, session, correctors)", *[f"{b:.1f}" for _, b in results]])
    body = (
        "## Headset loop (`vrcorrect xr`) per stage, against the test runtime\n\n"
        f"Machine: {machine_description()}; OpenGL renderer: {renderer} (GLFW/GLX under Xvfb); "
        f"OpenXR runtime: {runtime} (tests/xr_runtime, loaded by pyopenxr's loader; it does not pace xrWaitFrame "
        "and reads nothing back here). Demo scene from each tracked eye, bundled sample prescription, Quest 2 "
        f"profile, sRGB swapchains, the Corrector's default correction ({options.filter}, "
        f"{options.iterations_per_frame} iterations a frame, warm-started; the "
        "prescription's pupil and one eye's design, not `vrcorrect xr`'s --pupil auto --robust on). Median of "
        f"{repeats} rendered "
        "frames after the first. Cells: `GPU ms / CPU ms` (GPU from timer queries) or CPU ms alone for the "
        "OpenXR calls; `-` for a GPU time of 4.29 s or more, which moderngl's 32-bit timer query cannot hold.\n\n"
        + markdown_table(["stage", *columns], rows)
        + "\n\nThe correction of the two eyes is the whole cost; the OpenXR calls (wait, begin, locate, acquire, "
        "release, end) and the scene are small beside it. On llvmpipe (2 CPU cores) a Quest 2 frame takes "
        "seconds; a headset needs the GPU figures (no GPU in this session: not measured yet).\n"
    )
    if write:
        write_section(out, "xr", body)
    return body
