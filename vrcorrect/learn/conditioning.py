"""What the learned model is told about the eye, and the range it was trained on (numpy only).

The runtime (layer 5, never torch) imports this module to feed an exported model, so it
must not import torch, directly or through :mod:`vrcorrect.learn.model`.

* :class:`SamplingRanges` - the prescriptions a data set samples and a model is valid for
  (sphere, minus-form cylinder, axis, pupil); :func:`check_eye` refuses an eye outside them.
* :func:`eye_features` - the FiLM conditioning vector: the power vector (M, J0, J45, D) and
  the pupil (mm), each scaled to about [-1, 1] by the training ranges.
* :func:`precorrect` - the model's extra input channels: by default (``steps > 0``) a few
  accelerated projected-gradient steps on the true objective from the image
  (:func:`vrcorrect.solvers.fista.projected_gradient`); with ``steps = 0`` the eye's
  regularised inverse ``(K^H K + mu I)^-1 K^H K_ref`` applied to the image (mirrored borders)
  and clipped to [0, 1] (the ``wiener`` method's filters, without the blend).  The inverse
  alone is a poor start for strong eyes: on the default data set's eyes its best blend
  with the image closes 4 % of the gap between no correction and ``fast``, where three
  projected-gradient steps close about half of it.
* :data:`UNROLLED_FORMAT`, :data:`UNROLLED_INPUTS` - the unrolled model's ONNX contract, shared by
  its exporter and the runtime.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Mapping

import numpy as np

from ..physics.kernel import EyeKernel
from ..physics.refraction import refractive_state
from ..plumbing.errors import ValidationError
from ..solvers import make_problem
from ..solvers.fista import gradient_plan, gradient_step, projected_gradient
from ..solvers.realtime import power_of_two_grid
from ..solvers.spectral import gram, kernel_spectrum, padded_shape, spectral_norm_squared
from ..solvers.wiener import apply_filters, correction_filters
from ..specs.prescription import EyeRx

#: Regulariser of the pre-correction channels, relative to ``||K||^2`` (one of ``wiener``'s candidates).
PRECORRECTION_MU_REL = 0.1
#: Projected-gradient steps of the pre-correction channels (0: the clipped regularised inverse).
PRECORRECTION_STEPS = 3
#: Number of conditioning features (M, J0, J45, pupil).
N_FEATURES = 4


@dataclass(frozen=True)
class SamplingRanges:
    """Prescription ranges (closed intervals) a data set samples uniformly and a model serves.

    Attributes
    ----------
    sphere_D
        Sphere S, dioptres (minus-cylinder form), default -6 to +6.
    cylinder_D
        Cylinder C in minus-cylinder form, dioptres, default -3 to 0 (plus-cylinder eyes are
        transposed before checking).
    axis_deg
        Cylinder axis, degrees, default 0 to 180 (any axis).
    pupil_diameter_mm
        Pupil diameter, millimetres, default 2 to 6.
    """

    sphere_D: tuple[float, float] = (-6.0, 6.0)
    cylinder_D: tuple[float, float] = (-3.0, 0.0)
    axis_deg: tuple[float, float] = (0.0, 180.0)
    pupil_diameter_mm: tuple[float, float] = (2.0, 6.0)

    def __post_init__(self) -> None:
        limits = {"sphere_D": (-20.0, 20.0), "cylinder_D": (-10.0, 0.0), "axis_deg": (0.0, 180.0),
                  "pupil_diameter_mm": (1.0, 9.0)}
        for name, (lo_lim, hi_lim) in limits.items():
            value = getattr(self, name)
            try:
                lo, hi = (float(v) for v in value)
            except (TypeError, ValueError):
                raise ValidationError(name, value, "a pair (low, high) of numbers") from None
            if not (math.isfinite(lo) and math.isfinite(hi) and lo_lim <= lo <= hi <= hi_lim):
                raise ValidationError(name, value, f"low <= high within {lo_lim:g} to {hi_lim:g}")
            object.__setattr__(self, name, (lo, hi))

    def as_dict(self) -> dict[str, list[float]]:
        """JSON-ready: field -> [low, high]."""
        return {k: list(v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any]) -> "SamplingRanges":
        """Inverse of :meth:`as_dict` (missing fields take the defaults)."""
        known = {k: tuple(v) for k, v in doc.items() if k in cls.__dataclass_fields__}
        return cls(**known)

    def describe(self) -> str:
        """One line, e.g. ``sphere -6 to +6 D, cylinder -3 to 0 D, axis 0-180 deg, pupil 2-6 mm``."""
        return (f"sphere {self.sphere_D[0]:+g} to {self.sphere_D[1]:+g} D, cylinder {self.cylinder_D[0]:+g} to "
                f"{self.cylinder_D[1]:g} D (minus form), axis {self.axis_deg[0]:g}-{self.axis_deg[1]:g} deg, "
                f"pupil {self.pupil_diameter_mm[0]:g}-{self.pupil_diameter_mm[1]:g} mm")

    def sample(self, rng: np.random.Generator) -> EyeRx:
        """One eye drawn uniformly over each range (four draws from ``rng``, in field order)."""
        s, c, a, p = (float(rng.uniform(lo, hi)) for lo, hi in
                      (self.sphere_D, self.cylinder_D, self.axis_deg, self.pupil_diameter_mm))
        return EyeRx(sphere_D=s, cylinder_D=c, axis_deg=min(a, 180.0), pupil_diameter_mm=p)


def without_accommodation(eye: EyeRx, distance_m: float) -> EyeRx:
    """An eye that cannot focus and sees a display at ``distance_m`` as ``eye`` does: the
    accommodation ``eye`` uses there (:func:`~vrcorrect.physics.refraction.refractive_state`) folded
    into its sphere. Its residual error at the display, so its kernel there, is ``eye``'s; an eye that
    uses none of its amplitude there (a myope whose far point is nearer than the display) keeps its
    sphere. An accommodative lag is folded with it (the accommodation used is what the lagging eye
    uses). The learned model was trained on eyes that cannot focus: this is the eye it is told of."""
    if eye.accommodation_D == 0.0 and eye.accommodative_lag_D == 0.0:
        return eye
    used = refractive_state(eye, distance_m).accommodation_used_D
    return eye.with_changes(sphere_D=eye.sphere_D - used, accommodation_D=0.0, accommodative_lag_D=0.0)


def kernel_distance_m(kernel: EyeKernel) -> float:
    """The viewing distance a kernel was built for (from its refractive state's vergence)."""
    vergence = kernel.state.vergence_D
    return math.inf if vergence == 0.0 else 1.0 / vergence


def check_eye(eye: EyeRx, ranges: SamplingRanges, what: str = "the learned model",
              distance_m: float | None = None) -> EyeRx:
    """The eye in minus-cylinder form if ``ranges`` hold it, else a :class:`ValidationError`.

    The error names the field, the value, the range and the methods that have no range
    limit (``wiener`` or ``fast``).  Higher-order aberrations are refused: the model was trained
    without them. So is accommodation, unless the display's ``distance_m`` is given: then the eye
    checked and returned is :func:`without_accommodation`'s, which sees that display alike.
    """
    e = eye.minus_cylinder()
    hint = f"(the range {what} was trained on); for other eyes use --method wiener or fast"
    folded = ""
    if distance_m is not None and (e.accommodation_D != 0.0 or e.accommodative_lag_D != 0.0):
        given, e = e, without_accommodation(e, distance_m)
        if e.sphere_D != given.sphere_D:
            folded = (f" (the sphere with the {given.sphere_D - e.sphere_D:.2f} D of its "
                      f"{given.accommodation_D:.2f} D of accommodation the eye uses at the display taken off)")
    for name, unit in (("sphere_D", "D"), ("cylinder_D", "D"), ("axis_deg", "deg"), ("pupil_diameter_mm", "mm")):
        lo, hi = getattr(ranges, name)
        value = getattr(e, name)
        if not (lo - 1e-9 <= value <= hi + 1e-9):
            raise ValidationError(name, value, f"{lo:g} to {hi:g} {unit} {hint}" + (folded if name == "sphere_D"
                                                                                     else ""))
    for name in ("accommodation_D", "accommodative_lag_D"):
        if getattr(e, name) != 0.0:
            raise ValidationError(name, getattr(e, name), f"0 {hint}")
    if e.higher_order is not None and e.higher_order.coefficients_um:
        raise ValidationError("higher_order", "present", f"none {hint}")
    return e


def eye_features(eye: EyeRx, ranges: SamplingRanges) -> np.ndarray:
    """FiLM input: ``(M, J0, J45, pupil)`` scaled to about [-1, 1] by the training ranges.

    M and J are divided by the largest |M| and |C|/2 the ranges allow; the pupil is mapped
    from its range to [-1, 1].  Returns float32 ``(4,)``.
    """
    pv = eye.power_vector()
    m_scale = max(abs(ranges.sphere_D[0] + ranges.cylinder_D[0] / 2), abs(ranges.sphere_D[1]), 1e-3)
    j_scale = max(abs(ranges.cylinder_D[0]) / 2, 0.25)
    p_lo, p_hi = ranges.pupil_diameter_mm
    p = (eye.pupil_diameter_mm - (p_lo + p_hi) / 2) / max((p_hi - p_lo) / 2, 0.5)
    return np.array([pv.M_D / m_scale, pv.J0_D / j_scale, pv.J45_D / j_scale, p], dtype=np.float32)


def model_inputs(image: np.ndarray, kernel: EyeKernel, reference_kernel: EyeKernel | None,
                 mu_rel: float = PRECORRECTION_MU_REL, steps: int = 0, gradient: bool = False,
                 plan=None) -> tuple[np.ndarray, np.ndarray | None]:
    """``(precorrected, gradient_step)`` for a model: :func:`precorrect`'s channels and, when the
    model takes them (``gradient``), :func:`vrcorrect.solvers.fista.gradient_step` at them
    (``None`` otherwise).  Both float32 ``(H, W, 3)``; the problem is built once.
    """
    if not gradient:
        return precorrect(image, kernel, reference_kernel, mu_rel, steps, plan), None

    if plan is None:
        plan = gradient_plan(kernel, image.shape[:2])
    problem = make_problem(image, kernel, reference_kernel)
    if steps > 0:
        pre = projected_gradient(problem, steps, plan)
    else:
        pre = precorrect(image, kernel, reference_kernel, mu_rel, 0)
    return pre, gradient_step(problem, pre, plan)


def precorrect(image: np.ndarray, kernel: EyeKernel, reference_kernel: EyeKernel | None,
               mu_rel: float = PRECORRECTION_MU_REL, steps: int = 0, plan=None) -> np.ndarray:
    """The model's extra input: ``steps`` projected-gradient steps on the eye's objective from
    ``image``, or (``steps = 0``) the eye's regularised inverse applied to ``image``, clipped.

    Parameters
    ----------
    image
        ``(H, W, 3)`` linear display RGB in [0, 1].
    kernel, reference_kernel
        The eye's kernel and its glasses-on kernel (``None``: the ideal target ``A t``).
    mu_rel
        Regulariser relative to ``||K||^2`` (``steps = 0`` only).
    steps
        Accelerated projected-gradient steps (:func:`vrcorrect.solvers.fista.projected_gradient`;
        its objective is the glasses-on target of ``reference_kernel``, or ``A t``).
    plan
        :func:`vrcorrect.solvers.fista.gradient_plan` of ``kernel`` for this image size
        (``steps > 0`` only; None: built here).  A renderer keeps one per eye and frame size.

    Returns
    -------
    numpy.ndarray
        float32 ``(H, W, 3)`` in [0, 1]; the image itself when the eye's kernel is 1x1.
    """
    if kernel.size == 1:
        return np.ascontiguousarray(image, dtype=np.float32)
    if steps > 0:
        return projected_gradient(make_problem(image, kernel, reference_kernel), steps, plan)
    filters = correction_filters(kernel, mu_rel, reference_kernel)
    out = apply_filters(np.moveaxis(image, 2, 0), filters.taps)
    return np.ascontiguousarray(np.clip(np.moveaxis(out, 0, 2), 0.0, 1.0), dtype=np.float32)


#: Length of :func:`unrolled_features`.
N_UNROLLED_FEATURES = 5

UNROLLED_FORMAT = "vrcorrect-unrolled-v4"   # v2: starts from fast_start (the duals d1, d2 added); v3: box weight
#                                             per stage; v4: the box's top per pixel (upper: the light cap)
"""The unrolled model's ONNX format: what :mod:`vrcorrect.learn.unrolled_export` writes and
:mod:`vrcorrect.runtime.unrolled` runs."""
UNROLLED_FORMATS = ("vrcorrect-unrolled-v3", UNROLLED_FORMAT)
"""The formats the runtime runs: a v3 model has no ``upper`` input, so it cannot hold the light cap."""
UNROLLED_INPUTS_V3 = ("target_lms", "z0", "spectrum", "gram", "norm2", "features", "target", "d1", "d2")
UNROLLED_INPUTS = UNROLLED_INPUTS_V3 + ("upper",)
"""The unrolled model's inputs, in order (v4; v3's without ``upper``)."""


def unrolled_features(eye: EyeRx, kernel_size: int, ranges: SamplingRanges) -> np.ndarray:
    """The unrolled model's stage-settings input (:mod:`vrcorrect.learn.unrolled`): the eye's
    :func:`eye_features` and ``log(kernel px) / 4``, the blur's extent on this display; float32 ``(5,)``."""
    return np.append(eye_features(eye, ranges), math.log(kernel_size) / 4.0).astype(np.float32)


def unrolled_spectra(kernel: np.ndarray, shape: tuple[int, int], grid_kernel_size: int | None = None,
                     power_of_two: bool = True) -> tuple[np.ndarray, np.ndarray, float]:
    """The unrolled model's data-step inputs for a ``(3, 3, s, s)`` kernel and ``shape`` images: the
    spectrum ``K`` and the Gram matrix ``K^H K`` per frequency, each ``(3, 3, P0, P1 // 2 + 1, 2)``
    float32 (computed in float64; real and imaginary parts last), and ``||K||^2``. From the Gram
    matrix a stage solves ``(K^H K + n I) U = R`` by cofactors for a box weight ``n`` of its own (as
    :func:`vrcorrect.solvers.spectral.hermitian_inverse` does for ``fast``).

    The grid holds the image and the blur of a ``grid_kernel_size`` kernel (default ``s``): with
    ``power_of_two`` a power-of-two grid (:func:`vrcorrect.solvers.realtime.power_of_two_grid`, the
    real-time path's before its mixed-radix grids), on which onnxruntime's DFT is a radix-2 FFT
    (other lengths run a direct DFT, slower and with float32 errors near 1e-4 after four stages);
    otherwise ``fast``'s (:func:`~vrcorrect.solvers.spectral.padded_shape`)."""

    k = np.asarray(kernel, np.float64)
    size = grid_kernel_size or k.shape[-1]
    grid = power_of_two_grid(shape[1], shape[0], size) if power_of_two else padded_shape(shape[0], shape[1], size)
    spectrum = kernel_spectrum(k, grid)
    n = spectral_norm_squared(k)
    def pairs(c: np.ndarray) -> np.ndarray:
        return np.stack([c.real, c.imag], axis=-1).astype(np.float32)

    return pairs(spectrum), pairs(gram(spectrum)), n
