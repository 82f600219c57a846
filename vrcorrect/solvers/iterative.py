"""Iterative correction methods that need autograd (torch, CPU or GPU; float32 images).

The one module of the package that imports torch; :data:`vrcorrect.solvers.METHODS` names these
methods without importing it (:class:`vrcorrect.solvers.methods.TorchMethod`), and nothing on the
real-time path may import this module.  (``fast``, the ADMM solver, is numpy only:
:mod:`vrcorrect.solvers.admm`.)

* ``paper``: ChromaCorrect as published - Adam on the displayed image,
  initialised at the target, clamped to [0, 1] after each step, loss = MSE of
  retinal LMS (or opponent) against the target, learning rate 0.01, 100
  iterations (stopping early only if the loss is already below 1e-10, where
  Adam's normalised steps would just add noise).
* ``conventional``: Montalto et al. (2015) constrained total variation with a
  per-primary RGB PSF and no cone model,
  ``||k * x - t||^2 + theta TV(x) + tau sum(exp(-L x) + exp(-L (1 - x)))``,
  theta = 1e-6, tau = 2e-5, L = 65 (sums over pixels; isotropic TV smoothed
  with eps = 1e-8), solved by L-BFGS with strong-Wolfe line search from the
  target, stopping on relative change < ``tolerance`` or ``max_iterations``;
  then clipped.  The per-primary PSF is the kernel's luminance (L + M) part:
  ``k_c = (K[L, c] + K[M, c]) / sum``.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from ..physics.perception import OPPONENT_MATRIX
from .problem import Correction, Problem, scale_contrast
from .spectral import padded_shape


class FftOperator:
    """``y_k = sum_c K[k, c] * x_c`` (linear convolution, zero outside, same size) and its adjoint:
    :class:`vrcorrect.solvers.spectral.Blur` in torch, for autograd (the kernel zero-padded at the
    grid's corner and the result cropped at its radius, rather than centred)."""

    def __init__(self, kernel: np.ndarray, height: int, width: int, dtype=torch.float32, device="cpu"):
        s = kernel.shape[-1]
        self.r = s // 2
        self.H, self.W = height, width

        self.P = padded_shape(height, width, s)
        k = torch.as_tensor(np.ascontiguousarray(kernel), dtype=dtype, device=device)
        self.Kf = torch.fft.rfft2(k, s=self.P)                 # (n_out, n_in, P0, F1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        X = torch.fft.rfft2(x, s=self.P)
        Y = torch.einsum("kcyx,cyx->kyx", self.Kf, X)
        y = torch.fft.irfft2(Y, s=self.P)
        return y[..., self.r:self.r + self.H, self.r:self.r + self.W]

    def adjoint(self, z: torch.Tensor) -> torch.Tensor:
        Zp = torch.zeros(z.shape[:-2] + self.P, dtype=z.dtype, device=z.device)
        Zp[..., self.r:self.r + self.H, self.r:self.r + self.W] = z
        Z = torch.fft.rfft2(Zp)
        X = torch.einsum("kcyx,kyx->cyx", self.Kf.conj(), Z)
        return torch.fft.irfft2(X, s=self.P)[..., :self.H, :self.W]


def _chw(image: np.ndarray, dtype=torch.float32) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(np.moveaxis(image, 2, 0)), dtype=dtype)


def _hwc(x: torch.Tensor) -> np.ndarray:
    return np.moveaxis(x.detach().cpu().numpy(), 0, 2).astype(np.float32)


def paper(problem: Problem, iterations: int = 100, learning_rate: float = 0.01, opponent: bool = False,
          seed: int = 0, progress: Callable[[int, int], None] | None = None) -> Correction:
    """ChromaCorrect's published optimisation: Adam from the target, clamped, LMS (or opponent) MSE."""
    torch.manual_seed(seed)
    H, W = problem.target.shape[:2]
    op = FftOperator(problem.kernel.kernel, H, W)
    t = _chw(problem.target_lms)
    x = _chw(problem.target).clone().requires_grad_(True)
    opt = torch.optim.Adam([x], lr=learning_rate)
    to_opponent = torch.tensor(np.array(OPPONENT_MATRIX), dtype=torch.float32)
    history = []
    for it in range(iterations):
        opt.zero_grad()
        sim = op.forward(x)
        if opponent:
            loss = torch.mean((torch.einsum("ok,kyx->oyx", to_opponent, sim - t)) ** 2)
        else:
            loss = torch.mean((sim - t) ** 2)
        if float(loss.detach()) < 1e-10:      # already optimal: Adam's normalised steps would only add noise
            history.append(float(loss.detach()))
            break
        loss.backward()
        opt.step()
        with torch.no_grad():
            x.clamp_(0.0, 1.0)
        history.append(float(loss.detach()))
        if progress is not None:
            progress(it + 1, iterations)
    iterations = len(history)
    settings = {"optimizer": "Adam", "learning_rate": learning_rate, "iterations": iterations,
                "loss": "opponent MSE" if opponent else "LMS MSE", "seed": seed}
    return Correction(_hwc(x), iterations, settings, history)


def conventional(problem: Problem, max_iterations: int = 300, tolerance: float = 1e-7,
                 theta: float = 1e-6, tau: float = 2e-5, barrier: float = 65.0,
                 progress: Callable[[int, int], None] | None = None) -> Correction:
    """Montalto et al. (2015) constrained TV deconvolution per RGB primary (no cone model)."""
    H, W = problem.target.shape[:2]

    def rgb_psf_operator(kernel: np.ndarray) -> FftOperator:
        lum = kernel[0] + kernel[1]                               # (primaries, s, s)
        psf = lum / lum.sum(axis=(1, 2), keepdims=True)
        diag = np.zeros((3, 3) + psf.shape[-2:])
        for c in range(3):
            diag[c, c] = psf[c]
        return FftOperator(diag, H, W, dtype=torch.float64)

    op = rgb_psf_operator(problem.kernel.kernel)
    t = _chw(scale_contrast(problem.target, problem.contrast), dtype=torch.float64)
    if problem.reference_kernel is not None:                      # what the eye sees with glasses, per primary
        with torch.no_grad():
            t = rgb_psf_operator(problem.reference_kernel.kernel).forward(t)
    x = t.clone().requires_grad_(True)
    opt = torch.optim.LBFGS([x], lr=1.0, max_iter=20, history_size=10, line_search_fn="strong_wolfe",
                            tolerance_grad=1e-12, tolerance_change=1e-14)

    def energy():
        d = op.forward(x) - t
        data = (d * d).sum()
        dx = x[:, :, 1:] - x[:, :, :-1]
        dy = x[:, 1:, :] - x[:, :-1, :]
        tv = torch.sqrt(dx[:, :-1, :] ** 2 + dy[:, :, :-1] ** 2 + 1e-8).sum()
        box = torch.exp(-barrier * x).sum() + torch.exp(-barrier * (1.0 - x)).sum()
        return data + theta * tv + tau * box

    def closure():
        opt.zero_grad()
        e = energy()
        e.backward()
        return e

    history = []
    rounds = max(1, max_iterations // 20)
    for i in range(rounds):
        e = float(opt.step(closure).detach())
        history.append(e)
        if progress is not None:
            progress(i + 1, rounds)
        if len(history) > 1 and abs(history[-2] - history[-1]) <= tolerance * max(abs(history[-2]), 1e-30):
            break
    iters = opt.state[opt._params[0]].get("n_iter", len(history) * 20)
    settings = {"solver": "L-BFGS (strong Wolfe)", "theta": theta, "tau": tau, "Lambda": barrier,
                "psf": "per primary, luminance (L+M) weighted", "tolerance": tolerance}
    return Correction(_hwc(x), int(iters), settings, history)
