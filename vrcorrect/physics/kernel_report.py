"""What shaped an eye's kernel, as data (:class:`KernelReport`), and the same in words (:func:`explain`).

:func:`vrcorrect.physics.kernel.build_kernel` records every decision it takes in a frozen report
attached to the kernel (``EyeKernel.report``): where the display is and what the eye does about it,
whether the eye is in focus there (the identity path), the wavelength step chosen and why, the
wavelength nodes and those left out for lack of spectral weight, the PSF model of each node (wave or
geometric optics) and why, the pupil sampling, and the kernel's size and energy.  :func:`explain`
turns a report into the lines ``vrcorrect simulate --explain`` prints, ``correct``'s report and
``psf``'s JSON sidecar hold (``decisions``).

Units are in the names (docs/architecture.md, 'Physics conventions'): D, nm, mm, rad, px.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..specs.prescription import PowerVector
from .sampling import PsfSampling

# Why a wavelength step was chosen (WavelengthStep.reason).
STEP_FORCED = "forced"                      # KernelOptions.wavelength_step_nm
STEP_WITHIN_TOLERANCE = "within tolerance"  # the coarsest step whose estimated error is below the tolerance
STEP_FINEST = "finest"                      # no coarser step was within it: 1 nm, the reference itself

# Why a node's PSF has its model (NodePsf.reason).
PSF_GRID_FITS = "wave grid fits"            # wave optics: its pupil grid fits in OpticsOptions.max_grid
PSF_GRID_TOO_LARGE = "wave grid too large"  # geometric: the wave-optics grid would exceed max_grid
PSF_PHASE_UNRESOLVED = "phase unresolved"   # geometric: refining the pupil grid left phase steps >= pi/2
PSF_OPTION = "psf_model option"             # geometric: OpticsOptions.psf_model == "geometric"


@dataclass(frozen=True)
class Viewing:
    """Where the display is and what accommodation does about it."""

    distance_m: float                # the display's (or its virtual image's) distance; inf at optical infinity
    vergence_D: float                # 1 / distance
    accommodation_used_D: float
    accommodation_D: float           # the eye's amplitude
    accommodative_lag_D: float = 0.0  # the eye's lag at 40 cm (MEM); the residual keeps its share at the display


@dataclass(frozen=True)
class FocusCheck:
    """Whether the eye is in focus at this display: the test of the identity path."""

    reference_wavelength_nm: float
    residual: PowerVector            # at the reference wavelength, after distance and accommodation
    residual_worst_meridian_D: float
    chromatic_aberration: bool
    band_nm: tuple[float, float]     # holds all but 0.5 % at each end of every cone-primary weight
    worst_meridian_D: float          # largest over the band's ends and the reference, chromatic aberration in
    depth_of_focus_D: float
    blur_limit_rad: float            # the larger of one display pixel and 1 arcmin
    pupil_diameter_mm: float
    diffraction_blur_rad: float      # Airy disc diameter at the band's long end
    higher_order: bool               # the prescription has higher-order terms
    in_focus: bool                   # worst meridian within the depth of focus, diffraction within the
                                     # blur limit, no higher-order terms


@dataclass(frozen=True)
class StepTrial:
    """One step's estimated quadrature error against 1 nm (Richardson: ``|K_2h - K_h| / 3``)."""

    step_nm: int
    error_estimate: float


@dataclass(frozen=True)
class WavelengthStep:
    """The wavelength step of the kernel's quadrature, its nodes and the PSFs it took."""

    step_nm: int
    reason: str                      # STEP_FORCED, STEP_WITHIN_TOLERANCE or STEP_FINEST
    tolerance: float                 # KernelOptions.wavelength_tolerance
    trials: tuple[StepTrial, ...]    # coarsest first; empty when forced
    nodes_nm: tuple[float, ...]      # the kernel's nodes, ascending
    left_out_nm: tuple[float, ...]   # on the step's grid from the first to the last node, no spectral weight
    psfs_computed: int               # every PSF computed while choosing the step (>= len(nodes_nm))
    max_fft_grid: int                # the largest wave-optics grid among those (0: none)

    @property
    def error_estimate(self) -> float | None:
        """The last estimate made (the chosen step's, unless the step was forced or is 1 nm)."""
        return self.trials[-1].error_estimate if self.trials else None


@dataclass(frozen=True)
class NodePsf:
    """The PSF at one node of the kernel: which model made it, why, and how it was sampled."""

    wavelength_nm: float
    model: str                       # "wave" or "geometric"
    reason: str                      # PSF_GRID_FITS, PSF_GRID_TOO_LARGE, PSF_PHASE_UNRESOLVED or PSF_OPTION
    sampling: PsfSampling


@dataclass(frozen=True)
class KernelReport:
    """Every decision :func:`~vrcorrect.physics.kernel.build_kernel` took for one kernel.

    For the identity path (``identity``) there are no nodes: ``wavelength`` is None, ``psfs`` empty,
    the kernel 1x1.
    """

    pixels_per_degree: float
    viewing: Viewing
    focus: FocusCheck
    identity: bool
    identity_path: bool              # KernelOptions.identity_path (the identity path allowed)
    energy_fraction: float           # KernelOptions.energy_fraction, the least each cone's kernel keeps
    energy_held: float               # what the window holds of the least-held cone's energy, before renormalising
    kernel_size_px: int
    computed_field_px: int | None    # the PSFs' field before the crop (None: identity)
    wavelength: WavelengthStep | None
    psfs: tuple[NodePsf, ...]        # one per node, ascending
    psf_model: str                   # OpticsOptions.psf_model
    max_grid: int                    # OpticsOptions.max_grid

    @property
    def psf_models(self) -> dict[float, str]:
        """Each node's model, ``{wavelength_nm: "wave" | "geometric"}``."""
        return {p.wavelength_nm: p.model for p in self.psfs}

    @property
    def geometric_wavelengths_nm(self) -> list[float]:
        return [p.wavelength_nm for p in self.psfs if p.model == "geometric"]

    @property
    def geometric_error_estimate(self) -> float | None:
        """The largest estimated relative error of a geometric PSF among the nodes (None: none)."""
        return max((p.sampling.model_error_estimate for p in self.psfs if p.model == "geometric"), default=None)


def explain(report: KernelReport) -> list[str]:
    """The report in words, one decision a line (what ``--explain`` prints after ``  - ``)."""
    lines: list[str] = []
    v, f = report.viewing, report.focus
    dist_txt = "infinity" if math.isinf(v.distance_m) else f"{v.distance_m:.2f} m"
    lines.append(
        f"viewing distance {dist_txt} -> vergence {v.vergence_D:.2f} D; accommodation used "
        f"{v.accommodation_used_D:.2f} of {v.accommodation_D:.2f} D"
        + (f" (lag {v.accommodative_lag_D:.2f} D at 40 cm)" if v.accommodative_lag_D else ""))
    r = f.residual
    lines.append(
        f"residual refraction at {f.reference_wavelength_nm:.0f} nm: M {r.M_D:+.2f} D, J0 {r.J0_D:+.2f} D, "
        f"J45 {r.J45_D:+.2f} D (worst meridian {f.residual_worst_meridian_D:.2f} D); chromatic aberration "
        f"{'on (Thibos 1992)' if f.chromatic_aberration else 'off'}")
    band = f.band_nm
    lines.append(
        f"depth of focus +-{f.depth_of_focus_D:.3f} D ({math.degrees(f.blur_limit_rad) * 60:.2f} arcmin blur limit, "
        f"{f.pupil_diameter_mm:g} mm pupil); worst meridian over {band[0]:.0f}-{band[1]:.0f} nm is "
        f"{f.worst_meridian_D:.3f} D, diffraction blur {math.degrees(f.diffraction_blur_rad) * 60:.2f} arcmin"
        + (", higher-order terms present" if f.higher_order else ""))
    if report.identity:
        lines.append("identity path: the eye is in focus at this display; no convolution (kernel 1x1 = A)")
        return lines
    lines.append("convolution needed: the eye is out of focus at this display"
                 if not f.in_focus else "identity path disabled by option")

    w = report.wavelength
    assert w is not None
    nodes = w.nodes_nm
    if w.reason == STEP_FORCED:
        trail = [f"{w.step_nm} nm forced by option"]
    else:
        trail = [f"{t.step_nm} nm: estimated error {t.error_estimate:.4f}" for t in w.trials]
        if w.reason == STEP_FINEST:
            trail.append("1 nm is the reference itself")
    lines.append(
        f"wavelength step {w.step_nm} nm ({len(nodes)} PSFs over {nodes[0]:.0f}-{nodes[-1]:.0f} nm"
        + (f", none at {_runs_text(list(w.left_out_nm), w.step_nm)}: no spectral weight there"
           if w.left_out_nm else "")
        + (f"; {w.psfs_computed} PSFs computed while choosing the step" if w.psfs_computed > len(nodes) else "")
        + f"); tolerance {w.tolerance:.4f} of full scale; " + "; ".join(trail))

    size, full = report.kernel_size_px, report.computed_field_px
    lines.append(
        f"kernel {size}x{size} px holds {report.energy_fraction * 100:.2f}% of every cone's energy "
        f"(computed field {full}x{full} px at {report.pixels_per_degree:.1f} ppd); crop renormalised so sums "
        f"equal A")

    all_samp = [p.sampling for p in report.psfs]
    samp = [s for s in all_samp if s.model != "geometric"]
    geo = sorted((s for s in all_samp if s.model == "geometric"), key=lambda s: s.wavelength_nm)
    if samp:
        lines.append(
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
        why = (f"a wave-optics pupil grid would need up to {needed}x{needed} (limit {report.max_grid})"
               if needed else f"psf_model option {report.psf_model!r}")
        lines.append(
            f"PSF model: geometric optics at {_wavelength_runs(all_samp, 'geometric')} ({len(geo)} of "
            f"{len(all_samp)} PSFs; {why}): the pupil's ray-optics blur integrated over pixels, convolved with its "
            f"Airy pattern; estimated relative error of the geometric model {worst * 100:.2f}% "
            f"or less (Airy disc diameter / half-energy blur diameter)")
    return lines


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
