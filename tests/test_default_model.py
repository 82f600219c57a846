"""The shipped default model (models/default.onnx): it loads, carries its metadata, improves what
the eye sees over no correction for several prescriptions, and refuses eyes outside its range."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vrcorrect.specs.display import decode, get_display
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.plumbing.imageio import read_image
from vrcorrect.physics.kernel import build_kernel, build_reference_kernel
from vrcorrect.learn.conditioning import SamplingRanges
from vrcorrect.specs.prescription import EyeRx
from vrcorrect.runtime.learned import LearnedModel
from vrcorrect.solvers import make_problem, objective

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "models" / "default.onnx"
CARD = ROOT / "models" / "default.md"


@pytest.fixture(scope="module")
def model() -> LearnedModel:
    return LearnedModel(MODEL, providers=("CPUExecutionProvider",))


def test_default_model_is_shipped_small_with_its_card_and_metadata(model):
    from vrcorrect.runtime.model_path import DEFAULT_MODEL

    assert DEFAULT_MODEL.resolve() == MODEL.resolve()
    assert MODEL.stat().st_size <= 10 * 2 ** 20
    assert model.ranges == SamplingRanges()                       # the ranges, not a narrower set
    assert model.display["name"] == "quest2" and model.reference == "glasses"
    assert model.precorrection_steps > 0
    train = json.loads(model.metadata["vrcorrect.train"])
    assert train["images"] and not {"rocket", "retina"} & set(train["images"])   # the card's held-out images
    assert model.metadata["vrcorrect.precision"] == "fp32"
    card = CARD.read_text(encoding="utf-8")
    for needle in ("held-out", "rocket", "retina", "FLIP", "gap closed", model.ranges.describe()):
        assert needle in card


@pytest.mark.parametrize("rx", [(-3.0, -1.5, 20.0, 4.0), (2.5, 0.0, 0.0, 3.0), (-5.5, -2.75, 110.0, 5.5)])
def test_default_model_improves_the_objective_over_no_correction(model, rx):
    """On the bundled sample image (not a training image), for a myope with astigmatism, a
    hyperope and a strong mixed eye: the eye's objective is clearly below the uncorrected one's."""
    display = get_display("quest2")
    codes = read_image(ROOT / "vrcorrect" / "data" / "sample.png")[96:96 + 128, 128:128 + 160]
    target = decode(display, codes)
    eye = EyeRx(*rx)
    kernel, reference = build_kernel(eye, display), build_reference_kernel(eye, display)
    bound = model.for_eye(eye, display, kernel, reference)
    shown = np.moveaxis(bound.infer(np.ascontiguousarray(np.moveaxis(target, 2, 0))), 0, 2)
    p = make_problem(target, kernel, reference)
    assert shown.shape == target.shape and 0 <= shown.min() and shown.max() <= 1
    assert objective(shown, p) < 0.95 * objective(target, p)       # measured: 0.84 to 0.88


def test_default_model_refuses_an_eye_outside_its_range(model, tmp_path):
    with pytest.raises(ValidationError) as err:
        model.for_eye(EyeRx(-7.5, 0.0, 0.0, 4.0), get_display("quest2"))
    assert "-6 to 6 D" in str(err.value) and "wiener or fast" in str(err.value)
    rx = tmp_path / "rx.json"
    eye = {"sphere_D": -2.0, "cylinder_D": -4.0, "axis_deg": 90, "pupil_diameter_mm": 4.0}
    rx.write_text(json.dumps({"schema": "vrcorrect.prescription/1", "right": eye, "left": eye}))
    out = tmp_path / "shown.png"
    sample = str(ROOT / "vrcorrect" / "data" / "sample.png")
    run = subprocess.run([str(Path(sys.executable).parent / "vrcorrect"), "correct", sample,
                          "-o", str(out), "--rx", str(rx), "--eye", "right", "--display", "quest2",
                          "--method", "learned"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 2 and not out.exists()
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "cylinder_D" in lines[0] and "-3 to 0 D" in lines[0] and "Traceback" not in run.stderr


def test_mirror_runs_the_default_model_per_eye(x_display, tmp_path):
    """`vrcorrect mirror --backend onnx` with no --model: the shipped model corrects both eyes."""
    import os

    env = dict(os.environ, DISPLAY=x_display)
    run = subprocess.run([str(Path(sys.executable).parent / "vrcorrect"), "mirror", "--backend", "onnx",
                          "--source", str(ROOT / "vrcorrect" / "data" / "sample.png"), "--size", "48x40",
                          "--frames", "2", "--screenshot-dir", str(tmp_path)], capture_output=True, text=True,
                         env=env, cwd=tmp_path, timeout=600)
    assert run.returncode == 0, run.stderr
    assert "2 frame(s)" in run.stdout and "correct left" in run.stdout and "correct right" in run.stdout
