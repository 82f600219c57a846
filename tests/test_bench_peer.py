"""``vrcorrect bench cost --peer torch``: the default frame written plainly in torch (run here on the
CPU) equals the CPU twin ``AdmmFrames(precision="single")``; where torch sees no CUDA device the peer is
not run and the command says exactly so; and the one frame-timing routine both benches share."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vrcorrect.physics.kernel import build_kernel, build_reference_kernel
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.solvers.realtime import AdmmFrames
from vrcorrect.specs.display import get_display
from vrcorrect.specs.prescription import EyeRx


EYE = EyeRx(sphere_D=-2.0, cylinder_D=-1.0, axis_deg=120.0, pupil_diameter_mm=4.0)


@pytest.mark.parametrize("reference", ["glasses", "ideal"])
def test_the_torch_peer_equals_the_cpu_twin_frame_by_frame(reference):
    """Five frames of changing content (the first cold, then the warm start carried over), k = 2 and
    on the last two frames k = 3: the frame shown, the guard's weight and its objective equal the
    single-precision twin's (no half-resolution cold start) to 1e-5, 1e-5 and 1e-5 relative."""
    from vrcorrect.studies.bench.peer import TorchAdmmPeer

    d = get_display("quest2")
    K = build_kernel(EYE, d)
    R = build_reference_kernel(EYE, d) if reference == "glasses" else None
    H, W = 40, 56
    twin = AdmmFrames(K, R, (H, W), precision="single", cold_iterations=0)
    peer = TorchAdmmPeer(K, R, (H, W), torch.device("cpu"))
    assert peer.grid == twin.grid
    rng = np.random.default_rng(7)
    base = rng.random((H, W, 3), dtype=np.float32)
    for f in range(5):
        target = np.clip(base + 0.05 * f + 0.1 * rng.random((H, W, 3), dtype=np.float32), 0, 1).astype(np.float32)
        k = 2 if f < 3 else 3
        want = twin.frame(target, k)
        shown, beta, objective = peer.frame(torch.from_numpy(np.ascontiguousarray(np.moveaxis(target, 2, 0))), k)
        assert np.abs(np.moveaxis(shown.numpy(), 0, 2) - want.shown).max() <= 1e-5, f
        assert abs(float(beta) - want.beta) <= 1e-5, f
        assert float(objective) == pytest.approx(want.objective, rel=1e-5), f
        assert want.beta > 0                                   # the correction is used: a real comparison


def test_without_a_cuda_device_the_peer_is_not_run_and_says_so(monkeypatch, tmp_path, capsys):
    """With torch seeing no CUDA device: the timing returns the status, the bench's report and table
    say "no CUDA device: peer not run", and the command prints exactly that line; an unknown peer is
    refused naming --peer."""
    from vrcorrect.apps.cli import main
    from vrcorrect.studies.bench.peer import NO_DEVICE, time_torch_peer

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert NO_DEVICE == "no CUDA device: peer not run"
    K = build_kernel(EYE, get_display("quest2"))
    assert time_torch_peer(K, None, (64, 48), 2, 2, 0.0)["status"] == NO_DEVICE
    js = tmp_path / "cost.json"
    assert main(["bench", "cost", "--size", "64x48", "--dry-run", "--default-only", "--peer", "torch", "--no-write",
                 "--json", str(js)]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[-1] == NO_DEVICE
    assert f"--peer torch`)**: {NO_DEVICE}." in out
    import json
    report = json.loads(js.read_text())
    assert report["peer"]["status"] == NO_DEVICE and [m["method"] for m in report["methods"]] == ["admm (default)"] * 2
    assert main(["bench", "cost", "--size", "64x48", "--dry-run", "--peer", "jax", "--no-write"]) == 2
    err = capsys.readouterr().err
    assert "--peer" in err and "torch" in err


def test_both_benches_time_frames_by_one_routine_interleaved_in_rounds():
    """The frame-timing routine (bench cost with one subject, bench workgroups with several): after
    the warm-up, rounds of changing then cold frames per subject, two untimed frames before each run
    of timed ones, the order reversed every other round; a cold frame is reset before it; each timed
    frame's GPU time is the timer query's."""
    from vrcorrect.studies.bench.frame_timing import Subject, time_frames

    log: list[tuple[str, int, bool]] = []

    class Query:
        elapsed = 2_000_000                                # 2 ms in ns

        def __enter__(self):
            log.append(("query", -1, False))

        def __exit__(self, *exc):
            return False

    class Ctx:
        def query(self, time):
            return Query()

        def finish(self):
            pass

    resets = [False, False]

    def subject(i: int) -> Subject:
        def apply():
            log.append(("apply", i, resets[i]))
            resets[i] = False

        def reset():
            resets[i] = True

        return Subject(apply=apply, picture=lambda n: None, reset=reset)

    results = time_frames(Ctx(), [subject(0), subject(1)], frames=7, warm_up_s=0.0, per_round=5, untimed=2)
    applies = [(i, cold) for kind, i, cold in log if kind == "apply"]
    timed = [log[j + 1][1:] for j, e in enumerate(log) if e[0] == "query"]
    # round 1: subject 0 then 1 (5 timed); round 2 reversed (2 timed); each kind: 2 untimed first
    expected = []
    for order, n in (((0, 1), 5), ((1, 0), 2)):
        for i in order:
            for cold in (False, True):
                expected += [(i, cold)] * (2 + n)
    assert applies == expected
    assert len(timed) == 2 * 2 * 7
    for r in results:
        assert len(r["changing"].gpu_ms) == len(r["cold"].gpu_ms) == 7
        assert r["changing"].gpu_median == 2.0 and r["changing"].wall_median >= 0
    with pytest.raises(ValidationError):
        from vrcorrect.studies.bench.cost import check_frames
        check_frames(0)
