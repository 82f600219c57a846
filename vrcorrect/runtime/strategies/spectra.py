"""The eye's kernel spectra on a 5-smooth FFT grid, computed on the CPU for the strategies that
upload whole 3x3 complex spectra (:class:`~vrcorrect.runtime.fft.FftBankGL`: FISTA, the one-pass
FFT inverse and the preview's forward model), and the ADMM strategy's real-to-complex half spectra
(:func:`half_spectrum`).

Layer 5: numpy only.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np


if TYPE_CHECKING:  # pragma: no cover - typing only
    from ..eye_model import EyeModel

__all__ = ["kernel_spectra", "simulation_spectrum", "half_spectrum", "coarse_model", "model_spectra", "bank_spectra"]


def kernel_spectra(model: "EyeModel", grid: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """``K(f)`` and the target operator ``T(f)`` (``K_ref(f)`` with glasses, else the colour
    matrix ``A`` at every frequency), full complex ``(3, 3, NY, NX)`` spectra on ``grid``."""
    from ...solvers.spectral import centred_kernel  # start-up time: scipy with the first eye

    k = model.kernel
    Kf = np.fft.fft2(centred_kernel(k.kernel, grid), axes=(2, 3))
    Tf = (np.fft.fft2(centred_kernel(model.reference.kernel, grid), axes=(2, 3)) if model.reference is not None
          else np.broadcast_to(k.matrix[:, :, None, None], Kf.shape))
    return Kf, Tf


def simulation_spectrum(model: "EyeModel", grid: tuple[int, int]) -> np.ndarray:
    """The forward model's bank ``A^-1 K(f)`` (what the eye sees, in display RGB) on ``grid``: the
    eye's own kernel (:attr:`~vrcorrect.runtime.eye_model.EyeModel.seen_kernel`), never a robust
    design's effective one."""
    from ...solvers.spectral import centred_kernel  # start-up time (as above)

    k = model.seen_kernel
    Kf = np.fft.fft2(centred_kernel(k.kernel, grid), axes=(2, 3))
    return np.einsum("ik,kjyx->ijyx", np.linalg.inv(k.matrix), Kf)


def half_spectrum(kernel: np.ndarray, grid: tuple[int, int], dtype: str) -> np.ndarray:
    """The real-to-complex spectrum of a ``(3, 3, s, s)`` kernel in GL orientation (vertically
    flipped) on ``grid``, centred on the origin, as the texture holds it: ``(9, NY, NX/2 + 1, 2)``
    (real, imaginary) in float16 or float32 (``dtype`` ``"f2"``/``"f4"``), from float64."""
    from ...solvers.spectral import kernel_spectrum  # start-up time: scipy with the first eye

    Kf = kernel_spectrum(np.ascontiguousarray(kernel[:, :, ::-1, :]), grid)
    out = np.stack([Kf.real, Kf.imag], axis=-1).reshape(9, grid[0], grid[1] // 2 + 1, 2)
    return out.astype(np.float16 if dtype == "f2" else np.float32)


def coarse_model(m: "EyeModel") -> "EyeModel":
    """The model a cold frame's half-resolution level runs: the kernels 2x2 pixel blocks see."""
    from ...solvers.realtime import coarse_eye_kernel, coarse_kernel_size  # start-up time: scipy with the first eye

    return replace(m, kernel=coarse_eye_kernel(m.kernel),
                   reference=None if m.reference is None else coarse_eye_kernel(m.reference),
                   grid_kernel_size=None if m.grid_kernel_size is None else coarse_kernel_size(m.grid_kernel_size),
                   spectra={k: v for k, v in m.spectra.items() if k[2]})


def model_spectra(m: "EyeModel", grid: tuple[int, int], dtype: str, coarse: bool = False
                  ) -> tuple[np.ndarray, np.ndarray | None]:
    """The kernel's and the reference's half spectra on ``grid`` as the textures hold them
    (:func:`half_spectrum`): from ``m.spectra`` where a pupil bank computed them, else now."""
    have = m.spectra.get((grid, dtype, coarse))
    if have is not None:
        return have
    return (half_spectrum(m.kernel.kernel, grid, dtype),
            None if m.reference is None else half_spectrum(m.reference.kernel, grid, dtype))


def bank_spectra(m: "EyeModel", grids: tuple) -> dict:
    """``model_spectra`` on each of ``grids`` (:meth:`~vrcorrect.runtime.strategies.admm.AdmmStrategy.spectra_grids`), for
    ``EyeModel.spectra``: what a pupil bank's worker computes before a switch."""
    out = {}
    for grid, dtype, coarse in grids:
        source = coarse_model(m) if coarse else m
        out[(grid, dtype, coarse)] = model_spectra(source, grid, dtype)
    return out
