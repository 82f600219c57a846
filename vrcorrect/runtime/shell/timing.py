"""The time each stage of a frame takes (:class:`StageTimes`): GPU timer queries and CPU clocks,
read a frame late so that nothing waits for the GPU; the mirror's, the overlay's and the headset
app's frame times.

Layer 5: moderngl; never torch.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from typing import TYPE_CHECKING, Iterator, Sequence

from ..gl import timer_query_ms

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

__all__ = ["StageTimes"]


class StageTimes:
    """GPU timer queries and CPU clocks per stage (``stages``; those in ``cpu_only`` get no
    GPU query). A frame's GPU times are read at the start of the next frame (:meth:`collect`),
    when they are ready, so nothing waits for the GPU."""

    def __init__(self, ctx: "moderngl.Context", stages: Sequence[str], cpu_only: Sequence[str] = ("present",)):
        self.queries: dict[str, moderngl.Query] = {name: ctx.query(time=True) for name in stages
                                                   if name not in cpu_only}
        self._cpu: dict[str, float] = {}
        self._pending: list[str] = []
        self.last: dict[str, tuple[float | None, float]] = {}
        self.smoothed: dict[str, tuple[float | None, float]] = {}

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        query = self.queries.get(name)
        t0 = time.perf_counter()
        if query is None:
            yield
        else:
            with query:
                yield
            self._pending.append(name)
        self._cpu[name] = 1e3 * (time.perf_counter() - t0)

    def collect(self) -> dict[str, tuple[float | None, float]]:
        """The last frame's ``stage -> (gpu_ms or None, cpu_ms)``; updates :attr:`smoothed`."""
        out: dict[str, tuple[float | None, float]] = {name: (None, cpu) for name, cpu in self._cpu.items()}
        for name in self._pending:
            out[name] = (timer_query_ms(self.queries[name].elapsed), self._cpu[name])
        self._pending, self._cpu = [], {}
        for name, (gpu, cpu) in out.items():
            old = self.smoothed.get(name)
            if old is None or (old[0] is None) != (gpu is None):
                self.smoothed[name] = (gpu, cpu)
            else:
                k = 0.1
                self.smoothed[name] = (None if gpu is None else old[0] + k * (gpu - old[0]), old[1] + k * (cpu - old[1]))
        for name in list(self.smoothed):
            if name not in out:
                del self.smoothed[name]
        self.last = out
        return out

    def release(self) -> None:
        self.queries = {}  # moderngl queries have no release(): the context frees them
