"""Typed errors.

Every error a user can cause names the field, the value and what is allowed,
in one line.  Library code raises these; only :mod:`vrcorrect.apps.cli` turns them
into an exit status.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable


class VrcorrectError(Exception):
    """Base class of every error vrcorrect raises on purpose."""


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


class ValidationError(VrcorrectError, ValueError):
    """One bad value.

    Parameters
    ----------
    field
        Dotted path of the offending field, e.g. ``"right.sphere_D"``.
    value
        The value that was given.
    allowed
        What would have been accepted, in words (``"-20 to 20 D"``).
    source
        Optional file (and line) the value came from.
    """

    def __init__(self, field: str, value: Any, allowed: str, source: str | None = None):
        self.field = field
        self.value = value
        self.allowed = allowed
        self.source = source
        prefix = f"{source}: " if source else ""
        super().__init__(f"{prefix}{field} = {_show(value)} is not allowed; expected {allowed}")


@dataclass(frozen=True)
class FieldProblem:
    """One problem found while validating a document (kept to report all at once)."""

    field: str
    value: Any
    allowed: str

    def __str__(self) -> str:
        return f"{self.field} = {_show(self.value)} is not allowed; expected {self.allowed}"


class ValidationErrors(VrcorrectError, ValueError):
    """Several problems in one document, reported together."""

    def __init__(self, problems: Iterable[FieldProblem], source: str | None = None):
        self.problems = list(problems)
        self.source = source
        head = f"{source}: " if source else ""
        n = len(self.problems)
        lines = [f"{head}{n} problem{'s' if n != 1 else ''}:"]
        lines += [f"  - {p}" for p in self.problems]
        super().__init__("\n".join(lines))


class InputError(VrcorrectError, OSError):
    """A file that cannot be read, parsed or written as asked."""


class ModelLimitError(VrcorrectError, ValueError):
    """A request the model cannot honour within its resource limits."""


class ShaderError(VrcorrectError, RuntimeError):
    """A GLSL program that cannot be assembled: no ``#version``, an include cycle, a bad directive.

    The message starts with the file and line (``passthrough.glsl:3``) and, for problems
    inside included files, the chain of includes that led there.
    """


class ShaderCompileError(ShaderError):
    """The GL driver rejected a program; every location in the log is mapped back to its file.

    Attributes
    ----------
    program
        The program file, e.g. ``"passthrough.glsl"``.
    log
        The driver's log with each ``source:line`` rewritten as ``file.glsl:line``.
    raw_log
        The driver's log as it came.
    """

    def __init__(self, program: str, log: str, raw_log: str):
        self.program = program
        self.log = log
        self.raw_log = raw_log
        super().__init__(f"shader program {program} failed to build:\n{log}")


class GLError(VrcorrectError, RuntimeError):
    """OpenGL reported an error (``glGetError``) or an operation the driver refused."""


class GLUnavailableError(GLError):
    """No OpenGL context could be created (library missing, no display, version too old)."""


class XrUnavailableError(VrcorrectError, RuntimeError):
    """No OpenXR runtime, or no headset: the message is the paragraph shown to the user."""


class XrSessionError(VrcorrectError, RuntimeError):
    """An OpenXR call failed while the session ran (names the call and the runtime's result)."""


def json_error_location(exc) -> str:
    """Where a ``json.JSONDecodeError`` really is, in words: ``"line L, column C: message"``.

    A trailing comma (``{"a": 1,}``) makes the parser complain at the next token, often on the
    next line; the comma itself is what to fix, so that is where this points.
    """
    doc, pos = exc.doc, exc.pos
    if exc.msg.startswith(("Expecting property name", "Expecting value", "Illegal trailing comma")):
        i = pos - 1
        while i >= 0 and doc[i] in " \t\r\n":
            i -= 1
        if i >= 0 and doc[i] == "," and pos < len(doc) and doc[pos] in "}]":
            line = doc.count("\n", 0, i) + 1
            column = i - (doc.rfind("\n", 0, i) + 1) + 1
            return f"line {line}, column {column}: a comma before the closing {doc[pos]!r} (JSON allows none there)"
    return f"line {exc.lineno}, column {exc.colno}: {exc.msg}"
