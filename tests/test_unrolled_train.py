"""Training the unrolled correction (vrcorrect.learn.unrolled_train): a tiny real run on real kernels,
its files, its yardstick (fast, solved here) and the config's errors."""

from __future__ import annotations

import csv
import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from vrcorrect.learn.train import objective_per_sample
from vrcorrect.learn.unrolled import twin
from vrcorrect.learn.unrolled_train import (UnrolledTrainConfig, build_fast_bank, build_pool, evaluate, fast_objectives,
                                            fast_pull, load_unrolled, make_batch, run_model, train_unrolled)
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.plumbing.images import bundled_images

CONFIG = UnrolledTrainConfig(displays=("index",), eyes_per_display=2, held_out_eyes_per_display=1, crop_px=24,
                             steps=30, batch=4, prior_width=4, stages=2, lr=5e-3)


@pytest.fixture(scope="module")
def images():
    imgs = dict(bundled_images(48))
    return [imgs["astronaut"], imgs["coffee"]], [imgs["rocket"]]


@pytest.fixture(scope="module")
def pool():
    return build_pool(CONFIG, workers=1)


def test_the_pool_holds_each_display_and_split_with_kernels_and_glasses(pool):
    assert len(pool["train"]) == 2 and len(pool["held_out"]) == 1
    train_eyes = {(e.eye.sphere_D, e.eye.cylinder_D) for e in pool["train"]}
    assert (pool["held_out"][0].eye.sphere_D, pool["held_out"][0].eye.cylinder_D) not in train_eyes
    for e in pool["train"] + pool["held_out"]:
        assert e.display == "index" and e.kernel.ndim == 4 and e.kernel.shape[:2] == (3, 3)
        assert e.reference.shape[-1] <= e.kernel.shape[-1] + 2 and e.features.shape == (5,)


def test_the_batch_target_is_what_the_eye_sees_with_glasses(pool, images):
    """make_batch's target_lms equals solvers.make_problem's (the numpy forward model) to float32."""
    from vrcorrect.solvers import make_problem
    from vrcorrect.specs.display import decode, get_display

    entry, crop = pool["train"][0], images[0][0][:24, :24]
    b = make_batch([entry], [crop])
    p = make_problem(decode(get_display("index"), crop).astype(np.float32), entry.eye_kernel, entry.reference_kernel)
    assert np.abs(b["target_lms"][0].numpy().transpose(1, 2, 0) - p.target_lms).max() < 1e-5


def test_the_batch_starts_where_fast_starts(pool):
    """make_batch's z0, d1, d2 are solvers.admm.fast_start's for each crop (here 64 px: the coarse level runs)."""
    from vrcorrect.solvers.admm import fast_start

    imgs = dict(bundled_images(64))
    crops = [imgs["astronaut"], imgs["coffee"]]
    b = make_batch(pool["train"], crops)
    for i, entry in enumerate(pool["train"]):
        z0, d1, d2 = fast_start(entry.kernel, b["target"][i].numpy(), b["target_lms"][i].numpy())
        assert np.array_equal(b["z0"][i].numpy(), z0) and np.array_equal(b["d2"][i].numpy(), d2)
        assert np.array_equal(b["d1"][i].numpy(), d1) and np.abs(d1).max() > 0


def test_a_capped_crop_has_the_light_cap_as_its_box_and_starts_where_fast_starts_under_it(pool):
    """make_batch(capped=...): the capped crops' ``upper`` is the light cap of their target, the
    others' 1, and each starts at ``fast_start(capped=...)``; the model on the batch keeps under it."""
    from vrcorrect.solvers.admm import fast_start
    from vrcorrect.solvers.problem import light_cap

    codes = np.full((64, 64, 3), 0.1)
    codes[:, 4:60:10] = 0.9                          # light bars on a dark ground: the cap binds
    b = make_batch(pool["train"], [codes, codes], capped=np.array([True, False]))
    t = b["target"].numpy()
    assert np.array_equal(b["upper"][0].numpy(), light_cap(t[0])) and np.all(b["upper"][1].numpy() == 1.0)
    for i, entry in enumerate(pool["train"]):
        z0, d1, _ = fast_start(entry.kernel, t[i], b["target_lms"][i].numpy(), capped=i == 0)
        assert np.array_equal(b["z0"][i].numpy(), z0) and np.array_equal(b["d1"][i].numpy(), d1)
    with torch.no_grad():
        shown = run_model(twin(2), b).numpy()
    assert (shown[0] - light_cap(t[0])).max() <= 1e-6 and (shown[1] - light_cap(t[1])).max() > 0.05
    assert "upper" not in make_batch(pool["train"], [codes, codes], capped=np.array([False, False]))


def test_a_run_with_a_cap_share_trains_on_that_share_of_capped_crops(tmp_path, pool, images, monkeypatch):
    import vrcorrect.learn.unrolled_train as trainer

    drawn = []
    real = trainer.make_batch

    def spy(entries, crops, capped=None):
        if capped is not None:
            drawn.append(np.asarray(capped, bool).copy())
        return real(entries, crops, capped)

    monkeypatch.setattr(trainer, "make_batch", spy)
    report = train_unrolled(tmp_path, replace(CONFIG, steps=3, cap_share=0.5), images[0], images[1], pool=pool,
                            held_out_cases=1)
    flags = np.concatenate(drawn)
    assert flags.size == 3 * CONFIG.batch and 0 < flags.sum() < flags.size          # some crops capped, not all
    assert report["config"]["cap_share"] == 0.5 and report["steps"] == 3


def test_fasts_yardstick_is_below_no_correction_and_the_twin_between(pool, images):
    cases = [(pool["held_out"][0], images[1][0][:24, :24])]
    fast = fast_objectives(cases)[0]
    b = make_batch(*zip(*cases))
    none = float(objective_per_sample(b["target"], b["kernel"], b["target_lms"])[0])
    with torch.no_grad():
        tw = float(objective_per_sample(run_model(twin(2), b), b["kernel"], b["target_lms"])[0])
    assert fast < tw < none


def test_a_short_run_writes_its_files_and_beats_its_twin_on_what_it_trained(tmp_path, pool, images):
    report = train_unrolled(tmp_path, CONFIG, images[0], images[1], pool=pool, held_out_cases=3)
    assert report["steps"] == 30
    assert {p.name for p in tmp_path.iterdir()} == {"unrolled.pt", "log.csv", "report.json", "checkpoint.pt"}
    rows = list(csv.DictReader((tmp_path / "log.csv").open()))
    assert len(rows) == 30 and all(np.isfinite(float(r["loss"])) for r in rows)
    saved = json.loads((tmp_path / "report.json").read_text())
    assert saved["share_of_fast_gain"]["twin"]["median"] == pytest.approx(report["share_of_fast_gain"]["twin"]["median"])
    model = load_unrolled(tmp_path / "unrolled.pt")
    # on training crops the learned stages do better than the same stages untrained
    rng = np.random.default_rng(5)
    crops = [images[0][i % 2][y:y + 24, x:x + 24] for i, (y, x) in enumerate(rng.integers(0, 24, (8, 2)))]
    b = make_batch([pool["train"][i % 2] for i in range(8)], crops)
    with torch.no_grad():
        learned = objective_per_sample(run_model(model, b), b["kernel"], b["target_lms"]).mean()
        untrained = objective_per_sample(run_model(twin(2), b), b["kernel"], b["target_lms"]).mean()
    assert learned < untrained


def test_evaluate_reports_the_twin_as_the_untrained_model(pool, images):
    from vrcorrect.learn.unrolled import UnrolledADMM, UnrolledConfig

    cases = [(pool["held_out"][0], images[1][0][:24, :24])]
    model = UnrolledADMM(UnrolledConfig(stages=2, prior_width=4, features=5))
    result = evaluate(model, cases, fast_objectives(cases))
    assert result["learned"]["cases"] == result["twin"]["cases"]


@pytest.mark.parametrize("field, value", [("stages", 0), ("crop_px", 8), ("minutes", 0), ("lr", 2.0),
                                          ("displays", ()), ("batch", True), ("box_floor", 0.0), ("box_floor", 2.0),
                                          ("cap_share", -0.1), ("cap_share", 1.5), ("cap_share", True)])
def test_bad_configs_name_the_field(field, value):
    with pytest.raises(ValidationError, match=field):
        UnrolledTrainConfig(**{field: value})


def test_an_unknown_display_is_refused_by_name():
    with pytest.raises(ValidationError, match="nosuch"):
        UnrolledTrainConfig(displays=("nosuch",))


def test_a_file_that_is_not_a_checkpoint_is_refused(tmp_path):
    path = tmp_path / "x.pt"
    torch.save({"hello": 1}, path)
    with pytest.raises(ValidationError, match="checkpoint"):
        load_unrolled(path)


def _cli_error(args, capsys):
    from vrcorrect.apps.cli import main

    assert main(["unroll", *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("vrcorrect: error:")
    return err


def test_the_command_refuses_before_any_work(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    assert "not a folder" in _cli_error(["-o", str(tmp_path / "file")], capsys)
    run = tmp_path / "run"
    run.mkdir()
    (run / "unrolled.pt").write_text("mine")
    assert "--force" in _cli_error(["-o", str(run)], capsys)
    assert (run / "unrolled.pt").read_text() == "mine"
    assert "stages" in _cli_error(["-o", str(run), "--stages", "0", "--force"], capsys)
    assert "crop" in _cli_error(["-o", str(tmp_path / "new"), "--crop-px", "400"], capsys)   # > --image-px 320
    assert "fast_weight" in _cli_error(["-o", str(tmp_path / "new"), "--fast-weight", "-1"], capsys)
    err = _cli_error(["-o", str(tmp_path / "new"), "--box-floor", "2"], capsys)
    assert "box_floor" in err and "2" in err and "0.001 to 1" in err
    assert not (tmp_path / "new").exists()
    (run / "checkpoint.pt").write_text("a run's state")           # an earlier run stopped: continue or start over
    err = _cli_error(["-o", str(run)], capsys)
    assert "--resume" in err and "--force" in err
    assert "--resume" in _cli_error(["-o", str(run), "--resume", "--force"], capsys)


def test_the_command_trains_reports_and_exports(tmp_path, capsys, monkeypatch):
    """A new user's run as the README writes it (``unroll -o runs/NAME``: the folders are made), tiny:
    kernels, training, the held-out report and an ONNX file that ``correct --method learned`` can use;
    progress on standard error though it is not a terminal; a checkpoint ``--resume`` continues."""
    from vrcorrect.apps.cli import main
    from vrcorrect.runtime.unrolled import UnrolledModel

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("VRCORRECT_PROGRESS_S", "0.2")            # lines within this short run, whatever the machine
    args = ["--displays", "index", "--eyes-per-display", "1", "--steps", "3", "--crop-px", "24", "--image-px", "48",
            "--stages", "1", "--prior-width", "4"]
    assert main(["unroll", "-o", "runs/x", *args]) == 0
    run = tmp_path / "runs" / "x"
    captured = capsys.readouterr()
    out, err = captured.out, captured.err
    assert "trained 3 steps" in out and "its untrained twin" in out and "unrolled.onnx" in out
    assert {p.name for p in run.iterdir()} == {"unrolled.pt", "log.csv", "report.json", "unrolled.onnx",
                                               "checkpoint.pt", "pool.pickle"}
    assert UnrolledModel(run / "unrolled.onnx").displays == ["index"]
    assert "unroll: run folder runs/x" in out and "checkpoint" in out
    # not a terminal: a line every interval, and a word while the model is judged after its last step
    assert "unroll: kernels: 3 eyes in" in err and "unroll: training: " in err, err[-3000:]
    log = (run / "log.csv").read_text()
    assert main(["unroll", "-o", "runs/x", *args, "--resume"]) == 0          # nothing left: the same model again
    assert "trained 3 steps" in capsys.readouterr().out
    assert (run / "log.csv").read_text() == log


def test_the_pull_towards_fast_is_zero_at_fast_and_one_at_the_target():
    rng = np.random.default_rng(0)
    target, fast = (torch.from_numpy(rng.random((2, 3, 8, 8), dtype=np.float32)) for _ in range(2))
    assert torch.allclose(fast_pull(fast, fast, target), torch.zeros(2))
    assert torch.allclose(fast_pull(target, fast, target), torch.ones(2))
    assert (fast_pull(0.5 * (fast + target), fast, target) - 0.25).abs().max() < 1e-6


def test_a_run_pulled_towards_fast_ends_nearer_fast_on_its_bank(tmp_path, pool, images):
    """With a pull towards fast's solution, the crops come from a bank solved before training (each
    solution is fast's: its objective is the yardstick's), and the trained model ends nearer fast on
    them than the same run without the pull."""
    pulled = replace(CONFIG, fast_weight=20.0, fast_bank=4)
    bank = build_fast_bank(pulled, pool, images[0])
    assert len(bank) == 4 and all(x.shape == (3, 24, 24) for _, _, x in bank)
    e, crop, x = bank[0]
    assert fast_objectives([(pool["train"][e], crop)])[0] == pytest.approx(
        float(objective_per_sample(torch.from_numpy(x)[None], *[make_batch([pool["train"][e]], [crop])[k]
                                                               for k in ("kernel", "target_lms")])[0]), rel=1e-6)
    report = train_unrolled(tmp_path / "pulled", pulled, images[0], images[1], pool=pool, held_out_cases=2, bank=bank)
    assert report["config"]["fast_weight"] == 20.0 and report["config"]["fast_bank"] == 4
    plain = train_unrolled(tmp_path / "plain", CONFIG, images[0], images[1], pool=pool, held_out_cases=2)
    assert plain["config"]["fast_weight"] == 0.0
    b = make_batch([pool["train"][e] for e, _, _ in bank], [c for _, c, _ in bank])
    fast = torch.from_numpy(np.stack([x for _, _, x in bank]))
    with torch.no_grad():
        near = {name: float(fast_pull(run_model(load_unrolled(tmp_path / name / "unrolled.pt"), b), fast,
                                      b["target"]).mean()) for name in ("pulled", "plain")}
    assert near["pulled"] < near["plain"], near


def test_a_bad_fast_weight_is_refused_by_name():
    for value in (-1.0, 1001.0, True, "1"):
        with pytest.raises(ValidationError, match="fast_weight"):
            UnrolledTrainConfig(fast_weight=value)
    with pytest.raises(ValidationError, match="fast_bank"):
        UnrolledTrainConfig(fast_bank=0)


def test_a_stopped_run_resumed_from_its_checkpoint_ends_as_an_unstopped_one(tmp_path, pool, images):
    """The training's state (weights, optimiser, schedule, random streams, log) is checkpointed; a run
    stopped after 10 steps and resumed ends with the weights of one never stopped."""
    import torch

    config = replace(CONFIG, steps=16)
    train_unrolled(tmp_path / "whole", config, images[0], images[1], pool=pool, held_out_cases=2)

    def stop_at_ten(step: int, loss: float) -> None:
        if step == 10:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train_unrolled(tmp_path / "parts", config, images[0], images[1], pool=pool, held_out_cases=2,
                       progress=stop_at_ten, checkpoint_every_s=0.0)
    assert torch.load(tmp_path / "parts" / "checkpoint.pt", weights_only=False)["step"] == 10
    assert not (tmp_path / "parts" / "unrolled.pt").exists()
    report = train_unrolled(tmp_path / "parts", config, images[0], images[1], pool=pool, held_out_cases=2,
                            resume=True)
    assert report["steps"] == 16
    whole = load_unrolled(tmp_path / "whole" / "unrolled.pt").state_dict()
    parts = load_unrolled(tmp_path / "parts" / "unrolled.pt").state_dict()
    assert whole.keys() == parts.keys() and all(torch.equal(whole[k], parts[k]) for k in whole)
    logged = [line.split(",")[:2] for line in (tmp_path / "parts" / "log.csv").read_text().splitlines()]
    assert logged == [line.split(",")[:2] for line in (tmp_path / "whole" / "log.csv").read_text().splitlines()]
    with pytest.raises(ValidationError, match="same configuration"):
        train_unrolled(tmp_path / "parts", replace(config, seed=1), images[0], images[1], pool=pool,
                       held_out_cases=2, resume=True)
