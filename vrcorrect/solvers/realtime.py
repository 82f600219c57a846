"""The real-time iterations frame by frame, on the CPU: the twins of the GPU strategies
(:mod:`vrcorrect.runtime.strategies`), used by ``vrcorrect bench realtime`` and the tests that hold
the GPU to them: :class:`AdmmFrames` (the default) and :class:`FistaFrames`, one frame interface
(``frame(target, iterations, shift=(dx, dy), cold=...)`` -> :class:`AdmmFrame`; motion in image
pixels, x to the right, y down, as ``Corrector.apply``'s ``motion_px``).

**ADMM over frames** (:class:`AdmmFrames`, the GPU's default).  ``fast``'s boundary-aware split
(:mod:`vrcorrect.solvers.admm`): on a periodic grid holding the image and a black surround, the
retina ``v = K u`` (its data term only inside the image) and the displayed image ``z = u`` (the box
[0, 1] inside, 0 outside), each step exact.  Written in the form that needs the least state, two
fields on the grid: ``w`` (the argument of the data step) and ``q`` (that of the box), from which
``v = prox(w)``, ``d1 = w - prox(w)``, ``z = proj(q)`` and ``d2 = q - proj(q)``.  One iteration:

    a1 = 2 prox(w) - w,   a2 = 2 proj(q) - q                       (reflections)
    U  = G (K^H A1 + n A2),   KU = K U                               (per frequency, exact)
    w += alpha (Ku - prox(w)),   q += alpha (u - proj(q))            (over-relaxed by alpha)

with ``A = F(a)``, ``G = (K^H K + n I)^-1``, ``n = balance ||K||^2`` (the kernel's spectral norm
squared, at DC, weighed by :data:`ADMM_BALANCE`: how the box split weighs against the retina
split), ``prox(w) = keep w + (1 - keep) T`` inside the image (``keep = rho ||K||^2 / (2 + rho ||K||^2)``) and
``w`` outside, ``proj(q) = clip(q, 0, 1)`` inside and 0 outside.  That is ``fast``'s iteration (the
same split, over-relaxation and steps) with penalties of its own, tuned for frames: ``rho``
:data:`ADMM_RHO` and ``balance`` :data:`ADMM_BALANCE` (``fast``: 0.1 and 1); one FFT round trip of
six real channels each.

* **Cold start** (the first frame, a cut, a new prescription): ``w = T`` on the whole grid (the
  target retina, ``K_ref t``, spilling into the surround), ``q = t`` inside and 0 outside: the
  target as the image with the retina it should make, zero duals.  Where a half-resolution level
  pays (:func:`~vrcorrect.solvers.admm.coarse_level_pays`) ``cold_iterations`` ADMM iterations at
  half resolution come first, ``fast``'s coarse-to-fine start
  (:data:`~vrcorrect.solvers.admm.COARSE_ITERATIONS` by default): the same iteration on the 2x2
  block means of the target (:func:`pool_half`) with the kernels those blocks see
  (:func:`~vrcorrect.solvers.admm.coarse_kernel`), cold-started; what they add to their own cold
  start (``w - T``, ``q - t``) is upsampled (:func:`upsample_double`) and added to this one's, so
  the target's finest detail, which the blocks cannot hold, stays in the start (upsampling the
  coarse state itself would blur it away: worse than the target alone for a mild blur).  A coarse
  iteration moves a quarter of the bytes of a full one.
* **Warm start**: the previous frame's ``w`` and ``q`` moved by the change of target inside the
  image, ``q += t - t_prev`` and ``w += T - T_prev`` (the surround, where neither the data term
  nor the box looks at the target, is kept as it is); with the content's whole-pixel motion ``d``
  the image's part of both is first reprojected (``x(p) <- x(p - d)``), the surround staying where
  it is (it belongs to the window, not to the content).  So does a band along the image's edges
  across the motion (:func:`edge_band`: the kernel's radius plus the motion's length on that
  axis): near the black surround the solution carries the edge's own correction (the light the
  surround does not send), which belongs to the window too; moved with the content it would be
  carried inward, wrong there, and the pixels the motion exposes (all in the band) would have
  none.  On a still view N frames of k iterations are N k iterations of ``fast``'s ADMM.
* **Guard**: after the iterations, ``z = proj(q)`` and the target ``t`` are transformed once more
  (``K z`` and ``K t``, one round trip) and the frame shown is ``t + beta (z - t)`` with the
  ``beta`` in [0, 1] that minimises the objective (:func:`~vrcorrect.solvers.guard_weight`): no
  frame is worse than uncorrected.

Per frame: ``k + 2`` FFT round trips (the target ``T = K_ref t``, ``k`` iterations, the guard).

**Storage precision.**  ``precision="half"`` rounds to IEEE half precision (``float16``) at every
point where the GPU stores a value in a 16-bit texture: the decoded target, the row spectra between
the passes, ``w``, ``q``, ``T`` and the kernels' spectra; arithmetic stays float32 (float64 for the
kernel's spectrum before it is rounded).  ``"single"`` stores float32.

Grid: the smallest 5-smooth length (``2^a 3^b 5^c``: the GPU's mixed-radix FFT) of at least the image
plus the kernel less one in each direction, the image at the origin (:func:`admm_grid`); spectra are
real-to-complex (half the columns, ``NX // 2 + 1``, for an odd ``NX`` too), as the GPU keeps them.

The per-frequency 3x3 algebra, the kernels' spectra and the FISTA twin's blur are
:mod:`vrcorrect.solvers.spectral`'s; the ADMM twin's transforms are its own (they round where the
GPU stores).

Layer 4: numpy and scipy.fft; no torch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import scipy.fft

from ..physics.kernel import EyeKernel
from ..plumbing.errors import ValidationError
from ..specs.vocabulary import ITERATIVE_FILTERS, Filter, Precision, either, names, one_of
from .admm import COARSE_ITERATIONS, coarse_kernel, coarse_level_pays
from .fista import FistaState, gradient_plan, projected_gradient
from .problem import guard_weight, light_cap, make_problem
from .spectral import (Blur, apply3, conj_transpose, hermitian_inverse, kernel_spectrum, smooth_length,
                       spectral_norm_squared)

__all__ = ["ADMM_RHO", "ADMM_RELAXATION", "ADMM_BALANCE", "admm_grid", "power_of_two_grid", "edge_band_widths",
           "edge_band", "pool_half", "upsample_double", "guarded",
           "coarse_eye_kernel", "coarse_kernel_size", "AdmmFrames", "AdmmFrame", "FistaFrames", "frames_twin",
           "admm_weights"]

ADMM_RHO = 0.2
"""The penalty, relative to ``||K||^2``: twice ``fast``'s 0.1.  Warm-started ADMM at two iterations a
frame keeps more of ``fast``'s gain on content that changes by more than a shift (the demo scene's
head turn, 256 px, quest2: 77 % of the objective gain at 0.2 against 73 % at 0.1, 75 % at 0.5),
with still views, pans and cuts unchanged to 1 %: a sweep of 0.1 to 1 with the over-relaxation at
1.6 and 1.8 (``docs/benchmarks.md``, real-time section)."""
ADMM_RELAXATION = 1.8           # fast's over-relaxation
ADMM_BALANCE = 0.5
"""The box split's weight in the data step, relative to ``||K||^2`` (``fast``'s: 1), the retina
split's penalty unchanged.  Lower converges faster: on the motion suite (CPU twin, 2 iterations a
frame) 0.5 lifts the share of ``fast``'s objective gain on every clip (zoom 81 % to 87 %, head turn
80 % to 87 %), and 0.1-0.2 would lift it further (93-94 %).  But faster convergence also reaches
sooner the ripples the objective's optimum carries into flat fields from a black surround: after
10 frames a flat grey departs from flat by 1 code value at 1, 5 at 0.5, 16 at 0.2 (the optimum:
about 34).  0.5 is the lowest tried that keeps flat fields within what
``test_flat_fields_come_back_unchanged_away_from_the_border`` allows (docs/realtime.md)."""
MIN_GRID = 16


def admm_weights(kernel: np.ndarray, rho: float = ADMM_RHO, balance: float = ADMM_BALANCE) -> tuple[float, float]:
    """``(keep, n)`` of the frame iteration (module docstring) for a ``(3, 3, s, s)`` kernel bank: the
    data step's ``keep = rho ||K||^2 / (2 + rho ||K||^2)`` and the box split's weight
    ``n = balance ||K||^2``; float64, for the CPU twin and the GPU's uniforms alike."""
    n2 = spectral_norm_squared(kernel)
    return rho * n2 / (2.0 + rho * n2), balance * n2


def admm_grid(width: int, height: int, kernel_size: int) -> tuple[int, int]:
    """The ``(NY, NX)`` grid of the ADMM strategy: the image at the origin and room for the blur of a
    ``kernel_size`` kernel around it (a linear convolution with no wrap-around), each side the
    smallest 5-smooth length (``2^a 3^b 5^c``, :func:`~vrcorrect.solvers.spectral.smooth_length`:
    what the GPU's mixed-radix line transforms take) of at least the image plus the kernel less one,
    and at least :data:`MIN_GRID`.  One Quest 2 eye (1832 x 1920, a 17 px kernel) is 1944 x 1875
    where a power-of-two grid was 2048 x 2048; a Quest 3 eye (2064 x 2208) 2250 x 2160 where it was
    4096 x 4096."""
    def side(n: int) -> int:
        return max(MIN_GRID, smooth_length(n + kernel_size - 1))

    return side(height), side(width)


def power_of_two_grid(width: int, height: int, kernel_size: int) -> tuple[int, int]:
    """The ``(NY, NX)`` power-of-two grid holding the image and the blur of a ``kernel_size`` kernel
    (the real-time grid before the mixed-radix transforms; the learned model's spectra keep it, since
    onnxruntime's DFT is a radix-2 FFT only on powers of two)."""
    def side(n: int) -> int:
        return max(MIN_GRID, 1 << math.ceil(math.log2(n + kernel_size - 1)))

    return side(height), side(width)


def edge_band_widths(shift: tuple[int, int], radius: int) -> tuple[int, int]:
    """The edge band's width ``(along x, along y)`` for a motion ``shift = (dx, dy)``: ``radius + |d|``
    on each axis the content moves along, 0 on an axis it does not (the GPU's ``u_band``)."""
    return tuple(radius + abs(int(d)) if int(d) else 0 for d in shift)


def edge_band(shape: tuple[int, int], shift: tuple[int, int], radius: int) -> np.ndarray:
    """The ``(H, W)`` mask of the pixels whose warm start stays with the window when the content
    moves by ``shift = (dx, dy)``: on each axis the motion has, the :func:`edge_band_widths` pixels
    next to each of the two edges across it (module docstring); none for no motion."""
    H, W = shape
    mx, my = edge_band_widths(shift, radius)
    band = np.zeros((H, W), bool)
    if mx:
        x = np.arange(W)
        band |= ((x < mx) | (x >= W - mx))[None, :]
    if my:
        y = np.arange(H)
        band |= ((y < my) | (y >= H - my))[:, None]
    return band


def pool_half(a: np.ndarray) -> np.ndarray:
    """2x2 block means of a ``(C, H, W)`` array, ``(C, ceil(H/2), ceil(W/2))``: block ``(j, i)``
    holds pixels ``2j, 2j + 1`` and ``2i, 2i + 1``, the last row or column repeated where ``H`` or
    ``W`` is odd; float32."""
    _, H, W = a.shape
    y0 = np.arange(0, H, 2)
    x0 = np.arange(0, W, 2)
    y1, x1 = np.minimum(y0 + 1, H - 1), np.minimum(x0 + 1, W - 1)
    a = np.asarray(a, np.float32)
    return ((a[:, y0][:, :, x0] + a[:, y0][:, :, x1] + a[:, y1][:, :, x0] + a[:, y1][:, :, x1])
            * np.float32(0.25)).astype(np.float32)


def upsample_double(a: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Bilinear upsampling of a ``(C, h, w)`` array of :func:`pool_half`'s blocks to ``(C, H, W)``:
    pixel ``y`` sits at block coordinate ``(y + 1/2) / 2 - 1/2`` (weights 3/4 and 1/4), clamped to
    the blocks (edges repeated); float32."""
    H, W = shape

    def axis(n_out: int, n_in: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        c = np.clip((np.arange(n_out) + 0.5) / 2 - 0.5, 0, n_in - 1)
        i0 = np.floor(c).astype(int)
        return i0, np.minimum(i0 + 1, n_in - 1), (c - i0).astype(np.float32)

    a = np.asarray(a, np.float32)
    y0, y1, fy = axis(H, a.shape[1])
    x0, x1, fx = axis(W, a.shape[2])
    rows = a[:, y0] * (1 - fy)[None, :, None] + a[:, y1] * fy[None, :, None]
    return (rows[:, :, x0] * (1 - fx) + rows[:, :, x1] * fx).astype(np.float32)


def coarse_kernel_size(size: int) -> int:
    """The size of :func:`~vrcorrect.solvers.admm.coarse_kernel` of a ``size`` px kernel."""
    return 2 * (((size + 2) // 2) // 2) + 1


def coarse_eye_kernel(kernel: EyeKernel) -> EyeKernel:
    """``kernel`` as an image of half the resolution sees it (:func:`~vrcorrect.solvers.admm.coarse_kernel`:
    2x2 pixel blocks; the sums, hence the colour matrix, unchanged)."""
    k = coarse_kernel(kernel.kernel)
    return replace(kernel, kernel=k, matrix=k.sum(axis=(2, 3)), pixels_per_degree=kernel.pixels_per_degree / 2)


def _store(a: np.ndarray, half: bool) -> np.ndarray:
    """What a texture holds of ``a``: float16 rounding (``half``) or float32."""
    return a.astype(np.float16).astype(np.float32) if half else a.astype(np.float32, copy=False)


def _store_complex(a: np.ndarray, half: bool) -> np.ndarray:
    if not half:
        return a.astype(np.complex64, copy=False)
    return (_store(a.real, True) + 1j * _store(a.imag, True)).astype(np.complex64)


@dataclass(frozen=True)
class AdmmFrame:
    """One frame of :class:`AdmmFrames`: the image shown (``(H, W, 3)`` float32), its objective
    (the mean squared LMS error of what the eye sees, as :func:`vrcorrect.solvers.objective`), the
    guard's weight, the solution before the guard and the uncorrected objective."""

    shown: np.ndarray
    objective: float
    beta: float
    solution: np.ndarray
    uncorrected: float


class AdmmFrames:
    """ADMM over frames for one eye and image size (module docstring).

    Parameters
    ----------
    kernel
        The eye's kernel.
    reference
        The glasses-on eye's kernel (the target ``T = K_ref t``), or ``None`` for the ideal target
        ``A t``.
    shape
        The images' ``(H, W)``.
    precision
        ``"half"`` or ``"single"`` storage (module docstring).
    rho, relaxation
        ADMM's penalty (relative to ``||K||^2``) and over-relaxation (``fast``'s).
    balance
        The box split's weight in the data step, relative to ``||K||^2`` (:data:`ADMM_BALANCE`;
        ``fast``'s is 1).
    cold_iterations
        Half-resolution iterations that start a cold frame, where that level pays (module
        docstring); 0: a cold frame starts from the target.
    edge_band
        Leave the edge band in place when the content moves (module docstring; the GPU always
        does: ``False`` is the earlier warm start, kept for the benchmark's comparison).
    cap
        The box's upper end is the frame target's light cap instead of 1
        (:func:`~vrcorrect.solvers.problem.light_cap`: a robust design's, as ``fast``'s
        ``Problem.capped``; the GPU's ``LIGHT_CAP``).
    """

    def __init__(self, kernel: EyeKernel, reference: EyeKernel | None, shape: tuple[int, int],
                 precision: str = Precision.HALF, rho: float = ADMM_RHO, relaxation: float = ADMM_RELAXATION,
                 cold_iterations: int = COARSE_ITERATIONS, edge_band: bool = True, balance: float = ADMM_BALANCE,
                 grid_kernel_size: int | None = None, cap: bool = False):
        if precision not in names(Precision):
            raise ValidationError("precision", precision, one_of(Precision))
        if not (isinstance(balance, (int, float)) and math.isfinite(balance) and balance > 0):
            raise ValidationError("balance", balance, "a positive number (the box split's weight relative to ||K||^2)")
        H, W = (int(v) for v in shape)
        self.shape = (H, W)
        self.half = precision == Precision.HALF
        self.radius = kernel.size // 2
        self.edge_band = edge_band
        self.cold_iterations = int(cold_iterations)
        self.cap = bool(cap)
        self.upper: np.ndarray | None = None            # with cap: this frame's light cap inside the image
        self.coarse: AdmmFrames | None = None
        if self.cold_iterations > 0 and coarse_level_pays(H, W, kernel.size):
            self.coarse = AdmmFrames(coarse_eye_kernel(kernel), None if reference is None else
                                     coarse_eye_kernel(reference), ((H + 1) // 2, (W + 1) // 2), precision, rho,
                                     relaxation, cold_iterations=0, balance=balance,
                                     grid_kernel_size=None if grid_kernel_size is None else coarse_kernel_size(grid_kernel_size),
                                     cap=cap)
        size = max(kernel.size, reference.size if reference is not None else 1, grid_kernel_size or 1)
        self.grid = P = admm_grid(W, H, size)
        self.rho, self.balance = rho, balance
        keep, n = admm_weights(kernel.kernel, rho, balance)
        self.box_weight = n                             # the box split's weight in the data step
        self._set_spectra(kernel, reference)
        self.keep = np.float32(keep)
        self.alpha = np.float32(relaxation)
        self.inside = np.zeros(P, bool)
        self.inside[:H, :W] = True
        self.w: np.ndarray | None = None
        self.q: np.ndarray | None = None
        self.t_prev: np.ndarray | None = None
        self.T_prev: np.ndarray | None = None

    def _spectrum(self, k: np.ndarray) -> np.ndarray:
        return kernel_spectrum(k, self.grid)

    def _set_spectra(self, kernel: EyeKernel, reference: EyeKernel | None) -> None:
        size = max(kernel.size, reference.size if reference is not None else 1)
        room = min(self.grid[0] - self.shape[0], self.grid[1] - self.shape[1]) + 1
        if size > room:
            raise ValidationError("kernel size", size, f"at most {room} px: what the grid this twin was made for "
                                                       "holds (grid_kernel_size)")
        self.Kf = _store_complex(self._spectrum(kernel.kernel), self.half)
        self.Rf = None if reference is None else _store_complex(self._spectrum(reference.kernel), self.half)
        self.A = kernel.matrix.astype(np.float32)
        self.G = hermitian_inverse(self.Kf.astype(np.complex128), self.box_weight).astype(np.complex64)  # as the GPU's
        self.Kh = np.ascontiguousarray(conj_transpose(self.Kf))

    def set_design(self, kernel: EyeKernel, reference: EyeKernel | None, cap: bool | None = None) -> None:
        """Go on with another design's kernel and reference (a pupil bank's switch,
        :mod:`vrcorrect.runtime.pupil_bank`): the spectra change, the state stays, so the next frame
        continues from where this one left (as the GPU's ``AdmmStrategy.swap_model``).  The grid stays
        (the kernels must fit it: ``grid_kernel_size``); so does the box weight (``||A||^2``: every
        design of one eye and display has it).  ``cap``: the new design's light cap (``Design.capped``:
        a switch of band, the GPU's ``u_cap_floor``), from the next frame; None keeps it."""
        self._set_spectra(kernel, reference)
        if cap is not None:
            self.cap = bool(cap)
        if self.coarse is not None:
            self.coarse.set_design(coarse_eye_kernel(kernel), None if reference is None else coarse_eye_kernel(reference),
                                   cap)

    # ------------------------------------------------------------------ transforms, as the GPU stores them

    def _forward(self, a: np.ndarray) -> np.ndarray:
        """Row transforms (stored), then column transforms (in the column pass, not stored)."""
        rows = _store_complex(scipy.fft.rfft(a, axis=-1, workers=-1), self.half)
        return scipy.fft.fft(rows, axis=-2, workers=-1).astype(np.complex64)

    def _inverse(self, A: np.ndarray) -> np.ndarray:
        """Column inverse transforms (the column pass stores their result), then row inverses."""
        cols = _store_complex(scipy.fft.ifft(A, axis=-2, workers=-1), self.half)
        return scipy.fft.irfft(cols, n=self.grid[1], axis=-1, workers=-1).astype(np.float32)

    def _on_grid(self, image_chw: np.ndarray) -> np.ndarray:
        g = np.zeros((3,) + self.grid, np.float32)
        g[:, :self.shape[0], :self.shape[1]] = image_chw
        return g

    def target(self, t: np.ndarray) -> np.ndarray:
        """``T`` on the grid: ``K_ref t`` (or ``A t``) for a ``(3, H, W)`` target."""
        if self.Rf is None:
            return self._on_grid(np.einsum("ij,jyx->iyx", self.A, t))
        return self._inverse(apply3(self.Rf, self._forward(self._on_grid(t))))

    def prox(self, w: np.ndarray, T: np.ndarray) -> np.ndarray:
        out = w.copy()
        out[:, self.inside] = self.keep * w[:, self.inside] + (1 - self.keep) * T[:, self.inside]
        return out

    def proj(self, q: np.ndarray) -> np.ndarray:
        z = np.clip(q, 0.0, 1.0)
        if self.upper is not None:
            H, W = self.shape
            np.minimum(z[:, :H, :W], self.upper, out=z[:, :H, :W])
        z[:, ~self.inside] = 0.0
        return z

    # ------------------------------------------------------------------ frames

    def reset(self) -> None:
        """The next frame starts cold."""
        self.w = self.q = self.t_prev = self.T_prev = self.upper = None

    def start(self, t: np.ndarray, T: np.ndarray, shift: tuple[int, int] | None = None,
              first_guess: np.ndarray | None = None) -> None:
        """This frame's starting ``w``, ``q`` (module docstring); ``shift``: the content's motion
        ``(dx, dy)`` in whole pixels (x right, y down); with no state: cold, from ``first_guess``
        (``(3, H, W)``, clipped to [0, 1]: ``q`` starts there, ``w`` at ``T``, no coarse level, as
        the GPU's cold-start hook) when one is given."""
        H, W = self.shape
        if self.w is None and first_guess is not None:
            self.w, self.q = T.copy(), self._on_grid(np.clip(np.asarray(first_guess, np.float32), 0.0, 1.0))
        elif self.w is None:
            self.w, self.q = T.copy(), self._on_grid(t)
            if self.coarse is not None:
                dw, dq = self.coarse.cold_correction(pool_half(t), self.cold_iterations)
                self.w[:, :H, :W] += upsample_double(dw, (H, W))
                self.q[:, :H, :W] += upsample_double(dq, (H, W))
        else:
            w, q = self.w.copy(), self.q.copy()
            t_prev, T_prev = self.t_prev, self.T_prev
            if shift is not None and tuple(shift) != (0, 0):
                band = edge_band((H, W), shift, self.radius) if self.edge_band else None
                w[:, :H, :W], q[:, :H, :W], t_prev, T_prev = (
                    self._reproject(a, shift, cold, band) for a, cold in
                    ((w[:, :H, :W], T[:, :H, :W]), (q[:, :H, :W], t), (t_prev, t), (T_prev, T[:, :H, :W])))
            w[:, :H, :W] += T[:, :H, :W] - T_prev
            q[:, :H, :W] += t - t_prev
            self.w, self.q = w, q
        self.w, self.q = _store(self.w, self.half), _store(self.q, self.half)
        self.upper = light_cap(t) if self.cap else None
        self.t_prev, self.T_prev = t, T[:, :H, :W].copy()

    def cold_correction(self, target_chw: np.ndarray, iterations: int) -> tuple[np.ndarray, np.ndarray]:
        """What ``iterations`` iterations from a cold start on the ``(3, H, W)`` target (stored as the
        GPU stores it) add to the start inside the image: ``w - T`` and ``q - t``.  The state is left
        cold (the next frame starts cold again)."""
        H, W = self.shape
        t, T, T_inside = self._targets(target_chw)
        self.reset()
        self.start(t, T)
        for _ in range(iterations):
            self.iterate(T)
        out = self.w[:, :H, :W] - T_inside, self.q[:, :H, :W] - t
        self.reset()
        return out

    @staticmethod
    def _reproject(a: np.ndarray, shift: tuple[int, int], cold: np.ndarray, band: np.ndarray | None = None
                   ) -> np.ndarray:
        """``(3, H, W)`` ``a`` moved by ``shift = (dx, dy)``; pixels the motion exposes from ``cold``;
        pixels in ``band`` (an ``(H, W)`` mask, :func:`edge_band`) not moved."""
        dx, dy = (int(v) for v in shift)
        _, H, W = a.shape
        out = cold.copy()
        if abs(dx) < W and abs(dy) < H:
            ys, yd = (slice(0, H - dy), slice(dy, H)) if dy >= 0 else (slice(-dy, H), slice(0, H + dy))
            xs, xd = (slice(0, W - dx), slice(dx, W)) if dx >= 0 else (slice(-dx, W), slice(0, W + dx))
            out[:, yd, xd] = a[:, ys, xs]
        if band is not None:
            out[:, band] = a[:, band]
        return out

    def iterate(self, T: np.ndarray) -> None:
        """One ADMM iteration on the state (module docstring)."""
        w, q = self.w, self.q
        pw, pq = self.prox(w, T), self.proj(q)
        A1 = self._forward(2 * pw - w)
        A2 = self._forward(2 * pq - q)
        R = apply3(self.Kh, A1) + np.float32(self.box_weight) * A2
        U = apply3(self.G, R)
        KU = apply3(self.Kf, U)
        u, Ku = self._inverse(U), self._inverse(KU)
        self.w = _store(w + self.alpha * (Ku - pw), self.half)
        self.q = _store(q + self.alpha * (u - pq), self.half)

    def frame(self, target: np.ndarray, iterations: int, shift: tuple[int, int] | None = None,
              cold: bool = False, first_guess: np.ndarray | None = None) -> AdmmFrame:
        """One frame: ``target`` ``(H, W, 3)`` linear RGB in [0, 1]; ``iterations`` ADMM iterations
        from the warm start (``cold``: from the target; ``shift``: the content's motion ``(dx,
        dy)``), then the guard. ``first_guess`` ``(H, W, 3)``: where a cold frame starts instead
        (the GPU's cold-start hook: the learned model's pass); ignored on a warm frame."""
        t_chw = _frame_target(target, self.shape)
        if cold:
            self.reset()
        t, T, T_inside = self._targets(t_chw)
        guess = None if first_guess is None else _store(_frame_target(first_guess, self.shape), self.half)
        self.start(t, T, shift, guess)
        for _ in range(iterations):
            self.iterate(T)
        return self.guard(t, T_inside)

    def _targets(self, target_chw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The target ``t`` as stored, ``T`` on the grid (inside the image as stored, as the GPU keeps
        it) and ``T``'s inside part."""
        H, W = self.shape
        t = _store(target_chw, self.half)
        T = self.target(t)
        T_inside = _store(T[:, :H, :W], self.half)
        T = T.copy()
        T[:, :H, :W] = T_inside
        return t, T, T_inside

    def guard(self, t: np.ndarray, T_inside: np.ndarray) -> AdmmFrame:
        H, W = self.shape
        z = self.proj(self.q)[:, :H, :W]
        Kz = self._inverse(apply3(self.Kf, self._forward(self._on_grid(z))))[:, :H, :W]
        Kt = self._inverse(apply3(self.Kf, self._forward(self._on_grid(t))))[:, :H, :W]
        return guarded(t, z, (Kt - T_inside).astype(np.float64), (Kz - Kt).astype(np.float64))


def _frame_target(target: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A frame's ``(H, W, 3)`` target as ``(3, H, W)`` float32 planes, refused at another size."""
    H, W = shape
    t = np.ascontiguousarray(np.moveaxis(np.asarray(target, np.float32), 2, 0))
    if t.shape != (3, H, W):
        raise ValidationError("target", f"shape {np.shape(target)}", f"({H}, {W}, 3)")
    return t


def guarded(t: np.ndarray, z: np.ndarray, r0: np.ndarray, kd: np.ndarray) -> AdmmFrame:
    """The guard of both twins (module docstring): the frame ``t + beta (z - t)`` for a ``(3, H, W)``
    target ``t`` and solution ``z``, with :func:`~vrcorrect.solvers.guard_weight`'s weight from the
    uncorrected residual ``r0 = K t - T`` and the change ``kd = K (z - t)`` (float64)."""
    s_rk, s_kk, s_rr = float(np.vdot(r0, kd)), float(np.vdot(kd, kd)), float(np.vdot(r0, r0))
    beta = guard_weight(s_rk, s_kk, s_rr)
    n = float(r0.size)
    shown = t + np.float32(beta) * (z - t)
    return AdmmFrame(shown=np.ascontiguousarray(np.moveaxis(shown, 0, 2)),
                     objective=(s_rr + 2 * beta * s_rk + beta * beta * s_kk) / n, beta=beta,
                     solution=np.ascontiguousarray(np.moveaxis(z, 0, 2)), uncorrected=s_rr / n)


class FistaFrames:
    """Projected gradient (FISTA) over frames for one eye and image size: the twin of the GPU's
    ``method="fista"`` (:mod:`vrcorrect.runtime.strategies.fista`), with the same frame interface
    as :class:`AdmmFrames`.

    Each frame: the warm start (cold: ``x = y = t``; warm: ``x = clip(x + t - t_prev)``,
    ``y = y + t - t_prev``, FISTA's momentum kept; with the content's motion ``(dx, dy)`` both first
    reprojected, exposed pixels from ``t``), ``iterations`` steps of
    :func:`~vrcorrect.solvers.fista.projected_gradient` continued from that state, then the guard
    (the best blend of ``x`` with ``t``).  float32 throughout, as the GPU (32-bit storage)."""

    def __init__(self, kernel: EyeKernel, reference: EyeKernel | None, shape: tuple[int, int]):
        H, W = (int(v) for v in shape)
        self.shape = (H, W)
        self.kernel, self.reference = kernel, reference
        self.plan = gradient_plan(kernel, (H, W))
        size = max(kernel.size, reference.size if reference is not None else 1)
        self.grid = admm_grid(W, H, size)
        self.K = Blur(kernel_spectrum(kernel.kernel, self.grid), self.grid, (H, W))       # the guard's, float64
        self.R = None if reference is None else Blur(kernel_spectrum(reference.kernel, self.grid), self.grid, (H, W))
        self.A = kernel.matrix
        self.state = None
        self.t_prev: np.ndarray | None = None

    def reset(self) -> None:
        self.state = self.t_prev = None

    def frame(self, target: np.ndarray, iterations: int, shift: tuple[int, int] | None = None,
              cold: bool = False) -> AdmmFrame:
        t = _frame_target(target, self.shape)
        if cold:
            self.reset()
        start = None
        if self.state is not None:
            x, y, t_prev = self.state.x, self.state.y, self.t_prev
            if shift is not None and tuple(shift) != (0, 0):
                x, y, t_prev = (AdmmFrames._reproject(a, shift, t) for a in (x, y, t_prev))
            change = t - t_prev
            start = FistaState(x=np.clip(x + change, 0.0, 1.0), y=y + change, momentum=self.state.momentum)
        problem = make_problem(np.moveaxis(t, 0, 2), self.kernel, self.reference)
        x, self.state = projected_gradient(problem, iterations, self.plan, state=start, return_state=True)
        self.t_prev = t
        z = np.ascontiguousarray(np.moveaxis(x, 2, 0))
        t64 = t.astype(np.float64)
        T = np.einsum("ij,jyx->iyx", self.A, t) if self.R is None else self.R.apply(t64)
        r0 = self.K.apply(t64) - T
        return guarded(t, z, r0, self.K.apply(z.astype(np.float64)) - T - r0)


def frames_twin(method: str, kernel: EyeKernel, reference: EyeKernel | None, shape: tuple[int, int],
                precision: str = Precision.HALF, cold_iterations: int = COARSE_ITERATIONS,
                edge_band: bool = True, balance: float = ADMM_BALANCE, cap: bool = False) -> "AdmmFrames | FistaFrames":
    """The CPU twin of the GPU's ``method`` (``"admm"`` or ``"fista"``) for one eye and image size
    (``cold_iterations``, ``edge_band``, ``balance``, ``cap``: ADMM's, see :class:`AdmmFrames`)."""
    if method == Filter.ADMM:
        return AdmmFrames(kernel, reference, shape, precision=precision, cold_iterations=cold_iterations,
                          edge_band=edge_band, balance=balance, cap=cap)
    if method == Filter.FISTA:
        return FistaFrames(kernel, reference, shape)
    raise ValidationError("method", method, either(ITERATIVE_FILTERS) + " (the methods that iterate over frames)")
