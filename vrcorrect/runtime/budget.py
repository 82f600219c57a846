"""A frame-time budget (``--budget-ms``): the work of each eye's frame chosen so that its GPU time,
measured by the :class:`~vrcorrect.runtime.corrector.Corrector`'s own timer queries, stays at the
budget.

* :class:`FrameBudget` (plain numbers, no GL) chooses, frame by frame, the iterations a frame and,
  with a fovea, the window's radius from a ladder (the configured radius first, then smaller ones).
  - The iterations: a straight line ``ms = a + b k`` fitted to the recent frames' times (the
    timings come two frames late) gives the real number of iterations ``q`` that fits the budget.
    The frames run ``floor(q)`` or ``floor(q) + 1`` iterations, dithered by error diffusion, so that
    their mean time is the budget: single frames lie within one iteration's time of it. Two frames
    in a row far from the line (:data:`JUMP`) start a new fit: the load changed. One such frame
    alone (a hitch: the system stalled the process, a driver compiled a shader) is left out.
    A smaller drift (:data:`DRIFT_FRAMES` frames in a row all more than :data:`DRIFT` slower, or all
    faster, than the line: the renderer itself slowed, a clock fell, another process took a core)
    rescales the older frames of the fit by the drifted frames' median ratio, so the line keeps its
    slope and takes the new level at once, instead of when the old frames have left the window.
  - The radius (hysteresis): a smaller one only when even the fewest iterations have overrun the
    budget by more than :data:`BAND` for :data:`DWELL_FRAMES` frames in a row; the larger one again
    only when its fewest iterations would fit with :data:`BAND` to spare for as long (their time
    estimated from this window's by the windows' areas, which overstates it: the periphery's share
    does not grow), and never within :data:`DWELL_FRAMES` of a change. Each change restarts the fit
    (a new window is a new grid, started cold).
* :class:`GpuTimer`: ``GL_TIMESTAMP`` queries in a ring, read two frames late so that nothing
  waits for the GPU.

Under a budget the early stop is off (``CorrectorOptions.budget_ms``): a converged still view would
time as nearly free and teach the fit that iterations cost nothing, and the first changing frame
after it would then run far too many.  Without a budget the fixed settings apply, and nothing here
runs.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from dataclasses import dataclass
from typing import Any, Sequence

from ..plumbing.errors import ValidationError

__all__ = ["MIN_BUDGET_MS", "MAX_BUDGET_MS", "BAND", "DRIFT", "DRIFT_FRAMES", "DWELL_FRAMES", "FIT_FRAMES", "JUMP",
           "RADIUS_STEPS", "BudgetChoice", "FrameBudget", "GpuTimer", "radius_ladder", "check_budget_ms"]

MIN_BUDGET_MS = 0.05
MAX_BUDGET_MS = 10_000.0
BAND = 0.15
"""How far past (or short of) the budget the iterations' ends may leave a frame before the radius
moves (issue 45's band)."""
DWELL_FRAMES = 8
"""Frames in a row past the band before the radius moves, and the least between two moves."""
FIT_FRAMES = 24
"""The recent frames the line ``ms = a + b k`` is fitted to."""
JUMP = 1.5
"""Two frames in a row this many times slower (or faster) than the line predicts are a change of
load: the line is fitted anew from them. One alone is a hitch, left out of the fit."""
DRIFT = 0.06
"""How far (as a fraction) every one of :data:`DRIFT_FRAMES` frames in a row must lie from the line, on
the same side, to be a drift of the renderer's speed rather than noise: with frame-to-frame noise of
3 %, four frames past 2 sigma on one side come about once in three million frames."""
DRIFT_FRAMES = 4
"""Frames in a row a drift needs (:data:`DRIFT`)."""
RADIUS_STEPS = (1.0, 0.75, 0.5, 0.35, 0.25)
"""The radius ladder, as fractions of the configured radius."""


def check_budget_ms(value: Any, field: str = "budget_ms") -> float | None:
    """``None`` (no budget) or milliseconds a frame, :data:`MIN_BUDGET_MS` to :data:`MAX_BUDGET_MS`."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or \
            not MIN_BUDGET_MS <= value <= MAX_BUDGET_MS:
        raise ValidationError(field, value, f"None (no budget) or milliseconds a frame from {MIN_BUDGET_MS:g} to "
                                            f"{MAX_BUDGET_MS:g}")
    return float(value)


def radius_ladder(radius_deg: float | None, smallest_deg: float) -> tuple[float | None, ...]:
    """The radii the budget may choose, the configured one first (``None``: no fovea, one rung)."""
    if radius_deg is None:
        return (None,)
    rungs: list[float] = []
    for f in RADIUS_STEPS:
        r = max(radius_deg * f, smallest_deg)
        if not rungs or r < rungs[-1] - 1e-9:
            rungs.append(r)
    return tuple(rungs)


@dataclass(frozen=True)
class BudgetChoice:
    """What a frame runs: its iterations, and its window's radius (degrees; ``None``: no fovea);
    ``cold``: it started cold and ran its cold work too (the first frame, a cut, a new window), so
    its time is not on the line and the fit leaves it out."""

    iterations: int
    fovea_deg: float | None
    cold: bool = False


class FrameBudget:
    """Chooses each frame's work so that its time stays at ``budget_ms`` (module docstring).

    ``radii``: the ladder, most expensive first (:func:`radius_ladder`); ``iterations``: the
    range of iterations a frame; ``start``: the first frames' iterations."""

    def __init__(self, budget_ms: float, radii: Sequence[float | None] = (None,), iterations: tuple[int, int] = (1, 16),
                 start: int = 2):
        self.budget_ms = check_budget_ms(budget_ms)
        if not radii:
            raise ValidationError("radii", radii, "at least one radius (None: no fovea)")
        low, high = iterations
        if not (isinstance(low, int) and isinstance(high, int) and 1 <= low <= high):
            raise ValidationError("iterations", iterations, "(low, high), whole numbers with 1 <= low <= high")
        self.radii = tuple(radii)
        self.low, self.high = low, high
        self.level = 0
        self.q = float(min(max(start, low), high))
        self._carry = 0.0
        self._samples: deque[tuple[int, float]] = deque(maxlen=FIT_FRAMES)
        self._line: tuple[float, float] | None = None      # the fit to _samples, kept until they change
        self._hitch: tuple[int, float] | None = None       # a frame far off the line, not yet believed
        self.hitches = 0
        """Frames left out of the fit as hitches (one frame far off the line, the next back on it)."""
        self._ratios: deque[float] = deque(maxlen=DRIFT_FRAMES)   # the newest fitted frames' time / the line's
        self.drifts = 0
        """Drifts followed: the fit's older frames rescaled to the renderer's new speed."""
        self._over = self._under = 0
        self._since_move = DWELL_FRAMES
        self.last_ms: float | None = None
        self.moves = 0
        self.history: deque[tuple[BudgetChoice, float]] = deque(maxlen=256)
        """The frames timed so far (the newest 256): what each ran and its ms."""

    @property
    def fovea_deg(self) -> float | None:
        return self.radii[self.level]

    def choose(self) -> BudgetChoice:
        """The next frame's work: ``floor(q)`` or one more, dithered so the mean is ``q``."""
        k = math.floor(self.q + self._carry)
        k = min(max(k, self.low), self.high)
        self._carry += self.q - k
        self._carry = min(max(self._carry, -1.0), 1.0)
        self._since_move += 1
        return BudgetChoice(k, self.fovea_deg)

    def observe(self, choice: BudgetChoice, ms: float) -> None:
        """A frame's measured time (it ran ``choice``); frames of another radius than the current
        one (timed before a move) and cold frames are kept in :attr:`history` but not fitted."""
        if not math.isfinite(ms) or ms < 0:
            return
        self.last_ms = ms
        self.history.append((choice, ms))
        if choice.fovea_deg != self.fovea_deg or choice.cold:
            return
        if len(self._samples) >= 4:              # a change of load (a new picture size, a new scene): refit
            a, b = self._line or self._fit()
            predicted = a + b * choice.iterations
            if not predicted / JUMP <= ms <= predicted * JUMP:
                if self._hitch is None:           # one frame alone may be a hitch: wait for the next
                    self._hitch = (choice.iterations, ms)
                    return
                self._samples.clear()             # two in a row: the load changed; both start the fit
                self._samples.append(self._hitch)
                self._ratios.clear()
            else:
                if self._hitch is not None:
                    self.hitches += 1
                self._follow_drift(ms / predicted if predicted > 0 else 1.0)
            self._hitch = None
        self._samples.append((choice.iterations, ms))
        self._line = a, b = self._fit()
        self.q = min(max((self.budget_ms - a) / b, self.low), self.high)
        fewest = a + b * self.low
        self._over = self._over + 1 if fewest > self.budget_ms * (1 + BAND) else 0
        if self.level > 0:          # the larger window's fewest iterations, scaled by its area, would fit
            scale = (self.radii[self.level - 1] / self.radii[self.level]) ** 2
            self._under = self._under + 1 if fewest * scale < self.budget_ms * (1 - BAND) else 0
        if self._since_move < DWELL_FRAMES:
            return
        if self._over >= DWELL_FRAMES and self.level + 1 < len(self.radii):
            self._move(+1)
        elif self._under >= DWELL_FRAMES and self.level > 0:
            self._move(-1)

    def _follow_drift(self, ratio: float) -> None:
        """A frame on the line within :data:`JUMP`, ``ratio`` its time over the line's: after
        :data:`DRIFT_FRAMES` of them in a row all past :data:`DRIFT` on one side, the fit's older
        frames (all but the drifted ones, the newest not yet in it) are scaled by their median."""
        self._ratios.append(ratio)
        if len(self._ratios) < DRIFT_FRAMES:
            return
        if not (all(r > 1 + DRIFT for r in self._ratios) or all(r < 1 - DRIFT for r in self._ratios)):
            return
        scale = statistics.median(self._ratios)
        samples = list(self._samples)
        split = max(len(samples) - (DRIFT_FRAMES - 1), 0)   # the drifted frames already in the fit stay
        older, recent = samples[:split], samples[split:]
        self._samples.clear()
        self._samples.extend([(k, t * scale) for k, t in older] + recent)
        self._ratios.clear()
        self.drifts += 1

    def _fit(self) -> tuple[float, float]:
        """``(a, b)`` of ``ms = a + b k`` through the median time of each count of iterations among
        the recent frames (a cold frame, after a cut, is an outlier the medians ignore); with one
        count only, a fifth of its time fixed and the rest per iteration."""
        by_k: dict[int, list[float]] = {}
        for k, t in self._samples:
            by_k.setdefault(k, []).append(t)
        points = [(k, statistics.median(ts)) for k, ts in by_k.items()]
        if len(points) >= 2:
            mean_k = sum(k for k, _ in points) / len(points)
            mean_t = sum(t for _, t in points) / len(points)
            var = sum((k - mean_k) ** 2 for k, _ in points)
            b = sum((k - mean_k) * (t - mean_t) for k, t in points) / var
            if b > 1e-3 * max(mean_t, 1e-9):
                return mean_t - b * mean_k, b
        k, t = max(points, key=lambda p: len(by_k[p[0]]))
        return 0.2 * t, max(0.8 * t / k, 1e-9)

    def _move(self, step: int) -> None:
        self.level += step
        self._samples.clear()
        self._line = self._hitch = None
        self._ratios.clear()
        self._over = self._under = 0
        self._since_move = 0
        self._carry = 0.0
        self.q = float(self.low if step < 0 else min(max(round(self.q), self.low), self.high))
        self.moves += 1

    def describe(self) -> str:
        """One line: the budget and what it chose (for the mirror's text and the layer's log)."""
        window = "" if self.fovea_deg is None else f", fovea {self.fovea_deg:.3g} deg"
        last = "" if self.last_ms is None else f" (last {self.last_ms:.2f} ms)"
        return f"budget {self.budget_ms:g} ms: {self.q:.2f} iterations a frame{window}{last}"


class GpuTimer:
    """GPU time of a frame's GL work from two ``GL_TIMESTAMP`` queries (``glQueryCounter``, through
    glvnd's ``libOpenGL.so.0``, which reaches the current context, EGL or GLX): unlike a
    ``GL_TIME_ELAPSED`` query it may run inside the application's own timer queries. Kept in a ring
    of three frames; the frame two before is read as a frame begins, so nothing waits for the GPU.

    Raises :class:`RuntimeError` when the library or the entry points are missing."""

    _GL_TIMESTAMP = 0x8E28
    _GL_QUERY_RESULT = 0x8866
    _GL_QUERY_RESULT_AVAILABLE = 0x8867

    def __init__(self) -> None:
        import ctypes  # only with a budget

        try:
            gl = ctypes.CDLL("libOpenGL.so.0")
        except OSError as exc:
            raise RuntimeError(f"the frame budget's GPU timer needs libOpenGL.so.0 (Debian: libopengl0): {exc}") \
                from None
        self._c = ctypes
        self._gen, self._delete = gl.glGenQueries, gl.glDeleteQueries
        self._counter, self._get = gl.glQueryCounter, gl.glGetQueryObjectui64v
        self._gen.argtypes = self._delete.argtypes = [ctypes.c_int, ctypes.POINTER(ctypes.c_uint)]
        self._counter.argtypes = [ctypes.c_uint, ctypes.c_uint]
        self._get.argtypes = [ctypes.c_uint, ctypes.c_uint, ctypes.POINTER(ctypes.c_uint64)]
        self._ids = (ctypes.c_uint * 6)()
        self._gen(6, self._ids)
        self._tags: list[Any] = [None, None, None]
        self._frame = 0

    def _value(self, query: int, what: int) -> int:
        out = self._c.c_uint64(0)
        self._get(query, what, self._c.byref(out))
        return int(out.value)

    def take(self) -> tuple[Any, float] | None:
        """Before a frame begins: the frame two before, ``(its tag, ms)``, or ``None`` (none yet, or
        its result not ready: then it is dropped rather than waited for)."""
        j = (self._frame - 2) % 3
        if self._frame < 2 or self._tags[j] is None:
            return None
        tag, self._tags[j] = self._tags[j], None
        start, end = self._ids[2 * j], self._ids[2 * j + 1]
        if not self._value(end, self._GL_QUERY_RESULT_AVAILABLE):
            return None
        return tag, (self._value(end, self._GL_QUERY_RESULT) - self._value(start, self._GL_QUERY_RESULT)) / 1e6

    def begin(self, tag: Any) -> None:
        """Stamp the start of a frame tagged ``tag``."""
        i = self._frame % 3
        self._tags[i] = tag
        self._counter(self._ids[2 * i], self._GL_TIMESTAMP)

    @property
    def tag(self) -> Any:
        """The tag of the frame begun last."""
        return self._tags[self._frame % 3]

    def retag(self, tag: Any) -> None:
        """Tag the frame begun last anew (what it turned out to run)."""
        self._tags[self._frame % 3] = tag

    def end(self) -> None:
        """Stamp the end of the frame begun last."""
        self._counter(self._ids[2 * (self._frame % 3) + 1], self._GL_TIMESTAMP)
        self._frame += 1

    def release(self) -> None:
        if self._ids is not None:
            self._delete(6, self._ids)
            self._ids = None
