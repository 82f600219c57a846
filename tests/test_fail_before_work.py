"""Failures come before the work, not after it: a model's eye range, an unwritable output, an
image too large for memory and a missing input are each refused in one line before any kernel is
built (the kernel build is replaced by a tripwire here); animated and transparent inputs are
reported instead of silently reduced."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from vrcorrect.apps import cli, common, correct
from vrcorrect.plumbing.errors import ValidationError

ROOT = Path(__file__).resolve().parents[1]
OUTSIDE = {"schema": "vrcorrect.prescription/1",     # sphere -12 D: outside the shipped model's -6..+6
           **{e: {"sphere_D": -12.0, "cylinder_D": -1.0, "axis_deg": 90, "pupil_diameter_mm": 4.0}
              for e in ("right", "left")}}


@pytest.fixture
def small_png(tmp_path) -> Path:
    path = tmp_path / "in.png"
    Image.fromarray(np.full((16, 16, 3), 128, np.uint8)).save(path)
    return path


@pytest.fixture
def no_kernel_builds(monkeypatch):
    """Any kernel build fails the test: the refusal must come first."""
    def tripwire(*args, **kwargs):
        raise AssertionError("a kernel was built before the refusal")

    import vrcorrect.physics.kernel as K
    import vrcorrect.physics.robust as Rb
    import vrcorrect.runtime.corrector as C

    monkeypatch.setattr(correct, "build_design", tripwire)
    monkeypatch.setattr(K, "build_kernel", tripwire)
    monkeypatch.setattr(Rb, "build_kernel", tripwire)
    monkeypatch.setattr(Rb, "build_reference_kernel", tripwire)
    monkeypatch.setattr(C, "build_eye_model", tripwire)


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("vrcorrect:")]
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize("command", [["correct", "--method", "learned"], ["render", "--backend", "onnx"]],
                         ids=["correct --method learned", "render --backend onnx"])
def test_a_learned_model_refuses_an_eye_outside_its_range_before_the_kernel(command, tmp_path, small_png, capsys,
                                                                           no_kernel_builds):
    rx = tmp_path / "rx.json"
    rx.write_text(json.dumps(OUTSIDE))
    code = cli.main([command[0], str(small_png), "-o", str(tmp_path / "o.png"), "--rx", str(rx), *command[1:],
                     "--display", "quest2"])
    assert code == 2
    line = _one_line_error(capsys)
    assert "sphere" in line and "-12" in line and ("wiener" in line or "fast" in line), line
    assert not (tmp_path / "o.png").exists()


def test_an_unwritable_output_folder_is_refused_before_the_work(small_png, capsys, no_kernel_builds):
    """/proc exists and passes os.access for root, but no file can be made there."""
    assert cli.main(["correct", str(small_png), "-o", "/proc/vrcorrect_out.png"]) == 2
    line = _one_line_error(capsys)
    assert "/proc" in line and "cannot create a file" in line, line


def test_an_image_too_large_for_memory_is_refused_before_the_kernel(tmp_path, small_png, capsys, monkeypatch,
                                                                   no_kernel_builds):
    monkeypatch.setattr(common, "available_memory_bytes", lambda: 64e6)   # a machine with 64 MB free
    assert cli.main(["correct", str(small_png), "-o", str(tmp_path / "o.png")]) == 2
    line = _one_line_error(capsys)
    assert "16x16" in line and "GiB" in line and "available" in line, line


def test_memory_estimate_grows_with_the_image_and_names_the_method():
    from vrcorrect.solvers import peak_memory_bytes

    small, large = peak_memory_bytes("fast", 256, 256), peak_memory_bytes("fast", 4096, 4096)
    assert 0 < small < large and large > 5e9                   # 4096^2 x 330 B is 5.5 GB
    with pytest.raises(ValidationError, match="method"):
        peak_memory_bytes("magic", 8, 8)


def test_a_missing_input_is_told_before_the_heavy_imports(tmp_path):
    """The check comes before the solvers, kernels and metrics are imported (seconds of imports)."""
    code = ("import sys; from vrcorrect.apps.cli import main; "
            f"rc = main(['correct', {str(tmp_path / 'missing.png')!r}, '-o', {str(tmp_path / 'o.png')!r}]); "
            "heavy = [m for m in ('vrcorrect.physics.kernel', 'vrcorrect.solvers', 'vrcorrect.vision.metrics', 'scipy') "
            "if m in sys.modules]; print('HEAVY', heavy); sys.exit(rc)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert result.returncode == 2
    assert "missing.png: no such file" in result.stderr
    assert "HEAVY []" in result.stdout, result.stdout


def test_animated_and_transparent_inputs_are_reported(tmp_path, capsys):
    from vrcorrect.plumbing.imageio import read_image

    frames = [Image.fromarray(np.full((8, 8, 3), v, np.uint8)) for v in (10, 200, 90)]
    gif = tmp_path / "clip.gif"
    frames[0].save(gif, save_all=True, append_images=frames[1:], duration=100, loop=0)
    notes: list[str] = []
    image = read_image(gif, notes)
    assert abs(float(image.mean()) - 10 / 255) < 0.02                      # the first frame
    assert len(notes) == 1 and "animated (3 frames)" in notes[0] and "first frame" in notes[0]
    rgba = tmp_path / "rgba.png"
    Image.fromarray(np.full((8, 8, 4), 100, np.uint8)).save(rgba)
    notes = []
    read_image(rgba, notes)
    assert len(notes) == 1 and "transparency" in notes[0]
    notes = []
    read_image(tmp_path / "clip.gif", None)                                # no list: nothing said, no error
    assert cli.main(["simulate", str(rgba), "-o", str(tmp_path / "seen.png"), "--display", "desktop"]) == 0
    assert "vrcorrect: note: rgba.png has transparency" in capsys.readouterr().err
