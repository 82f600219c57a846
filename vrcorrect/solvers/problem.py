"""What every correction method is asked and what it answers: the :class:`Problem`, the objective,
the closed-form weight of the best blend with the target, and the results.

All methods share one problem statement (:class:`Problem`): a linear RGB target, the eye's kernel,
and the target's cone image; and one objective, the mean squared error between the simulated
retinal cone image of the displayed image and the target cone image (:func:`objective`).  A method
returns a :class:`Correction`; :func:`vrcorrect.solvers.solve` times it, clips its image and
judges it into a :class:`SolveResult`.

Layer 4: numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from ..physics.kernel import EyeKernel
from ..plumbing.errors import ValidationError
from ..vision.forward import check_image, simulate_lms

if TYPE_CHECKING:  # pragma: no cover - typing only
    from ..physics.robust import Design

__all__ = ["Problem", "Correction", "SolveResult", "scale_contrast", "make_problem", "make_design_problem", "objective",
           "guard_weight", "light_cap", "LIGHT_CAP_FLOOR"]

#: The light cap's floor (a fraction of white): a robust design's displayed primary may be at most
#: ``2 t + LIGHT_CAP_FLOOR`` where the target's is ``t`` (:func:`light_cap`).
LIGHT_CAP_FLOOR = 0.02


def light_cap(target: np.ndarray, floor: float = LIGHT_CAP_FLOOR) -> np.ndarray:
    """The light cap of a robust design (issue 44): the most each displayed primary may show,
    ``min(1, 2 t + floor)`` for the target's ``t`` (any shape, linear light), float32.

    A correction may add to a pixel at most the light the target has there, plus ``floor`` of white.
    By Weber's law the eye sees light added to a dark ground relative to that ground, so a halo that
    lifts a dark ground is seen far more than its share of the linear objective; an eye that sees
    better than the design assumed sees such halos where the design put them, and on light text over a
    dark ground the correction then fell below no correction (docs/realtime.md, "The light cap").
    On a bright image the cap is 1 nearly everywhere.  It is the upper end of the box that ``fast``
    and the real-time ADMM project onto (``0 <= x <= light_cap(t)``), a pointwise bound, so it costs
    nothing but the target's read where the box is applied."""
    return np.minimum(np.float32(1.0), np.float32(2.0) * np.asarray(target, np.float32) + np.float32(floor))


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
    members
        A robust design's eyes (:func:`make_design_problem`): then ``kernel`` is the design's
        effective kernel ``U`` and ``target_lms`` its ``R t``, the objective is the expectation over
        the members (:func:`objective`), and ``fast`` minimises it exactly
        (:mod:`vrcorrect.solvers.expectation`); the other methods solve the effective form.
    capped
        The displayed image is bounded by :func:`light_cap` of ``target`` instead of 1 (a robust
        design's whose band keeps the cap, :func:`make_design_problem`); ``fast`` honours it, and the real-time ADMM does
        the same for a robust design; the other methods keep the box [0, 1].
    """

    target: np.ndarray
    kernel: EyeKernel
    target_lms: np.ndarray
    contrast: float = 1.0
    reference: str = "ideal"
    reference_kernel: EyeKernel | None = None
    members: tuple = ()
    capped: bool = False


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


def make_design_problem(target: np.ndarray, design: "Design", contrast: float = 1.0) -> Problem:
    """The :class:`Problem` of a correction design (:func:`vrcorrect.physics.robust.design_eye`): a
    robust design's carries its members (each eye's kernel and target cone image: with glasses, its
    glasses kernel's view; ideal, ``A t``), the effective kernel and ``R t``; a single eye's is
    :func:`make_problem`'s."""
    problem = make_problem(target, design.kernel, design.reference, contrast)
    if not design.robust:
        return problem
    from .expectation import BandEye  # the robust path only

    ts = scale_contrast(problem.target, contrast)
    members = []
    for m in design.members:
        k, r = design.member_kernels(m)
        tl = simulate_lms(ts, r)[0] if r is not None else (ts @ k.matrix.T.astype(np.float32))
        members.append(BandEye(m.weight, k, np.asarray(tl, np.float32)))
    return replace(problem, members=tuple(members), capped=design.capped, reference="glasses" if design.nominal_reference is not None
                   else "ideal", reference_kernel=design.nominal_reference)


def objective(displayed: np.ndarray, problem: Problem) -> float:
    """Mean squared error between the retinal cone image of ``displayed`` and the target's (float64);
    for a robust problem, its expectation over the members."""
    shown = check_image(displayed, "displayed").astype(np.float32)
    if shown.shape != problem.target.shape:
        raise ValidationError("displayed.shape", shown.shape, f"the problem's shape {problem.target.shape}")
    if problem.members:
        from .expectation import expectation_objective  # the robust path only

        return expectation_objective(np.ascontiguousarray(np.moveaxis(shown, 2, 0)), problem.members)
    lms, _ = simulate_lms(shown, problem.kernel, "fft" if problem.kernel.size > 1 else "auto")
    d = lms.astype(np.float64) - problem.target_lms.astype(np.float64)
    return float(np.mean(d * d))


def guard_weight(s_rk: float, s_kk: float, s_rr: float = 0.0) -> float:
    """The blend weight in [0, 1] minimising ``|r0 + beta Kd|^2`` from ``s_rk = <r0, Kd>`` and
    ``s_kk = <Kd, Kd>``: ``clip(-s_rk / s_kk, 0, 1)``; 0 when ``Kd`` is 0 or negligible beside
    ``r0`` (``s_kk <= 1e-10 s_rr``, ``s_rr = <r0, r0>``: the correction is the target itself, to
    rounding; with the default ``s_rr = 0``, only when ``s_kk <= 0``).

    With ``r0 = K t - T`` (the uncorrected residual) and ``Kd = K (x - t)``, ``t + beta (x - t)`` is
    the best blend of the target and a correction ``x``, never worse than the target: the guard of
    the real-time frames (:mod:`vrcorrect.solvers.realtime`; on the GPU ``shaders/admm.glsl``'s
    ``GUARD_FINAL`` and ``shaders/blend.glsl``), ``wiener``'s blend and ``fast``'s closed-form start.
    """
    return 0.0 if not s_kk > 1e-10 * s_rr else min(max(-s_rk / s_kk, 0.0), 1.0)


@dataclass
class Correction:
    """What a correction method returns (the one shape of every entry of
    :data:`vrcorrect.solvers.METHODS`): the displayed image, before :func:`vrcorrect.solvers.solve`
    clips it to [0, 1], and how it was found.

    Attributes
    ----------
    image
        ``(H, W, 3)`` linear display RGB.
    iterations
        Iterations taken (0 for a closed form).
    settings
        What the method chose and was given, for reports.
    history
        The objective (or the method's own loss) after each iteration.
    objective
        The problem's objective of ``image`` where the method evaluated it (``fast`` does, to compare
        its result with the target); None: :func:`vrcorrect.solvers.solve` evaluates it.
    """

    image: np.ndarray
    iterations: int = 0
    settings: dict = field(default_factory=dict)
    history: list[float] = field(default_factory=list)
    objective: float | None = None


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
