"""The ``wiener`` method: closed-form correction in one pass (numpy only; the mathematics of the
real-time one-pass filters, ``fft`` and ``separable``).

Per spatial frequency f, with the eye's 3x3 kernel spectrum ``K(f)`` (cones x
primaries) and the target operator ``T(f)`` (``A``, the target's cone image with
no blur, or the glasses-on eye's kernel spectrum), the inverse regularised toward
the target, ``argmin_x ||K x - T t||^2 + mu ||x - t||^2``,

    x = t + (K^H K + mu I)^-1 K^H (T - K) t,   F(f) = (K^H K + mu I)^-1 (K^H T(f) + mu I)

(3 x 3: primaries out x primaries in), maps the target RGB image to the displayed
one.  ``F(0) = I`` (both kernels sum to the colour matrix ``A``), so a flat field
comes back unchanged; the toward-zero inverse ``(K^H K + mu I)^-1 K^H T`` would
shrink it along ``A``'s weak directions and tint it (docs/architecture.md,
'Physics conventions').  :func:`correction_filters` designs ``F`` once per eye as a
bank of 3 x 3 spatial filters, truncated to the smallest square holding all but
``tolerance`` of their absolute sum; the same taps run on the CPU (here, by FFT) and
on the GPU (the runtime's separable low-rank passes), with mirrored image borders in
both.  :func:`wiener` then clips ``v = F t`` to [0, 1] and blends it with the
target by the weight that minimises the true objective (closed form,
:func:`~vrcorrect.solvers.guard_weight`; the blur ``K`` is
:class:`~vrcorrect.solvers.spectral.Blur`).  ``mu``
(relative to the largest eigenvalue of ``K^H K``) is chosen from a few values; the
blend weight 0 is no correction, so the result is never worse than no correction.  Contrast
compression of the target is the separate ``contrast`` option of every method.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import scipy.fft

from ..physics.kernel import EyeKernel
from .problem import Correction, Problem, guard_weight, scale_contrast
from .spectral import (Blur, apply3, centred_kernel, irfft_grid, kernel_spectrum, margin_shape, mirror_fill,
                       padded_shape, rfft_grid, spectral_norm_squared)

DEFAULT_REGULARISATION = (0.03, 0.1, 0.3)
DESCENT_STEP = 4.0
MAX_DESIGN_GRID = 2048
DESIGN_TOLERANCE = 1e-3       # largest discarded absolute sum of the filters of one output primary


@dataclass(frozen=True, eq=False)
class CorrectionFilters:
    """The regularised inverse of one eye as spatial filters (see :func:`correction_filters`).

    Attributes
    ----------
    taps
        ``(3, 3, S, S)`` float64, ``taps[i, j]`` maps input primary ``j`` to output primary ``i``;
        centred (``S`` odd), applied as a convolution ``out_i = sum_j taps[i, j] * in_j``.
    mu_rel
        Regulariser relative to the largest eigenvalue of ``K^H K``.
    tail
        Largest discarded absolute sum of one output primary's filters (the truncation error bound
        for inputs in [0, 1]).
    design_grid
        FFT grid on which the filters were designed (``N x N``).
    """

    taps: np.ndarray
    mu_rel: float
    tail: float
    design_grid: int

    @property
    def size(self) -> int:
        return int(self.taps.shape[-1])


def _chebyshev_tails(f: np.ndarray) -> np.ndarray:
    """``tails[r]``: the largest over output primaries of ``sum_j sum_{|y|,|x| > r} |f_ij|`` for an
    origin-centred (wrapped) ``(3, 3, N, N)`` bank (r = 0 .. N/2)."""
    N = f.shape[-1]
    idx = np.minimum(np.arange(N), N - np.arange(N))                     # wrapped distance to 0
    d = np.maximum(idx[:, None], idx[None, :]).ravel()
    per_out = np.abs(f).sum(axis=1).reshape(3, -1)                      # (3 out, N*N)
    tails = []
    for row in per_out:
        ring = np.bincount(d, weights=row, minlength=N // 2 + 1)       # mass at Chebyshev radius r
        tails.append(row.sum() - np.cumsum(ring))                       # mass outside radius r
    return np.max(tails, axis=0)


def _inverse_spectrum(kernel: EyeKernel, reference_kernel: EyeKernel | None, mu: float,
                      shape: tuple[int, int], full: bool = False) -> np.ndarray:
    """``F(f) = (K^H K + mu I)^-1 (K^H T(f) + mu I)`` on a periodic ``shape`` grid (origin-centred
    kernels), ``(3, 3, P0, P1 // 2 + 1)`` complex (``full``: ``(3, 3, P0, P1)``); the 3x3 algebra
    in blocks of rows (bounded memory).

    This is the Tikhonov solution regularised toward the target, ``argmin ||K x - T t||^2 +
    mu ||x - t||^2 = t + (K^H K + mu I)^-1 K^H (T - K) t``, as one filter on ``t``.  At DC both
    ``K`` and ``T`` are the colour matrix ``A`` (the kernels' sums), so ``F(0) = I``: a flat field
    comes back unchanged (the toward-zero ``(K^H K + mu I)^-1 K^H T`` shrinks it along ``A``'s weak
    directions and tints it)."""
    fft = (lambda a: scipy.fft.fft2(a, axes=(2, 3), workers=-1)) if full else \
        (lambda a: scipy.fft.rfft2(a, axes=(2, 3), workers=-1))
    Kf = fft(centred_kernel(kernel.kernel, shape))
    Tf = fft(centred_kernel(reference_kernel.kernel, shape)) if reference_kernel is not None else None
    Ff = np.empty_like(Kf)
    eye = mu * np.eye(3)
    for r0 in range(0, shape[0], 128):
        Kb = np.moveaxis(Kf[:, :, r0:r0 + 128], (0, 1), (2, 3))           # (rows, F1, 3, 3)
        Kh = np.conj(np.swapaxes(Kb, 2, 3))
        rhs = Kh @ (kernel.matrix if Tf is None else np.moveaxis(Tf[:, :, r0:r0 + 128], (0, 1), (2, 3)))
        Ff[:, :, r0:r0 + 128] = np.moveaxis(np.linalg.solve(Kh @ Kb + eye, rhs + eye), (2, 3), (0, 1))
    return Ff


def inverse_spectrum(kernel: EyeKernel, mu_rel: float, shape: tuple[int, int],
                     reference_kernel: EyeKernel | None = None) -> np.ndarray:
    """The regularised inverse's full complex spectrum ``(3, 3, *shape)`` on a periodic grid
    (the real-time FFT path uploads it); ``mu_rel`` relative to ``||K||^2``."""
    return _inverse_spectrum(kernel, reference_kernel, mu_rel * spectral_norm_squared(kernel.kernel), shape,
                             full=True)


def _regularised_inverse(kernel: EyeKernel, reference_kernel: EyeKernel | None, mu: float,
                         shape: tuple[int, int]) -> np.ndarray:
    """Spatial ``F`` on a periodic ``shape`` grid, origin-centred, ``(3, 3, *shape)`` float64."""
    return irfft_grid(_inverse_spectrum(kernel, reference_kernel, mu, shape), shape)


def _exact_inverse_image(image_chw: np.ndarray, kernel: EyeKernel, reference_kernel: EyeKernel | None,
                         mu: float, grid: tuple[int, int] | None = None, margin: int | None = None) -> np.ndarray:
    """``F t`` without truncation on a periodic grid holding the image at ``(margin, margin)``
    and its mirrored repeat around it (default: one kernel width of margin, the next fast FFT
    size).  The real-time FFT path computes exactly this on its (5-smooth) grid."""
    _, H, W = image_chw.shape
    m = margin if margin is not None else max(kernel.size, reference_kernel.size if reference_kernel is not None else 1)
    Q = grid if grid is not None else margin_shape(H, W, m)
    X = rfft_grid(mirror_fill(image_chw.astype(np.float64), Q, m), Q)
    y = irfft_grid(apply3(_inverse_spectrum(kernel, reference_kernel, mu, Q), X), Q)
    return y[:, m:m + H, m:m + W]


def _first_design_grid(kernel: EyeKernel, reference_kernel: EyeKernel | None) -> int:
    """The side of the first grid :func:`correction_filters` designs on: 8 kernel widths, at
    least 64, a power of two."""
    widths = [kernel.size] + ([reference_kernel.size] if reference_kernel is not None else [])
    return max(64, 1 << int(np.ceil(np.log2(8 * max(widths)))))


@functools.lru_cache(maxsize=32)
def correction_filters(kernel: EyeKernel, mu_rel: float, reference_kernel: EyeKernel | None = None,
                       tolerance: float = DESIGN_TOLERANCE) -> CorrectionFilters:
    """Design the regularised inverse ``F = (K^H K + mu I)^-1 (K^H T + mu I)`` as spatial filters.

    Parameters
    ----------
    kernel
        The eye's kernel (not the identity kernel: see :func:`wiener`).
    mu_rel
        Regulariser relative to the largest eigenvalue of ``K^H K`` (> 0).
    reference_kernel
        The glasses-on eye (``T = K_ref``); ``None``: the ideal target ``T = A``.
    tolerance
        Truncation: the filters keep the smallest centred square whose discarded absolute sum
        is at most this, per output primary (so the error for inputs in [0, 1] is at most this).
        The truncated taps' sums are then set back to ``F(0) = I`` exactly (the discarded sum
        added to the centre tap), so flat fields stay exact.

    The design grid starts at 8 kernel widths (at least 64) and doubles (to ``MAX_DESIGN_GRID`` at most)
    until the filters' mass near the grid's edge is negligible, so the periodic design
    does not alias their tails.  Designs are cached per (kernel object, mu_rel, reference,
    tolerance): one eye's filters are designed once, whatever the number of images.
    """
    if not mu_rel > 0:
        raise ValueError(f"mu_rel must be > 0, got {mu_rel!r}")
    N = _first_design_grid(kernel, reference_kernel)
    lam_max = spectral_norm_squared(kernel.kernel)
    while True:
        f = _regularised_inverse(kernel, reference_kernel, mu_rel * lam_max, (N, N))
        tails = _chebyshev_tails(f)
        edge = tails[N // 2 - N // 8]                                          # mass in the outer eighth
        if edge <= 0.01 * tolerance or N >= MAX_DESIGN_GRID:
            break
        N *= 2
    r = int(np.argmax(tails <= tolerance)) if np.any(tails <= tolerance) else N // 2
    idx = np.arange(-r, r + 1) % N
    taps = np.ascontiguousarray(f[:, :, idx[:, None], idx[None, :]])
    taps[:, :, r, r] += np.eye(3) - taps.sum(axis=(2, 3))                  # DC gain exactly I
    return CorrectionFilters(taps=taps, mu_rel=float(mu_rel), tail=float(tails[r]) if r < len(tails) else 0.0,
                             design_grid=N)


def apply_filters(image_chw: np.ndarray, taps: np.ndarray) -> np.ndarray:
    """``out_i = sum_j taps[i, j] * image_j`` with mirrored borders (edge pixel repeated:
    numpy's ``symmetric``, OpenGL's ``MIRRORED_REPEAT``), by FFT; float32 ``(3, H, W)``."""
    _, H, W = image_chw.shape
    r = taps.shape[-1] // 2
    Q = margin_shape(H, W, r)
    x = np.pad(image_chw.astype(np.float32), ((0, 0), (r, r), (r, r)), mode="symmetric")
    X = rfft_grid(x, Q)
    y = irfft_grid(apply3(kernel_spectrum(taps, Q, np.float32), X), Q)
    return y[:, r:r + H, r:r + W].astype(np.float32)


def _best_on_simplex(r0: np.ndarray, dirs: list[np.ndarray]) -> tuple[list[float], float]:
    """Minimise ``||r0 + sum_i b_i a_i||^2`` over ``b_i >= 0``, ``sum b_i <= 1`` for one or two
    directions ``a_i`` (closed form: the convex quadratic's minimum is the interior stationary
    point or lies on an edge, each a clipped 1-D solve, :func:`~vrcorrect.solvers.guard_weight`);
    returns (weights, objective sum)."""
    c = np.array([float(np.sum(r0 * a)) for a in dirs])
    A = np.array([[float(np.sum(a * b)) for b in dirs] for a in dirs])
    base = float(np.sum(r0 * r0))

    def value(b: np.ndarray) -> float:
        return base + 2.0 * float(c @ b) + float(b @ A @ b)

    def line(p: np.ndarray, q: np.ndarray) -> np.ndarray:           # best point on segment p..q
        d = q - p
        return p + guard_weight(float(c @ d + p @ A @ d), float(d @ A @ d)) * d

    n = len(dirs)
    vertices = [np.zeros(n)] + [np.eye(n)[i] for i in range(n)]
    candidates = [line(vertices[0], v) for v in vertices[1:]]
    if n == 2:
        candidates.append(line(vertices[1], vertices[2]))
        if abs(np.linalg.det(A)) > 1e-12 * max(A[0, 0] * A[1, 1], 1e-300):
            b = np.linalg.solve(A, -c)
            if b.min() >= 0 and b.sum() <= 1:
                candidates.append(b)
    best = min(candidates, key=value)
    return [float(x) for x in best], value(best)


def wiener(problem: Problem, regularisation: Sequence[float] = DEFAULT_REGULARISATION,
           beta: float | None = None, tolerance: float = DESIGN_TOLERANCE,
           design: bool | None = None, grid: tuple[int, int] | None = None,
           margin: int | None = None, descent: bool = True,
           progress: Callable[[int, int], None] | None = None) -> Correction:
    """Best blend of the target and the clipped regularised inverse (one pass: ``progress`` is not
    called); the :class:`~vrcorrect.solvers.Correction` holds the image and the settings chosen.

    For each ``mu_rel`` in ``regularisation``: ``v = F t'`` (the inverse regularised toward the
    target, ``F(0) = I``: flat areas are kept as they are; :func:`correction_filters`,
    :func:`apply_filters`; ``t'`` the contrast-scaled target) clipped to [0, 1], then
    ``x = t + beta (clip(v) - t)`` with ``beta`` in [0, 1] minimising the objective in closed
    form (it is quadratic in ``beta``, and every blend of two images in [0, 1] stays in
    [0, 1]); ``beta = 0`` is no correction, so the result is never worse than no correction.
    A fixed ``beta`` (the real-time path's, chosen once per eye) skips that choice.
    ``design=False`` skips the filter design and applies the untruncated inverse on a
    mirror-filled FFT grid (cheaper for one image; the real-time FFT path computes it on the GPU:
    ``grid`` and ``margin`` give its grid, see
    :func:`_exact_inverse_image`).  ``design=None`` (the default) models only what the image
    needs: it designs (and caches) the filters when their first design grid, 8 kernel widths, is
    no larger than the image's own padded grid, and otherwise applies the untruncated inverse on
    the image's grid (a strong eye on a small image: designing on a 1024-2048 px grid took 40 s
    at 256 px for -6 / -2 x 30 with a 5 mm pupil on desktop, the image's grid 2 s, and the
    untruncated inverse is the more exact of the two).

    ``descent`` (with automatic ``beta``) adds a second direction: one projected-gradient step
    from the target, ``g = clip(t - s K^H (K t - t_lms)) - t`` (step ``s`` = 4 / ||K||^2).  It
    is a descent direction whenever the target is not already optimal in the box, so the best
    blend ``x = t + b1 (clip(v) - t) + b2 g`` (``b1, b2 >= 0``, ``b1 + b2 <= 1``: a convex
    combination of three images in [0, 1], solved in closed form) is *strictly* below no
    correction, also where the inverse alone clips so hard that its own blend weight is 0
    (binary charts, strong prescriptions).  The real-time path blends along the inverse only
    (``descent=False``: one weight per frame, computed on the GPU).
    """
    H, W = problem.target.shape[:2]
    if problem.kernel.size == 1:
        x = np.clip(problem.target_lms @ np.linalg.inv(problem.kernel.matrix).T, 0, 1).astype(np.float32)
        return Correction(x, settings={"chosen": "colour matrix (identity kernel)", "beta": 1.0, "mu_rel": 0.0})
    if beta is not None and not 0.0 <= beta <= 1.0:
        raise ValueError(f"beta must be in [0, 1], got {beta!r}")
    P = padded_shape(H, W, problem.kernel.size)
    if design is None:
        design = _first_design_grid(problem.kernel, problem.reference_kernel) <= max(P)
    K = Blur.of(problem.kernel.kernel, (H, W), P)                     # exact, black outside the image
    t_lms = np.moveaxis(problem.target_lms.astype(np.float64), 2, 0)
    t_rgb = np.moveaxis(problem.target.astype(np.float64), 2, 0)
    t_in = np.moveaxis(scale_contrast(problem.target, problem.contrast), 2, 0)
    r0 = K.apply(t_rgb) - t_lms
    best = (float(np.mean(r0 * r0)), t_rgb, {"chosen": "no correction", "beta": 0.0, "mu_rel": None})
    step_dir = step_K = None
    if descent and beta is None:
        s = DESCENT_STEP / spectral_norm_squared(problem.kernel.kernel)
        step_dir = np.clip(t_rgb - s * K.adjoint(r0), 0.0, 1.0) - t_rgb
        step_K = K.apply(step_dir)
    tried = []
    for mu_rel in regularisation:
        if design:
            filters = correction_filters(problem.kernel, mu_rel, problem.reference_kernel, tolerance)
            v = apply_filters(t_in, filters.taps).astype(np.float64)
            size, tail = filters.size, filters.tail
        else:
            lam_max = spectral_norm_squared(problem.kernel.kernel)
            v = _exact_inverse_image(t_in, problem.kernel, problem.reference_kernel, mu_rel * lam_max, grid, margin)
            size, tail = None, 0.0
        d = np.clip(v, 0.0, 1.0) - t_rgb
        Kd = K.apply(d)
        b2 = 0.0
        if beta is not None:
            b = float(beta)
        elif step_dir is not None:
            (b, b2), _ = _best_on_simplex(r0, [Kd, step_K])
        else:
            (b,), _ = _best_on_simplex(r0, [Kd])
        x = t_rgb + b * d
        res = r0 + b * Kd
        if b2 > 0:
            x = x + b2 * step_dir
            res = res + b2 * step_K
        obj = float(np.mean(res * res))
        tried.append({"mu_rel": mu_rel, "beta": b, "descent_weight": b2, "objective": obj, "filter_size": size,
                      "clipped_fraction": float(np.mean((v < 0) | (v > 1)))})
        if obj < best[0] or beta is not None:
            best = (obj, x, {"chosen": "blend of target and clipped regularised inverse"
                             + (" and a projected-gradient step" if b2 > 0 else ""), "beta": b,
                             "descent_weight": b2, "mu_rel": mu_rel, "filter_size": size, "filter_tail": tail})
    settings = dict(best[2])
    settings["candidates"] = tried
    return Correction(np.clip(np.moveaxis(best[1], 0, 2), 0.0, 1.0).astype(np.float32), settings=settings)
