"""The conditioned U-Net: one model for every eye in its training range (torch).

Architecture (as in ChromaCorrect): a U-Net whose contracting path is ``depth`` steps of
a double convolution (3x3 conv, batch norm, ReLU, twice) followed by 2x2 max-pooling, a
double convolution at the bottom, and an expanding path of bilinear up-sampling (to the
skip's exact size, so any H and W work), concatenation with the skip, and a double
convolution; channels ``width * 2**level``.

Conditioning on the eye (our addition: the paper trains one network per prescription):

1. **Pre-correction channels.**  Besides the target image (3 channels, linear RGB), the
   network sees a few accelerated projected-gradient steps on the eye's own objective from
   it (:func:`vrcorrect.learn.conditioning.precorrect`; older models: the ``wiener``
   inverse, clipped).  That puts the eye's blur - its size, orientation and chromatic
   structure, which a few scalars describe poorly at the pixel level - into the input in
   the image's own coordinates, where convolutions handle it; the network's job becomes
   finishing an optimisation that is already under way, which is local.  It is numpy
   (FFT) and is computed by the data pipeline and, at run time, by
   :mod:`vrcorrect.runtime.learned` without torch.
2. **FiLM.**  A small MLP maps the eye's features (:func:`~vrcorrect.learn.conditioning.eye_features`:
   power vector M, J0, J45 and pupil, scaled) to a per-channel scale and shift
   ``y <- y (1 + gamma) + beta`` after the second batch norm of every double convolution,
   so the same weights can behave differently for myopia and hyperopia (whose
   pre-corrections look alike) and for small and large pupils.

3. **Gradient step (optional, ``gradient_input``).**  The projected-gradient step the eye's
   objective would take next from the pre-correction, ``K^H (K x - t) / ||K||^2``: one more
   pair of FFT convolutions at run time.  The fixed step ``1 / ||K||^2`` is tiny for the
   high frequencies the eye attenuates most (that is why a few FISTA steps leave most of the
   gap); a network that sees the direction can take a larger, local, nonlinear step along
   it - a learned preconditioner, as in learned gradient schemes.

Output: ``clip(base + head(features), 0, 1)`` with the head's 1x1 convolution and the FiLM
MLP's last layer initialised to zero, so an untrained model returns ``base`` exactly: by
default (``base="precorrected"``) the pre-correction channels, so training starts from the
projected-gradient steps' objective (already below ``wiener``'s on the data set's eyes) and
the network learns what those few steps miss; ``base="image"`` starts from no correction.

Default size (``width=16, depth=3``: 16-32-64-128 channels, about 0.5 M parameters, 2 MB in
float32) is chosen for real time; ``width=8`` is a quarter of the cost.

The exported graph (``tools/export_onnx.py``) has three inputs - ``image`` and
``precorrected`` float32 ``(N, 3, H, W)`` and ``eye`` float32 ``(N, 4)`` - and one output
``(N, 3, H, W)``: see :mod:`vrcorrect.runtime.learned` for why and how the runtime feeds it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import torch
from torch import nn
from torch.nn import functional as F

from ..plumbing.errors import ValidationError
from .conditioning import N_FEATURES

#: Factor on the gradient input inside the network: the step ``K^H (K x - t) / ||K||^2`` has an
#: RMS of about 0.02 on the default data set, some ten times less than the image channels
#: (and than the change ``fast`` makes to the pre-correction), so the first convolution's weights
#: on it would otherwise have to grow ten times larger before they matter.
GRADIENT_SCALE = 10.0
#: What the output may be added to.
BASES = ("precorrected", "image")


@dataclass(frozen=True)
class UNetConfig:
    """Size of the U-Net.

    Attributes
    ----------
    width
        Channels at full resolution (1 to 256); level ``l`` has ``width * 2**l``.
    depth
        Number of max-pool down-samplings (1 to 6).
    film_hidden
        Hidden units of the FiLM MLP (0: no FiLM, pre-correction channels only).
    base
        What the network's output is added to: ``"precorrected"`` (default) or ``"image"``.
    gradient_input
        Also feed the network the projected-gradient step at the pre-correction (3 more
        channels, :func:`vrcorrect.solvers.fista.gradient_step`): where the eye's objective
        still pulls, which the network can turn into a better step than ``1 / ||K||^2``.
    """

    width: int = 16
    depth: int = 3
    film_hidden: int = 32
    base: str = "precorrected"
    gradient_input: bool = False

    def __post_init__(self) -> None:
        for name, lo, hi in (("width", 1, 256), ("depth", 1, 6), ("film_hidden", 0, 4096)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ValidationError(name, v, f"an integer from {lo} to {hi}")
        if self.base not in BASES:
            raise ValidationError("base", self.base, " or ".join(BASES))
        if not isinstance(self.gradient_input, bool):
            raise ValidationError("gradient_input", self.gradient_input, "true or false")

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @property
    def input_names(self) -> tuple[str, ...]:
        """The network's (and the exported graph's) inputs, in order."""
        return ("image", "precorrected", "eye") + (("gradient",) if self.gradient_input else ())

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> "UNetConfig":
        """Inverse of :meth:`as_dict`; a checkpoint from before ``base`` existed added to the image."""
        d = {k: v for k, v in doc.items() if k in cls.__dataclass_fields__}
        d.setdefault("base", "image")
        return cls(**d)


class _DoubleConv(nn.Module):
    def __init__(self, c_in: int, c_out: int):
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_out, 3, padding=1, bias=False)
        self.bn1 = nn.BatchNorm2d(c_out)
        self.conv2 = nn.Conv2d(c_out, c_out, 3, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(c_out)
        self.channels = c_out

    def forward(self, x: torch.Tensor, film: torch.Tensor | None) -> torch.Tensor:
        x = F.relu(self.bn1(self.conv1(x)))
        x = self.bn2(self.conv2(x))
        if film is not None:                                     # (N, 2C): gamma, beta
            gamma, beta = film[:, :self.channels, None, None], film[:, self.channels:, None, None]
            x = x * (1.0 + gamma) + beta
        return F.relu(x)


class ConditionedUNet(nn.Module):
    """``forward(image, precorrected, eye[, gradient]) -> displayed``, all ``(N, 3, H, W)`` but ``eye (N, 4)``."""

    def __init__(self, config: UNetConfig | None = None):
        super().__init__()
        self.config = config or UNetConfig()
        w, d = self.config.width, self.config.depth
        chans = [w * 2 ** level for level in range(d + 1)]
        c_in = 9 if self.config.gradient_input else 6
        self.down = nn.ModuleList([_DoubleConv(c_in if i == 0 else chans[i - 1], chans[i]) for i in range(d)])
        self.bottom = _DoubleConv(chans[d - 1], chans[d])
        self.up = nn.ModuleList([_DoubleConv(chans[i + 1] + chans[i], chans[i]) for i in reversed(range(d))])
        self.head = nn.Conv2d(chans[0], 3, 1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)
        blocks = list(self.down) + [self.bottom] + list(self.up)
        self._film_sizes = [2 * b.channels for b in blocks]
        if self.config.film_hidden > 0:
            last = nn.Linear(self.config.film_hidden, sum(self._film_sizes))
            nn.init.zeros_(last.weight)
            nn.init.zeros_(last.bias)
            self.film = nn.Sequential(nn.Linear(N_FEATURES, self.config.film_hidden), nn.ReLU(), last)
        else:
            self.film = None

    @property
    def input_names(self) -> tuple[str, ...]:
        """The forward's (and the exported graph's) inputs, in order (:attr:`UNetConfig.input_names`)."""
        return self.config.input_names

    def forward(self, image: torch.Tensor, precorrected: torch.Tensor, eye: torch.Tensor,
                gradient: torch.Tensor | None = None) -> torch.Tensor:
        films: list[torch.Tensor | None]
        if self.film is not None:
            films = list(torch.split(self.film(eye), self._film_sizes, dim=1))
        else:
            films = [None] * (2 * len(self.down) + 1)
        if self.config.gradient_input:
            if gradient is None:
                raise ValueError("this model takes the gradient step as its fourth input")
            x = torch.cat([image, precorrected, gradient * GRADIENT_SCALE], dim=1)
        else:
            x = torch.cat([image, precorrected], dim=1)
        skips = []
        k = 0
        for block in self.down:
            x = block(x, films[k])
            k += 1
            skips.append(x)
            x = F.max_pool2d(x, 2)
        x = self.bottom(x, films[k])
        k += 1
        for block in self.up:
            skip = skips.pop()
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = block(torch.cat([x, skip], dim=1), films[k])
            k += 1
        base = precorrected if self.config.base == "precorrected" else image
        return torch.clamp(base + self.head(x), 0.0, 1.0)


def parameter_count(model: nn.Module) -> int:
    """Trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
