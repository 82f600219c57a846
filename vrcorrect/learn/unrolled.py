"""The unrolled correction (issue 25, begun): ``fast``'s ADMM as a fixed number of stages, each
stage's settings predicted from the eye, with a small learned prior between the data steps (torch).

Why unrolled. A network that sees only the image and four numbers about the eye must learn the
eye's blur from examples, for every display. The unrolled solver takes the blur itself as an
input: its data step is ``fast``'s exact per-frequency solve with the eye's cone x primary kernel
bank (USRNet, Zhang et al. CVPR 2020, does the same for one-channel deblurring with a closed-form
FFT step). One model then serves any kernel the forward model can build, on any display.

One stage is one iteration of :func:`vrcorrect.solvers.admm._admm` (the boundary-aware split
``v = K u`` for the retina, ``z = u`` for the box; two FFT round trips):

* ``u``: ``(K^H K + n I)^-1 (K^H F(v - d1) + n F(z - d2))`` per frequency, by the 3x3 algebra of
  :mod:`vrcorrect.solvers.spectral` (``gram`` and ``inv3`` are written for numpy and run here on
  torch's complex tensors unchanged), with ``n = balance_s ||K||^2``;
* relaxation by ``alpha_s``; ``v`` per pixel inside the image (``rho_s``);
* ``z``: ``u + d2``, plus the prior's residual (``prior(u + d2, target)``), then the box: clipped
  to [0, 1] inside the image, zero outside, at every stage;
* the scaled duals.

The stage settings ``(rho_s, alpha_s, balance_s)`` start at ``fast``'s (0.1, 1.8, 1) and a tiny
MLP adds an eye-dependent correction (its last layer zero at start); the prior's last layer
is zero at start too. So an untrained model *is* its unlearned twin: ``stages`` iterations of
``fast``'s ADMM from the same start, and :func:`twin` (``prior_width=0``) has no prior at all.
Tests check the twin against the numpy ADMM iteration by iteration.

Inputs are batched channel-first: the target's cone image ``t_lms`` and the start ``z0`` as
``(N, 3, H, W)`` float32, the kernel bank's spectrum on the padded grid as ``(N, 3, 3, P0, P1 // 2 + 1)``
complex64 (:func:`kernel_spectra`), ``||K||^2`` per sample ``(N,)`` and the eye's features
``(N, F)`` (:func:`vrcorrect.learn.conditioning.eye_features`, any fixed length).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Sequence

import numpy as np
import torch
from torch import nn

from ..plumbing.errors import ValidationError
from ..solvers.spectral import gram, inv3, kernel_spectrum, padded_shape, spectral_norm_squared

__all__ = ["UnrolledConfig", "UnrolledADMM", "twin", "kernel_spectra", "FAST_RHO", "FAST_RELAXATION"]

#: ``fast``'s settings (:func:`vrcorrect.solvers.admm.fast`): where every stage starts.
FAST_RHO = 0.1
FAST_RELAXATION = 1.8


@dataclass(frozen=True)
class UnrolledConfig:
    """Shape of an :class:`UnrolledADMM`.

    Attributes
    ----------
    stages
        ADMM stages (2 FFT round trips each), 1 to 32.
    prior_width
        Channels of the prior network (0: no prior, the unlearned twin).
    features
        Length of the eye's feature vector the stage MLP reads (0: no MLP, shared settings).
    hidden
        Width of the stage MLP.
    """

    stages: int = 4
    prior_width: int = 16
    features: int = 4
    hidden: int = 32

    def __post_init__(self) -> None:
        for name, lo, hi in (("stages", 1, 32), ("prior_width", 0, 256), ("features", 0, 64), ("hidden", 1, 1024)):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or not lo <= value <= hi:
                raise ValidationError(name, value, f"an integer from {lo} to {hi}")

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class _Prior(nn.Module):
    """A small residual network on ``(u + d2, target, stage)``, 7 channels in, 3 out: a two-level U-Net of
    3x3 convolutions (``width`` then ``2 width`` channels), its last convolution zero at start."""

    def __init__(self, width: int):
        super().__init__()
        w = width
        self.enc = nn.Sequential(nn.Conv2d(7, w, 3, padding=1), nn.ReLU(), nn.Conv2d(w, w, 3, padding=1), nn.ReLU())
        self.down = nn.Sequential(nn.Conv2d(w, 2 * w, 3, stride=2, padding=1), nn.ReLU(),
                                  nn.Conv2d(2 * w, 2 * w, 3, padding=1), nn.ReLU())
        self.up = nn.ConvTranspose2d(2 * w, w, 2, stride=2)
        self.dec = nn.Sequential(nn.Conv2d(2 * w, w, 3, padding=1), nn.ReLU())
        self.out = nn.Conv2d(w, 3, 3, padding=1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, x: torch.Tensor, target: torch.Tensor, stage: torch.Tensor) -> torch.Tensor:
        n, _, h, w = x.shape
        e = self.enc(torch.cat([x, target, stage.expand(n, 1, h, w)], dim=1))
        d = self.down(e)
        u = self.up(d)[..., :h, :w]
        if u.shape[-2:] != (h, w):                              # odd sizes: pad the up-sampled map back
            u = nn.functional.pad(u, (0, w - u.shape[-1], 0, h - u.shape[-2]))
        return self.out(self.dec(torch.cat([e, u], dim=1)))


class UnrolledADMM(nn.Module):
    """``stages`` ADMM stages with eye-dependent settings and a learned prior (module docstring)."""

    def __init__(self, config: UnrolledConfig = UnrolledConfig()):
        super().__init__()
        self.config = config
        S = config.stages
        # per-stage settings in an unconstrained form: log rho, logit(alpha / 2), log balance
        base = torch.tensor([math.log(FAST_RHO), math.log(FAST_RELAXATION / (2 - FAST_RELAXATION)), 0.0],
                            dtype=torch.float32)
        self.stage_base = nn.Parameter(base.repeat(S, 1))                                  # (S, 3)
        if config.features:
            self.mlp = nn.Sequential(nn.Linear(config.features, config.hidden), nn.ReLU(),
                                     nn.Linear(config.hidden, 3 * S))
            nn.init.zeros_(self.mlp[-1].weight)
            nn.init.zeros_(self.mlp[-1].bias)
        else:
            self.mlp = None
        self.prior = _Prior(config.prior_width) if config.prior_width else None

    def stage_settings(self, features: torch.Tensor | None, n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(rho, alpha, balance)``, each ``(N, S)``: the shared settings plus the eye's correction."""
        raw = self.stage_base.unsqueeze(0).expand(n, -1, -1)
        if self.mlp is not None and features is not None:
            raw = raw + self.mlp(features).view(n, self.config.stages, 3)
        rho = torch.exp(raw[..., 0])
        alpha = 2.0 * torch.sigmoid(raw[..., 1])                # over-relaxation stays in (0, 2)
        balance = torch.exp(raw[..., 2])
        return rho, alpha, balance

    def forward(self, t_lms: torch.Tensor, z0: torch.Tensor, spectrum: torch.Tensor, norm2: torch.Tensor,
                features: torch.Tensor | None = None, target: torch.Tensor | None = None,
                history: list[torch.Tensor] | None = None) -> torch.Tensor:
        """The displayed image ``(N, 3, H, W)`` in [0, 1] after the stages.

        ``target``: the target image the prior sees (default ``z0``); ``history``, when given,
        receives each stage's ``z`` (inside the image)."""
        N, _, H, W = t_lms.shape
        P = (spectrum.shape[-2], 2 * (spectrum.shape[-1] - 1))
        if P[0] < H or P[1] < W:
            raise ValidationError("spectrum", tuple(spectrum.shape), f"a grid of at least {H}x{W}")
        if spectrum.shape[-1] != P[1] // 2 + 1:
            raise ValidationError("spectrum", tuple(spectrum.shape), "an rfft2 spectrum (last axis P1 // 2 + 1)")
        # the 3x3 planes first, as solvers.spectral stores them: (3, 3, N, P0, F1) and (3, N, ...)
        Kf = spectrum.permute(1, 2, 0, 3, 4)
        Kh = Kf.conj().transpose(0, 1)
        KhK = gram(Kf)
        rho, alpha, balance = self.stage_settings(features, N)
        inside = torch.zeros((1, N, *P), dtype=t_lms.dtype, device=t_lms.device)
        inside[..., :H, :W] = 1.0
        t_grid = torch.zeros((3, N, *P), dtype=t_lms.dtype, device=t_lms.device)
        t_grid[..., :H, :W] = t_lms.transpose(0, 1)
        z = torch.zeros_like(t_grid)
        z[..., :H, :W] = z0.transpose(0, 1)
        target = z0 if target is None else target
        v = self._apply(Kf, z, P)
        d1 = torch.zeros_like(v)
        d2 = torch.zeros_like(z)
        eye3 = torch.eye(3, dtype=Kf.dtype, device=Kf.device).view(3, 3, 1, 1, 1)
        S = self.config.stages
        for s in range(S):
            n = (balance[:, s] * norm2).to(t_lms.dtype)                                   # (N,)
            G = inv3(KhK + eye3 * n.view(1, 1, N, 1, 1).to(Kf.dtype))
            R = self._mul(Kh, torch.fft.rfft2(v - d1, s=P)) + n.view(1, N, 1, 1) * torch.fft.rfft2(z - d2, s=P)
            U = self._mul(G, R)
            u = torch.fft.irfft2(U, s=P)
            Ku = torch.fft.irfft2(self._mul(Kf, U), s=P)
            a = alpha[:, s].view(1, N, 1, 1)
            Ku = a * Ku + (1 - a) * v
            u = a * u + (1 - a) * z
            rho_eff = (rho[:, s] * n).view(1, N, 1, 1)
            v_new = Ku + d1
            v_new = torch.where(inside > 0, (rho_eff * v_new + 2.0 * t_grid) / (2.0 + rho_eff), v_new)
            z_new = u + d2
            if self.prior is not None:
                stage = torch.full((1, 1, 1, 1), (s + 0.5) / S, dtype=t_lms.dtype, device=t_lms.device)
                inner = z_new[..., :H, :W].transpose(0, 1)
                z_new = z_new.clone()
                z_new[..., :H, :W] = z_new[..., :H, :W] + self.prior(inner, target, stage).transpose(0, 1)
            z_new = torch.clamp(z_new, 0.0, 1.0) * inside
            d1 = d1 + Ku - v_new
            d2 = d2 + u - z_new
            v, z = v_new, z_new
            if history is not None:
                history.append(z[..., :H, :W].transpose(0, 1))
        return z[..., :H, :W].transpose(0, 1).contiguous()

    @staticmethod
    def _mul(M: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """Per-frequency ``M x``: ``(3, 3, N, ...)`` by ``(3, N, ...)``."""
        return torch.einsum("ijn...,jn...->in...", M, x)

    def _apply(self, Kf: torch.Tensor, x: torch.Tensor, P: tuple[int, int]) -> torch.Tensor:
        return torch.fft.irfft2(self._mul(Kf, torch.fft.rfft2(x, s=P)), s=P)


def twin(stages: int) -> UnrolledADMM:
    """The unlearned twin: ``stages`` of ``fast``'s ADMM iterations, no prior, no eye MLP."""
    return UnrolledADMM(UnrolledConfig(stages=stages, prior_width=0, features=0))


def kernel_spectra(kernels: Sequence[np.ndarray], shape: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """The spectra ``(N, 3, 3, P0, P1 // 2 + 1)`` complex64 (computed in float64) of ``(3, 3, s, s)``
    kernels on one grid for ``shape`` images (:func:`~vrcorrect.solvers.spectral.padded_shape` of
    the largest kernel), and ``||K||^2`` of each ``(N,)`` float32."""
    H, W = shape
    size = max(k.shape[-1] for k in kernels)
    grid = padded_shape(H, W, size)
    spectra = np.stack([kernel_spectrum(np.asarray(k, np.float64), grid) for k in kernels]).astype(np.complex64)
    norms = np.array([spectral_norm_squared(np.asarray(k, np.float64)) for k in kernels], np.float32)
    return torch.from_numpy(spectra), torch.from_numpy(norms)


def describe(model: UnrolledADMM) -> dict[str, Any]:
    """The configuration and parameter count, JSON-ready."""
    return {**model.config.as_dict(), "parameters": sum(p.numel() for p in model.parameters())}
