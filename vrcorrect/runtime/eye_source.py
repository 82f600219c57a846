"""The prescription watched once for every eye, and each eye's model built off the render thread.

An application that corrects eyes live (the mirror, the overlay, ``vrcorrect xr``, the OpenXR
layer) makes one :class:`EyeSource`.  Designing an eye (the kernel: PSFs over wavelengths, seconds
of CPU) never runs on the render thread after start:

* :meth:`EyeSource.poll` (once a frame; cheap) looks at the file's stamp at most every
  :data:`POLL_INTERVAL_S` and, when it changed, has the worker read, validate and design every eye;
  it returns the :class:`EyeUpdate`\\ s that are ready, which the application hands to its
  correctors (:meth:`~vrcorrect.runtime.corrector.Corrector.install`: GL work only).  Meanwhile the
  old correction runs.  An unreadable or invalid file keeps the last good prescription and says why
  in one message.
* :meth:`EyeSource.adjust` designs one eye with live changes (the mirror's keys) the same way; the
  changed eye is checked against the prescription's ranges at once (a refusal is immediate, the
  design is not).
* :meth:`EyeSource.build` designs an eye on the caller's thread: for the start, before the first
  frame (an application shows "building" then, not a frozen picture).
* :meth:`EyeSource.design_all` designs every eye on the worker instead: a start that must not wait
  (the OpenXR layer passes the application's frames through meanwhile).  The models come from
  :meth:`~EyeSource.poll` (reason ``"start"``), all eyes in the same call, or a refusal comes as
  one message.  The display may be given as a function that returns it, called on first use: on
  the worker for this start (loading a display profile imports colour-science: seconds).

One worker thread, jobs in order; a newer edit of the file supersedes a queued one, and a changed
file is read once its stamp has settled (:data:`SETTLE_S`).  The eyes of one reload (or start)
arrive in the same :meth:`~EyeSource.poll`, every eye or none.

The source is the prescription's one owner: the file, its stamp, the last good content and each
eye's live changes (:attr:`EyeSource.offsets`, as asked for; :meth:`EyeSource.handed_offset`, as
in the last model handed over).  A :class:`~vrcorrect.runtime.corrector.Corrector` only installs
the models and applies them.  ``worker=False`` makes a synchronous source, for library users and
for a corrector built without one (its :meth:`~vrcorrect.runtime.corrector.Corrector.poll` and
:meth:`~vrcorrect.runtime.corrector.Corrector.adjust`): every job then runs at once on the
caller's thread, and :meth:`~EyeSource.take` hands its result over.

Layer 5: numpy; never torch.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ..plumbing.errors import VrcorrectError
from ..specs.display import DisplayProfile
from ..specs.prescription import EyeRx, Prescription, load_prescription
from ..specs.vocabulary import VIEW_ORDER
from .eye_model import CorrectorOptions, EyeModel, build_eye_model
from .rx_snapshot import RxSnapshot, RxSource, file_stamp, load_rx, with_offset

__all__ = ["POLL_INTERVAL_S", "EyeUpdate", "EyeSource", "Designer"]

log = logging.getLogger(__name__)

POLL_INTERVAL_S = 0.25
"""The prescription file's stamp is looked at no more often than this."""
SETTLE_S = 0.1
"""A changed file is read on the worker once its stamp has held for this long (looked at again up to
:data:`SETTLE_TRIES` times): an editor that writes in place (truncates, then writes) is read once,
when written, not also while empty."""
SETTLE_TRIES = 20

Offset = tuple[float, float, float]
NO_OFFSET: Offset = (0.0, 0.0, 0.0)

Designer = Callable[[str, EyeRx, Prescription], EyeModel]
"""How an eye is designed: ``design(eye, eye_rx, prescription)`` (the eye's name, its prescription
with the live changes, the whole prescription it is from) returns the model."""


@dataclass(frozen=True)
class EyeUpdate:
    """A newly designed eye: its model, the prescription it came from, the live changes on top of
    the file's (``offset``: sphere, cylinder, axis) and how long the design took."""

    eye: str
    model: EyeModel
    prescription: Prescription
    offset: Offset
    seconds: float
    reason: str                       # "reload" (the file changed), "adjust" (live changes), "start" (design_all)


class EyeSource:
    """One prescription (a file watched for edits, or a fixed one) and its eyes' models.

    Parameters
    ----------
    rx
        Prescription JSON path, :class:`~vrcorrect.specs.prescription.Prescription` or
        :class:`~vrcorrect.runtime.rx_snapshot.RxSnapshot` (read once; watched from then on).
    display, options
        What every eye is designed for (an age in ``options`` is the wearer's: each eye that states no
        accommodation gets that age's amplitude, :meth:`Prescription.with_age`); ``display`` may be a
        function that returns the profile,
        called once on first use (on the worker for :meth:`design_all`; a failure there refuses
        that start and is tried again on the next use).
    eyes
        The eyes the application corrects (a reload designs these).
    check
        Called with each eye before it is designed (e.g. a learned model's range); raising a
        :class:`~vrcorrect.plumbing.errors.VrcorrectError` refuses it.
    design
        How an eye is designed (:data:`Designer`); ``None``: :func:`~vrcorrect.runtime.eye_model.build_eye_model`
        with ``options``, the wearer's age from the options or else the prescription.
    worker
        ``False``: a synchronous source, no thread (module docstring).
    """

    def __init__(self, rx: RxSource, display: DisplayProfile | Callable[[], DisplayProfile],
                 options: CorrectorOptions = CorrectorOptions(), eyes: tuple[str, ...] = VIEW_ORDER,
                 check: Callable[[EyeRx], object] | None = None, design: Designer | None = None,
                 worker: bool = True):
        self.options = options
        snapshot = load_rx(rx)
        snapshot = RxSnapshot(self._aged(snapshot.prescription), snapshot.path, snapshot.stamp)
        self.snapshot: RxSnapshot = snapshot
        self.eyes = tuple(eyes)
        self._display = display
        self._display_lock = threading.Lock()
        self.check, self.design = check, design
        self.offsets: dict[str, Offset] = {}         # each eye's live changes, as last asked for
        self._handed: dict[str, Offset] = {}         # ... as in the last model of each eye handed over
        self.poll_interval_s: float | None = None
        """How often :meth:`poll` looks at the file's stamp; ``None``: :data:`POLL_INTERVAL_S`."""
        self._stamp = snapshot.stamp
        self._last_poll = time.monotonic()
        self._jobs: queue.Queue[tuple[str, object] | None] = queue.Queue()
        self._done: queue.Queue[list[EyeUpdate] | str] = queue.Queue()     # a job's eyes together, or a message
        self._pending = 0
        self._closed = False
        self._lock = threading.Lock()
        self._idle = threading.Condition(self._lock)
        self._file_generation = 0
        self._worker: threading.Thread | None = None
        if worker:
            self._worker = threading.Thread(target=self._run, name="vrcorrect-eye-source", daemon=True)
            self._worker.start()

    @property
    def synchronous(self) -> bool:
        """Jobs run at once on the caller's thread (``worker=False``)."""
        return self._worker is None

    @property
    def display(self) -> DisplayProfile:
        """What every eye is designed for (a function given for it is called now if it was not yet)."""
        with self._display_lock:
            if not isinstance(self._display, DisplayProfile):
                self._display = self._display()
            return self._display

    @property
    def reloads_started(self) -> int:
        """How many changes of the file :meth:`poll` has seen (each starts a reload)."""
        with self._lock:
            return self._file_generation

    @property
    def prescription(self) -> Prescription:
        """The last good prescription."""
        return self.snapshot.prescription

    @property
    def path(self) -> Path | None:
        return self.snapshot.path

    def eye_rx(self, eye: str, offset: Offset | None = None) -> EyeRx:
        """``eye`` of the last good prescription with its live changes (or ``offset``)."""
        return with_offset(self.prescription.eye(eye), self.offsets.get(eye, NO_OFFSET) if offset is None
                           else offset)

    def handed_offset(self, eye: str) -> Offset:
        """The live changes in the last model of ``eye`` that :meth:`poll` or :meth:`take` handed over
        (before any: none).  :attr:`offsets` holds those asked for, which a design may not have reached yet."""
        return self._handed.get(eye, NO_OFFSET)

    def design_eye(self, eye: str, eye_rx: EyeRx, rx: Prescription) -> EyeModel:
        """Design ``eye_rx`` (``eye`` of ``rx`` with its live changes) as this source does: ``check``
        first, then ``design`` (default: module docstring)."""
        if self.check is not None:
            self.check(eye_rx)
        if self.design is not None:
            return self.design(eye, eye_rx, rx)
        age = self.options.age_years if self.options.age_years is not None else rx.age_years
        return build_eye_model(eye_rx, self.display, self.options, age_years=age)

    # ------------------------------------------------------------------ on the caller's thread

    def build(self, eye: str) -> EyeModel:
        """Design ``eye`` now, on this thread (the start)."""
        return self.design_eye(eye, self.eye_rx(eye), self.prescription)

    def design_all(self) -> None:
        """Design every eye of the last good prescription (with its live changes) on the worker:
        the start, without waiting.  :meth:`poll` then returns all the eyes at once (reason
        ``"start"``) or, when the design is refused (the display, ``check`` or the design itself),
        one message and no eye."""
        self._queue(("start", None))

    def adjust(self, eye: str, offset: Offset) -> EyeRx:
        """Design ``eye`` with the live changes ``offset`` (sphere, cylinder, axis, on top of the
        file's) on the worker; returns the eye it will be.  Out of range: ``ValidationError`` now,
        nothing queued."""
        e = self.eye_rx(eye, offset)
        if self.check is not None:
            self.check(e)
        offset = tuple(float(v) for v in offset)
        previous = self.offsets.get(eye, NO_OFFSET)
        self.offsets[eye] = offset                  # a reload from now on keeps it
        self._queue(("adjust", (eye, offset, previous)))
        return e

    def poll(self, now: float | None = None) -> tuple[list[EyeUpdate], list[str]]:
        """What is ready: designed eyes and messages (a refused edit).  Also starts a reload when
        the file's stamp changed (looked at no more often than :attr:`poll_interval_s`).  Never
        waits (a synchronous source designs the reload first)."""
        now = time.monotonic() if now is None else now
        path = self.snapshot.path
        interval = POLL_INTERVAL_S if self.poll_interval_s is None else self.poll_interval_s
        if path is not None and now - self._last_poll >= interval:
            self._last_poll = now
            stamp = file_stamp(path)
            with self._lock:
                changed = stamp != self._stamp
                if changed:
                    self._stamp = stamp
                    self._file_generation += 1
                    generation = self._file_generation
            if changed:
                self._queue(("file", generation))
        return self.take()

    def take(self) -> tuple[list[EyeUpdate], list[str]]:
        """What is ready, as :meth:`poll` gives it, without looking at the file."""
        updates: list[EyeUpdate] = []
        messages: list[str] = []
        while True:
            try:
                item = self._done.get_nowait()
            except queue.Empty:
                break
            if isinstance(item, str):
                messages.append(item)
                continue
            for update in item:
                if update.reason == "reload":
                    self.snapshot = RxSnapshot(update.prescription, self.snapshot.path, self.snapshot.stamp)
                self._handed[update.eye] = update.offset
                updates.append(update)
        return updates, messages

    @property
    def busy(self) -> bool:
        """A design is queued or running."""
        with self._lock:
            return self._pending > 0

    def wait(self, timeout: float | None = None) -> bool:
        """Block until nothing is queued or running (tests, and callers that may wait); False on
        timeout.  (A synchronous source is never busy between calls.)"""
        with self._idle:
            return self._idle.wait_for(lambda: self._pending == 0, timeout)

    def close(self, wait: bool = True) -> None:
        """Stop the worker: designs still queued are dropped; with ``wait``, wait (at most 5 s) for
        the one running, else return at once (it finishes in the background, unused)."""
        self._closed = True
        if self._worker is None:
            return
        self._jobs.put(None)
        if wait:
            self.join(5.0)

    def join(self, timeout: float) -> bool:
        """After :meth:`close`: wait at most ``timeout`` s for the worker to end (a design it is running
        finishes first); True when it has ended (a synchronous source has none: True)."""
        if self._worker is None:
            return True
        self._worker.join(timeout=timeout)
        return not self._worker.is_alive()

    # ------------------------------------------------------------------ the worker

    def _queue(self, job: tuple[str, object]) -> None:
        with self._lock:
            self._pending += 1
        if self._worker is None:
            self._do(job)                                     # synchronous: now, on the caller's thread
        else:
            self._jobs.put(job)

    def _finish(self) -> None:
        with self._idle:
            self._pending -= 1
            self._idle.notify_all()

    def _run(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                return
            self._do(job)

    def _do(self, job: tuple[str, object]) -> None:
        try:
            kind, arg = job
            if self._closed:
                pass                                          # dropped: nobody will take it
            elif kind == "file":
                self._reload(int(arg))                        # type: ignore[arg-type]
            elif kind == "start":
                self._start()
            else:
                eye, offset, previous = arg                   # type: ignore[misc]
                self._adjust(eye, offset, previous)
        except Exception as exc:                              # the worker must outlive any one job
            self._done.put(f"eye design failed: {type(exc).__name__}: {exc}")
            log.exception("eye source job failed")
        finally:
            self._finish()

    def _reload(self, generation: int) -> None:
        path = self.snapshot.path
        with self._lock:
            if generation != self._file_generation:         # a newer edit is queued: it will be read
                return
        stamp = file_stamp(path)
        for _ in range(SETTLE_TRIES if self._worker is not None else 0):     # wait for the writer to finish
            time.sleep(SETTLE_S)
            now = file_stamp(path)
            if now == stamp:
                break
            stamp = now
        with self._lock:
            if generation != self._file_generation:         # poll saw a later stamp meanwhile: that job reads
                return
            self._stamp = stamp                             # what is read now; poll need not queue it again
        self._design_every(lambda: self._aged(load_prescription(path)), "reload",
                           f"{path}: not reloaded, keeping the last good prescription")

    def _aged(self, rx: Prescription) -> Prescription:
        """``rx`` for the options' wearer's age where they set one (:meth:`Prescription.with_age`: the
        pupil's formula and each eye that states no amplitude follow it), else as it is."""
        return rx if self.options.age_years is None else rx.with_age(self.options.age_years)

    def _start(self) -> None:
        self._design_every(lambda: self.prescription, "start", "the eye models were not designed")

    def _design_every(self, read: Callable[[], Prescription], reason: str, refused: str) -> None:
        """Design every eye of the prescription ``read`` gives and hand them over together; or
        none, and one message (``refused``, then why): one state for all the eyes."""
        try:
            rx = read()
            updates = [self._design(eye, self.offsets.get(eye, NO_OFFSET), rx, reason) for eye in self.eyes]
        except VrcorrectError as exc:
            message = f"{refused}: {exc}"
            log.warning(message)
            self._done.put(message)
            return
        self._done.put(updates)

    def _adjust(self, eye: str, offset: Offset, previous: Offset) -> None:
        try:
            self._done.put([self._design(eye, offset, self.prescription, "adjust")])
        except VrcorrectError as exc:
            if self.offsets.get(eye) == offset:       # not asked again meanwhile: a reload keeps the previous
                self.offsets[eye] = previous
            self._done.put(f"{eye} eye unchanged: {' '.join(str(exc).split())}")

    def _design(self, eye: str, offset: Offset, rx: Prescription, reason: str) -> EyeUpdate:
        t0 = time.perf_counter()
        model = self.design_eye(eye, with_offset(rx.eye(eye), offset), rx)
        return EyeUpdate(eye, model, rx, offset, time.perf_counter() - t0, reason)
