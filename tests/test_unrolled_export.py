"""The unrolled model exported to ONNX (vrcorrect.learn.unrolled_export) and run by onnxruntime without
torch (vrcorrect.runtime.unrolled): one file for every size, equal to torch, refusing what it is not."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from vrcorrect.learn.conditioning import unrolled_features
from vrcorrect.learn.unrolled import kernel_spectra
from vrcorrect.learn.unrolled_export import TOLERANCE, export_unrolled, model_from_onnx
from vrcorrect.learn.unrolled_train import UnrolledTrainConfig, build_pool, load_unrolled, train_unrolled
from vrcorrect.plumbing.errors import InputError, ValidationError
from vrcorrect.plumbing.images import bundled_images
from vrcorrect.runtime.unrolled import UnrolledModel
from vrcorrect.solvers.admm import fast_start
from vrcorrect.specs.display import decode, get_display
from vrcorrect.specs.prescription import EyeRx
from vrcorrect.vision.forward import simulate_lms

CONFIG = UnrolledTrainConfig(displays=("index",), eyes_per_display=1, held_out_eyes_per_display=1, crop_px=24,
                             steps=8, batch=2, prior_width=4, stages=2, lr=5e-3)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    run = tmp_path_factory.mktemp("run")
    imgs = dict(bundled_images(48))
    pool = build_pool(CONFIG, workers=1)
    train_unrolled(run, CONFIG, [imgs["astronaut"]], [imgs["rocket"]], pool=pool, held_out_cases=1)
    report = export_unrolled(run / "unrolled.pt", run / "unrolled.onnx")
    return run, report, pool


def test_the_export_is_checked_and_carries_its_metadata(exported):
    run, report, _ = exported
    assert report.max_abs_error <= TOLERANCE and (run / "unrolled.onnx").stat().st_size == report.bytes
    model = UnrolledModel(run / "unrolled.onnx")
    assert model.config["stages"] == 2 and model.displays == ["index"]
    assert model.metadata["vrcorrect.format"] == "vrcorrect-unrolled-v4" and model.takes_cap


@pytest.mark.parametrize("size", [(33, 47), (72, 64)])   # (72, 64): fast's start solves a coarse level
def test_onnxruntime_equals_torch_on_a_real_eye_at_any_size(exported, size):
    run, _, pool = exported
    entry = pool["held_out"][0]
    H, W = size
    photo = dict(bundled_images(80))["coffee"][:H, :W]
    image = decode(get_display("index"), photo).astype(np.float32)
    got = UnrolledModel(run / "unrolled.onnx").correct(image, entry.eye, entry.eye_kernel, entry.reference_kernel)
    assert got.shape == (H, W, 3) and got.min() >= 0.0 and got.max() <= 1.0
    model = load_unrolled(run / "unrolled.pt")
    t_lms, _ = simulate_lms(image, entry.reference_kernel)
    spectrum, gram, norm2 = kernel_spectra([entry.kernel], (H, W))
    chw = np.ascontiguousarray(image.transpose(2, 0, 1))
    lms = np.ascontiguousarray(t_lms.transpose(2, 0, 1), np.float32)
    z0, d1, d2 = (torch.from_numpy(a)[None] for a in fast_start(entry.kernel, chw, lms))
    eye = entry.eye.minus_cylinder()
    with torch.no_grad():
        ref = model(torch.from_numpy(lms)[None], z0, spectrum, gram, norm2,
                    torch.from_numpy(unrolled_features(eye, entry.eye_kernel.size, CONFIG.ranges))[None],
                    torch.from_numpy(chw)[None], d1, d2)[0].numpy().transpose(1, 2, 0)
    assert np.abs(got - ref).max() <= TOLERANCE


def test_an_eye_bound_to_the_model_keeps_its_spectra_per_size_and_equals_the_unbound_pass(exported):
    run, _, pool = exported
    entry = pool["held_out"][0]
    model = UnrolledModel(run / "unrolled.onnx")
    bound = model.for_eye(entry.eye, get_display("index"), entry.eye_kernel, entry.reference_kernel)
    photos = dict(bundled_images(80))
    for name, (H, W) in (("coffee", (33, 47)), ("rocket", (40, 40)), ("chelsea", (33, 47))):   # back to a size it has seen
        image = decode(get_display("index"), photos[name][:H, :W]).astype(np.float32)
        got = bound.infer(np.ascontiguousarray(image.transpose(2, 0, 1)))
        want = model.correct(image, entry.eye, entry.eye_kernel, entry.reference_kernel).transpose(2, 0, 1)
        assert got.shape == (3, H, W) and np.array_equal(got, want), name
    assert sorted(bound._spectra) == [(33, 47), (40, 40)]
    with pytest.raises(ValidationError, match="image.shape"):
        bound.infer(np.zeros((4, 8, 8), np.float32))
    bound.release()
    assert not bound._spectra


def test_an_existing_file_is_kept_without_force_and_paths_are_checked(exported):
    run, _, _ = exported
    before = (run / "unrolled.onnx").read_bytes()
    with pytest.raises(InputError):
        export_unrolled(run / "unrolled.pt", run / "unrolled.onnx")
    assert (run / "unrolled.onnx").read_bytes() == before
    with pytest.raises(ValidationError, match="onnx"):
        export_unrolled(run / "unrolled.pt", run / "model.bin")


def test_the_runtime_refuses_other_models_and_eyes_outside_the_range(exported, tmp_path):
    from vrcorrect.runtime.onnx_backend import write_one_minus_x_model

    other = tmp_path / "other.onnx"
    write_one_minus_x_model(other)
    with pytest.raises(ValidationError, match="vrcorrect-unrolled-v3 or vrcorrect-unrolled-v4"):
        UnrolledModel(other)
    run, _, pool = exported
    entry = pool["held_out"][0]
    far = EyeRx(sphere_D=-12.0, cylinder_D=0.0, axis_deg=0.0, pupil_diameter_mm=4.0)
    with pytest.raises(ValidationError, match="sphere_D"):
        UnrolledModel(run / "unrolled.onnx").correct(np.zeros((24, 24, 3), np.float32), far, entry.eye_kernel,
                                                    entry.reference_kernel)


def _as_v3(path, out):
    """The v4 file as a v3 model: no ``upper`` input (a graph node makes it ones, the unit box)."""
    import onnx
    from onnx import TensorProto, helper

    proto = onnx.load(str(path))
    graph = proto.graph
    kept = [i for i in graph.input if i.name != "upper"]
    del graph.input[:]
    graph.input.extend(kept)
    one = helper.make_tensor("v3_one", TensorProto.FLOAT, [], [1.0])
    graph.initializer.append(one)
    graph.node.insert(0, helper.make_node("Shape", ["target"], ["v3_shape"]))
    graph.node.insert(1, helper.make_node("Expand", ["v3_one", "v3_shape"], ["upper"]))
    for entry in proto.metadata_props:
        if entry.key == "vrcorrect.format":
            entry.value = "vrcorrect-unrolled-v3"
    onnx.save(proto, str(out))
    return out


def test_the_light_cap_holds_in_the_exported_model_and_a_v3_model_runs_as_before(exported, tmp_path):
    """``capped``: the model's box is [0, the light cap] at every stage (a robust design's, as in
    ``fast``), where the unit box goes past the cap on light bars over a dark ground; bound with
    ``capped`` it is the same pass.  A model of the older format v3 has no input for the cap: it
    runs, uncapped, and says so (``takes_cap``, the bound eye's ``capped``)."""
    from vrcorrect.solvers.problem import light_cap

    run, _, pool = exported
    entry = pool["held_out"][0]
    display = get_display("index")
    codes = np.full((40, 56, 3), 0.1)
    codes[:, 6:50:10] = 0.95
    image = decode(display, codes).astype(np.float32)
    model = UnrolledModel(run / "unrolled.onnx")
    capped = model.correct(image, entry.eye, entry.eye_kernel, entry.reference_kernel, capped=True)
    free = model.correct(image, entry.eye, entry.eye_kernel, entry.reference_kernel)
    cap = light_cap(image)
    assert (capped - cap).max() <= 1e-6 and capped.min() >= 0.0
    assert (free - cap).max() > 0.05
    bound = model.for_eye(entry.eye, display, entry.eye_kernel, entry.reference_kernel, capped=True)
    assert bound.capped and np.array_equal(bound.infer(np.ascontiguousarray(image.transpose(2, 0, 1))),
                                           capped.transpose(2, 0, 1))
    old = UnrolledModel(_as_v3(run / "unrolled.onnx", tmp_path / "v3.onnx"))
    assert old.metadata["vrcorrect.format"] == "vrcorrect-unrolled-v3" and not old.takes_cap
    assert np.abs(old.correct(image, entry.eye, entry.eye_kernel, entry.reference_kernel, capped=True)
                  - free).max() <= 1e-5
    assert not old.for_eye(entry.eye, display, entry.eye_kernel, entry.reference_kernel, capped=True).capped
    back, meta = model_from_onnx(tmp_path / "v3.onnx")              # what tools/reexport_unrolled.py reads
    want = load_unrolled(run / "unrolled.pt").state_dict()
    assert meta["vrcorrect.format"] == "vrcorrect-unrolled-v3"
    assert all(torch.allclose(v, want[k], atol=1e-7) for k, v in back.state_dict().items() if k in want)


def test_correct_method_learned_takes_an_unrolled_model(exported, tmp_path, capsys):
    """``vrcorrect correct --method learned --model FILE`` with an unrolled model: on a display it was
    trained for it writes the corrected image; on another it refuses before any work."""
    from PIL import Image

    from vrcorrect.apps.cli import main

    run, _, _ = exported
    src = tmp_path / "in.png"
    Image.fromarray((dict(bundled_images(32))["coffee"] * 255).astype(np.uint8)).save(src)
    out = tmp_path / "out.png"
    assert main(["correct", str(src), "-o", str(out), "--method", "learned", "--model", str(run / "unrolled.onnx"),
                 "--display", "index", "--report", str(tmp_path / "r.json")]) == 0
    shown = np.asarray(Image.open(out))
    assert shown.shape == (32, 32, 3) and not np.array_equal(shown, np.asarray(Image.open(src)))
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["robust"] and report["settings"]["light_cap"] is True     # the default's robust design: capped
    assert main(["correct", str(src), "-o", str(tmp_path / "one.png"), "--method", "learned", "--model",
                 str(run / "unrolled.onnx"), "--display", "index", "--robust", "off", "--report",
                 str(tmp_path / "one.json")]) == 0
    assert json.loads((tmp_path / "one.json").read_text())["settings"]["light_cap"] is False
    capsys.readouterr()
    assert main(["correct", str(src), "-o", str(tmp_path / "no.png"), "--method", "learned", "--model",
                 str(run / "unrolled.onnx"), "--display", "quest2"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("vrcorrect: error: display") and "index" in err and not (tmp_path / "no.png").exists()


# ---------------------------------------------------------------- vrcorrect bench unrolled, on the exported model

def test_bench_unrolled_scores_every_method_and_its_twin_is_the_torch_twin(exported, tmp_path):
    """One held-out case at 64 px (fast's start runs its coarse level): the bench's twin (numpy ADMM
    from fast_start) equals learn.unrolled's torch twin from the same start, starting there beats the
    same stages from the target, fast closes its own gap, and the section is written."""
    from vrcorrect.learn.unrolled import twin
    from vrcorrect.learn.train import objective_per_sample
    from vrcorrect.physics.kernel import build_kernel, build_reference_kernel
    from vrcorrect.solvers import make_problem
    from vrcorrect.studies.bench.learned import _held_out_image, held_out_eyes
    from vrcorrect.studies.bench.unrolled import METHODS, run_unrolled_bench

    run, _, _ = exported
    out = tmp_path / "bench.md"
    result = run_unrolled_bench(run / "unrolled.onnx", out=out, eyes=1, size=64, images=("rocket",),
                                displays=("index",), progress=False, with_cut=False)
    (case,) = result["cases"]
    for m in METHODS:
        assert np.isfinite(case[f"objective_{m}"]) and case[f"ms_{m}"] > 0 and 0 <= case[f"flip_{m}"] <= 1
    assert case["gap_fast"] == pytest.approx(1.0) and case["objective_twin"] < case["objective_admm cold"]

    model = UnrolledModel(run / "unrolled.onnx")
    display = get_display("index")
    eye = held_out_eyes(model.ranges, 1)[0]
    kernel, reference = build_kernel(eye, display), build_reference_kernel(eye, display)
    target = decode(display, _held_out_image("rocket", 64)).astype(np.float32)
    p = make_problem(target, kernel, reference)
    chw = np.ascontiguousarray(target.transpose(2, 0, 1))
    lms = np.ascontiguousarray(p.target_lms.transpose(2, 0, 1), np.float32)
    z0, d1, d2 = (torch.from_numpy(a)[None] for a in fast_start(kernel.kernel, chw, lms))
    spectrum, gram, norm2 = kernel_spectra([kernel.kernel], (64, 64))
    with torch.no_grad():
        z = twin(2)(torch.from_numpy(lms)[None], z0, spectrum, gram, norm2, d1=d1, d2=d2)
        obj = objective_per_sample(z, torch.from_numpy(kernel.kernel).float()[None], torch.from_numpy(lms)[None])
    assert case["objective_twin"] == pytest.approx(float(obj[0]), rel=1e-3)

    text = out.read_text()
    assert "<!-- bench:unrolled -->" in text and "| twin |" in text and "| admm cold |" in text


def test_bench_unrolled_refuses_what_it_cannot_measure(exported, tmp_path, capsys):
    from vrcorrect.apps.cli import main
    from vrcorrect.studies.bench.unrolled import run_unrolled_bench

    run, _, _ = exported
    with pytest.raises(ValidationError, match="displays"):
        run_unrolled_bench(run / "unrolled.onnx", out=tmp_path / "b.md", displays=("quest2",), progress=False)
    from vrcorrect.runtime.onnx_backend import write_one_minus_x_model

    other = tmp_path / "negate.onnx"
    write_one_minus_x_model(other)                           # an ONNX file, not an unrolled model
    assert main(["bench", "unrolled", "--model", str(other), "--out", str(tmp_path / "b.md")]) == 2
    assert "not an unrolled model" in capsys.readouterr().err
    assert main(["bench", "unrolled", "--model", str(tmp_path / "none.onnx"), "--out", str(tmp_path / "b.md")]) == 2
    assert "no such model" in capsys.readouterr().err and not (tmp_path / "b.md").exists()
    v3 = _as_v3(run / "unrolled.onnx", tmp_path / "v3.onnx")  # an older format it runs: taken as unrolled,
    assert main(["bench", "unrolled", "--model", str(v3), "--eyes", "0", "--out", str(tmp_path / "b.md")]) == 2
    err = capsys.readouterr().err                            # so the next check speaks (was: "not an unrolled model")
    assert "--eyes" in err and "not an unrolled model" not in err and not (tmp_path / "b.md").exists()


# ---------------------------------------------------------------- the learned pass as the real-time cold start

def test_the_learned_pass_is_the_real_time_cold_start(exported, gl):
    """Corrector(cold_start_model=...): a cold frame starts from the model's pass (read back, run on
    onnxruntime, uploaded), and the GPU then equals its CPU twin started from the same guess; a
    warm frame does not call the model; a display the model was not trained for is refused."""
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.corrector import Corrector
    from vrcorrect.solvers.realtime import AdmmFrames
    from vrcorrect.specs.prescription import Prescription

    run, _, pool = exported
    entry = pool["held_out"][0]
    rx = Prescription(right=entry.eye, left=entry.eye)
    W, H = 56, 40
    big = np.round(dict(bundled_images(96))["astronaut"] * 255).astype(np.uint8)
    frames = [np.ascontiguousarray(big[10 + 2 * f:10 + 2 * f + H, 5 + 3 * f:5 + 3 * f + W]) for f in range(2)]
    lin = [decode("srgb", f.astype(np.float32) / 255).astype(np.float32) for f in frames]
    model = UnrolledModel(run / "unrolled.onnx")
    c = Corrector(gl, rx, "index", "right", filter="admm", precision="single", iterations_per_frame=2,
                  early_stop=False, cold_start_model=str(run / "unrolled.onnx"))
    twin = AdmmFrames(entry.eye_kernel, entry.reference_kernel, (H, W), precision="single")
    src = G.upload_texture(gl, frames[0])
    tex, fbo = G.render_target(gl, width=W, height=H)
    calls = []
    slot_run = c.strategy.cold_start
    c.strategy.cold_start = lambda t: (calls.append(t.size), slot_run(t))[1]
    try:
        c.apply(src, fbo)
        guess = model.correct(lin[0], entry.eye, entry.eye_kernel, entry.reference_kernel)
        cpu = twin.frame(lin[0], 2, cold=True, first_guess=guess)
        assert np.abs(c.solution((W, H)) - cpu.solution).max() < 1e-4
        G.write_texture(src, frames[1])
        c.apply(src, fbo, motion_px=(-3, -2))
        cpu = twin.frame(lin[1], 2, shift=(-3, -2))
        assert np.abs(c.solution((W, H)) - cpu.solution).max() < 1e-4 and calls == [(W, H)]
    finally:
        c.release()
        G.release(fbo, tex, src)
    with pytest.raises(ValidationError, match="display"):
        Corrector(gl, rx, "quest2", "right", cold_start_model=str(run / "unrolled.onnx"))
    with pytest.raises(ValidationError, match="cold_start_model"):
        Corrector(gl, rx, "index", "right", filter="fista", cold_start_model=str(run / "unrolled.onnx"))


def test_backend_onnx_runs_the_unrolled_model_alone_on_every_frame(exported, gl):
    """Corrector(backend="onnx", model=UNROLLED.onnx): each frame is the model's pass on that frame
    (no temporal state), equal to the unbound pass within a code value; an eye the model was not
    trained for is refused up front, naming the display."""
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.corrector import Corrector
    from vrcorrect.specs.display import encode
    from vrcorrect.specs.prescription import Prescription

    run, _, pool = exported
    entry = pool["held_out"][0]
    rx = Prescription(right=entry.eye, left=entry.eye)
    model = UnrolledModel(run / "unrolled.onnx")
    big = np.round(dict(bundled_images(96))["astronaut"] * 255).astype(np.uint8)
    c = Corrector(gl, rx, "index", "right", backend="onnx", model=str(run / "unrolled.onnx"))
    try:
        for f, (y, x) in enumerate([(10, 5), (30, 33)]):            # two unrelated frames
            frame = np.ascontiguousarray(big[y:y + 40, x:x + 56])
            src = G.upload_texture(gl, frame)
            tex, fbo = G.render_target(gl, width=56, height=40)
            try:
                c.apply(src, fbo)
                got = G.read_framebuffer(fbo).astype(int)
            finally:
                G.release(fbo, tex, src)
            lin = decode("srgb", frame.astype(np.float32) / 255).astype(np.float32)
            want = model.correct(lin, entry.eye, entry.eye_kernel, entry.reference_kernel)
            want = np.round(np.clip(encode("srgb", want), 0, 1) * 255).astype(int)
            assert np.abs(got - want).max() <= 1, f
            assert np.abs(got - frame.astype(int)).max() > 8              # it did correct
    finally:
        c.release()
    with pytest.raises(ValidationError, match="display"):
        Corrector(gl, rx, "quest2", "right", backend="onnx", model=str(run / "unrolled.onnx"))


def test_backend_onnx_holds_a_robust_designs_light_cap(exported, gl):
    """With a robust design (``robust=True``) the Corrector binds the unrolled model capped: light
    bars on a dark ground stay under the light cap in every pixel, where the one eye's design (no
    cap) goes past it."""
    from vrcorrect.runtime import gl as G
    from vrcorrect.runtime.corrector import Corrector
    from vrcorrect.solvers.problem import light_cap
    from vrcorrect.specs.display import encode
    from vrcorrect.specs.prescription import Prescription

    run, _, pool = exported
    entry = pool["held_out"][0]
    rx = Prescription(right=entry.eye, left=entry.eye)
    frame = np.full((40, 56, 3), 26, np.uint8)
    frame[:, 6:50:10] = 242
    lin = decode("srgb", frame.astype(np.float32) / 255).astype(np.float32)
    top = np.round(encode("srgb", light_cap(lin)) * 255).astype(int)
    over = {}
    for robust in (True, False):
        c = Corrector(gl, rx, "index", "right", backend="onnx", model=str(run / "unrolled.onnx"),
                      pupil=entry.eye.pupil_diameter_mm, robust=robust)
        src = G.upload_texture(gl, frame)
        tex, fbo = G.render_target(gl, width=56, height=40)
        try:
            c.apply(src, fbo)
            over[robust] = int((G.read_framebuffer(fbo).astype(int) - top).max())
        finally:
            G.release(fbo, tex, src)
            c.release()
    assert over[True] <= 1 and over[False] > 8


def test_render_takes_the_learned_cold_start(exported, tmp_path, capsys):
    """``vrcorrect render --cold-start MODEL``: the picture rendered through the GPU path with the
    model's pass as the first frame's start, and the log says so."""
    from PIL import Image

    from vrcorrect.apps.cli import main

    run, _, _ = exported
    src = tmp_path / "in.png"
    Image.fromarray(np.round(dict(bundled_images(48))["coffee"] * 255).astype(np.uint8)).save(src)
    out = tmp_path / "out.png"
    assert main(["render", str(src), "-o", str(out), "--display", "index", "--cold-start",
                 str(run / "unrolled.onnx"), "--frames", "2"]) == 0
    shown = np.asarray(Image.open(out))
    assert shown.shape == (48, 48, 3) and not np.array_equal(shown, np.asarray(Image.open(src)))
    assert "cold start" in capsys.readouterr().out


def test_after_a_cut_starts_each_shot_from_the_model(exported):
    """The motion suite's cut measured both ways on a short held-out cut clip: the learned start is
    called on the two cold frames (the first and the detected cut) and changes them."""
    from vrcorrect.studies.bench.unrolled import after_a_cut

    run, _, _ = exported
    cut = after_a_cut(UnrolledModel(run / "unrolled.onnx"), size=64, frames=12, display_name="index")
    scores = cut["scores"]
    assert cut["cold_frames"] == 2 and cut["clip"].cut_at == 6
    learned, default = scores["learned cold start"], scores["default (half-resolution cold start)"]
    assert np.isfinite(learned["jod"]) and learned["objective_share"] != default["objective_share"]
    assert "the twin's 2 stages as the cold start" in scores
    assert learned["frames_after_cut"] is None or 1 <= learned["frames_after_cut"] <= 6


def test_the_halving_goal_is_read_on_the_mean_gap_left_open():
    """A case past fast leaves nothing open (not a negative amount), so a model worse than its twin
    on every case can never read as halving it; by hand: (0.10 + 0 + 0.02) / 3 = 0.04."""
    from vrcorrect.studies.bench.unrolled import mean_gap_left_open

    assert mean_gap_left_open([0.90, 1.05, 0.98]) == pytest.approx(0.04)
    twin, worse = [1.04, 1.05, 0.92], [1.02, 1.03, 0.90]          # the twin past fast at the median
    assert mean_gap_left_open(twin) == pytest.approx(0.08 / 3)
    assert mean_gap_left_open(worse) > mean_gap_left_open(twin) / 2
