"""Signals during a command: SIGTERM and SIGHUP end it as Ctrl-C does (every ``finally`` runs, no
partial output is left), and none of the three acts inside an import or an installed library's
Python code.

Native code may have called that Python (an extension's initialisation, torch's operators) and be
unable to pass an exception on; the process would then abort (one CI run of ``vrcorrect correct
--report`` ended with status -6 and a pybind11 exception's traceback after a SIGTERM).  There the
signal is *held*: sent again every :data:`HOLD_RETRY_S` until the command's own code (or the
standard library's) runs, and acts then, or after :data:`HOLD_MAX_S` wherever the command is.  A
command's outputs are committed only when no signal is held (:func:`raise_if_held`, called by
:func:`vrcorrect.plumbing.fileio.atomic_paths` before its renames), so a signal held while the
outputs were written still leaves nothing behind.  While the renames run (:func:`signals_deferred`)
a signal waits until they are done, whichever thread the kernel delivered it to.

The standard library only.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from typing import Any, Iterator

__all__ = ["Terminated", "command_signals", "raise_if_held", "signals_deferred", "HOLD_RETRY_S", "HOLD_MAX_S",
           "SIGNAL_NAMES"]

#: How long a held signal waits before it is sent again.
HOLD_RETRY_S = 0.05
#: The longest a signal is held: then it acts wherever the command is.
HOLD_MAX_S = 10.0
#: vrcorrect's own code, installed or not (a frame there is never held).
OWN_CODE = os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep
#: The signals a command handles, and that :func:`signals_deferred` holds back.
SIGNAL_NAMES = ("SIGINT", "SIGTERM", "SIGHUP")
_NUMBERS = tuple(getattr(signal, n) for n in SIGNAL_NAMES if hasattr(signal, n))
_held: dict[int, float] = {}                   # signal number -> when it was first held
_deferring = 0                                 # how many signals_deferred blocks are open
_deferred: list[int] = []                      # signals that arrived inside one, oldest first


class Terminated(BaseException):
    """SIGTERM or SIGHUP arrived: unwinds like Ctrl-C, so every ``finally`` (temporary files, GL
    and OpenXR objects) runs and no partial output is left."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def hold_here(frame: Any) -> bool:
    """Whether a signal landing in ``frame`` waits: inside an import (a frame of Python's import
    machinery below it), or in an installed library's Python code (site-packages, not vrcorrect's)."""
    code = frame.f_code.co_filename if frame is not None else ""
    if ("site-packages" in code or "dist-packages" in code) and not code.startswith(OWN_CODE):
        return True
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def _send_again(signum: int) -> None:
    if signum in _held:                        # not acted on (raise_if_held) nor dropped meanwhile
        os.kill(os.getpid(), signum)


def _raise(signum: int) -> None:
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated(signum)


def on_signal(signum: int, frame: Any) -> None:
    """The command's handler of SIGTERM, SIGHUP and Ctrl-C (module docstring)."""
    if _deferring:                             # renames under way: act when they are done
        _deferred.append(signum)
        return
    now = time.monotonic()
    if hold_here(frame) and now - _held.setdefault(signum, now) < HOLD_MAX_S:
        timer = threading.Timer(HOLD_RETRY_S, _send_again, (signum,))
        timer.daemon = True
        timer.start()
        return
    _held.pop(signum, None)
    _raise(signum)


def raise_if_held() -> None:
    """Act now on a signal that is being held (a command's commit point: nothing is written after
    a termination was asked for)."""
    if _held:
        signum = next(iter(_held))
        _held.clear()
        _raise(signum)


@contextlib.contextmanager
def command_signals() -> Iterator[None]:
    """SIGTERM, SIGHUP and Ctrl-C handled by :func:`on_signal` while the block runs (main thread
    only; elsewhere nothing changes).  A signal the process was started ignoring (``nohup``'s
    SIGHUP, a background job's Ctrl-C) stays ignored.  A signal still held when the block ends is
    dropped: the command finished."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _held.clear()
    old = {s: signal.signal(s, on_signal) for s in _NUMBERS if signal.getsignal(s) is not signal.SIG_IGN}
    try:
        yield
    finally:
        _held.clear()
        _deferred.clear()
        for s, handler in old.items():
            signal.signal(s, handler)


@contextlib.contextmanager
def signals_deferred() -> Iterator[None]:
    """Hold Ctrl-C, SIGTERM and SIGHUP back while the block runs (a group of renames is then never
    cut in half); one that arrived meanwhile acts when the block is done.

    Two shields, because the kernel may deliver a process's signal to any thread that does not
    block it (OpenBLAS's and torch's workers, say), while Python runs the handler in the main
    thread: the main thread's signal mask holds back a signal sent to it (whatever the handler is),
    and :func:`on_signal` keeps one that reached another thread until the block ends."""
    global _deferring
    mask = hasattr(signal, "pthread_sigmask") and threading.current_thread() is threading.main_thread()
    old = signal.pthread_sigmask(signal.SIG_BLOCK, _NUMBERS) if mask else None
    _deferring += 1
    try:
        yield
    finally:
        _deferring -= 1
        if mask:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)   # a blocked signal is delivered here
        if _deferred and not _deferring:       # after an error too: the termination was asked for
            signum = _deferred[0]
            _deferred.clear()
            _raise(signum)
