"""Command line: ``vrcorrect <command> ...``: the parser, built from one module per command
(each with an ``add_parser`` and its ``cmd_*``), and the one place that turns errors and signals
into exit codes.

Library errors (:class:`vrcorrect.plumbing.errors.VrcorrectError`) become one line on
stderr and exit status 2; a command-line user never sees a traceback
(``VRCORRECT_DEBUG=1`` shows it for bug reports).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
import time
from typing import Any, Iterator, Sequence

from ..plumbing.errors import VrcorrectError
from . import acuity, bench, correct, demo, displays, evaluate, layer, learning, mirror, overlay, psf, render, rx
from . import simulate, xr

EXIT_USAGE = 2
EXIT_INTERNAL = 3


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="vrcorrect", description=(
        "Pre-correct displays for eyes that need glasses (ChromaCorrect: display spectra, Zernike PSFs per "
        "wavelength, cone responses)."))
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for command in (simulate, correct, evaluate, acuity, learning, psf, rx, displays, demo, render, mirror,
                    overlay, xr, layer):
        command.add_parser(sub)
    bench.add_parser(sub)
    return ap


class Terminated(BaseException):
    """SIGTERM or SIGHUP arrived: unwinds like Ctrl-C, so every ``finally`` (temporary files, GL
    and OpenXR objects) runs and no partial output is left."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


#: How long a held signal waits before it is sent again (:func:`_raise_terminated`).
HOLD_RETRY_S = 0.05
#: The longest a signal is held: then it acts wherever the command is.
HOLD_MAX_S = 10.0
_held_since: dict[int, float] = {}
_OWN_CODE = os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep     # vrcorrect/, installed or not


def _hold_here(frame: Any) -> bool:
    """Whether a signal landing in ``frame`` waits: inside an import (a frame of Python's import
    machinery below it), or in an installed library's Python code (site-packages, not vrcorrect's)."""
    code = frame.f_code.co_filename if frame is not None else ""
    if ("site-packages" in code or "dist-packages" in code) and not code.startswith(_OWN_CODE):
        return True
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def _raise_terminated(signum: int, frame: Any) -> None:
    """The command's handler of SIGTERM, SIGHUP and Ctrl-C.

    Where the command's own code (or the standard library's) runs, it raises at once.  Inside an
    import or a library's Python code it raises nothing: native code may have called that Python (an
    extension's initialisation, torch's operators) and may be unable to pass an exception on, and the
    process would abort (one CI run of ``correct --report`` ended with status -6 and a pybind11
    exception's traceback after a SIGTERM).  The signal is sent again a moment later and acts once the
    command's own code runs again, or after :data:`HOLD_MAX_S` wherever it is."""
    now = time.monotonic()
    if _hold_here(frame) and now - _held_since.setdefault(signum, now) < HOLD_MAX_S:
        timer = threading.Timer(HOLD_RETRY_S, os.kill, (os.getpid(), signum))
        timer.daemon = True
        timer.start()
        return
    _held_since.pop(signum, None)
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated(signum)


@contextlib.contextmanager
def _terminate_like_interrupt() -> Iterator[None]:
    """Treat SIGTERM and SIGHUP as Ctrl-C for the duration of a command (main thread only), and hold
    all three back while a module is imported or a library's Python code runs
    (:func:`_raise_terminated`).  A signal the process was started ignoring (``nohup``'s SIGHUP, a
    background job's Ctrl-C) stays ignored."""
    names = [n for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n)]
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _held_since.clear()                         # a hold of an earlier command in this process is over
    old = {n: signal.signal(getattr(signal, n), _raise_terminated) for n in names
           if signal.getsignal(getattr(signal, n)) is not signal.SIG_IGN}
    try:
        yield
    finally:
        for n, handler in old.items():
            signal.signal(getattr(signal, n), handler)


def _interruption(exc: BaseException) -> BaseException | None:
    """The signal or Ctrl-C inside ``exc``'s chain, if any.  Python wraps an exception raised in some
    places (a descriptor's ``__set_name__`` while a module is imported, for one) in a RuntimeError
    whose cause is the original: a SIGTERM that lands there is still a SIGTERM."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, (Terminated, KeyboardInterrupt)):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def _interrupted(exc: BaseException) -> int:
    if isinstance(exc, Terminated):
        name = signal.Signals(exc.signum).name
        print(f"vrcorrect: terminated ({name})", file=sys.stderr)
        return 128 + exc.signum
    print("vrcorrect: interrupted", file=sys.stderr)
    return 130


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        with _terminate_like_interrupt():
            return int(args.func(args) or 0)
    except (Terminated, KeyboardInterrupt) as exc:
        return _interrupted(exc)
    except VrcorrectError as exc:
        print(f"vrcorrect: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except MemoryError:
        print("vrcorrect: error: out of memory; try a smaller image or pupil", file=sys.stderr)
        return EXIT_INTERNAL
    except Exception as exc:  # never a traceback for a command-line user
        signalled = _interruption(exc)
        if signalled is not None:
            return _interrupted(signalled)
        if os.environ.get("VRCORRECT_DEBUG"):
            raise
        print(f"vrcorrect: internal error: {type(exc).__name__}: {exc} (set VRCORRECT_DEBUG=1 for details)",
              file=sys.stderr)
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
