"""The one routine that times real-time frames, shared by ``vrcorrect bench cost`` and ``vrcorrect
bench workgroups`` (issue 43: the two disagreed by 25 % on the same default on an H200, 6.10 against
4.88 ms of GPU time, because each timed its frames its own way).

A *subject* is one corrector with its source texture and framebuffer.  :func:`time_frames` times the
subjects' frames **interleaved**, in rounds: each round gives every subject, in turn (the order
reversed every other round, so that a drift of the clocks falls on every subject alike), first
changing frames (a new picture each frame, the warm start carried over: the budget case) then cold
frames (a reset before each, as a cut), each kind as ``untimed`` frames then ``per_round`` timed
ones.  A timed frame is: the picture written, ``glFinish`` (the upload is not the frame's), the
clock read, ``Corrector.apply`` inside a ``GL_TIME_ELAPSED`` query, ``glFinish``, the clock read:
its wall time and the GPU's own time.  No cost ledger, pass timer or read-back is attached to a
timed frame (a ledger reads the early stop's indirect arguments back, a wait inside the frame).
Before the first round, untimed changing frames run for ``warm_up_s`` seconds on every subject in
turn (a GPU raises its clocks under load).  One subject is ``bench cost``'s case; several are
``bench workgroups``'.  Layer 6.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

__all__ = ["Subject", "KindTimes", "time_frames", "PER_ROUND", "UNTIMED"]

PER_ROUND = 5
"""Timed frames of one subject and kind in a row before the next."""
UNTIMED = 2
"""Untimed frames of the same subject and kind before each run of timed ones."""


@dataclass
class Subject:
    """A corrector to time: ``apply()`` runs one frame, ``picture(i)`` writes the ``i``-th new picture
    into its source, ``reset()`` makes the next frame cold."""

    apply: Callable[[], None]
    picture: Callable[[int], None]
    reset: Callable[[], None]


@dataclass
class KindTimes:
    """One subject's timed frames of one kind: wall and GPU milliseconds (a saturated or missing
    timer query is left out of ``gpu_ms``)."""

    wall_ms: list[float] = field(default_factory=list)
    gpu_ms: list[float] = field(default_factory=list)

    @property
    def wall_median(self) -> float | None:
        return statistics.median(self.wall_ms) if self.wall_ms else None

    @property
    def gpu_median(self) -> float | None:
        return statistics.median(self.gpu_ms) if self.gpu_ms else None


def time_frames(ctx: Any, subjects: Sequence[Subject], frames: int, warm_up_s: float, *,
                per_round: int = PER_ROUND, untimed: int = UNTIMED,
                progress: Callable[[], None] | None = None) -> list[dict[str, KindTimes]]:
    """Time ``frames`` changing and ``frames`` cold frames of each subject (module docstring);
    returns, per subject, ``{"changing": KindTimes, "cold": KindTimes}``.  ``progress`` is called
    after each run of one subject's frames of one kind."""
    from ...runtime.gl import timer_query_ms  # on use: start-up time (the CLI imports the studies to build its parser)

    query = ctx.query(time=True)
    shown = [0]

    def frame(s: Subject, cold: bool, out: KindTimes | None) -> None:
        shown[0] += 1
        s.picture(shown[0])
        if cold:
            s.reset()
        ctx.finish()                                        # the upload is not the frame's
        if out is None:
            s.apply()
            return
        t0 = time.perf_counter()
        with query:                                         # GL_TIME_ELAPSED: the GPU's own clock
            s.apply()
        ctx.finish()
        out.wall_ms.append(1e3 * (time.perf_counter() - t0))
        ms = timer_query_ms(query.elapsed)
        if ms is not None:
            out.gpu_ms.append(ms)

    until = time.perf_counter() + max(0.0, warm_up_s)
    while time.perf_counter() < until:
        for s in subjects:
            frame(s, False, None)
    results = [{"changing": KindTimes(), "cold": KindTimes()} for _ in subjects]
    order = list(range(len(subjects)))
    rounds = -(-int(frames) // per_round)
    for r in range(rounds):
        n = min(per_round, int(frames) - r * per_round)
        for i in (order if r % 2 == 0 else order[::-1]):
            for kind in ("changing", "cold"):
                for _ in range(untimed):
                    frame(subjects[i], kind == "cold", None)
                for _ in range(n):
                    frame(subjects[i], kind == "cold", results[i][kind])
                if progress is not None:
                    progress()
    return results
