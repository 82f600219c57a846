"""GLSL program loader: one ``.glsl`` file per program, one stage per define.

Everything here but :func:`compile_program` and :func:`compile_compute` is plain text
processing, testable without OpenGL.

File conventions (docs/architecture.md, 'Shaders')
--------------------------------------------------
* One file per program in the repository's top-level ``shaders/`` folder (see
  :func:`shaders_dir` for how it is found, installed or not). Its first line is
  ``#version`` (``#version 330 core``; compute shaders need ``#version 430``).
* Stages live in ``#if defined VERTEX_SHADER`` / ``GEOMETRY_SHADER`` / ``FRAGMENT_SHADER`` /
  ``COMPUTE_SHADER`` blocks. The loader assembles the file once per stage it names, with
  that stage's macro defined.
* ``#include "name.glsl"`` on a line of its own pulls in another file of ``shaders/``
  (path relative to ``shaders/``, never outside it). Included files have no ``#version``.
  An include is expanded every time it appears, like C's: a library that may be included
  twice guards itself with ``#ifndef``. An include cycle is an error naming the chain of
  files and lines. Includes are expanded before GLSL's own preprocessor runs, so an include
  inside a stage block is expanded for every stage (and compiled only in its own).
  moderngl has an include mechanism of its own that rewrites ``#include "..."`` anywhere in
  the text, comments too; the loader leaves none for it (in comments it becomes ``# include``).
* The caller's ``#define``\\ s and the stage macro are inserted right after ``#version``.

Line mapping
------------
Each file that goes into one stage's text gets a number *k*: 0 for the program file, then
included files in order of first appearance, and last the pseudo-file ``<defines>`` for the
inserted defines. Before every run of lines from file *k* starting at its line *n* the
loader writes ``#line (k * LINE_STRIDE + n) k``. The source-string number is the standard
GLSL way to name the file; the line number carries the file as well because Mesa (checked on
Mesa 22.3 llvmpipe) honours ``#line``'s line number but reports every message as source 0
(``0:10012(3): error: ...``). :meth:`ShaderSource.locate` therefore decodes a location from
the line number alone, ``divmod(line, LINE_STRIDE)`` -> (file number, line), and
:meth:`ShaderSource.translate_log` rewrites a driver's log (Mesa ``0:12(3)``, NVIDIA
``0(12)``, AMD/ANGLE ``ERROR: 0:12:``) into ``file.glsl:12(3)``. Lines of the program file
keep their own numbers, so an untranslated message about it still reads right.
"""

from __future__ import annotations

import math
import numbers
import re
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Callable, Mapping, TypeVar, Union

from ..plumbing.errors import InputError, ShaderCompileError, ShaderError, ValidationError

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

STAGES = ("vertex", "geometry", "fragment", "compute")
"""Shader stages the loader knows, in pipeline order; stage ``s`` is selected by ``S_SHADER``."""

LINE_STRIDE = 10_000
"""Line numbers of file *k* are ``k * LINE_STRIDE + line``; a file may have at most 9999 lines."""

DEFINES_FILE = "<defines>"
"""Pseudo-file name of the lines the loader inserts after ``#version``."""

DefineValue = Union[None, int, float, str]
T = TypeVar("T")

_PACKAGE_DIR = Path(__file__).resolve().parents[1]
_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_DIRECTIVE = re.compile(r"\s*#\s*([A-Za-z_]*)")
_INCLUDE = re.compile(r'\s*#\s*include\s+"([^"\s]+)"\s*')
_MODERNGL_INCLUDE = re.compile(r"#include(?=\s)")
_STAGE_REF = re.compile(r"\b(VERTEX|GEOMETRY|FRAGMENT|COMPUTE)_SHADER\b")
# Driver log locations, at the start of a log line (after an optional ERROR:/WARNING: tag).
_LOG_PREFIX = r"^(?P<pre>\s*(?:(?:ERROR|WARNING|error|warning)\s*:\s*)?)"
_LOG_MESA = re.compile(_LOG_PREFIX + r"(?P<src>\d+):(?P<line>\d+)\((?P<col>\d+)\)", re.M)
_LOG_NVIDIA = re.compile(_LOG_PREFIX + r"(?P<src>\d+)\((?P<line>\d+)\)", re.M)
_LOG_PLAIN = re.compile(_LOG_PREFIX + r"(?P<src>\d+):(?P<line>\d+)(?=:)", re.M)


def stage_macro(stage: str) -> str:
    """The macro that selects ``stage``: ``"vertex"`` -> ``"VERTEX_SHADER"``."""
    if stage not in STAGES:
        raise ValidationError("stage", stage, "one of: " + ", ".join(STAGES))
    return f"{stage.upper()}_SHADER"


def shaders_dir() -> Path:
    """The folder that holds the programs.

    Looked up in order: ``vrcorrect/shaders`` inside the package (in a wheel: the files,
    copied there as package data; in a checkout: a symbolic link to the top-level
    ``shaders/``), then the top-level ``shaders/`` beside the package folder (a checkout
    whose link was lost). Editable and regular installs find the same files.
    """
    for candidate in (_PACKAGE_DIR / "shaders", _PACKAGE_DIR.parent / "shaders"):
        if candidate.is_dir():
            return candidate
    raise InputError(f"GLSL folder not found: looked for {_PACKAGE_DIR / 'shaders'} and "
                     f"{_PACKAGE_DIR.parent / 'shaders'}")


# --------------------------------------------------------------------------
# Reading files
# --------------------------------------------------------------------------


def _check_name(name: str, field: str) -> str:
    """A file name relative to ``shaders/``: posix, ``.glsl``, no ``..``, not absolute."""
    allowed = "a .glsl file name relative to shaders/ (e.g. 'passthrough.glsl'), without '..'"
    if not isinstance(name, str) or not name.endswith(".glsl") or "\\" in name:
        raise ValidationError(field, name, allowed)
    path = PurePosixPath(name)
    if path.is_absolute() or any(part in ("..", "") for part in name.split("/")):
        raise ValidationError(field, name, allowed)
    return str(path)


def _chain_text(chain: tuple[tuple[str, int], ...]) -> str:
    """``a.glsl:3 -> b.glsl:7``: where each file of the chain included the next."""
    return " -> ".join(f"{f}:{n}" for f, n in chain)


def _read_lines(root: Path, name: str, chain: tuple[tuple[str, int], ...]) -> list[str]:
    path = root / name
    where = f"{_chain_text(chain)} includes {name}" if chain else name
    if not path.is_file():
        raise InputError(f"{where}: no such file in {root}")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{where}: cannot read {path}: {exc}") from None
    lines = text.splitlines()
    if len(lines) >= LINE_STRIDE:
        raise ShaderError(f"{where}: {len(lines)} lines; a shader file may have at most {LINE_STRIDE - 1}")
    return lines


def _code_part(line: str, in_comment: bool) -> tuple[str, bool]:
    """The line with comments blanked out, and whether a block comment is open at its end."""
    if not in_comment and "/" not in line:
        return line, False                      # most lines: no comment in them
    out = []
    i = 0
    while i < len(line):
        if in_comment:
            end = line.find("*/", i)
            if end < 0:
                return "".join(out), True
            out.append(" ")
            i = end + 2
            in_comment = False
            continue
        slashes, block = line.find("//", i), line.find("/*", i)
        if block < 0 or 0 <= slashes < block:    # a line comment first (or no block comment): the rest goes
            out.append(line[i:] if slashes < 0 else line[i:slashes])
            break
        out.append(line[i:block])
        in_comment = True
        i = block + 2
    return "".join(out), in_comment


def _has_version(line: str) -> bool:
    match = _DIRECTIVE.match(line)
    return bool(match and match.group(1) == "version")


# --------------------------------------------------------------------------
# Assembling one stage
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class ShaderSource:
    """One stage of one program, ready for the driver, with the way back to the files.

    Attributes
    ----------
    program
        The program file, relative to ``shaders/``.
    stage
        One of :data:`STAGES`.
    text
        The assembled GLSL.
    files
        Source-string number -> file (relative to ``shaders/``, or :data:`DEFINES_FILE`).
    origins
        For each line of ``text`` (index 0 is line 1): ``(file, line)`` it came from, or
        ``None`` for a ``#line`` directive the loader wrote.
    """

    program: str
    stage: str
    text: str
    files: tuple[str, ...]
    origins: tuple[tuple[str, int] | None, ...]

    def locate(self, line: int, source: int | None = None) -> tuple[str, int] | None:
        """File and line of a location the driver reported, or ``None`` if it is not ours.

        ``line`` is the reported line number (``k * LINE_STRIDE + n``); ``source`` the
        reported source-string number, used only to reject a contradiction (a driver that
        reports source numbers reports *k*; Mesa reports 0 for every file).
        """
        k, n = divmod(int(line), LINE_STRIDE)
        if n < 1 or k >= len(self.files):
            return None
        if source is not None and source not in (0, k):
            return None
        return self.files[k], n

    def translate_log(self, log: str) -> str:
        """The driver's log with every ``source:line`` location written as ``file.glsl:line``."""
        return translate_log(log, self)


def translate_log(log: str, source: ShaderSource) -> str:
    """Rewrite driver log locations into ``file.glsl:line(column)``.

    Understands Mesa (``0:12(3): error``), NVIDIA (``0(12) : error``) and AMD/ANGLE
    (``ERROR: 0:12: ...``) forms; a location that does not decode is left as it is.
    """

    def mesa(m: re.Match[str]) -> str:
        where = source.locate(int(m["line"]), int(m["src"]))
        return m[0] if where is None else f"{m['pre']}{where[0]}:{where[1]}({m['col']})"

    def plain(m: re.Match[str]) -> str:
        where = source.locate(int(m["line"]), int(m["src"]))
        return m[0] if where is None else f"{m['pre']}{where[0]}:{where[1]}"

    out = []
    for line in log.splitlines(keepends=True):
        for pattern, repl in ((_LOG_MESA, mesa), (_LOG_NVIDIA, plain), (_LOG_PLAIN, plain)):
            new, count = pattern.subn(repl, line, count=1)
            if count:
                line = new
                break
        out.append(line)
    return "".join(out)


def _define_line(name: str, value: DefineValue) -> str:
    field = f"defines.{name}" if isinstance(name, str) else "defines"
    if not isinstance(name, str) or not _IDENT.fullmatch(name) or name.startswith("GL_") or "__" in name:
        raise ValidationError(field, name, "a GLSL identifier ([A-Za-z_][A-Za-z0-9_]*, not GL_..., no '__')")
    if _STAGE_REF.fullmatch(name):
        raise ValidationError(field, name, "not a stage macro (the loader defines the stage's own)")
    if value is None:
        return f"#define {name}"
    if isinstance(value, bool):
        raise ValidationError(field, value, "None (defined, no value), an int, a finite float or a one-line "
                              "string; leave a switch out to turn it off")
    if isinstance(value, numbers.Integral):
        return f"#define {name} {int(value)}"
    if isinstance(value, numbers.Real):
        if not math.isfinite(value):
            raise ValidationError(field, value, "a finite float")
        return f"#define {name} {float(value)!r}"
    if isinstance(value, str) and "\n" not in value and "\r" not in value:
        return f"#define {name} {value.strip()}".rstrip()
    raise ValidationError(field, value, "None (defined, no value), an int, a finite float or a one-line string")


class _Assembler:
    """Expands one program file for one stage (state of a single call)."""

    def __init__(self, root: Path):
        self.root = root
        self.files: dict[str, int] = {}
        self.lines: list[str] = []
        self.origins: list[tuple[str, int] | None] = []

    def directive(self, k: int, n: int) -> None:
        self.lines.append(f"#line {k * LINE_STRIDE + n} {k}")
        self.origins.append(None)

    def expand(self, name: str, lines: list[str], first: int, chain: tuple[tuple[str, int], ...]) -> None:
        """Append ``lines[first-1:]`` of ``name``, expanding includes; ``chain`` leads to ``name``."""
        k = self.files.setdefault(name, len(self.files))
        self.directive(k, first)
        in_comment = False
        for n in range(first, len(lines) + 1):
            line = lines[n - 1]
            code, in_comment_after = _code_part(line, in_comment)
            directive = None if in_comment else _DIRECTIVE.match(code)
            in_comment = in_comment_after
            word = directive.group(1) if directive else None
            here = _chain_text(chain + ((name, n),)) if word in ("include", "version", "line") else ""
            if word == "include":
                match = _INCLUDE.fullmatch(code)
                if not match:
                    raise ShaderError(f'{here}: expected #include "file.glsl", found {line.strip()!r}')
                target = match.group(1)
                try:
                    target = _check_name(target, "#include")
                except ValidationError as exc:
                    raise ShaderError(f"{here}: {exc}") from None
                stack = chain + ((name, n),)
                if target in (f for f, _ in stack):
                    raise ShaderError(f"{_chain_text(stack)} includes {target}: include cycle "
                                      f"({' -> '.join([f for f, _ in stack] + [target])})")
                self.expand(target, _read_lines(self.root, target, stack), 1, stack)
                if n < len(lines):
                    self.directive(k, n + 1)
            elif word == "version":
                raise ShaderError(f"{here}: #version belongs on the first line of the program file only")
            elif word == "line":
                raise ShaderError(f"{here}: #line is reserved for the loader's line mapping")
            else:
                # moderngl expands '#include "x"' itself, anywhere in the text (comments too):
                # none may be left for it (a real directive was handled above).
                self.lines.append(_MODERNGL_INCLUDE.sub("# include", line))
                self.origins.append((name, n))


def _root(root: str | Path | None) -> Path:
    return shaders_dir() if root is None else Path(root)


def _program_lines(name: str, root: Path) -> list[str]:
    lines = _read_lines(root, name, ())
    if not lines or not _has_version(lines[0]) or lines[0] != lines[0].lstrip():
        found = repr(lines[0].strip()) if lines else "an empty file"
        raise ShaderError(f"{name}:1: the first line must be '#version ...' (e.g. '#version 330 core'), "
                          f"found {found}")
    return lines


def program_stages(name: str, *, root: str | Path | None = None) -> tuple[str, ...]:
    """Stages the program file selects with ``#if``/``#ifdef``/``#elif`` on a stage macro.

    Only the program file itself is read (not its includes), in :data:`STAGES` order.
    """
    name = _check_name(name, "shader")
    lines = _program_lines(name, _root(root))
    found = set()
    in_comment = False
    for line in lines:
        code, in_comment_after = _code_part(line, in_comment)
        directive = None if in_comment else _DIRECTIVE.match(code)
        in_comment = in_comment_after
        if directive and directive.group(1) in ("if", "ifdef", "elif"):
            found.update(m.lower() for m in _STAGE_REF.findall(code))
    if not found:
        raise ShaderError(f"{name}: no stage blocks; expected '#if defined VERTEX_SHADER' (or "
                          "GEOMETRY_SHADER, FRAGMENT_SHADER, COMPUTE_SHADER)")
    return tuple(s for s in STAGES if s in found)


def load_stage(name: str, stage: str, *, defines: Mapping[str, DefineValue] | None = None,
               root: str | Path | None = None) -> ShaderSource:
    """Assemble one stage of a program file.

    Parameters
    ----------
    name
        Program file relative to ``shaders/`` (``"passthrough.glsl"``).
    stage
        One of :data:`STAGES`; its macro (``VERTEX_SHADER``...) is defined.
    defines
        Extra macros, inserted after ``#version`` in the given order: ``None`` defines the
        name without a value (a switch for ``#if defined``); an int, a finite float or a
        one-line string becomes its value.
    root
        Folder to read from instead of :func:`shaders_dir` (tests, user shaders).

    Raises
    ------
    ValidationError
        Bad file name, stage, define name or value.
    InputError
        A file (the program or an include) that is missing or unreadable; names the chain.
    ShaderError
        No ``#version`` first line, an include cycle, a malformed ``#include``, a
        ``#version`` or ``#line`` elsewhere, a file of 10000 lines or more.
    """
    name = _check_name(name, "shader")
    macro = stage_macro(stage)
    define_lines = [f"#define {macro}"] + [_define_line(k, v) for k, v in (defines or {}).items()]
    folder = _root(root)
    lines = _program_lines(name, folder)
    body = _Assembler(folder)
    if len(lines) > 1:
        body.expand(name, lines, 2, ())
    else:
        body.files[name] = 0
    files = list(body.files)
    d = len(files)
    files.append(DEFINES_FILE)
    text_lines = [lines[0], f"#line {d * LINE_STRIDE + 1} {d}", *define_lines]
    origins: list[tuple[str, int] | None] = [(name, 1), None]
    origins += [(DEFINES_FILE, i) for i in range(1, len(define_lines) + 1)]
    text_lines += body.lines
    origins += body.origins
    return ShaderSource(program=name, stage=stage, text="\n".join(text_lines) + "\n",
                        files=tuple(files), origins=tuple(origins))


@dataclass(frozen=True)
class ProgramSource:
    """Every stage of one program file, assembled (see :func:`load_program`)."""

    name: str
    stages: tuple[ShaderSource, ...]

    @property
    def stage_names(self) -> tuple[str, ...]:
        return tuple(s.stage for s in self.stages)

    def __getitem__(self, stage: str) -> ShaderSource:
        for s in self.stages:
            if s.stage == stage:
                return s
        raise KeyError(f"{self.name} has no {stage} stage (it has: {', '.join(self.stage_names)})")

    def __contains__(self, stage: object) -> bool:
        return stage in self.stage_names


def load_program(name: str, *, defines: Mapping[str, DefineValue] | None = None,
                 root: str | Path | None = None) -> ProgramSource:
    """Assemble every stage named in the program file (see :func:`load_stage`)."""
    stages = program_stages(name, root=root)
    return ProgramSource(_check_name(name, "shader"),
                         tuple(load_stage(name, s, defines=defines, root=root) for s in stages))


# --------------------------------------------------------------------------
# Compiling (needs a moderngl context)
# --------------------------------------------------------------------------

_MODERNGL_SECTION = re.compile(r"^(vertex|geometry|fragment|compute)_shader$")


def _translate_build_error(message: str, program: ProgramSource) -> str:
    """moderngl's error text ('GLSL Compiler failed' or 'GLSL Linker failed', then per failing
    stage a '<stage>_shader' heading, an underline and the driver's log) with every location
    mapped to its file, one item a line."""
    out = []
    current = program.stages[0]
    for line in message.strip("\n").splitlines():
        text = line.strip()
        heading = _MODERNGL_SECTION.match(text)
        if not text or set(text) == {"="}:
            continue
        if heading and heading.group(1) in program:
            current = program[heading.group(1)]
            out.append(f"  {current.stage} stage:")
        elif text == "Program":
            out.append("  link:")
        else:
            out.append("    " + translate_log(text, current))
    return "\n".join(out)


def _build(program: ProgramSource, build: Callable[[], T]) -> T:
    import moderngl  # optional dependency (the realtime extra): the loader itself works without GL

    try:
        return build()
    except moderngl.Error as exc:
        raw = str(exc)
        raise ShaderCompileError(program.name, _translate_build_error(raw, program), raw) from None


def compile_program(ctx: "moderngl.Context", name: str, *, defines: Mapping[str, DefineValue] | None = None,
                    root: str | Path | None = None) -> "moderngl.Program":
    """Compile and link the vertex (+ geometry) + fragment stages of a program file.

    Raises
    ------
    ShaderCompileError
        The driver refused a stage or the link; the message lists the driver's log with
        every location as ``file.glsl:line(column)``.
    ShaderError
        The file has no vertex or fragment stage (or see :func:`load_stage`).
    """
    source = load_program(name, defines=defines, root=root)
    missing = [s for s in ("vertex", "fragment") if s not in source]
    if missing:
        raise ShaderError(f"{source.name}: no {' or '.join(missing)} stage; a render program needs "
                          "'#if defined VERTEX_SHADER' and '#if defined FRAGMENT_SHADER' blocks"
                          + (" (compile compute programs with compile_compute)" if "compute" in source else ""))
    geometry = source["geometry"].text if "geometry" in source else None
    return _build(source, lambda: ctx.program(vertex_shader=source["vertex"].text,
                                                    fragment_shader=source["fragment"].text,
                                                    geometry_shader=geometry))


def compile_compute(ctx: "moderngl.Context", name: str, *, defines: Mapping[str, DefineValue] | None = None,
                    root: str | Path | None = None) -> "moderngl.ComputeShader":
    """Compile the ``COMPUTE_SHADER`` stage of a program file (needs ``#version 430``)."""
    name = _check_name(name, "shader")
    if "compute" not in program_stages(name, root=root):
        raise ShaderError(f"{name}: no '#if defined COMPUTE_SHADER' block")
    source = ProgramSource(name, (load_stage(name, "compute", defines=defines, root=root),))
    return _build(source, lambda: ctx.compute_shader(source["compute"].text))
