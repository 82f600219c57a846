"""``vrcorrect bench cost``: a frame's cost counted from its dispatches, the issue's target held at a
Quest 2 eye's size, and the command's output and errors."""

from __future__ import annotations

import json

import pytest

from vrcorrect.runtime.dispatch import BANDWIDTHS
from vrcorrect.studies.bench.cost import (REFERENCE_RUNS, TARGET_BYTES, _measured_sentence, efficiency_source,
                                          eye_frame_cost, parse_size)
from vrcorrect.plumbing.errors import ValidationError
from vrcorrect.specs.display import get_display
from vrcorrect.specs.prescription import bundled_sample_path, load_prescription


def test_the_default_frame_of_a_quest2_eye_moves_at_most_2_gb(gl):
    """Counted (not run: the count does not depend on the pixels) for both eyes of the sample
    prescription at 1832 x 1920: the default's changing-content frame is within the target, in
    k + 2 round trips; a Quest 3 eye (2064 x 2208) costs at most 1.5x as much; and a real run at a
    small size counts the same passes as a dry run."""
    rx = load_prescription(bundled_sample_path())
    display = get_display("quest2")
    quest2 = 0
    for eye in ("left", "right"):
        cost = eye_frame_cost(gl, rx, display, eye, (1832, 1920), {}, warmup=1, dry_run=True)
        quest2 = max(quest2, cost.changing.bytes)
        assert cost.changing.bytes <= TARGET_BYTES, (eye, cost.changing.bytes)
        assert cost.changing.fft_round_trips == cost.describe["iterations_per_frame"] + 2
        # the cold frame: the same passes plus the coarse level's (15 iterations at a quarter of the
        # pixels, plus its target), so between one and two and a half changing frames
        coarse = [r for r in cost.cold.records if r.stage == "cold start"]
        assert sum(r.round_trip for r in coarse) == cost.describe["cold_iterations"] + 1
        assert cost.changing.bytes < cost.cold.bytes < 2.5 * cost.changing.bytes, (eye, cost.cold.bytes)
    # a Quest 3 eye, 1.30x the pixels: at most 1.5x the bytes (a power-of-two grid made it 4096 x 4096,
    # four times the work, and its passes did not link)
    quest3 = eye_frame_cost(gl, rx, get_display("quest3"), "right", (2064, 2208), {}, warmup=1, dry_run=True)
    assert quest3.grid is not None and max(quest3.grid) < 4096
    assert quest3.changing.bytes <= 1.5 * quest2, (quest3.changing.bytes, quest2)
    dry = eye_frame_cost(gl, rx, display, "right", (64, 48), {}, warmup=1, dry_run=True)
    real = eye_frame_cost(gl, rx, display, "right", (64, 48), {}, warmup=1)
    assert [(r.name, r.bytes) for r in dry.changing.records] == [(r.name, r.bytes) for r in real.changing.records]
    assert real.frame_ms is not None and dry.frame_ms is None
    assert real.cold_ms is not None and dry.cold_ms is None and len(real.frame_times_ms) == 1


def test_timed_frames_time_every_pass_of_the_frame(gl):
    """``--frames``: each pass of the changing frame has a measured time (a glFinish around each),
    the cold frames are timed after a reset (the coarse level's passes run then), and the count of
    the changing frame is the same as with one timed frame."""
    rx = load_prescription(bundled_sample_path())
    display = get_display("quest2")
    one = eye_frame_cost(gl, rx, display, "right", (64, 48), {}, warmup=1)
    three = eye_frame_cost(gl, rx, display, "right", (64, 48), {}, warmup=1, frames=3)
    assert len(three.frame_times_ms) == 3 and all(t > 0 for t in three.frame_times_ms)
    assert {r.name for r in three.changing.records} <= set(three.pass_ms)
    assert all(v > 0 for v in three.pass_ms.values())
    assert three.gpu_ms is not None and 0 < three.gpu_ms <= 1.5 * max(three.frame_times_ms)
    assert [(r.name, r.bytes) for r in one.changing.records] == [(r.name, r.bytes) for r in three.changing.records]
    with pytest.raises(ValidationError, match="--frames"):
        eye_frame_cost(gl, rx, display, "right", (64, 48), {}, frames=0)


def test_fista_costs_more_than_the_default_by_its_round_trips(gl):
    rx = load_prescription(bundled_sample_path())
    display = get_display("quest2")
    admm = eye_frame_cost(gl, rx, display, "right", (256, 256), {}, warmup=1, dry_run=True)
    fista = eye_frame_cost(gl, rx, display, "right", (256, 256), {"filter": "fista"}, warmup=1, dry_run=True)
    assert fista.changing.fft_round_trips == 2 * 4 + 3 and admm.changing.fft_round_trips == 2 + 2
    assert fista.changing.bytes > 4 * admm.changing.bytes


def test_bench_cost_command_prints_writes_and_refuses_bad_input(tmp_path, capsys):
    from vrcorrect.apps.cli import main

    out, js = tmp_path / "bench.md", tmp_path / "cost.json"
    assert main(["bench", "cost", "--size", "64x48", "--dry-run", "--out", str(out), "--json", str(js)]) == 0
    printed = capsys.readouterr().out
    assert "GB per eye frame" in printed and "projection" in printed and "admm (default)" in printed
    report = json.loads(js.read_text())
    assert report["size"] == [64, 48] and report["dry_run"] is True
    assert {"dispatches", "fft_round_trips", "bytes_per_eye_frame"} <= set(report["default"])
    assert set(report["methods"][0]["projected_ms"]) == {"RTX 3060", "RTX 4090", "H100 SXM"}
    assert report["methods"][0]["grid"] == report["default"]["grid"] and len(report["default"]["grid"]) == 2
    # projected from the last measured efficiency (llvmpipe is no GPU), not from peak bandwidth
    eff = REFERENCE_RUNS[-1].efficiency
    assert report["projection"]["this_run"] is False and report["projection"]["efficiency"] == eff
    row = report["methods"][0]
    for gpu, (bw, _) in BANDWIDTHS.items():
        assert row["projected_ms"][gpu] == pytest.approx(1e3 * row["bytes_per_eye_frame"] / (bw * eff))
        assert row["projected_ms"][gpu] > 10 * row["peak_bound_ms"][gpu]
    assert "projections, not measurements" in printed and "NVIDIA H200, 2026-11-27" in printed
    assert "<!-- bench:cost -->" in out.read_text()
    assert main(["bench", "cost", "--size", "64x48", "--dry-run", "--out", str(out), "--json", str(js)]) == 2
    assert "--force" in capsys.readouterr().err                       # the JSON is not overwritten
    for args, words in ((["--size", "64"], "--size"), (["--size", "8x8"], "--size"),
                        (["--json", str(tmp_path / "x.txt")], "--json"), (["--frames", "0"], "--frames"),
                        (["--frames", "1001"], "--frames")):
        assert main(["bench", "cost", "--dry-run", "--no-write", *args]) == 2
        err = capsys.readouterr().err
        assert err.startswith("vrcorrect: error:") and words in err and err.count("\n") == 1, err


def test_parse_size():
    assert parse_size("1832x1920") == (1832, 1920)
    with pytest.raises(ValidationError, match="WxH"):
        parse_size("4097x16")


def test_a_measurement_on_a_projected_gpu_is_set_beside_its_projection():
    """The H100 measured 2026-11-26 (6.73 ms per eye for 1.79 GB) is 13x its peak-bandwidth
    projection (0.53 ms); a software renderer and another card get no such comparison."""
    d = {"measured_ms_per_eye_frame": 6.73, "measured_cold_ms_per_eye_frame": 12.51,
         "measured_gpu_ms_per_eye_frame": 5.97, "bytes_per_eye_frame": 1_788_414_216}
    h100 = _measured_sentence(d, "NVIDIA H100 80GB HBM3/PCIe/SSE2")
    assert "13.46 ms" in h100 and "121 %" in h100 and "13x the 0.53 ms per eye projected for H100 SXM" in h100
    assert "projected for" not in _measured_sentence(d, "NVIDIA H100 PCIe/PCIe/SSE2")
    software = _measured_sentence(d, "llvmpipe (LLVM 15.0.6, 256 bits)")
    assert "not a GPU" in software and "projected for" not in software
    assert _measured_sentence({**d, "measured_ms_per_eye_frame": None}, "llvmpipe") == ""


def test_projections_use_the_measured_efficiency_of_this_run_or_the_last_gpu_run():
    """The H200's run of 2026-11-27 (1.79 GB in 6.10 ms of GPU time, 4.8 TB/s peak) reached 6.1 % of
    its peak: the RTX 3060 projection is then 1.79 GB at 6.1 % of 360 GB/s, 81 ms per eye, where its
    peak bandwidth alone said 5.0 ms.  A run on an H100 uses its own efficiency; a software renderer
    or an unknown card the last GPU run's."""
    last = REFERENCE_RUNS[-1]
    assert last.card == "NVIDIA H200" and last.efficiency == pytest.approx(0.0611, abs=5e-4)
    assert 1e3 * last.bytes_ / (BANDWIDTHS["RTX 3060"][0] * last.efficiency) == pytest.approx(81.3, abs=0.5)
    llvmpipe = efficiency_source("llvmpipe (LLVM 15.0.6, 256 bits)", 10 ** 9, 500.0)
    assert llvmpipe["efficiency"] == last.efficiency and not llvmpipe["this_run"] and "H200" in llvmpipe["source"]
    h100 = efficiency_source("NVIDIA H100 80GB HBM3/PCIe/SSE2", 1_000_000_000, 2.0)
    assert h100["this_run"] and h100["efficiency"] == pytest.approx(1e9 / 2e-3 / 3.35e12)
    assert "this run" in h100["source"] and "H100" in h100["source"]
    h200 = efficiency_source("NVIDIA H200/PCIe/SSE2", 1_000_000_000, 2.0)
    assert h200["efficiency"] == pytest.approx(1e9 / 2e-3 / 4.8e12)
    assert not efficiency_source("NVIDIA H100 PCIe/PCIe/SSE2", 10 ** 9, 2.0)["this_run"]      # another card
    assert not efficiency_source("NVIDIA H200", 10 ** 9, None)["this_run"]                      # not timed
