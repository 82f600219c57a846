"""Progress of a long command, whatever its output is: on a terminal one line redrawn in place (done of
total, the time a unit takes, the time left); otherwise (a log file, a pipe, CI) a line every few
seconds and one at the end, so that a run of minutes is never silent.

``render``, ``correct`` and ``simulate`` (clips), ``unroll`` (kernels, fast's solutions, training steps)
use it.  Layer 6 (an application's output); no heavy import.
"""

from __future__ import annotations

import math
import os
import sys
import threading
import time
from typing import IO, Callable

__all__ = ["Progress", "duration_text", "INTERVAL_S"]

INTERVAL_S = 5.0
"""Seconds between the lines written when the output is not a terminal (``VRCORRECT_PROGRESS_S`` sets
another: a CI log may want fewer lines, a test more)."""
INTERVAL_ENV = "VRCORRECT_PROGRESS_S"


def _interval() -> float:

    try:
        value = float(os.environ.get(INTERVAL_ENV, INTERVAL_S))
    except ValueError:
        return INTERVAL_S
    return value if math.isfinite(value) and value > 0 else INTERVAL_S
_REDRAW_S = 0.2


def duration_text(seconds: float) -> str:
    """``"41 s"``, ``"6 min 5 s"``, ``"1 h 02 min"``."""
    if not math.isfinite(seconds) or seconds < 0:
        return "?"
    if seconds < 60:
        return f"{seconds:.1f} s" if seconds < 10 else f"{seconds:.0f} s"
    minutes, s = divmod(int(round(seconds)), 60)
    if minutes < 60:
        return f"{minutes} min {s} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes:02d} min"


def _per_unit(seconds: float) -> str:
    return f"{seconds * 1e3:.0f} ms" if seconds < 10 else duration_text(seconds)


def _a(unit: str) -> str:
    return "an" if unit[:1].lower() in "aeio" else "a"


class Progress:
    """``what``: ``"render"``; ``unit``: ``"frame"``; ``total``: how many (``None``: unknown).  Call
    :meth:`update` with the count done; :meth:`close` at the end (or use it as a context manager).
    ``stream``: where it writes (standard error); ``interval``: seconds between lines off a terminal
    (default :data:`INTERVAL_S` or ``$VRCORRECT_PROGRESS_S``);
    ``clock``: for tests.  Between updates (a long step, or the work after the last one) a thread says
    every ``interval`` that it is still working, so that no stretch of a run is silent."""

    def __init__(self, what: str, unit: str, total: int | None = None, *, stream: IO[str] | None = None,
                 interval: float | None = None, clock: Callable[[], float] = time.monotonic):
        self.what, self.unit, self.total = what, unit, total
        self.stream = sys.stderr if stream is None else stream
        self.interval, self.clock = (_interval() if interval is None else interval), clock
        isatty = getattr(self.stream, "isatty", None)
        self.terminal = bool(isatty and isatty())
        self.start = clock()
        self.done = 0
        # off a terminal the first line comes after an interval: a short run (or one that fails at once,
        # whose error must stay the one line on standard error) writes none
        self._last = -math.inf if self.terminal else self.start
        self._first_done_at: float | None = None     # after the first unit (its set-up is no guide to the rest)
        self._width = 0
        self.note = ""
        self.closed = False
        self._last_update = self.start
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._ticker = threading.Thread(target=self._tick, name="vrcorrect-progress", daemon=True)
        self._ticker.start()

    def _tick(self) -> None:
        while not self._stop.wait(self.interval):
            now = self.clock()
            with self._lock:
                if self.closed or now - self._last < self.interval:
                    continue
                self._last = now
                quiet = now - self._last_update
                self._write(self.text(now) + (f" (working: {duration_text(quiet)} since the last {self.unit})"
                                              if self.done and quiet >= self.interval else ""))

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        self.close(summary=exc_type is None)

    def update(self, done: int, total: int | None = None, note: str | None = None) -> None:
        """``done`` so far (of ``total``, when it changed); ``note``: more for the line (a loss)."""
        if total is not None:
            self.total = total
        if note is not None:
            self.note = note
        now = self.clock()
        with self._lock:
            self.done = int(done)
            self._last_update = now
            if self.done >= 1 and self._first_done_at is None:
                self._first_done_at = now
            if now - self._last >= (_REDRAW_S if self.terminal else self.interval):
                self._last = now
                self._write(self.text(now))

    def advance(self, count: int = 1) -> None:
        self.update(self.done + count)

    def per_unit(self, now: float | None = None) -> float | None:
        """Seconds a unit takes: measured after the first (which holds the set-up) when there are two or
        more, else the first's."""
        now = self._last_update if now is None else min(now, self._last_update)
        if self._first_done_at is not None and self.done >= 2:
            return (now - self._first_done_at) / (self.done - 1)
        if self.done >= 1:
            return (now - self.start) / self.done
        return None

    def text(self, now: float | None = None) -> str:
        now = self.clock() if now is None else now
        total = f"/{self.total}" if self.total else ""
        parts = [f"{self.what}: {self.done}{total} {self.unit}s"]
        per = self.per_unit(now)
        if per is not None:
            parts.append(f"{_per_unit(per)} {_a(self.unit)} {self.unit}")
            if self.total:
                parts.append(f"about {duration_text(per * max(self.total - self.done, 0))} left")
        else:
            parts.append(f"{duration_text(now - self.start)} so far")
        if self.note:
            parts.append(self.note)
        return ", ".join(parts)

    def _write(self, line: str) -> None:
        try:
            if self.terminal:
                pad = max(self._width - len(line), 0)
                self.stream.write("\r" + line + " " * pad)
                self._width = len(line)
            else:
                self.stream.write(line + "\n")
            self.stream.flush()
        except (OSError, ValueError):
            pass

    def close(self, summary: bool = True) -> None:
        """The last line: how many, in how long (off a terminal, where ``summary`` and a line was
        written before; on one, the line is cleared)."""
        self._stop.set()
        with self._lock:
            if self.closed:
                return
            self.closed = True
        if self.terminal:
            self._write("")
            try:
                self.stream.write("\r")
                self.stream.flush()
            except (OSError, ValueError):
                pass
            return
        if self.done and summary and self._last > self.start:
            per = self.per_unit()
            self._write(f"{self.what}: {self.done} {self.unit}s in {duration_text(self._last_update - self.start)}"
                        + (f" ({_per_unit(per)} {_a(self.unit)} {self.unit})" if per is not None else ""))
