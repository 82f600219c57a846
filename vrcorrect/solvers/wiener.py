"""Closed-form correction in one pass (numpy only; the GLSL fallback's mathematics).

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
target by the weight that minimises the true objective (closed form).  ``mu``
(relative to the largest eigenvalue of ``K^H K``) is chosen from a few values; the
blend weight 0 is no correction, so the result is never worse than no correction.  Contrast
compression of the target is the separate ``contrast`` option of every method.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.fft

from ..physics.kernel import EyeKernel
from ..plumbing.errors import ValidationError
from ..vision.forward import check_image
from . import Problem, scale_contrast

DEFAULT_REGULARISATION = (0.03, 0.1, 0.3)
DESCENT_STEP = 4.0
MAX_DESIGN_GRID = 2048
DESIGN_TOLERANCE = 1e-3       # largest discarded absolute sum of the filters of one output primary


def padded_shape(height: int, width: int, kernel_size: int) -> tuple[int, int]:
    """FFT size that holds a linear convolution of the image with the kernel without wrap-around."""
    return (scipy.fft.next_fast_len(height + kernel_size - 1, real=True),
            scipy.fft.next_fast_len(width + kernel_size - 1, real=True))


def centred_kernel(kernel: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``(..., s, s)`` kernel zero-padded to ``shape`` with its centre wrapped to the origin,
    so the circular convolution on that grid has no shift."""
    s = kernel.shape[-1]
    out = np.zeros(kernel.shape[:-2] + tuple(shape), dtype=kernel.dtype)
    ys = (np.arange(s) - s // 2) % shape[0]
    xs = (np.arange(s) - s // 2) % shape[1]
    out[..., ys[:, None], xs[None, :]] = kernel
    return out


def spectral_norm_squared(kernel: np.ndarray) -> float:
    """Largest eigenvalue of K^H K over all frequencies (the kernel's spectral norm squared).

    The kernel is non-negative, so ``|K(f)| <= K(0) = A`` entrywise and, by
    Perron-Frobenius monotonicity, ``||K(f)|| <= ||A||``: the maximum is at DC.
    """
    return float(np.linalg.norm(kernel.sum(axis=(-2, -1)), 2) ** 2)


def inv3(M):
    """Inverse of 3x3 matrices stored as planes ``(3, 3, ...)``, by cofactors (numpy or torch)."""
    a, b, c = M[0, 0], M[0, 1], M[0, 2]
    d, e, f = M[1, 0], M[1, 1], M[1, 2]
    g, h, i = M[2, 0], M[2, 1], M[2, 2]
    A_, B_, C_ = e * i - f * h, f * g - d * i, d * h - e * g
    inv_det = 1.0 / (a * A_ + b * B_ + c * C_)
    out = M * 0
    out[0, 0], out[0, 1], out[0, 2] = A_ * inv_det, (c * h - b * i) * inv_det, (b * f - c * e) * inv_det
    out[1, 0], out[1, 1], out[1, 2] = B_ * inv_det, (a * i - c * g) * inv_det, (c * d - a * f) * inv_det
    out[2, 0], out[2, 1], out[2, 2] = C_ * inv_det, (b * g - a * h) * inv_det, (a * e - b * d) * inv_det
    return out


def matmul3(A, B, conj_a: bool = False, transpose_a: bool = False):
    """Per-frequency product of 3x3 plane stacks: ``out[i, j] = sum_k op(A)[i, k] B[k, j]``
    with ``op`` an optional conjugate and/or transpose (numpy or torch)."""
    out = B * 0
    for i in range(3):
        for j in range(3):
            acc = None
            for k in range(3):
                a = A[k, i] if transpose_a else A[i, k]
                if conj_a:
                    a = a.conj()
                term = a * B[k, j]
                acc = term if acc is None else acc + term
            out[i, j] = acc
    return out


def apply3(M, x):
    """Per-frequency matrix-vector product ``out[i] = sum_j M[i, j] x[j]`` (numpy or torch)."""
    out = x * 0
    for i in range(3):
        out[i] = M[i, 0] * x[0] + M[i, 1] * x[1] + M[i, 2] * x[2]
    return out


def gram(Kf):
    """``K^H K`` per frequency for spectra stored as planes ``(cones, primaries, ...)``."""
    return matmul3(Kf, Kf, conj_a=True, transpose_a=True)


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


def mirror_fill(image_chw: np.ndarray, shape: tuple[int, int], margin: int) -> np.ndarray:
    """The image on a periodic ``shape`` grid at offset ``(margin, margin)``, the rest of the grid
    filled by mirrored repeat (edge pixel repeated, period twice the image)."""
    _, H, W = image_chw.shape

    def mirror(i, n):
        m = np.mod(i, 2 * n)
        return np.where(m < n, m, 2 * n - 1 - m)

    ys = mirror(np.arange(shape[0]) - margin, H)
    xs = mirror(np.arange(shape[1]) - margin, W)
    return image_chw[:, ys[:, None], xs[None, :]]


def _regularised_inverse(kernel: EyeKernel, reference_kernel: EyeKernel | None, mu: float,
                         shape: tuple[int, int]) -> np.ndarray:
    """Spatial ``F`` on a periodic ``shape`` grid, origin-centred, ``(3, 3, *shape)`` float64."""
    return scipy.fft.irfft2(_inverse_spectrum(kernel, reference_kernel, mu, shape), s=shape, axes=(2, 3),
                            workers=-1)


def _exact_inverse_image(image_chw: np.ndarray, kernel: EyeKernel, reference_kernel: EyeKernel | None,
                         mu: float, grid: tuple[int, int] | None = None, margin: int | None = None) -> np.ndarray:
    """``F t`` without truncation on a periodic grid holding the image at ``(margin, margin)``
    and its mirrored repeat around it (default: one kernel width of margin, the next fast FFT
    size).  The real-time FFT path computes exactly this on its power-of-two grid."""
    _, H, W = image_chw.shape
    m = margin if margin is not None else max(kernel.size, reference_kernel.size if reference_kernel is not None else 1)
    Q = grid if grid is not None else (scipy.fft.next_fast_len(H + 2 * m, real=True),
                                       scipy.fft.next_fast_len(W + 2 * m, real=True))
    X = scipy.fft.rfft2(mirror_fill(image_chw.astype(np.float64), Q, m), axes=(1, 2), workers=-1)
    y = scipy.fft.irfft2(apply3(_inverse_spectrum(kernel, reference_kernel, mu, Q), X), s=Q, axes=(1, 2),
                         workers=-1)
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
    Q = (scipy.fft.next_fast_len(H + 2 * r, real=True), scipy.fft.next_fast_len(W + 2 * r, real=True))
    x = np.pad(image_chw.astype(np.float32), ((0, 0), (r, r), (r, r)), mode="symmetric")
    X = scipy.fft.rfft2(x, s=Q, axes=(1, 2), workers=-1)
    Ff = scipy.fft.rfft2(centred_kernel(taps, Q).astype(np.float32), axes=(2, 3), workers=-1)
    y = scipy.fft.irfft2(apply3(Ff, X), s=Q, axes=(1, 2), workers=-1)
    return y[:, r:r + H, r:r + W].astype(np.float32)


class _FastObjective:
    """The objective with the kernel's spectrum computed once (exact linear convolution, zero outside)."""

    def __init__(self, problem: Problem, Kf: np.ndarray, P: tuple[int, int]):
        self.Kf, self.P = Kf, P
        self.H, self.W = problem.target.shape[:2]
        self.t = np.moveaxis(problem.target_lms.astype(np.float64), 2, 0)

    def residual(self, x_chw: np.ndarray, offset: bool = True) -> np.ndarray:
        """``K x - t`` on the image (or ``K x`` without ``offset``), (3, H, W)."""
        X = scipy.fft.rfft2(x_chw, s=self.P, axes=(1, 2), workers=-1)
        y = scipy.fft.irfft2(apply3(self.Kf, X), s=self.P, axes=(1, 2), workers=-1)
        y = y[:, :self.H, :self.W]
        return y - self.t if offset else y

    def adjoint(self, r: np.ndarray) -> np.ndarray:
        """``K^H C^H r``: the residual (3 cones, H, W) back on the image's primaries (3, H, W)."""
        R = scipy.fft.rfft2(r, s=self.P, axes=(1, 2), workers=-1)
        y = scipy.fft.irfft2(apply3(np.conj(np.swapaxes(self.Kf, 0, 1)), R), s=self.P, axes=(1, 2), workers=-1)
        return y[:, :self.H, :self.W]


def _best_on_simplex(r0: np.ndarray, dirs: list[np.ndarray]) -> tuple[list[float], float]:
    """Minimise ``||r0 + sum_i b_i a_i||^2`` over ``b_i >= 0``, ``sum b_i <= 1`` for one or two
    directions ``a_i`` (closed form: the convex quadratic's minimum is the interior stationary
    point or lies on an edge, each a clipped 1-D solve); returns (weights, objective sum)."""
    c = np.array([float(np.sum(r0 * a)) for a in dirs])
    A = np.array([[float(np.sum(a * b)) for b in dirs] for a in dirs])
    base = float(np.sum(r0 * r0))

    def value(b: np.ndarray) -> float:
        return base + 2.0 * float(c @ b) + float(b @ A @ b)

    def line(p: np.ndarray, q: np.ndarray) -> np.ndarray:           # best point on segment p..q
        d = q - p
        curv = float(d @ A @ d)
        s = 0.0 if curv <= 0 else float(np.clip(-(c @ d + p @ A @ d) / curv, 0.0, 1.0))
        return p + s * d

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
           margin: int | None = None, descent: bool = True) -> tuple[np.ndarray, dict]:
    """Best blend of the target and the clipped regularised inverse; returns (image, settings).

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
        return x, {"chosen": "colour matrix (identity kernel)", "beta": 1.0, "mu_rel": 0.0}
    if beta is not None and not 0.0 <= beta <= 1.0:
        raise ValueError(f"beta must be in [0, 1], got {beta!r}")
    P = padded_shape(H, W, problem.kernel.size)
    if design is None:
        design = _first_design_grid(problem.kernel, problem.reference_kernel) <= max(P)
    Kf = scipy.fft.rfft2(centred_kernel(problem.kernel.kernel, P), axes=(2, 3), workers=-1)   # (3, 3, P0, F1)
    f = _FastObjective(problem, Kf, P)
    t_rgb = np.moveaxis(problem.target.astype(np.float64), 2, 0)
    t_in = np.moveaxis(scale_contrast(problem.target, problem.contrast), 2, 0)
    r0 = f.residual(t_rgb)
    best = (float(np.mean(r0 * r0)), t_rgb, {"chosen": "no correction", "beta": 0.0, "mu_rel": None})
    step_dir = step_K = None
    if descent and beta is None:
        s = DESCENT_STEP / spectral_norm_squared(problem.kernel.kernel)
        step_dir = np.clip(t_rgb - s * f.adjoint(r0), 0.0, 1.0) - t_rgb
        step_K = f.residual(step_dir, offset=False)
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
        Kd = f.residual(d, offset=False)
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
    return np.clip(np.moveaxis(best[1], 0, 2), 0.0, 1.0).astype(np.float32), settings


@dataclass(frozen=True)
class GradientPlan:
    """What :func:`projected_gradient` needs of the kernel for one image size, computed once.

    Attributes
    ----------
    shape
        The image's ``(H, W)``.
    padded
        The FFT size (linear convolution, black outside the image).
    spectrum
        The kernel's spectrum ``(3, 3, Py, Px // 2 + 1)`` complex64 (from float64).
    step
        ``1 / ||K||^2`` (the gradient's Lipschitz constant), float32.
    """

    shape: tuple[int, int]
    padded: tuple[int, int]
    spectrum: np.ndarray
    step: np.float32


def gradient_plan(kernel: EyeKernel, shape: tuple[int, int]) -> GradientPlan:
    """The kernel's spectrum and step for images of ``shape`` (a renderer keeps one per eye and size)."""
    H, W = (int(v) for v in shape)
    P = padded_shape(H, W, kernel.size)
    Kf = scipy.fft.rfft2(centred_kernel(kernel.kernel, P), axes=(2, 3), workers=-1).astype(np.complex64)
    return GradientPlan((H, W), P, Kf, np.float32(1.0 / spectral_norm_squared(kernel.kernel)))


def _image_objective(problem: Problem, plan: GradientPlan | None) -> tuple[_FastObjective, GradientPlan]:
    """The objective for an image pass (float32 planes, complex64 spectra) from ``plan``, which is
    built here when ``None`` and must be for the problem's image size otherwise."""
    H, W = problem.target.shape[:2]
    if plan is None:
        plan = gradient_plan(problem.kernel, (H, W))
    elif plan.shape != (H, W) or plan.spectrum.shape[:2] != (3, 3):
        raise ValidationError("plan", f"for {plan.shape[0]}x{plan.shape[1]}", f"a plan for {H}x{W} images")
    f = _FastObjective(problem, plan.spectrum, plan.padded)
    f.t = f.t.astype(np.float32)
    return f, plan


def gradient_step(problem: Problem, x: np.ndarray, plan: GradientPlan | None = None) -> np.ndarray:
    """``step * K^H (K x - t)``: the displacement a projected-gradient step from ``x`` would take
    before clipping (the gradient of ``J/2`` scaled by ``1 / ||K||^2``), float32 ``(H, W, 3)``.

    The learned model's optional fourth input: where the eye's objective still wants ``x`` to go.
    """
    f, plan = _image_objective(problem, plan)
    xc = np.ascontiguousarray(np.moveaxis(x, 2, 0), dtype=np.float32)
    g = plan.step * f.adjoint(f.residual(xc))
    return np.ascontiguousarray(np.moveaxis(g, 0, 2), dtype=np.float32)


@dataclass(frozen=True, eq=False)
class FistaState:
    """Where :func:`projected_gradient` stopped, to continue from there (the GPU keeps the same
    per eye from frame to frame).

    Attributes
    ----------
    x
        The current iterate, float32 ``(3, H, W)`` in [0, 1] (what is displayed, before the guard).
    y
        The extrapolated point the next gradient is taken at, float32 ``(3, H, W)``.
    momentum
        FISTA's ``t_k`` (1 at a cold start; the next weight is ``(t_k - 1) / t_{k+1}``).
    """

    x: np.ndarray
    y: np.ndarray
    momentum: float


def fista_momentum(momentum: float) -> tuple[float, float]:
    """FISTA's next ``t_{k+1} = (1 + sqrt(1 + 4 t_k^2)) / 2`` and the extrapolation weight
    ``(t_k - 1) / t_{k+1}`` (the GPU iteration takes the weight as a uniform)."""
    nxt = (1.0 + math.sqrt(1.0 + 4.0 * momentum * momentum)) / 2.0
    return nxt, (momentum - 1.0) / nxt


def projected_gradient(problem: Problem, steps: int, plan: GradientPlan | None = None,
                       start: np.ndarray | None = None, state: FistaState | None = None,
                       return_state: bool = False):
    """``steps`` accelerated projected-gradient (FISTA) steps on the true objective from the target.

    The step is ``1 / ||K||^2`` (the gradient's Lipschitz constant), the box is [0, 1], the
    convolution is exact and linear (black outside the image), as in :func:`vrcorrect.solvers.objective`.
    Each step costs two 3x3-channel FFT convolutions (``K`` and ``K^H``).  A fixed step
    count makes it a closed form of known cost: on the learned model's data (quest2, eyes
    over -6..+6 D sphere, 0..-3 D cylinder, 2-6 mm pupils, 128^2 crops) 1, 3 and 10 steps
    close about 30 %, 50 % and 80 % of the objective gap between no correction and ``fast``.

    ``plan`` (:func:`gradient_plan` of the problem's kernel and image size) skips the kernel's
    FFT, a fifth of the cost of three steps; without it the plan is built here.

    ``start`` (``(H, W, 3)`` in [0, 1]) starts from that image instead of the target, with the
    momentum reset; ``state`` (a :class:`FistaState` returned earlier, for this image size)
    continues where that run stopped, momentum included, so ``n`` steps then ``m`` more from its
    state equal ``n + m`` steps (the CPU twin of the GPU's frame-to-frame warm start).  Not both.
    ``return_state`` returns ``(image, state)``.

    Computed in float32 (complex64 spectra; the kernel's spectrum and norm in float64 first).
    Returns float32 ``(H, W, 3)`` in [0, 1] (the start itself for ``steps == 0`` or a 1x1 kernel).
    """
    if start is not None and state is not None:
        raise ValidationError("start", "given with state", "a start image or a state to continue, not both")
    H, W = problem.target.shape[:2]
    if state is not None:
        if state.x.shape != (3, H, W) or state.y.shape != (3, H, W):
            raise ValidationError("state", f"for {state.x.shape[1]}x{state.x.shape[2]}", f"a state for {H}x{W} images")
        x, y, momentum = state.x, state.y, float(state.momentum)
    else:
        first = problem.target if start is None else check_image(start, "start")
        if first.shape != (H, W, 3):
            raise ValidationError("start", f"shape {first.shape}", f"the target's shape {(H, W, 3)}")
        x = y = np.ascontiguousarray(np.moveaxis(first, 2, 0), dtype=np.float32)
        momentum = 1.0
    if steps > 0 and problem.kernel.size > 1:
        f, plan = _image_objective(problem, plan)
        step = plan.step
        for _ in range(steps):
            x_new = np.clip(y - step * f.adjoint(f.residual(y)), 0.0, 1.0)
            momentum, weight = fista_momentum(momentum)
            y = x_new + np.float32(weight) * (x_new - x)
            x = x_new
    image = np.ascontiguousarray(np.moveaxis(x, 0, 2), dtype=np.float32)
    return (image, FistaState(x=x, y=y, momentum=momentum)) if return_state else image
