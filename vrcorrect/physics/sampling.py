"""Pixel sampling: how a PSF is put on the display's pixel grid, and what is recorded about it.

* The display grid: one pixel subtends ``1 / pixels_per_degree`` degrees
  (:func:`pixel_angle_rad`, radians).  PSFs are odd-sized square float64 arrays in *display*
  coordinates as the subject sees the display (rows go down, columns to the subject's right), centred
  on the middle pixel and summing to 1 (:class:`PixelPsf`); :class:`PsfSampling` records how one was
  made (which model, the grids, the worst pupil phase step) for ``--explain`` and the tests.
* Exact integration over pixels (:func:`integrate_over_pixels`): an intensity PSF sampled at or above
  the Nyquist rate of its band limit ``D / lambda`` is multiplied in frequency by the pixel's transfer
  function (a separable sinc) and sampled at the pixel centres, which integrates it over each pixel
  with no aliasing.
* Windows (:func:`energy_size`, :func:`crop_center`, :func:`crop_to_energy`): the smallest odd centred
  window holding a fraction of the energy, and centred crops.

Conventions: docs/architecture.md, 'Physics conventions' ('Axes', 'PSF').
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.fft

from ..plumbing.errors import ValidationError


def pixel_angle_rad(pixels_per_degree: float) -> float:
    """Angle one display pixel subtends (radians)."""
    return math.radians(1.0 / pixels_per_degree)


def check_psf_request(wavelength_nm: float, pixels_per_degree: float) -> None:
    """Raise :class:`ValidationError` for a wavelength outside 300..1000 nm or a display outside
    1..500 pixels per degree (every PSF model's range)."""
    if not (300.0 <= wavelength_nm <= 1000.0):
        raise ValidationError("wavelength_nm", wavelength_nm, "300 to 1000 nm")
    if not (1.0 <= pixels_per_degree <= 500.0):
        raise ValidationError("pixels_per_degree", pixels_per_degree, "1 to 500")


@dataclass(frozen=True)
class PsfSampling:
    """How one monochromatic PSF was sampled (for --explain and tests).

    ``model`` is ``"wave"`` (FFT of the pupil function, :mod:`.wave_psf`) or
    ``"geometric"`` (ray-traced blur integrated over pixels, convolved with the
    Airy core, :mod:`.geometric_psf`).  For a geometric PSF ``grid`` is 0 (no FFT
    pupil grid), ``oversample`` and ``fine_step_rad`` describe the sub-pixel
    grid the blur was integrated on, ``pupil_samples`` is the number of rays
    across the pupil (0 where the blur patch was integrated analytically),
    ``max_phase_step_rad`` is NaN, ``wave_grid_needed`` is the wave-optics
    grid that would have been needed (0 when the model was forced) and
    ``model_error_estimate`` is
    :func:`~vrcorrect.physics.geometric_psf.geometric_error_estimate`.
    """

    wavelength_nm: float
    oversample: int              # fine samples per pixel per axis
    grid: int                    # FFT size per side
    pupil_samples: float         # samples across the pupil diameter
    fine_step_rad: float
    max_phase_step_rad: float    # worst phase step between neighbours in the pupil
    refinements: int             # times the pupil grid was refined for a steep wavefront
    slope_rad: float             # largest wavefront slope
    model: str = "wave"          # "wave" or "geometric"
    model_error_estimate: float | None = None   # relative error of the geometric model; None for wave
    wave_grid_needed: int = 0    # geometric: the wave-optics grid per side it replaced (0 if forced)


@dataclass(frozen=True, eq=False)
class PixelPsf:
    """A PSF integrated over display pixels: odd square array summing to 1."""

    values: np.ndarray           # (n, n) float64, rows down / columns right as seen on the display
    pixels_per_degree: float
    sampling: PsfSampling

    @property
    def size(self) -> int:
        return int(self.values.shape[0])


def _fold_indices(N: int, q: int, n_pix: int) -> tuple[np.ndarray, np.ndarray]:
    """For folding a real signal's half spectrum: indices into rfft output and conjugation mask."""
    j = (np.arange(n_pix)[None, :] + n_pix * np.arange(q)[:, None]).reshape(-1)   # (q*n_pix,) = 0..N-1
    conj = j > N // 2
    return np.where(conj, N - j, j), conj


def integrate_over_pixels(intensity: np.ndarray, q: int, n_pix: int, fine: float, p: float) -> np.ndarray:
    """Integrate a fine-sampled PSF exactly over pixels of width ``p`` (rad).

    The intensity PSF is band-limited to D/lambda and sampled at
    ``fine <= lambda/(2D)``, so its DFT holds the OTF without aliasing.  The
    OTF is multiplied by the pixel's transfer function (a separable sinc) and
    the result is sampled at the pixel centres, i.e. the spectrum is folded
    ``q`` times per axis.  Input: (N, N) with zero angle at index 0; output:
    (n_pix, n_pix) with the centre pixel at index 0.
    """
    N = intensity.shape[0]
    box = np.sinc(scipy.fft.fftfreq(N, d=fine) * p)       # pixel transfer function, cycles/rad
    idx, conj = _fold_indices(N, q, n_pix)
    half = scipy.fft.rfft(intensity, axis=1, workers=-1)   # (N, N//2+1)
    cols = half[:, idx]
    cols[:, conj] = np.conj(cols[:, conj])
    cols *= box[None, :]
    cols = cols.reshape(N, q, n_pix).sum(axis=1)           # folded along x: (N, n_pix)
    rows = scipy.fft.fft(cols, axis=0, workers=-1) * box[:, None]
    folded = rows.reshape(q, n_pix, n_pix).sum(axis=0)      # folded along y: (n_pix, n_pix)
    return scipy.fft.ifft2(folded, workers=-1).real


def energy_size(arrays: np.ndarray, fraction: float) -> int:
    """Smallest odd size ``s`` whose centred ``s x s`` window holds ``fraction``
    of the energy of every array in ``arrays`` (shape ``(..., n, n)``)."""
    if not (0.5 < fraction <= 1.0):
        raise ValidationError("energy_fraction", fraction, "a fraction in (0.5, 1]")
    a = np.abs(np.asarray(arrays, dtype=np.float64))
    n = a.shape[-1]
    flat = a.reshape(-1, n, n)
    totals = flat.sum(axis=(1, 2))
    totals = np.where(totals > 0, totals, 1.0)
    c = n // 2
    # energy inside growing squares via cumulative sums of rings
    for r in range(0, c + 1):
        win = flat[:, c - r:c + r + 1, c - r:c + r + 1].sum(axis=(1, 2))
        if np.all(win >= fraction * totals - 1e-15):
            return 2 * r + 1
    return n


def crop_center(array: np.ndarray, size: int) -> np.ndarray:
    """Centred ``size x size`` crop (or zero-pad) of the last two axes."""
    n = array.shape[-1]
    if size == n:
        return array
    if size < n:
        s = (n - size) // 2
        return array[..., s:s + size, s:s + size]
    out = np.zeros(array.shape[:-2] + (size, size), dtype=array.dtype)
    s = (size - n) // 2
    out[..., s:s + n, s:s + n] = array
    return out


def crop_to_energy(psf: np.ndarray, fraction: float) -> np.ndarray:
    """Crop a PSF to the smallest odd window holding ``fraction`` of its energy and renormalise to sum 1."""
    size = energy_size(psf, fraction)
    out = crop_center(psf, size).copy()
    return out / out.sum()

