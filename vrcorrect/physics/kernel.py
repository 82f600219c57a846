"""The eye's colour kernel ``K[lms, primary, y, x]``.

``K[k, c] = sum_lambda cone_k(lambda) spd_c(lambda) PSF_lambda`` so that the
spatial sum of ``K[k, c]`` equals the RGB->LMS matrix ``A[k, c]``
(:func:`vrcorrect.physics.perception.rgb_to_lms_matrix`).  The retinal image of a
linear RGB image ``x`` is ``r_k = sum_c K[k, c] * x_c`` (true convolution).

What the kernel models follows what the eye and display need, and every
decision is recorded in :attr:`EyeKernel.report`
(:class:`~vrcorrect.physics.kernel_report.KernelReport`;
:func:`~vrcorrect.physics.kernel_report.explain` puts it in words):

* **Identity path.**  When the residual refractive error over the spectrally
  significant band (including chromatic aberration) is inside the eye's depth
  of focus at this display and diffraction is below the same limit, the kernel
  is the 1x1 matrix ``A`` and no convolution happens.
* **Wavelength step.**  PSFs are computed at nodes ``390 + i h`` nm and the
  1 nm spectral weights are integrated against linear "hat" interpolants
  between nodes, so every step preserves ``A`` exactly and only the PSF's
  variation with wavelength is approximated.  Steps 80, 40, 20, 10, 5, 1 nm
  are nested; the error of step ``h`` against the 1 nm kernel is estimated
  by Richardson extrapolation (the quadrature error falls as ``h^2``, so
  ``err(h) ~ |K_2h - K_h| / 3``; tests check it against real 1 nm kernels), in
  the norm ``max_k sum_c sum_xy |dK[k, c]|`` - a bound on the change of any
  retinal cone response of an image in [0, 1].  The coarsest step whose
  estimate is below the tolerance is used.
* **Kernel size.**  The smallest odd window holding ``energy_fraction`` of the
  energy of every cone's kernel; the crop is renormalised so the spatial sums
  still equal ``A``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..plumbing.errors import ValidationError
from ..specs.display import DisplayProfile
from ..specs.prescription import EyeRx
from .kernel_report import (PSF_GRID_FITS, PSF_GRID_TOO_LARGE, PSF_OPTION, PSF_PHASE_UNRESOLVED, STEP_FINEST,
                            STEP_FORCED, STEP_WITHIN_TOLERANCE, FocusCheck, KernelReport, NodePsf, StepTrial, Viewing,
                            WavelengthStep)
from .options import OpticsOptions
from .perception import INTEGRATION_GRID_NM, normalised_weights
from .psf import psf_pixels
from .refraction import ARCMIN_RAD, RefractiveState, depth_of_focus_D, max_meridian_power_D, refractive_state
from .sampling import PixelPsf, PsfSampling, crop_center, energy_size, pixel_angle_rad
from .wave_psf import diffraction_blur_rad

STEPS_NM = (80, 40, 20, 10, 5, 1)
NODE_ORIGIN_NM = 390.0


@dataclass(frozen=True)
class KernelOptions:
    """How an eye's kernel is built.

    Attributes
    ----------
    energy_fraction
        Fraction of each cone kernel's energy the cropped kernel keeps (0.5..1).
    wavelength_tolerance
        Largest accepted error of the wavelength quadrature against 1 nm steps,
        as a bound on any retinal cone response per unit white (default 1/255).
    wavelength_step_nm
        Force one step (one of 80, 40, 20, 10, 5, 1) instead of choosing.
    identity_path
        Allow the no-convolution path for an eye in focus at this display.
    optics
        Optical model options.
    """

    energy_fraction: float = 0.995
    wavelength_tolerance: float = 1.0 / 255.0
    wavelength_step_nm: int | None = None
    identity_path: bool = True
    optics: OpticsOptions = field(default_factory=OpticsOptions)

    def __post_init__(self) -> None:
        if not (0.5 < self.energy_fraction <= 1.0):
            raise ValidationError("energy_fraction", self.energy_fraction, "a fraction in (0.5, 1]")
        if not (0.0 < self.wavelength_tolerance < 1.0):
            raise ValidationError("wavelength_tolerance", self.wavelength_tolerance, "a number in (0, 1)")
        if self.wavelength_step_nm is not None and self.wavelength_step_nm not in STEPS_NM:
            raise ValidationError("wavelength_step_nm", self.wavelength_step_nm,
                                  "one of " + ", ".join(map(str, STEPS_NM)) + " nm")


@dataclass(frozen=True, eq=False)
class EyeKernel:
    """A built kernel and the decisions that shaped it (``report``; in words:
    :func:`~vrcorrect.physics.kernel_report.explain`)."""

    kernel: np.ndarray                 # (3 cones, 3 primaries, s, s) float64
    matrix: np.ndarray                 # (3, 3) RGB -> LMS, = kernel.sum((2, 3))
    pixels_per_degree: float
    identity: bool
    wavelength_step_nm: int | None
    node_wavelengths_nm: tuple[float, ...]
    reference_wavelength_nm: float
    state: RefractiveState
    report: KernelReport

    @property
    def size(self) -> int:
        return int(self.kernel.shape[-1])

    @property
    def cone_kernels(self) -> np.ndarray:
        """Kernels for an achromatic (grey) input: ``sum_c K[k, c]``, shape (3, s, s)."""
        return self.kernel.sum(axis=1)


def significant_band_nm(weights: np.ndarray, wavelength_nm: np.ndarray = INTEGRATION_GRID_NM,
                        tail: float = 0.005) -> tuple[float, float]:
    """Wavelength band holding all but ``tail`` (at each end) of every cone-primary weight."""
    lo, hi = math.inf, -math.inf
    flat = weights.reshape(-1, weights.shape[-1])
    for row in flat:
        total = row.sum()
        if total <= 0:
            continue
        cum = np.cumsum(row) / total
        lo = min(lo, float(wavelength_nm[np.searchsorted(cum, tail)]))
        hi = max(hi, float(wavelength_nm[min(np.searchsorted(cum, 1.0 - tail), len(cum) - 1)]))
    return lo, hi


def hat_weights(weights: np.ndarray, step_nm: int,
                wavelength_nm: np.ndarray = INTEGRATION_GRID_NM) -> tuple[np.ndarray, np.ndarray]:
    """Integrate 1 nm spectral weights against linear hats on nodes ``390 + i*step``.

    Returns ``(nodes_nm, W)`` with ``W`` of shape ``(3, 3, n_nodes)``; nodes
    with no weight are dropped.  ``W.sum(-1) == weights.sum(-1)`` exactly
    (the hats form a partition of unity).
    """
    last = NODE_ORIGIN_NM + step_nm * math.ceil((wavelength_nm[-1] - NODE_ORIGIN_NM) / step_nm)
    nodes = np.arange(NODE_ORIGIN_NM, last + 0.5, step_nm, dtype=np.float64)
    hats = np.clip(1.0 - np.abs(wavelength_nm[None, :] - nodes[:, None]) / step_nm, 0.0, None)
    W = np.einsum("kcn,in->kci", weights, hats)
    keep = W.reshape(9, -1).sum(axis=0) > 1e-12 * W.sum()
    return nodes[keep], W[:, :, keep]


def _kernel_norm(dk: np.ndarray) -> float:
    """max over cones of sum over primaries and pixels of |dK|."""
    return float(np.abs(dk).sum(axis=(1, 2, 3)).max())


def build_kernel(eye: EyeRx, display: DisplayProfile, options: KernelOptions | None = None,
                 progress: Callable[[int, int], None] | None = None) -> EyeKernel:
    """Build the colour kernel of ``eye`` looking at ``display``.

    Parameters
    ----------
    eye
        One eye's prescription.
    display
        Display profile (spectra, pixels per degree, distance).
    options
        Build options; defaults are the product's.
    progress
        Optional callback ``progress(done, total)`` called after each PSF.

    Returns
    -------
    EyeKernel
    """
    options = options or KernelOptions()
    opt = options.optics
    ppd = display.pixels_per_degree
    distance = display.distance_m if opt.viewing_distance_m is None else opt.viewing_distance_m
    state = refractive_state(eye, distance)
    weights = normalised_weights(display.primaries)
    A = weights.sum(axis=2)
    viewing = Viewing(distance_m=distance, vergence_D=state.vergence_D,
                      accommodation_used_D=state.accommodation_used_D, accommodation_D=eye.accommodation_D,
                      accommodative_lag_D=eye.accommodative_lag_D)

    band = significant_band_nm(weights)
    worst = max(max_meridian_power_D(state.at_wavelength(lam, opt))
                for lam in (band[0], band[1], opt.reference_wavelength_nm))
    dof = depth_of_focus_D(eye.pupil_diameter_mm, ppd)
    blur_limit = max(pixel_angle_rad(ppd), ARCMIN_RAD)
    diffraction = diffraction_blur_rad(band[1], eye.pupil_diameter_mm)
    has_ho = eye.higher_order is not None and bool(eye.higher_order.coefficients_um)
    in_focus = worst <= dof and diffraction <= blur_limit and not has_ho
    focus = FocusCheck(reference_wavelength_nm=opt.reference_wavelength_nm, residual=state.residual,
                       residual_worst_meridian_D=max_meridian_power_D(state.residual),
                       chromatic_aberration=opt.chromatic_aberration, band_nm=band, worst_meridian_D=worst,
                       depth_of_focus_D=dof, blur_limit_rad=blur_limit, pupil_diameter_mm=eye.pupil_diameter_mm,
                       diffraction_blur_rad=diffraction, higher_order=has_ho, in_focus=in_focus)

    def report(**kw) -> KernelReport:
        return KernelReport(pixels_per_degree=ppd, viewing=viewing, focus=focus, identity_path=options.identity_path,
                            energy_fraction=options.energy_fraction, psf_model=opt.psf_model, max_grid=opt.max_grid,
                            **kw)

    if in_focus and options.identity_path:
        return EyeKernel(kernel=A[:, :, None, None].copy(), matrix=A, pixels_per_degree=ppd, identity=True,
                         wavelength_step_nm=None, node_wavelengths_nm=(), state=state,
                         reference_wavelength_nm=opt.reference_wavelength_nm,
                         report=report(identity=True, energy_held=1.0, kernel_size_px=1, computed_field_px=None,
                                       wavelength=None, psfs=()))

    psfs: dict[float, PixelPsf] = {}

    def psf_at(lam: float) -> PixelPsf:
        if lam not in psfs:
            psfs[lam] = psf_pixels(eye, state.at_wavelength(lam, opt), lam, ppd, opt)
            if progress is not None:
                progress(len(psfs), -1)
        return psfs[lam]

    def kernel_for(step: int) -> tuple[np.ndarray, np.ndarray]:
        nodes, W = hat_weights(weights, step)
        stack = [psf_at(float(lam)).values for lam in nodes]
        size = max(p.shape[0] for p in stack)
        P = np.stack([crop_center(p, size) for p in stack])
        return np.einsum("kci,iyx->kcyx", W, P), nodes

    steps = (options.wavelength_step_nm,) if options.wavelength_step_nm else STEPS_NM
    chosen: int | None = None
    reason = STEP_WITHIN_TOLERANCE
    previous: np.ndarray | None = None
    trials: list[StepTrial] = []
    K = nodes = None
    for step in steps:
        K, nodes = kernel_for(step)
        if options.wavelength_step_nm:
            chosen, reason = step, STEP_FORCED
            break
        if step == 1:
            chosen, reason = 1, STEP_FINEST
            break
        if previous is not None:
            size = max(previous.shape[-1], K.shape[-1])
            estimate = _kernel_norm(crop_center(previous, size) - crop_center(K, size)) / 3.0
            trials.append(StepTrial(step, estimate))
            if estimate <= options.wavelength_tolerance:
                chosen = step
                break
        previous = K
    assert K is not None and nodes is not None and chosen is not None
    # The kernel's PSFs: the chosen step's nodes.  Choosing the step may have computed more (a coarser
    # step's node that this step skips, such as 790 nm beyond a 10 nm step's 780 nm); the report's nodes
    # are the kernel's, and it says how many were computed in all.
    grid = np.arange(nodes[0], nodes[-1] + 0.5, chosen)
    skipped = [float(lam) for lam in grid if not np.isclose(nodes, lam).any()]
    wavelength = WavelengthStep(step_nm=chosen, reason=reason, tolerance=options.wavelength_tolerance,
                                trials=tuple(trials), nodes_nm=tuple(float(x) for x in nodes),
                                left_out_nm=tuple(skipped), psfs_computed=len(psfs),
                                max_fft_grid=max((p.sampling.grid for p in psfs.values()), default=0))

    full = K.shape[-1]
    cones = K.sum(axis=1)
    size = energy_size(cones, options.energy_fraction)
    held = float((crop_center(cones, size).sum(axis=(1, 2)) / cones.sum(axis=(1, 2))).min())
    K = crop_center(K, size).copy()
    sums = K.sum(axis=(2, 3))
    scale = np.where(sums > 0, A / np.where(sums > 0, sums, 1.0), 0.0)
    K *= scale[:, :, None, None]

    used = [psfs[float(lam)].sampling for lam in nodes]
    node_psfs = tuple(NodePsf(s.wavelength_nm, s.model, _model_reason(s, opt.max_grid), s) for s in used)
    return EyeKernel(kernel=K, matrix=A, pixels_per_degree=ppd, identity=False, wavelength_step_nm=chosen,
                     node_wavelengths_nm=tuple(float(x) for x in nodes), state=state,
                     reference_wavelength_nm=opt.reference_wavelength_nm,
                     report=report(identity=False, energy_held=held, kernel_size_px=size, computed_field_px=full,
                                   wavelength=wavelength, psfs=node_psfs))


def _model_reason(sampling: PsfSampling, max_grid: int) -> str:
    """Why a PSF has its model (:data:`~vrcorrect.physics.kernel_report.PSF_GRID_FITS` and so on), from
    what its sampling recorded (:func:`vrcorrect.physics.psf.psf_pixels` chose)."""
    if sampling.model != "geometric":
        return PSF_GRID_FITS
    if sampling.wave_grid_needed == 0:
        return PSF_OPTION
    return PSF_GRID_TOO_LARGE if sampling.wave_grid_needed > max_grid else PSF_PHASE_UNRESOLVED


def monochromatic_psf(eye: EyeRx, display: DisplayProfile, wavelength_nm: float,
                      options: KernelOptions | None = None) -> tuple[np.ndarray, PixelPsf, RefractiveState]:
    """The eye's PSF at one wavelength on the display's pixel grid, cropped to
    ``options.energy_fraction`` of its energy and renormalised to sum 1."""
    options = options or KernelOptions()
    opt = options.optics
    distance = display.distance_m if opt.viewing_distance_m is None else opt.viewing_distance_m
    state = refractive_state(eye, distance)
    psf = psf_pixels(eye, state.at_wavelength(wavelength_nm, opt), wavelength_nm, display.pixels_per_degree, opt)
    size = energy_size(psf.values, options.energy_fraction)
    cropped = crop_center(psf.values, size).copy()
    return cropped / cropped.sum(), psf, state


def build_reference_kernel(eye: EyeRx, display: DisplayProfile, options: KernelOptions | None = None) -> EyeKernel:
    """Kernel of the same eye wearing its glasses, focused on the display.

    Sphere and cylinder are fully corrected (residual zero at the reference
    wavelength); the pupil, higher-order terms, chromatic aberration and
    diffraction remain - glasses do not remove them.  This is what "a sharp
    eye would see", the target of the product's corrections.
    """
    options = options or KernelOptions()
    corrected = dataclasses.replace(eye, sphere_D=0.0, cylinder_D=0.0, axis_deg=0.0, accommodation_D=0.0,
                                    accommodative_lag_D=0.0)
    optics = dataclasses.replace(options.optics, viewing_distance_m=math.inf)
    return build_kernel(corrected, display, dataclasses.replace(options, optics=optics))
