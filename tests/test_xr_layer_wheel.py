"""The OpenXR layer as a Python user installs it: ``pip wheel .`` builds a wheel with the layer's shared
library inside (setuptools' extension building, ``setup.py``, with ``layer/build_flags.py``'s
``-Wall -Wextra -Werror``); installed into a fresh virtual environment whose ``PATH`` has no C
compiler, ``vrcorrect layer install --rx`` only writes the manifest and the configuration, and
Khronos's ``hello_xr`` (``-g Vulkan`` and ``-g OpenGL``, unmodified, on the test runtime, 96x64 views)
is corrected, each API in a fresh ``HOME`` (empty caches: vrcorrect's and Mesa's):

* after the first three frames no gap between frames reaching the runtime is longer than 0.5 s, or
  than twice the median corrected frame's gap on a renderer too slow for that (the runtime's
  ``frame_times.txt``; on a 2-core Intel Xeon a corrected frame of both eyes at 96x64 takes 0.41-0.49 s
  on llvmpipe, the first 0.69 s): the layer builds, compiles and primes its correction off
  ``hello_xr``'s thread, where a stall there took seconds (14 s before issue 46); each launch runs
  with the layer's stall trace (``VRCORRECT_LAYER_STALL_TRACE``), so that a failure shows every
  thread's stack in a frame that outlasted 0.5 s in the layer;
* the first launch is corrected within 60 s of its first frame;
* a second launch finds its eye models and every compiled program in the caches (vrcorrect's, under
  the fresh ``HOME``'s ``~/.cache``) and is corrected within 5 s of its first frame.

  Both times are the issue's bounds for a renderer whose corrected frame takes at most
  :data:`REFERENCE_PACE_S` (the 2-core AMD EPYC the bounds were set on: 0.24-0.30 s); on a slower
  one they scale with the corrected frames' median gap measured in the same launch (the 2-core Intel
  Xeon of 2026-12-02: 0.41-0.49 s, a second launch of 4.2-5.2 s).  Before it
  corrects, the layer primes the correction on ``hello_xr``'s frame for its default budget
  (``PRIME_BUDGET_S``, 1 s: on llvmpipe a still scene needs some 35 frames of both eyes at 96x64, 0.1-0.3 s
  each with the default design, so it hands over unconverged and converges on ``hello_xr``'s frames; the gap bound
  above holds for those frames too).

The fresh environment is ``python -m venv --without-pip`` with the wheel installed by pip (``--python``,
no index, no dependencies) and its dependencies reached through a ``.pth`` file naming this
interpreter's site-packages (no network, no second install of numpy or moderngl); the wheel is built
with ``--no-build-isolation`` from a copy of the sources (setuptools from this environment).  These
are behaviour bounds the issue sets (issue 46), not benchmarks.
"""

from __future__ import annotations

import ctypes
import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import numpy as np
import pytest
from xr_layer_kit import env, frames, kit, layer_log, received, run, runtime_log, submitted, xorg_display

__all__ = ["kit", "xorg_display"]          # fixtures
ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("pyproject.toml", "setup.py", "MANIFEST.in", "README.md", "layer", "shaders", "vrcorrect")
MAX_GAP_S = 0.5
FIRST_LAUNCH_S = 60.0
SECOND_LAUNCH_S = 5.0
REFERENCE_PACE_S = 0.3
"""The corrected frame's gap (both eyes at 96x64 on llvmpipe) the launch bounds above were set for."""


def _hello_xr() -> str:
    path = shutil.which("hello_xr")
    if path is None:
        pytest.fail("hello_xr not found: install Debian's libopenxr-utils (tools/setup.sh does)")
    return path


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> tuple[Path, str]:
    """``pip wheel .`` of a copy of the sources: the wheel and pip's verbose log."""
    folder = tmp_path_factory.mktemp("wheel")
    src = folder / "src"
    src.mkdir()
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.so", "*.egg-info", "build")
    for name in SOURCES:
        path = ROOT / name
        if path.is_dir():
            shutil.copytree(path, src / name, symlinks=True, ignore=ignore)
        else:
            shutil.copy2(path, src / name)
    dist = folder / "dist"
    result = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-v",
                             "--disable-pip-version-check", "-w", str(dist), str(src)],
                            capture_output=True, text=True, env={**os.environ, "PIP_NO_INDEX": "1"})
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-4000:]
    wheels = list(dist.glob("vrcorrect-*.whl"))
    assert len(wheels) == 1, list(dist.iterdir())
    return wheels[0], result.stdout + result.stderr


def test_pip_wheel_builds_the_layer_into_the_wheel_with_warnings_as_errors(built):
    import runpy

    wheel, log = built
    flags = runpy.run_path(str(ROOT / "layer" / "build_flags.py"))
    assert "-Werror" in flags["CFLAGS"] and "-Wall" in flags["CFLAGS"] and "-Wextra" in flags["CFLAGS"]
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        tag = z.read(next(n for n in names if n.endswith(".dist-info/WHEEL"))).decode()
        library = z.read("vrcorrect/runtime/layer/libvrcorrect_layer.so")
    assert "Root-Is-Purelib: false" in tag and "linux" in wheel.name, (tag, wheel.name)   # a platform wheel
    assert any(n.endswith("shaders/layer_copy.glsl") for n in names)
    compiles = [line for line in log.splitlines() if " -c layer/vrcorrect_" in line]
    assert len(compiles) == len(flags["SOURCES"]), log[-3000:]
    for line in compiles:                                  # the shared flags, -Werror among them, at wheel build
        assert all(f" {flag}" in line for flag in flags["CFLAGS"]), line
    path = wheel.parent / "libvrcorrect_layer.so"
    path.write_bytes(library)
    assert hasattr(ctypes.CDLL(str(path)), "xrNegotiateLoaderApiLayerInterface")    # the loader's entry point


def test_a_warning_fails_the_layers_build(tmp_path):
    """-Werror on the fallback route too: a source with a warning (an unused variable) is refused."""
    from vrcorrect.plumbing.errors import InputError
    from vrcorrect.runtime.layer import build as layer_build

    copy = tmp_path / "layer"
    shutil.copytree(ROOT / "layer", copy)
    source = copy / "vrcorrect_vulkan.c"
    source.write_text(source.read_text() + "\nvoid vrcorrect_warning_probe(void) { int unused = 1; }\n")
    original = layer_build.SOURCE_DIR
    layer_build.SOURCE_DIR = copy
    try:
        with pytest.raises(InputError, match="unused"):
            layer_build.build_layer(tmp_path / "out")
    finally:
        layer_build.SOURCE_DIR = original
    assert not (tmp_path / "out" / layer_build.LIBRARY).exists()


@pytest.fixture(scope="module")
def venv(built, tmp_path_factory) -> Path:
    """A fresh virtual environment with the wheel installed; its dependencies through a .pth file."""
    wheel, _ = built
    folder = tmp_path_factory.mktemp("venv") / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(folder)], check=True)
    python = folder / "bin" / "python"
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    ours = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "vrcorrect_test_dependencies.pth").write_text("\n".join(sorted(ours)) + "\n")
    result = subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index",
                             "--disable-pip-version-check", str(wheel)], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    where = subprocess.run([str(python), "-c", "import vrcorrect, pathlib; print(pathlib.Path(vrcorrect.__file__).parent)"],
                           capture_output=True, text=True, check=True, cwd=folder).stdout.strip()
    assert Path(where).is_relative_to(folder), where       # the wheel's copy, not this checkout's
    return folder


def _home(folder: Path) -> dict[str, str]:
    return {"HOME": str(folder), "XDG_CONFIG_HOME": str(folder / ".config"),
            "XDG_DATA_HOME": str(folder / ".local" / "share"), "XDG_STATE_HOME": str(folder / ".local" / "state")}


def _install(venv: Path, home: Path, rx: Path) -> subprocess.CompletedProcess:
    """``vrcorrect layer install --rx`` from the venv with a PATH that holds no C compiler."""
    path = str(venv / "bin")
    assert shutil.which("gcc", path=path) is None and shutil.which("cc", path=path) is None
    environ = {k: v for k, v in os.environ.items() if not k.startswith(("XDG_", "VRCORRECT_", "CC"))}
    environ.update(_home(home), PATH=path)
    return subprocess.run([str(venv / "bin" / "vrcorrect"), "layer", "install", "--rx", str(rx)], capture_output=True,
                          text=True, env=environ, cwd=home)


def test_layer_install_from_the_wheel_needs_no_compiler_and_only_writes_the_manifest_and_configuration(venv, kit,
                                                                                                       tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    result = _install(venv, home, kit.rx)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "using the layer built into this installation" in result.stdout and "compiling" not in result.stdout
    manifest = home / ".local" / "share" / "openxr" / "1" / "api_layers" / "implicit.d" / "vrcorrect_layer.json"
    library = Path(json.loads(manifest.read_text())["api_layer"]["library_path"])
    assert library.is_file() and library.is_relative_to(venv), library
    data = home / ".local" / "share" / "vrcorrect" / "layer"
    assert sorted(p.name for p in data.iterdir()) == ["vrcorrect_layer.cfg"]     # nothing built here
    cfg = (data / "vrcorrect_layer.cfg").read_text()
    assert f"home={sys.base_prefix}" in cfg and any(str(venv) in line for line in cfg.splitlines())
    assert json.loads((home / ".config" / "vrcorrect" / "layer.json").read_text())["rx"] == str(kit.rx)


def _times(out: Path) -> list[tuple[int, float, float]]:
    """frame_times.txt: (frame, arrival ms, gap ms) of every xrEndFrame that reached the runtime."""
    rows = [line.split() for line in (out / "frame_times.txt").read_text().splitlines() if not line.startswith("#")]
    return [(int(r[0]), float(r[1]), float(r[2])) for r in rows]


def _launch(kit, out: Path, venv: Path, home: Path, api: str, display: str) -> tuple[float, float, float, float]:
    """hello_xr -g ``api`` with the layer the wheel installed in ``home``, until 3 corrected frames have
    arrived; returns (seconds from the first frame to the first corrected one, the largest gap
    between frames after the first three over the gap it may reach (:data:`MAX_GAP_S`, or twice
    the corrected frames' median gap where that is longer), the seconds the layer spent priming, and
    that median gap in seconds: the renderer's pace)."""
    environ = env(kit, out, app="vk", home=home, DISPLAY=display, XRTEST_FRAME_MS="20", explicit=False,
                  PATH=str(venv / "bin"), prime=None,                  # the layer's default priming budget
                  VRCORRECT_LAYER_STALL_TRACE=str(out / "stalls.txt"))  # where a frame over 0.5 s waited
    environ.pop("MESA_SHADER_CACHE_DIR")                   # Mesa's own cache in the fresh HOME, as a user's
    before = _cpu_ticks()
    result = run([_hello_xr(), "-g", api], out, environ, corrected=3, stop_env="XRTEST_STOP_FILE", stdin=True)
    assert result.returncode == 0, (result.stdout + result.stderr)[-3000:]
    log = layer_log(out)
    assert any(f"vrcorrect from {venv}" in line for line in log), log              # the wheel's vrcorrect
    assert not any("pass-through" in line for line in log), log
    views = submitted(out)
    received_frames = frames(out)
    first = next(f for f in received_frames if views[f] != views[received_frames[0]])   # the layer's swapchains
    for view in (0, 1):                                    # hello_xr's still scene: corrected, not as it drew it
        assert not np.array_equal(received(out, first, view), received(out, received_frames[0], view))
    times = _times(out)
    arrival = {frame: t for frame, t, _ in times}
    pace = float(np.median([g for frame, _, g in times if frame >= first])) / 1e3     # the renderer's own pace
    allowed = max(MAX_GAP_S, 2.0 * pace)
    gap = max(g for frame, _, g in times[3:]) / 1e3 / allowed
    ready = [line for line in log if "correcting with" in line]
    assert len(ready) == 1, log
    priming = re.search(r"priming ([\d.]+) s", ready[0])
    assert priming, ready[0]
    # the default follows the light: its design is in use from the first corrected frame, not seconds later
    assert "designed for the light's pupil while priming" in ready[0], ready[0]
    (out / "machine.txt").write_text(_machine_said(before, _cpu_ticks()))
    return (arrival[first] - arrival[times[0][0]]) / 1e3, gap, float(priming.group(1)), pace


def _cpu_ticks() -> list[int]:
    """/proc/stat's first line: the machine's CPU ticks (user, nice, system, idle, iowait, irq, softirq,
    steal, ...)."""
    return [int(v) for v in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]


def _machine_said(before: list[int], after: list[int]) -> str:
    """What the machine did during a launch, for a failure's message: its load average at the end and
    the shares of its CPU time that were busy and that a virtual machine's host took (steal)."""
    spent = [a - b for a, b in zip(after, before)]
    total = max(1, sum(spent[:8]))
    busy = total - spent[3] - spent[4]
    return (f"load average {' '.join(f'{v:.2f}' for v in os.getloadavg())}; during the launch the CPUs were "
            f"{busy / total:.0%} busy, {spent[7] / total:.1%} taken by the host (steal)")


@pytest.mark.parametrize("api", ["Vulkan", "OpenGL"])
def test_hello_xr_corrected_from_the_wheel_never_stalls_and_starts_again_within_seconds(venv, kit, xorg_display,
                                                                                        tmp_path, api,
                                                                                        record_property):
    home = tmp_path / "home"
    home.mkdir()
    assert _install(venv, home, kit.rx).returncode == 0
    first_s, first_gap, _, first_pace = _launch(kit, tmp_path / "first", venv, home, api, xorg_display)
    second_s, second_gap, second_priming, pace = _launch(kit, tmp_path / "second", venv, home, api, xorg_display)
    for name, value in (("first_launch_s", first_s), ("first_launch_max_gap_share", first_gap),
                        ("second_launch_s", second_s), ("second_launch_priming_s", second_priming),
                        ("second_launch_max_gap_share", second_gap)):
        record_property(name, round(value, 3))
    print(f"{api}: corrected after {first_s:.1f} s (largest gap {first_gap:.2f} of what it may reach; a corrected "
          f"frame {first_pace:.2f} s), again after {second_s:.1f} s of which {second_priming:.1f} s priming (largest "
          f"gap {second_gap:.2f} of it; a corrected frame {pace:.2f} s)")
    second_log = layer_log(tmp_path / "second")
    assert any("came from the cache" in line for line in second_log), second_log
    assert any("correcting with" in line and ", 0 compiled" in line for line in second_log), second_log
    # on a failure, what the layer said of its build and its first frames (where the time went)
    said = [line for launch in ("first", "second") for line in layer_log(tmp_path / launch)
            if "correcting with" in line or "first corrected" in line or "1 frames corrected" in line
            or "took over" in line]
    said += [f"{launch} launch: {(tmp_path / launch / 'machine.txt').read_text()}" for launch in ("first", "second")]
    said += [f"{launch} launch's stall trace:\n{path.read_text()[-6000:]}" for launch in ("first", "second")
             if (path := tmp_path / launch / "stalls.txt").is_file() and path.stat().st_size]
    assert first_gap <= 1.0 and second_gap <= 1.0, (first_gap, second_gap, said)
    assert first_s <= FIRST_LAUNCH_S * max(1.0, first_pace / REFERENCE_PACE_S), (first_s, first_pace)
    assert second_s <= SECOND_LAUNCH_S * max(1.0, pace / REFERENCE_PACE_S), (second_s, second_priming, pace)
    assert "destroy_instance" in runtime_log(tmp_path / "second")
