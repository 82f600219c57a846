"""Shared fixtures: an X display for GLFW windows (a private Xvfb when none is set) and the
headless OpenGL context of the real-time tests; and the markers that sort the tests by what they
need (``pytest_collection_modifyitems``): ``gl``, ``x`` and ``xr`` from the fixtures a test asks for
or its module uses, ``torch`` and ``cvvdp`` from its module's imports, ``slow`` and ``serial`` (reads
a clock: run alone) by hand.
``bash tools/test.sh --fast`` runs what needs none of them.

These tests must run, not skip, wherever tools/setup.sh has run (it installs xvfb and Mesa):
a missing piece fails with what to install.
"""

from __future__ import annotations

import contextlib
import os
import re
import select
import shutil
import subprocess
import tempfile
import time
from typing import Iterator

import pytest

XVFB_START_TIMEOUT_S = 30.0

FIXTURE_MARKS = {"gl": ("gl", "headless_gl"), "x": ("x_display", "xorg_display"),
                 "xr": ("xr_runtime", "kit", "installed")}
"""Markers a test gets from the fixtures it asks for (directly or through other fixtures)."""
MODULE_MARKS = {
    "torch": re.compile(r"^\s*(import torch|from torch\b)|vrcorrect\.learn|vrcorrect\.solvers\.(iterative|paper)",
                        re.M),
    "cvvdp": re.compile(r"cvvdp|pyfvvdp|\bjod\b|_jod\(|video_jod|foveated_jod|with_jod=True"),
    "gl": re.compile(r"headless_context|\bmoderngl\b|\bglfw\b|\bgl\.finish\b|main\(\[\s*\"(render|mirror|overlay|bench)\""),
    "x": re.compile(r"\bXvfb\b|DISPLAY"),
    "xr": re.compile(r"xr_layer_kit|^\s*import xr\b|XR_RUNTIME_JSON|hello_xr", re.M),
}
"""Markers every test of a module gets when the module's text matches (what its tests run inside
functions that the fixtures do not show: a command that opens a context, a metric)."""
SLOW_MODULES = ("test_cli_correct.py", "test_first_hour.py", "test_cli_signals.py", "test_fail_before_work.py",
                "test_bench_robust.py", "test_bench_halfres.py", "test_bench_realtime.py", "test_clips.py",
                "test_default_model.py", "test_solvers.py", "test_evaluate.py")
"""Modules whose tests each take seconds (commands end to end, solvers to convergence): ``slow``."""
SLOW_TESTS = ("test_unusual_but_valid_images_are_corrected", "test_closing_a_bank_stops_the_design",
              "test_every_accepted_prescription_is_modelled_on_every_display_preset")
"""Tests (name prefixes) that take seconds each in modules of quick ones: ``slow``."""
SERIAL_MODULES = ("test_runtime_budget.py", "test_cli_signals.py", "test_xr_layer_wheel.py", "test_xr_runtime_gaze.py")
SERIAL_TESTS = ("test_a_long_gl_call_lets_other_python_threads_run", "test_progress_says_it_is_still_working",
                "test_a_stall_trace_writes")
"""Tests whose assertions read a clock (a frame budget held, a signal sent at a fraction of a timed
run, a launch within seconds, a thread's ticks): ``serial``. ``tools/test.sh`` runs them alone, after
the rest has run in parallel, so that a neighbour's load does not move their times. Also the test
runtime's own tests (``test_xr_runtime_gaze.py``), which load the OpenXR loader and the runtime into
the test process itself: a parallel worker that had run other files first crashed in them once."""


def pytest_collection_modifyitems(config, items):
    texts: dict[str, str] = {}
    for item in items:
        path = str(item.path)
        if path not in texts:
            try:
                texts[path] = item.path.read_text(encoding="utf-8")
            except OSError:
                texts[path] = ""
        names = set(getattr(item, "fixturenames", ()))
        for mark, fixtures in FIXTURE_MARKS.items():
            if names.intersection(fixtures):
                item.add_marker(mark)
        for mark, pattern in MODULE_MARKS.items():
            if pattern.search(texts[path]):
                item.add_marker(mark)
        if item.path.name in SLOW_MODULES or item.name.startswith(SLOW_TESTS):
            item.add_marker("slow")
        if item.path.name in SERIAL_MODULES or item.name.startswith(SERIAL_TESTS):
            item.add_marker("serial")


@pytest.fixture(scope="session", autouse=True)
def private_cache(tmp_path_factory) -> Iterator[None]:
    """vrcorrect's cache folder (``VRCORRECT_CACHE_DIR``: compiled programs, eye models, the pupil bank's
    designs, which the windowed apps keep between runs) in the session's temporary folder, never the
    user's ``~/.cache``.  The OpenXR layer's tests give each run its own ``HOME`` as well."""
    old = os.environ.get("VRCORRECT_CACHE_DIR")
    os.environ["VRCORRECT_CACHE_DIR"] = str(tmp_path_factory.mktemp("vrcorrect_cache"))
    yield
    if old is None:
        os.environ.pop("VRCORRECT_CACHE_DIR", None)
    else:
        os.environ["VRCORRECT_CACHE_DIR"] = old


_CACHES = iter(range(1 << 62))


@pytest.fixture(autouse=True)
def private_cache_per_test(private_cache, tmp_path_factory, monkeypatch) -> None:
    """Each test its own cache folder (made when something is kept): what one test's window designed
    is never another's start (a test that counts the designs at start would see none).  Fixtures
    wider than a test (a module's shared mirror) start before this and keep the session's."""
    monkeypatch.setenv("VRCORRECT_CACHE_DIR", str(tmp_path_factory.getbasetemp() / f"vrcorrect_cache_{next(_CACHES)}"))


@pytest.fixture(scope="session")
def x_display() -> Iterator[str]:
    """An X display name for the session (``DISPLAY`` is set to it while the session runs).

    With ``DISPLAY`` already set, that display is used as it is. Otherwise this starts
    ``Xvfb`` itself (no ``xvfb-run``): ``-displayfd`` makes Xvfb choose a free display number
    (it skips numbers whose lock file exists, so parallel sessions and workers do not clash)
    and report it once the server accepts connections. The server is stopped at the end.
    """
    existing = os.environ.get("DISPLAY")
    if existing:
        yield existing
        return
    xvfb = shutil.which("Xvfb")
    if xvfb is None:
        pytest.fail("Xvfb not found: install the Debian package xvfb (tools/setup.sh does)")
    read_fd, write_fd = os.pipe()
    log = tempfile.TemporaryFile()
    proc = subprocess.Popen(
        [xvfb, "-displayfd", str(write_fd), "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
        pass_fds=(write_fd,), stdout=log, stderr=log, stdin=subprocess.DEVNULL,
    )
    os.close(write_fd)
    try:
        number = _read_display_number(read_fd, proc)
        if number is None:
            proc.kill()
            proc.wait()
            log.seek(0)
            pytest.fail(f"Xvfb did not start within {XVFB_START_TIMEOUT_S:.0f} s (exit status "
                        f"{proc.returncode}):\n{log.read().decode(errors='replace')[-2000:]}")
        display = f":{number}"
        with pytest.MonkeyPatch.context() as mp:
            mp.setenv("DISPLAY", display)
            yield display
    finally:
        os.close(read_fd)
        stop_process(proc)
        log.close()


def stop_process(proc: subprocess.Popen, timeout_s: float = 10.0) -> None:
    """End a server the tests started (Xvfb, Xorg): SIGTERM, then SIGKILL if it has not gone after
    ``timeout_s``."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _read_display_number(fd: int, proc: subprocess.Popen) -> int | None:
    """The display number Xvfb writes to ``-displayfd`` (a line), or None if it never comes."""
    deadline = time.monotonic() + XVFB_START_TIMEOUT_S
    data = b""
    while time.monotonic() < deadline:
        ready, _, _ = select.select([fd], [], [], 0.1)
        if ready:
            chunk = os.read(fd, 64)
            if not chunk:  # Xvfb exited (closed its end) without a number
                return None
            data += chunk
            if b"\n" in data:
                text = data.split(b"\n", 1)[0].strip()
                return int(text) if text.isdigit() else None
        elif proc.poll() is not None:
            return None
    return None


@pytest.fixture(scope="session")
def headless_gl():
    """The session's headless OpenGL context (EGL, Mesa llvmpipe in CI); released at the end."""
    from vrcorrect.runtime.gl import headless_context

    ctx = headless_context(require=430)          # compute shaders (a driver gives what is asked)
    yield ctx
    ctx.release()


@pytest.fixture
def gl(headless_gl):
    """The headless context, made current for one test, with no GL error before or after it."""
    from vrcorrect.runtime.gl import check_gl_errors

    with headless_gl:  # current again even if a window test made its own context current
        check_gl_errors(headless_gl, "before the test")
        yield headless_gl
        check_gl_errors(headless_gl, "after the test")


GL_FACTORIES = ("texture", "texture_array", "texture3d", "texture_cube", "depth_texture", "buffer", "program",
                "compute_shader", "framebuffer", "simple_framebuffer", "renderbuffer", "vertex_array",
                "simple_vertex_array", "query", "sampler")
"""The context's methods that make GPU objects (what "allocates nothing per frame" counts)."""


@contextlib.contextmanager
def count_gl_objects(ctx):
    """Count the GPU objects made on ``ctx`` inside the block: yields a list that gets one factory
    name per object made."""
    made: list[str] = []
    originals = {name: getattr(ctx, name) for name in GL_FACTORIES if hasattr(ctx, name)}

    def counting(name, make):
        def factory(*args, **kwargs):
            made.append(name)
            return make(*args, **kwargs)
        return factory

    for name, make in originals.items():
        setattr(ctx, name, counting(name, make))
    try:
        yield made
    finally:
        for name in originals:
            delattr(ctx, name)
