"""The eye chart of the simulated acuity (:mod:`vrcorrect.vision.acuity`): Sloan letters drawn
procedurally, logMAR lines of five letters, and each line's sheet on a display.

The chart
---------
Sloan letters C D H K N O R S V Z (Sloan 1959; the ETDRS chart's letters,
Ferris et al. 1982), each a square of five stroke widths, drawn here
procedurally on a 5 x 5 stroke grid (no font file): straight strokes are
rectangles and bands, round strokes are rings of one stroke width, and the
pixels are the area average of an 8 x 8 supersampling.  Black (0) on white
(1), in linear light.  Five letters a line, chosen with a fixed seed and no
letter repeated within a line; lines in 0.1 logMAR steps (default +1.0 down to
-0.3); letter height ``5 arcmin x 10**logMAR`` (20/20 = logMAR 0: strokes of
1 arcmin), converted to display pixels with the display's pixels per degree;
letters one letter width apart (ETDRS crowding).  A line whose letter height
is below 5 display pixels (a stroke narrower than one pixel) cannot be shown
on that display: it is marked ``below the display's pixels`` and never
scored.

Layer 3: numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..plumbing.errors import ModelLimitError, ValidationError
from ..specs.display import DisplayProfile

__all__ = ["SLOAN_LETTERS", "LETTERS_PER_LINE", "LOGMAR_STEP", "MIN_LETTER_PX", "LETTER_ARCMIN_AT_0", "SUPERSAMPLE",
           "LOGMAR_RANGE", "MAX_SHEET_PX", "letter_height_arcmin", "snellen", "sloan_letter", "ChartLine",
           "chart_lines", "LineSheet", "line_sheet", "Chart", "build_chart"]

#: The ten Sloan letters, in the order of the observer's templates.
SLOAN_LETTERS: tuple[str, ...] = ("C", "D", "H", "K", "N", "O", "R", "S", "V", "Z")
#: Letters on each chart line.
LETTERS_PER_LINE = 5
#: Step between chart lines (logMAR).
LOGMAR_STEP = 0.1
#: Letter height (px) below which a stroke (height / 5) is narrower than one display pixel.
MIN_LETTER_PX = 5.0
#: Letter height at logMAR 0 (arcmin): 20/20, strokes of 1 arcmin.
LETTER_ARCMIN_AT_0 = 5.0
#: Supersampling per pixel and axis when drawing letters.
SUPERSAMPLE = 8
#: Range of chart lines accepted (logMAR).
LOGMAR_RANGE = (-1.0, 2.0)
#: Largest side of one line's image (px) before refusing.
MAX_SHEET_PX = 8192
_SNELLEN = {10: "200", 9: "160", 8: "125", 7: "100", 6: "80", 5: "63", 4: "50", 3: "40", 2: "32",
            1: "25", 0: "20", -1: "16", -2: "12.5", -3: "10"}


# --------------------------------------------------------------------------
# Letters
# --------------------------------------------------------------------------


def letter_height_arcmin(logmar: float) -> float:
    """Height of a letter on the logMAR line ``logmar`` (arcmin): ``5 * 10**logmar``."""
    return LETTER_ARCMIN_AT_0 * 10.0 ** float(logmar)


def snellen(logmar: float) -> str:
    """Snellen fraction (20 ft) of a logMAR value, e.g. ``0.3 -> "20/40"`` (standard chart steps)."""
    key = round(float(logmar) / LOGMAR_STEP)
    if abs(key * LOGMAR_STEP - logmar) < 1e-6 and key in _SNELLEN:
        return "20/" + _SNELLEN[key]
    return f"20/{20.0 * 10.0 ** float(logmar):.3g}"


def _bar(x, y, x0, x1, y0, y1):
    return (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)


def _band(x, y, p, q, width):
    """Points within ``width / 2`` of the segment p-q (cut square at its ends)."""
    dx, dy = q[0] - p[0], q[1] - p[1]
    n = math.hypot(dx, dy)
    ux, uy = dx / n, dy / n
    along = (x - p[0]) * ux + (y - p[1]) * uy
    across = (y - p[1]) * ux - (x - p[0]) * uy
    return (np.abs(across) <= width / 2) & (along >= 0) & (along <= n)


def _ring(x, y, cx, cy, r_out):
    """Ring of one stroke width: distance to (cx, cy) from ``r_out - 1`` to ``r_out``."""
    r = np.hypot(x - cx, y - cy)
    return (r <= r_out) & (r >= r_out - 1.0)


def _stadium_ring(x, y, cy):
    """S's bowls: points 0.5 to 1.5 strokes from the segment (1.5, cy)-(3.5, cy): 5 wide, 3 tall."""
    d = np.hypot(np.clip(x, 1.5, 3.5) - x, y - cy)
    return (d <= 1.5) & (d >= 0.5)


def _glyph(letter: str, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Inside-letter mask at points (x, y) of the 5 x 5 stroke grid (x right, y down)."""
    stem, right = _bar(x, y, 0, 1, 0, 5), _bar(x, y, 4, 5, 0, 5)
    if letter == "C":       # a ring open on the right by one stroke width
        return _ring(x, y, 2.5, 2.5, 2.5) & ~((x > 2.5) & (np.abs(y - 2.5) < 0.5))
    if letter == "D":
        bowl = (x >= 2.5) & _ring(x, y, 2.5, 2.5, 2.5)
        return stem | _bar(x, y, 0, 2.5, 0, 1) | _bar(x, y, 0, 2.5, 4, 5) | bowl
    if letter == "H":
        return stem | right | _bar(x, y, 0, 5, 2, 3)
    if letter == "K":
        return stem | _band(x, y, (0.6, 3.4), (5.0, -0.6), 1.15) | _band(x, y, (2.0, 2.0), (5.2, 5.6), 1.15)
    if letter == "N":
        return stem | right | _band(x, y, (0.35, -0.4), (4.65, 5.4), 1.15)
    if letter == "O":
        return _ring(x, y, 2.5, 2.5, 2.5)
    if letter == "R":
        bowl = (x >= 3.0) & _ring(x, y, 3.0, 1.5, 1.5)
        return (stem | _bar(x, y, 0, 3, 0, 1) | _bar(x, y, 0, 3, 2, 3) | bowl
                | _band(x, y, (2.4, 2.6), (5.0, 5.6), 1.15))
    if letter == "S":       # two stacked bowls, the upper open at lower right, the lower at upper left
        upper = _stadium_ring(x, y, 1.5) & ~((x > 2.5) & (y > 1.5))
        lower = _stadium_ring(x, y, 3.5) & ~((x < 2.5) & (y < 3.5))
        return upper | lower
    if letter == "V":
        return _band(x, y, (0.55, -0.5), (2.5, 5.2), 1.2) | _band(x, y, (4.45, -0.5), (2.5, 5.2), 1.2)
    if letter == "Z":
        return _bar(x, y, 0, 5, 0, 1) | _bar(x, y, 0, 5, 4, 5) | _band(x, y, (4.7, 0.2), (0.3, 4.8), 1.25)
    raise ValidationError("letter", letter, "one of the Sloan letters " + " ".join(SLOAN_LETTERS))


def _draw_letter(canvas: np.ndarray, letter: str, top: float, left: float, height_px: float,
                 supersample: int = SUPERSAMPLE) -> None:
    """Darken ``canvas`` (white 1) by ``letter``'s coverage; its box is ``height_px`` square at (top, left)."""
    r0, c0 = int(math.floor(top)), int(math.floor(left))
    n_r = int(math.ceil(top + height_px)) - r0
    n_c = int(math.ceil(left + height_px)) - c0
    sub = (np.arange(supersample) + 0.5) / supersample
    rows = ((r0 + np.arange(n_r))[:, None] + sub[None, :]).ravel()
    cols = ((c0 + np.arange(n_c))[:, None] + sub[None, :]).ravel()
    scale = 5.0 / height_px
    y, x = np.meshgrid((rows - top) * scale, (cols - left) * scale, indexing="ij")
    inside = _glyph(letter, x, y) & _bar(x, y, 0, 5, 0, 5)
    coverage = inside.reshape(n_r, supersample, n_c, supersample).mean(axis=(1, 3))
    region = canvas[r0:r0 + n_r, c0:c0 + n_c]
    region -= coverage.astype(canvas.dtype)
    np.clip(region, 0.0, 1.0, out=region)


def sloan_letter(letter: str, height_px: float, supersample: int = SUPERSAMPLE) -> np.ndarray:
    """One Sloan letter, black (0) on white (1), area-averaged from ``supersample``^2 samples a pixel.

    Parameters
    ----------
    letter
        One of :data:`SLOAN_LETTERS`.
    height_px
        Letter height (= width) in pixels, > 0 (may be fractional; the box starts at pixel 0).
    supersample
        Samples per pixel and axis, 1 to 32.

    Returns
    -------
    np.ndarray
        ``(n, n)`` float32 with ``n = ceil(height_px)``.
    """
    if letter not in SLOAN_LETTERS:
        raise ValidationError("letter", letter, "one of the Sloan letters " + " ".join(SLOAN_LETTERS))
    if not (isinstance(height_px, (int, float)) and math.isfinite(height_px) and 0 < height_px <= MAX_SHEET_PX):
        raise ValidationError("height_px", height_px, f"a letter height in (0, {MAX_SHEET_PX}] px")
    if not (isinstance(supersample, int) and 1 <= supersample <= 32):
        raise ValidationError("supersample", supersample, "an integer from 1 to 32")
    n = int(math.ceil(height_px))
    canvas = np.ones((n, n), dtype=np.float32)
    _draw_letter(canvas, letter, 0.0, 0.0, float(height_px), supersample)
    return canvas


# --------------------------------------------------------------------------
# The chart
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class ChartLine:
    """One line of the logMAR chart on one display.

    Attributes
    ----------
    logmar
        The line's logMAR (a multiple of 0.1).
    letters
        Its five letters, left to right (no repeats).
    letter_height_arcmin
        ``5 * 10**logmar`` arcmin.
    letter_height_px
        The same in display pixels (``arcmin / 60 * pixels_per_degree``).
    displayable
        False when the letter height is below :data:`MIN_LETTER_PX` (strokes narrower than one
        display pixel): the line is "below the display's pixels" and never scored.
    """

    logmar: float
    letters: tuple[str, ...]
    letter_height_arcmin: float
    letter_height_px: float
    displayable: bool

    @property
    def snellen(self) -> str:
        return snellen(self.logmar)


def _check_logmar(name: str, value: float) -> float:
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    v = float(value) if ok else float("nan")
    key = round(v / LOGMAR_STEP) if math.isfinite(v) else 0
    if not (math.isfinite(v) and LOGMAR_RANGE[0] <= v <= LOGMAR_RANGE[1] and abs(key * LOGMAR_STEP - v) < 1e-6):
        raise ValidationError(name, value, f"a multiple of {LOGMAR_STEP} logMAR from {LOGMAR_RANGE[0]} to "
                                           f"{LOGMAR_RANGE[1]}")
    return key * LOGMAR_STEP


def _line_letters(logmar: float, seed: int) -> tuple[str, ...]:
    rng = np.random.default_rng([seed, 100 + round(logmar / LOGMAR_STEP)])
    return tuple(SLOAN_LETTERS[i] for i in rng.choice(len(SLOAN_LETTERS), LETTERS_PER_LINE, replace=False))


def chart_lines(display: DisplayProfile, top_logmar: float = 1.0, bottom_logmar: float = -0.3,
                seed: int = 0) -> list[ChartLine]:
    """The lines of a logMAR chart of Sloan letters on ``display``, top (largest) first.

    Parameters
    ----------
    display
        Its ``pixels_per_degree`` converts letter sizes to pixels.
    top_logmar, bottom_logmar
        First and last line, multiples of 0.1 from -1.0 to 2.0, ``top >= bottom``.
    seed
        Chooses each line's letters (the same logMAR line gets the same letters for one seed).

    Returns
    -------
    list[ChartLine]
        In 0.1 logMAR steps; lines below the display's pixels are included, marked
        ``displayable=False``.
    """
    top = _check_logmar("top_logmar", top_logmar)
    bottom = _check_logmar("bottom_logmar", bottom_logmar)
    if bottom > top + 1e-9:
        raise ValidationError("bottom_logmar", bottom_logmar, f"at most top_logmar ({top:g})")
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValidationError("seed", seed, "a non-negative integer")
    ppd = display.pixels_per_degree
    lines = []
    for i in range(round((top - bottom) / LOGMAR_STEP) + 1):
        lm = round(round((top - i * LOGMAR_STEP) / LOGMAR_STEP) * LOGMAR_STEP, 1) + 0.0
        arcmin = letter_height_arcmin(lm)
        px = arcmin / 60.0 * ppd
        lines.append(ChartLine(logmar=lm, letters=_line_letters(lm, int(seed)), letter_height_arcmin=arcmin,
                               letter_height_px=px, displayable=px >= MIN_LETTER_PX - 1e-9))
    return lines


@dataclass(frozen=True, eq=False)
class LineSheet:
    """The image displayed to score one chart line: the line and the observer's ten templates.

    Layout (white 1, letters 0, linear light): a row of five cells holding the chart line (letters
    one letter width apart: each cell is one letter pitch, ``cell_px`` ~ two letter heights, square),
    then two rows of five template cells separated by ``blur_px`` of white so that no template's
    blurred light reaches another's cell; a margin of ``blur_px`` all round keeps the panel's black
    surround out of every cell.  All letters sit at the same sub-pixel phase in their cells, so a
    stimulus window and a template window are the same geometry.

    Attributes
    ----------
    line
        The chart line.
    image
        ``(H, W, 3)`` float32 linear RGB, grey.
    cell_px
        Side of each (square) cell and of the observer's window, px.
    line_cells
        (row, column) of the top-left corner of each chart letter's cell.
    template_cells
        The same for the templates, in :data:`SLOAN_LETTERS` order.
    blur_px
        The white gap between template cells and the margin, px.
    """

    line: ChartLine
    image: np.ndarray
    cell_px: int
    line_cells: tuple[tuple[int, int], ...]
    template_cells: tuple[tuple[int, int], ...]
    blur_px: int

    @property
    def chart_row(self) -> tuple[slice, slice]:
        """Rows and columns of the chart line's five cells."""
        r, c = self.line_cells[0]
        return slice(r, r + self.cell_px), slice(c, c + LETTERS_PER_LINE * self.cell_px)

    def window(self, image: np.ndarray, cell: tuple[int, int]) -> np.ndarray:
        """The ``cell_px`` square of ``image`` (H, W, ...) at ``cell``."""
        r, c = cell
        return image[r:r + self.cell_px, c:c + self.cell_px]


def line_sheet(line: ChartLine, blur_px: int) -> LineSheet:
    """Draw the :class:`LineSheet` of ``line`` for an eye whose kernel is ``blur_px`` wide.

    Parameters
    ----------
    line
        A displayable chart line.
    blur_px
        Width of the eye's kernel in pixels (``EyeKernel.size``), >= 1: the white space kept between
        template cells and around the sheet.
    """
    if not line.displayable:
        raise ValidationError("line", f"logMAR {line.logmar:+.1f}", "a line the display's pixels can draw "
                              f"(letter height >= {MIN_LETTER_PX:g} px)")
    if isinstance(blur_px, bool) or not isinstance(blur_px, (int, np.integer)) or blur_px < 1:
        raise ValidationError("blur_px", blur_px, "a kernel width of at least 1 px")
    h = line.letter_height_px
    cell = max(int(round(2.0 * h)), int(math.ceil(h)) + 2)
    gap = int(blur_px)
    width = 2 * gap + LETTERS_PER_LINE * cell + (LETTERS_PER_LINE - 1) * gap
    height = 2 * gap + 3 * cell + 2 * gap
    if max(width, height) > MAX_SHEET_PX:
        raise ModelLimitError(f"logMAR {line.logmar:+.1f}: the scoring image would be {width}x{height} px "
                              f"(limit {MAX_SHEET_PX}); use a smaller top line or a coarser display")
    canvas = np.ones((height, width), dtype=np.float32)
    offset = (cell - h) / 2.0
    line_cells = tuple((gap, gap + j * cell) for j in range(LETTERS_PER_LINE))
    template_cells = tuple((gap + cell + gap + (i // LETTERS_PER_LINE) * (cell + gap),
                            gap + (i % LETTERS_PER_LINE) * (cell + gap)) for i in range(len(SLOAN_LETTERS)))
    for letter, (r, c) in zip(line.letters, line_cells):
        _draw_letter(canvas, letter, r + offset, c + offset, h)
    for letter, (r, c) in zip(SLOAN_LETTERS, template_cells):
        _draw_letter(canvas, letter, r + offset, c + offset, h)
    image = np.repeat(canvas[:, :, None], 3, axis=2)
    return LineSheet(line=line, image=image, cell_px=cell, line_cells=line_cells,
                     template_cells=template_cells, blur_px=gap)


@dataclass(frozen=True, eq=False)
class Chart:
    """A chart on one display for one eye: its lines and, for the drawable ones, their sheets.

    ``sheets[i]`` belongs to ``lines[i]`` and is None when that line is below the display's pixels.
    ``targets`` are the sheets' images (what is displayed uncorrected), None likewise.
    """

    lines: tuple[ChartLine, ...]
    sheets: tuple[LineSheet | None, ...]

    @property
    def targets(self) -> tuple[np.ndarray | None, ...]:
        return tuple(None if s is None else s.image for s in self.sheets)


def build_chart(display: DisplayProfile, blur_px: int, top_logmar: float = 1.0, bottom_logmar: float = -0.3,
                seed: int = 0) -> Chart:
    """:func:`chart_lines` and a :func:`line_sheet` for each drawable line."""
    lines = chart_lines(display, top_logmar, bottom_logmar, seed)
    return Chart(lines=tuple(lines),
                 sheets=tuple(line_sheet(ln, blur_px) if ln.displayable else None for ln in lines))
