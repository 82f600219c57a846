"""What the specs' validators share: reading a user's file as text, numbers checked against a
range, and unknown keys with a suggestion.

The prescription (:mod:`vrcorrect.specs.prescription`) and the display profile
(:mod:`vrcorrect.specs.display`) validators both collect every
:class:`~vrcorrect.plumbing.errors.FieldProblem` in a document before raising
:class:`~vrcorrect.plumbing.errors.ValidationErrors`; the pieces below are the checks they have
in common. Each caller keeps its own wording: the messages name that caller's fields and files.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from ..plumbing.errors import InputError, FieldProblem, ValidationError

__all__ = [
    "Range", "FileWording", "is_number", "check_number", "positive_finite", "unknown_key_problem",
    "read_utf8_text",
]


def is_number(value: Any) -> bool:
    """True for int and float (and numpy scalars of those kinds), never for bool."""
    if isinstance(value, (bool, np.bool_)):
        return False
    return isinstance(value, (int, float, np.integer, np.floating))


@dataclass(frozen=True)
class Range:
    """The finite numbers a field accepts, ``lo`` to ``hi``, and how to say so.

    Parameters
    ----------
    lo, hi
        The limits (may be infinite: the value itself must still be finite).
    allowed
        What is allowed, in words, for the message (``"a finite number from 1 to 9 (millimetres)"``).
    lo_open, hi_open
        Whether the limit itself is excluded (``0 < v`` rather than ``0 <= v``).
    """

    lo: float
    hi: float
    allowed: str
    lo_open: bool = False
    hi_open: bool = False

    def holds(self, value: float | int) -> bool:
        """Whether ``value`` (already known finite) lies within the limits."""
        above = self.lo < value if self.lo_open else self.lo <= value
        below = value < self.hi if self.hi_open else value <= self.hi
        return above and below


def check_number(problems: list[FieldProblem], field: str, value: Any, rule: Range) -> float | None:
    """Validate one finite number within ``rule``.

    Appends a :class:`FieldProblem` (``field``, ``value``, ``rule.allowed``) and returns ``None`` when
    the value is not a number (bool is not), not finite or out of range; returns it as a float
    otherwise.
    """
    if not is_number(value):
        problems.append(FieldProblem(field, value, rule.allowed))
        return None
    if isinstance(value, (int, np.integer)):
        # Compare before converting: a huge JSON integer would overflow float().
        if not rule.holds(int(value)):
            problems.append(FieldProblem(field, value, rule.allowed))
            return None
        return float(value)
    number = float(value)
    if not math.isfinite(number) or not rule.holds(number):
        problems.append(FieldProblem(field, value, rule.allowed))
        return None
    return number


def unknown_key_problem(field: str, key: Any, value: Any, known: Iterable[str]) -> FieldProblem:
    """The problem of a key that is not a field here, with the closest known one as a hint.

    The hint is the nearest known field by :func:`difflib.get_close_matches` (cutoff 0.6), or
    failing that the one that differs only in case.
    """
    known = tuple(known)
    hint = ""
    if isinstance(key, str):
        close = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
        if not close:
            lowered = {k.lower(): k for k in known}
            if key.lower() in lowered:
                close = [lowered[key.lower()]]
        if close:
            hint = f" (did you mean {close[0]!r}?)"
    return FieldProblem(field, value, f"no such field{hint}; known fields here: {', '.join(known)}")


@dataclass(frozen=True)
class FileWording:
    """How one kind of file's reading problems are told (``str.format`` templates).

    Every template may use ``{path}``; ``unreadable`` also ``{reason}`` (the system's words),
    ``not_utf8`` also ``{offset}`` (of the first bad byte) and ``{byte}`` (its value, an int).
    """

    not_found: str
    is_directory: str
    unreadable: str
    not_utf8: str


def read_utf8_text(path: Path, wording: FileWording) -> str:
    """The text of a UTF-8 file (a byte-order mark is dropped).

    Raises
    ------
    InputError
        The file is missing, a directory, unreadable, or not UTF-8, told in ``wording``.
    """
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(wording.not_found.format(path=path)) from None
    except IsADirectoryError:
        raise InputError(wording.is_directory.format(path=path)) from None
    except OSError as exc:
        raise InputError(wording.unreadable.format(path=path, reason=exc.strerror or exc)) from None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(wording.not_utf8.format(path=path, offset=exc.start, byte=data[exc.start])) from None


def positive_finite(field: str, value: Any) -> float:
    """``value`` as a float when it is a positive finite number (bool is not).

    Raises
    ------
    ValidationError
        Naming ``field``, otherwise.
    """
    if not is_number(value):
        raise ValidationError(field, value, "a positive finite number")
    number = float(value)
    if not (math.isfinite(number) and number > 0):
        raise ValidationError(field, number, "a positive finite number")
    return number
