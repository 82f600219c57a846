"""The optical model's settings, :class:`OpticsOptions`, shared by every module that models the eye's
optics: the refraction (chromatic aberration and its reference wavelength, the viewing distance),
the wave- and geometric-optics PSFs (their sampling and grid limit) and the chooser between them
(``psf_model``).

Units (docs/architecture.md, 'Physics conventions'): wavelengths in nm, distances in metres, grid
sizes in samples per side.  The prescription holds at the reference wavelength, 555 nm by default,
the peak of photopic sensitivity V(lambda).
"""

from __future__ import annotations

from dataclasses import dataclass

from ..plumbing.errors import ValidationError

DEFAULT_REFERENCE_WAVELENGTH_NM = 555.0
PSF_MODELS = ("auto", "wave", "geometric")


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
        integration (:func:`.sampling.integrate_over_pixels`) is exact.
    min_pupil_samples
        Minimum samples across the pupil (sets the angular field that holds
        diffraction tails).
    max_grid
        Largest wave-optics FFT grid (per side).  Where the pupil grid a steep
        wavefront needs would be larger, the PSF is modelled by geometric
        optics instead (:mod:`.geometric_psf`); the same number
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

