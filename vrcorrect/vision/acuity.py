"""Simulated eye-chart acuity after Watson & Ahumada (2008).

Which line of a logMAR chart of Sloan letters does this eye read on this
display?  A. B. Watson and A. J. Ahumada, "Predicting visual acuity from
wavefront aberrations", Journal of Vision 8(4):17 (2008): the letter passes
through the eye's optics, white Gaussian noise is added, and an ideal
observer names it by matching it against templates of the candidate letters
as they reach its own retina.

Layer 3.  Imports numpy and the layers below (display, kernel, forward).

The chart (:mod:`vrcorrect.vision.chart`)
-----------------------------------------
Sloan letters on logMAR lines, drawn procedurally, five a line, a line below the display's
pixels never scored.

The observer
------------
* **Stimulus.**  What the eye sees of the displayed chart line
  (:func:`vrcorrect.vision.forward.simulate_lms`: the eye's polychromatic kernel,
  chromatic aberration included), reduced to a luminance channel
  ``Y = (L + M) / 2`` (white gives 1) and taken as contrast ``Y - 1``.  L + M
  is the achromatic, luminance-carrying cone signal (photopic luminance is
  a weighted L + M sum; equal weights here, in the white-normalised cone
  units); S cones are left out because they add nothing to luminance and are
  absent from the central fovea, where letters are read.
* **Window.**  Each letter is judged in a square window one letter pitch
  (two letter widths) wide centred on it, so the blurred light of its
  neighbours reaches it (crowding), and its own light that blur spreads
  beyond the window is lost.
* **Templates.**  The ten Sloan letters drawn at the same size, isolated,
  seen through the same eye and the same correction (an ideal observer knows
  its own optics).  They are drawn on the same image as the chart line, so a
  correction is computed once for both.
* **A second observer.**  The ideal observer has adapted perfectly to its
  blur and to each correction.  People have not: they know letters as they
  look sharp.  The **sharp-template observer** matches the same stimulus
  against the ten letters as the same eye sees them *with its glasses on*
  (``score_acuity(..., template_views=...)``); for an eye that needs no
  glasses the two observers are one.  A correction that makes the retinal
  image look like the sharp letters helps it more than it helps the ideal
  observer, which can already use any blurred letter it knows.
* **Decision.**  Nearest template in additive white Gaussian noise: choose
  ``i`` maximising ``<x, T_i> - |T_i|^2 / 2``, the ideal rule for equally
  likely letters.  The noise is drawn in the ten-dimensional space the rule
  looks at: ``(<n, T_i>)_i`` is exactly Gaussian with covariance
  ``sigma^2 T T^T``, so drawing it there is the same experiment as adding
  pixel noise, at a fraction of the cost.
* **Trials.**  ``trials_per_letter`` noisy presentations of each of the five
  letters of a line (numpy ``Generator``, fixed seed per line); the line's
  proportion correct is the mean over all of them.  A line is **read** when
  its proportion correct is at least 0.6 (the 60 % criterion; chance is
  0.1).
* **Acuity rule.**  Lines are taken from the top: the acuity is the smallest
  logMAR of the contiguous run of read lines that starts at the top line; it
  stops at the first line not read, or at the first line below the display's
  pixels (then the display, not the eye, limits the reading, and
  :attr:`AcuityScore.limit` says so).  When the top line is not read, the
  acuity is ``None`` (worse than the chart).  :attr:`AcuityScore.threshold_logmar`
  interpolates, linearly in logMAR, where the proportion correct crosses 0.6
  between the last line read and the next.

The noise, and why it is per solid angle
----------------------------------------
The noise is specified as the RMS contrast of the noise averaged over a
1 x 1 arcmin patch of the visual field, ``NOISE_CONTRAST_ARCMIN`` (units:
contrast x arcmin; white noise of power spectral density
``NOISE_CONTRAST_ARCMIN**2`` contrast^2 arcmin^2).  A display pixel covers
``(60 / ppd)^2`` arcmin^2, so the noise per pixel has standard deviation
``sigma_px = NOISE_CONTRAST_ARCMIN * ppd / 60``.  Then the observer's
sensitivity to the difference of two letters, ``d' = |T_i - T_j| /
sigma_px``, is ``sqrt(integral of (T_i - T_j)^2 dA) / NOISE`` - an integral
over visual angle, the same for every pixel size.  A constant noise *per
pixel* would make a finer display hand the observer more independent
samples of the same letter and improve its acuity by display resolution
alone; per solid angle, the display only matters through what it can draw.

Calibration (done once; the constant is not fitted to the check below)
---------------------------------------------------------------------
The published figure: logMAR 0.0 (Snellen 20/20, 6/6) is the acuity of the
standard normal eye: a letter of 5 arcmin with 1 arcmin strokes is the
smallest one read (Snellen 1862; the logMAR/ETDRS chart, Bailey & Lovie
1976, Ferris et al. 1982, keeps logMAR 0 = 20/20 as its standard).  Young
adults with healthy, fully corrected eyes do better on average (mean logMAR
-0.13 at 18-24 years, -0.16 at 25-29; Elliott, Yang & Whitaker 1995, Optom
Vis Sci 72:186-191): the standard, not the best eye, is what is calibrated
here.  The eye: sphere 0, cylinder 0, 4 mm pupil (the project's standard
pupil; between the 3 and 4 mm of a young eye at chart luminance), no
accommodation, chromatic aberration on, prescription at 555 nm, chart at
optical infinity.  The display: the desktop preset's primaries at
120 pixels per degree (every line from +1.0 to -0.3 drawable: 5 px at
logMAR -0.3).  The constant was set so that the 60 % threshold
(:attr:`AcuityScore.threshold_logmar`) falls at logMAR -0.05, half a line
below 0.0, so that the chart reading is 0.0: line 0.0 read, line -0.1 not.
The threshold moves about 0.6 logMAR per decade of noise (0.5 -> -0.026,
1.0 -> +0.156, 2.0 -> +0.415); value obtained: ``NOISE_CONTRAST_ARCMIN`` =
0.45 (threshold -0.048 logMAR, chart reading 0.0, with 400 trials a letter
and seed 0; the 3 mm pupil gives -0.055 and 0.0).

The check: defocus against a published relation
-----------------------------------------------
Blendowske R. (2015), "Unaided visual acuity and blur: a simple model",
Optometry and Vision Science 92(6):e121-e125 (PubMed 25955640): across
pooled published data on unaided acuity and refractive error,
``MAR = MAR_0 (1 + b^2)``, i.e. ``logMAR = logMAR_0 + log10(1 + b^2)``, with
``b`` the blur strength (dioptric distance) of the refractive error in
dioptres (for a sphere, ``|M|``; Thibos's ``sqrt(M^2 + J0^2 + J45^2)`` in
general); no pupil term (natural pupils).  So 1 D of myopia costs
``log10 2 = 0.30`` logMAR (three lines) and 2 D ``log10 5 = 0.70``.  This
model, with the calibrated constant, the 4 mm eye, the chart at optical
infinity (60 ppd; the thresholds are within 0.005 of 120 ppd's), against
``-0.05 + log10(1 + b^2)`` from the calibrated threshold:

=======  =============  ==================  ===========
defocus  chart reading  60 % threshold      Blendowske
=======  =============  ==================  ===========
0.5 D    0.3            0.27 (3 mm: 0.17)   0.05
1 D      0.5            0.45 (3 mm: 0.38)   0.25
2 D      0.7            0.60 (3 mm: 0.53)   0.65
3 D      0.8            0.72 (3 mm: 0.63)   0.95
=======  =============  ==================  ===========

The test holds 1 and 2 D to within 0.25 logMAR of the relation: wide, because
the pooled data do not control pupil size (Blendowske names the missing pupil
diameters as the main uncertainty) and this model moves by up to 0.1 logMAR
between 3 and 4 mm pupils.  The shapes differ: the model loses acuity too fast
at small defocus and too slowly at large defocus (see below).

What it leaves out (so read the numbers as a model's)
-----------------------------------------------------
No neural transfer function, no cone sampling and no higher-order
aberrations unless the prescription has them (Watson & Ahumada include an
NTF and measured aberrations); an ideal observer uses every bit of contrast
the optics pass, including the phase-reversed "spurious resolution" of
strong defocus, which human observers use little (Akutsu, Bedell & Patel
2000, Optom Vis Sci 77(10)).  Both show in the defocus table: the emmetropic
observer is limited by noise on detail up to the optics' cut-off, so 0.5 D
already costs it 0.3 logMAR where people lose about 0.1, and through 3 D it
still reads 0.7 where people read about 0.95.  A neural blur would flatten
the start: a Gaussian of sigma 1 arcmin on the luminance image before the
noise (tried, not shipped: recalibrated noise 0.15 contrast x arcmin) gives
thresholds 0.11, 0.29, 0.53, 0.62 at 0.5, 1, 2, 3 D - closer at 0.5 and
1 D, further at 3 D.  Below chance (0.1) at large blur is possible: the
templates are isolated letters, the chart's letters have neighbours, and
their blurred light pulls the decision towards particular wrong letters.
Letters are scored in probability (five letters x many trials), not letter
by letter as a clinician does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np

from ..physics.kernel import EyeKernel, KernelOptions, build_kernel
from ..plumbing.errors import ValidationError
from ..specs.display import DisplayProfile, get_display
from ..specs.prescription import EyeRx
from .chart import (
    LETTERS_PER_LINE,
    LOGMAR_STEP,
    MIN_LETTER_PX,
    SLOAN_LETTERS,
    Chart,
    ChartLine,
    LineSheet,
    build_chart,
    chart_lines,
    letter_height_arcmin,
    line_sheet,
    sloan_letter,
    snellen,
)
from .forward import check_image, simulate_lms

__all__ = [
    "SLOAN_LETTERS", "LETTERS_PER_LINE", "LOGMAR_STEP", "MIN_LETTER_PX", "CRITERION",
    "NOISE_CONTRAST_ARCMIN", "CALIBRATION_PPD", "CALIBRATION_PUPIL_MM",
    "letter_height_arcmin", "snellen", "sloan_letter", "ChartLine", "chart_lines",
    "LineSheet", "line_sheet", "Chart", "build_chart", "Observer", "LineScore", "AcuityScore",
    "score_acuity", "calibration_display", "simulated_acuity",
]

#: Proportion correct at which a line counts as read.
CRITERION = 0.6
#: RMS contrast of the observer's noise over a 1 x 1 arcmin patch (contrast x arcmin).  Calibrated
#: once, see the module docstring.
NOISE_CONTRAST_ARCMIN = 0.45
#: The calibration's display density (pixels per degree) and pupil (mm).
CALIBRATION_PPD = 120.0
CALIBRATION_PUPIL_MM = 4.0



# --------------------------------------------------------------------------
# The observer
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class Observer:
    """The simulated reader.

    Attributes
    ----------
    noise_contrast_arcmin
        RMS contrast of its internal white noise over a 1 x 1 arcmin patch (> 0); per pixel
        ``noise * ppd / 60``.  Default: the calibrated :data:`NOISE_CONTRAST_ARCMIN`.
    trials_per_letter
        Noisy presentations of each letter of a line (1 to 100000).
    criterion
        Proportion correct at which a line is read (0.1 to 1; chance is 0.1).
    seed
        Seed of the trials (a line's trials depend only on this and the line's logMAR).
    """

    noise_contrast_arcmin: float = NOISE_CONTRAST_ARCMIN
    trials_per_letter: int = 400
    criterion: float = CRITERION
    seed: int = 0

    def __post_init__(self) -> None:
        n = self.noise_contrast_arcmin
        if isinstance(n, bool) or not isinstance(n, (int, float)) or not (math.isfinite(n) and n > 0):
            raise ValidationError("noise_contrast_arcmin", n, "a positive finite number (contrast x arcmin)")
        t = self.trials_per_letter
        if isinstance(t, bool) or not isinstance(t, (int, np.integer)) or not (1 <= t <= 100000):
            raise ValidationError("trials_per_letter", t, "an integer from 1 to 100000")
        c = self.criterion
        if isinstance(c, bool) or not isinstance(c, (int, float)) or not (0.1 < c <= 1.0):
            raise ValidationError("criterion", c, "a proportion correct above chance (0.1) and at most 1")
        s = self.seed
        if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0:
            raise ValidationError("seed", s, "a non-negative integer")
        object.__setattr__(self, "noise_contrast_arcmin", float(n))
        object.__setattr__(self, "trials_per_letter", int(t))
        object.__setattr__(self, "criterion", float(c))
        object.__setattr__(self, "seed", int(s))

    def sigma_px(self, pixels_per_degree: float) -> float:
        """Standard deviation of the noise per display pixel (contrast)."""
        return self.noise_contrast_arcmin * pixels_per_degree / 60.0


@dataclass(frozen=True, eq=False)
class LineScore:
    """How one chart line was read.

    ``proportion_correct`` and ``read`` are None for a line below the display's pixels (not scored);
    ``seen_lms`` is the retinal cone image of the line's sheet (None likewise).
    """

    line: ChartLine
    proportion_correct: float | None
    read: bool | None
    seen_lms: np.ndarray | None = field(default=None, repr=False)


#: Why the run of read lines stopped.
LIMITS = {
    "letters": "the next line was not read",
    "pixels": "the next line is below the display's pixels",
    "chart": "every line of the chart was read",
    "top": "the top line was not read",
}


@dataclass(frozen=True, eq=False)
class AcuityScore:
    """The simulated chart reading.

    Attributes
    ----------
    logmar
        Smallest logMAR of the run of read lines from the top (None: top line not read).
    threshold_logmar
        Where the proportion correct crosses the criterion, interpolated linearly in logMAR between
        the last line read and the next (None unless ``limit == "letters"``).
    limit
        Why the run stopped: a key of :data:`LIMITS`.
    lines
        Every chart line's score, top first.
    observer
        The observer that read.
    """

    logmar: float | None
    threshold_logmar: float | None
    limit: str
    lines: tuple[LineScore, ...]
    observer: Observer

    @property
    def snellen(self) -> str:
        if self.logmar is not None:
            return snellen(self.logmar)
        if self.limit == "pixels":
            return "no line drawable"
        return "worse than " + snellen(self.lines[0].line.logmar)

    def as_dict(self) -> dict:
        """JSON-ready summary (no images)."""
        return {
            "logmar": self.logmar, "snellen": self.snellen, "threshold_logmar": self.threshold_logmar,
            "limit": self.limit, "limit_text": LIMITS[self.limit],
            "lines": [{"logmar": s.line.logmar, "snellen": s.line.snellen, "letters": "".join(s.line.letters),
                       "letter_height_px": s.line.letter_height_px,
                       "below_display_pixels": not s.line.displayable,
                       "proportion_correct": s.proportion_correct, "read": s.read} for s in self.lines],
        }


def _luminance_contrast(lms: np.ndarray) -> np.ndarray:
    """``(L + M) / 2 - 1``: luminance contrast against the display's white (float64)."""
    return 0.5 * (lms[..., 0].astype(np.float64) + lms[..., 1].astype(np.float64)) - 1.0


def _proportion_correct(sheet: LineSheet, seen_lms: np.ndarray, sigma_px: float, trials: int,
                        rng: np.random.Generator, template_lms: np.ndarray | None = None) -> float:
    """Template matching in white noise of ``sigma_px`` per pixel, drawn in template space.

    The templates are the sheet's template cells of ``template_lms`` (default: of ``seen_lms``, the
    ideal observer's own view)."""
    y = _luminance_contrast(seen_lms)
    yt = y if template_lms is None else _luminance_contrast(template_lms)
    T = np.stack([sheet.window(yt, c).ravel() for c in sheet.template_cells])     # (10, n)
    S = np.stack([sheet.window(y, c).ravel() for c in sheet.line_cells])          # (5, n)
    truth = np.array([SLOAN_LETTERS.index(ch) for ch in sheet.line.letters])
    base = S @ T.T - 0.5 * np.einsum("in,in->i", T, T)[None, :]                    # (5, 10)
    w, V = np.linalg.eigh(T @ T.T)
    root = V * np.sqrt(np.clip(w, 0.0, None))[None, :]                             # root @ root.T = T T^T
    correct = 0
    for k in range(LETTERS_PER_LINE):
        noise = sigma_px * (rng.standard_normal((trials, len(SLOAN_LETTERS))) @ root.T)
        correct += int(np.count_nonzero(np.argmax(base[k][None, :] + noise, axis=1) == truth[k]))
    return correct / (trials * LETTERS_PER_LINE)


def _reading(scores: Sequence[LineScore], criterion: float) -> tuple[float | None, float | None, str]:
    """The acuity rule: (logmar, threshold_logmar, limit) from line scores, top first."""
    last = None
    for i, s in enumerate(scores):
        if s.proportion_correct is None:
            return (None if last is None else scores[last].line.logmar), None, "pixels"
        if not s.read:
            if last is None:
                return None, None, "top"
            a, b = scores[last], s
            frac = (a.proportion_correct - criterion) / (a.proportion_correct - b.proportion_correct)
            return a.line.logmar, a.line.logmar + frac * (b.line.logmar - a.line.logmar), "letters"
        last = i
    return (None if last is None else scores[last].line.logmar), None, "chart"


def score_acuity(chart: Chart, displayed_for_line: Sequence[np.ndarray | None], eye_kernel: EyeKernel,
                 display: DisplayProfile, observer: Observer | None = None,
                 progress: Callable[[int, int], None] | None = None,
                 template_views: Sequence[np.ndarray | None] | None = None,
                 seen_views: Sequence[np.ndarray | None] | None = None) -> AcuityScore:
    """Read ``chart`` as displayed (``displayed_for_line``) through ``eye_kernel``.

    Parameters
    ----------
    chart
        From :func:`build_chart` with ``blur_px >= eye_kernel.size`` (use the eye's kernel size).
    displayed_for_line
        One image per chart line, aligned with ``chart.lines``: ``(H, W, 3)`` linear RGB in [0, 1]
        of the same shape as that line's sheet - the sheet itself (``chart.targets``) for no
        correction, or a corrected version of it; None for lines below the display's pixels.
    eye_kernel
        The eye looking at ``display`` (:func:`vrcorrect.physics.kernel.build_kernel`).
    display
        The display (its pixels per degree sets the noise per pixel; must match the kernel's).
    observer
        The reader (default: calibrated noise, 400 trials a letter, 60 % criterion, seed 0).
    progress
        Optional ``progress(done, total)`` after each line.
    template_views
        Optional retinal cone images, one per chart line (None where not drawable), whose template
        cells the observer matches against instead of its own view's: the **sharp-template
        observer** passes what the eye sees of the uncorrected sheet with its glasses on (it knows
        the letters only as they look sharp, as a person who has not adapted to a blur or to a
        correction does).  Default None: the ideal observer of Watson & Ahumada, whose templates
        pass through the same eye and correction as the stimulus.
    seen_views
        Optional retinal cone images of ``displayed_for_line`` through ``eye_kernel`` already
        computed (an earlier score's ``LineScore.seen_lms``), so a second observer reading the same
        display does not run the forward model again.  Default None: computed here.

    Returns
    -------
    AcuityScore
    """
    observer = observer or Observer()
    if template_views is not None and len(template_views) != len(chart.lines):
        raise ValidationError("template_views", f"{len(template_views)} images",
                              f"one per chart line ({len(chart.lines)})")
    if not math.isclose(display.pixels_per_degree, eye_kernel.pixels_per_degree, rel_tol=1e-9):
        raise ValidationError("display.pixels_per_degree", display.pixels_per_degree,
                              f"the eye kernel's {eye_kernel.pixels_per_degree:g} (build it for this display)")
    if len(displayed_for_line) != len(chart.lines):
        raise ValidationError("displayed_for_line", f"{len(displayed_for_line)} images",
                              f"one per chart line ({len(chart.lines)})")
    sigma = observer.sigma_px(display.pixels_per_degree)
    scores: list[LineScore] = []
    for i, (line, sheet, shown) in enumerate(zip(chart.lines, chart.sheets, displayed_for_line)):
        if sheet is None:
            if shown is not None:
                raise ValidationError(f"displayed_for_line[{i}]", "an image",
                                      f"None: logMAR {line.logmar:+.1f} is below the display's pixels")
            scores.append(LineScore(line, None, None))
        else:
            if sheet.blur_px < eye_kernel.size:
                raise ValidationError("chart.blur_px", sheet.blur_px, f"at least the kernel's {eye_kernel.size} px")
            if shown is None or np.shape(shown) != sheet.image.shape:
                raise ValidationError(f"displayed_for_line[{i}]", None if shown is None else np.shape(shown),
                                      f"an image of the sheet's shape {sheet.image.shape}")
            if seen_views is not None and seen_views[i] is not None:
                seen = seen_views[i]
            else:
                seen, _ = simulate_lms(check_image(shown, f"displayed_for_line[{i}]"), eye_kernel)
            rng = np.random.default_rng([observer.seed, 100 + round(line.logmar / LOGMAR_STEP)])
            views = None
            if template_views is not None:
                views = template_views[i]
                if views is None or np.shape(views) != seen.shape:
                    raise ValidationError(f"template_views[{i}]", None if views is None else np.shape(views),
                                          f"a cone image of the sheet's shape {seen.shape}")
            p = _proportion_correct(sheet, seen, sigma, observer.trials_per_letter, rng, views)
            scores.append(LineScore(line, p, p >= observer.criterion, seen))
        if progress is not None:
            progress(i + 1, len(chart.lines))
    logmar, threshold, limit = _reading(scores, observer.criterion)
    return AcuityScore(logmar=logmar, threshold_logmar=threshold, limit=limit, lines=tuple(scores),
                       observer=observer)


# --------------------------------------------------------------------------
# Uncorrected acuity in one call
# --------------------------------------------------------------------------


def calibration_display(pixels_per_degree: float = CALIBRATION_PPD, base: DisplayProfile | None = None
                        ) -> DisplayProfile:
    """A chart display fine enough for every line: ``base``'s primaries (default the desktop preset's)
    at ``pixels_per_degree``, at optical infinity."""
    base = base or get_display("desktop")
    return replace(base, name="acuity-chart", title=f"acuity chart ({pixels_per_degree:g} ppd, at infinity)",
                   pixels_per_degree=pixels_per_degree, distance_m=math.inf, resolution_px=None,
                   sources=f"{base.name} primaries at {pixels_per_degree:g} ppd (vrcorrect.vision.acuity calibration)")


def simulated_acuity(eye: EyeRx, display: DisplayProfile, options: KernelOptions | None = None, *,
                     observer: Observer | None = None, top_logmar: float = 1.0, bottom_logmar: float = -0.3,
                     chart_seed: int = 0) -> AcuityScore:
    """Uncorrected chart acuity of ``eye`` on ``display`` (builds the eye's kernel with ``options``).

    See :func:`score_acuity`; corrections need the solvers (``vrcorrect.studies.acuity_chart.measure_acuity``).
    """
    kernel = build_kernel(eye, display, options)
    chart = build_chart(display, kernel.size, top_logmar, bottom_logmar, chart_seed)
    return score_acuity(chart, chart.targets, kernel, display, observer)
