"""Layer 4: the correction methods, which find the displayed image whose retinal image matches the target's.

All methods share one problem statement (:class:`Problem`): a linear RGB
target, the eye's kernel, and the target's cone image; and one objective,
the mean squared error between the simulated retinal cone image of the
displayed image and the target cone image (:func:`objective`).

``none``, ``wiener`` (the real-time path's mathematics) and ``fast`` are numpy
only; ``paper`` and ``conventional`` import torch lazily.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from ..physics.kernel import EyeKernel
from ..plumbing.errors import ValidationError
from ..vision.forward import check_image, simulate_lms

METHODS = ("none", "wiener", "fast", "paper", "conventional")
"""The numerical methods: each needs only the problem."""
LEARNED = "learned"
"""The learned method: one pass of an exported model bound to the eye (``solve(..., model=...)``)."""


class BoundModel(Protocol):
    """What ``solve(problem, "learned", model=...)`` needs of a learned model bound to one eye and
    display (:meth:`vrcorrect.runtime.learned.LearnedModel.for_eye` gives one; the inference runs on
    onnxruntime, never torch)."""

    def infer(self, image_chw: np.ndarray) -> np.ndarray:
        """``(3, H, W)`` linear RGB target in [0, 1] -> ``(3, H, W)`` displayed image."""
        ...


@dataclass(frozen=True, eq=False)
class Problem:
    """What a correction method is asked to solve.

    Attributes
    ----------
    target
        ``(H, W, 3)`` linear display RGB in [0, 1] (float32): the image the user wants to see.
    kernel
        The eye's kernel.
    target_lms
        ``(H, W, 3)`` cone image the retina should receive.
    contrast
        Contrast scale applied to the target before its cone image was taken (1 = none).
    reference
        ``"glasses"`` (the same eye with its sphere and cylinder corrected: its own chromatic
        aberration and diffraction remain) or ``"ideal"`` (the paper's ``A t``, no blur at all).
    """

    target: np.ndarray
    kernel: EyeKernel
    target_lms: np.ndarray
    contrast: float = 1.0
    reference: str = "ideal"
    reference_kernel: EyeKernel | None = None


def scale_contrast(image: np.ndarray, contrast: float) -> np.ndarray:
    """Compress contrast about the image's mean (mean-preserving): ``m + c (t - m)``."""
    if not (0.0 < contrast <= 1.0):
        raise ValidationError("contrast", contrast, "a number in (0, 1]")
    if contrast == 1.0:
        return image
    m = image.mean(axis=(0, 1), keepdims=True)
    return (m + contrast * (image - m)).astype(image.dtype)


def make_problem(target: np.ndarray, kernel: EyeKernel, reference_kernel: EyeKernel | None = None,
                 contrast: float = 1.0) -> Problem:
    """Build a :class:`Problem`; ``reference_kernel`` is the eye with glasses on (None: ideal ``A t``)."""
    t = check_image(target, "target").astype(np.float32)
    ts = scale_contrast(t, contrast)
    if reference_kernel is None:
        tl = (ts @ kernel.matrix.T.astype(np.float32)).astype(np.float32)
        ref = "ideal"
    else:
        tl, _ = simulate_lms(ts, reference_kernel)
        ref = "glasses"
    return Problem(target=t, kernel=kernel, target_lms=tl, contrast=contrast, reference=ref,
                   reference_kernel=reference_kernel)


def objective(displayed: np.ndarray, problem: Problem) -> float:
    """Mean squared error between the retinal cone image of ``displayed`` and the target's (float64)."""
    shown = check_image(displayed, "displayed").astype(np.float32)
    if shown.shape != problem.target.shape:
        raise ValidationError("displayed.shape", shown.shape, f"the problem's shape {problem.target.shape}")
    lms, _ = simulate_lms(shown, problem.kernel, "fft" if problem.kernel.size > 1 else "auto")
    d = lms.astype(np.float64) - problem.target_lms.astype(np.float64)
    return float(np.mean(d * d))


@dataclass
class SolveResult:
    """A displayable image and how it was found."""

    image: np.ndarray                 # (H, W, 3) float32 linear RGB in [0, 1]
    method: str
    seconds: float
    iterations: int
    objective: float
    settings: dict = field(default_factory=dict)
    history: list[float] = field(default_factory=list)


# Peak resident memory of ``vrcorrect correct`` by method, measured on the development machine
# (ru_maxrss of a whole run, the sample prescription on quest2, random images of 256^2 and 768^2;
# paper at 256^2 and 512^2; conventional only at 256^2, so its bytes a pixel are an assumption,
# 1.5 times paper's): a fixed part (interpreter, libraries, the eye's kernel) and bytes per image
# pixel (the solver's float32 planes and complex64 spectra on the padded grid).  Used to refuse,
# before any work, an image that cannot fit; ``none`` is wiener's less the solve (an assumption).
PEAK_MEMORY = {                    # method: (fixed bytes, bytes per pixel)
    "none": (0.3e9, 120.0),
    "wiener": (0.3e9, 420.0),
    "fast": (0.3e9, 330.0),
    "learned": (0.4e9, 420.0),
    "paper": (0.45e9, 430.0),
    "conventional": (0.55e9, 650.0),
}


def peak_memory_bytes(method: str, height: int, width: int) -> float:
    """Estimated peak memory of correcting an ``height x width`` image with ``method`` (see
    :data:`PEAK_MEMORY`; a kernel much larger than the sample's adds to the fixed part)."""
    if method not in PEAK_MEMORY:
        raise ValidationError("method", method, "one of " + ", ".join(PEAK_MEMORY))
    fixed, per_pixel = PEAK_MEMORY[method]
    return fixed + per_pixel * height * width


def solve(problem: Problem, method: str = "fast", progress: Callable[[int, int], None] | None = None,
          **options) -> SolveResult:
    """Run one correction method on ``problem``.

    Options by method: ``wiener``: ``regularisation`` (list of relative values),
    ``fast``: ``tolerance``, ``max_iterations``, ``rho``;
    ``paper``: ``iterations``, ``learning_rate``, ``opponent``, ``seed``;
    ``conventional``: ``max_iterations``, ``tolerance``;
    ``learned``: ``model`` (a :class:`BoundModel`, required) and ``settings`` (recorded as given).
    """
    if method == LEARNED:
        return _solve_learned(problem, **options)
    if method not in METHODS:
        raise ValidationError("method", method, "one of " + ", ".join(METHODS + (LEARNED,)))
    # the methods' modules import Problem from this one, so they are imported here, not above
    from .wiener import wiener

    if method == "fast":
        from .admm import fast as fn
    elif method in ("paper", "conventional"):
        from . import iterative  # imports torch: outside the timed region

        fn = {"paper": iterative.paper, "conventional": iterative.conventional}[method]
    t0 = time.perf_counter()
    if method == "none":
        image, iters, settings, history = problem.target.copy(), 0, {}, []
    elif method == "wiener":
        image, settings = wiener(problem, **options)
        iters, history = 0, []
    else:
        image, iters, settings, history = fn(problem, progress=progress, **options)
    seconds = time.perf_counter() - t0
    image = np.clip(image, 0.0, 1.0).astype(np.float32)
    return SolveResult(image=image, method=method, seconds=seconds, iterations=iters,
                       objective=objective(image, problem), settings=settings, history=history)


def _solve_learned(problem: Problem, model: BoundModel | None = None, settings: dict | None = None) -> SolveResult:
    """One pass of the bound learned model (refused outside its range when it was bound)."""
    if model is None or not callable(getattr(model, "infer", None)):
        raise ValidationError("model", type(model).__name__, "a learned model bound to the eye (LearnedModel.for_eye)")
    t0 = time.perf_counter()
    chw = model.infer(np.ascontiguousarray(np.moveaxis(problem.target, 2, 0)))
    seconds = time.perf_counter() - t0
    image = np.clip(np.ascontiguousarray(np.moveaxis(chw, 0, 2)), 0.0, 1.0).astype(np.float32)
    return SolveResult(image=image, method=LEARNED, seconds=seconds, iterations=0,
                       objective=objective(image, problem), settings=dict(settings or {}))
