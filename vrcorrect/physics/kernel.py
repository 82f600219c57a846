"""The eye's colour kernel ``K[lms, primary, y, x]``.

``K[k, c] = sum_lambda cone_k(lambda) spd_c(lambda) PSF_lambda`` so that the
spatial sum of ``K[k, c]`` equals the RGB->LMS matrix ``A[k, c]``
(:func:`vrcorrect.physics.perception.rgb_to_lms_matrix`).  The retinal image of a
linear RGB image ``x`` is ``r_k = sum_c K[k, c] * x_c`` (true convolution).

What the kernel models follows what the eye and display need, and every
decision is recorded in :attr:`EyeKernel.decisions`:

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
from .optics import (
    ARCMIN_RAD,
    OpticsOptions,
    PixelPsf,
    RefractiveState,
    crop_center,
    depth_of_focus_D,
    diffraction_blur_rad,
    energy_size,
    max_meridian_power_D,
    pixel_angle_rad,
    psf_pixels,
    refractive_state,
)
from .perception import INTEGRATION_GRID_NM, normalised_weights

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
    """A built kernel and the decisions that shaped it."""

    kernel: np.ndarray                 # (3 cones, 3 primaries, s, s) float64
    matrix: np.ndarray                 # (3, 3) RGB -> LMS, = kernel.sum((2, 3))
    pixels_per_degree: float
    identity: bool
    wavelength_step_nm: int | None
    node_wavelengths_nm: tuple[float, ...]
    reference_wavelength_nm: float
    state: RefractiveState
    decisions: tuple[str, ...]
    info: dict

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
    decisions: list[str] = []
    info: dict = {"pixels_per_degree": ppd, "distance_m": distance,
                  "reference_wavelength_nm": opt.reference_wavelength_nm,
                  "chromatic_aberration": opt.chromatic_aberration,
                  "energy_fraction": options.energy_fraction,
                  "wavelength_tolerance": options.wavelength_tolerance}

    dist_txt = "infinity" if math.isinf(distance) else f"{distance:.2f} m"
    decisions.append(
        f"viewing distance {dist_txt} -> vergence {state.vergence_D:.2f} D; accommodation used "
        f"{state.accommodation_used_D:.2f} of {eye.accommodation_D:.2f} D")
    r = state.residual
    decisions.append(
        f"residual refraction at {opt.reference_wavelength_nm:.0f} nm: M {r.M_D:+.2f} D, J0 {r.J0_D:+.2f} D, "
        f"J45 {r.J45_D:+.2f} D (worst meridian {max_meridian_power_D(r):.2f} D); chromatic aberration "
        f"{'on (Thibos 1992)' if opt.chromatic_aberration else 'off'}")

    band = significant_band_nm(weights)
    worst = max(max_meridian_power_D(state.at_wavelength(lam, opt))
                for lam in (band[0], band[1], opt.reference_wavelength_nm))
    dof = depth_of_focus_D(eye.pupil_diameter_mm, ppd)
    blur_limit = max(pixel_angle_rad(ppd), ARCMIN_RAD)
    diffraction = diffraction_blur_rad(band[1], eye.pupil_diameter_mm)
    has_ho = eye.higher_order is not None and bool(eye.higher_order.coefficients_um)
    in_focus = worst <= dof and diffraction <= blur_limit and not has_ho
    info.update(band_nm=list(band), depth_of_focus_D=dof, worst_meridian_D=worst)
    decisions.append(
        f"depth of focus +-{dof:.3f} D ({math.degrees(blur_limit) * 60:.2f} arcmin blur limit, "
        f"{eye.pupil_diameter_mm:g} mm pupil); worst meridian over {band[0]:.0f}-{band[1]:.0f} nm is "
        f"{worst:.3f} D, diffraction blur {math.degrees(diffraction) * 60:.2f} arcmin"
        + (", higher-order terms present" if has_ho else ""))

    if in_focus and options.identity_path:
        decisions.append("identity path: the eye is in focus at this display; no convolution (kernel 1x1 = A)")
        info.update(identity=True, kernel_size=1, wavelength_step_nm=None, nodes_nm=[])
        return EyeKernel(kernel=A[:, :, None, None].copy(), matrix=A, pixels_per_degree=ppd, identity=True,
                         wavelength_step_nm=None, node_wavelengths_nm=(), state=state,
                         reference_wavelength_nm=opt.reference_wavelength_nm,
                         decisions=tuple(decisions), info=info)
    decisions.append("convolution needed: the eye is out of focus at this display"
                     if not in_focus else "identity path disabled by option")

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
    previous: np.ndarray | None = None
    trail: list[str] = []
    K = nodes = None
    estimate = None
    for step in steps:
        K, nodes = kernel_for(step)
        if options.wavelength_step_nm:
            chosen = step
            trail.append(f"{step} nm forced by option")
            break
        if step == 1:
            chosen = 1
            trail.append("1 nm is the reference itself")
            break
        if previous is not None:
            size = max(previous.shape[-1], K.shape[-1])
            estimate = _kernel_norm(crop_center(previous, size) - crop_center(K, size)) / 3.0
            trail.append(f"{step} nm: estimated error {estimate:.4f}")
            if estimate <= options.wavelength_tolerance:
                chosen = step
                break
        previous = K
    assert K is not None and nodes is not None and chosen is not None
    # The kernel's PSFs: the chosen step's nodes.  Choosing the step may have computed more (a coarser
    # step's node that this step skips, such as 790 nm beyond a 10 nm step's 780 nm); every count and
    # range below is of the kernel's, and the step line says how many were computed in all.
    used = [psfs[float(lam)] for lam in nodes]
    grid = np.arange(nodes[0], nodes[-1] + 0.5, chosen)
    skipped = [float(lam) for lam in grid if not np.isclose(nodes, lam).any()]
    decisions.append(
        f"wavelength step {chosen} nm ({len(nodes)} PSFs over {nodes[0]:.0f}-{nodes[-1]:.0f} nm"
        + (f", none at {_runs_text(skipped, chosen)}: no spectral weight there" if skipped else "")
        + (f"; {len(psfs)} PSFs computed while choosing the step" if len(psfs) > len(nodes) else "")
        + f"); tolerance {options.wavelength_tolerance:.4f} of full scale; " + "; ".join(trail))

    full = K.shape[-1]
    size = energy_size(K.sum(axis=1), options.energy_fraction)
    K = crop_center(K, size).copy()
    sums = K.sum(axis=(2, 3))
    scale = np.where(sums > 0, A / np.where(sums > 0, sums, 1.0), 0.0)
    K *= scale[:, :, None, None]
    decisions.append(
        f"kernel {size}x{size} px holds {options.energy_fraction * 100:.2f}% of every cone's energy "
        f"(computed field {full}x{full} px at {ppd:.1f} ppd); crop renormalised so sums equal A")

    all_samp = [p.sampling for p in used]
    samp = [s for s in all_samp if s.model != "geometric"]
    geo = sorted((s for s in all_samp if s.model == "geometric"), key=lambda s: s.wavelength_nm)
    if samp:
        decisions.append(
            "pupil sampling: FFT grid {}-{}, {:.0f}-{:.0f} samples across the pupil, {}-{} fine samples per "
            "pixel, worst phase step {:.2f} rad (< pi/2), {} refinement(s)".format(
                min(s.grid for s in samp), max(s.grid for s in samp),
                min(s.pupil_samples for s in samp), max(s.pupil_samples for s in samp),
                min(s.oversample for s in samp), max(s.oversample for s in samp),
                max(s.max_phase_step_rad for s in samp), sum(s.refinements for s in samp))
            + (f" (wave optics at {_wavelength_runs(all_samp, 'wave')})" if geo else ""))
    if geo:
        needed = max(s.wave_grid_needed for s in geo)
        worst = max(s.model_error_estimate for s in geo)
        why = (f"a wave-optics pupil grid would need up to {needed}x{needed} (limit {opt.max_grid})"
               if needed else f"psf_model option {opt.psf_model!r}")
        decisions.append(
            f"PSF model: geometric optics at {_wavelength_runs(all_samp, 'geometric')} ({len(geo)} of "
            f"{len(all_samp)} PSFs; {why}): the pupil's ray-optics blur integrated over pixels, convolved with its "
            f"Airy pattern; estimated relative error of the geometric model {worst * 100:.2f}% "
            f"or less (Airy disc diameter / half-energy blur diameter)")
    info.update(identity=False, kernel_size=size, computed_field_px=full, wavelength_step_nm=chosen,
                nodes_nm=[float(x) for x in nodes], wavelength_error_estimate=estimate,
                psfs_computed=len(psfs), max_fft_grid=max((p.sampling.grid for p in psfs.values()), default=0),
                psf_models={float(lam): s.model for lam, s in zip(nodes, all_samp)},
                geometric_wavelengths_nm=[s.wavelength_nm for s in geo],
                geometric_error_estimate=max((s.model_error_estimate for s in geo), default=None))
    return EyeKernel(kernel=K, matrix=A, pixels_per_degree=ppd, identity=False, wavelength_step_nm=chosen,
                     node_wavelengths_nm=tuple(float(x) for x in nodes), state=state,
                     reference_wavelength_nm=opt.reference_wavelength_nm,
                     decisions=tuple(decisions), info=info)


def _runs_text(wavelengths: list[float], step: float) -> str:
    """Sorted wavelengths as runs of ``step`` (for example ``"740-760 nm"`` or ``"750 nm"``)."""
    runs: list[list[float]] = []
    for lam in wavelengths:
        if runs and math.isclose(lam - runs[-1][-1], step):
            runs[-1].append(lam)
        else:
            runs.append([lam])
    return ", ".join(f"{r[0]:.0f} nm" if len(r) == 1 else f"{r[0]:.0f}-{r[-1]:.0f} nm" for r in runs)


def _wavelength_runs(samplings: list, model: str) -> str:
    """Wavelengths whose PSF used ``model``, as runs over the sorted computed wavelengths
    (for example ``"390-470 nm, 750 nm"``)."""
    ordered = sorted(samplings, key=lambda s: s.wavelength_nm)
    runs: list[list[float]] = []
    previous = False
    for s in ordered:
        hit = (s.model == "geometric") == (model == "geometric")
        if hit:
            if previous:
                runs[-1].append(s.wavelength_nm)
            else:
                runs.append([s.wavelength_nm])
        previous = hit
    return ", ".join(f"{r[0]:.0f} nm" if len(r) == 1 else f"{r[0]:.0f}-{r[-1]:.0f} nm" for r in runs)


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
    corrected = dataclasses.replace(eye, sphere_D=0.0, cylinder_D=0.0, axis_deg=0.0, accommodation_D=0.0)
    optics = dataclasses.replace(options.optics, viewing_distance_m=math.inf)
    return build_kernel(corrected, display, dataclasses.replace(options, optics=optics))
