"""The project's one vocabulary: the names that prescription files, the command line, the library's
options and the reports share, each written once here (issue 26).

* :class:`Eye`: ``right``, ``left``. The canonical order is the prescription's, right then left (the
  optometric order of a spectacle prescription, and the order of a prescription file's keys); it is
  the order of ``for eye in Eye``. Where the *display* order is meant, left then right (side-by-side
  views, OpenXR's view 0 being the left eye in ``PRIMARY_STEREO``), use :data:`VIEW_ORDER`.
* :class:`Backend`: what corrects in real time, ``glsl`` (the strategies of a :class:`Filter`) or
  ``onnx`` (a model through onnxruntime).
* :class:`Filter`: the GLSL backend's methods, the default first; :data:`ITERATIVE_FILTERS` those that
  iterate over frames.
* :class:`Precision`: the storage precision of the ADMM iterations (GPU and CPU twin).
* :class:`Method`: the offline correction methods (``vrcorrect.solvers``).
* :class:`Periphery`: what a foveated view shows outside its window, the default first;
  :data:`PERIPHERY_LEVELS` the 2x2 poolings each takes and :data:`PERIPHERY_DESCRIPTIONS` their words.
* :data:`ITERATIONS_PER_FRAME`: the range of the iterations-per-frame knob on the command line and the
  windows' keys; :data:`MAX_ITERATIONS_PER_FRAME` its (wider) range in the API.

The enums are :class:`enum.StrEnum`: each member *is* its string, so it compares equal to the plain
text a file or the command line gives, hashes as that text (a dict keyed by members is found by
text), formats as it in f-strings and JSON. Its ``repr`` is not the text's: where names are shown to
a person as a list (argparse ``choices``, the allowed values of an error) use :func:`names`, which
gives plain strings, or :func:`one_of`.

Layer 1: nothing here imports anything of vrcorrect.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Iterable, NamedTuple

__all__ = ["Eye", "VIEW_ORDER", "Backend", "Filter", "ITERATIVE_FILTERS", "Precision", "Method", "Periphery", "PERIPHERY_LEVELS",
           "PERIPHERY_DESCRIPTIONS", "IterationRange",
           "ITERATIONS_PER_FRAME", "MAX_ITERATIONS_PER_FRAME", "MAX_GAZE_DEG", "names", "one_of", "either"]


class Eye(StrEnum):
    """An eye, in the prescription's order: right, then left."""

    RIGHT = "right"
    LEFT = "left"


VIEW_ORDER: tuple[Eye, Eye] = (Eye.LEFT, Eye.RIGHT)
"""The eyes in display order: the left eye's view on the left of a side-by-side picture, and
OpenXR's view index 0 (``PRIMARY_STEREO``) is the left eye."""


class Backend(StrEnum):
    """What corrects a real-time frame."""

    GLSL = "glsl"
    """The GLSL strategies (:class:`Filter`)."""
    ONNX = "onnx"
    """A model through onnxruntime."""


class Filter(StrEnum):
    """The GLSL backend's methods (``filter=``, ``--filter``), the default first."""

    ADMM = "admm"
    """ADMM iterations on the true objective, spread over frames (the default)."""
    FISTA = "fista"
    """Projected-gradient (FISTA) iterations spread over frames."""
    FFT = "fft"
    """The regularised inverse in one pass, by FFT."""
    SEPARABLE = "separable"
    """The same inverse as a separable low-rank filter bank."""


ITERATIVE_FILTERS: tuple[Filter, ...] = (Filter.ADMM, Filter.FISTA)
"""The methods that iterate over frames; the iterations per frame are their knob."""


class Precision(StrEnum):
    """Storage precision of the ADMM iterations' textures (arithmetic is 32-bit either way)."""

    HALF = "half"
    SINGLE = "single"


class Method(StrEnum):
    """The offline correction methods (``vrcorrect.solvers``), in the order :data:`METHODS` lists the
    numerical ones, then ``learned``."""

    NONE = "none"
    WIENER = "wiener"
    FAST = "fast"
    PAPER = "paper"
    CONVENTIONAL = "conventional"
    LEARNED = "learned"


class Periphery(StrEnum):
    """What a foveated view shows outside its window (``fovea_periphery=``, ``--periphery``), the
    default first."""

    QUARTER = "quarter"
    """A correction of the whole view at a quarter of the resolution (the default)."""
    HALF = "half"
    """A correction of the whole view at half the resolution."""
    TARGET = "target"
    """The target itself, uncorrected."""


PERIPHERY_LEVELS: dict[Periphery, int] = {Periphery.TARGET: 0, Periphery.HALF: 1, Periphery.QUARTER: 2}
"""How many 2x2 poolings of the view each periphery's correction is solved on (0: none solved)."""

PERIPHERY_DESCRIPTIONS: dict[Periphery, str] = {
    Periphery.QUARTER: "a correction of the whole view at a quarter of the resolution",
    Periphery.HALF: "a correction of the whole view at half the resolution",
    Periphery.TARGET: "the target, uncorrected"}
"""Each periphery in words, for reports (``layer status``)."""


class IterationRange(NamedTuple):
    """A range of iterations per frame, both ends included."""

    low: int
    high: int


ITERATIONS_PER_FRAME = IterationRange(1, 64)
"""The iterations-per-frame knob's range on the command line (``--iterations-per-frame``) and the
windows' keys (``[``, ``]``)."""
MAX_ITERATIONS_PER_FRAME = 256
"""The knob's range in the API is 0 (keep the start; the guard still applies) to this."""
MAX_GAZE_DEG = 90.0
"""The gaze's largest offset from the view's centre, degrees on each axis (``gaze_deg``, ``--gaze``,
an eye tracker's gaze)."""


def names(members: Iterable[StrEnum]) -> tuple[str, ...]:
    """The members' texts as plain strings, in order (``names(Backend) == ("glsl", "onnx")``): for
    argparse ``choices`` (whose error shows each choice's ``repr``) and lists shown to a person."""
    return tuple(str(m.value) for m in members)


def one_of(members: Iterable[StrEnum]) -> str:
    """``"one of glsl, onnx"``: the allowed values of a :class:`ValidationError`."""
    return "one of " + ", ".join(names(members))


def either(members: Iterable[StrEnum], quote: bool = True) -> str:
    """``"'right' or 'left'"`` (``quote=False``: ``"right or left"``)."""
    texts = [repr(n) if quote else n for n in names(members)]
    return ", ".join(texts[:-1]) + " or " + texts[-1] if len(texts) > 1 else "".join(texts)
