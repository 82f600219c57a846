"""What the eye sees of a displayed image, on the GPU (:meth:`~vrcorrect.runtime.corrector.
Corrector.simulate`): the forward model's bank ``A^-1 K`` with black outside the image, by FFT
(every method but ``separable``) or as the separable low-rank bank the separable method's model
carries.

Layer 5: numpy, moderngl; never torch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..dispatch import Gpu
from ..fft import FftBankGL, fft_grid
from ..gl import release
from .base import Size
from .onepass import SeparableBankGL
from .spectra import simulation_spectrum

if TYPE_CHECKING:  # pragma: no cover - typing only
    import moderngl

    from ..eye_model import EyeModel

__all__ = ["Preview"]


class Preview:
    """The forward model of one eye (spectra made on the first frame of each size)."""

    def __init__(self, gpu: Gpu, model: "EyeModel"):
        self.gpu, self.model = gpu, model
        self.bank = None if model.simulation is None else SeparableBankGL(gpu, "simulation.glsl", model.simulation,
                                                                          "zero")
        self._fft: dict[Size, FftBankGL] = {}

    def run(self, shown: "moderngl.Texture", seen: "moderngl.Texture") -> None:
        if self.bank is not None:
            self.bank.run(shown, seen)
            return
        size = tuple(shown.size)
        bank = self._fft.get(size)
        if bank is None:
            m = self.model
            bank = self._fft[size] = FftBankGL(self.gpu.ctx, simulation_spectrum(m, fft_grid(*size, m.margin)), size,
                                               m.margin, border="zero", combine="clip")
        bank.run(self.gpu, shown, seen)

    def release(self) -> None:
        release(self.bank, *self._fft.values())
        self._fft.clear()
