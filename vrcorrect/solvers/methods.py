"""The correction methods by name, and :func:`solve`, which runs one.

:data:`METHODS` maps each numerical method's name to a function of one signature,
``method(problem, progress=None, **options) -> Correction`` (``progress(done, total)`` is called by
the iterative ones): ``none``, ``wiener`` (:func:`vrcorrect.solvers.wiener.wiener`), ``fast``
(:func:`vrcorrect.solvers.admm.fast`), ``paper`` and ``conventional``
(:mod:`vrcorrect.solvers.iterative`).  The last two need torch: they stand here as
:class:`TorchMethod` entries, which import :mod:`~vrcorrect.solvers.iterative` (and torch) only
when one runs, so listing the methods, and everything numpy-only (the real-time path included),
never loads torch.  :data:`LEARNED` is the one method that needs more than the problem: an exported
model bound to the eye (``solve(problem, "learned", model=...)``, :func:`learned`), same signature
and result.

:func:`solve` times the method, clips its image to [0, 1] and judges it by the objective.

Layer 4: numpy here; torch only through :class:`TorchMethod`.
"""

from __future__ import annotations

import time
from types import MappingProxyType
from typing import Callable, Mapping, Protocol

import numpy as np

from ..plumbing.errors import ValidationError
from ..specs.vocabulary import Method, names
from .admm import fast
from .problem import Correction, Problem, SolveResult, objective
from .wiener import wiener

__all__ = ["MethodFunction", "TorchMethod", "METHODS", "LEARNED", "BoundModel", "none", "learned", "solve",
           "PEAK_MEMORY", "peak_memory_bytes"]

MethodFunction = Callable[..., Correction]
"""``method(problem, progress=None, **options) -> Correction`` (its name: a
:class:`~vrcorrect.specs.vocabulary.Method`)."""


def none(problem: Problem, progress: Callable[[int, int], None] | None = None, **options) -> Correction:
    """No correction: the target itself (there is nothing to set: options are ignored)."""
    return Correction(problem.target.copy())


class TorchMethod:
    """A method of :mod:`vrcorrect.solvers.iterative` (torch), named without importing torch: the
    module is imported when the method is loaded (:meth:`load`, which :func:`solve` does before its
    clock starts: torch takes seconds to import) or called."""

    def __init__(self, name: str):
        self.name = str(name)

    def load(self) -> MethodFunction:
        """The method itself (imports torch the first time)."""
        from . import iterative  # torch: only when a torch method runs, never on the real-time path

        return getattr(iterative, self.name)

    def __call__(self, problem: Problem, progress: Callable[[int, int], None] | None = None,
                 **options) -> Correction:
        return self.load()(problem, progress=progress, **options)

    def __repr__(self) -> str:
        return f"TorchMethod({self.name!r})"


METHODS: Mapping[str, MethodFunction] = MappingProxyType({
    Method.NONE: none,
    Method.WIENER: wiener,
    Method.FAST: fast,
    Method.PAPER: TorchMethod(Method.PAPER),
    Method.CONVENTIONAL: TorchMethod(Method.CONVENTIONAL),
})
"""The numerical methods: each needs only the problem (and its own options)."""
LEARNED = Method.LEARNED
"""The learned method: one pass of an exported model bound to the eye (``solve(..., model=...)``)."""


class BoundModel(Protocol):
    """What ``solve(problem, "learned", model=...)`` needs of a learned model bound to one eye and
    display (:meth:`vrcorrect.runtime.learned.LearnedModel.for_eye` gives one; the inference runs on
    onnxruntime, never torch)."""

    def infer(self, image_chw: np.ndarray) -> np.ndarray:
        """``(3, H, W)`` linear RGB target in [0, 1] -> ``(3, H, W)`` displayed image."""
        ...


def learned(problem: Problem, progress: Callable[[int, int], None] | None = None,
            model: BoundModel | None = None, settings: dict | None = None) -> Correction:
    """One pass of the bound learned model (refused outside its range when it was bound);
    ``settings`` are recorded as given."""
    if model is None or not callable(getattr(model, "infer", None)):
        raise ValidationError("model", type(model).__name__, "a learned model bound to the eye (LearnedModel.for_eye)")
    chw = model.infer(np.ascontiguousarray(np.moveaxis(problem.target, 2, 0)))
    return Correction(np.ascontiguousarray(np.moveaxis(chw, 0, 2)), settings=dict(settings or {}))


def solve(problem: Problem, method: str = Method.FAST, progress: Callable[[int, int], None] | None = None,
          **options) -> SolveResult:
    """Run one correction method on ``problem``: the image clipped to [0, 1] (float32), the seconds
    the method took, its objective.

    Options by method: ``wiener``: ``regularisation`` (list of relative values),
    ``fast``: ``tolerance``, ``max_iterations``, ``rho``;
    ``paper``: ``iterations``, ``learning_rate``, ``opponent``, ``seed``;
    ``conventional``: ``max_iterations``, ``tolerance``;
    ``learned``: ``model`` (a :class:`BoundModel`, required) and ``settings`` (recorded as given).
    """
    if method == LEARNED:
        fn: MethodFunction = learned
    elif method in METHODS:
        fn = METHODS[method]
    else:
        raise ValidationError("method", method, "one of " + ", ".join(names((*METHODS, LEARNED))))
    if isinstance(fn, TorchMethod):
        fn = fn.load()                      # imports torch: outside the timed region
    t0 = time.perf_counter()
    found = fn(problem, progress=progress, **options)
    seconds = time.perf_counter() - t0
    image = np.clip(found.image, 0.0, 1.0).astype(np.float32)
    known = found.objective is not None and np.array_equal(image, found.image)     # the method's own, unclipped
    return SolveResult(image=image, method=method, seconds=seconds, iterations=found.iterations,
                       objective=found.objective if known else objective(image, problem), settings=found.settings,
                       history=found.history)


# Peak resident memory of ``vrcorrect correct`` by method, measured on the development machine
# (ru_maxrss of a whole run, the sample prescription on quest2, random images of 256^2 and 768^2;
# paper at 256^2 and 512^2; conventional only at 256^2, so its bytes a pixel are an assumption,
# 1.5 times paper's): a fixed part (interpreter, libraries, the eye's kernel) and bytes per image
# pixel (the solver's float32 planes and complex64 spectra on the padded grid).  Used to refuse,
# before any work, an image that cannot fit; ``none`` is wiener's less the solve (an assumption).
PEAK_MEMORY = {                    # method: (fixed bytes, bytes per pixel)
    Method.NONE: (0.3e9, 120.0),
    Method.WIENER: (0.3e9, 420.0),
    Method.FAST: (0.3e9, 330.0),
    Method.LEARNED: (0.4e9, 420.0),
    Method.PAPER: (0.45e9, 430.0),
    Method.CONVENTIONAL: (0.55e9, 650.0),
}


def peak_memory_bytes(method: str, height: int, width: int) -> float:
    """Estimated peak memory of correcting an ``height x width`` image with ``method`` (see
    :data:`PEAK_MEMORY`; a kernel much larger than the sample's adds to the fixed part)."""
    if method not in PEAK_MEMORY:
        raise ValidationError("method", method, "one of " + ", ".join(names(PEAK_MEMORY)))
    fixed, per_pixel = PEAK_MEMORY[method]
    return fixed + per_pixel * height * width
