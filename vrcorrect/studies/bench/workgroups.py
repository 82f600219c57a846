"""``vrcorrect bench workgroups``: the real-time default's frame under several work-group shapes,
timed on whatever GPU the context has, to choose (or check) each pass's values per thread.

A row or column pass of the ADMM frame runs one work group per line of the spectrum grid; each of
its threads holds some values of each channel of that line, and the work group is the line's length
over that number (:class:`~vrcorrect.runtime.eye_model.WorkGroups`, the corrector's
``work_groups`` option: per pass, and for a cold frame's half-resolution level). The shape changes
no value, only which thread holds it; what it changes is how well the GPU is occupied, which no
byte count shows.

Each setting below gets its own :class:`~vrcorrect.runtime.corrector.Corrector` on one eye, with
that shape as its ``work_groups`` option (the eye model built once). Its frames are timed by the
routine ``bench cost`` times its own with (:func:`~vrcorrect.studies.bench.frame_timing.time_frames`):
after :data:`~vrcorrect.studies.bench.cost.WARM_UP_S` seconds of untimed frames (a GPU raises its
clocks under load), **interleaved**, in rounds of
:data:`~vrcorrect.studies.bench.frame_timing.PER_ROUND` (two untimed frames first), the order
reversed every other round, so that a drift of the clocks falls on every setting alike: changing
content (a new picture each frame, the budget case) and cold frames (a reset before each, as a cut).
Each frame's GPU time comes from a ``GL_TIME_ELAPSED`` query around it; the medians are reported.
Every setting's output after the same three frames is compared with the default's, to the last bit
of the 8-bit picture. Besides the values a thread, two settings give a column pass's work group two
spectrum columns (``WorkGroups.column_lines``): its threads then read neighbouring columns of a grid
row side by side, where one column a group reads one value a row. On llvmpipe the figures measure
CPU cores, not a GPU: the command runs there (the tests run it), but its choice is for a GPU. Layer
6.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from tqdm import tqdm

from ...runtime.corrector import Corrector, CorrectorOptions, build_eye_model
from ...runtime.eye_model import WORK_GROUP_PASSES, WorkGroups
from ...runtime.gl import headless_context, read_framebuffer, release, render_target, upload_texture, write_texture
from ...specs.display import get_display
from ...specs.prescription import bundled_sample_path, load_prescription
from . import machine_description, markdown_table, publish
from .cost import HEADSET_SIZE, WARM_UP_S, check_frames
from .frame_timing import PER_ROUND, Subject, time_frames

__all__ = ["PASSES", "SETTINGS", "PER_ROUND", "Setting", "run_workgroup_bench"]

PASSES = WORK_GROUP_PASSES
"""The passes that have a work-group shape, in the order the tables print them."""


@dataclass(frozen=True)
class Setting:
    """A label and a work-group shape."""

    label: str
    shape: WorkGroups


_ROWS_8_COLUMNS_4 = {**dict.fromkeys(WORK_GROUP_PASSES, 8), "COLUMNS": 4}
SETTINGS: tuple[Setting, ...] = (
    Setting("the default", WorkGroups()),
    Setting("8 everywhere (before 2026-11-27)", WorkGroups.every(8)),
    Setting("4 everywhere", WorkGroups.every(4)),
    Setting("2 everywhere", WorkGroups.every(2)),
    Setting("columns 4, rows 8", WorkGroups(_ROWS_8_COLUMNS_4, _ROWS_8_COLUMNS_4)),
    Setting("the default, coarse columns 8", WorkGroups(coarse={"COLUMNS": 8})),
    Setting("the default, 2 columns a column work group", WorkGroups(column_lines={"full": 2, "coarse": 2})),
    Setting("columns 8, 2 columns a column work group",
            WorkGroups({"COLUMNS": 8}, {"COLUMNS": 8}, column_lines={"full": 2, "coarse": 2})),
)
"""The settings compared, the default first (the ratios are to it)."""


def run_workgroup_bench(size: tuple[int, int] = HEADSET_SIZE, display_name: str = "quest2",
                        rx_path: str | None = None, frames: int = 20, settings: Sequence[Setting] = SETTINGS,
                        eye: str = "right", out: Path = Path("docs/benchmarks.md"), write: bool = True,
                        json_out: Path | None = None, force: bool = False, warm_up_s: float = WARM_UP_S,
                        progress: bool = True) -> dict[str, Any]:
    """Time the default frame under each setting (module docstring): ``frames`` changing and
    ``frames`` cold frames each; returns the report (``rows``, ``markdown``), writes the
    ``workgroups`` section of ``out`` and, with ``json_out``, the JSON."""
    check_frames(frames, "timed frames per setting")
    display = get_display(display_name)
    rx = load_prescription(rx_path or bundled_sample_path())
    W, H = size
    ctx = headless_context(require=430)
    renderer = ctx.info.get("GL_RENDERER", "?")
    model = build_eye_model(rx.eye(eye), display, CorrectorOptions())
    rng = np.random.default_rng(0)
    pictures = [rng.integers(0, 256, (H, W, 3), dtype=np.uint8) for _ in range(2)]
    src = upload_texture(ctx, pictures[0])
    tex, fbo = render_target(ctx, width=W, height=H)
    correctors: list[Corrector] = []

    def picture(i: int) -> None:
        write_texture(src, pictures[i % 2])

    try:
        outputs = []
        for s in settings:
            c = Corrector(ctx, rx, display, eye, eye_model=model,
                          options=CorrectorOptions(work_groups=s.shape))
            correctors.append(c)
            for p in (0, 1, 0):                          # the same three frames for every setting
                write_texture(src, pictures[p])
                c.apply(src, fbo)
            outputs.append(read_framebuffer(fbo))
        rounds = -(-int(frames) // PER_ROUND)
        subjects = [Subject(apply=lambda c=c: c.apply(src, fbo), picture=picture, reset=c.reset) for c in correctors]
        with tqdm(total=2 * rounds * len(settings), desc="bench workgroups", unit="run", leave=False,
                  disable=None if progress else True) as bar:
            timed = time_frames(ctx, subjects, frames, warm_up_s, progress=bar.update)
    finally:
        for c in correctors:
            c.release()
        release(fbo, tex, src)
        ctx.release()
    changing = [t["changing"].gpu_ms for t in timed]
    cold = [t["cold"].gpu_ms for t in timed]
    rows = []
    for s, out_image, ch, co in zip(settings, outputs, changing, cold):
        rows.append({"setting": s.label, "values_per_thread": s.shape.table(),
                     "coarse_values_per_thread": s.shape.table(coarse=True),
                     "column_lines": dict(s.shape.column_lines),
                     "changing_gpu_ms": statistics.median(ch) if ch else None,
                     "cold_gpu_ms": statistics.median(co) if co else None,
                     "changing_frames_ms": ch, "cold_frames_ms": co,
                     "same_output_as_default": bool(np.array_equal(out_image, outputs[0]))})
    report = {"size": [W, H], "display": display.name, "eye": eye, "renderer": renderer,
              "machine": machine_description(), "frames": int(frames), "warm_up_s": warm_up_s, "rows": rows}
    report["markdown"] = _markdown(report)
    return publish(report, "workgroups", out, write, json_out, force)


def _ratio(value: float | None, base: float | None) -> str:
    return "-" if value is None or not base else f"{value / base:.2f}"


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


def _markdown(report: Mapping[str, Any]) -> str:
    rows = report["rows"]
    base = rows[0]
    W, H = report["size"]
    table = markdown_table(
        ("setting", "values a thread: rows target / start / update / guard, columns; columns a work group",
         "changing frame, ms (GPU)",
         "× the default", "cold frame, ms (GPU)", "× the default", "same output"),
        [(r["setting"], _describe(r), _ms(r["changing_gpu_ms"]), _ratio(r["changing_gpu_ms"], base["changing_gpu_ms"]),
          _ms(r["cold_gpu_ms"]), _ratio(r["cold_gpu_ms"], base["cold_gpu_ms"]),
          "yes" if r["same_output_as_default"] else "**no**") for r in rows])
    return (f"## Work-group shapes of the real-time default (`vrcorrect bench workgroups`): {W}x{H}, one eye\n\n"
            f"Machine: {report['machine']}; OpenGL renderer: {report['renderer']}. Display `{report['display']}`, "
            f"the {report['eye']} eye of the prescription. Each setting's frames were timed interleaved with the "
            f"others' after {report['warm_up_s']:g} s of untimed frames, in rounds of {PER_ROUND}, "
            f"{report['frames']} changing and {report['frames']} cold frames each; medians of each frame's GPU time "
            "by timer query. Same output: the 8-bit picture after the same three frames equals the default's to "
            "the last bit. On a software renderer these are CPU figures, not a GPU's.\n\n" + table + "\n")


def _describe(row: Mapping[str, Any]) -> str:
    full, coarse = row["values_per_thread"], row["coarse_values_per_thread"]
    lines = row.get("column_lines", {"full": 1, "coarse": 1})
    shape = " / ".join(str(full[p]) for p in PASSES[:-1]) + f", {full['COLUMNS']} (coarse columns {coarse['COLUMNS']})"
    if lines["full"] == lines["coarse"] == 1:
        return shape
    return shape + f"; {lines['full']} columns a work group (coarse {lines['coarse']})"
