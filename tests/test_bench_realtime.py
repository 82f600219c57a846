"""``vrcorrect bench realtime`` at a tiny size: the clips, the twins frame after frame (a cold start
at a detected cut, the guard never losing, the default converging on a still view), the scores and
a quick run that writes its section and plots.  Behaviour only; timings are the bench's business."""

from __future__ import annotations

import numpy as np
import pytest

from vrcorrect.studies.bench.realtime import (
    Run, floor_and_ceiling, frames_to_within, make_case, run_clip, run_realtime_bench, score_clip, still_convergence,
)
from vrcorrect.studies.bench.sequences import SEQUENCES, BenchClip, held_out, suite
from vrcorrect.solvers.realtime import frames_twin

SIZE, FRAMES = 48, 8


@pytest.fixture(scope="module")
def case():
    return make_case()


@pytest.fixture(scope="module")
def clips():
    return {c.name: c for c in suite(SIZE, FRAMES)}


def test_the_suite_and_the_held_out_clips(gl, clips):
    assert tuple(clips) == tuple(n for n in SEQUENCES if n != "head turn")       # the demo scene needs GL
    with_scene = suite(SIZE, 3, gl, ("head turn",))
    assert len(with_scene[0].frames) == 3 and with_scene[0].frames[0].shape == (SIZE, SIZE, 3)
    assert not np.array_equal(with_scene[0].frames[0], with_scene[0].frames[2])  # the head turns
    for c in clips.values():
        assert len(c.frames) == FRAMES and all(f.shape == (SIZE, SIZE, 3) and f.dtype == np.uint8 for f in c.frames)
    assert all(np.array_equal(f, clips["still"].frames[0]) for f in clips["still"].frames)
    text = clips["text"].frames
    np.testing.assert_array_equal(text[1][:-2], text[0][2:])                      # scrolls up 2 px a frame
    assert clips["cut"].cut_at == FRAMES // 2
    held = held_out(SIZE, FRAMES)
    assert [c.name for c in held] == ["sprite", "text", "cut"]
    for mine, other in zip((clips["sprite"], clips["text"], clips["cut"]), held):
        assert not np.array_equal(mine.frames[0], other.frames[0])               # other pictures, other words


def test_a_cut_starts_cold_and_the_guard_never_loses(case, clips):
    cut = clips["cut"]
    none, fast = floor_and_ceiling(case, cut, keep_shown=False)
    run = run_clip(case, cut, "admm", 2, keep_shown=False)
    assert all(o <= n * (1 + 1e-6) for o, n in zip(run.objective, none.objective))
    fresh = frames_twin("admm", case.kernel, case.reference, (SIZE, SIZE))
    from vrcorrect.studies.bench.realtime import linear

    first_after = fresh.frame(linear(cut.frames[cut.cut_at]), 2)
    assert run.objective[cut.cut_at] == pytest.approx(first_after.objective, rel=1e-6)   # cold, like a fresh start
    assert frames_to_within([3.0, 2.0, 1.04, 1.0], [1.0] * 4) == 3
    assert frames_to_within([3.0, 2.0, 1.04], [1.0] * 3, start=1) == 2
    assert frames_to_within([3.0], [1.0]) is None


def test_the_default_converges_on_a_still_view(case, clips):
    still = still_convergence(case, clips["still"], 6)
    for label, series in still["series"].items():
        assert series[0] < still["none_ratio"], label
        assert all(b <= a * (1 + 1e-3) for a, b in zip(series, series[1:])), (label, series)
    d, k1 = still["series"]["admm k=2 (default)"], still["series"]["admm k=1"]
    assert all(a < b for a, b in zip(d, k1))                                      # more iterations, lower


def test_scores_are_shares_of_fasts_gain(case, clips):
    clip = BenchClip("x", clips["sprite"].frames[:3])
    none, fast = floor_and_ceiling(case, clip, keep_shown=False)
    half = Run([(n + f) / 2 for n, f in zip(none.objective, fast.objective)])
    s = score_clip(case, clip, {"none": none, "fast": fast, "half way": half}, with_jod=False)
    assert s["none"]["objective_share"] == pytest.approx(0.0) and s["fast"]["objective_share"] == pytest.approx(1.0)
    assert s["half way"]["objective_share"] == pytest.approx(0.5) and s["half way"]["jod"] is None


def test_a_quick_run_writes_its_section_and_plots(tmp_path):
    out = tmp_path / "benchmarks.md"
    body = run_realtime_bench(out=out, write=True, quick=True)
    text = out.read_text()
    assert "<!-- bench:realtime -->" in text and "<!-- /bench:realtime -->" in text
    for words in ("Still image", "motion suite", "| sprite |", "| text |", "| cut |", "| zoom |", "| head turn |",
                  "admm k=2 (default)", "fista k=4", "llvmpipe", "GPU check", "bench cost"):
        assert words in body, words
    for name in ("realtime_still.png", "realtime_motion.png"):
        assert (tmp_path / name).stat().st_size > 1000
