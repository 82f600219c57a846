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
sphere alone"): the objective is linear in light, so an error on a dark ground weighs almost nothing
in it.  ``measure="lightness"`` guards a lightness-like error instead (:func:`lightness_error`: the
cube roots of each cone's light relative to white's, plus :data:`LIGHTNESS_FLOOR`), which is not
quadratic in ``b``; the eye's cone image still is linear in ``b``, so two simulations an eye give
the error at every ``b`` of a grid of :data:`LIGHTNESS_STEPS` steps, and ``b`` is the largest grid
point every eye allows (the thirteenth look of ``docs/realtime.md``).  ``measure="visibility"``
guards the same six eyes on :func:`~vrcorrect.vision.visibility.visibility_error` (each band's
contrast against the goal's local light, weighted by the eye's contrast sensitivity there), which is
quadratic in ``b`` like the objective, so three points give ``b`` exactly (the fourteenth look).

Layer 4: numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ..plumbing.errors import ValidationError
from ..vision.forward import simulate_lms
from ..vision.visibility import ViewingLight, visibility_error
from .problem import Problem, objective

__all__ = ["GUARD_MEASURES", "GUARD_PUPILS_MM", "GUARD_SPHERE_D", "LIGHTNESS_FLOOR", "LIGHTNESS_STEPS",
           "PUPIL_GUARD_MEASURES", "Guarded", "guard_blend", "lightness_error"]

#: The guard eyes: the prescription's sphere this far off, either way (the ``Done when`` of issue 44).
GUARD_SPHERE_D = 0.5

#: The lightness guard's eyes besides those two: the prescribed eye through each of these pupils (the
#: pupils of the ``Done when`` of issue 44), mm.
GUARD_PUPILS_MM = (2.5, 3.0, 4.0, 5.5)

#: What the guard keeps each eye's view of the blend within ``rho`` times none's of.
GUARD_MEASURES = ("objective", "lightness", "visibility")

#: The measures that guard the prescribed eye through :data:`GUARD_PUPILS_MM` too.
PUPIL_GUARD_MEASURES = ("lightness", "visibility")

#: The lightness-like error's floor, of white's light: a cone's light ``q`` of white's ``w`` counts
#: as ``(q / w + LIGHTNESS_FLOOR) ** (1/3)``, so that black's slope stays finite (CIELAB's cube root
#: turns linear below 0.009 of white; this floor does the same work without a seam).
LIGHTNESS_FLOOR = 0.01

#: The lightness guard's grid of blend weights: ``b`` in ``0, 1/STEPS, ..., 1``.
LIGHTNESS_STEPS = 40


@dataclass(frozen=True)
class Guarded:
    """What the guard did: the image shown, the blend weight ``b`` (1: the correction as it was), and
    each guard eye's objective for the correction, for the image shown and for none (``t`` itself)."""

    image: np.ndarray
    weight: float
    before: tuple[float, ...]
    after: tuple[float, ...]
    none: tuple[float, ...]
    measure: str = "objective"

    def ratios(self, which: str = "before") -> tuple[float, ...]:
        """Each guard eye's error by :attr:`measure` over none's (``inf`` where none's is 0 and the image's is not)."""
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


def _lightness(lms: np.ndarray, white: np.ndarray) -> np.ndarray:
    """Each cone's light as the lightness-like scale: ``cbrt(max(q, 0) / w + LIGHTNESS_FLOOR)`` (float64)."""
    return np.cbrt(np.maximum(lms.astype(np.float64), 0.0) / white + LIGHTNESS_FLOOR)


def _seen_by(problem: Problem):
    """The cone image an eye's problem sees of a displayed image (a function), and white's cone light."""
    if problem.members:
        raise ValidationError("problem", "a robust design", "one eye's problem (the guard judges single eyes)")
    method = "fft" if problem.kernel.size > 1 else "auto"
    return (lambda image: simulate_lms(image, problem.kernel, method)[0]), problem.kernel.matrix.sum(axis=1)


def lightness_error(displayed: np.ndarray, problem: Problem) -> float:
    """The mean squared difference, on the lightness-like scale (white's cone light 1), between the
    cone image of ``displayed`` seen by ``problem``'s eye and the target's cone image (float64).  A
    dark ground's error weighs here as the eye sees it, where the objective (linear in light) all but
    ignores it."""
    seen, white = _seen_by(problem)
    d = _lightness(seen(np.asarray(displayed, np.float32)), white) - _lightness(problem.target_lms, white)
    return float(np.mean(d * d))


def _lightness_curve(x: np.ndarray, t: np.ndarray, problem: Problem, steps: int) -> np.ndarray:
    """The lightness error of ``t + b (x - t)`` at ``b = 0, 1/steps, ..., 1`` (the cone image is linear
    in ``b``: two simulations)."""
    seen, white = _seen_by(problem)
    seen_t = seen(t).astype(np.float64)
    seen_d = seen(x).astype(np.float64) - seen_t
    goal = _lightness(problem.target_lms, white)
    out = np.empty(steps + 1)
    for i in range(steps + 1):
        d = _lightness(seen_t + (i / steps) * seen_d, white) - goal
        out[i] = float(np.mean(d * d))
    return out


def _blend(x: np.ndarray, t: np.ndarray, b: float) -> np.ndarray:
    """``t + b (x - t)`` in float32 (``x`` itself at ``b`` = 1)."""
    return x if b >= 1.0 else (t + np.float32(b) * (x - t)).astype(np.float32)


def _guard_lightness(x: np.ndarray, t: np.ndarray, problems: Sequence[Problem], rho: float) -> Guarded:
    """:func:`guard_blend` on the lightness-like error."""
    steps = LIGHTNESS_STEPS
    allowed = np.ones(steps + 1, bool)
    curves = []
    for problem in problems:
        curve = _lightness_curve(x, t, problem, steps)
        curves.append(curve)
        allowed &= curve <= rho * curve[0] * (1.0 + 1e-12)
    k = int(np.flatnonzero(allowed).max())               # b = 0 is always allowed
    weight = k / steps
    return Guarded(image=_blend(x, t, weight), weight=weight, before=tuple(float(c[-1]) for c in curves),
                   after=tuple(float(c[k]) for c in curves), none=tuple(float(c[0]) for c in curves),
                   measure="lightness")


def _guard_quadratic(x: np.ndarray, t: np.ndarray, problems: Sequence[Problem], rho: float,
                     error_of: Callable[[Problem], Callable[[float], float]], measure: str) -> Guarded:
    """:func:`guard_blend` on an error quadratic in ``b``: ``error_of(problem)`` is that eye's error of
    ``t + b (x - t)`` as a function of ``b``; three values an eye (``b`` = 0, 1/2, 1) give ``b`` exactly."""
    weight, curves = 1.0, []
    for problem in problems:
        error = error_of(problem)
        f0, fh, f1 = error(0.0), error(0.5), error(1.0)
        curves.append((error, f0, f1))
        weight = min(weight, _largest_weight(f0, fh, f1, rho))
    return Guarded(image=_blend(x, t, weight), weight=float(weight), before=tuple(f1 for _, _, f1 in curves),
                   after=tuple(f1 if weight >= 1.0 else error(weight) for error, _, f1 in curves),
                   none=tuple(f0 for _, f0, _ in curves), measure=measure)


def _visibility_of(x: np.ndarray, t: np.ndarray, viewing: ViewingLight) -> Callable[[Problem], Callable[[float], float]]:
    """Each eye's visibility error of ``t + b (x - t)`` as a function of ``b``, from two simulations (the
    cone image is linear in ``b``)."""
    def error_of(problem: Problem) -> Callable[[float], float]:
        seen, white = _seen_by(problem)
        seen_t, seen_x = seen(t).astype(np.float64), seen(x).astype(np.float64)
        return lambda b: visibility_error(seen_t + b * (seen_x - seen_t), problem.target_lms, white, viewing)
    return error_of


def guard_blend(shown: np.ndarray, target: np.ndarray, problems: Sequence[Problem], rho: float,
                measure: str = "objective", viewing: ViewingLight | None = None) -> Guarded:
    """``t + b (x - t)`` for a correction ``shown`` (``x``, linear display RGB in [0, 1]) of ``target``
    (``t``), with the largest ``b`` in [0, 1] that keeps every guard eye's objective (``problems``: one
    :class:`~vrcorrect.solvers.problem.Problem` per guard eye, of ``target``) at most ``rho`` times
    its objective for ``t``.  float64 for the objectives, float32 for the image.  ``measure``
    (:data:`GUARD_MEASURES`): ``"objective"`` (exact ``b``), ``"lightness"`` (:func:`lightness_error`,
    ``b`` on a grid of :data:`LIGHTNESS_STEPS`) or ``"visibility"``
    (:func:`~vrcorrect.vision.visibility.visibility_error` at ``viewing``, the display's light and pixels
    per degree; exact ``b``)."""
    if not (isinstance(rho, (int, float)) and math.isfinite(rho) and rho >= 1.0):
        raise ValidationError("guard", rho, "a finite factor of at least 1 (the most objective, times none's, a "
                                            "guard eye may see)")
    x = np.asarray(shown, np.float32)
    t = np.asarray(target, np.float32)
    if x.shape != t.shape:
        raise ValidationError("shown.shape", x.shape, f"the target's shape {t.shape}")
    if measure not in GUARD_MEASURES:
        raise ValidationError("measure", measure, f"one of {', '.join(GUARD_MEASURES)}")
    if measure == "lightness":
        return _guard_lightness(x, t, problems, float(rho))
    if measure == "visibility":
        if not isinstance(viewing, ViewingLight):
            raise ValidationError("viewing", viewing, "the display's ViewingLight (its light and pixels per degree) for "
                                                      "the visibility guard")
        return _guard_quadratic(x, t, problems, float(rho), _visibility_of(x, t, viewing), "visibility")
    return _guard_quadratic(x, t, problems, float(rho),
                            lambda problem: (lambda b: objective(_blend(x, t, b), problem)), "objective")
