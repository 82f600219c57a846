"""Command line: ``vrcorrect <command> ...``: the parser, built from one module per command
(each with an ``add_parser`` and its ``cmd_*``), and the one place that turns errors and signals
into exit codes.

Library errors (:class:`vrcorrect.plumbing.errors.VrcorrectError`) become one line on
stderr and exit status 2; a command-line user never sees a traceback
(``VRCORRECT_DEBUG=1`` shows it for bug reports).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
from typing import Sequence

from ..plumbing.errors import VrcorrectError
from ..plumbing.signals import Terminated, command_signals
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
    args = parser.parse_args(rx.join_line_values(list(sys.argv[1:] if argv is None else argv)))
    try:
        with command_signals():
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
