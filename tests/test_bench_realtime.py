"""``vrcorrect bench realtime``'s accounting at a tiny size (48x48, a few frames): the warm start
converges on a still image, reprojection beats the plain warm start on a pan, phase correlation
finds the pan's shift, the guard never loses, the cost model counts what the shaders run, and a
quick run writes its section and plots.  Behaviour only; timings are the bench's business."""

from __future__ import annotations

import numpy as np
import pytest

from vrcorrect.apps.bench.realtime import (
    CUT, FFT_BANDWIDTH, cost_model, cut_targets, guarded, make_case, motion_sequence, pan_sequence,
    phase_correlation_shift, reproject, round_trip_bytes, run_realtime_bench, still_convergence, zoom_targets,
)

SIZE, FRAMES = 48, 5


@pytest.fixture(scope="module")
def case():
    return make_case(SIZE, FRAMES)


def test_still_warm_start_falls_over_frames_toward_fast(case):
    still = still_convergence(case, (1, 4), FRAMES, with_jod=False)
    for k, series in still["series"].items():
        obj = series.objective
        assert obj[0] < still["none"], k                                   # better than uncorrected at once
        assert all(b < a for a, b in zip(obj, obj[1:])), (k, obj)           # and better every frame
        assert series.ratio == pytest.approx([o / still["fast"] for o in obj])
    # k = 4 per frame is k = 1 per frame four times as fast: frame n at k = 4 beats frame n at k = 1
    assert all(a < b for a, b in zip(still["series"][4].objective, still["series"][1].objective))


def test_pan_reprojection_beats_the_plain_warm_start_and_finds_the_shift(case):
    pan = pan_sequence(case, FRAMES, k=4, px=2, with_jod=False)
    assert pan["shifts"] == [(0, -2)] * (FRAMES - 1)                      # content moves 2 px left
    s = pan["series"]
    assert s["estimated"].objective == s["reprojected"].objective         # the estimate is the known shift
    for f in range(FRAMES):
        for strategy, series in s.items():
            assert series.objective[f] < pan["none"][f], (strategy, f)    # the guard: never worse
    assert s["cold"].objective[0] == s["warm"].objective[0] == s["reprojected"].objective[0]
    for f in range(2, FRAMES):
        assert s["reprojected"].ratio[f] < s["warm"].ratio[f] < s["cold"].ratio[f], f


def test_a_cut_starts_cold_and_a_zoom_has_no_known_shift(case):
    """The clip with a cut: phase correlation sees the cut, and both reprojected runs start that
    frame cold (the cold run's objective exactly); a zoom runs without the known-shift strategy."""
    images, cut_at = cut_targets(case, FRAMES)
    known = [(0, -2)] * (FRAMES - 1)
    known[cut_at - 1] = CUT
    run = motion_sequence(case, images, known, k=4, with_jod=False)
    assert run["shifts"][cut_at - 1] is None
    assert [d for i, d in enumerate(run["shifts"]) if i != cut_at - 1] == [(0, -2)] * (FRAMES - 2)
    s = run["series"]
    for strategy in ("reprojected", "estimated"):
        assert s[strategy].objective[cut_at] == s["cold"].objective[cut_at], strategy
    for f in range(FRAMES):
        assert all(series.objective[f] < run["none"][f] for series in s.values()), f
    zoom = motion_sequence(case, zoom_targets(case, 3), None, k=2, with_jod=False)
    assert set(zoom["series"]) == {"cold", "warm", "estimated"}


def test_reproject_and_guard_helpers(case):
    rng = np.random.default_rng(0)
    image = rng.random((3, 6, 8), dtype=np.float32)
    fill = np.full((6, 8, 3), 0.5, np.float32)
    moved = reproject(image, fill, (1, -2))
    np.testing.assert_array_equal(moved[:, 1:, :6], image[:, :5, 2:])
    assert (moved[:, 0] == 0.5).all() and (moved[:, :, 6:] == 0.5).all()
    a = rng.random((32, 32, 3))
    b = np.roll(a, (3, -5), axis=(0, 1))
    assert phase_correlation_shift(a, b) == (3, -5)
    p = case.problem(case.still_u8)
    shown, obj, beta = guarded(np.zeros_like(p.target), p)                  # black: a bad solution
    none = guarded(p.target, p)[1]
    assert 0.0 <= beta <= 1.0 and obj <= none
    assert np.abs(shown - (p.target * (1 - beta))).max() < 1e-6


def test_cost_model_counts_the_round_trips_and_bytes():
    rows = cost_model((1, 2, 4), size=(1832, 1920), margin=40)
    for r in rows:
        assert r["grid"] == (2048, 2048)
        assert r["round_trips"] == (2 * r["k"] + 3 if r["form"] == "phase A" else r["k"] + 3)
        assert r["fft2d"] == 4 * r["round_trips"]
        assert r["ms"] == pytest.approx(r["GB"] * 1e9 / (FFT_BANDWIDTH["GBps"] * 1e9) * 1e3)
    for form in ("phase A", "Gram"):
        gb = [r["GB"] for r in rows if r["form"] == form]
        assert gb == sorted(gb) and len(set(gb)) == 3
    n, p = 2048 * 2048, 1832 * 1920
    # every FFT pass reads and writes two complex64 layers; the multiply also reads the 3x3 spectrum
    assert round_trip_bytes((2048, 2048), (1832, 1920), 0) == 16 * p + 16 * n * 8 + 72 * n + 16 * p


def test_a_quick_run_writes_its_section_and_plots(tmp_path):
    out = tmp_path / "benchmarks.md"
    body = run_realtime_bench(out=out, write=True, quick=True)
    text = out.read_text()
    assert "<!-- bench:realtime -->" in text and "<!-- /bench:realtime -->" in text
    for words in ("Still image", "Moving sequences", "| pan |", "| zoom |", "| cut |", "| head turn |", "llvmpipe",
                  "projection, not a measurement", "GPU check", FFT_BANDWIDTH["gpu"]):
        assert words in body, words
    for name in ("realtime_still.png", "realtime_motion.png"):
        assert (tmp_path / name).stat().st_size > 1000
