"""The objective guard of an offline correction (``vrcorrect correct --guard RHO``; issue 44).

A correction ``x`` is designed for the eye as modelled (a band of pupils and spheres around it).  An
eye whose sphere is off by more than the band allows, 0.5 D *nearer focus* above all, may see ``x``
worse than the target shown as it is: the design sharpens what that eye already sees sharp.  The
guard shows ``t + b (x - t)`` instead, with the largest ``b`` in [0, 1] that keeps each guard eye's
objective at most ``rho`` times its objective for ``t`` itself (``rho >= 1``; 1: never worse than
none, by the objective).  Each guard eye's objective of the blend is exactly quadratic in ``b``
(the eye's cone image is linear in the displayed image, and a blend of two images in [0, 1] stays
in [0, 1]), so three evaluations, at ``b`` = 0, 1/2 and 1, give it:
``f(b) = f0 + 2 g b + c b^2`` with ``c = 2 (f1 - 2 fh + f0)``, ``g = (f1 - f0 - c) / 2``.

It acts only where the objective sees harm: an eye for whom ``x`` is no worse than ``rho`` times
none leaves ``b`` at 1.  It does not see every fall that JOD sees (``docs/realtime.md``, "Eyes of
sphere alone").

Layer 4: numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..plumbing.errors import ValidationError
from .problem import Problem, objective

__all__ = ["GUARD_SPHERE_D", "Guarded", "guard_blend"]

#: The guard eyes: the prescription's sphere this far off, either way (the ``Done when`` of issue 44).
GUARD_SPHERE_D = 0.5


@dataclass(frozen=True)
class Guarded:
    """What the guard did: the image shown, the blend weight ``b`` (1: the correction as it was), and
    each guard eye's objective for the correction, for the image shown and for none (``t`` itself)."""

    image: np.ndarray
    weight: float
    before: tuple[float, ...]
    after: tuple[float, ...]
    none: tuple[float, ...]

    def ratios(self, which: str = "before") -> tuple[float, ...]:
        """Each guard eye's objective over none's (``inf`` where none's is 0 and the image's is not)."""
        values = self.before if which == "before" else self.after
        return tuple(v / n if n > 0 else (1.0 if v <= 0 else math.inf) for v, n in zip(values, self.none))


def _largest_weight(f0: float, fh: float, f1: float, rho: float) -> float:
    """The largest ``b`` in [0, 1] with ``f(b) <= rho f0`` for the quadratic through ``f(0), f(1/2), f(1)``."""
    if f1 <= rho * f0:
        return 1.0                               # f is convex (a sum of squares): f(b) <= max(f0, f1) <= rho f0
    c = 2.0 * (f1 - 2.0 * fh + f0)
    g = 0.5 * (f1 - f0 - c)
    if c <= 0.0:                                 # rounding: a straight line from f0 to f1 > rho f0
        return max(0.0, (rho - 1.0) * f0 / (f1 - f0)) if f1 > f0 else 1.0
    root = (-g + math.sqrt(max(g * g + c * (rho - 1.0) * f0, 0.0))) / c
    return min(max(root, 0.0), 1.0)


def guard_blend(shown: np.ndarray, target: np.ndarray, problems: Sequence[Problem], rho: float) -> Guarded:
    """``t + b (x - t)`` for a correction ``shown`` (``x``, linear display RGB in [0, 1]) of ``target``
    (``t``), with the largest ``b`` in [0, 1] that keeps every guard eye's objective (``problems``: one
    :class:`~vrcorrect.solvers.problem.Problem` per guard eye, of ``target``) at most ``rho`` times
    its objective for ``t``.  float64 for the objectives, float32 for the image."""
    if not (isinstance(rho, (int, float)) and math.isfinite(rho) and rho >= 1.0):
        raise ValidationError("guard", rho, "a finite factor of at least 1 (the most objective, times none's, a "
                                            "guard eye may see)")
    x = np.asarray(shown, np.float32)
    t = np.asarray(target, np.float32)
    if x.shape != t.shape:
        raise ValidationError("shown.shape", x.shape, f"the target's shape {t.shape}")
    half = (t + np.float32(0.5) * (x - t)).astype(np.float32)
    weight, before, none = 1.0, [], []
    for problem in problems:
        f0, fh, f1 = objective(t, problem), objective(half, problem), objective(x, problem)
        before.append(f1)
        none.append(f0)
        weight = min(weight, _largest_weight(f0, fh, f1, float(rho)))
    image = x if weight >= 1.0 else (t + np.float32(weight) * (x - t)).astype(np.float32)
    after = tuple(before) if weight >= 1.0 else tuple(objective(image, p) for p in problems)
    return Guarded(image=image, weight=float(weight), before=tuple(before), after=after, none=tuple(none))
