"""The learned correction's foundations (issue 5): data set, conditioning, model, training, export.

Everything is tiny (32x32 crops, 2-3 samples, a 4-channel U-Net) so each test takes seconds
on two cores; eyes are drawn from narrow ranges with small pupils so kernels build quickly.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vrcorrect.plumbing.charts import siemens_star, text_chart
from vrcorrect.plumbing.errors import InputError, ValidationError
from vrcorrect.learn.conditioning import SamplingRanges, check_eye, eye_features
from vrcorrect.learn.dataset import DatasetConfig, build_dataset, load_shard, read_manifest, sample_spec
from vrcorrect.specs.prescription import EyeRx

ROOT = Path(__file__).resolve().parents[1]
TINY_RANGES = SamplingRanges(sphere_D=(-1.5, -0.5), cylinder_D=(-0.5, 0.0), pupil_diameter_mm=(2.0, 3.0))


def tiny_config(**kw) -> DatasetConfig:
    base = dict(samples=3, crop_px=32, samples_per_shard=2, seed=7, ranges=TINY_RANGES, wavelength_step_nm=40)
    return DatasetConfig(**{**base, **kw})


def tiny_images() -> list[tuple[str, np.ndarray]]:
    return [("star", siemens_star(48)), ("text", text_chart(40, 48))]


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("learn") / "data"
    build_dataset(out, tiny_images(), tiny_config(), workers=1, progress=False)
    return out


# --------------------------------------------------------------------------
# Data set
# --------------------------------------------------------------------------

def test_dataset_builds_shards_and_manifest(tiny_dataset):
    m = read_manifest(tiny_dataset)
    assert m["config"]["seed"] == 7 and m["config"]["ranges"]["sphere_D"] == [-1.5, -0.5]
    assert m["display"]["name"] == "quest2" and [i["name"] for i in m["images"]] == ["star", "text"]
    samples = [s for e in m["shards"] for s in e["samples"]]
    assert [s["index"] for s in samples] == [0, 1, 2] and len(m["shards"]) == 2
    for s in samples:
        assert -1.5 <= s["sphere_D"] <= -0.5 and -0.5 <= s["cylinder_D"] <= 0 and 2 <= s["pupil_diameter_mm"] <= 3
        assert s["objective_fast"] <= s["objective_uncorrected"]        # fast never worse than no correction
    shard = load_shard(tiny_dataset, m["shards"][0])
    assert shard["target"].shape == (2, 3, 32, 32) and shard["fast"].dtype == np.float32
    assert shard["kernel"].shape[:3] == (2, 3, 3) and shard["kernel"].shape[-1] == max(shard["kernel_px"])
    assert 0 <= shard["precorrected"].min() and shard["precorrected"].max() <= 1
    # the stored kernel reproduces the stored objective (the forward model training uses)
    from vrcorrect.learn.train import objective_per_sample
    import torch

    t = {k: torch.as_tensor(shard[k]) for k in ("fast", "kernel", "target_lms")}
    np.testing.assert_allclose(objective_per_sample(t["fast"], t["kernel"], t["target_lms"]).numpy(),
                               shard["objective_fast"], rtol=1e-3)


def test_dataset_resumes_without_recomputing(tiny_dataset, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(tiny_dataset, out)
    before = {p.name: p.stat().st_mtime_ns for p in out.glob("shard_*.npz")}
    report = build_dataset(out, tiny_images(), tiny_config(), progress=False)
    assert (report.computed_shards, report.skipped_shards) == (0, 2)
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("shard_*.npz")} == before
    # an interrupted build: shard 1 never written -> only it is computed, and it is the same data
    m = read_manifest(out)
    old = load_shard(out, m["shards"][1])
    (out / "shard_00001.npz").unlink()
    built: list[int] = []
    report = build_dataset(out, tiny_images(), tiny_config(), progress=False, on_shard=built.append)
    assert built == [1] and report.computed_shards == 1
    new = load_shard(out, read_manifest(out)["shards"][1])
    np.testing.assert_array_equal(new["target"], old["target"])
    np.testing.assert_allclose(new["fast"], old["fast"], atol=1e-6)


def test_parallel_build_equals_serial(tiny_dataset, tmp_path):
    """Two local processes, other sharding: every sample is the same as the serial build's."""
    report = build_dataset(tmp_path / "par", tiny_images(), tiny_config(samples=2, samples_per_shard=1), workers=2,
                           progress=False)
    assert report.computed_shards == 2
    serial = load_shard(tiny_dataset, read_manifest(tiny_dataset)["shards"][0])
    for entry in read_manifest(tmp_path / "par")["shards"]:
        par = load_shard(tmp_path / "par", entry)
        i = int(par["index"][0])
        for key in ("target", "precorrected", "target_lms", "eye"):
            np.testing.assert_array_equal(par[key][0], serial[key][i])
        np.testing.assert_allclose(par["fast"][0], serial["fast"][i], atol=1e-6)


def test_dataset_with_other_settings_is_refused(tiny_dataset, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(tiny_dataset, out)
    with pytest.raises(InputError, match="other settings.*--force"):
        build_dataset(out, tiny_images(), tiny_config(seed=8), progress=False)


def test_samples_are_deterministic_per_seed():
    shapes = [(48, 48), (40, 48)]
    a = [sample_spec(tiny_config(), shapes, i) for i in range(20)]
    assert a == [sample_spec(tiny_config(), shapes, i) for i in range(20)]
    assert a != [sample_spec(tiny_config(seed=8), shapes, i) for i in range(20)]
    # sample i does not depend on how many samples the data set has or how it is sharded
    assert sample_spec(tiny_config(samples=100, samples_per_shard=7), shapes, 5) == a[5]
    for s in a:
        assert 0 <= s.y <= shapes[s.image][0] - 32 and 0 <= s.x <= shapes[s.image][1] - 32


def test_default_ranges_are_the_issue_s():
    r = SamplingRanges()
    assert (r.sphere_D, r.cylinder_D, r.axis_deg, r.pupil_diameter_mm) == ((-6, 6), (-3, 0), (0, 180), (2, 6))
    rng = np.random.default_rng(0)
    for _ in range(50):
        check_eye(r.sample(rng), r)
    with pytest.raises(ValidationError):
        SamplingRanges(sphere_D=(2.0, -2.0))


# --------------------------------------------------------------------------
# Conditioning and the trained range
# --------------------------------------------------------------------------

@pytest.mark.parametrize("eye, field", [
    (EyeRx(-8.0, -1.0, 90.0, 4.0), "sphere_D"),
    (EyeRx(-2.0, -4.0, 10.0, 4.0), "cylinder_D"),
    (EyeRx(-2.0, -1.0, 10.0, 7.0), "pupil_diameter_mm"),
])
def test_out_of_range_eye_is_refused_naming_the_range(eye, field):
    with pytest.raises(ValidationError) as err:
        check_eye(eye, SamplingRanges())
    text = str(err.value)
    assert err.value.field == field and "wiener" in text and "fast" in text and "trained on" in text
    lo, hi = getattr(SamplingRanges(), field)
    assert f"{lo:g} to {hi:g}" in text


def test_plus_cylinder_form_is_the_same_eye():
    plus = EyeRx(-4.0, 2.0, 30.0, 4.0)           # = -2.00 / -2.00 x 120
    e = check_eye(plus, SamplingRanges())
    assert e.cylinder_D == -2.0 and e.sphere_D == -2.0
    np.testing.assert_allclose(eye_features(plus, SamplingRanges()), eye_features(e, SamplingRanges()), atol=1e-6)


def test_an_eye_that_can_focus_is_taken_as_the_eye_that_cannot_and_sees_the_display_alike():
    """The model was trained on eyes that cannot focus. Given the display's distance, an eye that can
    is checked as one that cannot, with the accommodation it uses there taken off its sphere: a myope
    whose far point is nearer than the display uses none (its sphere stays), a hyperope uses all it
    has; the kernel at the display is the same either way, so the model is told of the eye it sees."""
    from vrcorrect.physics.kernel import build_kernel
    from vrcorrect.specs.display import get_display

    quest2 = get_display("quest2")                            # 1.3 m: 0.77 D of vergence
    myope = EyeRx(-2.0, -1.0, 120.0, 3.0, accommodation_D=5.0)
    assert check_eye(myope, SamplingRanges(), distance_m=quest2.distance_m) == myope.with_changes(accommodation_D=0.0)
    hyperope = EyeRx(2.0, -0.5, 90.0, 3.0, accommodation_D=1.0)
    taken = check_eye(hyperope, SamplingRanges(), distance_m=quest2.distance_m)
    assert taken.accommodation_D == 0.0 and taken.sphere_D == pytest.approx(1.0)
    np.testing.assert_allclose(build_kernel(taken, quest2).kernel, build_kernel(hyperope, quest2).kernel, atol=1e-12)
    with pytest.raises(ValidationError) as err:               # with no distance, as before: refused
        check_eye(hyperope, SamplingRanges())
    assert err.value.field == "accommodation_D"


def test_the_learned_model_is_told_of_a_lagging_eye_as_the_eye_that_sees_the_display_alike():
    """A lag leaves part of the demand unfocused (0.75 D of lag at 40 cm: 0.3 of it); the eye told of
    has the focused part taken off its sphere and keeps the residual, so the kernel is the same. An
    eye asked for nothing (its far point nearer than the display) keeps its sphere."""
    from vrcorrect.physics.kernel import build_kernel
    from vrcorrect.specs.display import get_display

    quest2 = get_display("quest2")
    lagging = EyeRx(-0.5, -1.0, 120.0, 3.0, accommodation_D=5.0, accommodative_lag_D=0.75)
    taken = check_eye(lagging, SamplingRanges(), distance_m=quest2.distance_m)
    asked = 1.0 / quest2.distance_m - 1.0                     # M = -1.00 (S -0.50, C -1.00): 0.769 - 1.0 < 0
    assert asked < 0 and taken.sphere_D == -0.5              # nothing asked of it: nothing folded
    near = EyeRx(0.0, -0.5, 90.0, 3.0, accommodation_D=5.0, accommodative_lag_D=0.75)
    taken = check_eye(near, SamplingRanges(), distance_m=quest2.distance_m)
    asked = 1.0 / quest2.distance_m - 0.25                    # M = -0.25
    assert taken.accommodation_D == 0.0 and taken.accommodative_lag_D == 0.0
    assert taken.sphere_D == pytest.approx(-asked * 0.7)      # the 0.7 of the demand it focuses, taken off
    np.testing.assert_allclose(build_kernel(taken, quest2).kernel, build_kernel(near, quest2).kernel, atol=1e-12)
    with pytest.raises(ValidationError) as err:               # with no distance: refused, by name
        check_eye(near.with_changes(accommodation_D=0.0), SamplingRanges())
    assert err.value.field == "accommodative_lag_D"


def test_an_eye_out_of_range_after_its_focus_is_taken_off_says_so():
    with pytest.raises(ValidationError) as err:
        check_eye(EyeRx(10.0, 0.0, 0.0, 3.0, accommodation_D=2.0), SamplingRanges(), distance_m=1.3)
    text = str(err.value)
    assert err.value.field == "sphere_D" and "= 8" in text and "-6 to 6 D" in text
    assert "the 2.00 D of its 2.00 D of accommodation the eye uses at the display taken off" in text


# --------------------------------------------------------------------------
# Model and training
# --------------------------------------------------------------------------

TINY_MODEL = dict(width=4, depth=2, film_hidden=8)


def tiny_train_config(**kw):
    from vrcorrect.learn.model import UNetConfig
    from vrcorrect.learn.train import TrainConfig

    base = dict(steps=12, batch_size=3, learning_rate=1e-3, checkpoint_every=4, seed=3, model=UNetConfig(**TINY_MODEL))
    return TrainConfig(**{**base, **kw})


def _log(run: Path) -> list[dict[str, str]]:
    import csv

    with open(run / "log.csv", newline="") as f:
        return list(csv.DictReader(f))


def test_untrained_model_returns_its_base_at_any_size():
    """Zero-initialised head: an untrained model is exactly its base, the pre-correction
    channels by default and the image itself with ``base="image"``."""
    import torch

    from vrcorrect.learn.model import ConditionedUNet, UNetConfig

    x, pre = torch.rand(2, 3, 37, 45), torch.rand(2, 3, 37, 45)
    for base, expected in (("precorrected", pre), ("image", x)):
        model = ConditionedUNet(UNetConfig(**TINY_MODEL, base=base)).eval()
        with torch.no_grad():
            y = model(x, pre, torch.randn(2, 4))
        assert y.shape == x.shape
        torch.testing.assert_close(y, expected)
    with pytest.raises(ValidationError, match="base"):
        UNetConfig(base="target")
    assert UNetConfig.from_dict({"width": 4}).base == "image"       # checkpoints from before the option


def test_precorrection_is_projected_gradient_and_lowers_the_objective(tiny_dataset):
    """The stored pre-correction channels are three projected-gradient steps on the sample's own
    objective: each sample's is below its uncorrected objective (the training's forward model)."""
    import torch

    from vrcorrect.learn.train import objective_per_sample

    m = read_manifest(tiny_dataset)
    assert m["config"]["precorrection_steps"] == 3
    for entry in m["shards"]:
        shard = load_shard(tiny_dataset, entry)
        t = {k: torch.as_tensor(shard[k]) for k in ("precorrected", "target", "kernel", "target_lms")}
        pre = objective_per_sample(t["precorrected"], t["kernel"], t["target_lms"]).numpy()
        unc = objective_per_sample(t["target"], t["kernel"], t["target_lms"]).numpy()
        np.testing.assert_allclose(unc, shard["objective_uncorrected"], rtol=1e-3)
        assert np.all(pre < unc) and np.all(pre >= shard["objective_fast"] * 0.999)


def test_gradient_input_is_the_same_in_numpy_and_torch():
    """The optional gradient channels: numpy at run time (FFT plan) equals torch autograd in training,
    and a step along them from the pre-correction lowers the objective."""
    import torch

    from vrcorrect.specs.display import decode, get_display
    from vrcorrect.physics.kernel import KernelOptions, build_kernel, build_reference_kernel
    from vrcorrect.learn.conditioning import model_inputs
    from vrcorrect.learn.train import gradient_step
    from vrcorrect.solvers import make_problem, objective

    display = get_display("quest2")
    eye = EyeRx(-2.0, -1.0, 30.0, 4.0)
    opts = KernelOptions(wavelength_step_nm=40)
    k, r = build_kernel(eye, display, opts), build_reference_kernel(eye, display, opts)
    image = decode(display, siemens_star(48)[:40])
    pre, g = model_inputs(image, k, r, steps=2, gradient=True)
    p = make_problem(image, k, r)
    chw = torch.from_numpy(np.moveaxis(pre, 2, 0).copy())[None]
    ref = gradient_step(chw, torch.from_numpy(k.kernel.astype(np.float32))[None],
                        torch.from_numpy(np.moveaxis(p.target_lms, 2, 0).copy())[None])[0].numpy()
    assert g.shape == image.shape and np.abs(g).max() > 1e-3
    np.testing.assert_allclose(np.moveaxis(g, 2, 0), ref, atol=2e-5 * np.abs(ref).max())
    assert objective(np.clip(pre - g, 0, 1), p) < objective(pre, p)
    assert model_inputs(image, k, r, steps=2)[1] is None


def test_manifest_from_before_precorrection_steps_means_the_inverse():
    cfg = tiny_config(precorrection_steps=5).as_dict()
    assert DatasetConfig.from_dict(cfg).precorrection_steps == 5
    del cfg["precorrection_steps"]
    assert DatasetConfig.from_dict(cfg).precorrection_steps == 0
    with pytest.raises(ValidationError, match="precorrection_steps"):
        tiny_config(precorrection_steps=-1)


def test_tiny_model_trains_and_its_loss_decreases(tiny_dataset, tmp_path):
    from vrcorrect.learn.train import train

    from vrcorrect.learn.model import UNetConfig

    run = tmp_path / "run"
    config = tiny_train_config(model=UNetConfig(**TINY_MODEL, base="image"))
    report = train(tiny_dataset, run, config, progress=False)
    rows = _log(run)
    assert [int(r["step"]) for r in rows] == list(range(1, 13))
    losses = [float(r["loss"]) for r in rows]
    assert losses[0] == pytest.approx(1.0, abs=1e-4)          # base "image" starts as no correction: ratio 1
    assert np.mean(losses[-3:]) < losses[0] - 0.02
    assert report.last_loss == pytest.approx(losses[-1], rel=1e-4)
    assert (run / "checkpoint.pt").is_file() and json.loads((run / "train.json").read_text())["samples"] == 3
    with pytest.raises(InputError, match="--resume"):
        train(tiny_dataset, run, config, progress=False)


def test_training_starts_from_the_precorrection(tiny_dataset, tmp_path):
    """With the default base the first step's objective ratio is the pre-correction's, below 1."""
    import torch

    from vrcorrect.learn.train import objective_per_sample, train

    train(tiny_dataset, tmp_path / "run", tiny_train_config(steps=1), progress=False)
    first = _log(tmp_path / "run")[0]
    ratios = []
    for entry in read_manifest(tiny_dataset)["shards"]:
        shard = load_shard(tiny_dataset, entry)
        t = {k: torch.as_tensor(shard[k]) for k in ("precorrected", "kernel", "target_lms")}
        ratios += list(objective_per_sample(t["precorrected"], t["kernel"], t["target_lms"]).numpy()
                       / shard["objective_uncorrected"])
    assert float(first["objective_ratio"]) == pytest.approx(np.mean(ratios), rel=1e-3) and np.mean(ratios) < 1


def test_resumed_training_equals_uninterrupted(tiny_dataset, tmp_path):
    from vrcorrect.learn.train import load_checkpoint, train

    cfg = dict(steps=4, batch_size=2, checkpoint_every=2)
    train(tiny_dataset, tmp_path / "a", tiny_train_config(**cfg), progress=False)
    train(tiny_dataset, tmp_path / "b", tiny_train_config(**{**cfg, "steps": 2}), progress=False)
    report = train(tiny_dataset, tmp_path / "b", tiny_train_config(**cfg), resume=True, progress=False)
    assert report.start_step == 2 and load_checkpoint(tmp_path / "b" / "checkpoint.pt")["step"] == 4
    a, b = _log(tmp_path / "a"), _log(tmp_path / "b")
    assert [r["step"] for r in b] == ["1", "2", "3", "4"]
    np.testing.assert_allclose([float(r["loss"]) for r in b], [float(r["loss"]) for r in a], rtol=1e-4)
    with pytest.raises(InputError, match="other settings"):
        train(tiny_dataset, tmp_path / "b", tiny_train_config(**{**cfg, "learning_rate": 1e-2}), resume=True,
              progress=False)


def test_cosine_schedule_lowers_the_learning_rate_and_fixes_the_step_count(tiny_dataset, tmp_path):
    from vrcorrect.learn.train import train

    cfg = tiny_train_config(steps=6, batch_size=2, checkpoint_every=3, lr_schedule="cosine")
    assert cfg.learning_rate_at(0) == pytest.approx(1e-3) and cfg.learning_rate_at(6) == pytest.approx(1e-5)
    assert cfg.learning_rate_at(3) == pytest.approx((1e-3 + 1e-5) / 2)
    train(tiny_dataset, tmp_path / "c", cfg, progress=False)
    lrs = [float(r["lr"]) for r in _log(tmp_path / "c")]
    assert lrs[0] == pytest.approx(1e-3) and all(a > b for a, b in zip(lrs, lrs[1:])) and lrs[-1] < 1e-4
    constant = tiny_train_config(steps=2, batch_size=2)
    train(tiny_dataset, tmp_path / "k", constant, progress=False)
    assert {float(r["lr"]) for r in _log(tmp_path / "k")} == {1e-3}
    with pytest.raises(InputError, match="--steps 6"):
        train(tiny_dataset, tmp_path / "c", tiny_train_config(steps=8, batch_size=2, checkpoint_every=3,
                                                              lr_schedule="cosine"), resume=True, progress=False)
    with pytest.raises(ValidationError, match="lr_schedule"):
        tiny_train_config(lr_schedule="step")


def test_dataset_and_train_commands_end_to_end(tmp_path, capsys):
    from vrcorrect.apps.cli import main

    data, run = tmp_path / "data", tmp_path / "run"
    rng = ["--sphere-D", "-1", "-0.5", "--cylinder-D", "-0.25", "0", "--pupil-mm", "2", "2.5"]
    args = ["dataset", str(data), "--samples", "2", "--crop-px", "32", "--image-px", "48", "--workers", "1",
            "--wavelength-step-nm", "80", "--samples-per-shard", "1", *rng]
    assert main(args) == 0 and "2 computed" in capsys.readouterr().out
    assert main(args) == 0 and "0 computed, 2 already there" in capsys.readouterr().out     # resumed: nothing to do
    names = [i["name"] for i in read_manifest(data)["images"]]
    assert names[-1] == "colour_bars" and "astronaut" in names      # the bundled images ...
    assert "rocket" not in names                                    # ... but bench learned's held-out one
    targs = ["train", str(data), "-o", str(run), "--steps", "2", "--width", "4", "--depth", "2", "--film-hidden", "4"]
    assert main(targs) == 0 and "checkpoint" in capsys.readouterr().out
    assert main(targs) == 2 and "--resume" in capsys.readouterr().err
    assert main(targs[:5] + ["4"] + targs[6:] + ["--resume"]) == 0 and "steps 2..4" in capsys.readouterr().out


def test_cli_one_line_errors(tmp_path):
    def run(*args):
        r = subprocess.run([sys.executable, "-m", "vrcorrect.apps.cli", *args], capture_output=True, text=True)
        return r.returncode, r.stderr.strip().splitlines()

    code, err = run("dataset", str(tmp_path / "d"), "--crop-px", "64", "--image-px", "48")
    assert code == 2 and len(err) == 1 and "--crop-px" in err[0]          # (Ray's errors: test_learn_ray.py)
    code, err = run("train", str(tmp_path / "none"), "-o", str(tmp_path / "r"))
    assert code == 2 and len(err) == 1 and "manifest" in err[0]


def test_train_init_from_a_missing_checkpoint_is_one_line(tiny_dataset, tmp_path):
    r = subprocess.run([sys.executable, "-m", "vrcorrect.apps.cli", "train", str(tiny_dataset), "-o", str(tmp_path / "r"),
                        "--init", str(tmp_path / "nope.pt")], capture_output=True, text=True)
    err = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(err) == 1 and "nope.pt: no such checkpoint" in err[0]
    assert not (tmp_path / "r").exists()


# --------------------------------------------------------------------------
# Export to ONNX and the runtime side
# --------------------------------------------------------------------------

@pytest.fixture(scope="module")
def perturbed_checkpoint(tiny_dataset, tmp_path_factory) -> Path:
    """A briefly trained tiny model whose zero-initialised parts (the head and FiLM's last
    layer) are given random weights, so the export is compared on a model far from the
    identity it starts as (the other layers keep their random initialisation)."""
    import torch

    from vrcorrect.learn.train import train

    run = tmp_path_factory.mktemp("learn") / "run"
    train(tiny_dataset, run, tiny_train_config(steps=3), progress=False)
    ckpt = torch.load(run / "checkpoint.pt", weights_only=True)
    g = torch.Generator().manual_seed(0)
    for k, v in ckpt["model"].items():
        if k.startswith(("head.", "film.2.")):
            v += 0.1 * torch.randn(v.shape, generator=g)
    path = run / "perturbed.pt"
    torch.save(ckpt, path)
    return path


def test_export_equals_torch_with_metadata_and_dynamic_size(perturbed_checkpoint, tmp_path):
    import onnx
    import onnxruntime as ort
    import torch

    from vrcorrect.learn.export import OPSET, check_against_torch, export_onnx
    from vrcorrect.learn.train import load_checkpoint, model_from_checkpoint

    out = tmp_path / "tiny.onnx"
    report = export_onnx(perturbed_checkpoint, out)
    assert report.max_abs_error_fp32 <= 1e-4 and report.precision == "fp32"
    proto = onnx.load(out)
    assert [o.version for o in proto.opset_import if o.domain in ("", "ai.onnx")] == [OPSET]
    meta = {p.key: p.value for p in proto.metadata_props}
    assert json.loads(meta["vrcorrect.ranges"]) == TINY_RANGES.as_dict()
    assert json.loads(meta["vrcorrect.display"])["name"] == "quest2" and meta["vrcorrect.version"]
    assert json.loads(meta["vrcorrect.train"])["step"] == 3
    # dynamic H and W: another size, compared with torch again
    model = model_from_checkpoint(load_checkpoint(perturbed_checkpoint))
    assert check_against_torch(model, out.read_bytes(), seed=1, size=(64, 24)) <= 1e-4
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    y = session.run(None, {"image": np.zeros((2, 3, 17, 33), np.float32),
                           "precorrected": np.zeros((2, 3, 17, 33), np.float32),
                           "eye": np.zeros((2, 4), np.float32)})[0]
    assert y.shape == (2, 3, 17, 33)
    x = torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():                                     # the compared model is not the identity
        assert float((model(x, x, torch.zeros(1, 4)) - x).abs().mean()) > 1e-2
    with pytest.raises(InputError, match="--force"):
        export_onnx(perturbed_checkpoint, out)


def test_fine_tuning_starts_from_another_runs_weights_and_says_so(perturbed_checkpoint, tiny_dataset, tmp_path):
    """--init: the new run's first step starts from the given weights (not from the identity a
    fresh run starts as), its checkpoint and export record where they came from, and a
    checkpoint of another size, or --init with --resume, is refused naming --init."""
    import onnx
    import torch

    from vrcorrect.learn.export import export_onnx
    from vrcorrect.learn.model import UNetConfig
    from vrcorrect.learn.train import load_checkpoint, train

    cfg = tiny_train_config(steps=1, learning_rate=1e-9, target_weight=1.0)
    train(tiny_dataset, tmp_path / "fresh", cfg, progress=False)
    train(tiny_dataset, tmp_path / "tuned", cfg, progress=False, init=perturbed_checkpoint)
    source = load_checkpoint(perturbed_checkpoint)["model"]
    tuned = load_checkpoint(tmp_path / "tuned" / "checkpoint.pt")
    for name, value in source.items():
        if name.endswith("weight") and value.dim() == 4:         # convolutions: moved by at most ~lr
            torch.testing.assert_close(tuned["model"][name], value, atol=1e-6, rtol=0)
    assert float(_log(tmp_path / "tuned")[0]["loss"]) != pytest.approx(float(_log(tmp_path / "fresh")[0]["loss"]),
                                                                       rel=1e-3)
    assert tuned["init"]["step"] == 3 and tuned["init"]["train_config"]["target_weight"] == 0.2
    export_onnx(tmp_path / "tuned" / "checkpoint.pt", tmp_path / "tuned.onnx")
    meta = {p.key: p.value for p in onnx.load(tmp_path / "tuned.onnx").metadata_props}
    assert json.loads(meta["vrcorrect.train"])["init"]["step"] == 3
    from vrcorrect.studies.bench.learned import _training_lines

    assert _training_lines(json.loads(meta["vrcorrect.train"]))[0].startswith(
        "- fine-tuned (`vrcorrect train --init`) from a run of 3 steps")
    wider = tiny_train_config(steps=1, model=UNetConfig(**{**TINY_MODEL, "width": 6}))
    with pytest.raises(ValidationError, match="--init"):
        train(tiny_dataset, tmp_path / "wide", wider, progress=False, init=perturbed_checkpoint)
    assert not (tmp_path / "wide").exists()
    with pytest.raises(ValidationError, match="--init.*--resume"):
        train(tiny_dataset, tmp_path / "tuned", cfg, progress=False, init=perturbed_checkpoint, resume=True)


def test_fp16_export_reports_its_error(perturbed_checkpoint, tmp_path):
    from vrcorrect.learn.export import export_onnx

    r32 = export_onnx(perturbed_checkpoint, tmp_path / "a.onnx")
    r16 = export_onnx(perturbed_checkpoint, tmp_path / "b.onnx", fp16=True)
    assert r16.precision == "fp16-weights" and r16.metadata["vrcorrect.precision"] == "fp16-weights"
    assert 0 < r16.max_abs_error_fp16 < 2e-2 and r16.bytes < r32.bytes


def test_export_tool_command_line(perturbed_checkpoint, tmp_path):
    tool = [sys.executable, str(ROOT / "tools" / "export_onnx.py")]
    r = subprocess.run(tool + [str(perturbed_checkpoint), "-o", str(tmp_path / "m.onnx"), "--fp16"],
                       capture_output=True, text=True)
    assert r.returncode == 0 and "max abs error" in r.stdout and "fp16 weights" in r.stdout
    r = subprocess.run(tool + [str(tmp_path / "missing.pt"), "-o", str(tmp_path / "n.onnx")],
                       capture_output=True, text=True)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "no such checkpoint" in r.stderr


def test_runtime_learned_model_refuses_out_of_range_and_equals_torch(perturbed_checkpoint, tmp_path):
    import torch

    from vrcorrect.specs.display import get_display
    from vrcorrect.physics.kernel import KernelOptions, build_kernel, build_reference_kernel
    from vrcorrect.learn.export import export_onnx
    from vrcorrect.learn.train import load_checkpoint, model_from_checkpoint
    from vrcorrect.runtime.learned import LearnedModel, is_learned_model

    path = tmp_path / "m.onnx"
    export_onnx(perturbed_checkpoint, path)
    assert is_learned_model(path)
    model = LearnedModel(path)
    display = get_display("quest2")
    with pytest.raises(ValidationError) as err:
        model.for_eye(EyeRx(-4.0, 0.0, 0.0, 2.5), display)            # the tiny model knows -1.5..-0.5 D
    assert "-1.5 to -0.5 D" in str(err.value) and "wiener or fast" in str(err.value)
    with pytest.raises(ValidationError, match="trained for"):
        model.for_eye(EyeRx(-1.0, 0.0, 0.0, 2.5), get_display("desktop"))
    eye = EyeRx(-1.0, -0.25, 30.0, 2.5)
    opts = KernelOptions(wavelength_step_nm=40)
    bound = model.for_eye(eye, display, build_kernel(eye, display, opts), build_reference_kernel(eye, display, opts))
    image = np.moveaxis(siemens_star(40), 2, 0).astype(np.float32) ** 2.2
    out = bound.infer(image)
    net = model_from_checkpoint(load_checkpoint(perturbed_checkpoint))
    with torch.no_grad():
        ref = net(torch.from_numpy(image)[None], torch.from_numpy(bound.precorrected(image))[None],
                  torch.from_numpy(eye_features(eye, TINY_RANGES))[None])[0].numpy()
    assert out.shape == image.shape and np.max(np.abs(out - ref)) <= 1e-4
    # the kept kernel spectrum (one per frame size) gives the same pre-correction as a fresh one
    from vrcorrect.learn.conditioning import precorrect

    def fresh(img):
        hwc = np.moveaxis(img, 0, 2)
        return np.moveaxis(precorrect(hwc, bound.kernel, bound.reference_kernel, model.mu_rel,
                                      model.precorrection_steps), 2, 0)

    small = image[:, :24, :32].copy()
    for img in (image, small, image):
        np.testing.assert_array_equal(bound.precorrected(img), fresh(img))
    assert model.precorrection_steps > 0 and sorted(bound._plans) == [(24, 32), (40, 40)]


def test_model_with_gradient_input_trains_exports_and_runs_without_torch(tiny_dataset, tmp_path):
    """``--gradient-input``: 9 input channels; the export has a fourth input ``gradient``; the
    runtime computes it (numpy) and its output equals torch fed the same four inputs."""
    import torch

    from vrcorrect.specs.display import get_display
    from vrcorrect.physics.kernel import KernelOptions, build_kernel, build_reference_kernel
    from vrcorrect.learn.export import export_onnx
    from vrcorrect.learn.model import UNetConfig
    from vrcorrect.learn.train import load_checkpoint, model_from_checkpoint, train
    from vrcorrect.runtime.learned import LearnedModel

    cfg = tiny_train_config(steps=3, batch_size=2, model=UNetConfig(**TINY_MODEL, gradient_input=True))
    train(tiny_dataset, tmp_path / "run", cfg, progress=False)
    net = model_from_checkpoint(load_checkpoint(tmp_path / "run" / "checkpoint.pt"))
    assert net.input_names == ("image", "precorrected", "eye", "gradient") and net.down[0].conv1.in_channels == 9
    with torch.no_grad():                      # make the head matter (3 steps barely move it)
        net.head.weight.normal_(0, 0.2)
    ckpt = load_checkpoint(tmp_path / "run" / "checkpoint.pt")
    ckpt["model"] = net.state_dict()
    torch.save(ckpt, tmp_path / "p.pt")
    report = export_onnx(tmp_path / "p.pt", tmp_path / "g.onnx")
    assert report.max_abs_error_fp32 <= 1e-4
    model = LearnedModel(tmp_path / "g.onnx")
    assert model.gradient_input and model.metadata["vrcorrect.inputs"] == "image,precorrected,eye,gradient"
    display = get_display("quest2")
    eye = EyeRx(-1.0, -0.25, 30.0, 2.5)
    opts = KernelOptions(wavelength_step_nm=40)
    bound = model.for_eye(eye, display, build_kernel(eye, display, opts), build_reference_kernel(eye, display, opts))
    image = np.moveaxis(siemens_star(40), 2, 0).astype(np.float32) ** 2.2
    out = bound.infer(image)
    pre, g = bound.inputs(image)
    assert g is not None and np.abs(g).max() > 0
    with torch.no_grad():
        feats = torch.from_numpy(eye_features(eye, TINY_RANGES))[None]
        ref = net(torch.from_numpy(image)[None], torch.from_numpy(pre)[None], feats, torch.from_numpy(g)[None])
    ref = ref[0].numpy()
    assert np.max(np.abs(out - ref)) <= 1e-4 and np.max(np.abs(out - pre)) > 1e-3


def test_loss_of_an_eye_in_focus_stays_bounded():
    """An in-focus eye (1x1 kernel) has an uncorrected objective of exactly 0: the floored
    denominator keeps a small deviation a small loss."""
    import torch

    from vrcorrect.learn.train import loss_terms

    t = torch.rand(1, 3, 8, 8, generator=torch.Generator().manual_seed(0))
    A = torch.eye(3)[None, :, :, None, None]                       # (1, 3, 3, 1, 1)
    batch = {"kernel": A, "target_lms": t, "objective_uncorrected": torch.zeros(1), "fast": t, "target": t}
    loss, ratio, dratio = loss_terms(t, batch, 0.2)
    assert float(loss) < 1e-6                                      # FFT round-off only
    loss, ratio, dratio = loss_terms((t + 1e-3).clamp(0, 1), batch, 0.2)
    assert 0 < float(loss) < 2.0


# --------------------------------------------------------------------------
# Use: vrcorrect correct --method learned, and the renderer's ONNX slot
# --------------------------------------------------------------------------

@pytest.fixture(scope="module")
def tiny_onnx(perturbed_checkpoint, tmp_path_factory) -> Path:
    from vrcorrect.learn.export import export_onnx

    path = tmp_path_factory.mktemp("learn") / "tiny.onnx"
    export_onnx(perturbed_checkpoint, path)
    return path


def _rx_file(path: Path, right: tuple, left: tuple) -> Path:
    def eye(s, c, a):
        return {"sphere_D": s, "cylinder_D": c, "axis_deg": a, "pupil_diameter_mm": 2.5}
    path.write_text(json.dumps({"schema": "vrcorrect.prescription/1", "right": eye(*right), "left": eye(*left)}))
    return path


def test_correct_with_the_learned_method(tiny_onnx, tmp_path, capsys):
    """The command runs the model bound to the eye and reports it; the written image equals the
    runtime's own inference; an eye outside the trained range is refused in one line that names
    the range and the alternatives; --model without --method learned is refused."""
    from vrcorrect.apps.cli import main
    from vrcorrect.specs.display import decode, get_display
    from vrcorrect.plumbing.imageio import read_image, write_png
    from vrcorrect.physics.kernel import KernelOptions, build_kernel, build_reference_kernel
    from vrcorrect.runtime.learned import LearnedModel

    src = tmp_path / "in.png"
    write_png(src, siemens_star(40))
    rx = _rx_file(tmp_path / "rx.json", (-1.0, -0.25, 30.0), (-3.0, 0.0, 0.0))
    out, report = tmp_path / "out.png", tmp_path / "r.json"
    args = ["correct", str(src), "-o", str(out), "--rx", str(rx), "--display", "quest2", "--method", "learned",
            "--model", str(tiny_onnx), "--wavelength-step-nm", "40", "--pupil", "rx", "--robust", "off"]
    assert main(args + ["--report", str(report)]) == 0
    doc = json.loads(report.read_text())
    assert doc["method"] == "learned" and doc["settings"]["model"] == str(tiny_onnx)
    assert doc["settings"]["ranges"] == TINY_RANGES.as_dict()
    display = get_display("quest2")
    eye = EyeRx(-1.0, -0.25, 30.0, 2.5)
    opts = KernelOptions(wavelength_step_nm=40)
    bound = LearnedModel(tiny_onnx).for_eye(eye, display, build_kernel(eye, display, opts),
                                            build_reference_kernel(eye, display, opts))
    expected = bound.infer(np.ascontiguousarray(np.moveaxis(decode(display, read_image(src)), 2, 0)))
    written = decode(display, read_image(out))
    assert np.abs(np.moveaxis(written, 2, 0) - expected).max() < 2.5 / 255     # 8-bit quantisation
    capsys.readouterr()
    assert main(args[:-2] + ["--eye", "left", "-o", str(tmp_path / "left.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "-1.5 to -0.5 D" in err[0] and "wiener or fast" in err[0]
    assert not (tmp_path / "left.png").exists()
    # a robust design: this format has no input for the light cap, runs as it is and says so
    robust_report = tmp_path / "robust.json"
    assert main(args[:-1] + ["on", "-o", str(tmp_path / "robust.png"), "--report", str(robust_report)]) == 0
    doc = json.loads(robust_report.read_text())
    assert doc["robust"] and doc["settings"]["light_cap"] is False
    assert main(["correct", str(src), "-o", str(tmp_path / "x.png"), "--model", str(tiny_onnx)]) == 2
    assert "only with --method learned" in capsys.readouterr().err


def test_renderer_onnx_backend_runs_the_learned_model_per_eye(gl, tiny_onnx, tmp_path):
    """The Corrector binds the learned model to its own eye: the frame equals the runtime's
    inference for that eye (read back, infer, upload, sRGB), each eye gets its own result,
    and moving the eye out of the trained range is refused with the last state kept."""
    from vrcorrect.specs.display import decode, encode
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.corrector import Corrector

    rx = _rx_file(tmp_path / "rx.json", (-1.0, -0.25, 30.0), (-0.6, -0.5, 120.0))
    img = np.round(siemens_star(40) * 255).astype(np.uint8)
    outs = {}
    for side in ("right", "left"):
        c = Corrector(gl, str(rx), "quest2", side, backend="onnx", model=str(tiny_onnx))
        try:
            src = G.upload_texture(gl, img)
            tex, fbo = G.render_target(gl, width=40, height=40)
            c.apply(src, fbo)
            outs[side] = G.read_framebuffer(fbo)
            G.release(fbo, tex, src)
            linear = np.moveaxis(decode("srgb", img.astype(np.float32) / 255), 2, 0)
            expected = np.round(np.clip(encode("srgb", np.moveaxis(c.strategy.slot.infer(linear), 0, 2)), 0, 1) * 255)
            assert np.abs(outs[side].astype(int) - expected.astype(int)).max() <= 1, side
            assert c.strategy.slot.eye.sphere_D == c.eye_rx.sphere_D
            with pytest.raises(ValidationError, match="wiener or fast"):
                c.adjust(sphere_D=-3.0)
            assert c.eye_rx.sphere_D == pytest.approx(-1.0 if side == "right" else -0.6)
        finally:
            c.release()
    assert np.abs(outs["right"].astype(int) - outs["left"].astype(int)).max() > 2
    with pytest.raises(ValidationError, match="-1.5 to -0.5 D"):
        Corrector(gl, str(_rx_file(tmp_path / "far.json", (-4.0, 0.0, 0.0), (-1.0, 0.0, 0.0))), "quest2",
                  "right", backend="onnx", model=str(tiny_onnx))


def test_crops_per_eye_share_the_eye_and_nothing_else():
    config = tiny_config(samples=8, crops_per_eye=4)
    shapes = [(48, 48), (48, 40)]
    specs = [sample_spec(config, shapes, i) for i in range(8)]
    eyes = [(s.sphere_D, s.cylinder_D, s.axis_deg, s.pupil_diameter_mm) for s in specs]
    assert eyes[0] == eyes[1] == eyes[2] == eyes[3] and eyes[4] == eyes[7] and eyes[0] != eyes[4]
    assert len({(s.image, s.y, s.x) for s in specs}) > 4
    with pytest.raises(ValidationError, match="crops_per_eye"):
        tiny_config(crops_per_eye=0)


def test_bench_learned_scores_a_model_on_held_out_data(tiny_onnx, tmp_path):
    """The benchmark's accounting (not its timings): per case the gap share is computed from the
    objectives it reports, the held-out eyes lie in the model's ranges, and the card is written."""
    from vrcorrect.studies.bench.learned import held_out_eyes, run_learned_bench
    from vrcorrect.learn.conditioning import check_eye

    out, card, plot = tmp_path / "bench.md", tmp_path / "models" / "card.md", tmp_path / "learned.png"
    card.parent.mkdir()
    r = run_learned_bench(tiny_onnx, out=out, card=card, images=("rocket",), eyes=2, size=48, repeats=1,
                          progress=False, speed_sizes=((48, 48), (32, 40)), plot=plot, floor_unets=((2, 1),),
                          tradeoff=tmp_path / "tradeoff.png", fista_steps=(1, 4))
    assert len(r["cases"]) == 2
    # the floor: one convolution and one untrained U-Net, timed; the picture, linked from both documents
    assert [name for name, _ in r["speed"]["floor"]] == ["one 3x3 convolution, 6 to 3 channels",
                                                         "U-Net width 2, depth 1 (untrained)"]
    assert all(ms > 0 for _, ms in r["speed"]["floor"])
    from PIL import Image

    with Image.open(plot) as im:                       # one row (one image), six views
        assert im.width > 3 * im.height
    assert "](learned.png)" in out.read_text() and "](../learned.png)" in card.read_text()
    assert "](tradeoff.png)" in out.read_text() and (tmp_path / "tradeoff.png").stat().st_size > 0
    # FISTA steps alone: more steps close more of the gap (the same accounting as the model's)
    for c in r["cases"]:
        assert c["gap_closed_fista4"] > c["gap_closed_fista1"] > 0
        assert c["gap_closed_wiener"] == pytest.approx(
            (c["objective_none"] - c["objective_wiener"]) / (c["objective_none"] - c["objective_fast"]))
    assert set(r["speed"]["fista_ms"]) == {1, 4} and "4 FISTA steps, no network" in r["markdown"]
    for c in r["cases"]:
        expected = (c["objective_none"] - c["objective_learned"]) / (c["objective_none"] - c["objective_fast"])
        assert c["gap_closed"] == pytest.approx(expected)
        assert c["objective_precorrected"] < c["objective_none"]        # 3 projected-gradient steps
        assert c["objective_fast"] < c["objective_none"]
        # JOD of what the eye sees, for each method the table reports (10 = identical to the target)
        assert all(0.0 < c[f"jod_{m}"] <= 10.0 for m in ("none", "wiener", "learned", "fast", "fista1", "fista4"))
    assert "JOD ↑" in r["markdown"] and "JOD unc." in r["markdown"]
    for e in held_out_eyes(TINY_RANGES, 4):
        check_eye(e, TINY_RANGES)
    assert "<!-- bench:learned -->" in out.read_text() and "48x48" in r["markdown"] and "40x32" in r["markdown"]
    assert "Model card" in card.read_text() and TINY_RANGES.describe() in card.read_text()
    # the card tells the data and the run from the model's metadata: 3 crops of the tiny images, 3 eyes
    assert "- data: 3 random 32x32 crops of star, text; 3 eyes drawn" in card.read_text()
    assert "batch 3, learning rate 0.001 (constant)" in card.read_text()
    with pytest.raises(ValidationError, match="not trained on.*star, text"):    # the tiny data set's images
        run_learned_bench(tiny_onnx, out=tmp_path / "b2.md", images=("text",), eyes=1, size=48, progress=False)
    assert not (tmp_path / "b2.md").exists()


def test_bench_speed_words_never_round_a_slower_model_up_to_1x():
    from vrcorrect.studies.bench.learned import _times

    assert _times(0.997).endswith("slower") and not _times(0.997).startswith("1x")
    assert _times(2.44) == "2.4x faster" and _times(123.4) == "123x faster"
