"""The frame budget on the real renderer (``CorrectorOptions(budget_ms=...)``, ``--budget-ms``; issue 45):
the Corrector times its own frames with GL timestamps (two frames late) and holds them at the budget,
scaled here to llvmpipe (between one and four iterations' time), while the content changes every
frame and the shot is cut; with a fovea whose one iteration overruns the budget, the window shrinks.
(The controller alone, on synthetic renderers: ``tests/test_budget.py``.)"""

from __future__ import annotations

import statistics

import numpy as np
import pytest

from vrcorrect.runtime import gl as G
from vrcorrect.runtime.budget import GpuTimer
from vrcorrect.runtime.corrector import Corrector
from vrcorrect.specs.prescription import EyeRx, Prescription

EYE = EyeRx(sphere_D=-2.0, cylinder_D=-1.0, axis_deg=120.0, pupil_diameter_mm=4.0)
SIZE = 128
BAND = 0.15                                   # issue 45: within +-15 % of the budget (tests/test_budget.py)


def _trimmed_mean(times: list[float]) -> float:
    """The mean without the one slowest and the one fastest frame: the dithered frames' mean is what the
    budget holds (their median is one of the two iteration counts, not the budget), and one frame the
    machine stalls for a second (CI once did) must not decide it."""
    kept = sorted(times)[1:-1] if len(times) > 4 else list(times)
    return statistics.mean(kept)


def _pictures(n: int = 4) -> list[np.ndarray]:
    """Pictures that differ everywhere (the content changes every frame)."""
    rng = np.random.default_rng(3)
    base = rng.integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8)
    return [np.roll(base, 7 * i, axis=1) for i in range(n)]


def _gpu_ms(gl, corrector: Corrector, src, fbo, pictures, frames: int) -> float:
    """The median GPU time of ``frames`` frames (after the first), by the budget's own clock."""
    timer, times = GpuTimer(), []
    try:
        for i in range(frames + 2):
            done = timer.take()
            if done is not None and done[0] > 0:
                times.append(done[1])
            if i < frames:
                G.write_texture(src, pictures[i % len(pictures)])
                timer.begin(i)
                corrector.apply(src, fbo)
                timer.end()
            else:
                gl.finish()
                timer.begin(-1)
                timer.end()
    finally:
        timer.release()
    return statistics.median(times)


def _scaled_budget(gl, rx, src, fbo, pictures, **options) -> tuple[float, float]:
    """This renderer's GPU time of a frame with one and with four iterations (fixed settings), by the
    clock the budget reads; measured again (at most three times) while four iterations do not come
    out at least 1.5 times one: a stall of the shared machine during the one-iteration frames (CI
    once measured 120 ms for one iteration and 175 ms for four) is not the renderer's cost."""
    for _ in range(3):
        out = []
        for k in (1, 4):
            c = Corrector(gl, rx, "quest2", "right", iterations_per_frame=k, **options)
            try:
                out.append(_gpu_ms(gl, c, src, fbo, pictures, 6))
            finally:
                c.release()
        if out[1] > 1.5 * out[0]:
            break
    return out[0], out[1]


@pytest.fixture
def frame(gl):
    src = G.upload_texture(gl, _pictures(1)[0])
    tex, fbo = G.render_target(gl, width=SIZE, height=SIZE)
    yield src, fbo
    G.release(fbo, tex, src)


def _renderer_slowed(history: list, tail: int = 24, settled: int = 36, change: float = 0.10) -> bool:
    """Whether the renderer itself changed speed between the settled frames and the tail: some count of
    iterations whose median time moved by more than ``change`` (the controller cannot move a count's
    cost; the shared machine can: on the dev machine one run saw the same two and three iterations
    cost 1.5 times as much for twenty frames, another 11 and 18 % more in its last sixteen, which
    carried their mean 21 % over the budget before the controller had followed)."""
    def medians(frames):
        by_k: dict[int, list[float]] = {}
        for choice, ms in frames:
            by_k.setdefault(choice.iterations, []).append(ms)
        return {k: statistics.median(v) for k, v in by_k.items() if len(v) >= 3}

    before, after = medians(history[settled:-tail]), medians(history[-tail:])
    return any(abs(after[k] / before[k] - 1) > change for k in before.keys() & after.keys())


def test_a_change_of_the_renderers_speed_is_told_from_a_steady_run():
    from vrcorrect.runtime.budget import BudgetChoice

    steady = [(BudgetChoice(2 + i % 2, None), 46.0 + 12.0 * (i % 2)) for i in range(90)]
    slowed = steady[:66] + [(c, 1.5 * ms) for c, ms in steady[66:]]
    dithered = steady[:66] + [(BudgetChoice(2, None), 46.0)] * 24      # other counts chosen, same costs
    assert not _renderer_slowed(steady) and _renderer_slowed(slowed) and not _renderer_slowed(dithered)


def test_the_budget_holds_the_frame_time_while_the_content_changes_and_cuts(gl, frame):
    """Within the issue's 15 % (the test passed it in 18 runs of 18 alone on the dev machine, its trimmed
    mean 0.6-1.4 % off the budget in the four runs printed; the test is ``serial``; on renderers of known
    cost the controller holds 5 %: tests/test_budget.py). A run in which the renderer's own speed changed (:func:`_renderer_slowed`)
    is run once more: the budget is scaled to the renderer measured before the run, and the controller's
    following of a change of load is checked on renderers of known cost (tests/test_budget.py). So is a
    run that held the budget with more iterations than the scale allows (CI on 2026-12-03: 5-7 where
    about 2.5 fit, the budget held): the renderer ran faster than when it was measured, and the scale
    is measured again."""
    src, fbo = frame
    rx = Prescription(right=EYE, left=EYE)
    pictures = _pictures()
    for attempt in range(2):
        t1, t4 = _scaled_budget(gl, rx, src, fbo, pictures)
        assert t4 > 1.5 * t1                                 # iterations cost time on this renderer
        budget_ms = t1 + 0.5 * (t4 - t1)                      # about two and a half iterations' worth
        c = Corrector(gl, rx, "quest2", "right", budget_ms=budget_ms)
        try:
            for i in range(90):                               # a cut at 30, then time to settle again
                if i == 30:
                    c.reset()                                 # a scene cut: a cold frame, then warm again
                G.write_texture(src, pictures[i % len(pictures)])
                c.apply(src, fbo)
            gl.finish()
            history = list(c.budget.history)
            measured = [ms for _, ms in history]
            ks = [choice.iterations for choice, _ in history]
            assert len(measured) >= 80                        # the timestamps were read, two frames late
            tail = measured[-24:]
            held = abs(_trimmed_mean(tail) / budget_ms - 1) <= BAND
            counted = 1 <= min(ks[-16:]) and max(ks[-16:]) <= 5 and len(set(ks[-16:])) <= 3
            if attempt == 0 and ((not held and _renderer_slowed(history)) or (held and not counted)):
                continue
            assert held, (budget_ms, tail, ks[-24:])
            assert counted, (budget_ms, t1, t4, ks[-16:])
            assert "budget" in c.describe()["budget"]
            break
        finally:
            c.release()


def test_a_budget_the_window_cannot_meet_shrinks_the_fovea(gl, frame):
    """The window shrinks and its frames come back under the budget, within the issue's 15 % (25 % until
    2026-11-29: one run in ten had ended 31 % over; probing 25 more, 23 ended 0.85-1.10 of the budget
    and two 1.21, both while the renderer's own speed changed). A run that ends over the band is run once
    more (until 2026-11-29 only when ``_renderer_slowed`` saw the renderer change speed; CI then failed
    twice on a run whose tail went from 33 to 46 ms a frame at the same window, which that check did not
    catch; on 2026-12-02 a run's window moved in its last frames, one of 217 ms, and left one frame at
    its last size): the window must shrink in every run, and settle and hold the budget in one of two."""
    from vrcorrect.specs.display import get_display

    src, fbo = frame
    rx = Prescription(right=EYE, left=EYE)
    pictures = _pictures()
    radius = 60 / get_display("quest2").pixels_per_degree        # a window of 120 px: nearly the whole view
    options = {"fovea_deg": radius, "fovea_periphery": "target"}
    for attempt in range(2):
        t1, t4 = _scaled_budget(gl, rx, src, fbo, pictures, **options)
        budget_ms = 0.55 * t1                                 # one iteration at the full window overruns it
        c = Corrector(gl, rx, "quest2", "right", budget_ms=budget_ms, **options)
        try:
            for i in range(120):                              # time to settle: each move waits DWELL_FRAMES
                G.write_texture(src, pictures[i % len(pictures)])
                c.gaze_deg = (0.0, 0.0)
                c.apply(src, fbo)
            gl.finish()
            assert c.budget.fovea_deg < radius and c.options.fovea_deg == c.budget.fovea_deg
            assert c.budget.moves >= 1
            tail = [ms for choice, ms in list(c.budget.history)[-16:] if choice.fovea_deg == c.budget.fovea_deg]
            settled = len(tail) >= 8                                  # at its last window for half the tail
            held = settled and _trimmed_mean(tail) <= budget_ms * (1 + BAND)   # back under it (a smaller
            if not held and attempt == 0:                                      # window may leave room)
                continue
            assert settled, (budget_ms, list(c.budget.history)[-16:])
            assert held, (budget_ms, tail)
            break
        finally:
            c.release()
