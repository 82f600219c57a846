"""A correction designed for the eye as it may be: the kernels of a band of pupils and defocus,
summed into one effective kernel.

The pupil a correction is designed for is an estimate (:mod:`vrcorrect.physics.pupil`), and the
sphere the prescription states is known to a quarter dioptre at best.  A correction designed for a
larger pupil or more defocus than the eye has over-sharpens, and can look worse than none.  The
robust design minimises the objective's expectation over a band of eyes instead of one::

    sum_i w_i || C K_i x - T_i ||^2,    K_i: the eye at pupil p f_i and sphere S + s_i,
                                          T_i = K_ref,i t (its view with glasses) or A t (ideal)

over the eyes of a :class:`RobustBand`: by default spheres ``S + {-0.25, 0, +0.25} D`` (the eye as
modelled counting three times) at one pupil, ``0.93 p``.

Why that band.  Over-correcting an eye that sees better than modelled (a smaller pupil, less defocus)
costs far more than under-correcting one that sees worse: a 4 mm design seen through 2.5 mm lost
about 1 JOD against no correction, seen through 5.5 mm it still gained 0.2-0.3.  A first band of
pupils ``p x {0.8, 1, 1.25}`` with the same spheres, the modelled eye counting twice on each axis,
kept only 54-63 % of an exact design's gain at 3 mm on a text image (scikit-image's ``text``) and
fell 0.04-0.10 JOD below no correction with the sphere 0.5 D off on photographs.  On the choice
images (:data:`CHOICE_NOTE`) a sweep of bands (pupil factors and priors, sphere offsets and
priors, where the design pupil sits) found the pupil axis best collapsed to one pupil a bank step
below the estimate: 79-101 % of the exact gain at 3 mm, and no worse than -0.05 JOD with the pupil
at 2.5 to 5.5 mm or the sphere 0.5 D off (the pupil band with equal sphere weights: 75 % and
+0.03; the modelled sphere counting four times: 81 % and -0.10).  ``RobustBand(pupil_factors=...)``
still designs over a band of pupils.  Offline, ``fast`` minimises exactly that
(:func:`vrcorrect.solvers.expectation.fast_expectation`, one split per member: about five times the
work).  For every other solver, the real-time path among them, the design is *one effective
kernel*: without the crop ``C`` the expectation's normal equations are one 3x3 system per
frequency, as a single kernel's, ``M(f) = sum_i w_i K_i^H K_i`` with the right-hand side ``sum_i w_i
K_i^H T_i``.  Any ``U`` with ``U^H U = M`` and ``R = U^-H sum_i w_i K_i^H K_ref,i`` then make
``||U x - R t||^2`` equal to the expectation up to a constant, and every solver runs unchanged on
``(U, R)`` as on a kernel and its glasses reference, at the cost of one kernel (``vrcorrect bench
cost``: a frame costs what it cost).

Which ``U``: every ``Q U`` with ``Q`` unitary per frequency has the same ``U^H U``.  The crop ``C``
(the data term inside the image only; the light spilled past the image's edge is free) is where the
choice matters: the expectation crops each ``K_i x``, the effective form crops ``U x``, and a ``U``
whose phase differs from the members' mixes the free spill into the image.  So ``U`` is the
Cholesky factor turned per frequency to the phase of the members' mean kernel (the polar factor of
``K_mean U_chol^H``): on the evaluation photograph (desktop and quest2, 256 px) the Cholesky factor
alone lost 10 to 25 % of the JOD gain at the band's sharper eyes to the crop, the turned factor
about a third of that (``vrcorrect bench robust`` measures it against the exact expectation).  The
turn has jumps where the mean kernel's transfer changes sign, so ``U`` and ``R`` are windowed in
space to the widest member's size as a radius (a raised-cosine taper over its outer half) and
cropped to all but :data:`CROP_TAIL` of their magnitude; their spatial sums are then restored exactly
(``U(0)`` and ``R(0)``, equal: a flat field inside the gamut is shown unchanged).  ``M`` carries a
floor (:data:`FLOOR_REL`, a pull towards the target, never towards zero) where every member's
transfer has died out.  Everything is float64.

Weights: each member's prior weight over its expected uncorrected error, ``sum_f ||K_i(f) -
T_i(f)||^2 S(f)`` with a natural image's spectrum ``S(f) = 1 / (|f|^2 + f0^2)``, so that an eye that
sees the uncorrected image well (a smaller pupil, less defocus) counts for as much, in relative terms,
as one that sees it badly: without that, the blurriest eyes would set the design and over-sharpen
for the sharper ones.  The ratio of two weights is capped at :data:`MAX_WEIGHT_RATIO` (an in-focus
member would otherwise take all the weight).  The weights do not depend on the image, so a real-time
frame and an offline correction design alike.

Layer 2: numpy and scipy.fft (kernel construction).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.fft

from ..plumbing.errors import ValidationError
from ..specs.display import DisplayProfile
from ..specs.prescription import EyeRx
from .kernel import EyeKernel, KernelOptions, build_kernel, build_reference_kernel
from .sampling import crop_center

__all__ = ["RobustBand", "Member", "Design", "design_eye", "design_grid", "member_spectra", "effective_kernels",
           "member_weights", "CROP_TAIL", "FLOOR_REL", "MAX_MEMBER_PUPIL_MM",
           "MAX_WEIGHT_RATIO", "ROBUST_CHOICES", "DESIGN_PUPIL_FACTOR", "CHOICE_NOTE"]

#: The effective kernels keep all but this fraction of their magnitude (sum of |values|): an error of
#: at most about this in any cone response of an image in [0, 1].
CROP_TAIL = 1e-3
#: The pull towards the target added to the expectation, relative to ``||A||^2`` (:func:`effective_kernels`).
FLOOR_REL = 1e-4
#: The largest ratio of two members' weights.
MAX_WEIGHT_RATIO = 20.0
#: A band's pupils are held at or below this (mm): about the largest a dark-adapted young eye opens to.
MAX_MEMBER_PUPIL_MM = 8.0
#: The robust design's pupil as a multiple of the estimate: one step of the pupil bank below it
#: (``1.25 ** (-1/3)``, about 0.93, so that a bank entry's design lands on the entry below).
DESIGN_PUPIL_FACTOR = 1.25 ** (-1.0 / 3.0)
#: How the default band was chosen (the module docstring says why).
CHOICE_NOTE = ("chosen on scikit-image's astronaut, coffee and text and the project's text chart, on desktop and quest2 "
               "(the eye -2.00/-1.00 x 120 at 256 px), never on the held-out images of vrcorrect bench robust")
#: ``--robust``'s values.
ROBUST_CHOICES = ("on", "off")


@dataclass(frozen=True)
class RobustBand:
    """The band of eyes a robust correction is designed over.

    Attributes
    ----------
    pupil_factors
        The viewing pupil's multiples (each > 0): the estimate's uncertainty.
    sphere_offsets_D
        Offsets added to the prescription's sphere, dioptres (each within +-2).
    pupil_priors, sphere_priors
        Prior weights of the factors and offsets (None: equal); a member's prior is the product.
    light_cap
        Whether the design's display light is held under the light cap
        (:func:`~vrcorrect.solvers.problem.light_cap`); the page band
        (:data:`~vrcorrect.physics.page.PAGE_BAND`) is not.
    towards_sharper
        Whether the sphere offsets point towards the sharper eye: a positive offset lessens the eye's
        residual defocus at the display, so the offsets' signs flip where that residual is hyperopic
        (:func:`oriented_band`; the page band's hedge).  False: offsets as given.
    pull
        A pull towards the target, ``pull ||A||^2 ||x - t||^2`` added to the expectation on top of
        :data:`FLOOR_REL` (from 0 to 1): where the band's summed transfer ``sum w |K|^2`` falls under
        ``pull ||A||^2`` the design leaves the target nearly as it is.  0: the floor alone.

    The default (chosen on the choice images, :data:`CHOICE_NOTE`): one pupil,
    :data:`DESIGN_PUPIL_FACTOR` of the estimate, and spheres -0.25/0/+0.25 D with the eye as
    modelled counting three times.
    """

    pupil_factors: tuple[float, ...] = (DESIGN_PUPIL_FACTOR,)
    sphere_offsets_D: tuple[float, ...] = (-0.25, 0.0, 0.25)
    pupil_priors: tuple[float, ...] | None = None
    sphere_priors: tuple[float, ...] | None = (1.0, 3.0, 1.0)
    light_cap: bool = True
    towards_sharper: bool = False
    pull: float = 0.0

    def prior(self, i: int, j: int) -> float:
        """The prior weight of pupil factor ``i`` with sphere offset ``j`` (uniform unless given)."""
        a = 1.0 if self.pupil_priors is None else self.pupil_priors[i]
        b = 1.0 if self.sphere_priors is None else self.sphere_priors[j]
        return a * b

    def __post_init__(self) -> None:
        pf = tuple(float(f) for f in self.pupil_factors)
        so = tuple(float(s) for s in self.sphere_offsets_D)
        for name, priors, n in (("pupil_priors", self.pupil_priors, len(pf)), ("sphere_priors", self.sphere_priors, len(so))):
            if priors is not None and (len(priors) != n or any(not (math.isfinite(w) and w > 0) for w in priors)):
                raise ValidationError(name, priors, f"{n} positive weights, one per value")
        if not pf or any(not (math.isfinite(f) and 0.2 <= f <= 5.0) for f in pf):
            raise ValidationError("pupil_factors", self.pupil_factors, "one or more factors from 0.2 to 5")
        if not so or any(not (math.isfinite(s) and abs(s) <= 2.0) for s in so):
            raise ValidationError("sphere_offsets_D", self.sphere_offsets_D, "one or more offsets from -2 to 2 D")
        if not (isinstance(self.pull, (int, float)) and math.isfinite(self.pull) and 0.0 <= self.pull <= 1.0):
            raise ValidationError("pull", self.pull, "a pull towards the target from 0 to 1 (relative to ||A||^2)")
        object.__setattr__(self, "pupil_factors", pf)
        object.__setattr__(self, "sphere_offsets_D", so)

    def describe(self, pupil_mm: float) -> str:
        pupils = "/".join(f"{pupil_mm * f:.2f}" for f in self.pupil_factors)
        spheres = "/".join(f"{s:+.2f}" for s in self.sphere_offsets_D)
        return f"pupils {pupils} mm x sphere {spheres} D" + ("" if self.light_cap else ", no light cap")


@dataclass(frozen=True)
class Member:
    """One eye of the band: its pupil, its sphere offset, its weight and its kernel's size."""

    pupil_mm: float
    sphere_offset_D: float
    weight: float
    kernel_size: int


@dataclass(frozen=True, eq=False)
class Design:
    """What a correction is designed for: the kernel and reference the solvers use, and the physical
    eye they stand for.

    Attributes
    ----------
    pupil_mm
        The viewing pupil designed for.
    kernel, reference
        What the solvers take: the effective kernel ``U`` and reference ``R`` (robust), or the eye's own
        kernel and its glasses kernel (``reference`` None: the ideal target ``A t``).
    nominal, nominal_reference
        The eye at ``pupil_mm`` with the prescription's sphere (what it sees, as modelled) and its
        glasses kernel (None for the ideal target): for reports and previews, never for solving.
    members
        The band's eyes (empty when not robust).
    robust
        Whether ``kernel`` is an effective kernel.
    band
        The band (None when not robust).
    """

    pupil_mm: float
    kernel: EyeKernel
    reference: EyeKernel | None
    nominal: EyeKernel
    nominal_reference: EyeKernel | None
    members: tuple[Member, ...] = ()
    robust: bool = False
    band: RobustBand | None = None
    notes: tuple[str, ...] = field(default=())
    _kernels: dict = field(default_factory=dict, repr=False)

    @property
    def capped(self) -> bool:
        """Whether a correction of this design is held under the light cap: a robust design's band says
        (:attr:`RobustBand.light_cap`); one eye's never is (the box [0, 1])."""
        return self.robust and self.band is not None and self.band.light_cap

    @property
    def sees_as_with_glasses(self) -> bool:
        """Whether the kernel solved for equals its glasses reference (to 1e-9): every eye designed for
        sees the display as well as with its glasses (in focus after accommodation, its chromatic blur
        left alone as glasses leave it), so there is nothing to correct."""
        k, r = self.kernel, self.reference
        return r is not None and r.kernel.shape == k.kernel.shape and bool(
            np.allclose(r.kernel, k.kernel, rtol=0.0, atol=1e-9))

    def member_kernels(self, member: Member) -> tuple[EyeKernel, EyeKernel | None]:
        """A member's kernel and glasses kernel (None: the ideal target), as the design built them."""
        return self._kernels[(member.pupil_mm, member.sphere_offset_D)]

    def describe(self) -> list[str]:
        """The design in words (``--explain``, reports)."""
        if not self.robust:
            return [f"designed for one eye: pupil {self.pupil_mm:.2f} mm, the prescription's sphere (--robust off)"]
        assert self.band is not None
        weights = ", ".join(f"{m.pupil_mm:.2f} mm/{m.sphere_offset_D:+.2f} D: {m.weight:.3f}" for m in self.members)
        return [f"robust design over {len(self.members)} eyes ({self.band.describe(self.pupil_mm)}), one effective "
                f"kernel of {self.kernel.size} px (the members' {max(m.kernel_size for m in self.members)} px)",
                f"weights: {weights}", *self.notes]


def _spectrum(kernel: np.ndarray, grid: int) -> np.ndarray:
    """``(3, 3, n, n // 2 + 1)`` complex128 spectrum of a centred ``(3, 3, s, s)`` kernel on an ``n``-grid."""
    s = kernel.shape[-1]
    padded = np.zeros(kernel.shape[:2] + (grid, grid))
    idx = (np.arange(s) - s // 2) % grid
    padded[..., idx[:, None], idx[None, :]] = kernel
    return scipy.fft.rfft2(padded, axes=(-2, -1))


def _image_spectrum_weight(grid: int) -> np.ndarray:
    """A natural image's power spectrum ``1 / (|f|^2 + f0^2)`` on the half-spectrum grid (cycles/pixel,
    ``f0 = 1 / grid``), counting the columns the half spectrum stands for twice."""
    fy = np.fft.fftfreq(grid)[:, None]
    fx = np.fft.rfftfreq(grid)[None, :]
    s = 1.0 / (fx ** 2 + fy ** 2 + (1.0 / grid) ** 2)
    twice = np.full(fx.shape, 2.0)
    twice[0, 0] = 1.0
    if grid % 2 == 0:
        twice[0, -1] = 1.0
    return s * twice


def member_weights(spectra: list[np.ndarray], targets: list[np.ndarray], priors: list[float], grid: int) -> np.ndarray:
    """Each member's weight: its prior over its expected uncorrected error (module docstring), the
    ratio of two weights capped at :data:`MAX_WEIGHT_RATIO`, summing to 1."""
    s = _image_spectrum_weight(grid)
    errors = np.array([float((np.abs(k - t) ** 2 * s).sum()) for k, t in zip(spectra, targets)])
    floor = errors.max() / MAX_WEIGHT_RATIO if errors.max() > 0 else 1.0
    w = np.asarray(priors, np.float64) / np.maximum(errors, floor)
    return w / w.sum()


def _cholesky_upper(M: np.ndarray) -> np.ndarray:
    """``U`` upper triangular with a positive real diagonal and ``U^H U = M``, per frequency, for
    Hermitian positive definite ``(3, 3, ...)`` planes."""
    U = np.zeros_like(M)
    u00 = np.sqrt(M[0, 0].real)
    U[0, 0] = u00
    U[0, 1] = M[0, 1] / u00
    U[0, 2] = M[0, 2] / u00
    u11 = np.sqrt((M[1, 1] - np.abs(U[0, 1]) ** 2).real)
    U[1, 1] = u11
    U[1, 2] = (M[1, 2] - np.conj(U[0, 1]) * U[0, 2]) / u11
    U[2, 2] = np.sqrt((M[2, 2] - np.abs(U[0, 2]) ** 2 - np.abs(U[1, 2]) ** 2).real)
    return U


def _solve_upper_h(U: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``Y`` with ``U^H Y = B`` per frequency (``U^H`` lower triangular), ``B`` ``(3, 3, ...)``."""
    Y = np.zeros_like(B)
    for j in range(3):
        y0 = B[0, j] / np.conj(U[0, 0])
        y1 = (B[1, j] - np.conj(U[0, 1]) * y0) / np.conj(U[1, 1])
        y2 = (B[2, j] - np.conj(U[0, 2]) * y0 - np.conj(U[1, 2]) * y1) / np.conj(U[2, 2])
        Y[0, j], Y[1, j], Y[2, j] = y0, y1, y2
    return Y


def _to_space(X: np.ndarray, grid: int) -> np.ndarray:
    """A half spectrum back in space, centred: ``(3, 3, grid, grid)`` with the origin in the middle
    (``grid`` odd)."""
    x = scipy.fft.irfft2(X, s=(grid, grid), axes=(-2, -1))
    return np.fft.fftshift(x, axes=(-2, -1))


def _crop(x: np.ndarray, dc: np.ndarray, tail: float) -> np.ndarray:
    """The smallest odd centred window holding all but ``tail`` of every plane's magnitude, its spatial
    sums then set to ``dc`` exactly (the difference added at the centre)."""
    n = x.shape[-1]
    c = n // 2
    a = np.abs(x).reshape(9, n, n)
    totals = a.sum(axis=(1, 2))
    size = n
    for r in range(0, c + 1):
        inside = a[:, c - r:c + r + 1, c - r:c + r + 1].sum(axis=(1, 2))
        if np.all(inside >= (1.0 - tail) * totals - 1e-300):
            size = 2 * r + 1
            break
    out = np.array(crop_center(x, size), dtype=np.float64)
    out[:, :, size // 2, size // 2] += dc - out.sum(axis=(2, 3))
    return out


def design_grid(sizes: list[int]) -> int:
    """The odd grid the effective kernels are computed on: four times the widest member, at least 65."""
    return max(65, 4 * max(sizes) + 1) | 1


def member_spectra(kernels: list[np.ndarray], references: list[np.ndarray | None], matrix: np.ndarray,
                   grid: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The members' kernel spectra and their targets' (their glasses kernels', or the constant ``A``)."""
    spectra = [_spectrum(k, grid) for k in kernels]
    targets = [_spectrum(r, grid) if r is not None else np.asarray(matrix, np.float64)[:, :, None, None]
               for r in references]
    return spectra, targets


def _nearest_unitary(C: np.ndarray) -> np.ndarray:
    """The unitary ``Q`` nearest ``C`` per frequency (the polar factor ``W V^H`` of ``C = W S V^H``),
    ``(3, 3, ...)`` planes."""
    w, _, vh = np.linalg.svd(np.moveaxis(C, (0, 1), (-2, -1)))
    return np.moveaxis(w @ vh, (-2, -1), (0, 1))


def _window(x: np.ndarray, radius: int) -> np.ndarray:
    """The centre ``2 radius + 1`` window of centred planes ``x``, tapered radially (1 to half the
    radius, a raised cosine to 0 at the radius)."""
    c = x.shape[-1] // 2
    out = x[..., c - radius:c + radius + 1, c - radius:c + radius + 1].copy()
    yy, xx = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    r = np.hypot(yy, xx) / radius
    return out * np.where(r <= 1.0, 0.5 + 0.5 * np.cos(np.pi * np.clip(2.0 * r - 1.0, 0.0, 1.0)), 0.0)


def effective_kernels(spectra: list[np.ndarray], targets: list[np.ndarray], weights: np.ndarray, grid: int,
                      floor: float, radius: int, tail: float = CROP_TAIL) -> tuple[np.ndarray, np.ndarray]:
    """The effective kernel ``U`` and reference ``R`` (module docstring) of members whose spectra and
    targets' spectra on ``grid`` are given (:func:`member_spectra`), with ``weights``: both
    ``(3, 3, s, s)`` float64, odd ``s <= 2 radius + 1``.

    ``floor`` (``FLOOR_REL ||A||^2``) adds ``floor ||x - t||^2`` to the expectation (a pull towards the
    target, never towards zero, so the DC is unchanged), which keeps ``M`` away from singular where
    every member's transfer has died out.  The factor is the Cholesky factor turned, per frequency,
    to the phase of the members' mean kernel (:func:`_nearest_unitary`), then windowed to ``radius``
    (:func:`_window`) and cropped (:func:`_crop`, which restores the spatial sums)."""
    M = 0.0
    rhs = 0.0
    mean = 0.0
    for K, T, w in zip(spectra, targets, weights):
        Kh = np.conj(np.swapaxes(K, 0, 1))
        M = M + w * np.einsum("ikyx,kjyx->ijyx", Kh, K)
        rhs = rhs + w * np.einsum("ikyx,kjyx->ijyx", Kh, np.broadcast_to(T, K.shape))
        mean = mean + w * K
    for i in range(3):
        M[i, i] = M[i, i] + floor
        rhs[i, i] = rhs[i, i] + floor
    U = _cholesky_upper(M)
    R = _solve_upper_h(U, rhs)
    Q = _nearest_unitary(np.einsum("ikyx,jkyx->ijyx", mean, np.conj(U)))
    U = np.einsum("ikyx,kjyx->ijyx", Q, U)
    R = np.einsum("ikyx,kjyx->ijyx", Q, R)
    return tuple(_crop(_window(_to_space(X, grid), radius), X[:, :, 0, 0].real, tail) for X in (U, R))


def _effective(nominal: EyeKernel, kernel: np.ndarray) -> EyeKernel:
    """An :class:`EyeKernel` holding an effective kernel, the nominal eye's report and state beside it
    (``matrix`` is its spatial sum, as for every kernel)."""
    return dataclasses.replace(nominal, kernel=kernel, matrix=kernel.sum(axis=(2, 3)), identity=False)


def oriented_band(band: RobustBand, residual_M_D: float) -> RobustBand:
    """``band`` with its sphere offsets as added to the prescription's sphere for an eye whose residual
    spherical equivalent at the display (after distance and accommodation, :class:`FocusCheck`) is
    ``residual_M_D``: where the band points :attr:`~RobustBand.towards_sharper`, the offsets lessen
    that defocus (their signs flip where it is hyperopic, positive) and go no further than focus,
    each at most ``|residual_M_D|`` (an eye near focus at the display: past focus the eye is blurrier
    again, and the sharpest eye on that side, the one in focus, must be in the band: with the hedge
    crossing it, a -0.50 D eye in the Quest 2, 0.27 D from focus, fell 0.07-0.17 JOD below none on
    every page with the sphere 0.25-0.5 D off).  Otherwise ``band`` itself."""
    if not band.towards_sharper:
        return band
    sign = -1.0 if residual_M_D > 0.0 else 1.0
    reach = abs(residual_M_D)
    offsets = tuple(0.0 + sign * math.copysign(min(abs(s), reach), s) for s in band.sphere_offsets_D)
    if offsets == band.sphere_offsets_D:
        return band
    return dataclasses.replace(band, sphere_offsets_D=offsets, towards_sharper=False)


def design_eye(eye: EyeRx, display: DisplayProfile, pupil_mm: float, *, robust: bool = True,
               reference: str = "glasses", band: RobustBand | None = None, options: KernelOptions | None = None,
               kernels: dict | None = None, progress: Callable[[int, int], None] | None = None) -> Design:
    """The correction's design for ``eye`` (its sphere, cylinder, axis, accommodation, higher-order
    terms) viewing ``display`` through a ``pupil_mm`` pupil: robust over ``band`` (default
    :class:`RobustBand`) or for the one eye (``robust=False``, today's single-pupil design).

    ``reference`` is ``"glasses"`` or ``"ideal"``.  ``kernels`` caches built kernels between designs
    (keyed by the eye as built, whether it is a glasses kernel, the options and the display's name,
    pixels per degree and distance): a bank of designs shares them.
    ``progress(done, total)`` after each kernel built.  A member's pupil is held within the
    prescription's higher-order measurement pupil and above 1 mm, with a note.
    """
    if reference not in ("glasses", "ideal"):
        raise ValidationError("reference", reference, "'glasses' or 'ideal'")
    if not (math.isfinite(pupil_mm) and 1.0 <= pupil_mm <= 9.0):
        raise ValidationError("pupil_mm", pupil_mm, "a pupil diameter from 1 to 9 mm")
    band = band or RobustBand()
    options = options or KernelOptions()
    cache = kernels if kernels is not None else {}
    ho_limit = eye.higher_order.pupil_diameter_mm if eye.higher_order is not None else math.inf
    notes: list[str] = []
    wanted = [(round(pupil_mm * f, 4), s) for f in band.pupil_factors for s in band.sphere_offsets_D] if robust \
        else [(round(pupil_mm, 4), 0.0)]
    total = len(wanted) + len({p for p, _ in wanted}) * (reference == "glasses")
    done = 0

    def held(p: float) -> float:
        q = min(max(p, 1.0), ho_limit, MAX_MEMBER_PUPIL_MM)
        if q != p:
            why = (f"the pupil the higher-order terms were measured at ({ho_limit:g} mm)" if q == ho_limit
                   else f"the largest pupil an eye opens to ({MAX_MEMBER_PUPIL_MM:g} mm)" if q == MAX_MEMBER_PUPIL_MM
                   else "the smallest pupil modelled (1 mm)")
            note = f"a band pupil of {p:g} mm held at {q:g} mm: {why}"
            if note not in notes:
                notes.append(note)
        return q

    def get(p: float, s: float, glasses: bool) -> EyeKernel:
        nonlocal done
        e = eye.with_changes(pupil_diameter_mm=held(p), sphere_D=eye.sphere_D + (0.0 if glasses else s))
        key = (e, glasses, options, display.name, display.pixels_per_degree, display.distance_m)   # any eye, display
        if key not in cache:
            cache[key] = build_reference_kernel(e, display, options) if glasses else build_kernel(e, display, options)
        done += 1
        if progress is not None:
            progress(done, total)
        return cache[key]

    nominal = get(pupil_mm, 0.0, False)
    nominal_ref = get(pupil_mm, 0.0, True) if reference == "glasses" else None
    if not robust:
        return Design(pupil_mm=pupil_mm, kernel=nominal, reference=nominal_ref, nominal=nominal,
                      nominal_reference=nominal_ref, notes=tuple(notes))
    if band.towards_sharper:                      # the offsets towards this eye's sharper side
        band = oriented_band(band, nominal.report.focus.residual.M_D)
        wanted = [(round(pupil_mm * f, 4), s) for f in band.pupil_factors for s in band.sphere_offsets_D]
    ks = [get(p, s, False) for p, s in wanted]
    rs = [get(p, 0.0, True) if reference == "glasses" else None for p, _ in wanted]
    if all(k.identity for k in ks) and all(r is None or r.identity for r in rs):
        notes.append("every eye of the band sees the display in focus: nothing to correct")
        return Design(pupil_mm=pupil_mm, kernel=nominal, reference=nominal_ref, nominal=nominal,
                      nominal_reference=nominal_ref, notes=tuple(notes))
    grid = design_grid([k.size for k in ks + [r for r in rs if r is not None]])
    spectra, targets = member_spectra([k.kernel for k in ks], [None if r is None else r.kernel for r in rs],
                                      nominal.matrix, grid)
    priors = [band.prior(i, j) for i in range(len(band.pupil_factors)) for j in range(len(band.sphere_offsets_D))]
    weights = member_weights(spectra, targets, priors, grid)
    U, R = effective_kernels(spectra, targets, weights, grid,
                             (FLOOR_REL + band.pull) * float(np.linalg.norm(nominal.matrix, 2)) ** 2,
                             radius=max(k.size for k in ks))
    members = tuple(Member(pupil_mm=float(k.report.focus.pupil_diameter_mm), sphere_offset_D=s, weight=float(w),
                           kernel_size=k.size) for k, (_, s), w in zip(ks, wanted, weights))
    kernels = {(m.pupil_mm, m.sphere_offset_D): (k, r) for m, k, r in zip(members, ks, rs)}
    return Design(pupil_mm=pupil_mm, kernel=_effective(nominal, U), reference=_effective(nominal, R),
                  nominal=nominal, nominal_reference=nominal_ref, members=members, robust=True, band=band,
                  notes=tuple(notes), _kernels=kernels)
