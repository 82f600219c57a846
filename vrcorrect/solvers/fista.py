"""Accelerated projected gradient (FISTA) on the true objective, a fixed number of steps at a time
(numpy and scipy.fft; no torch).

Not one of :data:`vrcorrect.solvers.METHODS`: a closed form of known cost, used for the learned
model's inputs (its pre-correction and gradient channels, :mod:`vrcorrect.learn.conditioning`) and
as the CPU twin of the GPU's FISTA over frames (:class:`vrcorrect.solvers.realtime.FistaFrames`;
the GPU strategy takes :func:`fista_momentum`'s weights as uniforms).

The step is ``1 / ||K||^2`` (the gradient's Lipschitz constant), the box is [0, 1], the blur is
exact and linear (:class:`~vrcorrect.solvers.spectral.Blur`: black outside the image), as in
:func:`vrcorrect.solvers.objective`.

Layer 4: numpy and scipy.fft only, so the real-time path may import it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..physics.kernel import EyeKernel
from ..plumbing.errors import ValidationError
from ..vision.forward import check_image
from . import Problem
from .spectral import Blur, kernel_spectrum, padded_shape, spectral_norm_squared

__all__ = ["GradientPlan", "gradient_plan", "gradient_step", "FistaState", "fista_momentum", "projected_gradient"]


@dataclass(frozen=True)
class GradientPlan:
    """What :func:`projected_gradient` needs of the kernel for one image size, computed once.

    Attributes
    ----------
    blur
        The kernel's blur for the image size, its spectrum complex64 (from float64) on the padded
        grid (linear convolution, black outside the image).
    step
        ``1 / ||K||^2`` (the gradient's Lipschitz constant), float32.
    """

    blur: Blur
    step: np.float32

    @property
    def shape(self) -> tuple[int, int]:
        """The image's ``(H, W)``."""
        return self.blur.shape

    @property
    def padded(self) -> tuple[int, int]:
        """The FFT size."""
        return self.blur.grid

    @property
    def spectrum(self) -> np.ndarray:
        """The kernel's spectrum ``(3, 3, Py, Px // 2 + 1)`` complex64."""
        return self.blur.spectrum


def gradient_plan(kernel: EyeKernel, shape: tuple[int, int]) -> GradientPlan:
    """The kernel's blur and step for images of ``shape`` (a renderer keeps one per eye and size)."""
    H, W = (int(v) for v in shape)
    P = padded_shape(H, W, kernel.size)
    blur = Blur(kernel_spectrum(kernel.kernel, P).astype(np.complex64), P, (H, W))
    return GradientPlan(blur, np.float32(1.0 / spectral_norm_squared(kernel.kernel)))


def _plan_for(problem: Problem, plan: GradientPlan | None) -> tuple[GradientPlan, np.ndarray]:
    """``plan`` (built here when ``None``; otherwise it must be for the problem's image size) and the
    target's cone image as ``(3, H, W)`` float32 planes."""
    H, W = problem.target.shape[:2]
    if plan is None:
        plan = gradient_plan(problem.kernel, (H, W))
    elif plan.shape != (H, W) or plan.spectrum.shape[:2] != (3, 3):
        raise ValidationError("plan", f"for {plan.shape[0]}x{plan.shape[1]}", f"a plan for {H}x{W} images")
    return plan, np.moveaxis(problem.target_lms.astype(np.float64), 2, 0).astype(np.float32)


def gradient_step(problem: Problem, x: np.ndarray, plan: GradientPlan | None = None) -> np.ndarray:
    """``step * K^H (K x - t)``: the displacement a projected-gradient step from ``x`` would take
    before clipping (the gradient of ``J/2`` scaled by ``1 / ||K||^2``), float32 ``(H, W, 3)``.

    The learned model's optional fourth input: where the eye's objective still wants ``x`` to go.
    """
    plan, t = _plan_for(problem, plan)
    xc = np.ascontiguousarray(np.moveaxis(x, 2, 0), dtype=np.float32)
    g = plan.step * plan.blur.adjoint(plan.blur.apply(xc) - t)
    return np.ascontiguousarray(np.moveaxis(g, 0, 2), dtype=np.float32)


@dataclass(frozen=True, eq=False)
class FistaState:
    """Where :func:`projected_gradient` stopped, to continue from there (the GPU keeps the same
    per eye from frame to frame).

    Attributes
    ----------
    x
        The current iterate, float32 ``(3, H, W)`` in [0, 1] (what is displayed, before the guard).
    y
        The extrapolated point the next gradient is taken at, float32 ``(3, H, W)``.
    momentum
        FISTA's ``t_k`` (1 at a cold start; the next weight is ``(t_k - 1) / t_{k+1}``).
    """

    x: np.ndarray
    y: np.ndarray
    momentum: float


def fista_momentum(momentum: float) -> tuple[float, float]:
    """FISTA's next ``t_{k+1} = (1 + sqrt(1 + 4 t_k^2)) / 2`` and the extrapolation weight
    ``(t_k - 1) / t_{k+1}`` (the GPU iteration takes the weight as a uniform)."""
    nxt = (1.0 + math.sqrt(1.0 + 4.0 * momentum * momentum)) / 2.0
    return nxt, (momentum - 1.0) / nxt


def projected_gradient(problem: Problem, steps: int, plan: GradientPlan | None = None,
                       start: np.ndarray | None = None, state: FistaState | None = None,
                       return_state: bool = False):
    """``steps`` accelerated projected-gradient (FISTA) steps on the true objective from the target.

    The step is ``1 / ||K||^2`` (the gradient's Lipschitz constant), the box is [0, 1], the
    convolution is exact and linear (black outside the image), as in :func:`vrcorrect.solvers.objective`.
    Each step costs two 3x3-channel FFT convolutions (``K`` and ``K^H``).  A fixed step
    count makes it a closed form of known cost: on the learned model's data (quest2, eyes
    over -6..+6 D sphere, 0..-3 D cylinder, 2-6 mm pupils, 128^2 crops) 1, 3 and 10 steps
    close about 30 %, 50 % and 80 % of the objective gap between no correction and ``fast``.

    ``plan`` (:func:`gradient_plan` of the problem's kernel and image size) skips the kernel's
    FFT, a fifth of the cost of three steps; without it the plan is built here.

    ``start`` (``(H, W, 3)`` in [0, 1]) starts from that image instead of the target, with the
    momentum reset; ``state`` (a :class:`FistaState` returned earlier, for this image size)
    continues where that run stopped, momentum included, so ``n`` steps then ``m`` more from its
    state equal ``n + m`` steps (the CPU twin of the GPU's frame-to-frame warm start).  Not both.
    ``return_state`` returns ``(image, state)``.

    Computed in float32 (complex64 spectra; the kernel's spectrum and norm in float64 first).
    Returns float32 ``(H, W, 3)`` in [0, 1] (the start itself for ``steps == 0`` or a 1x1 kernel).
    """
    if start is not None and state is not None:
        raise ValidationError("start", "given with state", "a start image or a state to continue, not both")
    H, W = problem.target.shape[:2]
    if state is not None:
        if state.x.shape != (3, H, W) or state.y.shape != (3, H, W):
            raise ValidationError("state", f"for {state.x.shape[1]}x{state.x.shape[2]}", f"a state for {H}x{W} images")
        x, y, momentum = state.x, state.y, float(state.momentum)
    else:
        first = problem.target if start is None else check_image(start, "start")
        if first.shape != (H, W, 3):
            raise ValidationError("start", f"shape {first.shape}", f"the target's shape {(H, W, 3)}")
        x = y = np.ascontiguousarray(np.moveaxis(first, 2, 0), dtype=np.float32)
        momentum = 1.0
    if steps > 0 and problem.kernel.size > 1:
        plan, t = _plan_for(problem, plan)
        blur, step = plan.blur, plan.step
        for _ in range(steps):
            x_new = np.clip(y - step * blur.adjoint(blur.apply(y) - t), 0.0, 1.0)
            momentum, weight = fista_momentum(momentum)
            y = x_new + np.float32(weight) * (x_new - x)
            x = x_new
    image = np.ascontiguousarray(np.moveaxis(x, 0, 2), dtype=np.float32)
    return (image, FistaState(x=x, y=y, momentum=momentum)) if return_state else image
