"""Optics of the eye: Zernike wavefronts, chromatic aberration and the
pixel-sampled point-spread function.

(One file of about 1,000 lines on purpose: the wave-optics and geometric-optics PSFs share the
refraction state, the options and the pixel sampling, and :func:`psf_pixels` chooses between them
per wavelength; split apart, the two models would import each other.)

Conventions (see docs/architecture.md, 'Physics conventions'):

* Zernike polynomials follow OSA/ANSI Z80.28: single index ``j = (n(n+2)+m)/2``,
  each term normalised to unit RMS over the unit disc, ``Z_n^m = N R_n^|m|(rho)
  cos(m theta)`` for ``m >= 0`` and ``-N R_n^|m|(rho) sin(m theta)`` for
  ``m < 0``.  Coefficients are in micrometres for a stated pupil radius.
* Pupil coordinates ``(x, y)`` are in the OSA/ISO 8429 frame: the eye as seen
  by the examiner, ``x`` to the examiner's right (the subject's left), ``y``
  up, angles counter-clockwise.  Spectacle axes (TABO) use the same frame.
* PSFs are returned in *display* coordinates as the subject sees the display:
  array rows go down the screen, columns go to the subject's right.  The map
  from the OSA frame is therefore a mirror in ``x`` (an optometric axis
  ``alpha`` appears on the display at ``180 - alpha``) and a flip of ``y`` for
  row order.
* Second-order terms from a power vector (Thibos 1997):
  ``c(2,0) = -M r^2/(4 sqrt 3)``, ``c(2,2) = -J0 r^2/(2 sqrt 6)``,
  ``c(2,-2) = -J45 r^2/(2 sqrt 6)`` with ``r`` in mm, powers in dioptres and
  ``c`` in micrometres.  The resulting wavefront is
  ``W(x, y) = -(M (x^2+y^2) + J0 (x^2-y^2) + 2 J45 x y) / 2`` (+ piston).
* Viewing distance ``d``: the refraction that would make the display sharp is
  ``R = M + 1/d``.  Accommodation removes positive ``R`` up to its amplitude,
  never negative ``R``.
* Longitudinal chromatic aberration: Thibos et al. (1992) "chromatic eye",
  ``Rx(lambda) = p - q / (lambda - c)`` with ``p = 1.68524 D``,
  ``q = 633.46 D nm``, ``c = 214.102 nm``: about -1.0 D at 450 nm and +0.23 D
  at 650 nm relative to 590 nm (short wavelengths are focused in front of the
  retina, i.e. the eye is more myopic for blue).  The prescription holds at
  the reference wavelength (default 555 nm, the peak of photopic
  sensitivity V(lambda)).
* PSF: pupil function ``A exp(i 2 pi W / lambda)``, ``PSF = |FFT|^2``
  normalised to sum 1, computed on an angular grid ``oversample`` times finer
  than a display pixel and integrated over each pixel; centred on the centre
  pixel of an odd-sized array.
* Where the wavefront is so steep that the wave-optics pupil grid would
  exceed ``OpticsOptions.max_grid``, the blur is many diffraction widths wide
  and the PSF comes from geometric optics instead: the pupil's ray-traced blur
  (each ray lands at angle ``grad W``) integrated over pixels and convolved
  with the Airy pattern (:func:`geometric_psf_pixels`); ``PsfSampling.model``
  records which model made each PSF.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.fft

from ..plumbing.errors import ModelLimitError, ValidationError
from ..specs.prescription import EyeRx, PowerVector

# Thibos, Ye, Zhang & Bradley (1992), Applied Optics 31(19):3594, chromatic eye.
LCA_P_D = 1.68524
LCA_Q_D_NM = 633.46
LCA_C_NM = 214.102

DEFAULT_REFERENCE_WAVELENGTH_NM = 555.0
ARCMIN_RAD = math.radians(1.0 / 60.0)
PSF_MODELS = ("auto", "wave", "geometric")


# --------------------------------------------------------------------------
# Zernike polynomials (OSA/ANSI)
# --------------------------------------------------------------------------

def osa_index(n: int, m: int) -> int:
    """OSA/ANSI single index ``j`` of ``Z_n^m``."""
    if n < 0 or abs(m) > n or (n - m) % 2:
        raise ValidationError("zernike (n, m)", (n, m), "n >= 0, |m| <= n, n - m even")
    return (n * (n + 2) + m) // 2


def osa_nm(j: int) -> tuple[int, int]:
    """Radial order ``n`` and azimuthal frequency ``m`` of OSA/ANSI index ``j``."""
    if j < 0:
        raise ValidationError("zernike j", j, "an integer >= 0")
    n = int(math.ceil((-3 + math.sqrt(9 + 8 * j)) / 2))
    m = 2 * j - n * (n + 2)
    return n, m


def _radial(n: int, m_abs: int, rho: np.ndarray) -> np.ndarray:
    out = np.zeros_like(rho)
    for s in range((n - m_abs) // 2 + 1):
        coef = ((-1) ** s * math.factorial(n - s)
                / (math.factorial(s) * math.factorial((n + m_abs) // 2 - s)
                   * math.factorial((n - m_abs) // 2 - s)))
        out += coef * rho ** (n - 2 * s)
    return out


def zernike(n: int, m: int, rho: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """OSA/ANSI normalised Zernike polynomial ``Z_n^m(rho, theta)``.

    Parameters
    ----------
    n, m
        Radial order and azimuthal frequency.
    rho
        Normalised radius (0..1 inside the pupil); float64 array.
    theta
        Azimuth in radians, counter-clockwise from +x (OSA frame).

    Returns
    -------
    numpy.ndarray
        Values with unit RMS over the unit disc (not masked outside it).
    """
    osa_index(n, m)  # validates
    rho = np.asarray(rho, dtype=np.float64)
    theta = np.asarray(theta, dtype=np.float64)
    norm = math.sqrt((2 * (n + 1)) / (2.0 if m == 0 else 1.0))
    radial = _radial(n, abs(m), rho)
    if m > 0:
        return norm * radial * np.cos(m * theta)
    if m < 0:
        return -norm * radial * np.sin(m * theta)
    return norm * radial


# --------------------------------------------------------------------------
# Refraction: power vectors, distance, accommodation, chromatic aberration
# --------------------------------------------------------------------------

def power_vector_to_zernike_um(pv: PowerVector, pupil_radius_mm: float) -> dict[tuple[int, int], float]:
    """Second-order Zernike coefficients (um) of a power vector over a pupil radius (mm)."""
    r2 = pupil_radius_mm ** 2
    return {
        (2, 0): -pv.M_D * r2 / (4.0 * math.sqrt(3.0)),
        (2, 2): -pv.J0_D * r2 / (2.0 * math.sqrt(6.0)),
        (2, -2): -pv.J45_D * r2 / (2.0 * math.sqrt(6.0)),
    }


def zernike_um_to_power_vector(coefficients: dict[tuple[int, int], float],
                               pupil_radius_mm: float) -> PowerVector:
    """Inverse of :func:`power_vector_to_zernike_um` (second order only)."""
    r2 = pupil_radius_mm ** 2
    return PowerVector(
        M_D=-coefficients.get((2, 0), 0.0) * 4.0 * math.sqrt(3.0) / r2,
        J0_D=-coefficients.get((2, 2), 0.0) * 2.0 * math.sqrt(6.0) / r2,
        J45_D=-coefficients.get((2, -2), 0.0) * 2.0 * math.sqrt(6.0) / r2,
    )


def chromatic_refraction_D(wavelength_nm: np.ndarray | float) -> np.ndarray:
    """Refractive error of the Thibos (1992) chromatic eye at ``wavelength_nm`` (D).

    Zero near 590 nm; negative (myopic) at short wavelengths.
    """
    lam = np.asarray(wavelength_nm, dtype=np.float64)
    return LCA_P_D - LCA_Q_D_NM / (lam - LCA_C_NM)


def lca_defocus_D(wavelength_nm: np.ndarray | float, reference_wavelength_nm: float) -> np.ndarray:
    """Change in the eye's refraction at ``wavelength_nm`` relative to the reference (D)."""
    return chromatic_refraction_D(wavelength_nm) - chromatic_refraction_D(reference_wavelength_nm)


@dataclass(frozen=True)
class OpticsOptions:
    """How the eye's optics are modelled.

    Attributes
    ----------
    chromatic_aberration
        Include the eye's longitudinal chromatic aberration.
    reference_wavelength_nm
        Wavelength at which the prescription holds (nm).
    viewing_distance_m
        Distance of the display (or the headset's virtual image) in metres;
        ``None`` takes the display profile's, ``math.inf`` is the paper's
        setting (no vergence).
    oversample
        Minimum number of fine angular samples per display pixel and axis
        (odd, >= 1).  More are used when diffraction needs them.
    pupil_padding
        Fine angular step is at most ``lambda / (pupil_padding * D)``; 2 (the
        default) is the Nyquist rate of the intensity PSF, at which the pixel
        integration below is exact.
    min_pupil_samples
        Minimum samples across the pupil (sets the angular field that holds
        diffraction tails).
    max_grid
        Largest wave-optics FFT grid (per side).  Where the pupil grid a steep
        wavefront needs would be larger, the PSF is modelled by geometric
        optics instead (see :func:`geometric_psf_pixels`); the same number
        bounds the geometric PSF's pixel array (per side).
    psf_model
        ``"auto"`` (default): wave optics wherever its grid fits in
        ``max_grid``, geometric optics where it would not (there the defocus
        blur is many times the diffraction blur).  ``"wave"``: wave optics
        only, refusing with :class:`~vrcorrect.plumbing.errors.ModelLimitError` where
        the grid would not fit.  ``"geometric"``: geometric optics everywhere.
    """

    chromatic_aberration: bool = True
    reference_wavelength_nm: float = DEFAULT_REFERENCE_WAVELENGTH_NM
    viewing_distance_m: float | None = None
    oversample: int = 1
    pupil_padding: float = 2.0
    min_pupil_samples: int = 192
    max_grid: int = 6144
    psf_model: str = "auto"

    def __post_init__(self) -> None:
        if not (380.0 <= self.reference_wavelength_nm <= 780.0):
            raise ValidationError("reference_wavelength_nm", self.reference_wavelength_nm, "380 to 780 nm")
        if self.viewing_distance_m is not None and not (self.viewing_distance_m > 0.05):
            raise ValidationError("viewing_distance_m", self.viewing_distance_m,
                                  "a distance > 0.05 m, or inf for optical infinity")
        if not (isinstance(self.oversample, int) and 1 <= self.oversample <= 99 and self.oversample % 2 == 1):
            raise ValidationError("oversample", self.oversample, "an odd integer from 1 to 99")
        if not (2.0 <= self.pupil_padding <= 8.0):
            raise ValidationError("pupil_padding", self.pupil_padding,
                                  "2 to 8 (below 2 the intensity PSF is under-sampled)")
        if not (32 <= self.min_pupil_samples <= 2048):
            raise ValidationError("min_pupil_samples", self.min_pupil_samples, "32 to 2048")
        if self.psf_model not in PSF_MODELS:
            raise ValidationError("psf_model", self.psf_model, "one of " + ", ".join(PSF_MODELS))


@dataclass(frozen=True)
class RefractiveState:
    """The eye's residual refractive error while looking at the display (D)."""

    residual: PowerVector          # at the reference wavelength, after distance and accommodation
    accommodation_used_D: float
    vergence_D: float              # 1/d of the display (0 at infinity)

    def at_wavelength(self, wavelength_nm: float, options: OpticsOptions) -> PowerVector:
        """Residual power vector at another wavelength (adds chromatic defocus)."""
        dM = float(lca_defocus_D(wavelength_nm, options.reference_wavelength_nm)) if options.chromatic_aberration else 0.0
        return PowerVector(self.residual.M_D + dM, self.residual.J0_D, self.residual.J45_D)


def refractive_state(eye: EyeRx, distance_m: float) -> RefractiveState:
    """Residual refraction of ``eye`` looking at a display at ``distance_m``.

    ``R = M + 1/d``; accommodation removes positive ``R`` up to
    ``eye.accommodation_D``, never negative ``R``.
    """
    pv = eye.power_vector()
    vergence = 0.0 if math.isinf(distance_m) else 1.0 / distance_m
    R = pv.M_D + vergence
    used = min(max(R, 0.0), eye.accommodation_D)
    return RefractiveState(PowerVector(R - used, pv.J0_D, pv.J45_D), used, vergence)


def max_meridian_power_D(pv: PowerVector) -> float:
    """Largest refractive error over all meridians, in magnitude (D)."""
    return abs(pv.M_D) + math.hypot(pv.J0_D, pv.J45_D)


def meridian_power_D(pv: PowerVector, meridian_deg: float) -> float:
    """Refractive error along one meridian (OSA/TABO angle, degrees)."""
    a = math.radians(2.0 * meridian_deg)
    return pv.M_D + pv.J0_D * math.cos(a) + pv.J45_D * math.sin(a)


# --------------------------------------------------------------------------
# Wavefront
# --------------------------------------------------------------------------

def wavefront_um(eye: EyeRx, pv: PowerVector, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    """Wavefront error (um) over pupil coordinates (mm, OSA frame).

    Second order from the residual power vector ``pv``; higher orders from the
    prescription's measured coefficients, evaluated in physical coordinates of
    the pupil they were measured at (so no rescaling formula is needed when the
    eye's pupil is smaller).
    """
    x = np.asarray(x_mm, dtype=np.float64)
    y = np.asarray(y_mm, dtype=np.float64)
    w = -0.5 * (pv.M_D * (x * x + y * y) + pv.J0_D * (x * x - y * y) + 2.0 * pv.J45_D * x * y)
    ho = eye.higher_order
    if ho is not None and ho.coefficients_um:
        radius = ho.pupil_diameter_mm / 2.0
        rho = np.hypot(x, y) / radius
        theta = np.arctan2(y, x)
        for j, c in ho.coefficients_um:
            n, m = osa_nm(int(j))
            w = w + c * zernike(n, m, rho, theta)
    return w


def wavefront_from_zernike_um(coefficients: dict[tuple[int, int], float], pupil_radius_mm: float,
                              x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    """Wavefront (um) from OSA Zernike coefficients (um) for a pupil radius (mm)."""
    rho = np.hypot(x_mm, y_mm) / pupil_radius_mm
    theta = np.arctan2(y_mm, x_mm)
    out = np.zeros(np.broadcast(rho, theta).shape)
    for (n, m), c in coefficients.items():
        out = out + c * zernike(n, m, rho, theta)
    return out


def max_wavefront_slope_rad(eye: EyeRx, pv: PowerVector) -> float:
    """Largest wavefront slope over the pupil (radians; um/mm = mrad).

    Exact for second order; higher orders are sampled on a 129x129 grid.
    """
    radius_mm = eye.pupil_diameter_mm / 2.0
    slope = max_meridian_power_D(pv) * radius_mm * 1e-3  # D * mm -> mrad * 1e-3 = rad
    if eye.higher_order is not None and eye.higher_order.coefficients_um:
        n = 129
        c = np.linspace(-radius_mm, radius_mm, n)
        X, Y = np.meshgrid(c, c)
        inside = X * X + Y * Y <= radius_mm ** 2
        zero = PowerVector(0.0, 0.0, 0.0)
        w = wavefront_um(eye, zero, X, Y)
        gy, gx = np.gradient(w, c, c)
        ho_slope = float(np.max(np.hypot(gx, gy)[inside])) * 1e-3
        slope += ho_slope
    return slope


# --------------------------------------------------------------------------
# PSF
# --------------------------------------------------------------------------

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


@dataclass(frozen=True)
class PsfSampling:
    """How one monochromatic PSF was sampled (for --explain and tests).

    ``model`` is ``"wave"`` (FFT of the pupil function) or ``"geometric"``
    (ray-traced blur integrated over pixels, convolved with the Airy core; see
    :func:`geometric_psf_pixels`).  For a geometric PSF ``grid`` is 0 (no FFT
    pupil grid), ``oversample`` and ``fine_step_rad`` describe the sub-pixel
    grid the blur was integrated on, ``pupil_samples`` is the number of rays
    across the pupil (0 where the blur patch was integrated analytically),
    ``max_phase_step_rad`` is NaN, ``wave_grid_needed`` is the wave-optics
    grid that would have been needed (0 when the model was forced) and
    ``model_error_estimate`` is :func:`geometric_error_estimate`.
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


def pixel_angle_rad(pixels_per_degree: float) -> float:
    return math.radians(1.0 / pixels_per_degree)


def _fold_indices(N: int, q: int, n_pix: int) -> tuple[np.ndarray, np.ndarray]:
    """For folding a real signal's half spectrum: indices into rfft output and conjugation mask."""
    j = (np.arange(n_pix)[None, :] + n_pix * np.arange(q)[:, None]).reshape(-1)   # (q*n_pix,) = 0..N-1
    conj = j > N // 2
    return np.where(conj, N - j, j), conj


def _integrate_over_pixels(intensity: np.ndarray, q: int, n_pix: int, fine: float, p: float) -> np.ndarray:
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


def psf_pixels(eye: EyeRx, pv: PowerVector, wavelength_nm: float, pixels_per_degree: float,
               options: OpticsOptions = OpticsOptions()) -> PixelPsf:
    """Monochromatic PSF of ``eye`` with residual power vector ``pv``, integrated over pixels.

    Parameters
    ----------
    eye
        Supplies pupil diameter and higher-order terms.
    pv
        Residual second-order refraction at this wavelength (D).
    wavelength_nm
        Wavelength (nm), 300..1000.
    pixels_per_degree
        Display sampling (pixels per degree of visual angle).
    options
        Sampling options.

    Returns
    -------
    PixelPsf
        Odd-sized float64 array centred on its centre pixel, summing to 1,
        covering the whole computed angular field (crop with
        :func:`crop_to_energy`).  ``sampling.model`` says which model made it.

    Notes
    -----
    Wave optics (FFT of the pupil function) wherever its pupil grid fits in
    ``options.max_grid``.  Where it would not, the wavefront is so steep that
    the defocus blur is many times the diffraction blur, and (with
    ``options.psf_model == "auto"``) the PSF comes from geometric optics,
    :func:`geometric_psf_pixels`; ``options.psf_model == "wave"`` refuses
    there instead.

    Raises
    ------
    ModelLimitError
        Wave optics only and the grid would not fit; or the geometric PSF's
        pixel array would exceed ``options.max_grid`` per side.
    """
    if not (300.0 <= wavelength_nm <= 1000.0):
        raise ValidationError("wavelength_nm", wavelength_nm, "300 to 1000 nm")
    if not (1.0 <= pixels_per_degree <= 500.0):
        raise ValidationError("pixels_per_degree", pixels_per_degree, "1 to 500")
    lam_mm = wavelength_nm * 1e-6
    D = eye.pupil_diameter_mm
    radius = D / 2.0
    p = pixel_angle_rad(pixels_per_degree)

    # Fine angular step: at most p/oversample and at most lambda/(padding*D).
    q = max(options.oversample, int(math.ceil(options.pupil_padding * D * p / lam_mm)))
    q = _next_fast_odd(q)
    fine = p / q
    L = lam_mm / fine  # pupil-plane grid length (mm) so that the FFT step is `fine`

    if options.psf_model == "geometric":
        return geometric_psf_pixels(eye, pv, wavelength_nm, pixels_per_degree, options)
    slope = max_wavefront_slope_rad(eye, pv)  # rad
    # Pupil sample spacing: phase step < pi/2 needs slope*dx < lambda/4; keep some margin,
    # and at least min_pupil_samples across the pupil for the diffraction tails.
    dx = min(lam_mm / (4.0 * 1.25 * slope) if slope > 0 else math.inf, D / options.min_pupil_samples)
    refinements = 0
    while True:
        n_pix = _next_fast_odd(max(L / dx / q, 3.0))
        N = n_pix * q
        if N > options.max_grid:
            if options.psf_model == "auto":
                # Too steep for a wave-optics grid: the blur is many diffraction widths wide here.
                return geometric_psf_pixels(eye, pv, wavelength_nm, pixels_per_degree, options,
                                            wave_grid_needed=N)
            raise ModelLimitError(
                f"the PSF at {wavelength_nm:.0f} nm needs a {N}x{N} pupil grid (limit {options.max_grid}): "
                f"the wavefront is too steep ({max_meridian_power_D(pv):.1f} D over a {D:g} mm pupil) "
                f"for {pixels_per_degree:g} pixels per degree; use a smaller pupil_diameter_mm or a lower "
                f"pixels_per_degree")
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
        if refinements > 12:
            if options.psf_model == "auto":
                return geometric_psf_pixels(eye, pv, wavelength_nm, pixels_per_degree, options,
                                            wave_grid_needed=N)
            raise ModelLimitError("could not sample the pupil finely enough (wavefront too steep)")

    pupil = np.where(inside, np.exp(1j * phase), 0.0)
    # Far-field by a zero-padded 2-D DFT.  Only the pupil's rows are non-zero, so transform those
    # along x first, then all columns along y.  (Where the pupil sits in the padded grid only adds
    # a linear phase to the field, which |.|^2 removes.)
    spectrum = scipy.fft.fft(scipy.fft.fft(pupil, n=N, axis=1, workers=-1), n=N, axis=0, workers=-1)
    intensity = spectrum.real ** 2 + spectrum.imag ** 2   # zero angle at index 0
    del spectrum
    pix = _integrate_over_pixels(intensity, q, n_pix, fine, p)
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
                           pupil_samples=D / dxe, fine_step_rad=fine, max_phase_step_rad=step,
                           refinements=refinements, slope_rad=slope)
    return PixelPsf(pix, float(pixels_per_degree), sampling)


# --------------------------------------------------------------------------
# Geometric-optics PSF (where the wave-optics grid would be too large)
# --------------------------------------------------------------------------

_GEOMETRIC_PIECES_PER_PIXEL = 16       # quadrature pieces per pixel along the blur's main axis
_RAY_BUDGET = 16_000_000               # most rays traced for one PSF with higher-order terms
_RAY_FINE_LIMIT = 3072                 # largest sub-pixel grid (per side) the rays are deposited on
_RAY_COARSE_CELLS = 192                # pupil cells across the diameter where the gradient is evaluated


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


def _uniform_cdf(z: np.ndarray, w: np.ndarray) -> np.ndarray:
    """CDF at ``z`` of the uniform law on ``[-w, w]`` (a unit step at 0 where ``w == 0``)."""
    wide = w > 0.0
    return np.where(wide, np.clip((z + w) / (2.0 * np.where(wide, w, 1.0)), 0.0, 1.0), (z >= 0.0) * 1.0)


def _uniform_cdf_integral(z: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``int_-inf^z`` of :func:`_uniform_cdf` (``max(z, 0)`` where ``w == 0``)."""
    inner = (z + w) ** 2 / (4.0 * np.where(w > 0.0, w, 1.0))
    return np.where(z >= w, z, np.where(z <= -w, 0.0, inner))


def _trapezoid_cdf(z: np.ndarray, w: np.ndarray, d: np.ndarray) -> np.ndarray:
    """CDF at ``z`` of ``U[-w, w] + U[-d, d]`` (either width may be 0)."""
    moving = d > 1e-6
    dd = np.where(moving, d, 1.0)
    trapezoid = (_uniform_cdf_integral(z + dd, w) - _uniform_cdf_integral(z - dd, w)) / (2.0 * dd)
    out = np.where(moving, trapezoid, _uniform_cdf(z, w))
    return np.where(z >= w + d, 1.0, np.where(z < -(w + d), 0.0, out))


def _column_cdfs(col: np.ndarray, m: np.ndarray, c: np.ndarray, w: np.ndarray, d: np.ndarray,
                 n1: int, h2: int) -> np.ndarray:
    """``cdf[j, k] = sum over pieces in column j of m * F(e_k - c)`` at the pixel boundaries
    ``e_k = k - h2 - 1/2`` (``k = 0 .. 2 h2 + 1``), ``F`` = :func:`_trapezoid_cdf` with
    half-widths ``w`` and ``d`` (``d < 1/2``; supports inside ``(-h2 - 1/2, h2 + 1/2)``)."""
    n2 = 2 * h2 + 1
    ne = n2 + 1                                               # pixel boundaries e_k = k - h2 - 1/2
    off = h2 + 0.5
    edges = np.arange(ne, dtype=np.float64) - off
    size = n1 * (ne + 1)                                      # one spare slot per column: "above all"

    def binned(k: np.ndarray, weights: np.ndarray, keep: np.ndarray) -> np.ndarray:
        """Sum ``weights`` into (column, boundary ``k``) cells; shape (n1, ne + 1)."""
        k = np.clip(k, 0, ne)
        return np.bincount((col * (ne + 1) + k)[keep], weights[keep], minlength=size).reshape(n1, ne + 1)

    def at_edge(k: np.ndarray, values: np.ndarray, keep: np.ndarray) -> np.ndarray:
        keep = keep & (k >= 0) & (k < ne)
        return binned(k, values, keep)[:, :ne]

    def first_edge_at_or_above(x: np.ndarray) -> np.ndarray:
        return np.ceil(x + off).astype(np.int64)

    out = np.zeros((n1, ne))
    wide = w >= 0.5
    narrow = ~wide
    # Wide intervals: the uniform CDF is (ramp(z + w) - ramp(z - w)) / (2 w); sum the ramps.
    a1 = np.zeros((n1, ne + 1))
    a0 = np.zeros((n1, ne + 1))
    safe_w = np.where(wide, w, 1.0)
    for sign, start in ((1.0, c - w), (-1.0, c + w)):
        alpha = sign * m / (2.0 * safe_w)
        k = np.floor(start + off).astype(np.int64) + 1      # first boundary strictly above `start`
        a1 += binned(k, alpha, wide)
        a0 += binned(k, alpha * start, wide)
    out += edges[None, :] * np.cumsum(a1, axis=1)[:, :ne] - np.cumsum(a0, axis=1)[:, :ne]
    # ... and the trapezoid's corrections within d of each end: a window narrower than a pixel,
    # so at most one boundary, and (as 2 w >= 1) never the other end's boundary.
    for kink in (c - w, c + w):
        k = first_edge_at_or_above(kink - d)
        z = np.clip(k, 0, ne - 1) - off - c
        out += at_edge(k, m * (_trapezoid_cdf(z, w, d) - _uniform_cdf(z, w)), wide)
    # Narrow intervals (support under 1.2 pixels): a step of m above the support, exact values inside.
    top = first_edge_at_or_above(c + w + d)
    out += np.cumsum(binned(top, m, narrow), axis=1)[:, :ne]
    k0 = first_edge_at_or_above(c - w - d)
    for k in (k0, k0 + 1):
        z = np.clip(k, 0, ne - 1) - off - c
        out += at_edge(k, m * _trapezoid_cdf(z, w, d), narrow & (k < top))
    return out


def _sheared_disc_masses(l11: float, l21: float, l22: float,
                         pieces_per_px: int = _GEOMETRIC_PIECES_PER_PIXEL) -> np.ndarray:
    """Pixel masses of ``(a1, a2) = (l11 v1, l21 v1 + l22 v2)`` for ``(v1, v2)``
    uniform on the unit disc (``a`` in pixels, ``l11 > 0``, ``|l21| <= l11``).

    Given ``v1``, ``a2`` is uniform on ``l21 v1 +- |l22| sqrt(1 - v1^2)``, so
    its mass in each pixel along axis 2 is an exact interval overlap (a step
    when ``l22 = 0``: a line).  Along axis 1 the range of ``v1`` is cut into
    pieces (at every pixel boundary, and at ``sin`` of equal angles so that
    they are finer near the disc's rim, ``pieces_per_px`` per pixel) whose
    masses are exact (the marginal's CDF
    ``1/2 + (v sqrt(1 - v^2) + asin v) / pi``).  Within a piece the
    interval's centre moves linearly with ``v1`` (by at most
    ``1 / pieces_per_px`` pixel); taking ``v1`` as uniform within the piece,
    the law of ``a2`` is the interval at the piece's middle convolved with
    that motion (a trapezoid), whose CDF is evaluated exactly at the pixel
    boundaries, so a line crossing pixel rows is split between them
    correctly.  The sum over pieces of each column's CDF is accumulated in
    ``O(pieces + pixels)``: the piecewise-linear part as ramps by cumulative
    sums, the corrections near the interval's ends (at most two boundaries
    each) directly.  Returns ``(2 h2 + 1, 2 h1 + 1)`` masses indexed
    ``[a2, a1]``, centred, summing to 1.
    """
    l22 = abs(l22)
    h1 = int(math.ceil(l11 + 0.5))
    h2 = int(math.ceil(math.hypot(l21, l22) + 0.5))
    n1, n2 = 2 * h1 + 1, 2 * h2 + 1
    n_pieces = max(64, int(math.ceil(math.pi / 2 * pieces_per_px * 2.0 * l11)))
    v = np.sin(np.linspace(-math.pi / 2, math.pi / 2, n_pieces + 1))
    cuts = (np.arange(-h1, h1 + 1) + 0.5) / l11          # pixel boundaries a1 = i + 1/2
    v = np.unique(np.concatenate([v, cuts[np.abs(cuts) < 1.0], [-1.0, 1.0]]))
    cdf = 0.5 + (v * np.sqrt(np.maximum(1.0 - v * v, 0.0)) + np.arcsin(v)) / math.pi
    m = np.diff(cdf)
    mid = 0.5 * (v[1:] + v[:-1])
    col = np.clip(np.floor(l11 * mid + 0.5).astype(np.int64) + h1, 0, n1 - 1)
    c = l21 * mid                                             # centre of the interval along a2
    w = l22 * np.sqrt(np.maximum(1.0 - mid * mid, 0.0))       # its half-width
    d = 0.5 * abs(l21) * np.diff(v)                           # half the centre's motion over the piece
    return np.diff(_column_cdfs(col, m, c, w, d, n1, h2), axis=1).T


def _convolve_full(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Full 2-D linear convolution of two real arrays by FFT."""
    shape = (a.shape[0] + b.shape[0] - 1, a.shape[1] + b.shape[1] - 1)
    fshape = tuple(scipy.fft.next_fast_len(n, real=True) for n in shape)
    spec = scipy.fft.rfft2(a, fshape, workers=-1) * scipy.fft.rfft2(b, fshape, workers=-1)
    return scipy.fft.irfft2(spec, fshape, workers=-1)[:shape[0], :shape[1]]


def _pad_square(a: np.ndarray) -> np.ndarray:
    n = max(a.shape)
    out = np.zeros((n, n))
    r0, c0 = (n - a.shape[0]) // 2, (n - a.shape[1]) // 2
    out[r0:r0 + a.shape[0], c0:c0 + a.shape[1]] = a
    return out


def _sphero_cylinder_masses(pv: PowerVector, pupil_radius_mm: float, p: float) -> np.ndarray:
    """Geometric blur of a pure sphero-cylindrical error, integrated over display pixels.

    The wavefront ``W = -(M (x^2+y^2) + J0 (x^2-y^2) + 2 J45 x y) / 2`` (um, x
    and y in mm, OSA frame) sends the ray through pupil point ``r`` to the
    angle ``grad W = -P r`` (mrad) with ``P = [[M + J0, J45], [J45, M - J0]]``.
    On the display (columns right = ``-theta_x``, rows down = ``-theta_y``,
    as in the wave-optics path) the uniform pupil disc maps to the uniform
    ellipse ``(col, row) = B u``, ``B = P R 1e-3 / p``, ``u`` on the unit
    disc; ``B`` may be singular (a line or a point).  Since the disc is
    rotation-invariant, ``B u`` has the law of ``L v`` with ``L`` lower
    triangular along the axis of the longer row of ``B``
    (:func:`_sheared_disc_masses`).
    """
    P = np.array([[pv.M_D + pv.J0_D, pv.J45_D], [pv.J45_D, pv.M_D - pv.J0_D]])
    B = P * (pupil_radius_mm * 1e-3 / p)          # pixels per unit pupil radius
    norms = np.hypot(B[:, 0], B[:, 1])
    if norms.max() < 1e-9:
        return np.ones((1, 1))
    first = int(np.argmax(norms))                  # 0: quadrature along columns, 1: along rows
    b1, b2 = B[first], B[1 - first]
    l11 = float(norms[first])
    e1 = b1 / l11
    e2 = np.array([-e1[1], e1[0]])
    masses = _sheared_disc_masses(l11, float(b2 @ e1), float(b2 @ e2))   # [other axis, first axis]
    grid = masses if first == 0 else masses.T     # [row, col]
    return _pad_square(grid)


def _ray_traced_masses(eye: EyeRx, pv: PowerVector, p: float) -> tuple[np.ndarray, int, int]:
    """Geometric blur with higher-order terms: rays traced through the pupil.

    The transverse ray aberration is the wavefront gradient: the ray through
    pupil point ``(x, y)`` lands at angle ``grad W(x, y)`` (um/mm = mrad),
    drawn on the display as in :func:`_sphero_cylinder_masses`.  The gradient
    is evaluated (central differences) at the corners of 192 x 192 pupil cells
    and interpolated bilinearly to ``s x s`` rays per cell, ``s`` chosen so
    neighbouring rays land at most half a sub-pixel apart (at most 16 M rays);
    each ray carries equal weight and is shared bilinearly between the four
    nearest cells of a grid 3 times finer than the display pixel (1 time
    where that grid would exceed 3072 per side), which is then summed over
    each pixel.  Returns (masses (n, n) centred, sub-pixels per pixel, rays
    across the pupil).
    """
    radius = eye.pupil_diameter_mm / 2.0
    nc = _RAY_COARSE_CELLS
    hc = 2.0 * radius / nc
    c = np.linspace(-radius, radius, nc + 1)
    X, Y = np.meshgrid(c, c)                       # rows: y ascending, columns: x ascending (OSA)
    eps = 1e-3 * hc
    gx = (wavefront_um(eye, pv, X + eps, Y) - wavefront_um(eye, pv, X - eps, Y)) / (2.0 * eps)
    gy = (wavefront_um(eye, pv, X, Y + eps) - wavefront_um(eye, pv, X, Y - eps)) / (2.0 * eps)
    col = -gx * 1e-3 / p                           # display columns go to -theta_x
    row = -gy * 1e-3 / p                           # display rows go to -theta_y
    mid = 0.5 * (c[1:] + c[:-1])
    MX, MY = np.meshgrid(mid, mid)
    touch = np.hypot(MX, MY) <= radius + hc * 0.7072    # cells that reach into the pupil
    iy, ix = np.nonzero(touch)
    corners_c = np.stack([col[iy, ix], col[iy, ix + 1], col[iy + 1, ix], col[iy + 1, ix + 1]])
    corners_r = np.stack([row[iy, ix], row[iy, ix + 1], row[iy + 1, ix], row[iy + 1, ix + 1]])
    half = int(math.ceil(max(np.abs(corners_c).max(), np.abs(corners_r).max()) + 1.0))
    n_pix = 2 * half + 1
    q = 3 if 3 * n_pix <= _RAY_FINE_LIMIT else 1
    nf = n_pix * q
    spread = max(np.ptp(corners_c, axis=0).max(), np.ptp(corners_r, axis=0).max()) * q   # sub-pixels per cell
    s_max = max(2, int(math.sqrt(_RAY_BUDGET / iy.size)))
    s = int(min(max(math.ceil(2.0 * spread), 2), s_max))
    t = (np.arange(s) + 0.5) / s
    x0, y0 = c[ix], c[iy]
    fine = np.zeros(nf * nf)
    centre = (nf - 1) / 2.0
    batch_c: list[np.ndarray] = []
    batch_r: list[np.ndarray] = []
    pending = 0

    def deposit() -> None:
        fc = np.concatenate(batch_c) * q + centre
        fr = np.concatenate(batch_r) * q + centre
        i0 = np.floor(fc).astype(np.int64)
        j0 = np.floor(fr).astype(np.int64)
        wc = fc - i0
        wr = fr - j0
        base = j0 * nf + i0
        n = nf * nf
        fine[:] += np.bincount(base, (1 - wc) * (1 - wr), minlength=n)
        fine[:] += np.bincount(base + 1, wc * (1 - wr), minlength=n)
        fine[:] += np.bincount(base + nf, (1 - wc) * wr, minlength=n)
        fine[:] += np.bincount(base + nf + 1, wc * wr, minlength=n)
        batch_c.clear()
        batch_r.clear()

    for ty in t:
        for tx in t:
            inside = (x0 + tx * hc) ** 2 + (y0 + ty * hc) ** 2 <= radius * radius
            w00, w01, w10, w11 = (1 - tx) * (1 - ty), tx * (1 - ty), (1 - tx) * ty, tx * ty
            cc = w00 * corners_c[0] + w01 * corners_c[1] + w10 * corners_c[2] + w11 * corners_c[3]
            rr = w00 * corners_r[0] + w01 * corners_r[1] + w10 * corners_r[2] + w11 * corners_r[3]
            batch_c.append(cc[inside])
            batch_r.append(rr[inside])
            pending += int(inside.sum())
            if pending > 1_000_000:
                deposit()
                pending = 0
    if batch_c:
        deposit()
    masses = fine.reshape(n_pix, q, n_pix, q).sum(axis=(1, 3))
    return masses / masses.sum(), q, nc * s


def half_energy_radius_px(masses: np.ndarray) -> float:
    """Radius (pixels, from the centre pixel) of the circle holding half of ``masses``'
    energy, each pixel's mass taken at its centre and the cumulative energy
    interpolated linearly in radius (a pixel-resolution estimate)."""
    n = masses.shape[0]
    c = n // 2
    yy, xx = np.mgrid[:n, :n]
    r = np.hypot(xx - c, yy - c).ravel()
    order = np.argsort(r, kind="stable")
    cum = np.cumsum(masses.ravel()[order])
    return float(np.interp(0.5 * cum[-1], cum, r[order]))


def geometric_error_estimate(wavelength_nm: float, pupil_diameter_mm: float, blur_r50_rad: float) -> float:
    """Estimated relative error of the geometric-optics PSF.

    The ratio of the diffraction blur, the Airy disc's diameter
    ``2.44 lambda / D``, to the geometric blur's size, the diameter of the
    circle holding half its energy (``2 blur_r50_rad``; for a uniform disc
    of radius ``a`` that is ``sqrt(2) a``).  Geometric optics leaves out
    interference (the ripples of the defocused wave PSF, the diffraction
    structure of caustics); their effect on the blur's size, relative to it,
    is of this order or less.  Checked in ``tests/test_optics_geometric.py``
    against wave-optics PSFs where both are feasible (3 to 20 waves of
    aberration): the radii holding half the energy agreed to 0.2-1.3 %, at
    most 0.55 of this estimate.  Infinite for no geometric blur.
    """
    if not blur_r50_rad > 0.0:
        return math.inf
    return diffraction_blur_rad(wavelength_nm, pupil_diameter_mm) / (2.0 * blur_r50_rad)


def geometric_psf_pixels(eye: EyeRx, pv: PowerVector, wavelength_nm: float, pixels_per_degree: float,
                         options: OpticsOptions = OpticsOptions(), *, wave_grid_needed: int = 0) -> PixelPsf:
    """Monochromatic PSF by geometric optics, integrated over pixels, with the Airy core.

    For a wavefront so steep that a wave-optics pupil grid would be too large
    the defocus blur is many times the diffraction blur and geometric optics
    is accurate.  The PSF is the pupil's ray-traced blur patch integrated
    exactly over display pixels, convolved with the Airy pattern of the pupil
    at this wavelength (:func:`airy_pixels`, also pixel-integrated), clipped
    at 0 and normalised to sum 1.

    * Pure sphero-cylinder (no higher-order terms): the blur patch is the
      uniform pupil disc mapped through the power matrix, an ellipse,
      possibly degenerate (a line or a point), integrated over pixels
      semi-analytically (:func:`_sphero_cylinder_masses`).
    * With higher-order terms: rays traced to ``grad W``
      (:func:`_ray_traced_masses`).

    Orientation and centre are those of :func:`psf_pixels`: rows down and
    columns right as the subject sees the display (the OSA frame mirrored in
    x), zero angle on the centre pixel.  The diffraction is applied at pixel
    resolution (the blur's pixel masses convolved with the pixel-integrated
    Airy pattern), which widens it by up to one pixel's box; that matters only
    where the Airy pattern is not small against the blur.

    Parameters
    ----------
    eye, pv, wavelength_nm, pixels_per_degree, options
        As for :func:`psf_pixels`.
    wave_grid_needed
        The wave-optics grid (per side) this PSF replaces, recorded in its
        sampling; 0 when geometric optics was asked for directly.

    Returns
    -------
    PixelPsf
        ``sampling.model == "geometric"``; ``sampling.model_error_estimate``
        from :func:`geometric_error_estimate`.

    Raises
    ------
    ModelLimitError
        If the blur would need more than ``options.max_grid`` pixels per side.
    """
    if not (300.0 <= wavelength_nm <= 1000.0):
        raise ValidationError("wavelength_nm", wavelength_nm, "300 to 1000 nm")
    if not (1.0 <= pixels_per_degree <= 500.0):
        raise ValidationError("pixels_per_degree", pixels_per_degree, "1 to 500")
    p = pixel_angle_rad(pixels_per_degree)
    D = eye.pupil_diameter_mm
    slope = max_wavefront_slope_rad(eye, pv)
    needed = 2 * int(math.ceil(slope / p + 2.0)) + 1
    if needed > options.max_grid:
        raise ModelLimitError(
            f"the geometric PSF at {wavelength_nm:.0f} nm would be {needed}x{needed} pixels (limit "
            f"{options.max_grid}): the blur ({max_meridian_power_D(pv):.1f} D over a {D:g} mm pupil) is too wide "
            f"for {pixels_per_degree:g} pixels per degree; use a smaller pupil_diameter_mm or a lower "
            f"pixels_per_degree")
    has_ho = eye.higher_order is not None and bool(eye.higher_order.coefficients_um)
    if has_ho:
        blur, q, rays = _ray_traced_masses(eye, pv, p)
    else:
        blur, q, rays = _sphero_cylinder_masses(pv, D / 2.0, p), 1, 0
    airy = airy_pixels(wavelength_nm, D, pixels_per_degree)
    pix = _convolve_full(blur, airy)
    np.maximum(pix, 0.0, out=pix)
    total = pix.sum()
    if not (total > 0 and math.isfinite(total)):
        raise ModelLimitError("geometric PSF computation produced no energy")
    pix = np.ascontiguousarray(pix / total)
    sampling = PsfSampling(wavelength_nm=float(wavelength_nm), oversample=q, grid=0, pupil_samples=float(rays),
                           fine_step_rad=p / q, max_phase_step_rad=math.nan, refinements=0, slope_rad=slope,
                           model="geometric",
                           model_error_estimate=geometric_error_estimate(
                               wavelength_nm, D, half_energy_radius_px(blur) * p),
                           wave_grid_needed=int(wave_grid_needed))
    return PixelPsf(pix, float(pixels_per_degree), sampling)


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


def depth_of_focus_D(pupil_diameter_mm: float, pixels_per_degree: float) -> float:
    """Half-width of the eye's depth of focus at this display (D).

    A blur disc is invisible on this display when its angular diameter is
    below the larger of one display pixel and the eye's 1 arcmin acuity limit;
    the geometric blur diameter of a defocus ``F`` (D) through a pupil of
    diameter ``D`` (m) is ``F * D`` radians.
    """
    tol = max(pixel_angle_rad(pixels_per_degree), ARCMIN_RAD)
    return tol / (pupil_diameter_mm * 1e-3)


def diffraction_blur_rad(wavelength_nm: float, pupil_diameter_mm: float) -> float:
    """Diameter of the Airy disc's first dark ring (radians)."""
    return 2.44 * wavelength_nm * 1e-9 / (pupil_diameter_mm * 1e-3)
