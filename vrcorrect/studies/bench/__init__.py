"""Benchmarks (not tests): each measures one thing, returns its table and writes it into its own
section of ``docs/benchmarks.md``, naming the machine it ran on. The command that runs them,
``vrcorrect bench``, is :mod:`vrcorrect.apps.bench`; this package is what it measures and how.

The command's ``--out`` defaults to the repository's ``docs/benchmarks.md`` only when it runs
inside the checkout this package is imported from (:func:`default_out`); anywhere else (an
installed package, another folder) it must be named, so a run never writes a stray
``docs/benchmarks.md`` relative to wherever it was started."""

from __future__ import annotations

import json
import os
import platform
import re
import statistics
import time
from datetime import date
from pathlib import Path
from typing import Callable, Sequence

from ...plumbing.errors import InputError
from ...plumbing.fileio import write_text_atomic


def machine_description() -> str:
    """One line naming the machine: CPU model, cores, memory, OS, Python."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = ""
    try:
        kb = int(Path("/proc/meminfo").read_text().split()[1])
        mem = f", {kb / 1024 ** 2:.0f} GiB RAM"
    except (OSError, ValueError, IndexError):
        pass
    return (f"{cpu}, {os.cpu_count()} cores{mem}, {platform.system()} {platform.release()}, "
            f"Python {platform.python_version()}")


def median_seconds(fn: Callable[[], object], repeats: int, warmup: int = 1) -> tuple[float, list[float]]:
    """Median wall time of ``fn`` over ``repeats`` runs after ``warmup`` runs."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def write_section(path: Path, name: str, body: str) -> None:
    """Replace (or append) the section ``name`` of the benchmarks file, atomically."""
    begin, end = f"<!-- bench:{name} -->", f"<!-- /bench:{name} -->"
    block = f"{begin}\n{body.rstrip()}\n\n_Run on {date.today().isoformat()}._\n{end}"
    text = path.read_text(encoding="utf-8") if path.exists() else (
        "# vrcorrect benchmarks\n\nWritten by `vrcorrect bench ...`; each section names the machine it ran on. "
        "Timings are medians of several runs; these machines are shared and noisy, so compare methods "
        "as ratios measured in one run.\n")
    pattern = re.compile(re.escape(begin) + ".*?" + re.escape(end), re.S)
    if pattern.search(text):
        text = pattern.sub(lambda _: block, text)
    else:
        text = text.rstrip() + "\n\n" + block + "\n"
    write_text_atomic(path, text, force=True)


def publish(report: dict, name: str, out: Path, write: bool, json_out: Path | None, force: bool) -> dict:
    """Write a bench's ``report`` (a dict with ``markdown``): with ``json_out``, everything but the
    markdown as JSON there (``force`` to overwrite); with ``write``, the markdown as section ``name``
    of ``out``. Returns the report."""
    if json_out is not None:
        write_text_atomic(json_out, json.dumps({k: v for k, v in report.items() if k != "markdown"}, indent=2) + "\n",
                          force=force)
    if write:
        write_section(out, name, report["markdown"])
    return report


# ---------------------------------------------------------------- where the command writes

#: The benchmarks file inside the repository (``--out``'s default there).
BENCHMARKS_FILE = Path("docs") / "benchmarks.md"


def checkout_root() -> Path | None:
    """The repository checkout this package is imported from, or None (an installed package)."""
    root = Path(__file__).resolve().parents[3]              # vrcorrect/studies/bench/__init__.py
    if (root / "pyproject.toml").is_file() and (root / "vrcorrect").is_dir() and (root / "docs").is_dir():
        return root
    return None


def default_out(cwd: Path | None = None) -> Path:
    """``--out``'s default: the checkout's ``docs/benchmarks.md`` when run inside that checkout (any
    folder of it); anywhere else an :class:`InputError` asking for ``--out``."""
    root = checkout_root()
    here = (Path.cwd() if cwd is None else Path(cwd)).resolve()
    if root is not None and (here == root or root in here.parents):
        return root / BENCHMARKS_FILE
    where = f"the vrcorrect repository at {root}" if root is not None else "a vrcorrect repository checkout"
    raise InputError(f"--out: no default outside {where} (the default is its tracked {BENCHMARKS_FILE}); "
                     "pass --out FILE.md, or --no-write to print only")
