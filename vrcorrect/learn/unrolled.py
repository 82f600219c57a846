"""The unrolled correction: ``fast``'s ADMM as a fixed number of stages, each
stage's settings predicted from the eye, with a small learned prior between the data steps (torch).

Why unrolled. A network that sees only the image and four numbers about the eye must learn the
eye's blur from examples, for every display. The unrolled solver takes the blur itself as an
input: its data step is ``fast``'s exact per-frequency solve with the eye's cone x primary kernel
bank (USRNet, Zhang et al. CVPR 2020, does the same for one-channel deblurring with a closed-form
FFT step). One model then serves any kernel the forward model can build, on any display.

One stage is one iteration of :func:`vrcorrect.solvers.admm._admm` (the boundary-aware split
``v = K u`` for the retina, ``z = u`` for the box; two FFT round trips):

* ``u``: ``(K^H K + n_s I)^-1 (K^H F(v - d1) + n_s F(z - d2))`` per frequency, with the stage's own
  box weight ``n_s = beta_s ||K||^2``: solved by Cayley-Hamilton (:meth:`UnrolledADMM._solve`: the
  adjugate and the determinant's coefficients of the Hermitian ``K^H K`` made once a pass, by
  cofactors as ``fast``'s :func:`~vrcorrect.solvers.spectral.hermitian_inverse`), from the Gram matrix ``K^H K``
  made once per eye in float64 (:func:`~vrcorrect.learn.conditioning.unrolled_spectra`) and given
  to the model as an input, like the spectrum; all 3x3 arithmetic real, on (real, imaginary) pairs,
  so that only the FFTs are complex and the graph exports to ONNX;
* relaxation by ``alpha_s``; ``v`` per pixel inside the image (penalty ``rho_s ||K||^2``);
* ``z``: ``u + d2``, plus the prior's residual (``prior(u + d2, target)``), then the box: clipped
  to [0, 1] inside the image (or to [0, the light cap] for a robust design, the ``upper`` input),
  zero outside, at every stage;
* the scaled duals.

The stage settings ``(rho_s, alpha_s, beta_s)`` start at ``fast``'s (0.1, 1.8, 1) and a tiny MLP
adds an eye-dependent correction (its last layer zero at start); the prior's last layer is zero at
start too. So an untrained model *is* its unlearned twin: ``stages`` iterations of
``fast``'s ADMM from the same start, and :func:`twin` (``prior_width=0``) has no prior at all.
Tests check the twin against the numpy ADMM iteration by iteration.

Where it starts. The stages continue from where ``fast``'s own full-resolution iterations start
(:func:`vrcorrect.solvers.admm.fast_start`): the half-resolution level's solution and its scaled
duals, upsampled, where that level pays. From there 8 plain stages reach 72–124 % of ``fast``'s JOD
gain on held-out photographs, where 8 stages from the target reach 25–87 % (docs/learned.md); the
learned part's job is the rest. From the target with zero duals the stages are a cold start.

Inputs are batched channel-first: the target's cone image ``t_lms``, the start ``z0`` and its duals
``d1``, ``d2`` as ``(N, 3, H, W)`` float32, the kernel bank's spectrum and its Gram matrix ``K^H K``
on the padded grid as ``(N, 3, 3, P0, P1 // 2 + 1, 2)`` float32 pairs (:func:`kernel_spectra`),
``||K||^2`` per sample ``(N,)`` and the eye's features ``(N, F)`` (any fixed length).

Why the box weight is learned. ``fast`` weighs the box split with ``||K||^2``; fitted to a held-out
case's own objective the weight falls to 0.01-0.15 of that, and a constant 0.1-0.3 closes what the
16-stage twin leaves open (docs/learned.md). ``UnrolledConfig.box_weight`` sets the starting value
(1: ``fast``'s, the twin), so that a twin at a hand-set constant can be measured beside the model.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Sequence

import numpy as np
import torch
from torch import nn

from ..plumbing.errors import ValidationError
from ..solvers.admm import FAST_RELAXATION, FAST_RHO
from .conditioning import unrolled_spectra

__all__ = ["UnrolledConfig", "UnrolledADMM", "twin", "kernel_spectra", "FAST_RHO", "FAST_RELAXATION"]


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
    box_weight
        The box split's weight at start, as a fraction of ``||K||^2`` (1: ``fast``'s), from
        ``BOX_WEIGHT_RANGE``; training moves it per stage and per eye within that range, above ``box_floor``.
    box_floor
        The least box weight a stage may learn, from ``BOX_WEIGHT_RANGE``'s floor to 1: the data step
        then amplifies what the kernel all but removes by at most ``1 / box_floor``.
    """

    stages: int = 4
    prior_width: int = 16
    features: int = 4
    hidden: int = 32
    box_weight: float = 1.0
    box_floor: float = 1e-3

    def __post_init__(self) -> None:
        for name, lo, hi in (("stages", 1, 32), ("prior_width", 0, 256), ("features", 0, 64), ("hidden", 1, 1024)):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or not lo <= value <= hi:
                raise ValidationError(name, value, f"an integer from {lo} to {hi}")
        lo, hi = BOX_WEIGHT_RANGE
        f = self.box_floor
        if isinstance(f, bool) or not isinstance(f, (int, float)) or not lo <= f <= 1.0:
            raise ValidationError("box_floor", f, f"a number from {lo:g} to 1 (a fraction of ||K||^2)")
        b = self.box_weight
        if isinstance(b, bool) or not isinstance(b, (int, float)) or not f <= b <= hi:
            raise ValidationError("box_weight", b, f"a number from box_floor ({f:g}) to {hi:g} (a fraction of ||K||^2)")

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


#: The box weights a stage may use, as fractions of ``||K||^2``: below 1e-3 the data step's inverse
#: amplifies what the kernel all but removes by more than 1000x, and above 10 the box split stalls.
BOX_WEIGHT_RANGE = (1e-3, 10.0)


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
        # per-stage settings in an unconstrained form: log rho, logit(alpha / 2), log beta
        base = torch.tensor([math.log(FAST_RHO), math.log(FAST_RELAXATION / (2 - FAST_RELAXATION)),
                             math.log(config.box_weight)], dtype=torch.float32)
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
        """``(rho, alpha, beta)``, each ``(N, S)``: the shared settings plus the eye's correction;
        ``beta`` (the box weight over ``||K||^2``) held between ``config.box_floor`` and ``BOX_WEIGHT_RANGE``'s top."""
        raw = self.stage_base.unsqueeze(0).expand(n, -1, -1)
        if self.mlp is not None and features is not None:
            raw = raw + self.mlp(features).view(n, self.config.stages, 3)
        beta = torch.exp(torch.clamp(raw[..., 2], math.log(self.config.box_floor), math.log(BOX_WEIGHT_RANGE[1])))
        return torch.exp(raw[..., 0]), 2.0 * torch.sigmoid(raw[..., 1]), beta   # over-relaxation in (0, 2)

    def forward(self, t_lms: torch.Tensor, z0: torch.Tensor, spectrum: torch.Tensor, gram: torch.Tensor,
                norm2: torch.Tensor, features: torch.Tensor | None = None, target: torch.Tensor | None = None,
                d1: torch.Tensor | None = None, d2: torch.Tensor | None = None,
                upper: torch.Tensor | None = None, history: list[torch.Tensor] | None = None) -> torch.Tensor:
        """The displayed image ``(N, 3, H, W)`` in [0, 1] after the stages.

        ``spectrum`` and ``gram`` (:func:`kernel_spectra`): ``K`` and ``K^H K`` per frequency,
        ``(N, 3, 3, P0, P1 // 2 + 1, 2)`` float32 (real and imaginary parts last); ``norm2`` ``(N,)``. ``target``: the image the prior sees (default ``z0``). ``d1``, ``d2``:
        the scaled duals to start from, ``(N, 3, H, W)`` inside the image (zero outside; default
        zero), as :func:`vrcorrect.solvers.admm.fast_start` gives them with ``z0``. ``upper``: the box's
        top per pixel ``(N, 3, H, W)`` (default 1: the box [0, 1]); the light cap
        (:func:`vrcorrect.solvers.problem.light_cap`) of a robust design holds at every stage, as in
        ``fast``. ``history``, when given, receives each stage's ``z``."""
        N, _, H, W = t_lms.shape
        P = (spectrum.shape[-3], 2 * (spectrum.shape[-2] - 1))
        if spectrum.shape[-1] != 2 or gram.shape != spectrum.shape:
            raise ValidationError("spectrum", tuple(spectrum.shape), "(N, 3, 3, P0, P1 // 2 + 1, 2), as the Gram matrix")
        if P[0] < H or P[1] < W:
            raise ValidationError("spectrum", tuple(spectrum.shape), f"a grid of at least {H}x{W}")
        Kh = torch.stack([spectrum[..., 0].transpose(1, 2), -spectrum[..., 1].transpose(1, 2)], dim=-1)
        rho, alpha, beta = self.stage_settings(features, N)
        prepared = self._prepare(gram)
        pad = (0, P[1] - W, 0, P[0] - H)
        inside = nn.functional.pad(torch.ones_like(t_lms[:, :1]), pad)                  # (N, 1, P0, P1)
        t_grid = nn.functional.pad(t_lms, pad)
        z = nn.functional.pad(z0, pad)
        target = z0 if target is None else target
        v = self._irfft(self._mul(spectrum, self._rfft(z, P)), P)
        d1 = torch.zeros_like(v) if d1 is None else nn.functional.pad(d1, pad)
        d2 = torch.zeros_like(z) if d2 is None else nn.functional.pad(d2, pad)
        n = norm2.view(N, 1, 1, 1).to(t_lms.dtype)
        top = None if upper is None else nn.functional.pad(upper, pad, value=1.0)
        S = self.config.stages
        for s in range(S):
            nb = beta[:, s].view(N, 1, 1, 1) * n                                       # the box weight
            R = self._mul(Kh, self._rfft(v - d1, P)) + nb.unsqueeze(-1) * self._rfft(z - d2, P)
            U = self._solve(prepared, nb, R)
            u = self._irfft(U, P)
            Ku = self._irfft(self._mul(spectrum, U), P)
            a = alpha[:, s].view(N, 1, 1, 1)
            Ku = a * Ku + (1 - a) * v
            u = a * u + (1 - a) * z
            rho_eff = rho[:, s].view(N, 1, 1, 1) * n
            v_new = Ku + d1
            v_new = inside * (rho_eff * v_new + 2.0 * t_grid) / (2.0 + rho_eff) + (1 - inside) * v_new
            z_new = u + d2
            if self.prior is not None:
                stage = torch.full((1, 1, 1, 1), (s + 0.5) / S, dtype=t_lms.dtype, device=t_lms.device)
                z_new = z_new + nn.functional.pad(self.prior(z_new[..., :H, :W], target, stage), pad)
            z_new = torch.clamp(z_new, 0.0, 1.0) if top is None else torch.minimum(torch.clamp(z_new, min=0.0), top)
            z_new = z_new * inside
            d1 = d1 + Ku - v_new
            d2 = d2 + u - z_new
            v, z = v_new, z_new
            if history is not None:
                history.append(z[..., :H, :W])
        return z[..., :H, :W]

    @staticmethod
    def _prepare(gram: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """What every stage's solve needs from the Hermitian Gram matrix ``G`` ``(N, 3, 3, ..., 2)``,
        made once a pass: ``G``, its adjugate (by cofactors, on (real, imaginary) pairs) and the
        coefficients of ``det(G + n I) = n^3 + c2 n^2 + c1 n + c0``."""
        def mul(x, y):
            return torch.stack([x[..., 0] * y[..., 0] - x[..., 1] * y[..., 1],
                                x[..., 0] * y[..., 1] + x[..., 1] * y[..., 0]], dim=-1)

        def conj(x):
            return torch.stack([x[..., 0], -x[..., 1]], dim=-1)

        a, b, c = (gram[:, i, i, ..., 0] for i in range(3))                  # the real diagonal
        p, q, r = gram[:, 0, 1], gram[:, 0, 2], gram[:, 1, 2]                # the upper off-diagonal
        c00 = b * c - (r * r).sum(-1)
        c11 = a * c - (q * q).sum(-1)
        c22 = a * b - (p * p).sum(-1)
        a01 = mul(q, conj(r)) - c.unsqueeze(-1) * p                          # adjugate, upper part
        a02 = mul(p, r) - b.unsqueeze(-1) * q
        a12 = mul(q, conj(p)) - a.unsqueeze(-1) * r
        det = a * c00 + (p * a01).sum(-1) + (q * a02).sum(-1)                # first row x cofactors (real)
        d = lambda v: torch.stack([v, torch.zeros_like(v)], dim=-1)          # noqa: E731  (a real entry)
        adj = torch.stack([torch.stack([d(c00), a01, a02], dim=1),
                           torch.stack([conj(a01), d(c11), a12], dim=1),
                           torch.stack([conj(a02), conj(a12), d(c22)], dim=1)], dim=1)
        return gram, adj, a + b + c, c00 + c11 + c22, det

    @classmethod
    def _solve(cls, prepared: tuple[torch.Tensor, ...], n: torch.Tensor, R: torch.Tensor) -> torch.Tensor:
        """``(G + n I)^-1 R`` per frequency (``prepared``: :meth:`_prepare` of ``G``; ``n`` ``(N, 1, 1,
        1)``, ``R`` ``(N, 3, ..., 2)``). By Cayley-Hamilton, ``adj(G + n I) = n^2 I + n (tr G I - G) +
        adj G`` and ``det(G + n I) = n^3 + c2 n^2 + c1 n + c0``: two 3x3 products a stage, whatever ``n``."""
        G, adj, c2, c1, c0 = prepared
        n1 = n[:, 0]
        det = ((n1 + c2) * n1 + c1) * n1 + c0                               # (N, ...)
        num = (n1 * (n1 + c2)).unsqueeze(1).unsqueeze(-1) * R - n1.unsqueeze(1).unsqueeze(-1) * cls._mul(G, R) \
            + cls._mul(adj, R)
        return num / det.unsqueeze(1).unsqueeze(-1)

    @staticmethod
    def _rfft(x: torch.Tensor, P: tuple[int, int]) -> torch.Tensor:
        """``(N, 3, P0, P1)`` real planes -> ``(N, 3, P0, P1 // 2 + 1, 2)`` spectra (real, imaginary)."""
        return torch.view_as_real(torch.fft.rfft2(x, s=P))

    @staticmethod
    def _irfft(X: torch.Tensor, P: tuple[int, int]) -> torch.Tensor:
        return torch.fft.irfft2(torch.view_as_complex(X.contiguous()), s=P)

    @staticmethod
    def _mul(M: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """Per-frequency complex ``M x`` on (real, imaginary) pairs: ``M`` ``(N, 3, 3, ..., 2)``, ``x``
        ``(N, 3, ..., 2)`` -> ``(N, 3, ..., 2)`` (real arithmetic: exportable to ONNX)."""
        mr, mi = M[..., 0], M[..., 1]
        xr, xi = x[..., 0].unsqueeze(1), x[..., 1].unsqueeze(1)
        return torch.stack([(mr * xr - mi * xi).sum(2), (mr * xi + mi * xr).sum(2)], dim=-1)


def twin(stages: int, box_weight: float = 1.0) -> UnrolledADMM:
    """The unlearned twin: ``stages`` of ``fast``'s ADMM iterations, no prior, no eye MLP
    (``box_weight``: the box split's weight over ``||K||^2``, ``fast``'s 1 by default)."""
    return UnrolledADMM(UnrolledConfig(stages=stages, prior_width=0, features=0, box_weight=box_weight))


def kernel_spectra(kernels: Sequence[np.ndarray], shape: tuple[int, int], power_of_two: bool = True
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`~vrcorrect.learn.conditioning.unrolled_spectra` of each kernel on one grid (that of the
    largest; ``power_of_two``: a power-of-two grid, else ``fast``'s), batched: ``spectrum`` and
    ``gram`` ``(N, 3, 3, P0, P1 // 2 + 1, 2)`` float32 and ``||K||^2`` ``(N,)`` float32."""
    size = max(k.shape[-1] for k in kernels)
    made = [unrolled_spectra(k, shape, size, power_of_two) for k in kernels]
    return (torch.from_numpy(np.stack([m[0] for m in made])), torch.from_numpy(np.stack([m[1] for m in made])),
            torch.tensor([m[2] for m in made], dtype=torch.float32))


def describe(model: UnrolledADMM) -> dict[str, Any]:
    """The configuration and parameter count, JSON-ready."""
    return {**model.config.as_dict(), "parameters": sum(p.numel() for p in model.parameters())}
