"""The wave-optics PSF: the pupil function's far field, integrated over display pixels.

Physics and conventions (docs/architecture.md, 'Physics conventions', 'PSF' and 'Axes'):

* Pupil function ``A exp(i 2 pi W / lambda)`` over the pupil disc (``W`` from
  :func:`vrcorrect.physics.refraction.wavefront_um`, um; pupil coordinates in mm, OSA frame), and
  ``PSF = |FFT|^2`` normalised to sum 1 (Fraunhofer diffraction).
* Sampling (:func:`pupil_grid`): the fine angular step is at most one display pixel over
  ``OpticsOptions.oversample`` and at most ``lambda / (pupil_padding D)`` (at the default 2, the
  Nyquist rate of the intensity PSF, so the integration over pixels is exact,
  :func:`vrcorrect.physics.sampling.integrate_over_pixels`); an odd 3-5-7-smooth number of fine
  samples per pixel.  The pupil sample spacing keeps the phase step between neighbouring samples
  below pi/2 (refined up to 12 times), with at least ``min_pupil_samples`` across the pupil for the
  diffraction tails.  Where that grid would exceed ``OpticsOptions.max_grid`` per side the wave
  model does not fit (:attr:`PupilGrid.fits`); :mod:`.psf` then chooses geometric optics.
* Orientation: the far field comes out in the OSA frame; it is mirrored in ``x`` (the OSA ``x`` is
  the subject's left) and flipped in ``y`` (rows go down) into display coordinates, centred on the
  middle pixel of an odd-sized array.
* Diffraction alone (:func:`diffraction_mtf`, :func:`airy_pixels`): the aberration-free pupil's
  transfer function and its Airy pattern integrated over pixels, the core the geometric-optics PSF is
  convolved with; :func:`diffraction_blur_rad` is the Airy disc's diameter, ``2.44 lambda / D``.

Units: wavelengths in nm (in mm inside the sampling arithmetic), angles in radians, the pupil in mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.fft

from ..plumbing.errors import ModelLimitError
from ..specs.prescription import EyeRx, PowerVector
from .options import OpticsOptions
from .refraction import max_meridian_power_D, max_wavefront_slope_rad, wavefront_um
from .sampling import PixelPsf, PsfSampling, check_psf_request, integrate_over_pixels, pixel_angle_rad

MAX_REFINEMENTS = 12                   # pupil refinements tried before the wave model gives up

_FAST_ODD = None


def _fast_odd_sizes() -> np.ndarray:
    """Odd 3-5-7-smooth integers up to 20000 (good FFT sizes)."""
    global _FAST_ODD
    if _FAST_ODD is None:
        vals = []
        for a in range(0, 10):
            for b in range(0, 7):
                for c in range(0, 6):
                    v = 3 ** a * 5 ** b * 7 ** c
                    if v <= 20000:
                        vals.append(v)
        _FAST_ODD = np.array(sorted(set(vals)))
    return _FAST_ODD


def _next_fast_odd(n: float) -> int:
    sizes = _fast_odd_sizes()
    i = int(np.searchsorted(sizes, math.ceil(n)))
    if i >= len(sizes):
        return int(math.ceil(n)) | 1
    return int(sizes[i])


@dataclass(frozen=True, eq=False)
class PupilGrid:
    """The sampling a wave-optics PSF needs at one wavelength (:func:`pupil_grid`).

    ``fits`` is False where the model cannot be sampled within the options: the grid the pupil
    needs is larger than ``OpticsOptions.max_grid`` (``limit == "grid"``; ``grid`` is the size it
    would need), or ``MAX_REFINEMENTS`` refinements left the phase step at pi/2 or more
    (``limit == "refinements"``; ``grid`` is the last size tried).  Where it fits, ``pupil`` holds
    the complex pupil function on the rows and columns that reach the pupil (OSA frame: rows ``y``
    ascending, columns ``x`` ascending).
    """

    wavelength_nm: float
    oversample: int              # fine samples per pixel per axis
    fine_step_rad: float
    pixels: int                  # pixels per side of the computed field
    grid: int                    # FFT size per side, pixels * oversample
    pupil_step_mm: float         # pupil sample spacing (NaN where the grid was too large)
    refinements: int
    slope_rad: float             # largest wavefront slope
    max_phase_step_rad: float    # worst phase step between pupil neighbours (NaN where not sampled)
    fits: bool
    limit: str                   # "" where it fits, else "grid" or "refinements"
    pupil: np.ndarray | None = None


def pupil_grid(eye: EyeRx, pv: PowerVector, wavelength_nm: float, pixels_per_degree: float,
               options: OpticsOptions = OpticsOptions()) -> PupilGrid:
    """Size the wave-optics grid for ``eye`` with residual power vector ``pv`` at one wavelength.

    Fine angular step at most ``p / oversample`` and ``lambda / (pupil_padding D)``; pupil spacing
    so that the phase step between neighbours stays below pi/2 (with a margin of 1.25, refined by
    1/1.4 while it does not), at least ``min_pupil_samples`` across the pupil.  See
    :class:`PupilGrid` for what comes back where it does not fit.
    """
    lam_mm = wavelength_nm * 1e-6
    D = eye.pupil_diameter_mm
    radius = D / 2.0
    p = pixel_angle_rad(pixels_per_degree)

    # Fine angular step: at most p/oversample and at most lambda/(padding*D).
    q = max(options.oversample, int(math.ceil(options.pupil_padding * D * p / lam_mm)))
    q = _next_fast_odd(q)
    fine = p / q
    L = lam_mm / fine  # pupil-plane grid length (mm) so that the FFT step is `fine`

    slope = max_wavefront_slope_rad(eye, pv)  # rad
    # Pupil sample spacing: phase step < pi/2 needs slope*dx < lambda/4; keep some margin,
    # and at least min_pupil_samples across the pupil for the diffraction tails.
    dx = min(lam_mm / (4.0 * 1.25 * slope) if slope > 0 else math.inf, D / options.min_pupil_samples)
    refinements = 0

    def unfit(n_pix: int, N: int, dxe: float, step: float, limit: str) -> PupilGrid:
        return PupilGrid(float(wavelength_nm), q, fine, n_pix, N, dxe, refinements, slope, step, False, limit)

    while True:
        n_pix = _next_fast_odd(max(L / dx / q, 3.0))
        N = n_pix * q
        if N > options.max_grid:
            # Too steep for a wave-optics grid: the blur is many diffraction widths wide here.
            return unfit(n_pix, N, math.nan, math.nan, "grid")
        dxe = L / N
        coords = (np.arange(N) - (N - 1) / 2.0) * dxe
        half = int(math.ceil(radius / dxe)) + 1
        c0 = (N - 1) // 2
        sl = slice(max(c0 - half, 0), min(c0 + half + 1, N))
        xs = coords[sl]
        X, Y = np.meshgrid(xs, xs)          # rows: y ascending, columns: x ascending (OSA frame)
        inside = X * X + Y * Y <= radius * radius
        w_mm = wavefront_um(eye, pv, X, Y) * 1e-3
        phase = (2.0 * math.pi / lam_mm) * w_mm
        # worst phase step between neighbours that are both inside the pupil
        step = 0.0
        both = inside[:, 1:] & inside[:, :-1]
        if both.any():
            step = max(step, float(np.max(np.abs(np.diff(phase, axis=1))[both])))
        both = inside[1:, :] & inside[:-1, :]
        if both.any():
            step = max(step, float(np.max(np.abs(np.diff(phase, axis=0))[both])))
        if step < math.pi / 2.0:
            break
        refinements += 1
        dx = dxe / 1.4
        if refinements > MAX_REFINEMENTS:
            return unfit(n_pix, N, dxe, step, "refinements")

    pupil = np.where(inside, np.exp(1j * phase), 0.0)
    return PupilGrid(float(wavelength_nm), q, fine, n_pix, N, dxe, refinements, slope, step, True, "", pupil)


def wave_psf_pixels(eye: EyeRx, pv: PowerVector, wavelength_nm: float, pixels_per_degree: float,
                    options: OpticsOptions = OpticsOptions(), *, grid: PupilGrid | None = None) -> PixelPsf:
    """Monochromatic PSF by wave optics, integrated over pixels.

    Parameters
    ----------
    eye, pv, wavelength_nm, pixels_per_degree, options
        As for :func:`~vrcorrect.physics.psf.psf_pixels`.
    grid
        The sampling from :func:`pupil_grid` for these arguments, where the caller has it already.

    Returns
    -------
    PixelPsf
        Odd-sized float64 array centred on its centre pixel, summing to 1, covering the whole
        computed angular field; ``sampling.model == "wave"``.

    Raises
    ------
    ModelLimitError
        Where the pupil grid does not fit (:attr:`PupilGrid.fits`).
    """
    check_psf_request(wavelength_nm, pixels_per_degree)
    if grid is None:
        grid = pupil_grid(eye, pv, wavelength_nm, pixels_per_degree, options)
    D = eye.pupil_diameter_mm
    if grid.limit == "grid":
        N = grid.grid
        raise ModelLimitError(
            f"the PSF at {wavelength_nm:.0f} nm needs a {N}x{N} pupil grid (limit {options.max_grid}): "
            f"the wavefront is too steep ({max_meridian_power_D(pv):.1f} D over a {D:g} mm pupil) "
            f"for {pixels_per_degree:g} pixels per degree; use a smaller pupil_diameter_mm or a lower "
            f"pixels_per_degree")
    if not grid.fits:
        raise ModelLimitError("could not sample the pupil finely enough (wavefront too steep)")
    q, N, n_pix, fine = grid.oversample, grid.grid, grid.pixels, grid.fine_step_rad
    p = pixel_angle_rad(pixels_per_degree)
    # Far-field by a zero-padded 2-D DFT.  Only the pupil's rows are non-zero, so transform those
    # along x first, then all columns along y.  (Where the pupil sits in the padded grid only adds
    # a linear phase to the field, which |.|^2 removes.)
    spectrum = scipy.fft.fft(scipy.fft.fft(grid.pupil, n=N, axis=1, workers=-1), n=N, axis=0, workers=-1)
    intensity = spectrum.real ** 2 + spectrum.imag ** 2   # zero angle at index 0
    del spectrum
    pix = integrate_over_pixels(intensity, q, n_pix, fine, p)
    pix = scipy.fft.fftshift(pix)         # centre pixel at (n_pix-1)/2; rows theta_y up, cols theta_x (OSA)
    # To display orientation: mirror x (OSA x is the subject's left), flip y (rows go down).
    pix = np.ascontiguousarray(pix[::-1, ::-1])
    # Ringing of the band-limited interpolation can leave tiny negative values far out; clip them.
    np.maximum(pix, 0.0, out=pix)
    total = pix.sum()
    if not (total > 0 and math.isfinite(total)):
        raise ModelLimitError("PSF computation produced no energy (check the pupil sampling)")
    pix /= total
    sampling = PsfSampling(wavelength_nm=float(wavelength_nm), oversample=q, grid=N,
                           pupil_samples=D / grid.pupil_step_mm, fine_step_rad=fine,
                           max_phase_step_rad=grid.max_phase_step_rad, refinements=grid.refinements,
                           slope_rad=grid.slope_rad)
    return PixelPsf(pix, float(pixels_per_degree), sampling)


# --------------------------------------------------------------------------
# Diffraction alone: the aberration-free pupil
# --------------------------------------------------------------------------

def diffraction_mtf(rho: np.ndarray) -> np.ndarray:
    """Transfer function of an aberration-free circular pupil (incoherent light).

    ``rho = f lambda / D`` is the spatial frequency ``f`` (cycles per radian)
    over the cutoff ``D / lambda``; the value is
    ``(2/pi)(acos rho - rho sqrt(1 - rho^2))`` below the cutoff, 0 above.  Its
    Fourier transform is the Airy pattern.
    """
    r = np.abs(np.asarray(rho, dtype=np.float64))
    c = np.minimum(r, 1.0)
    return np.where(r < 1.0, (2.0 / math.pi) * (np.arccos(c) - c * np.sqrt(1.0 - c * c)), 0.0)


def airy_pixels(wavelength_nm: float, pupil_diameter_mm: float, pixels_per_degree: float) -> np.ndarray:
    """The Airy pattern of the pupil integrated exactly over display pixels.

    The pattern's transfer function (:func:`diffraction_mtf`) times the
    pixel's (a separable sinc) is band-limited to ``D / lambda``, so sampling
    it at the harmonics of the field and folding it onto the field's DFT
    bins gives the pixel integrals exactly (of the pattern wrapped onto the
    field, as in the wave-optics path).  The field is +-96 ``lambda / D``, the
    smallest field the wave-optics path computes, at least 3 pixels and at
    most 1025.  Odd square float64 array, centred, summing to 1.
    """
    p = pixel_angle_rad(pixels_per_degree)
    lam_over_d = wavelength_nm * 1e-9 / (pupil_diameter_mm * 1e-3)   # rad
    half = int(min(max(math.ceil(96.0 * lam_over_d / p), 1), 512))
    n = 2 * half + 1
    df = 1.0 / (n * p)                                  # cycles/rad between harmonics of the field
    kmax = int(math.floor(1.0 / (lam_over_d * df)))     # harmonics below the cutoff D/lambda
    k = np.arange(-kmax, kmax + 1)
    f = k * df
    box = np.sinc(f * p)
    spectrum = diffraction_mtf(np.hypot(f[:, None], f[None, :]) * lam_over_d) * box[:, None] * box[None, :]
    idx = np.mod(k, n)
    rows = np.zeros((n, k.size))
    np.add.at(rows, idx, spectrum)
    folded = np.zeros((n, n))
    np.add.at(folded.T, idx, rows.T)
    pix = scipy.fft.fftshift(scipy.fft.ifft2(folded).real)
    np.maximum(pix, 0.0, out=pix)
    return pix / pix.sum()


def diffraction_blur_rad(wavelength_nm: float, pupil_diameter_mm: float) -> float:
    """Diameter of the Airy disc's first dark ring (radians)."""
    return 2.44 * wavelength_nm * 1e-9 / (pupil_diameter_mm * 1e-3)
