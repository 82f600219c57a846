"""The shipped default model (models/default.onnx, the unrolled correction): it is what the README's
training command makes, it loads with its card and metadata, improves what the eye sees over no
correction on every display it names, refuses eyes outside its range, and is what `--backend onnx`,
`--method learned` and `--cold-start` use when no model is named."""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vrcorrect.learn.conditioning import SamplingRanges
from vrcorrect.physics.kernel import build_kernel, build_reference_kernel
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.plumbing.imageio import read_image
from vrcorrect.runtime.unrolled import UnrolledModel
from vrcorrect.solvers import make_problem, objective
from vrcorrect.specs.display import decode, get_display, preset_names
from vrcorrect.specs.prescription import EyeRx

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "models" / "default.onnx"
CARD = ROOT / "models" / "default.md"


@pytest.fixture(scope="module")
def model() -> UnrolledModel:
    return UnrolledModel(MODEL, providers=("CPUExecutionProvider",))


def _readme_training_command() -> list[str]:
    """The one ``vrcorrect unroll`` line of the README's code blocks, as arguments."""
    lines = [line.split("#")[0].strip() for line in (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
             if line.strip().startswith("vrcorrect unroll ")]
    assert len(lines) == 1, lines
    return shlex.split(lines[0])[1:]


def test_the_shipped_model_is_what_the_readmes_training_command_makes(model):
    """Every setting the run records equals what the README's command asks (its flags read by the
    real parser, defaults included), so the file was made by that command."""
    from vrcorrect.apps.cli import build_parser

    args = build_parser().parse_args(_readme_training_command())
    train = json.loads(model.metadata["vrcorrect.train"])
    cfg = train["config"]
    asked = {"stages": args.stages, "prior_width": args.prior_width, "crop_px": args.crop_px,
             "batch": args.batch_size, "steps": args.steps, "minutes": args.minutes, "seed": args.seed,
             "eyes_per_display": args.eyes_per_display, "displays": list(args.displays),
             "fast_weight": args.fast_weight, "box_floor": args.box_floor}
    assert {k: cfg[k] for k in asked} == asked
    assert train["image_px"] == args.image_px
    assert train["steps"] == cfg["steps"]                        # it ran all its steps, not out of time
    assert train["seconds"] < 90 * 60                            # the budget on this machine


def test_default_model_is_shipped_small_with_its_card_and_metadata(model):
    from vrcorrect.runtime.model_path import DEFAULT_MODEL

    assert DEFAULT_MODEL.resolve() == MODEL.resolve()
    assert MODEL.stat().st_size <= 10 * 2 ** 20
    assert model.ranges == SamplingRanges()                       # the ranges, not a narrower set
    assert sorted(model.displays) == sorted(preset_names()) and model.reference == "glasses"
    train = json.loads(model.metadata["vrcorrect.train"])
    assert train["images"] and not {"rocket", "retina"} & set(train["images"])   # the card's held-out images
    card = CARD.read_text(encoding="utf-8")
    for needle in ("held-out", "rocket", "retina", "FLIP", "gap closed", "JOD share", model.ranges.describe(),
                   "vrcorrect unroll", "minutes"):
        assert needle in card, needle


@pytest.mark.parametrize("display", ["quest2", "desktop", "index"])
@pytest.mark.parametrize("rx", [(-3.0, -1.5, 20.0, 4.0), (2.5, 0.0, 0.0, 3.0), (-5.5, -2.75, 110.0, 5.5)])
def test_default_model_improves_the_objective_over_no_correction(model, rx, display):
    """On the bundled sample image (not a training image), for a myope with astigmatism, a
    hyperope and a strong mixed eye, on three displays: the eye's objective is clearly below the
    uncorrected one's."""
    d = get_display(display)
    codes = read_image(ROOT / "vrcorrect" / "data" / "sample.png")[96:96 + 96, 128:128 + 112]
    target = decode(d, codes).astype(np.float32)
    eye = EyeRx(*rx)
    kernel, reference = build_kernel(eye, d), build_reference_kernel(eye, d)
    shown = model.correct(target, eye, kernel, reference)
    p = make_problem(target, kernel, reference)
    assert shown.shape == target.shape and 0 <= shown.min() and shown.max() <= 1
    assert objective(shown, p) < 0.9 * objective(target, p)


def test_default_model_refuses_an_eye_outside_its_range(model, tmp_path):
    with pytest.raises(ValidationError) as err:
        model.check(EyeRx(-7.5, 0.0, 0.0, 4.0), get_display("quest2"))
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


def test_a_prescription_with_an_age_is_corrected_by_the_learned_model(tmp_path):
    """The README's tour asks for ``age_years`` and then runs ``--method learned``: a myope of 45, whose
    amplitude (5 D) cannot help at the Valve Index's 2 m (its far point is nearer), is corrected as
    the same eye that cannot focus (the model's training eyes), not refused; the two shown images are
    the same."""
    eye = {"sphere_D": -2.0, "cylinder_D": -1.0, "axis_deg": 120, "pupil_diameter_mm": 4.0}
    sample = str(ROOT / "vrcorrect" / "data" / "sample.png")
    shown = {}
    for tag, doc in (("aged", {"age_years": 45, "right": eye, "left": eye}),
                     ("stated", {"right": {**eye, "accommodation_D": 0}, "left": eye})):
        rx = tmp_path / f"{tag}.json"
        rx.write_text(json.dumps({"schema": "vrcorrect.prescription/1", **doc}))
        out = tmp_path / f"{tag}.png"
        run = subprocess.run([str(Path(sys.executable).parent / "vrcorrect"), "correct", sample, "-o", str(out),
                              "--rx", str(rx), "--eye", "right", "--display", "index", "--method", "learned",
                              "--pupil", "3"], capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stderr[-2000:]
        shown[tag] = read_image(out)
    np.testing.assert_array_equal(shown["aged"], shown["stated"])


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


def test_cold_start_alone_takes_the_shipped_model(tmp_path, capsys):
    """`vrcorrect render --cold-start` with no file: the shipped model starts the first frame."""
    from PIL import Image

    from vrcorrect.apps.cli import main

    src = tmp_path / "in.png"
    codes = read_image(ROOT / "vrcorrect" / "data" / "sample.png")[96:96 + 40, 128:128 + 48]
    Image.fromarray(np.round(np.asarray(codes, np.float32) * 255).astype(np.uint8)).save(src)
    out = tmp_path / "out.png"
    assert main(["render", str(src), "-o", str(out), "--display", "desktop", "--cold-start", "--frames", "1"]) == 0
    log = capsys.readouterr().out
    assert "cold start" in log and re.search(r"default\.onnx", log), log
    assert np.asarray(Image.open(out)).shape == (40, 48, 3)


def test_by_default_the_real_time_path_takes_the_learned_start_where_a_gpu_runs_it():
    """``--cold-start`` left out (auto): the shipped model starts a shot wherever onnxruntime offers a
    GPU execution provider; on a CPU-only machine the half-resolution level does, and the line says
    why; nothing iterates, nothing is chosen."""
    from vrcorrect.apps.realtime_options import cold_start_choice
    from vrcorrect.runtime.model_path import DEFAULT_MODEL

    for given in (None, "auto"):
        model, note = cold_start_choice(given, "admm", "glsl", available=["CUDAExecutionProvider", "CPUExecutionProvider"])
        assert model == str(DEFAULT_MODEL) and "CUDAExecutionProvider" in note
        model, note = cold_start_choice(given, "admm", "glsl", available=["DmlExecutionProvider", "CPUExecutionProvider"])
        assert model == str(DEFAULT_MODEL) and "DmlExecutionProvider" in note
        model, note = cold_start_choice(given, "admm", "glsl", available=["CPUExecutionProvider"])
        assert model is None and "half-resolution level" in note and "no GPU execution provider" in note
        assert cold_start_choice(given, "fista", "glsl", available=["CUDAExecutionProvider"]) == (None, "")
        assert cold_start_choice(given, "admm", "onnx", available=["CUDAExecutionProvider"]) == (None, "")
    model, note = cold_start_choice("none", "admm", "glsl", available=["CUDAExecutionProvider"])
    assert model is None and "--cold-start none" in note
    assert cold_start_choice("default", "admm", "glsl", available=["CPUExecutionProvider"])[0] == str(DEFAULT_MODEL)
    with pytest.raises(ValidationError, match="only with --filter admm"):
        cold_start_choice("default", "fista", "glsl")


def test_render_says_what_starts_a_shot_on_this_machine(tmp_path, capsys):
    """The default render on this machine: the choice its line names is the one onnxruntime's own
    providers here call for (CPU only in CI: the half-resolution level)."""
    from PIL import Image

    from vrcorrect.apps.cli import main
    from vrcorrect.runtime.learned import gpu_provider

    src = tmp_path / "in.png"
    codes = read_image(ROOT / "vrcorrect" / "data" / "sample.png")[96:96 + 24, 128:128 + 32]
    Image.fromarray(np.round(np.asarray(codes, np.float32) * 255).astype(np.uint8)).save(src)
    assert main(["render", str(src), "-o", str(tmp_path / "out.png"), "--display", "desktop", "--frames", "1"]) == 0
    log = capsys.readouterr().out
    line = next(x for x in log.splitlines() if "cold start:" in x)
    if gpu_provider() is None:
        assert "half-resolution level" in line and "no GPU execution provider" in line
    else:
        assert "learned pass on " + gpu_provider() in line
