"""Iterative correction methods (torch, CPU or GPU; float32 images).

* ``fast``: box-constrained least squares solved properly - ADMM with a
  boundary-aware split (exact per-frequency 3x3 solves, the penalty scaled by
  the kernel's spectral norm), warm-started from
  :func:`vrcorrect.solvers.wiener.wiener`, stopping on a relative tolerance.
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

import math
from typing import Callable

import numpy as np
import torch

from . import Problem


class FftOperator:
    """``y_k = sum_c K[k, c] * x_c`` (linear convolution, zero outside, same size) and its adjoint."""

    def __init__(self, kernel: np.ndarray, height: int, width: int, dtype=torch.float32, device="cpu"):
        s = kernel.shape[-1]
        self.r = s // 2
        self.H, self.W = height, width
        from .wiener import padded_shape

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


def _admm(kernel: np.ndarray, t_lms: torch.Tensor, z0: torch.Tensor, rho: float, relaxation: float,
          balance: float, max_iterations: int, tolerance: float,
          progress: Callable[[int, int], None] | None = None,
          duals: tuple[torch.Tensor, torch.Tensor] | None = None
          ) -> tuple[torch.Tensor, int, list[float], float, tuple[torch.Tensor, torch.Tensor]]:
    """The ADMM iterations of :func:`fast` on (3, H, W) tensors, optionally warm-started in the
    scaled duals too (inside the image; zero outside); returns (z, iterations, history, norm2,
    duals) with the duals cropped to the image."""
    from .wiener import apply3, centred_kernel, gram, inv3, matmul3, padded_shape, spectral_norm_squared

    H, W = t_lms.shape[1:]
    P = padded_shape(H, W, kernel.shape[-1])
    Kf = torch.fft.rfft2(torch.as_tensor(centred_kernel(kernel, P), dtype=torch.float32))  # (cones, primaries, P0, F1)
    M = gram(Kf)                                                     # planes (primaries, primaries, P0, F1)
    norm2 = spectral_norm_squared(kernel) * balance          # box split weighed against the retina split
    for c in range(3):
        M[c, c] += norm2
    G = inv3(M)
    GKh = matmul3(G, Kf.conj().transpose(0, 1))                     # (primaries, cones, P0, F1)
    Gn = G * norm2
    mask = torch.zeros(P, dtype=torch.bool)
    mask[:H, :W] = True
    t = torch.zeros((3,) + P)
    t[:, :H, :W] = t_lms
    z = torch.zeros((3,) + P)
    z[:, :H, :W] = z0
    Ku = torch.fft.irfft2(apply3(Kf, torch.fft.rfft2(z)), s=P)
    v = Ku.clone()
    d1 = torch.zeros_like(v)
    d2 = torch.zeros_like(z)
    if duals is not None:
        d1[:, :H, :W] = duals[0]
        d2[:, :H, :W] = duals[1]
    n = float(H * W * 3)
    rho_eff = rho * norm2
    history: list[float] = []
    iterations = 0
    for it in range(1, max_iterations + 1):
        A = torch.fft.rfft2(v - d1)
        B = torch.fft.rfft2(z - d2)
        U = apply3(GKh, A) + apply3(Gn, B)
        u = torch.fft.irfft2(U, s=P)
        Ku = torch.fft.irfft2(apply3(Kf, U), s=P)
        if relaxation != 1.0:                                      # over-relaxation (Eckstein & Bertsekas)
            Ku = relaxation * Ku + (1.0 - relaxation) * v
            u = relaxation * u + (1.0 - relaxation) * z
        sv = Ku + d1
        v = torch.where(mask, (2.0 * t + rho_eff * sv) / (2.0 + rho_eff), sv)
        z = (u + d2).clamp(0.0, 1.0) * mask
        d1 += Ku - v
        d2 += u - z
        iterations = it
        if progress is not None:
            progress(it, max_iterations)
        if it % 2 == 0 or it == max_iterations:         # the true objective at the feasible z, every 2nd step
            Kz = torch.fft.irfft2(apply3(Kf, torch.fft.rfft2(z)), s=P)[:, :H, :W]
            obj = float(((Kz - t_lms) ** 2).sum()) / n
            previous = history[-1] if history else None
            history.append(obj)
            if previous is not None and (previous - obj) <= tolerance * previous:
                break
    return z[:, :H, :W], iterations, history, norm2, (d1[:, :H, :W], d2[:, :H, :W])


def coarse_kernel(kernel: np.ndarray) -> np.ndarray:
    """The kernel seen by an image of half the resolution (2x2 pixel blocks): the kernel
    convolved with the two box pixels ([1,2,1]/4 per axis) and sampled every second pixel
    about its centre; sums kept equal to the fine kernel's."""
    tri = np.array([0.25, 0.5, 0.25])
    k = kernel
    k = np.apply_along_axis(lambda v: np.convolve(v, tri), -1, k)
    k = np.apply_along_axis(lambda v: np.convolve(v, tri), -2, k)
    c = k.shape[-1] // 2
    half = c // 2
    idx = c + 2 * np.arange(-half, half + 1)
    out = k[..., idx[:, None], idx[None, :]]
    sums = out.sum(axis=(-2, -1), keepdims=True)
    return out * np.where(sums > 0, kernel.sum(axis=(-2, -1), keepdims=True) / np.where(sums > 0, sums, 1), 0)


def _pool2(a: torch.Tensor) -> torch.Tensor:
    H2, W2 = a.shape[1] // 2 * 2, a.shape[2] // 2 * 2
    return torch.nn.functional.avg_pool2d(a[None, :, :H2, :W2], 2)[0]


def _coarse_to_fine(problem: Problem, kernel: np.ndarray, target: torch.Tensor, t_lms: torch.Tensor,
                    levels: int, coarse_iterations: int, level_iterations: int, rho: float, relaxation: float,
                    balance: float, warm_start: bool
                    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor] | None, list[str]]:
    """Starting point at this resolution, primal and dual: wiener's closed form on the coarsest
    level, refined by ADMM there and on each finer level; the image and ADMM's scaled duals are
    upsampled bilinearly (the duals carry which pixels press on the box and how the retina's
    residual stands, so the finer level does not start its duals from zero)."""
    import dataclasses

    from .wiener import wiener

    H, W = t_lms.shape[1:]
    if levels > 0 and min(H, W) >= 64 and kernel.shape[-1] >= 9:
        Kc = coarse_kernel(kernel)
        zc, dc, notes = _coarse_to_fine(problem, Kc, _pool2(target), _pool2(t_lms), levels - 1, coarse_iterations,
                                    level_iterations, rho, relaxation, balance, warm_start)
        deeper = bool(notes) and notes[-1] != "wiener" and notes[-1] != "target"
        its = level_iterations if deeper else coarse_iterations
        zc, done, _, _, dc = _admm(Kc, _pool2(t_lms), zc, rho, relaxation, balance, its, 0.0, duals=dc)
        notes.append(f"{done} ADMM iterations at {zc.shape[2]}x{zc.shape[1]}")
        H2, W2 = H // 2 * 2, W // 2 * 2

        def up(a: torch.Tensor, fill: torch.Tensor) -> torch.Tensor:
            out = fill.clone()
            out[:, :H2, :W2] = torch.nn.functional.interpolate(a[None], size=(H2, W2), mode="bilinear",
                                                               align_corners=False)[0]
            return out

        zero = torch.zeros_like(target)
        return up(zc, target).clamp(0.0, 1.0), (up(dc[0], zero), up(dc[1], zero)), notes
    if not warm_start:
        return target.clone(), None, ["target"]
    sub = Problem(target=_hwc(target), kernel=dataclasses.replace(problem.kernel, kernel=kernel),
                  target_lms=_hwc(t_lms))
    x0, _ = wiener(sub, regularisation=(0.03,), design=False)
    return _chw(x0), None, ["wiener"]


def fast(problem: Problem, tolerance: float = 1e-2, max_iterations: int = 200, rho: float = 0.1,
         relaxation: float = 1.8, balance: float = 1.0, levels: int = 1, coarse_iterations: int = 15,
         level_iterations: int = 3, warm_start: bool = True,
         progress: Callable[[int, int], None] | None = None) -> tuple[np.ndarray, int, dict, list[float]]:
    """ADMM for ``min ||C K x - t||^2`` subject to ``0 <= x <= 1`` inside the image, ``x = 0`` outside.

    Split (Almeida & Figueiredo 2013, boundary-aware deconvolution): on a padded
    periodic domain, ``v = K u`` (the retina, cropped by ``C`` only in the data
    term) and ``z = u`` (the box and the black surround).  Each step is exact
    and cheap: ``u`` by one 3x3 solve per frequency, ``(K^H K + n I)^-1`` with
    ``n = ||K||^2`` the kernel's spectral norm squared (at DC, since K >= 0),
    ``v`` per pixel, ``z`` by clipping; over-relaxed.

    Warm start, coarse to fine: the closed-form ``wiener`` solution on the
    coarsest of ``levels`` halvings (2x2 blocks, with the kernel those blocks
    see: :func:`coarse_kernel`), ``coarse_iterations`` of ADMM there,
    ``level_iterations`` on each finer level, each upsampled bilinearly, the
    image and ADMM's scaled duals both (with zero duals the finer level first
    loses ground; with the coarse duals its first iteration is already below
    what the paper's 100 Adam steps reach, on the evaluation images).
    Images too small for a level start from ``wiener`` directly.  Stops when two
    iterations improve the objective by less than ``tolerance`` (relative).
    """
    K = problem.kernel.kernel
    t = _chw(problem.target_lms)
    z0, duals, notes = _coarse_to_fine(problem, K, _chw(problem.target), t, levels, coarse_iterations, level_iterations,
                                rho, relaxation, balance, warm_start)
    z, iterations, history, norm2, _ = _admm(K, t, z0, rho, relaxation, balance, max_iterations, tolerance,
                                             progress, duals)
    settings = {"solver": "ADMM (boundary-aware split), over-relaxed", "rho": rho, "relaxation": relaxation,
                "spectral_norm_squared": norm2, "tolerance": tolerance,
                "warm_start": ", then ".join(notes)}
    return _hwc(z), iterations, settings, history


def paper(problem: Problem, iterations: int = 100, learning_rate: float = 0.01, opponent: bool = False,
          seed: int = 0, progress: Callable[[int, int], None] | None = None
          ) -> tuple[np.ndarray, int, dict, list[float]]:
    """ChromaCorrect's published optimisation: Adam from the target, clamped, LMS (or opponent) MSE."""
    from ..perception import OPPONENT_MATRIX

    torch.manual_seed(seed)
    H, W = problem.target.shape[:2]
    op = FftOperator(problem.kernel.kernel, H, W)
    t = _chw(problem.target_lms)
    x = _chw(problem.target).clone().requires_grad_(True)
    opt = torch.optim.Adam([x], lr=learning_rate)
    O = torch.tensor(np.array(OPPONENT_MATRIX), dtype=torch.float32)
    history = []
    for it in range(iterations):
        opt.zero_grad()
        sim = op.forward(x)
        if opponent:
            loss = torch.mean((torch.einsum("ok,kyx->oyx", O, sim - t)) ** 2)
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
    return _hwc(x), iterations, settings, history


def conventional(problem: Problem, max_iterations: int = 300, tolerance: float = 1e-7,
                 theta: float = 1e-6, tau: float = 2e-5, barrier: float = 65.0,
                 progress: Callable[[int, int], None] | None = None) -> tuple[np.ndarray, int, dict, list[float]]:
    """Montalto et al. (2015) constrained TV deconvolution per RGB primary (no cone model)."""
    from . import scale_contrast

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
    return _hwc(x), int(iters), settings, history
