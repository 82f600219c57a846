"""The eye's PSF at one wavelength on the display's pixel grid: which model makes it.

Two models compute the same thing, the pupil's point-spread function integrated over display pixels
(odd-sized float64 array in display coordinates, centred on its middle pixel, summing to 1;
docs/architecture.md, 'Physics conventions', 'PSF'):

* wave optics (:mod:`.wave_psf`): the FFT of the pupil function, exact up to sampling, whose pupil
  grid grows with the wavefront's slope;
* geometric optics (:mod:`.geometric_psf`): the ray-traced blur convolved with the Airy pattern,
  accurate where the blur is many diffraction widths wide.

:func:`psf_pixels` chooses per wavelength by ``OpticsOptions.psf_model``: ``"auto"`` takes wave
optics wherever its grid fits in ``OpticsOptions.max_grid`` (:func:`~.wave_psf.pupil_grid`) and
geometric optics where it would not; ``"wave"`` refuses there instead; ``"geometric"`` always takes
geometric optics.  ``PsfSampling.model`` records the choice, ``PsfSampling.wave_grid_needed`` why.
"""

from __future__ import annotations

from ..specs.prescription import EyeRx, PowerVector
from .geometric_psf import geometric_psf_pixels
from .options import OpticsOptions
from .sampling import PixelPsf, check_psf_request
from .wave_psf import pupil_grid, wave_psf_pixels


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
        :func:`~vrcorrect.physics.sampling.crop_to_energy`).  ``sampling.model``
        says which model made it.

    Notes
    -----
    Wave optics (FFT of the pupil function) wherever its pupil grid fits in
    ``options.max_grid``.  Where it would not, the wavefront is so steep that
    the defocus blur is many times the diffraction blur, and (with
    ``options.psf_model == "auto"``) the PSF comes from geometric optics,
    :func:`~vrcorrect.physics.geometric_psf.geometric_psf_pixels`;
    ``options.psf_model == "wave"`` refuses there instead.

    Raises
    ------
    ModelLimitError
        Wave optics only and the grid would not fit; or the geometric PSF's
        pixel array would exceed ``options.max_grid`` per side.
    """
    check_psf_request(wavelength_nm, pixels_per_degree)
    if options.psf_model == "geometric":
        return geometric_psf_pixels(eye, pv, wavelength_nm, pixels_per_degree, options)
    grid = pupil_grid(eye, pv, wavelength_nm, pixels_per_degree, options)
    if grid.fits or options.psf_model == "wave":
        return wave_psf_pixels(eye, pv, wavelength_nm, pixels_per_degree, options, grid=grid)  # refuses unfit
    # Too steep for a wave-optics grid: the blur is many diffraction widths wide here.
    return geometric_psf_pixels(eye, pv, wavelength_nm, pixels_per_degree, options, wave_grid_needed=grid.grid)
