"""What the GPU needs for one eye, designed on the CPU: :func:`build_eye_model`.

:class:`~vrcorrect.runtime.corrector.Corrector` builds one :class:`EyeModel` per eye and
prescription (again at every prescription change) and uploads it; everything here is numpy.

* Every backend: the eye's kernel ``K`` and, for ``reference="glasses"``, the glasses-on eye's
  kernel (the target ``T = K_ref t``); whether there is anything to correct (``identity``); for
  ``filter="separable"`` the forward model's bank ``A^-1 K`` (the preview, ``simulate``).
* ``backend="glsl"`` with ``filter="fft"`` or ``"separable"``: the regulariser and the blend weight,
  chosen once per eye by the CPU ``wiener`` method on the bundled sample image (so the GPU result
  equals ``wiener(problem, regularisation=(mu,), beta=beta, design=False, grid=..., margin=...)`` on
  the CPU up to float32 with ``filter="fft"``, and ``wiener(problem, regularisation=(mu,),
  beta=beta)`` up to the bank's rank tolerance with ``"separable"``; the GPU blends along the
  regularised inverse only, as ``wiener`` with ``descent=False``: the CPU method's extra
  projected-gradient direction is not computed here); for ``"separable"`` also the correction's
  filters as a separable bank (:mod:`vrcorrect.runtime.filters`).
* ``backend="glsl"`` with ``filter="fista"``: nothing more (the iterations minimise the objective
  itself, on the GPU).
* ``backend="onnx"``: nothing more either (the model corrects; no ``wiener`` solve, no filters).

Layer 5: numpy only; never torch.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Mapping

import numpy as np

from ..physics.pupil import pupil_from_light
from ..plumbing.errors import ValidationError
from ..plumbing.fileio import package_data
from ..plumbing.imageio import read_image
from ..specs.display import DisplayProfile, decode
from ..specs.prescription import EyeRx
from ..specs.vocabulary import (
    ITERATIVE_FILTERS,
    MAX_GAZE_DEG,
    MAX_ITERATIONS_PER_FRAME,
    Backend,
    Filter,
    Periphery,
    Precision,
    either,
    names,
    one_of,
)
from .budget import check_budget_ms
from .filters import DEFAULT_RANK_TOLERANCE, SeparableBank, separable_bank
from .pupil_bank import band_slack, bank_grid_kernel_size, bank_reach_mm, nearest_bank_pupil

if TYPE_CHECKING:  # pragma: no cover - typing only
    from ..physics.kernel import EyeKernel, KernelOptions

__all__ = ["as_options", "initial_pupil_mm", "auto_reach_mm", "NEUTRAL_LUMINANCE", "DEFAULT_ITERATIONS", "DEFAULT_COLD_ITERATIONS", "WORK_GROUP_PASSES", "VALUES_PER_THREAD",
           "COARSE_VALUES_PER_THREAD", "COLUMN_LINES", "WorkGroups", "CorrectorOptions", "EyeModel", "build_eye_model",
           "check_iterations", "BAND_OPTIONS", "band_switches"]

# The names (backends, filters, precisions) and the iterations' ranges are the vocabulary's
# (vrcorrect.specs.vocabulary): Backend, Filter, ITERATIVE_FILTERS, Precision, ITERATIONS_PER_FRAME,
# MAX_ITERATIONS_PER_FRAME.
DEFAULT_ITERATIONS = {Filter.ADMM: 2, Filter.FISTA: 4}
"""Iterations per frame by default: the fewest that keep 90 % of per-frame ``fast``'s gain on moving
clips and reach within 5 % of ``fast`` in 10 frames of a still view (``vrcorrect bench realtime``)."""
DEFAULT_COLD_ITERATIONS = 15
"""Half-resolution iterations that start a cold frame of ``filter="admm"``: ``fast``'s own
coarse-level count (:data:`vrcorrect.solvers.admm.COARSE_ITERATIONS`; a test holds the two equal,
this module imports no solver at start-up)."""


WORK_GROUP_PASSES = ("ROWS_TARGET", "ROWS_START", "ROWS_UPDATE", "ROWS_GUARD", "COLUMNS")
"""The ADMM strategy's passes that have a work-group shape (their shader's define)."""
MAX_VALUES_PER_THREAD = 64
VALUES_PER_THREAD = {"ROWS_TARGET": 8, "ROWS_START": 4, "ROWS_UPDATE": 8, "ROWS_GUARD": 8, "COLUMNS": 4}
"""Values of each channel one thread of a row or column pass keeps, by pass (the work group is the
line's length over this). Chosen by GPU time on an H100 at 1832x1920 (2026-11-27; each setting's
frames timed interleaved with the others' after a warm-up, docs/realtime.md; ``vrcorrect bench
workgroups`` reruns the comparison): 8 for every pass took 5.94 ms an eye, these 4.93 ms, the same
output to the last bit. The column passes, which each hold six channels and a 3x3 solve a thread,
gained most (0.93 to 0.70 ms); the start's row pass gained 0.25 ms at 4; the update passes are
slower at 4 (0.88 ms, against 0.61 at 8)."""
COARSE_VALUES_PER_THREAD = {**VALUES_PER_THREAD, "COLUMNS": 2}
"""The same for a cold frame's coarse level (a grid half as wide: 1024 at headset size). There the
columns at 4 made the cold frame 16.5 ms on the H100, at 8 10.6 ms, at 2 10.0 ms (the same day and
way of timing; why 4 is slow at that length is not known)."""
COLUMN_LINES = (1, 2, 4, 8)
"""Spectrum columns one work group of a column pass may transform together (``WorkGroups.column_lines``).
The shipped shape keeps 1, the only one timed on a GPU so far."""


@dataclass(frozen=True)
class WorkGroups:
    """The work-group shape of the ADMM strategy's row and column passes: for each pass of
    :data:`WORK_GROUP_PASSES` the values of each channel one thread keeps (a power of two from 1 to
    64), at full resolution (``full``) and on a cold frame's half-resolution level (``coarse``).
    The shape changes which thread holds a value, never the value: it is a GPU's tuning
    (``vrcorrect bench workgroups`` times settings against each other). Where a line would need
    more than 1,024 threads, has fewer points than asked or a length the value does not divide (a
    5-smooth line), the strategy compiles the divisor of the line nearest it
    (:func:`vrcorrect.runtime.fft.values_per_thread`). The
    default is :data:`VALUES_PER_THREAD` and :data:`COARSE_VALUES_PER_THREAD`; a mapping given
    may name some passes only, the others keep the default's.

    ``column_lines`` (``{"full": n, "coarse": n}``, either may be left out; default 1 each): the
    spectrum columns one work group of a column pass transforms together, one of
    :data:`COLUMN_LINES`. Its threads then read neighbouring columns of a grid row side by side
    (one column a group reads a single value from each row). The strategy lowers it where the lines
    would not fit the 32 KiB of shared memory every OpenGL 4.3 GPU has, or 1,024 threads."""

    full: Mapping[str, int] = field(default_factory=lambda: dict(VALUES_PER_THREAD))
    coarse: Mapping[str, int] = field(default_factory=lambda: dict(COARSE_VALUES_PER_THREAD))
    column_lines: Mapping[str, int] = field(default_factory=lambda: {"full": 1, "coarse": 1})

    def __post_init__(self) -> None:
        for name, given, default in (("full", self.full, VALUES_PER_THREAD),
                                     ("coarse", self.coarse, COARSE_VALUES_PER_THREAD)):
            if not isinstance(given, Mapping):
                raise ValidationError(f"work_groups.{name}", given, "a mapping of pass names to values per thread")
            for pass_, per in given.items():
                if pass_ not in WORK_GROUP_PASSES:
                    raise ValidationError(f"work_groups.{name} pass", pass_, "one of " + ", ".join(WORK_GROUP_PASSES))
                if isinstance(per, bool) or not isinstance(per, (int, np.integer)) or \
                        not 1 <= per <= MAX_VALUES_PER_THREAD or per & (per - 1):
                    raise ValidationError(f"work_groups.{name}[{pass_}]", per,
                                          f"a power of two from 1 to {MAX_VALUES_PER_THREAD}")
            object.__setattr__(self, name, {p: int(given.get(p, default[p])) for p in WORK_GROUP_PASSES})
        lines = self.column_lines
        if not isinstance(lines, Mapping):
            raise ValidationError("work_groups.column_lines", lines, "a mapping with 'full' and/or 'coarse'")
        for level, n in lines.items():
            if level not in ("full", "coarse"):
                raise ValidationError("work_groups.column_lines level", level, "'full' or 'coarse'")
            if isinstance(n, bool) or n not in COLUMN_LINES:
                raise ValidationError(f"work_groups.column_lines[{level}]", n,
                                      "one of " + ", ".join(map(str, COLUMN_LINES)))
        object.__setattr__(self, "column_lines", {level: int(lines.get(level, 1)) for level in ("full", "coarse")})

    def __hash__(self) -> int:
        return hash((tuple(self.full.items()), tuple(self.coarse.items()), tuple(self.column_lines.items())))

    def lines(self, coarse: bool = False) -> int:
        """Spectrum columns a column pass's work group transforms together, as asked."""
        return self.column_lines["coarse" if coarse else "full"]

    def table(self, coarse: bool = False) -> dict[str, int]:
        """Values per thread by pass, at full resolution or on the coarse level (a copy)."""
        return dict(self.coarse if coarse else self.full)

    @classmethod
    def every(cls, per: int) -> "WorkGroups":
        """``per`` values a thread in every pass, at both resolutions."""
        table = dict.fromkeys(WORK_GROUP_PASSES, per)
        return cls(table, table)


def as_options(backend: str, value: "CorrectorOptions | Mapping[str, Any] | None") -> "CorrectorOptions":
    """``value`` as :class:`CorrectorOptions` for ``backend`` (a mapping of its fields, checked now,
    or options already made, which must be for that backend)."""
    if isinstance(value, CorrectorOptions):
        if value.backend != backend:
            raise ValidationError("corrector_options.backend", value.backend, f"the application's backend, {backend}")
        return value
    return CorrectorOptions(backend=backend, **dict(value or {}))


def check_iterations(value: object, field: str = "iterations_per_frame") -> int:
    """``iterations_per_frame`` (or ``field``): a whole number from 0 to
    :data:`~vrcorrect.specs.vocabulary.MAX_ITERATIONS_PER_FRAME`."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or \
            not 0 <= value <= MAX_ITERATIONS_PER_FRAME:
        raise ValidationError(field, value, f"a whole number from 0 to {MAX_ITERATIONS_PER_FRAME}")
    return int(value)


@dataclass(frozen=True)
class CorrectorOptions:
    """How the correction is designed (frozen; defaults are the product's).

    Attributes
    ----------
    regularisation
        Candidate regularisers (relative to the kernel's spectral norm squared) tried by the
        CPU ``wiener`` on the sample image; the best is kept.
    beta
        Fixed blend weight in [0, 1]; ``None``: chosen with the regulariser.
    reference
        ``"glasses"`` (the target is what the eye sees wearing its glasses) or ``"ideal"``.
    design_tolerance
        Truncation of the designed filters (see ``correction_filters``).
    rank_tolerance
        Reconstruction error of the separable bank (see ``separable_bank``).
    choice_size
        Side of the sample image the regulariser and blend are chosen on (pixels).
    model
        ONNX model path for ``backend="onnx"``.
    kernel_options
        How the eye's kernels are built (``None``: :class:`~vrcorrect.physics.kernel.KernelOptions`'
        defaults).
    filter
        ``"admm"`` (default), ``"fista"``, ``"fft"`` or ``"separable"`` (see
        :mod:`vrcorrect.runtime.strategies`).
    iterations_per_frame
        ``"admm"``, ``"fista"``: iterations per frame (the speed-accuracy knob; 0 keeps the start,
        the guard still applies; ``None``: the method's default, :data:`DEFAULT_ITERATIONS`); also
        changeable live (:attr:`Corrector.iterations_per_frame`).
    blend
        ``"frame"`` (FFT strategy, default when ``beta`` is None): the blend weight minimising the
        objective is computed on the GPU for every frame, as the CPU ``wiener`` does per image, so
        no frame is made worse than uncorrected (three more FFT filterings and a reduction);
        ``"fixed"``: the weight chosen once on the sample image (cheaper; a compromise).
        ``"admm"`` and ``"fista"`` always blend their solution with the target by the best weight of
        the frame.
    backend
        What corrects: ``"glsl"`` (the strategies of ``filter``) or ``"onnx"`` (a model: no
        regulariser, blend or filters are designed for it).  The :class:`Corrector` sets it from its
        own ``backend`` argument.
    precision
        ``filter="admm"``: ``"half"`` (16-bit float storage on the GPU, the default) or ``"single"``
        (32-bit).
    early_stop
        ``filter="admm"``: give the passes no work while the view is still (the target unchanged
        since the last frame) and converged (two frames' objectives agree to 1e-3): the GPU decides
        each frame, nothing waits for it.
    cold_iterations
        ``filter="admm"``: half-resolution ADMM iterations that start a cold frame (the first of a
        size, a cut, a new prescription), ``fast``'s coarse-to-fine start, where the image is at
        least 64 px on its short side and the kernel at least 9 px; 0: a cold frame starts from the
        target.  From 0 to :data:`~vrcorrect.specs.vocabulary.MAX_ITERATIONS_PER_FRAME`.
    cold_start_model
        ``filter="admm"``: an unrolled model (``vrcorrect unroll``'s ``unrolled.onnx``,
        :class:`~vrcorrect.runtime.unrolled.UnrolledModel`) whose single pass starts every cold frame
        instead of the half-resolution level: the frame is read back, corrected on onnxruntime and
        uploaded (counted as transfers); ``None`` (default): the half-resolution level.
    work_groups
        ``filter="admm"``: the row and column passes' work-group shape (:class:`WorkGroups`); it
        changes the GPU time, never the picture; a mapping ``{"full": {...}, "coarse": {...}}`` is
        taken as one. Default: the shape chosen on an H100.
    pupil
        The viewing pupil designed for: ``"rx"`` (the default here: the eye's ``pupil_diameter_mm`` as
        given), a number of millimetres (:data:`~vrcorrect.physics.pupil.PUPIL_RANGE_MM`), or
        ``"auto"``: from the light of the frames shown (:class:`~vrcorrect.runtime.pupil_bank.PupilBank`:
        the GPU measures each frame's luminance, the pupil follows it with its own dynamics, and the
        correction switches between designs built off the render thread).  The commands (``render``,
        ``mirror``, ``overlay``, ``xr``, the layer) use ``"auto"``.
    robust
        Design over a band of pupils and defocus around the pupil
        (:func:`~vrcorrect.physics.robust.design_eye`: one effective kernel, the frame's cost
        unchanged) instead of for the one eye; the commands use ``True``.
    band
        ``"default"`` (the default here): every design over the default band
        (:class:`~vrcorrect.physics.robust.RobustBand`); ``"auto"`` (the commands'): by the picture, as
        ``correct --band auto``: a page of dark text on white paper is designed over the page band
        (:data:`~vrcorrect.physics.page.PAGE_BAND`, no light cap), anything else over the default band.
        The GPU looks at every few frames (:class:`~vrcorrect.runtime.pupil_state.PupilState`) and the
        bank switches designs as it does between pupils.  Only where :func:`band_switches` (a robust
        design followed with the light, the whole view, the ADMM filter); elsewhere the default band.
    age_years
        The wearer's age for ``pupil="auto"`` (None: the prescription's ``age_years``, else the
        pupil formula's reference age).
    fovea_deg
        ``filter="admm"``: correct only a window of this radius (degrees of visual angle, the half-side
        of a square) around the gaze (:attr:`Corrector.gaze_deg`), the rest of the view shown as it
        is (:mod:`vrcorrect.runtime.strategies.foveated`); ``None`` (default): the whole view.
    fovea_periphery
        With ``fovea_deg``: what the view shows outside the window: ``"quarter"`` (default) or
        ``"half"``, a correction of the whole view at that resolution, or ``"target"``, the view as
        it came (:data:`~vrcorrect.runtime.strategies.foveated.DEFAULT_PERIPHERY` says why).
    gaze_deg
        With ``fovea_deg``: where the eye looks at first, ``(x, y)`` degrees from the view's centre, x
        right, y up (:attr:`Corrector.gaze_deg` follows an eye tracker from there).
    budget_ms
        An iterative filter (``admm``, ``fista``): hold each frame's GPU time at this many ms, the
        Corrector choosing the iterations a frame and, with ``fovea_deg``, the window's radius from
        ``fovea_deg`` down (:mod:`vrcorrect.runtime.budget`); ``None`` (default): the fixed settings.
        A budget turns ``early_stop`` off.
    """

    regularisation: tuple[float, ...] = (0.03, 0.1, 0.3)
    beta: float | None = None
    reference: str = "glasses"
    design_tolerance: float = 1e-3
    rank_tolerance: float = DEFAULT_RANK_TOLERANCE
    choice_size: int = 128
    model: str | None = None
    kernel_options: KernelOptions | None = None
    filter: str = Filter.ADMM
    blend: str = "frame"
    iterations_per_frame: int | None = None
    backend: str = Backend.GLSL
    precision: str = Precision.HALF
    early_stop: bool = True
    cold_iterations: int = DEFAULT_COLD_ITERATIONS
    cold_start_model: str | None = None
    work_groups: WorkGroups = field(default_factory=WorkGroups)
    pupil: str | float = "rx"
    robust: bool = False
    band: str = "default"
    age_years: float | None = None
    fovea_deg: float | None = None
    fovea_periphery: str = Periphery.QUARTER
    gaze_deg: tuple[float, float] = (0.0, 0.0)
    budget_ms: float | None = None

    def __post_init__(self) -> None:
        if self.budget_ms is not None:

            object.__setattr__(self, "budget_ms", check_budget_ms(self.budget_ms))
            if self.filter not in ITERATIVE_FILTERS or self.backend != Backend.GLSL:
                raise ValidationError("budget_ms", self.budget_ms, "only with an iterative filter ("
                                      + either(ITERATIVE_FILTERS) + ") on the glsl backend")
            object.__setattr__(self, "early_stop", False)   # runtime.budget: a still view must not time as free
        if self.pupil not in ("rx", "auto"):
            from ..physics.pupil import check_pupil_mm  # start-up time: the optics load with the first eye

            object.__setattr__(self, "pupil", check_pupil_mm(self.pupil, "pupil"))
        if not isinstance(self.robust, bool):
            raise ValidationError("robust", self.robust, "True or False")
        if self.band not in BAND_OPTIONS:
            raise ValidationError("band", self.band, "'auto' (the page band for a page on white paper) or 'default'")
        if self.age_years is not None and (isinstance(self.age_years, bool) or
                                           not isinstance(self.age_years, (int, float)) or
                                           not 1 <= self.age_years <= 120):
            raise ValidationError("age_years", self.age_years, "None or a number of years from 1 to 120")
        if not self.regularisation or not all(isinstance(m, (int, float)) and m > 0 for m in self.regularisation):
            raise ValidationError("regularisation", self.regularisation, "one or more numbers > 0")
        if self.beta is not None and not (isinstance(self.beta, (int, float)) and 0.0 <= self.beta <= 1.0):
            raise ValidationError("beta", self.beta, "a number in [0, 1] or None")
        if self.reference not in ("glasses", "ideal"):
            raise ValidationError("reference", self.reference, "'glasses' or 'ideal'")
        if self.filter not in names(Filter):
            raise ValidationError("filter", self.filter, one_of(Filter))
        if self.iterations_per_frame is None:
            object.__setattr__(self, "iterations_per_frame", DEFAULT_ITERATIONS.get(self.filter, 0))
        check_iterations(self.iterations_per_frame)
        if self.blend not in ("frame", "fixed"):
            raise ValidationError("blend", self.blend, "'frame' or 'fixed'")
        if self.backend not in names(Backend):
            raise ValidationError("backend", self.backend, one_of(Backend))
        if not isinstance(self.early_stop, bool):
            raise ValidationError("early_stop", self.early_stop, "True or False")
        if self.precision not in names(Precision):
            raise ValidationError("precision", self.precision, one_of(Precision))
        check_iterations(self.cold_iterations, "cold_iterations")
        if isinstance(self.work_groups, Mapping) and set(self.work_groups) <= {"full", "coarse", "column_lines"}:
            object.__setattr__(self, "work_groups", WorkGroups(**self.work_groups))   # as JSON gives it
        if not isinstance(self.work_groups, WorkGroups):
            raise ValidationError("work_groups", self.work_groups,
                                  "a WorkGroups, or a mapping with 'full' and/or 'coarse' tables of values per thread "
                                  "(and 'column_lines')")
        if self.fovea_deg is not None:
            from .strategies.foveated import MAX_FOVEA_DEG, MIN_FOVEA_DEG  # circular: strategies import this module

            if isinstance(self.fovea_deg, bool) or not isinstance(self.fovea_deg, (int, float)) or \
                    not MIN_FOVEA_DEG <= self.fovea_deg <= MAX_FOVEA_DEG:
                raise ValidationError("fovea_deg", self.fovea_deg,
                                      f"None (the whole view) or a radius from {MIN_FOVEA_DEG:g} to {MAX_FOVEA_DEG:g} degrees")
            if self.filter != Filter.ADMM or self.backend != Backend.GLSL or self.cold_start_model is not None:
                raise ValidationError("fovea_deg", self.fovea_deg, "only with filter 'admm' on the glsl backend "
                                      "(no cold_start_model)")
        if self.fovea_periphery not in names(Periphery):
            raise ValidationError("fovea_periphery", self.fovea_periphery, either(Periphery))
        gaze = self.gaze_deg
        if not (isinstance(gaze, (tuple, list)) and len(gaze) == 2 and
                all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and
                    -MAX_GAZE_DEG <= v <= MAX_GAZE_DEG for v in gaze)):
            raise ValidationError("gaze_deg", gaze, "(x, y): two numbers of degrees from the view's centre, each "
                                  f"from {-MAX_GAZE_DEG:g} to {MAX_GAZE_DEG:g}")
        object.__setattr__(self, "gaze_deg", (float(gaze[0]), float(gaze[1])))
        if self.cold_start_model is not None:
            if not isinstance(self.cold_start_model, str) or not self.cold_start_model:
                raise ValidationError("cold_start_model", self.cold_start_model, "a path to an unrolled ONNX model or None")
            if self.filter != Filter.ADMM or self.backend != Backend.GLSL:
                raise ValidationError("cold_start_model", self.cold_start_model,
                                      "only with filter 'admm' on the glsl backend")
            if self.reference != "glasses":
                raise ValidationError("cold_start_model", self.cold_start_model,
                                      "only with reference 'glasses' (the target the model was trained on)")

    @property
    def per_frame_blend(self) -> bool:
        """The FFT strategy's blend weight is computed for every frame, on the GPU."""
        return self.blend == "frame" and self.beta is None and self.filter == Filter.FFT


BAND_OPTIONS = ("default", "auto")
""":attr:`CorrectorOptions.band`'s values."""


def band_switches(options: CorrectorOptions) -> bool:
    """Whether a corrector with ``options`` designs by the picture (``band="auto"``): a robust design
    whose pupil follows the light (its bank switches designs) on the ADMM filter of the glsl backend,
    over the whole view and with no learned cold start (their caps are the programs'); anything else
    keeps the default band."""
    return (options.band == "auto" and options.robust and options.pupil == "auto" and options.filter == Filter.ADMM
            and options.backend == Backend.GLSL and options.fovea_deg is None and options.cold_start_model is None)


@dataclass(frozen=True, eq=False)
class EyeModel:
    """Everything the GPU needs for one eye, computed on the CPU (numpy).

    ``correction`` is the separable strategy's correction bank (``None`` for the other strategies
    and the ONNX backend), ``simulation`` its forward-model bank (``None`` unless
    ``filter="separable"``); ``mu_rel`` and ``beta`` are ``wiener``'s choice (``0`` and ``1`` where
    nothing was chosen)."""

    eye: EyeRx
    kernel: EyeKernel
    reference: EyeKernel | None                  # the glasses-on eye's, or None (ideal)
    identity: bool                               # nothing to correct
    correction: SeparableBank | None
    simulation: SeparableBank | None
    mu_rel: float
    beta: float
    build_seconds: float
    notes: tuple[str, ...] = field(default_factory=tuple)
    seen: EyeKernel | None = None                # the physical eye (a robust design's kernel is not); None: kernel
    pupil_mm: float | None = None                # the viewing pupil designed for
    design: Any = None                           # the Design (vrcorrect.physics.robust) it came from
    grid_kernel_size: int | None = None          # the kernel size grids are made for (a pupil bank's largest)
    reach_mm: float | None = None                # a pupil bank's largest entry its grids hold (bank_reach_mm)
    spectra: dict = field(default_factory=dict)  # precomputed half spectra by (grid, dtype, coarse): a bank's switch
    band: str = "default"                        # the robust band designed over: "default" or "page" (PAGE_BAND)

    @property
    def seen_kernel(self) -> EyeKernel:
        """The eye's physical kernel (what it sees of the display: previews, ``simulate``)."""
        return self.seen if self.seen is not None else self.kernel

    @property
    def margin(self) -> int:
        """Border of the FFT grid around the image (one kernel width; a pupil bank's widest)."""
        own = max(self.kernel.size, self.reference.size if self.reference is not None else 1)
        return max(own, self.grid_kernel_size or 1)


def _sample_target(size: int) -> np.ndarray:
    img = read_image(package_data("sample.png"))
    h, w = img.shape[:2]
    s = min(h, w)
    img = img[(h - s) // 2:(h - s) // 2 + s, (w - s) // 2:(w - s) // 2 + s]
    step = max(1, s // size)
    n = s // step
    lin = decode("srgb", img[:n * step, :n * step].astype(np.float64))
    return lin.reshape(n, step, n, step, 3).mean(axis=(1, 3)).astype(np.float32)      # area average


def _identity_bank() -> SeparableBank:
    return separable_bank(np.eye(3)[:, :, None, None])


def initial_pupil_mm(eye_rx: EyeRx, display: DisplayProfile, options: "CorrectorOptions",
                     mean_relative_luminance: float | None = None, age_years: float | None = None) -> float:
    """The pupil a model is first designed for: ``options.pupil``'s number, the eye's own for
    ``"rx"``, and for ``"auto"`` the light's (:func:`~vrcorrect.physics.pupil.pupil_from_light`) of
    ``mean_relative_luminance`` (None: a mid-grey frame, :data:`NEUTRAL_LUMINANCE`, until the GPU has
    measured one), snapped to the pupil bank's nearest entry, and at most the reach of a mid-grey
    frame's grids (:func:`auto_reach_mm`: a first frame in the dark is not designed for its large pupil)."""
    if options.pupil == "rx":
        return eye_rx.pupil_diameter_mm
    if options.pupil != "auto":
        return float(options.pupil)

    lum = NEUTRAL_LUMINANCE if mean_relative_luminance is None else mean_relative_luminance
    entry = _light_entry(eye_rx, display, options, lum, age_years)
    return min(entry, auto_reach_mm(eye_rx, display, options, entry, age_years))


def _light_entry(eye_rx: EyeRx, display: DisplayProfile, options: "CorrectorOptions", lum: float,
                 age_years: float | None) -> float:
    """The bank entry of the light-adapted pupil for a frame of mean relative luminance ``lum``."""
    age = options.age_years if options.age_years is not None else age_years
    upper = eye_rx.higher_order.pupil_diameter_mm if eye_rx.higher_order is not None else None
    return nearest_bank_pupil(pupil_from_light(lum, display, age, upper_mm=upper).diameter_mm, upper)


def auto_reach_mm(eye_rx: EyeRx, display: DisplayProfile, options: "CorrectorOptions", pupil_mm: float,
                  age_years: float | None = None) -> float:
    """The grids' reach (:func:`~vrcorrect.runtime.pupil_bank.bank_reach_mm`) of a ``pupil="auto"`` bank
    first designed at ``pupil_mm``: its own, or a mid-grey frame's where the first frame was darker.
    A dark first frame (a fade from black, a loading screen) would otherwise size the grids for the
    largest pupil for the whole run; :func:`initial_pupil_mm` holds its design at this reach."""
    return bank_reach_mm(min(pupil_mm, _light_entry(eye_rx, display, options, NEUTRAL_LUMINANCE, age_years)))


NEUTRAL_LUMINANCE = 0.2
"""The mean relative luminance (white = 1) a ``pupil="auto"`` model assumes before the GPU has measured
a frame: a typical photograph's."""


def build_eye_model(eye_rx: EyeRx, display: DisplayProfile,
                    options: CorrectorOptions = CorrectorOptions(), *, pupil_mm: float | None = None,
                    age_years: float | None = None, kernels: dict | None = None,
                    grid_kernel_size: int | None = None, reach_mm: float | None = None,
                    progress: Callable[[int, int], None] | None = None, band: str = "default") -> EyeModel:
    """Kernel, regulariser, blend weight (and, for the separable strategy, both banks) for one
    eye (CPU, numpy); only what ``options.backend`` and ``options.filter`` use (module docstring).

    The eye is designed for the viewing pupil ``pupil_mm`` (default :func:`initial_pupil_mm`), for
    that eye alone or, with ``options.robust``, over the band around it
    (:func:`~vrcorrect.physics.robust.design_eye`); ``kernels`` caches kernels between designs (a
    pupil bank's), ``grid_kernel_size`` makes the grids hold a larger kernel than this design's (with
    ``pupil="auto"`` and none given: the kernel of the bank's reach, ``reach_mm``, by default
    :func:`auto_reach_mm` of this design's pupil);
    ``progress(done, total)`` after each kernel (a bank's worker stops a design from it).  ``band``:
    ``"default"`` or ``"page"`` (:data:`~vrcorrect.physics.page.PAGE_BAND`, with ``options.robust``)."""
    # start-up time, each below: scipy, the optics and the solvers load with the first eye (importing the
    # runtime loads none of them)
    from ..physics.kernel import KernelOptions  # start-up time (above)
    from ..physics.page import PAGE_BAND  # start-up time (above)
    from ..physics.robust import design_eye  # start-up time (above)
    from ..solvers import make_problem  # start-up time (above)
    from ..solvers.wiener import correction_filters, wiener  # start-up time (above)

    t0 = time.perf_counter()
    separable = options.filter == Filter.SEPARABLE
    designs = options.backend == Backend.GLSL            # the ONNX backend corrects with its model
    kopts = options.kernel_options or KernelOptions()
    pupil = initial_pupil_mm(eye_rx, display, options, age_years=age_years) if pupil_mm is None else float(pupil_mm)
    if band not in ("default", "page"):
        raise ValidationError("band", band, "'default' or 'page'")
    design = design_eye(eye_rx, display, pupil, robust=options.robust, reference=options.reference, options=kopts,
                        kernels=kernels, progress=progress, band=PAGE_BAND if band == "page" else None)
    kernel, reference, seen = design.kernel, design.reference, design.nominal
    if options.pupil == "auto" and grid_kernel_size is None:          # the grids hold the bank's reachable designs
        reach_mm = auto_reach_mm(eye_rx, display, options, pupil, age_years) if reach_mm is None else reach_mm
        grid_kernel_size = bank_grid_kernel_size(design, reach_mm, band_slack(design) if band_switches(options)
                                                 else 1.0)
    notes: list[str] = []
    if options.pupil != "rx" or options.robust:
        notes.append(f"designed for a {pupil:.2f} mm pupil" + (" (auto: from the light)" if options.pupil == "auto"
                                                              else "") + "; " + design.describe()[0])
    simulation = None
    if separable:
        sim_taps = np.einsum("ik,kjyx->ijyx", np.linalg.inv(seen.matrix), seen.kernel)       # A^-1 K, the eye's own
        simulation = separable_bank(sim_taps, options.rank_tolerance)

    def model(correction: SeparableBank | None = None, mu_rel: float = 0.0, beta: float = 1.0,
              identity: bool = False) -> EyeModel:
        return EyeModel(eye=eye_rx, kernel=kernel, reference=reference, identity=identity, correction=correction,
                        simulation=simulation, mu_rel=mu_rel, beta=beta,
                        build_seconds=time.perf_counter() - t0, notes=tuple(notes),
                        seen=None if seen is kernel else seen, pupil_mm=pupil, design=design,
                        grid_kernel_size=grid_kernel_size, reach_mm=reach_mm, band=band)

    def nothing_to_correct(why: str) -> EyeModel:
        notes.append(why + ": the correction is the identity")
        return model(_identity_bank() if separable and designs else None, identity=True)

    if kernel.identity or kernel.size == 1:
        return nothing_to_correct("the eye is sharp at this display (identity kernel)")
    if design.sees_as_with_glasses:
        return nothing_to_correct("the eye sees as well as with its glasses (nothing to correct)")
    if not designs:
        notes.append("the ONNX model corrects (no regulariser, blend or filters designed)")
        return model()
    if options.filter == Filter.FISTA:
        notes.append(f"projected gradient (FISTA), {options.iterations_per_frame} iteration(s) per frame, "
                     "warm-started from frame to frame, blended with the target by the frame's best weight")
        return model()
    if options.filter == Filter.ADMM:
        notes.append(f"ADMM, {options.iterations_per_frame} iteration(s) per frame, warm-started from frame to "
                     f"frame with its duals, {options.precision} precision storage, blended with the target by the "
                     "frame's best weight")
        return model()
    problem = make_problem(_sample_target(options.choice_size), kernel, reference)
    settings = wiener(problem, regularisation=options.regularisation, beta=options.beta,
                      tolerance=options.design_tolerance, design=separable, descent=False).settings
    mu = settings.get("mu_rel") or options.regularisation[0]
    beta = float(settings["beta"]) if settings.get("mu_rel") is not None else 0.0
    notes.append(f"regulariser {mu:g} and blend {beta:.3f} chosen by wiener on the sample image")
    correction = None
    if separable:
        filters = correction_filters(kernel, mu, reference, options.design_tolerance)
        correction = separable_bank(filters.taps, options.rank_tolerance)
    return model(correction, float(mu), beta)
