"""Which line of an eye chart this eye reads, uncorrected and corrected (``vrcorrect acuity``, whose
command is :mod:`vrcorrect.apps.acuity`, and the evaluation's acuity column).

The chart, the observer and the acuity rule are :mod:`vrcorrect.vision.acuity` (Watson & Ahumada 2008,
calibrated there).  This study adds the corrections (layer 4, the solvers), the table and the
panel: every drawable chart line's scoring image (the five chart letters and the observer's
ten templates) is corrected as a whole by each method - ``make_problem(target, kernel,
reference_kernel)`` with the project's default target, what the same eye sees with its glasses
on - then seen through the eye and read.  ``none`` (the chart displayed as it is) is always read,
as "uncorrected".

Nothing heavy at import (no torch; the physics and solvers on use); ``paper`` and
``conventional`` import torch when they run.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ..plumbing.errors import ValidationError
from ..specs.display import encode
from ..specs.vocabulary import Method, names

if TYPE_CHECKING:  # annotations only: importing these at run time would slow the command line's start
    from ..physics.kernel import EyeKernel, KernelOptions
    from ..specs.display import DisplayProfile
    from ..specs.prescription import EyeRx
    from ..vision.acuity import AcuityScore, Chart, Observer

__all__ = ["METHODS", "AcuityResult", "measure_acuity", "check_methods", "method_label", "summary_line",
           "line_table", "acuity_panel"]

#: Correction methods the command accepts (``none``, uncorrected, is always read).
METHODS: tuple[str, ...] = names((Method.FAST, Method.WIENER, Method.PAPER, Method.CONVENTIONAL))

_READ_RGB = (0, 150, 70)        # the last line read
_BELOW_RGB = (205, 205, 205)    # lines the display's pixels cannot draw


@dataclass(frozen=True, eq=False)
class AcuityResult:
    """The chart read by one eye on one display, uncorrected and with each correction.

    Attributes
    ----------
    eye, display
        Who read, on what.
    chart
        The chart (:class:`vrcorrect.vision.acuity.Chart`).
    scores
        ``{"none": AcuityScore, method: AcuityScore, ...}``, uncorrected first.
    glasses
        The same eye with its glasses on (sphere and cylinder corrected; the corrections' target)
        reading the chart as it is: the best a correction could hope for on this display.
    sharp_scores
        Like ``scores``, read by the sharp-template observer: its templates are the letters as the
        eye sees them with its glasses on (:func:`vrcorrect.vision.acuity.score_acuity`'s
        ``template_views``), as a person who has not adapted to the blur or the correction.
    displayed
        Per method, the displayed image of each chart line (None below the display's pixels).
    seconds
        Wall time: ``"kernel"`` (both kernels), then per method (solving and reading every line).
    kernel
        The eye's kernel on this display.
    """

    eye: EyeRx
    display: DisplayProfile
    chart: Chart
    scores: dict[str, AcuityScore]
    glasses: AcuityScore
    displayed: dict[str, tuple[np.ndarray | None, ...]]
    seconds: dict[str, float]
    kernel: EyeKernel
    sharp_scores: dict[str, AcuityScore]

    def logmar(self, method: str, observer: str = "ideal") -> float | None:
        """The reading with ``method`` by the ``"ideal"`` or the ``"sharp"``-template observer."""
        if observer not in ("ideal", "sharp"):
            raise ValidationError("observer", observer, "'ideal' or 'sharp'")
        return (self.scores if observer == "ideal" else self.sharp_scores)[method].logmar

    def as_dict(self) -> dict:
        """JSON-ready: ``uncorrected_logmar``, ``<method>_logmar``, and per method the lines read."""
        from ..physics.kernel_report import explain  # on use: start-up time

        out: dict = {"uncorrected_logmar": self.scores["none"].logmar}
        for m in self.scores:
            if m != Method.NONE:
                out[f"{m}_logmar"] = self.scores[m].logmar
        out["glasses_logmar"] = self.glasses.logmar
        for m, sc in self.sharp_scores.items():
            out[f"{method_label(m)}_logmar_sharp_templates"] = sc.logmar
        obs = self.scores["none"].observer
        d = self.display
        out.update({
            "methods": {method_label(m): s.as_dict() for m, s in self.scores.items()},
            "methods_sharp_templates": {method_label(m): s.as_dict() for m, s in self.sharp_scores.items()},
            "glasses": self.glasses.as_dict(),
            "eye": {"sphere_D": self.eye.sphere_D, "cylinder_D": self.eye.cylinder_D, "axis_deg": self.eye.axis_deg,
                    "pupil_diameter_mm": self.eye.pupil_diameter_mm, "accommodation_D": self.eye.accommodation_D},
            "display": {"name": d.name, "title": d.title, "pixels_per_degree": d.pixels_per_degree,
                        "distance_m": _metres(d.distance_m)},
            "viewing_distance_m": _metres(self.kernel.report.viewing.distance_m),
            "noise_contrast_arcmin": obs.noise_contrast_arcmin,
            "observer": {"trials_per_letter": obs.trials_per_letter, "criterion": obs.criterion, "seed": obs.seed},
            "seconds": {method_label(k): v for k, v in self.seconds.items()},
            "kernel_decisions": explain(self.kernel.report),
        })
        return out


def _metres(distance_m: float) -> float | None:
    """A distance for JSON: None for optical infinity."""
    return None if math.isinf(distance_m) else distance_m


def measure_acuity(eye: EyeRx, display: DisplayProfile, methods: Sequence[str] = ("fast",),
                   kernel_options: KernelOptions | None = None, *, observer: Observer | None = None,
                   top_logmar: float = 1.0, bottom_logmar: float = -0.3, contrast: float = 1.0,
                   chart_seed: int = 0, progress: Callable[[int, int], None] | None = None) -> AcuityResult:
    """Read the chart uncorrected and with each correction ``methods``.

    Parameters
    ----------
    eye
        :class:`vrcorrect.specs.prescription.EyeRx`.
    display
        :class:`vrcorrect.specs.display.DisplayProfile`.
    methods
        Some of :data:`METHODS` (``"none"`` and repeats are ignored: uncorrected is always read).
    kernel_options
        :class:`vrcorrect.physics.kernel.KernelOptions` (viewing distance, chromatic aberration, ...).
    observer
        :class:`vrcorrect.vision.acuity.Observer` (default: the calibrated one).
    top_logmar, bottom_logmar, chart_seed
        The chart (:func:`vrcorrect.vision.acuity.chart_lines`).
    contrast
        Contrast scale of the corrections' target, (0, 1] (``make_problem``'s; 1 = none).
    progress
        Optional ``progress(done, total)`` over the two kernel builds and each line x method.

    Returns
    -------
    AcuityResult
    """
    from ..physics.kernel import build_kernel, build_reference_kernel  # on use: start-up time (apps/__init__)
    from ..solvers import make_problem, solve  # on use: start-up time (the CLI imports the studies to build its parser)
    from ..vision.acuity import (  # on use: start-up time (the CLI imports the studies to build its parser)
        Observer,
        build_chart,
        score_acuity,
    )

    chosen = check_methods(methods)
    if not (isinstance(contrast, (int, float)) and 0.0 < contrast <= 1.0):
        raise ValidationError("contrast", contrast, "a number in (0, 1]")
    observer = observer or Observer()
    t0 = time.perf_counter()
    kernel = build_kernel(eye, display, kernel_options)
    reference = build_reference_kernel(eye, display, kernel_options)
    seconds = {"kernel": time.perf_counter() - t0}
    # gaps of two kernel widths: a corrected letter spreads about one kernel width on the display
    # and the eye spreads it one more, so no template's light reaches another's cell
    chart = build_chart(display, 2 * kernel.size, top_logmar, bottom_logmar, chart_seed)
    drawable = sum(s is not None for s in chart.sheets)
    total, done = 2 + drawable * (1 + len(chosen)), 2
    if progress is not None:
        progress(done, total)
    scores, displayed = {}, {}
    for method in (Method.NONE.value,) + chosen:
        t1 = time.perf_counter()
        shown = []
        for target in chart.targets:
            if target is None or method == Method.NONE:
                shown.append(target)
            else:
                shown.append(solve(make_problem(target, kernel, reference, contrast=contrast), method).image)
            if target is not None and progress is not None:
                done += 1
                progress(done, total)
        displayed[method] = tuple(shown)
        scores[method] = score_acuity(chart, shown, kernel, display, observer)
        seconds[method] = time.perf_counter() - t1
    glasses = score_acuity(chart, chart.targets, reference, display, observer)
    sharp_views = tuple(s.seen_lms for s in glasses.lines)
    sharp = {m: score_acuity(chart, displayed[m], kernel, display, observer, template_views=sharp_views,
                             seen_views=tuple(s.seen_lms for s in scores[m].lines))
             for m in displayed}
    return AcuityResult(eye=eye, display=display, chart=chart, scores=scores, glasses=glasses,
                        displayed=displayed, seconds=seconds, kernel=kernel, sharp_scores=sharp)


def check_methods(methods: Sequence[str]) -> tuple[str, ...]:
    if isinstance(methods, str):
        methods = (methods,)
    chosen: list[str] = []
    for m in methods:
        if m == Method.NONE or m in chosen:
            continue
        if m not in METHODS:
            raise ValidationError("methods", m, "some of " + ", ".join(METHODS))
        chosen.append(m)
    return tuple(chosen)


# --------------------------------------------------------------------------
# Text
# --------------------------------------------------------------------------


def method_label(method: str) -> str:
    return "uncorrected" if method == Method.NONE else method


def _reading_text(score) -> str:
    if score.logmar is None:
        return f"none ({score.snellen})"
    note = " (display limit)" if score.limit == "pixels" else ""
    return f"{score.logmar:.2f} ({score.snellen}){note}"


def _columns(result: AcuityResult) -> list[tuple[str, AcuityScore]]:
    """(label, score): uncorrected, each method, then the eye with its glasses (the target)."""
    return [(method_label(m), s) for m, s in result.scores.items()] + [("with glasses", result.glasses)]


def _sharp_columns(result: AcuityResult) -> list[AcuityScore]:
    """The sharp-template observer's scores in :func:`_columns`' order (with glasses: one observer)."""
    return list(result.sharp_scores.values()) + [result.glasses]


def summary_line(result: AcuityResult, observer: str = "ideal") -> str:
    """``uncorrected 0.50 (20/63) -> fast 0.30 (20/40), wiener 0.40 (20/50); with glasses ...``."""
    scores = result.scores if observer == "ideal" else result.sharp_scores
    head = f"uncorrected {_reading_text(scores['none'])}"
    rest = [f"{m} {_reading_text(s)}" for m, s in scores.items() if m != Method.NONE]
    return (head + (" -> " + ", ".join(rest) if rest else "")
            + f"; with glasses {_reading_text(result.glasses)}")


def line_table(result: AcuityResult) -> list[str]:
    """Proportion correct per chart line and method; ``*`` marks a line read, ``-`` one not drawable."""
    columns = _columns(result)
    rows = [f"{'line':>5} {'Snellen':>9} {'px':>6}  " + "  ".join(f"{label:>12}" for label, _ in columns)]
    for i, line in enumerate(result.chart.lines):
        cells = []
        for _, score in columns:
            s = score.lines[i]
            cells.append(f"{'-':>12}" if s.proportion_correct is None
                         else f"{s.proportion_correct:>11.2f}{'*' if s.read else ' '}")
        rows.append(f"{line.logmar:>+5.1f} {line.snellen:>9} {line.letter_height_px:>6.1f}  " + "  ".join(cells))
    return rows


# --------------------------------------------------------------------------
# The panel
# --------------------------------------------------------------------------


def _default_font(px: int):
    try:
        return ImageFont.load_default(size=px)
    except TypeError:  # pragma: no cover - Pillow without FreeType
        return ImageFont.load_default()


def acuity_panel(result: AcuityResult, title: str | None = None) -> np.ndarray:
    """The chart as the eye sees it, sRGB uint8 ``(H, W, 3)``: one column per method (uncorrected
    first), and last the same eye with its glasses on (the corrections' target).

    Each row is one chart line (five letters) as seen; a green box marks the last line the ideal
    observer reads (and a green bar each line it reads; the sharp-template observer's reading is
    printed under it); lines below the display's pixels are a grey strip saying so.  The
    seen lines are scaled up by a whole factor (nearest neighbour) when the display's pixels make
    them too small to look at.
    """
    from ..vision.forward import lms_to_display  # on use: start-up time (apps/__init__)

    chart, kernel, display = result.chart, result.kernel, result.display
    columns = _columns(result)
    sheets = [s for s in chart.sheets if s is not None]
    top_cell = sheets[0].cell_px if sheets else 16
    scale = max(1, min(6, int(round(360 / (5 * top_cell)))))
    width = 5 * top_cell * scale
    font_px = 14
    font, small = _default_font(font_px), _default_font(12)
    gutter, gap, head = 118, 18, 4 * (font_px + 4) + 10
    below_h = 2 * (font_px + 4)
    # lines below the display's pixels: one strip for all of them (they are the chart's smallest)
    below = [i for i, s in enumerate(chart.sheets) if s is None]
    shown = [i for i in range(len(chart.lines)) if chart.sheets[i] is not None or i == (below[0] if below else -1)]
    heights = {i: below_h if chart.sheets[i] is None else chart.sheets[i].cell_px * scale for i in shown}
    heights = [heights.get(i, 0) for i in range(len(chart.lines))]
    height = head + sum(heights) + 6 * len(shown) + 10
    im = Image.new("RGB", (gutter + len(columns) * (width + gap), height), "white")
    draw = ImageDraw.Draw(im)
    draw.text((6, 4), title or "", fill="black", font=font)
    for j, ((label, score), sharp) in enumerate(zip(columns, _sharp_columns(result))):
        x0 = gutter + j * (width + gap)
        draw.text((x0, 4 + font_px + 4), label, fill="black", font=font)
        draw.text((x0, 4 + 2 * (font_px + 4)), "reads " + _reading_text(score), fill=_READ_RGB if score.logmar
                  is not None else (180, 0, 0), font=font)
        draw.text((x0, 4 + 3 * (font_px + 4)), "sharp-template observer: " + _reading_text(sharp),
                  fill=(90, 90, 90), font=small)
        y = head
        for i, (line, sheet) in enumerate(zip(chart.lines, chart.sheets)):
            if i not in shown:
                continue
            h = heights[i]
            s = score.lines[i]
            last = chart.lines[below[-1]] if sheet is None else line
            if j == 0:
                label = f"{line.logmar:+.1f}  {line.snellen}" if last is line else \
                    f"{line.logmar:+.1f} to\n{last.logmar:+.1f}"
                draw.text((6, y + max(0, h // 2 - font_px)), label, fill="black", font=font)
            if sheet is None:
                draw.rectangle([x0, y, x0 + width - 1, y + h - 1], fill=_BELOW_RGB)
                size = (f"{line.letter_height_px:.1f} px letters" if last is line else
                        f"{line.letter_height_px:.1f} to {last.letter_height_px:.1f} px letters")
                draw.text((x0 + 6, y + 4), f"{size}: below the display's pixels", fill=(90, 90, 90), font=small)
            else:
                rows, cols = sheet.chart_row
                seen = encode(display, lms_to_display(s.seen_lms, kernel))[rows, cols]
                u8 = np.round(np.clip(seen, 0.0, 1.0) * 255.0).astype(np.uint8)
                tile = Image.fromarray(u8, "RGB").resize((u8.shape[1] * scale, u8.shape[0] * scale), Image.NEAREST)
                left = x0 + (width - tile.width) // 2          # centred, as on a printed chart
                im.paste(tile, (left, y))
                if s.read:
                    draw.rectangle([x0 - 6, y, x0 - 3, y + h - 1], fill=_READ_RGB)
                if score.logmar is not None and math.isclose(line.logmar, score.logmar):
                    draw.rectangle([left - 3, y - 2, left + tile.width + 2, y + h + 1], outline=_READ_RGB, width=3)
            y += h + 6
    return np.asarray(im)
