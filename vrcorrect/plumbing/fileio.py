"""Safe file output: atomic writes that never leave a partial file and never
overwrite a user's file unless asked."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Callable, Iterator, Sequence

from .errors import InputError
from .signals import raise_if_held, signals_deferred


def package_data(name: str) -> Path:
    """Path of a file the package ships in ``vrcorrect/data`` (the one place that knows where it is)."""
    return Path(__file__).resolve().parents[1] / "data" / name


def file_stamp(path: str | os.PathLike[str]) -> tuple[int, int] | None:
    """A file's modification time (ns) and size, or ``None`` when it cannot be read: what a watcher
    compares to notice an edit (the real-time correctors, the eye source, the OpenXR layer)."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_mtime_ns, st.st_size)


def check_writable(path: Path, *, force: bool) -> Path:
    """Fail early, before any work, if ``path`` may not be written."""
    path = Path(path)
    if path.exists() and not force:
        raise InputError(f"{path}: file exists; pass --force to overwrite it")
    if path.exists() and path.is_dir():
        raise InputError(f"{path}: is a directory, expected a file path")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"{path}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise InputError(f"{path}: folder {parent} is not writable")
    with signals_deferred():               # a signal never strands the probe between its creation and removal
        try:                               # what the write will do (a root user passes os.access on /proc)
            fd, probe = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".probe", dir=parent)
        except OSError as exc:
            raise InputError(f"{path}: cannot create a file in folder {parent} ({exc.strerror or exc})") from None
        os.close(fd)
        os.unlink(probe)
    return path


def check_readable(path: str | os.PathLike[str]) -> Path:
    """Fail at once, before heavy imports and work, if the input file ``path`` cannot be read."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, expected an image file")
    if not os.access(path, os.R_OK):
        raise InputError(f"{path}: not readable (permissions)")
    return path


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: Path, *, force: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it into place.

    On any exception the temporary file is removed and ``path`` is untouched (one output of
    :func:`atomic_paths`).
    """
    with atomic_paths([path], force=force) as tmps:
        yield tmps[0]


@contextlib.contextmanager
def atomic_paths(paths: Sequence[Path], *, force: bool = False) -> Iterator[list[Path]]:
    """All-or-nothing output of several files: yield one temporary path beside each of ``paths``;
    when the block succeeds, all are renamed into place with signals held back, so an interruption
    leaves either every output or none (and no temporary file)."""
    targets = [check_writable(Path(p), force=force) for p in paths]
    if len({t.resolve() for t in targets}) != len(targets):
        raise InputError("two outputs name the same file: " + ", ".join(str(t) for t in targets))
    tmps: list[Path] = []
    try:
        with signals_deferred():           # a temporary file is listed for removal as it is made, never after
            for path in targets:
                fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix or ".tmp",
                                           dir=path.parent if str(path.parent) else ".")
                tmps.append(Path(tmp))
                os.close(fd)
                try:
                    mode = path.stat().st_mode & 0o7777 if path.exists() else 0o666 & ~_umask()
                    os.chmod(tmp, mode)
                except OSError:
                    pass
        yield list(tmps)
        raise_if_held()                        # a termination asked for while the outputs were written
        with signals_deferred():
            for path in targets:
                if path.exists() and not force:  # appeared while we worked
                    raise InputError(f"{path}: file exists; pass --force to overwrite it")
            for tmp, path in zip(tmps, targets):
                os.replace(tmp, path)
    finally:
        with signals_deferred():           # a second signal does not cut the clean-up short
            for tmp in tmps:
                with contextlib.suppress(FileNotFoundError):
                    tmp.unlink()


def write_text_atomic(path: Path, text: str, *, force: bool = False) -> None:
    with atomic_path(path, force=force) as tmp:
        tmp.write_text(text, encoding="utf-8")


Writer = Callable[[Path], object]
"""Writes one output into the temporary path it is given."""


def text_writer(text: str) -> Writer:
    """A writer of ``text`` (UTF-8) for :func:`write_together`."""
    return lambda tmp: tmp.write_text(text, encoding="utf-8")


def write_together(outputs: Sequence[tuple[Path, Writer]], *, force: bool = False) -> None:
    """Write a command's outputs all or nothing: each ``(path, writer)`` pair's writer fills a
    temporary file beside ``path``; only when every writer has succeeded are they renamed into place
    together (:func:`atomic_paths`)."""
    with atomic_paths([Path(path) for path, _ in outputs], force=force) as tmps:
        for (_, writer), tmp in zip(outputs, tmps):
            writer(tmp)


def write_with(path: Path, writer: Writer, *, force: bool = False) -> None:
    """Call ``writer(tmp_path)`` and move the result to ``path`` atomically."""
    write_together([(path, writer)], force=force)
